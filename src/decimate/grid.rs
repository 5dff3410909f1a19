//! Uniform grids: a static one over the dense vertices, a dynamic one over the base faces.
//! Both answer "what lies near this box", which bounds every search for a smaller |d|.

use crate::topology::Topology;
use glam::DVec3;

/// Cells along the bounding box's longest side of the dense-vertex grid.
/// Why: late in a run a region spans a tenth of the model; 64 keeps its query to a few hundred cells.
const DENSE_GRID_RESOLUTION: f64 = 64.0;

/// Cells along the longest side of the face grid.
/// Why: late in a run a base face spans a few cells; early faces share a cell with tens of others.
const FACE_GRID_RESOLUTION: f64 = 32.0;

/// The cell layout shared by both grids.
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
    fn for_cells(&self, a: [usize; 3], b: [usize; 3], mut f: impl FnMut(usize)) {
        for z in a[2]..=b[2] {
            for y in a[1]..=b[1] {
                for x in a[0]..=b[0] {
                    f(self.index([x, y, z]));
                }
            }
        }
    }
}

/// A static grid over the dense vertex positions (CSR cells), to find the vertices near a
/// changed region whatever face they are associated with.
pub struct DenseGrid {
    frame: Frame,
    start: Vec<u32>,
    items: Vec<u32>,
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
        DenseGrid { frame, start, items }
    }

    /// Calls `f` for every vertex in the cells overlapping the box [lo, hi].
    pub fn query(&self, lo: DVec3, hi: DVec3, mut f: impl FnMut(u32)) {
        self.frame.for_cells(self.frame.coords(lo), self.frame.coords(hi), |c| {
            for &v in &self.items[self.start[c] as usize..self.start[c + 1] as usize] {
                f(v);
            }
        });
    }
}

/// A uniform grid over the base faces' bounding boxes, updated as faces change, to find the
/// faces outside a candidate's neighbourhood that could hold a smaller solution.
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
        out.clear();
        self.frame.for_cells(self.frame.coords(lo), self.frame.coords(hi), |c| out.extend_from_slice(&self.cells[c]));
        out.sort_unstable();
        out.dedup();
    }
}

#[cfg(test)]
mod tests {
    use super::*;

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
