//! The independent, global check of SPEC §1/§4: every dense vertex is solved against the whole
//! base mesh (not only a neighbourhood), then every dense triangle's orientation and every dense
//! edge's continuity are checked with those primary solutions.
//!
//! Triangles are visited best-first by a lower bound on |d| (the distance from the point to a
//! BVH node's box, then to the triangle), so a vertex costs a handful of cubic solves.

use crate::geometry::bvh::Bvh;
use crate::guarantee::{TriBounds, lean_lower_bound_of, shell_lower_bound_of, check_face, find_primary, solve_tri, direction_at, CheckScratch, CheckStats, FaceCheck, FaceInfo, Found, LoopSampling, Map, MapContext, NormalMode, preferred, Scratch, Tris, SAME_SOLUTION_REL};
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
    /// Every failing vertex and face (internal indices), not only the first: what
    /// `validate --failures` draws. Not in the JSON report (a broken base can fail on most of
    /// the scan).
    #[serde(skip)]
    pub failing: Failing,
    /// Judged by brute force (`--exhaustive`).
    pub exhaustive: bool,
    /// Positive loops walked again at 8 and 64 pieces an edge (`--fine-loops`; what that
    /// found: `checks.fine_flipped`, `checks.fine_torn`).
    pub fine_loops: bool,
    /// (constant mode) Vertices exempt because no base can map them (counted in `pinched`).
    pub exempt_constant: usize,
    /// (constant mode) Dense edges exempt because the scan itself cannot map their points (its
    /// two faces are folded by more than 90°), and the first of them; their triangles are not
    /// drawn.
    pub exempt_edges: usize,
    pub first_exempt_edges: Vec<(u32, u32)>,
    /// Jump edges and the largest jump (SPEC §1), straddling triangles and their charts.
    pub checks: CheckStats,
}

/// Every unmapped dense vertex and every flipped and torn dense face of a verdict, in index
/// order (internal indices).
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct Failing {
    pub unmapped: Vec<u32>,
    pub flipped: Vec<u32>,
    pub torn: Vec<u32>,
}

/// A base mesh ready for point searches over the whole of it: its BVH and every face's search
/// bounds, derived once. Why the bounds: a search derived them for each face it met, again at
/// every point (a seventh of `validate`'s time on a 34,725-face base); kept, they cost 200 bytes
/// a base face.
pub struct BaseIndex<'a> {
    pub base: &'a Base,
    pub bvh: Bvh,
    bounds: Vec<TriBounds>,
}

impl<'a> BaseIndex<'a> {
    pub fn new(base: &'a Base) -> BaseIndex<'a> {
        let bvh = Bvh::build(&base.positions, &base.faces);
        let bounds = base
            .faces
            .par_iter()
            .map(|t| TriBounds::new(&t.map(|v| base.positions[v as usize]), &t.map(|v| base.directions[v as usize])))
            .collect();
        BaseIndex { base, bvh, bounds }
    }
}

/// Candidate triangles for one point: the exact search set of a best-first query, as [`Tris`].
fn candidate_tris(index: &BaseIndex, x: DVec3, limit: f64, near: &mut Vec<(f64, u32)>, tris: &mut Tris) {
    let base = index.base;
    index.bvh.near(&base.positions, &base.faces, x, limit, near);
    tris.clear();
    for &(_, f) in near.iter() {
        let t = base.faces[f as usize];
        tris.push_with(f, t, t.map(|v| base.positions[v as usize]), t.map(|v| base.directions[v as usize]), &index.bounds[f as usize]);
    }
    tris.finish();
}

struct ValidateContext<'a> {
    /// The base (`index.base`), its BVH and its faces' bounds.
    index: &'a BaseIndex<'a>,
    /// Faces around each base vertex (CSR).
    vf_start: Vec<u32>,
    vf: Vec<u32>,
    maps: &'a [Option<Map>],
    pinched: &'a [bool],
    mode: NormalMode,
    dmax: f64,
    /// Every base triangle, for `--exhaustive`.
    all: Option<&'a Tris>,
}

/// First search radius of [`primary_global`], as a fraction of dmax.
/// Why: most points lie far closer to the base than dmax; small radii keep the set tiny.
const FIRST_RADIUS: f64 = 1.0 / 64.0;

