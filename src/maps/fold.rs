//! The fold image (paper Fig. 1c): every base triangle gets a cell of a texture atlas; every
//! dense triangle is drawn into it through its vertices' primary solutions, and the coverage of
//! each texel is counted. Covered once: good. More than once: a fold (white). Never: a hole.
//!
//! A dense triangle whose vertices map to several base faces is split in four, the new points
//! solved like its vertices, until every piece lies on one face (at most MAX_SPLIT levels); a
//! piece still straddling is drawn into each of its corners' faces, the other corners unfolded
//! into that face's plane across the edges between ([`unfold_across`]).
//!
//! Atlas: base triangles are taken in pairs, one square cell per pair (the first triangle in
//! the lower-left half, the second in the upper-right half), cells row by row from the top-left.
//! A gutter of GUTTER texels surrounds each cell and a band of about DIAGONAL_GAP texels
//! separates the two triangles of a cell, so that a bilinear lookup inside a chart never reads
//! another chart's texels (the displacement map fills gutters from its own chart).

use crate::guarantee::{Map, NormalMode, Scratch, Tris};
use crate::geometry::{barycentric, interpolate_direction};
use crate::mesh::DenseData;
use crate::validate::Base;
use rayon::prelude::*;
use std::sync::atomic::{AtomicU32, Ordering};

/// Texels around each cell. Why: a bilinear lookup reads one texel beyond the chart; two keep
/// it inside the chart's own gutter.
const GUTTER: f64 = 2.0;

/// Texels (along each axis) between the hypotenuses of a cell's two triangles.
/// Why: the same bilinear margin as GUTTER, on the diagonal.
const DIAGONAL_GAP: f64 = 3.0;

/// Levels of splitting for a dense triangle that straddles base faces.
/// Why: 4 levels make pieces 1/16 of a dense edge, below a texel at any practical resolution.
const MAX_SPLIT: u32 = 4;

/// Texel value outside every chart.
pub const OUTSIDE: u8 = 255;

/// The atlas layout of a base mesh at a given resolution.
#[derive(Clone, Copy, Debug)]
pub struct Atlas {
    pub size: u32,
    pub cells_per_row: u32,
    pub cell_px: u32,
    pub faces: u32,
}

impl Atlas {
    pub fn new(faces: usize, size: u32) -> Atlas {
        let cells = faces.div_ceil(2).max(1) as u32;
        let cells_per_row = (cells as f64).sqrt().ceil() as u32;
        let cell_px = (size / cells_per_row).max(4);
        Atlas { size: cell_px * cells_per_row, cells_per_row, cell_px, faces: faces as u32 }
    }

    /// Chart scale: the triangle's legs span `k` of the cell's inner width.
    fn k(&self) -> f64 {
        let inner = self.cell_px as f64 - 2.0 * GUTTER;
        (1.0 - DIAGONAL_GAP / inner).max(0.5)
    }

    /// The base face and barycentric coordinates a texel centre stands for, when it lies on the
    /// face's chart.
    pub fn texel(&self, px: u32, py: u32) -> Option<(u32, [f64; 3])> {
        match self.texel_any(px, py) {
            Some((f, b, true)) => Some((f, b)),
            _ => None,
        }
    }

    /// The face whose side of its cell a texel lies on, with (possibly out-of-triangle)
    /// barycentric coordinates and whether the texel is on the chart itself (not in a gutter).
    pub fn texel_any(&self, px: u32, py: u32) -> Option<(u32, [f64; 3], bool)> {
        if px >= self.size || py >= self.size {
            return None;
        }
        let (cx, cy) = (px / self.cell_px, py / self.cell_px);
        let inner = self.cell_px as f64 - 2.0 * GUTTER;
        let lx = ((px % self.cell_px) as f64 + 0.5 - GUTTER) / inner;
        let ly = ((py % self.cell_px) as f64 + 0.5 - GUTTER) / inner;
        let cell = cy * self.cells_per_row + cx;
        let k = self.k();
        let (face, u, v) = if lx + ly <= 1.0 { (2 * cell, lx / k, ly / k) } else { (2 * cell + 1, (1.0 - lx) / k, (1.0 - ly) / k) };
        if face >= self.faces {
            return None;
        }
        let inside = u >= 0.0 && v >= 0.0 && u + v <= 1.0;
        Some((face, [1.0 - u - v, u, v], inside))
    }

