//! The independent, global check of SPEC §1/§4: every dense vertex is solved against the whole
//! base mesh (not only a neighbourhood), then every dense triangle's orientation and every dense
//! edge's continuity are checked with those primary solutions.
//!
//! Triangles are visited best-first by a lower bound on |d| (the distance from the point to a
//! BVH node's box, then to the triangle), so a vertex costs a handful of cubic solves.

use crate::eval::{check_faces_and_edges, find_primary, FaceInfo, Found, Map, MapContext, NormalMode, Reject, Scratch, Tris};
use crate::bvh::Bvh;
use crate::decimate::State;
use crate::mesh::{vertex_faces, DenseData};
use glam::DVec3;
use rayon::prelude::*;

/// A base mesh to judge: positions, per-vertex directions, faces.
#[derive(Clone, Debug)]
pub struct Base {
    pub positions: Vec<DVec3>,
    pub directions: Vec<DVec3>,
    pub faces: Vec<[u32; 3]>,
}

/// Per dense vertex category.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum VertexStatus {
    Mapped,
    Unmapped,
    Pinched,
}

/// The result of a global check.
#[derive(Clone, Debug, serde::Serialize)]
pub struct Verdict {
    /// unmapped = flipped = torn = 0 (and, with `strict`, ambiguous = 0).
    pub valid: bool,
    pub strict: bool,
    pub dense_vertices: usize,
    pub mapped: usize,
    pub unmapped: usize,
    pub pinched: usize,
    /// Mapped vertices with a second solution satisfying (4) on a triangle touching the
    /// primary's (the shells overlap there); counted only when asked for.
    pub ambiguous: usize,
    /// Mapped vertices with a second solution satisfying (4) on a triangle that does not touch
    /// the primary's (another sheet); counted only when asked for.
    pub far_hits: usize,
    pub dense_faces: usize,
    pub flipped: usize,
    pub torn: usize,
    pub max_abs_d: f64,
    pub rms_d: f64,
    pub dmax: f64,
    /// Internal indices of the first unmapped vertices.
    pub first_unmapped: Vec<u32>,
    /// Internal indices of the first flipped and torn dense faces.
    pub first_flipped: Vec<u32>,
    pub first_torn: Vec<u32>,
}

/// Candidate triangles for one point: the exact search set of a best-first query, as [`Tris`].
fn candidate_tris(base: &Base, bvh: &Bvh, x: DVec3, limit: f64, near: &mut Vec<(f64, u32)>, tris: &mut Tris) {
    bvh.near(&base.positions, &base.faces, x, limit, near);
    tris.clear();
    for &(_, f) in near.iter() {
        let t = base.faces[f as usize];
        tris.push(f, t, t.map(|v| base.positions[v as usize]), t.map(|v| base.directions[v as usize]));
    }
    tris.finish();
}

struct ValidateContext<'a> {
    base: &'a Base,
    /// Faces around each base vertex (CSR).
    vf_start: Vec<u32>,
    vf: Vec<u32>,
    bvh: &'a Bvh,
    maps: &'a [Option<Map>],
    pinched: &'a [bool],
    mode: NormalMode,
    dmax: f64,
}

/// First search radius of [`primary_global`], as a fraction of dmax.
/// Why: most points lie far closer to the base than dmax; small radii keep the set tiny.
const FIRST_RADIUS: f64 = 1.0 / 64.0;

/// The primary solution of `x` over the whole base: triangles within a growing radius L are
/// searched; a hit with |d| ≤ L is the primary, since any solution with |d| ≤ L lies on a
/// triangle within distance L.
#[allow(clippy::too_many_arguments)]
pub(crate) fn primary_global(
    base: &Base,
    bvh: &Bvh,
    x: DVec3,
    normals: &[DVec3],
    mode: NormalMode,
    dmax: f64,
    check4: bool,
    scratch: &mut Scratch,
    near: &mut Vec<(f64, u32)>,
    tris: &mut Tris,
) -> Option<Map> {
    let mut radius = FIRST_RADIUS * dmax;
    loop {
        let r = radius.min(dmax);
        candidate_tris(base, bvh, x, r, near, tris);
        if let Found::Hit(t, h) = find_primary(x, normals, tris, mode, dmax, check4, false, scratch) {
            if h.d.abs() <= r || r >= dmax {
                return Some(Map { face: tris.ids[t], bary: h.bary, d: h.d });
            }
        }
        if r >= dmax {
            return None;
        }
        radius *= 4.0;
    }
}