/// The primary solution of `x` over the whole base: triangles within a growing radius L are
/// searched; a hit with |d| ≤ L is the primary, since any solution with |d| ≤ L lies on a
/// triangle within distance L.
#[allow(clippy::too_many_arguments)]
pub(crate) fn primary_global(
    index: &BaseIndex,
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
        candidate_tris(index, x, r, near, tris);
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
        if let Some(all) = self.all {
            return primary_exhaustive(all, x, normals, self.mode, self.dmax, true);
        }
        // The search's buffers, kept on the scratch between points (a bisection solves many).
        let mut memo: Box<(Vec<(f64, u32)>, Tris)> = scratch.take_context_memo();
        let (near, tris) = &mut *memo;
        let m = primary_global(self.index, x, normals, self.mode, self.dmax, true, scratch, near, tris);
        scratch.keep_context_memo(memo);
        m
    }
}

/// Every base triangle as one [`Tris`] (for `--exhaustive`).
pub fn all_tris(base: &Base) -> Tris {
    let mut all = Tris::default();
    for (f, t) in base.faces.iter().enumerate() {
        all.push(f as u32, *t, t.map(|v| base.positions[v as usize]), t.map(|v| base.directions[v as usize]));
    }
    all.finish();
    all
}

/// The primary solution of `x` by brute force (`validate --exhaustive`): every solution on every
/// base triangle, no BVH, no bounds, no early exit; the solution satisfying (4) that
/// [`preferred`] ranks first — the rule of [`find_primary`], computed the slow way to cross-check it.
pub fn primary_exhaustive(all: &Tris, x: DVec3, normals: &[DVec3], mode: NormalMode, dmax: f64, check4: bool) -> Option<Map> {
    let mut best: Option<Map> = None;
    for t in 0..all.len() {
        for h in solve_tri(x, all, t, mode, dmax).iter() {
            if check4 && !crate::geometry::condition4(direction_at(all, t, &h, mode), normals.iter().copied()) {
                continue;
            }
            let better = match best {
                None => true,
                Some(b) => preferred(h.d.abs(), all.ids[t], b.d.abs(), b.face),
            };
            if better {
                best = Some(Map { face: all.ids[t], bary: h.bary, d: h.d });
            }
        }
    }
    best
}

impl MapContext for ValidateContext<'_> {
    fn map_of(&self, v: u32) -> Option<Map> {
        if self.pinched[v as usize] {
            return None;
        }
        self.maps[v as usize]
    }
    fn face_info(&self, face: u32) -> FaceInfo {
        let verts = self.index.base.faces[face as usize];
        FaceInfo {
            verts,
            pos: verts.map(|v| self.index.base.positions[v as usize]),
            dir: verts.map(|v| self.index.base.directions[v as usize]),
        }
    }
    fn face_containing(&self, verts: &[u32]) -> Option<u32> {
        let v = verts[0] as usize;
        self.vf[self.vf_start[v] as usize..self.vf_start[v + 1] as usize]
            .iter()
            .copied()
            .find(|&f| verts.iter().all(|w| self.index.base.faces[f as usize].contains(w)))
    }
    fn faces_around(&self, v: u32, out: &mut Vec<u32>) {
        out.clear();
        let v = v as usize;
        out.extend_from_slice(&self.vf[self.vf_start[v] as usize..self.vf_start[v + 1] as usize]);
    }
    fn mode(&self) -> NormalMode {
        self.mode
    }
    fn dmax(&self) -> f64 {
        self.dmax
    }
    fn solve_point(&self, x: DVec3, normals: &[DVec3], _fa: u32, _fb: u32, scratch: &mut Scratch) -> Option<Map> {
        self.solve(x, normals, scratch)
    }
}