    /// Texture coordinates of corner `k` (0, 1, 2) of `face`, u right and v up in [0, 1] (the
    /// OBJ and Blender convention; glTF's v runs down: 1 − v).
    pub fn uv_up(&self, face: u32, k: usize) -> (f64, f64) {
        let (u, v) = [(0.0, 0.0), (1.0, 0.0), (0.0, 1.0)][k];
        let (x, y) = self.position(face, u, v);
        (x / self.size as f64, 1.0 - y / self.size as f64)
    }

    /// Texel-space position (continuous, texel centres at +0.5) of barycentric (u, v) on `face`.
    pub fn position(&self, face: u32, u: f64, v: f64) -> (f64, f64) {
        let cell = face / 2;
        let (cx, cy) = ((cell % self.cells_per_row) as f64, (cell / self.cells_per_row) as f64);
        let inner = self.cell_px as f64 - 2.0 * GUTTER;
        let k = self.k();
        let (lx, ly) = if face % 2 == 0 { (u * k, v * k) } else { (1.0 - u * k, 1.0 - v * k) };
        (cx * self.cell_px as f64 + GUTTER + lx * inner, cy * self.cell_px as f64 + GUTTER + ly * inner)
    }
}

/// Crossing counts per texel and per base face.
pub struct FoldImage {
    pub atlas: Atlas,
    /// Row-major, `OUTSIDE` where no chart is.
    pub counts: Vec<u8>,
    /// Per base face: texels, texels covered once, folded texels (> 1), holes (0).
    pub per_face: Vec<[u32; 4]>,
}

impl FoldImage {
    /// Mean coverage of each base face (1 = exactly once everywhere).
    pub fn coverage(&self) -> Vec<f64> {
        let mut sum = vec![0.0f64; self.per_face.len()];
        for py in 0..self.atlas.size {
            for px in 0..self.atlas.size {
                let c = self.counts[(py * self.atlas.size + px) as usize];
                if c != OUTSIDE {
                    if let Some((f, _)) = self.atlas.texel(px, py) {
                        sum[f as usize] += c as f64;
                    }
                }
            }
        }
        sum.iter().zip(&self.per_face).map(|(s, p)| if p[0] > 0 { s / p[0] as f64 } else { 1.0 }).collect()
    }

    pub fn folded_texels(&self) -> usize {
        self.per_face.iter().map(|p| p[2] as usize).sum()
    }
    pub fn hole_texels(&self) -> usize {
        self.per_face.iter().map(|p| p[3] as usize).sum()
    }

    /// RGB PNG: once = green-grey, folds = white, holes = red, outside the charts = dark grey.
    pub fn to_png(&self) -> Vec<u8> {
        let n = self.atlas.size as usize;
        let mut rgb = Vec::with_capacity(n * n * 3);
        for &c in &self.counts {
            rgb.extend_from_slice(&match c {
                OUTSIDE => [32, 32, 32],
                0 => [220, 40, 40],
                1 => [96, 150, 96],
                _ => [255, 255, 255],
            });
        }
        let mut out = Vec::new();
        {
            let mut enc = png::Encoder::new(&mut out, n as u32, n as u32);
            enc.set_color(png::ColorType::Rgb);
            enc.set_depth(png::BitDepth::Eight);
            let mut w = enc.write_header().expect("PNG header into memory");
            w.write_image_data(&rgb).expect("PNG data into memory");
        }
        out
    }
}

