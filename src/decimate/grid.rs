//! Uniform grids: a static one over the dense vertices, a dynamic one over the base faces.
//! Both answer "what lies near this box", which bounds every search for a smaller |d|.

use crate::topology::Topology;
use glam::DVec3;

/// Cells along the bounding box's longest side of the dense-vertex grid.
/// Why: late in a run a region spans a tenth of the model; 64 keeps its query to a few hundred cells.
const DENSE_GRID_RESOLUTION: f64 = 64.0;

/// Cells along each side of a block of the dense-vertex grid, the unit of its reach bounds.
/// Why: 4 gives at most 16³ blocks (32 KB of bounds), fine enough that a query skips the
/// blocks where every |d| is small, which late in a run is most of them.
const REACH_BLOCK: usize = 4;

/// Cells along the longest side of the face grid.
/// Why: late in a run a base face spans a few cells; early faces share a cell with tens of others.
const FACE_GRID_RESOLUTION: f64 = 32.0;

/// The cell layout shared by both grids.
#[derive(Default)]
struct Frame {
    lo: DVec3,
    cell: f64,
    dims: [usize; 3],
}

impl Frame {
    fn new(points: &[DVec3], resolution: f64) -> Frame {
        let mut lo = DVec3::splat(f64::INFINITY);
        let mut hi = DVec3::splat(f64::NEG_INFINITY);
        for p in points {
            lo = lo.min(*p);
            hi = hi.max(*p);
        }
        let ext = (hi - lo).max(DVec3::splat(1e-12));
        let cell = ext.max_element() / resolution;
        let dims = [0, 1, 2].map(|k| ((ext[k] / cell).floor() as usize + 1).max(1));
        Frame { lo, cell, dims }
    }
    fn num_cells(&self) -> usize {
        self.dims[0] * self.dims[1] * self.dims[2]
    }
    fn coords(&self, p: DVec3) -> [usize; 3] {
        [0, 1, 2].map(|k| (((p[k] - self.lo[k]) / self.cell).floor().max(0.0) as usize).min(self.dims[k] - 1))
    }
    fn index(&self, c: [usize; 3]) -> usize {
        (c[2] * self.dims[1] + c[1]) * self.dims[0] + c[0]
    }
    /// The cells from `a` to `b` (corners included), x fastest.
    fn cells(&self, a: [usize; 3], b: [usize; 3]) -> impl Iterator<Item = usize> + '_ {
        (a[2]..=b[2]).flat_map(move |z| (a[1]..=b[1]).flat_map(move |y| (a[0]..=b[0]).map(move |x| self.index([x, y, z]))))
    }
    /// Calls `f` for each of [`Frame::cells`] (an internal iteration: the nested loops).
    fn for_cells(&self, a: [usize; 3], b: [usize; 3], f: impl FnMut(usize)) {
        self.cells(a, b).for_each(f);
    }
}

/// A static grid over the dense vertex positions (CSR cells), to find the vertices near a
/// changed region whatever face they are associated with.
#[derive(Default)]
pub struct DenseGrid {
    frame: Frame,
    start: Vec<u32>,
    items: Vec<u32>,
    /// Blocks of REACH_BLOCK³ cells along each axis.
    block_dims: [usize; 3],
    /// Per block, an upper bound of the reach its vertices were given ([`DenseGrid::raise_reach`]):
    /// raised, never lowered.
    block_reach: Vec<f64>,
}

impl DenseGrid {
    pub fn new(pos: &[DVec3]) -> DenseGrid {
        let frame = Frame::new(pos, DENSE_GRID_RESOLUTION);
        let ids: Vec<usize> = pos.iter().map(|p| frame.index(frame.coords(*p))).collect();
        let mut start = vec![0u32; frame.num_cells() + 1];
        for &c in &ids {
            start[c + 1] += 1;
        }
        for i in 0..start.len() - 1 {
            start[i + 1] += start[i];
        }
        let mut fill = start.clone();
        let mut items = vec![0u32; pos.len()];
        for (v, &c) in ids.iter().enumerate() {
            items[fill[c] as usize] = v as u32;
            fill[c] += 1;
        }
        let block_dims = frame.dims.map(|d| d.div_ceil(REACH_BLOCK));
        let block_reach = vec![0.0; block_dims[0] * block_dims[1] * block_dims[2]];
        DenseGrid { frame, start, items, block_dims, block_reach }
    }

    /// The block holding cell `c`.
    fn block_of(&self, c: [usize; 3]) -> usize {
        self.block_index(c.map(|k| k / REACH_BLOCK))
    }

    fn block_index(&self, b: [usize; 3]) -> usize {
        (b[2] * self.block_dims[1] + b[1]) * self.block_dims[0] + b[0]
    }