/// Second solutions of a mapped vertex: (ambiguous, far hit).
fn second_solutions(
    index: &BaseIndex,
    all: Option<&Tris>,
    faces_touch: impl Fn(u32, u32) -> bool,
    x: DVec3,
    normals: &[DVec3],
    primary: Map,
    mode: NormalMode,
    dmax: f64,
    tris: &mut Tris,
) -> (bool, bool) {
    let base = index.base;
    // Every triangle that can hold a solution within dmax (`--exhaustive`: every triangle of
    // the base, to cross-check this): within dmax of x, and not put beyond it by its bounds
    // (the strict search's culls, at its reach). Within dmax of a point of a fine base lie
    // thousands of faces, nearly all culled here before a distance or a cubic; the order does
    // not matter (two flags).
    let tris: &Tris = match all {
        Some(all) => all,
        None => {
            tris.clear();
            index.bvh.visit_within(x, dmax, |f| {
                let b = &index.bounds[f as usize];
                let t = base.faces[f as usize];
                let pos = t.map(|v| base.positions[v as usize]);
                if crate::geometry::sphere_lower_bound(x, b.sphere.0, b.sphere.1) > dmax
                    || (mode == NormalMode::Interpolated && lean_lower_bound_of(x, &pos, b.slope, &b.lean, b.sphere.1, dmax) > dmax)
                    || crate::geometry::triangle_distance(x, &pos) > dmax
                    || shell_lower_bound_of(x, &pos, b.slope, b.sphere.1, mode) > dmax
                {
                    return;
                }
                tris.push_with(f, t, pos, t.map(|v| base.directions[v as usize]), b);
            });
            tris.finish();
            tris
        }
    };
    let p0 = {
        let t = base.faces[primary.face as usize].map(|v| base.positions[v as usize]);
        crate::geometry::interpolate_direction(&t, &primary.bary)
    };
    let (mut amb, mut far) = (false, false);
    for t in 0..tris.len() {
        for h in solve_tri(x, tris, t, mode, dmax).iter() {
            if !crate::geometry::condition4(direction_at(tris, t, &h, mode), normals.iter().copied()) {
                continue;
            }
            let p = crate::geometry::interpolate_direction(&tris.pos[t], &h.bary);
            if p.distance(p0) <= SAME_SOLUTION_REL * dmax {
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

/// How a check is made.
#[derive(Clone, Copy, Debug)]
pub struct CheckOptions {
    pub mode: NormalMode,
    pub dmax: f64,
    /// The paper's uniqueness: an ambiguous vertex makes the base invalid (implies `second`).
    pub strict: bool,
    /// Classify every mapped vertex's other solutions (ambiguous, far hit).
    pub second: bool,
    /// Brute force: every point against every base triangle, no BVH, no culling.
    pub exhaustive: bool,
    /// Also judge straddling triangles by the first release's chord rule, and count where it
    /// differs.
    pub compare_chords: bool,
    /// How positive loops are sampled (`--fine-loops`: again at 8 and 64 pieces an edge).
    pub sampling: LoopSampling,
}

impl CheckOptions {
    pub fn new(mode: NormalMode, dmax: f64) -> CheckOptions {
        CheckOptions { mode, dmax, strict: false, second: false, exhaustive: false, compare_chords: false, sampling: LoopSampling::Sampled }
    }
}

/// A device that can project every dense vertex onto a base (the GPU); the validator knows it
/// only through this trait.
pub trait Project {
    fn project(&self, dense: &DenseData, index: &BaseIndex, mode: NormalMode, dmax: f64) -> Result<Vec<Option<Map>>, crate::error::GpuError>;
}

/// Judges `base` against the dense mesh over the whole base mesh.
pub fn validate(dense: &DenseData, base: &Base, opts: &CheckOptions) -> Verdict {
    validate_with_maps(dense, base, opts).0
}

/// [`validate`], also returning every dense vertex's primary solution (`None`: unmapped or
/// pinched), for the fold image.
pub fn validate_with_maps(dense: &DenseData, base: &Base, opts: &CheckOptions) -> (Verdict, Vec<Option<Map>>) {
    match validate_on(dense, base, opts, None) {
        Ok(r) => r,
        Err(e) => unreachable!("the CPU projection cannot fail: {e}"),
    }
}

/// The primary solution of every dense vertex over the whole base, on the CPU.
fn project_cpu(dense: &DenseData, index: &BaseIndex, all: Option<&Tris>, mode: NormalMode, dmax: f64) -> Vec<Option<Map>> {
    (0..dense.pos.len() as u32)
        .into_par_iter()
        .map_init(
            || (Scratch::default(), Vec::new(), Vec::new(), Tris::default()),
            |(scratch, normals, near, tris), v| {
                dense.vertex_normals(v, normals);
                let x = dense.pos[v as usize];
                let pinched = dense.pinched[v as usize];
                match all {
                    Some(all) => primary_exhaustive(all, x, normals, mode, dmax, !pinched),
                    None => primary_global(index, x, normals, mode, dmax, !pinched, scratch, near, tris),
                }
            },
        )
        .collect()
}

/// [`validate_with_maps`] with the projection step on `gpu` when given (the GPU decides each
/// vertex's primary triangle; the tolerance band and the d values are settled in f64, so the
/// verdict is the CPU's). `--exhaustive` never uses the GPU.
pub fn validate_on(
    dense: &DenseData,
    base: &Base,
    opts: &CheckOptions,
    gpu: Option<&dyn Project>,
) -> Result<(Verdict, Vec<Option<Map>>), crate::error::GpuError> {
    let (mode, dmax, strict) = (opts.mode, opts.dmax, opts.strict);
    // Constant mode: the vertices no base can map (none of their own faces' normals sees all of
    // their faces) are exempt like pinched ones.
    let exempted;
    let (dense, exempt_constant) = if mode == NormalMode::Constant {
        let mut d = dense.clone();
        let n = d.exempt_for_constant_mode();
        exempted = d;
        (&exempted, n)
    } else {
        (dense, 0)
    };
    let second = opts.second || strict;
    let index = BaseIndex::new(base);
    let all_owned = opts.exhaustive.then(|| all_tris(base));
    let all = all_owned.as_ref();
    let maps: Vec<Option<Map>> = match gpu {
        Some(g) if all.is_none() => g.project(dense, &index, mode, dmax)?,
        _ => project_cpu(dense, &index, all, mode, dmax),
    };
    let (vf_start, vf) = vertex_faces(base.positions.len(), &base.faces);
    let ctx = ValidateContext { index: &index, vf_start, vf, maps: &maps, pinched: &dense.pinched, mode, dmax, all };
    let results: Vec<(u32, FaceCheck, CheckStats)> = (0..dense.faces.len() as u32)
        .into_par_iter()
        .map_init(CheckScratch::default, |sc, f| {
            let mut stats = CheckStats::default();
            let r = check_face(&ctx, dense, f, opts.compare_chords, opts.sampling, sc, &mut stats);
            (f, r, stats)
        })
        .collect();
    let mut checks = CheckStats::default();
    for r in &results {
        checks.add(&r.2);
    }
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
    let flipped: Vec<u32> = results.iter().filter(|r| r.1 == FaceCheck::Flipped).map(|r| r.0).collect();
    let torn: Vec<u32> = results.iter().filter(|r| r.1 == FaceCheck::Torn).map(|r| r.0).collect();
    let (ambiguous, far_hits) = if second {
        let touch = |a: u32, b: u32| {
            let (fa, fb) = (base.faces[a as usize], base.faces[b as usize]);
            fa.iter().any(|v| fb.contains(v))
        };
        let flags: Vec<(bool, bool)> = (0..dense.pos.len() as u32)
            .into_par_iter()
            .map_init(
                || (Vec::new(), Tris::default()),
                |(normals, tris), v| match maps[v as usize] {
                    Some(m) if !dense.pinched[v as usize] => {
                        dense.vertex_normals(v, normals);
                        second_solutions(&index, all, touch, dense.pos[v as usize], normals, m, mode, dmax, tris)
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
        first_unmapped: unmapped.iter().copied().take(10).collect(),
        first_flipped: flipped.iter().copied().take(10).collect(),
        first_torn: torn.iter().copied().take(10).collect(),
        failing: Failing { unmapped, flipped, torn },
        exhaustive: opts.exhaustive,
        fine_loops: opts.sampling.is_fine(),
        checks,
        exempt_constant,
        exempt_edges: dense.exempt_edges.len(),
        first_exempt_edges: dense.exempt_edges.iter().copied().take(10).collect(),
    };
    let maps = maps.into_iter().enumerate().map(|(v, m)| if dense.pinched[v] { None } else { m }).collect();
    Ok((verdict, maps))
}