/// Draws every dense triangle with three maps into the atlas of `base` and counts coverage.
/// `maps[v]` is the primary solution of dense vertex v (`None`: unmapped or pinched).
pub fn fold_image(dense: &DenseData, base: &Base, maps: &[Option<Map>], mode: NormalMode, dmax: f64, size: u32) -> FoldImage {
    let atlas = Atlas::new(base.faces.len(), size);
    let n = atlas.size as usize;
    let acc: Vec<AtomicU32> = (0..n * n).map(|_| AtomicU32::new(0)).collect();
    paint(dense, base, maps, mode, dmax, &atlas, &acc, None);
    let mut counts = vec![OUTSIDE; n * n];
    let mut per_face = vec![[0u32; 4]; base.faces.len()];
    for py in 0..atlas.size {
        for px in 0..atlas.size {
            let Some((f, _)) = atlas.texel(px, py) else { continue };
            let i = py as usize * n + px as usize;
            let c = acc[i].load(Ordering::Relaxed).min(254) as u8;
            counts[i] = c;
            let e = &mut per_face[f as usize];
            e[0] += 1;
            match c {
                0 => e[3] += 1,
                1 => e[1] += 1,
                _ => e[2] += 1,
            }
        }
    }
    FoldImage { atlas, counts, per_face }
}

/// Draws every dense triangle with three maps: counts into `acc`, and with `owner`, the
/// lowest dense face covering each texel.
#[allow(clippy::too_many_arguments)]
fn paint(dense: &DenseData, base: &Base, maps: &[Option<Map>], mode: NormalMode, dmax: f64, atlas: &Atlas, acc: &[AtomicU32], owner: Option<&[[AtomicU32; 2]]>) {
    let index = crate::validate::BaseIndex::new(base);
    let (fan_start, fan) = crate::mesh::vertex_faces(base.positions.len(), &base.faces);
    let painter = Painter { atlas, base, index: &index, fan_start: &fan_start, fan: &fan, mode, dmax, acc, owner };
    (0..dense.faces.len()).into_par_iter().for_each_init(
        || (Scratch::default(), Vec::new(), Tris::default()),
        |(scratch, near, tris), df| {
            let t = dense.faces[df];
            let [Some(m0), Some(m1), Some(m2)] = t.map(|v| maps[v as usize]) else { return };
            let p = t.map(|v| dense.pos[v as usize]);
            painter.draw(df as u32, p, [m0, m1, m2], dense.normal[df], MAX_SPLIT, scratch, near, tris);
        },
    );
}

/// Which dense triangles' images cover each texel of the atlas: the lowest and the highest
/// dense face id (the same where one does; `u32::MAX` for both where none does; where the
/// image folds, the two sheets): the fold image's rasterisation, kept per texel.
pub struct Owners {
    pub atlas: Atlas,
    pub owner: Vec<[u32; 2]>,
}

pub fn cover_owners(dense: &DenseData, base: &Base, maps: &[Option<Map>], mode: NormalMode, dmax: f64, size: u32) -> Owners {
    let atlas = Atlas::new(base.faces.len(), size);
    let n = atlas.size as usize;
    let acc: Vec<AtomicU32> = (0..n * n).map(|_| AtomicU32::new(0)).collect();
    let owner: Vec<[AtomicU32; 2]> = (0..n * n).map(|_| [AtomicU32::new(u32::MAX), AtomicU32::new(u32::MAX)]).collect();
    paint(dense, base, maps, mode, dmax, &atlas, &acc, Some(&owner));
    Owners { atlas, owner: owner.into_iter().map(|[a, b]| [a.into_inner(), b.into_inner()]).collect() }
}

struct Painter<'a> {
    atlas: &'a Atlas,
    base: &'a Base,
    index: &'a crate::validate::BaseIndex<'a>,
    /// The base faces around each base vertex v: `fan[fan_start[v]..fan_start[v + 1]]`.
    fan_start: &'a [u32],
    fan: &'a [u32],
    mode: NormalMode,
    dmax: f64,
    acc: &'a [AtomicU32],
    owner: Option<&'a [[AtomicU32; 2]]>,
}