    /// Raises the reach bound of the block holding position `p` (a vertex's) to at least `r`.
    pub fn raise_reach(&mut self, p: DVec3, r: f64) {
        let b = self.block_of(self.frame.coords(p));
        if !(self.block_reach[b] >= r) {
            self.block_reach[b] = r;
        }
    }

    /// Calls `f` for every vertex in the cells overlapping [lo − reach, hi + reach] except those
    /// of blocks that lie at least their reach bound away from the box [lo, hi]: a vertex there
    /// is no nearer the box than its raised reach (the f64 distance is monotone in each
    /// coordinate, and a block's box holds its cells' vertices with a margin for the rounding
    /// of the cell coordinates).
    pub fn query_near(&self, lo: DVec3, hi: DVec3, reach: f64, mut f: impl FnMut(u32)) {
        let r = DVec3::splat(reach);
        let (a, b) = (self.frame.coords(lo - r), self.frame.coords(hi + r));
        let side = self.frame.cell * REACH_BLOCK as f64;
        let margin = 1e-6 * self.frame.cell;
        for bz in a[2] / REACH_BLOCK..=b[2] / REACH_BLOCK {
            for by in a[1] / REACH_BLOCK..=b[1] / REACH_BLOCK {
                for bx in a[0] / REACH_BLOCK..=b[0] / REACH_BLOCK {
                    let bi = [bx, by, bz];
                    let blo = self.frame.lo + DVec3::from_array(bi.map(|k| k as f64)) * side - DVec3::splat(margin);
                    let bhi = blo + DVec3::splat(side + 2.0 * margin);
                    let gap = (lo - bhi).max(blo - hi).max(DVec3::ZERO);
                    if gap.length() >= self.block_reach[self.block_index(bi)] {
                        continue;
                    }
                    let c0 = [0, 1, 2].map(|k| a[k].max(bi[k] * REACH_BLOCK));
                    let c1 = [0, 1, 2].map(|k| b[k].min(bi[k] * REACH_BLOCK + REACH_BLOCK - 1));
                    self.for_items(c0, c1, &mut f);
                }
            }
        }
    }

    /// Calls `f` for every vertex in the cells overlapping the box [lo, hi].
    pub fn query(&self, lo: DVec3, hi: DVec3, f: impl FnMut(u32)) {
        self.for_items(self.frame.coords(lo), self.frame.coords(hi), f);
    }

    /// Calls `f` for every vertex in the cells from `a` to `b` (corners included).
    fn for_items(&self, a: [usize; 3], b: [usize; 3], mut f: impl FnMut(u32)) {
        self.frame.for_cells(a, b, |c| {
            for &v in &self.items[self.start[c] as usize..self.start[c + 1] as usize] {
                f(v);
            }
        });
    }
}

/// A uniform grid over the base faces' bounding boxes, updated as faces change, to find the
/// faces outside a candidate's neighbourhood that could hold a smaller solution.
#[derive(Default)]
pub struct FaceGrid {
    frame: Frame,
    cells: Vec<Vec<u32>>,
    /// Cell range of each face as inserted (low corner, high corner); NO_RANGE for deleted
    /// faces. In u16: the grid has at most FACE_GRID_RESOLUTION + 1 cells a side.
    range: Vec<[u16; 6]>,
}

/// The cell range of a face not in the grid.
const NO_RANGE: [u16; 6] = [u16::MAX; 6];

impl FaceGrid {
    pub fn new(pos: &[DVec3], topo: &Topology) -> FaceGrid {
        let frame = Frame::new(pos, FACE_GRID_RESOLUTION);
        let nf = topo.num_faces_total();
        let mut g = FaceGrid { cells: vec![Vec::new(); frame.num_cells()], frame, range: vec![NO_RANGE; nf] };
        for f in 0..nf as u32 {
            if topo.face_alive(f) {
                g.insert(f, topo.face(f).map(|v| pos[v as usize]));
            }
        }
        g
    }

    pub fn insert(&mut self, f: u32, p: [DVec3; 3]) {
        let a = self.frame.coords(p[0].min(p[1]).min(p[2]));
        let b = self.frame.coords(p[0].max(p[1]).max(p[2]));
        let cells = &mut self.cells;
        self.frame.for_cells(a, b, |c| cells[c].push(f));
        self.range[f as usize] = [a[0], a[1], a[2], b[0], b[1], b[2]].map(|k| k as u16);
    }

    pub fn remove(&mut self, f: u32) {
        let r = std::mem::replace(&mut self.range[f as usize], NO_RANGE);
        if r != NO_RANGE {
            let (a, b) = ([0, 1, 2].map(|k| r[k] as usize), [3, 4, 5].map(|k| r[k] as usize));
            let cells = &mut self.cells;
            self.frame.for_cells(a, b, |c| cells[c].retain(|&g| g != f));
        }
    }