impl ValidateContext<'_> {
    fn solve(&self, x: DVec3, normals: &[DVec3], scratch: &mut Scratch) -> Option<Map> {
        let mut near = Vec::new();
        let mut tris = Tris::default();
        primary_global(self.base, self.bvh, x, normals, self.mode, self.dmax, true, scratch, &mut near, &mut tris)
    }
}

impl MapContext for ValidateContext<'_> {
    fn map_of(&self, v: u32) -> Option<Map> {
        if self.pinched[v as usize] {
            return None;
        }
        self.maps[v as usize]
    }
    fn face_info(&self, face: u32) -> FaceInfo {
        let verts = self.base.faces[face as usize];
        FaceInfo {
            verts,
            pos: verts.map(|v| self.base.positions[v as usize]),
            dir: verts.map(|v| self.base.directions[v as usize]),
        }
    }
    fn face_containing(&self, verts: &[u32]) -> Option<u32> {
        let v = verts[0] as usize;
        self.vf[self.vf_start[v] as usize..self.vf_start[v + 1] as usize]
            .iter()
            .copied()
            .find(|&f| verts.iter().all(|w| self.base.faces[f as usize].contains(w)))
    }
    fn solve_point(&self, x: DVec3, normals: &[DVec3], _fa: u32, _fb: u32, scratch: &mut Scratch) -> Option<Map> {
        self.solve(x, normals, scratch)
    }
}

/// Second solutions of a mapped vertex: (ambiguous, far hit).
fn second_solutions(
    base: &Base,
    bvh: &Bvh,
    faces_touch: impl Fn(u32, u32) -> bool,
    x: DVec3,
    normals: &[DVec3],
    primary: Map,
    mode: NormalMode,
    dmax: f64,
    near: &mut Vec<(f64, u32)>,
    tris: &mut Tris,
) -> (bool, bool) {
    candidate_tris(base, bvh, x, dmax, near, tris);
    let p0 = {
        let t = base.faces[primary.face as usize].map(|v| base.positions[v as usize]);
        crate::geometry::interpolate_direction(&t, &primary.bary)
    };
    let (mut amb, mut far) = (false, false);
    for t in 0..tris.len() {
        for h in crate::eval::solve_tri(x, tris, t, mode, dmax).iter() {
            if !crate::geometry::condition4(crate::eval::direction_at(tris, t, &h, mode), normals.iter().copied()) {
                continue;
            }
            let p = crate::geometry::interpolate_direction(&tris.pos[t], &h.bary);
            if p.distance(p0) <= crate::eval::SAME_SOLUTION_REL * dmax {
                continue; // the primary itself, seen from a neighbouring face
            }
            if faces_touch(tris.ids[t], primary.face) {
                amb = true;
            } else {
                far = true;
            }
        }
    }
    (amb, far)
}

/// Judges `base` against the dense mesh over the whole base mesh. With `second`, every mapped
/// vertex's other solutions are classified too (ambiguous or far hit); `strict` makes an
/// ambiguous vertex invalid (and implies `second`).
pub fn validate(dense: &DenseData, base: &Base, mode: NormalMode, dmax: f64, strict: bool, second: bool) -> Verdict {
    validate_with_maps(dense, base, mode, dmax, strict, second).0
}

/// [`validate`], also returning every dense vertex's primary solution (`None`: unmapped or
/// pinched), for the fold image.
pub fn validate_with_maps(
    dense: &DenseData,
    base: &Base,
    mode: NormalMode,
    dmax: f64,
    strict: bool,
    second: bool,
) -> (Verdict, Vec<Option<Map>>) {
    match validate_on(dense, base, mode, dmax, strict, second, None) {
        Ok(r) => r,
        Err(e) => unreachable!("the CPU projection cannot fail: {e}"),
    }
}

/// The primary solution of every dense vertex over the whole base, on the CPU.
fn project_cpu(dense: &DenseData, base: &Base, bvh: &Bvh, mode: NormalMode, dmax: f64) -> Vec<Option<Map>> {
    (0..dense.pos.len() as u32)
        .into_par_iter()
        .map_init(
            || (Scratch::default(), Vec::new(), Vec::new(), Tris::default()),
            |(scratch, normals, near, tris), v| {
                dense.vertex_normals(v, normals);
                let x = dense.pos[v as usize];
                let pinched = dense.pinched[v as usize];
                primary_global(base, bvh, x, normals, mode, dmax, !pinched, scratch, near, tris)
            },
        )
        .collect()
}

