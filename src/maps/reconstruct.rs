//! Rebuilding the scan from the base mesh and its displacement map (SPEC §5, paper Fig. 6):
//! each base triangle is subdivided 1-to-4 per level in its own parameter domain; every new
//! vertex X (positions and directions interpolated as in SPEC §1) moves to X + d·N(X), d read
//! bilinearly from the map. Vertices on base edges and corners are shared between faces, so the
//! result has no cracks and is closed wherever the base is. Where the map has no d (the scan was
//! not met: its own holes), the faces touching such a vertex are left out, as in the scan.

use crate::maps::bake::DispMap;
use crate::geometry::bvh::Bvh;
use crate::guarantee::NormalMode;
use crate::geometry::{face_normal, interpolate_direction};
use crate::validate::Base;
use glam::DVec3;
use rayon::prelude::*;
use std::collections::HashMap;

/// A reconstructed mesh.
#[derive(Clone, Debug)]
pub struct Rebuilt {
    pub positions: Vec<DVec3>,
    pub faces: Vec<[u32; 3]>,
}

/// Key of a subdivision vertex: a base vertex, a point on a base edge (ordered vertex pair and
/// the step from the lower one), or a face-interior point.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
enum Key {
    Corner(u32),
    Edge(u32, u32, u32),
    Inner(u32, u32, u32),
}

/// Subdivides `base` `level` times and displaces by `map` (level 0: the base mesh itself). In
/// constant-normal mode each face is displaced along its own normal, so faces share no vertex
/// (the direction field jumps at every base edge: the paper's Fig. 3b, cracks included).
pub fn reconstruct(base: &Base, map: &DispMap, level: u32, mode: NormalMode) -> Rebuilt {
    let n = 1u32 << level;
    let mut index: HashMap<Key, u32> = HashMap::new();
    let mut positions = Vec::new();
    let mut missing: Vec<bool> = Vec::new();
    let mut faces = Vec::with_capacity(base.faces.len() * (n * n) as usize);
    for (fi, t) in base.faces.iter().enumerate() {
        let fi = fi as u32;
        // Grid point (i, j): barycentric (1 - (i + j)/n, i/n, j/n).
        let key = |i: u32, j: u32| -> Key {
            let k = n - i - j;
            let c = [(k, t[0]), (i, t[1]), (j, t[2])];
            let on: Vec<(u32, u32)> = c.iter().copied().filter(|&(w, _)| w > 0).collect();
            match on.len() {
                _ if mode == NormalMode::Constant => Key::Inner(fi, i, j),
                1 => Key::Corner(on[0].1),
                2 => {
                    let ((wa, a), (_, b)) = (on[0], on[1]);
                    // Steps from the lower-numbered vertex, so both faces agree.
                    if a < b {
                        Key::Edge(a, b, n - wa)
                    } else {
                        Key::Edge(b, a, wa)
                    }
                }
                _ => Key::Inner(fi, i, j),
            }
        };
        let mut id = |i: u32, j: u32, positions: &mut Vec<DVec3>, missing: &mut Vec<bool>| -> u32 {
            let k = key(i, j);
            *index.entry(k).or_insert_with(|| {
                let bary = [(n - i - j) as f64 / n as f64, i as f64 / n as f64, j as f64 / n as f64];
                let p = t.map(|v| base.positions[v as usize]);
                let dir = t.map(|v| base.directions[v as usize]);
                let x = interpolate_direction(&p, &bary);
                let d = if level == 0 { Some(0.0) } else { map.sample(fi, bary[1], bary[2]) };
                let n_x = match mode {
                    NormalMode::Interpolated => interpolate_direction(&dir, &bary),
                    NormalMode::Constant => face_normal(p[0], p[1], p[2]),
                };
                positions.push(x + d.unwrap_or(0.0) * n_x);
                missing.push(d.is_none());
                (positions.len() - 1) as u32
            })
        };
        for j in 0..n {
            for i in 0..n - j {
                let a = id(i, j, &mut positions, &mut missing);
                let b = id(i + 1, j, &mut positions, &mut missing);
                let c = id(i, j + 1, &mut positions, &mut missing);
                faces.push([a, b, c]);
                if i + j + 1 < n {
                    let d = id(i + 1, j + 1, &mut positions, &mut missing);
                    faces.push([b, d, c]);
                }
            }
        }
    }
    if missing.iter().any(|&m| m) {
        faces.retain(|f| f.iter().all(|&v| !missing[v as usize]));
        let mut remap = vec![u32::MAX; positions.len()];
        let mut kept = Vec::new();
        for f in faces.iter_mut() {
            for v in f.iter_mut() {
                if remap[*v as usize] == u32::MAX {
                    remap[*v as usize] = kept.len() as u32;
                    kept.push(positions[*v as usize]);
                }
                *v = remap[*v as usize];
            }
        }
        positions = kept;
    }
    Rebuilt { positions, faces }
}