    /// Faces whose cells overlap the box [lo, hi], ascending, without repeats.
    pub fn query(&self, lo: DVec3, hi: DVec3, out: &mut Vec<u32>) {
        let named = self.frame.cells(self.frame.coords(lo), self.frame.coords(hi)).flat_map(|c| self.cells[c].iter().copied());
        crate::guarantee::ids::sorted_unique(named, out);
    }

    /// The faces of [`FaceGrid::query`] that `keep` accepts, cell by cell: unsorted, a face as
    /// many times as it has cells in the box (a cheap cull spares the sort what a coarse cell
    /// holds beyond a small box).
    pub fn query_where(&self, lo: DVec3, hi: DVec3, keep: impl Fn(u32) -> bool, out: &mut Vec<u32>) {
        out.clear();
        self.frame.for_cells(self.frame.coords(lo), self.frame.coords(hi), |c| out.extend(self.cells[c].iter().copied().filter(|&f| keep(f))));
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_near_query_skips_only_vertices_beyond_their_reach() {
        // 4,000 points in a unit cube with reaches of 0.01 .. 0.05, and a few with 0.3 (the
        // large |d| of a thin part): every query finds the same vertices within reach as the
        // full query of the same box, and passes over most of the others.
        let mut rng = crate::geometry::testing::Rng(12345);
        let pos: Vec<DVec3> = (0..4000).map(|_| DVec3::new(rng.next(), rng.next(), rng.next())).collect();
        let reach: Vec<f64> = (0..4000).map(|v| if v % 500 == 0 { 0.3 } else { 0.01 + 0.04 * rng.next() }).collect();
        let mut g = DenseGrid::new(&pos);
        for (p, &r) in pos.iter().zip(&reach) {
            g.raise_reach(*p, r);
        }
        let within = |lo: DVec3, hi: DVec3, v: u32| pos[v as usize].clamp(lo, hi).distance(pos[v as usize]) < reach[v as usize];
        let (mut seen_all, mut seen_near) = (0, 0);
        for q in 0..50 {
            let c = DVec3::new(rng.next(), rng.next(), rng.next());
            let h = DVec3::splat(0.02 + 0.1 * (q % 5) as f64);
            let (lo, hi) = (c - h, c + h);
            let (mut all, mut near) = (Vec::new(), Vec::new());
            g.query(lo - DVec3::splat(0.3), hi + DVec3::splat(0.3), |v| all.push(v));
            g.query_near(lo, hi, 0.3, |v| near.push(v));
            seen_all += all.len();
            seen_near += near.len();
            let mut a: Vec<u32> = all.into_iter().filter(|&v| within(lo, hi, v)).collect();
            let mut b: Vec<u32> = near.into_iter().filter(|&v| within(lo, hi, v)).collect();
            a.sort_unstable();
            b.sort_unstable();
            assert_eq!(a, b, "query {q}");
        }
        // Measured: 30,363 of the full queries' 91,691 vertices visited (33 %); 40 % allowed.
        assert!(seen_near * 10 < seen_all * 4, "{seen_near} of {seen_all}");
    }

    #[test]
    fn face_grid_tracks_moves() {
        // Two triangles far apart on the x axis.
        let pos = vec![
            DVec3::ZERO,
            DVec3::new(0.1, 0.0, 0.0),
            DVec3::new(0.0, 0.1, 0.0),
            DVec3::new(10.0, 0.0, 0.0),
            DVec3::new(10.1, 0.0, 0.0),
            DVec3::new(10.0, 0.1, 0.0),
        ];
        let topo = Topology::build(6, &[[0, 1, 2], [3, 4, 5]]).unwrap();
        let mut g = FaceGrid::new(&pos, &topo);
        let mut out = Vec::new();
        g.query(DVec3::splat(-0.1), DVec3::splat(0.2), &mut out);
        assert_eq!(out, vec![0]);
        g.remove(0);
        g.insert(0, [pos[3], pos[4], pos[5]]);
        g.query(DVec3::splat(-0.1), DVec3::splat(0.2), &mut out);
        assert!(out.is_empty());
        g.query(DVec3::new(9.9, -0.1, -0.1), DVec3::new(10.2, 0.2, 0.1), &mut out);
        assert_eq!(out, vec![0, 1]);
        let dg = DenseGrid::new(&pos);
        let mut seen = Vec::new();
        dg.query(DVec3::new(9.9, -0.1, -0.1), DVec3::new(10.2, 0.2, 0.1), |v| seen.push(v));
        seen.sort();
        assert_eq!(seen, vec![3, 4, 5]);
    }
}