/// [`validate_with_maps`] with the projection step on `gpu` when given (the GPU decides each
/// vertex's primary triangle; the tolerance band and the d values are settled in f64, so the
/// verdict is the CPU's).
pub fn validate_on(
    dense: &DenseData,
    base: &Base,
    mode: NormalMode,
    dmax: f64,
    strict: bool,
    second: bool,
    gpu: Option<&crate::gpu_eval::GpuEvaluator>,
) -> Result<(Verdict, Vec<Option<Map>>), crate::gpu::GpuError> {
    let second = second || strict;
    let bvh = Bvh::build(&base.positions, &base.faces);
    let adj = dense;
    let maps: Vec<Option<Map>> = match gpu {
        Some(g) => g.project(dense, base, &bvh, mode, dmax)?,
        None => project_cpu(dense, base, &bvh, mode, dmax),
    };
    let (vf_start, vf) = vertex_faces(base.positions.len(), &base.faces);
    let ctx = ValidateContext { base, vf_start, vf, bvh: &bvh, maps: &maps, pinched: &dense.pinched, mode, dmax };
    let failures: Vec<(u32, Reject)> = (0..dense.faces.len() as u32)
        .into_par_iter()
        .map_init(Scratch::default, |scratch, f| check_faces_and_edges(&ctx, adj, &[f], |_| true, scratch).err().map(|r| (f, r)))
        .flatten()
        .collect();
    let status: Vec<VertexStatus> = (0..dense.pos.len())
        .map(|v| {
            if dense.pinched[v] {
                VertexStatus::Pinched
            } else if maps[v].is_some() {
                VertexStatus::Mapped
            } else {
                VertexStatus::Unmapped
            }
        })
        .collect();
    let unmapped: Vec<u32> =
        status.iter().enumerate().filter(|(_, s)| **s == VertexStatus::Unmapped).map(|(i, _)| i as u32).collect();
    let flipped: Vec<u32> = failures.iter().filter(|r| r.1 == Reject::Flip).map(|r| r.0).collect();
    let torn: Vec<u32> = failures.iter().filter(|r| r.1 == Reject::Tear).map(|r| r.0).collect();
    let (ambiguous, far_hits) = if second {
        let touch = |a: u32, b: u32| {
            let (fa, fb) = (base.faces[a as usize], base.faces[b as usize]);
            fa.iter().any(|v| fb.contains(v))
        };
        let flags: Vec<(bool, bool)> = (0..dense.pos.len() as u32)
            .into_par_iter()
            .map_init(
                || (Vec::new(), Vec::new(), Tris::default()),
                |(normals, near, tris), v| match maps[v as usize] {
                    Some(m) if !dense.pinched[v as usize] => {
                        dense.vertex_normals(v, normals);
                        second_solutions(base, &bvh, touch, dense.pos[v as usize], normals, m, mode, dmax, near, tris)
                    }
                    _ => (false, false),
                },
            )
            .collect();
        (flags.iter().filter(|f| f.0).count(), flags.iter().filter(|f| f.1).count())
    } else {
        (0, 0)
    };
    let mapped_d: Vec<f64> = maps.iter().flatten().map(|m| m.d).collect();
    let rms_d = if mapped_d.is_empty() { 0.0 } else { (mapped_d.iter().map(|d| d * d).sum::<f64>() / mapped_d.len() as f64).sqrt() };
    let verdict = Verdict {
        valid: unmapped.is_empty() && flipped.is_empty() && torn.is_empty() && !(strict && ambiguous > 0),
        strict,
        dense_vertices: dense.pos.len(),
        mapped: status.iter().filter(|s| **s == VertexStatus::Mapped).count(),
        unmapped: unmapped.len(),
        pinched: status.iter().filter(|s| **s == VertexStatus::Pinched).count(),
        ambiguous,
        far_hits,
        dense_faces: dense.faces.len(),
        flipped: flipped.len(),
        torn: torn.len(),
        max_abs_d: mapped_d.iter().map(|d| d.abs()).fold(0.0, f64::max),
        rms_d,
        dmax,
        first_unmapped: unmapped.into_iter().take(10).collect(),
        first_flipped: flipped.into_iter().take(10).collect(),
        first_torn: torn.into_iter().take(10).collect(),
    };
    let maps = maps.into_iter().enumerate().map(|(v, m)| if dense.pinched[v] { None } else { m }).collect();
    Ok((verdict, maps))
}

// ---------------------------------------------------------------------------------------------
// The local re-check of a decimation state.

