//! The first release's orientation rule, kept only to report where it disagrees with the exact
//! rule of [`super::check`]: straight chords between the three vertex images, drawn in one base
//! triangle's barycentric plane or projected onto the plane orthogonal to a nearby vertex
//! direction. SPEC §1: at sharp creases chords report false flips and can hide true ones.

use super::check::{on_face, MapContext};
use super::primary::{FaceInfo, Map};
use crate::geometry::{self, interpolate_direction};
use glam::DVec3;

fn image_point(info: &FaceInfo, bary: &[f64; 3]) -> DVec3 {
    interpolate_direction(&info.pos, bary)
}


/// Whether a dense triangle, drawn through its vertices' maps, keeps positive orientation.
/// One base triangle: its barycentric plane. Several: the images are projected onto the plane
/// orthogonal to the direction of their common base vertex (which sees every face of its fan),
/// or, without a common vertex, to the mean normal of the base faces involved.
pub fn chord_positive<C: MapContext>(ctx: &C, m: [Map; 3]) -> bool {
    let orient2 = |a: [f64; 3], b: [f64; 3], c: [f64; 3]| (b[1] - a[1]) * (c[2] - a[2]) - (b[2] - a[2]) * (c[1] - a[1]);
    if m[0].face == m[1].face && m[1].face == m[2].face {
        return orient2(m[0].bary, m[1].bary, m[2].bary) > 0.0;
    }
    let fi = [ctx.face_info(m[0].face), ctx.face_info(m[1].face), ctx.face_info(m[2].face)];
    // Points on a vertex or an edge lie on several faces: if one face holds all three images,
    // draw the triangle in that face's barycentric plane (exact).
    for k in 0..3 {
        let target = &fi[k].verts;
        let on = |i: usize| on_face(&fi[i].verts, &m[i].bary, target);
        if let (Some(a), Some(b), Some(c)) = (on(0), on(1), on(2)) {
            return orient2(a, b, c) > 0.0;
        }
    }
    // The base vertices carrying each point (one for a point on a vertex, two on an edge).
    let sup = [support(&fi[0], &m[0]), support(&fi[1], &m[1]), support(&fi[2], &m[2])];
    let x = [image_point(&fi[0], &m[0].bary), image_point(&fi[1], &m[1].bary), image_point(&fi[2], &m[2].bary)];
    let centroid = (x[0] + x[1] + x[2]) / 3.0;
    let mut best: Option<(f64, DVec3)> = None;
    let mut consider = |dir: DVec3, pos: DVec3| {
        let dist = pos.distance(centroid);
        if best.is_none_or(|b| dist < b.0) {
            best = Some((dist, dir));
        }
    };
    if sup.iter().all(|s| s.len() == 3) {
        // Interior points: the chart vertices are exactly the faces' common vertices.
        for k in 0..3 {
            let v = fi[0].verts[k];
            if fi[1].verts.contains(&v) && fi[2].verts.contains(&v) {
                consider(fi[0].dir[k], fi[0].pos[k]);
            }
        }
    } else {
        let mut all: Vec<u32> = sup.iter().flat_map(|s| s.as_slice().iter().copied()).collect();
        all.sort_unstable();
        all.dedup();
        if all.len() <= 3 {
            if let Some(f) = ctx.face_containing(&all) {
                let target = ctx.face_info(f).verts;
                let on = |i: usize| on_face(&fi[i].verts, &m[i].bary, &target);
                if let (Some(a), Some(b), Some(c)) = (on(0), on(1), on(2)) {
                    return orient2(a, b, c) > 0.0;
                }
            }
        }
        // A base vertex whose closed star holds all three points.
        let mut cands = all;
        cands.extend(fi.iter().flat_map(|f| f.verts));
        cands.sort_unstable();
        cands.dedup();
        for v in cands {
            if let Some((dir, pos)) = star_direction(ctx, v, &sup) {
                consider(dir, pos);
            }
        }
    }
    // Of several chart vertices, the one nearest the image's centroid: a geometric choice, so
    // that the verdict depends neither on which equivalent face represents a point nor on the
    // numbering of the base mesh.
    let n_ref = match best {
        Some((_, dir)) => dir,
        None => fi.iter().map(|f| geometry::face_normal(f.pos[0], f.pos[1], f.pos[2])).sum(),
    };
    (x[1] - x[0]).cross(x[2] - x[0]).dot(n_ref) > 0.0
}

/// The base vertices carrying a point: those with a non-zero barycentric weight.
#[derive(Clone, Copy, Debug)]
struct Support {
    v: [u32; 3],
    n: usize,
}

impl Support {
    fn len(&self) -> usize {
        self.n
    }
    fn as_slice(&self) -> &[u32] {
        &self.v[..self.n]
    }
}

fn support(face: &FaceInfo, m: &Map) -> Support {
    let mut s = Support { v: [0; 3], n: 0 };
    for k in 0..3 {
        if m.bary[k] > geometry::BARY_EPS {
            s.v[s.n] = face.verts[k];
            s.n += 1;
        }
    }
    s
}

/// The direction and position of vertex `v` when every support set lies in a face with `v` (the
/// points are in `v`'s closed star), else `None`.
fn star_direction<C: MapContext>(ctx: &C, v: u32, sup: &[Support]) -> Option<(DVec3, DVec3)> {
    let mut dir = None;
    for s in sup {
        let mut q = [0u32; 4];
        q[..s.n].copy_from_slice(s.as_slice());
        let mut n = s.n;
        if !s.as_slice().contains(&v) {
            q[n] = v;
            n += 1;
        }
        if n > 3 {
            return None;
        }
        let f = ctx.face_containing(&q[..n])?;
        if dir.is_none() {
            let info = ctx.face_info(f);
            dir = info.verts.iter().position(|&w| w == v).map(|k| (info.dir[k], info.pos[k]));
        }
    }
    dir
}