impl Painter<'_> {
    fn corners(&self, f: u32) -> [glam::DVec3; 3] {
        self.base.faces[f as usize].map(|v| self.base.positions[v as usize])
    }

    /// Point `x` of face `g` laid out in the plane of face `f`: unfolded across the edge they
    /// share; where they share only a vertex, across the two edges of a face `h` between them
    /// (g → h → f); else projected. `None` where an unfolding meets a degenerate triangle.
    fn lay_out(&self, g: u32, f: u32, x: glam::DVec3) -> Option<glam::DVec3> {
        if let Some((p, q)) = self.shared_edge(g, f) {
            return unfold_across(p, q, self.corners(g), self.corners(f), x);
        }
        let (vg, vf) = (self.base.faces[g as usize], self.base.faces[f as usize]);
        let Some(&w) = vg.iter().find(|v| vf.contains(v)) else { return Some(x) };
        // A face h across an edge (w, a) of g, in the order of g's corners, that shares an edge
        // with f: the fan between them.
        let around = &self.fan[self.fan_start[w as usize] as usize..self.fan_start[w as usize + 1] as usize];
        for &a in vg.iter().filter(|&&a| a != w) {
            for &h in around.iter().filter(|&&h| h != g && self.base.faces[h as usize].contains(&a)) {
                if let (Some((p1, q1)), Some((p2, q2))) = (self.shared_edge(g, h), self.shared_edge(h, f)) {
                    let xh = unfold_across(p1, q1, self.corners(g), self.corners(h), x)?;
                    return unfold_across(p2, q2, self.corners(h), self.corners(f), xh);
                }
            }
        }
        Some(x)
    }

    /// The positions of the edge faces `f` and `g` share, when they share one.
    fn shared_edge(&self, f: u32, g: u32) -> Option<(glam::DVec3, glam::DVec3)> {
        let (vf, vg) = (self.base.faces[f as usize], self.base.faces[g as usize]);
        let mut shared = vf.iter().filter(|v| vg.contains(v)).map(|&v| self.base.positions[v as usize]);
        match (shared.next(), shared.next(), shared.next()) {
            (Some(p), Some(q), None) => Some((p, q)),
            _ => None,
        }
    }

    /// Draws the dense (sub-)triangle `p` whose corners map to `m`.
    #[allow(clippy::too_many_arguments)]
    fn draw(
        &self,
        df: u32,
        p: [glam::DVec3; 3],
        m: [Map; 3],
        normal: glam::DVec3,
        depth: u32,
        scratch: &mut Scratch,
        near: &mut Vec<(f64, u32)>,
        tris: &mut Tris,
    ) {
        if m[0].face == m[1].face && m[1].face == m[2].face {
            let f = m[0].face;
            let pts = m.map(|mi| self.atlas.position(f, mi.bary[1], mi.bary[2]));
            rasterise(self.atlas, f, pts, self.acc, self.owner.map(|o| (o, df)));
            return;
        }
        if depth > 0 {
            let mid = [0.5 * (p[0] + p[1]), 0.5 * (p[1] + p[2]), 0.5 * (p[2] + p[0])];
            let solve = |x, scratch: &mut Scratch, near: &mut Vec<(f64, u32)>, tris: &mut Tris| {
                crate::validate::primary_global(self.index, x, &[normal], self.mode, self.dmax, true, scratch, near, tris)
            };
            if let (Some(a), Some(b), Some(c)) =
                (solve(mid[0], scratch, near, tris), solve(mid[1], scratch, near, tris), solve(mid[2], scratch, near, tris))
            {
                for (q, mm) in [
                    ([p[0], mid[0], mid[2]], [m[0], a, c]),
                    ([mid[0], p[1], mid[1]], [a, m[1], b]),
                    ([mid[2], mid[1], p[2]], [c, b, m[2]]),
                    ([mid[0], mid[1], mid[2]], [a, b, c]),
                ] {
                    self.draw(df, q, mm, normal, depth - 1, scratch, near, tris);
                }
                return;
            }
        }
        // Still straddling: draw into each corner's face, the corners on other faces laid out
        // in its chart (unfolded across the edges between; else projected onto its plane), so
        // that the chart's own edges clip the piece to the part that lies on the face.
        let x = m.map(|mi| interpolate_direction(&self.corners(mi.face), &mi.bary));
        let mut drawn = [u32::MAX; 3];
        for k in 0..3 {
            let f = m[k].face;
            if drawn.contains(&f) {
                continue;
            }
            drawn[k] = f;
            let c = self.corners(f);
            let uv = |i: usize| -> Option<(f64, f64)> {
                if m[i].face == f {
                    return Some((m[i].bary[1], m[i].bary[2]));
                }
                let x = self.lay_out(m[i].face, f, x[i])?;
                barycentric(x, c[0], c[1], c[2]).map(|b| (b[1], b[2]))
            };
            let (Some(a), Some(b), Some(cc)) = (uv(0), uv(1), uv(2)) else { continue };
            let pts = [self.atlas.position(f, a.0, a.1), self.atlas.position(f, b.0, b.1), self.atlas.position(f, cc.0, cc.1)];
            rasterise(self.atlas, f, pts, self.acc, self.owner.map(|o| (o, df)));
        }
    }
}