impl State {
    /// From-scratch re-check of the guarantee over every dense vertex's neighbourhood: each
    /// vertex is solved again over the 2-ring of the base face it is associated with, then
    /// every dense triangle's orientation and every dense edge's continuity are checked.
    pub fn recheck(&self) -> Recheck {
        let nf = self.topo.num_faces_total() as u32;
        let per_face: Vec<Vec<(u32, Option<Map>, bool)>> = (0..nf)
            .into_par_iter()
            .map(|f| {
                if !self.topo.face_alive(f) || self.face_dense[f as usize].is_empty() {
                    return Vec::new();
                }
                let mut tris = Tris::default();
                self.two_ring_tris(f, &mut tris);
                let mut scratch = Scratch::default();
                let mut normals = Vec::new();
                let dense = &self.dense;
                self.face_dense[f as usize]
                    .iter()
                    .map(|&v| {
                        dense.vertex_normals(v, &mut normals);
                        let pinched = self.dense.pinched[v as usize];
                        let x = self.dense.pos[v as usize];
                        let r = match find_primary(x, &normals, &tris, self.mode, self.dmax, !pinched, false, &mut scratch) {
                            Found::Hit(t, h) => Some(Map { face: tris.ids[t], bary: h.bary, d: h.d }),
                            _ => None,
                        };
                        // The paper's uniqueness, reported (over this 2-ring) in strict mode.
                        let ambiguous = self.strict
                            && !pinched
                            && find_primary(x, &normals, &tris, self.mode, self.dmax, true, true, &mut scratch) == Found::Ambiguous;
                        (v, r, ambiguous)
                    })
                    .collect()
            })
            .collect();
        let mut maps: Vec<Option<Map>> = vec![None; self.dense.pos.len()];
        let mut unmapped = Vec::new();
        let mut ambiguous = 0;
        for (v, m, amb) in per_face.into_iter().flatten() {
            if m.is_none() && !self.dense.pinched[v as usize] {
                unmapped.push(v);
            }
            ambiguous += amb as usize;
            maps[v as usize] = m;
        }
        unmapped.sort_unstable();
        let ctx = GlobalContext { st: self, maps: &maps };
        let dense = &self.dense;
        let failures: Vec<(u32, Reject)> = (0..self.dense.faces.len() as u32)
            .into_par_iter()
            .filter_map(|f| {
                let mut scratch = Scratch::default();
                check_faces_and_edges(&ctx, &dense, &[f], |_| true, &mut scratch).err().map(|r| (f, r))
            })
            .collect();
        let flipped = failures.iter().filter(|(_, r)| *r == Reject::Flip).map(|(f, _)| *f).collect();
        let torn = failures.iter().filter(|(_, r)| *r == Reject::Tear).map(|(f, _)| *f).collect();
        let max_abs_d = maps.iter().flatten().map(|m| m.d.abs()).fold(0.0, f64::max);
        Recheck {
            unmapped,
            flipped,
            torn,
            pinched: self.dense.pinched.iter().filter(|&&p| p).count(),
            ambiguous,
            max_abs_d,
        }
    }

}

/// Result of [`State::recheck`].
#[derive(Clone, Debug, serde::Serialize)]
pub struct Recheck {
    pub unmapped: Vec<u32>,
    pub flipped: Vec<u32>,
    pub torn: Vec<u32>,
    pub pinched: usize,
    /// (strict mode) vertices with more than one solution satisfying (4) on their 2-ring.
    pub ambiguous: usize,
    pub max_abs_d: f64,
}

impl Recheck {
    pub fn ok(&self) -> bool {
        self.unmapped.is_empty() && self.flipped.is_empty() && self.torn.is_empty()
    }
}

/// Map context of the re-check: recomputed maps, current base mesh.
struct GlobalContext<'a> {
    st: &'a State,
    maps: &'a [Option<Map>],
}

impl MapContext for GlobalContext<'_> {
    fn map_of(&self, v: u32) -> Option<Map> {
        if self.st.dense.pinched[v as usize] {
            return None;
        }
        // An unmapped vertex is already counted; its triangles cannot be drawn.
        self.maps[v as usize]
    }
    fn face_info(&self, face: u32) -> FaceInfo {
        self.st.face_info_current(face)
    }
    fn face_containing(&self, verts: &[u32]) -> Option<u32> {
        self.st.face_containing(verts)
    }
    fn solve_point(&self, x: DVec3, normals: &[DVec3], fa: u32, fb: u32, scratch: &mut Scratch) -> Option<Map> {
        let mut tris = Tris::default();
        self.st.two_ring_tris(fa, &mut tris);
        let mut more = Tris::default();
        self.st.two_ring_tris(fb, &mut more);
        for t in 0..more.len() {
            if tris.index_of(more.ids[t]).is_none() {
                tris.push(more.ids[t], more.verts[t], more.pos[t], more.dir[t]);
            }
        }
        tris.finish();
        match find_primary(x, normals, &tris, self.st.mode, self.st.dmax, true, false, scratch) {
            Found::Hit(t, h) => Some(Map { face: tris.ids[t], bary: h.bary, d: h.d }),
            _ => None,
        }
    }
}