/// Distances between a reconstruction and the scan, both ways, relative to the scan's
/// bounding-box diagonal: RMS and Hausdorff (max) over the vertices of each side.
#[derive(Clone, Debug, serde::Serialize)]
pub struct Distances {
    pub level: u32,
    pub faces: usize,
    pub rms_to_scan: f64,
    pub hausdorff_to_scan: f64,
    pub rms_from_scan: f64,
    pub hausdorff_from_scan: f64,
}

/// Distance from each point to the nearest triangle of (pos, faces), by a growing search.
fn distances(points: &[DVec3], pos: &[DVec3], faces: &[[u32; 3]], diag: f64) -> Vec<f64> {
    let bvh = Bvh::build(pos, faces);
    points
        .par_iter()
        .map_init(Vec::new, |near, &x| {
            let mut r = diag * 1e-3;
            loop {
                bvh.near(pos, faces, x, r, near);
                if let Some(&(d, _)) = near.first() {
                    return d;
                }
                r *= 4.0;
                if r > 4.0 * diag {
                    return f64::INFINITY;
                }
            }
        })
        .collect()
}

/// Measures a reconstruction against the scan.
pub fn compare(rebuilt: &Rebuilt, level: u32, scan_pos: &[DVec3], scan_faces: &[[u32; 3]]) -> Distances {
    let diag = crate::mesh::bbox_diagonal(scan_pos.iter().copied());
    let stats = |d: &[f64]| {
        let rms = (d.iter().map(|x| x * x).sum::<f64>() / d.len().max(1) as f64).sqrt();
        let max = d.iter().copied().fold(0.0, f64::max);
        (rms / diag, max / diag)
    };
    let (rt, ht) = stats(&distances(&rebuilt.positions, scan_pos, scan_faces, diag));
    let (rf, hf) = stats(&distances(scan_pos, &rebuilt.positions, &rebuilt.faces, diag));
    Distances { level, faces: rebuilt.faces.len(), rms_to_scan: rt, hausdorff_to_scan: ht, rms_from_scan: rf, hausdorff_from_scan: hf }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::maps::fold::Atlas;

    //      2
    //      | \        two triangles sharing edge 1-2; a constant map d = 0.5
    //      |  \       lifts every subdivision vertex by 0.5 along +z, edges shared
    //      0---1
    //       \  |
    //        3-+
    #[test]
    fn subdivision_shares_edges_and_level_zero_is_the_base() {
        let base = Base {
            positions: vec![DVec3::ZERO, DVec3::X, DVec3::Y, DVec3::new(1.0, -1.0, 0.0)],
            directions: vec![DVec3::Z; 4],
            faces: vec![[0, 1, 2], [0, 3, 1]],
        };
        let atlas = Atlas::new(2, 64);
        let map = DispMap { atlas, d: vec![0.5; (atlas.size * atlas.size) as usize], dir: Vec::new(), jump: f64::INFINITY };
        let r0 = reconstruct(&base, &map, 0, NormalMode::Interpolated);
        assert_eq!(r0.positions, base.positions);
        assert_eq!(r0.faces, base.faces);
        let r2 = reconstruct(&base, &map, 2, NormalMode::Interpolated);
        assert_eq!(r2.faces.len(), 2 * 16);
        // (5·6/2) grid points per face, the 5 points of the shared edge counted once.
        assert_eq!(r2.positions.len(), 2 * 15 - 5);
        assert!(r2.positions.iter().all(|p| (p.z - 0.5).abs() < 1e-12));
        let (_, loops) = crate::topology::topology_summary(r2.positions.len(), &r2.faces);
        assert_eq!(loops, 1, "one boundary loop, no cracks along the shared edge");
    }
}