/// Point `x` of triangle `g` laid out in the plane of triangle `f`, the two unfolded about the
/// edge `p`–`q` they share (an isometry of the hinge): `x` keeps its distance along the edge and
/// from it, on the side away from `f`'s third corner. An orthogonal projection instead can put
/// a point of `g` inside `f` where `f`'s plane is turned across `g` (a sliver of a base face,
/// nearly a segment, whose plane may stand at any angle): it was drawn into `f` as if it lay
/// there. `None` when either triangle is degenerate at the edge.
///
/// ```text
///        r_f                    r_f
///       /   \                  /   \
///      p─────q    →  unfold   p─────q
///       \ x /                  \ x'/     x' in f's plane, across p–q
///        r_g  (bent away)       r_g'
/// ```
fn unfold_across(p: glam::DVec3, q: glam::DVec3, g: [glam::DVec3; 3], f: [glam::DVec3; 3], x: glam::DVec3) -> Option<glam::DVec3> {
    let e = (q - p).normalize_or_zero();
    // The unit direction in a triangle's plane, perpendicular to the edge, toward its third
    // corner (the corner farthest from the edge's line).
    let inward = |t: [glam::DVec3; 3]| -> Option<glam::DVec3> {
        let off = t.map(|c| (c - p) - e * (c - p).dot(e));
        let far = off.into_iter().max_by(|a, b| a.length_squared().total_cmp(&b.length_squared()))?;
        let u = far.normalize_or_zero();
        (u != glam::DVec3::ZERO && e != glam::DVec3::ZERO).then_some(u)
    };
    let (ug, uf) = (inward(g)?, inward(f)?);
    let (s, t) = ((x - p).dot(e), (x - p).dot(ug));
    Some(p + e * s - uf * t)
}

/// Adds 1 to every texel of face `f`'s chart whose centre lies in the triangle `pts` (either
/// orientation; a centre on a shared edge belongs to one side only: the top-left rule), and
/// with `owner` records dense face `df` there (the lowest and the highest are kept).
fn rasterise(atlas: &Atlas, f: u32, mut pts: [(f64, f64); 3], acc: &[AtomicU32], owner: Option<(&[[AtomicU32; 2]], u32)>) {
    let area = (pts[1].0 - pts[0].0) * (pts[2].1 - pts[0].1) - (pts[1].1 - pts[0].1) * (pts[2].0 - pts[0].0);
    if area == 0.0 || !area.is_finite() {
        return;
    }
    if area < 0.0 {
        pts.swap(1, 2);
    }
    let n = atlas.size as i64;
    let cell = (f / 2) as i64;
    let cpr = atlas.cells_per_row as i64;
    let (cx0, cy0) = ((cell % cpr) * atlas.cell_px as i64, (cell / cpr) * atlas.cell_px as i64);
    let (cx1, cy1) = (cx0 + atlas.cell_px as i64 - 1, cy0 + atlas.cell_px as i64 - 1);
    let lo_x = (pts.iter().map(|p| p.0).fold(f64::INFINITY, f64::min).floor() as i64).max(cx0);
    let hi_x = (pts.iter().map(|p| p.0).fold(f64::NEG_INFINITY, f64::max).ceil() as i64).min(cx1);
    let lo_y = (pts.iter().map(|p| p.1).fold(f64::INFINITY, f64::min).floor() as i64).max(cy0);
    let hi_y = (pts.iter().map(|p| p.1).fold(f64::NEG_INFINITY, f64::max).ceil() as i64).min(cy1);
    let edge = |a: (f64, f64), b: (f64, f64), x: f64, y: f64| (b.0 - a.0) * (y - a.1) - (b.1 - a.1) * (x - a.0);
    // Top-left rule for a counter-clockwise triangle in a y-down raster.
    let owns = |a: (f64, f64), b: (f64, f64)| (a.1 == b.1 && b.0 < a.0) || b.1 > a.1;
    for py in lo_y..=hi_y {
        for px in lo_x..=hi_x {
            let (x, y) = (px as f64 + 0.5, py as f64 + 0.5);
            let inside = (0..3).all(|k| {
                let (a, b) = (pts[k], pts[(k + 1) % 3]);
                let w = edge(a, b, x, y);
                w > 0.0 || (w == 0.0 && owns(a, b))
            });
            if !inside || px < 0 || py < 0 || px >= n || py >= n {
                continue;
            }
            if atlas.texel(px as u32, py as u32).map(|t| t.0) == Some(f) {
                acc[(py * n + px) as usize].fetch_add(1, Ordering::Relaxed);
                if let Some((o, df)) = owner {
                    let slot = &o[(py * n + px) as usize];
                    slot[0].fetch_min(df, Ordering::Relaxed);
                    // u32::MAX + 1 wraps to 0: the highest id, with MAX still meaning none.
                    slot[1].fetch_update(Ordering::Relaxed, Ordering::Relaxed, |h| (h == u32::MAX || df > h).then_some(df)).ok();
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A face `g` folded back over `f` (a dihedral of 45°, as at a sliver whose plane stands
    /// across its neighbours'): projected onto f's plane, a point of g lands inside f; unfolded
    /// about the shared edge, it lands across the edge, at its own distances.
    ///
    /// ```text
    ///   side view along p–q (the x axis):   r_f (y = 1, z = 0)
    ///                                      /
    ///     r_g (y = 0.5, z = 0.5)  g ──── p,q ──── f
    ///   g leans back over f; x on g at (0.3, 0.2, 0.2)
    /// ```
    #[test]
    fn a_point_of_a_face_folded_over_its_neighbour_is_laid_out_across_the_shared_edge() {
        use glam::DVec3;
        let (p, q) = (DVec3::ZERO, DVec3::X);
        let f = [p, q, DVec3::new(0.5, 1.0, 0.0)];
        let g = [q, p, DVec3::new(0.5, 0.5, 0.5)];
        let x = DVec3::new(0.3, 0.2, 0.2);
        let b = |x: DVec3| barycentric(x, f[0], f[1], f[2]).unwrap();
        // The projection onto f's plane, (0.3, 0.2, 0), is inside f: every weight positive.
        assert!(b(DVec3::new(0.3, 0.2, 0.0)).iter().all(|&w| w > 0.0));
        let u = unfold_across(p, q, g, f, x).unwrap();
        // Same distance along the edge (0.3) and from it (0.2·√2), on the far side of f.
        let d = 0.2 * 2f64.sqrt();
        assert!((u - DVec3::new(0.3, -d, 0.0)).length() < 1e-12, "{u}");
        assert!(b(u)[2] < 0.0, "across the edge p–q: f's third weight negative");
        // A point on the shared edge stays where it is.
        assert!((unfold_across(p, q, g, f, DVec3::new(0.7, 0.0, 0.0)).unwrap() - DVec3::new(0.7, 0.0, 0.0)).length() < 1e-15);
    }

    #[test]
    fn atlas_covers_every_face_with_both_halves() {
        let a = Atlas::new(7, 256);
        let mut seen = vec![0u32; 7];
        for py in 0..a.size {
            for px in 0..a.size {
                if let Some((f, b)) = a.texel(px, py) {
                    seen[f as usize] += 1;
                    assert!(b.iter().all(|&x| x >= -1e-12) && (b.iter().sum::<f64>() - 1.0).abs() < 1e-12);
                }
            }
        }
        assert!(seen.iter().all(|&s| s > 100), "{seen:?}");
    }
}
