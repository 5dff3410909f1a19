//! Evaluation of candidate collapses: the [`Evaluator`] trait and the CPU reference
//! [`CpuEvaluator`] (rayon over the batch).
//!
//! A candidate is tested against the guarantee of SPEC §1, locally: every dense vertex
//! associated with the collapsed region or the ring bordering it gets its primary solution
//! over that neighbourhood (condition (4), smallest |d|), and every dense triangle touching
//! those vertices must keep its orientation and must not tear along its edges.

use crate::decimate::{Candidate, State};
use crate::geometry::{
    self, condition4, interpolate_direction, solve_constant, solve_shell, sphere_lower_bound, triangle_distance,
    triangle_sphere,
    ShellHit,
};
use crate::mesh::DenseData;
use glam::DVec3;
use rayon::prelude::*;

/// How deep a dense edge is bisected when the base triangles of its two ends do not touch.
/// Why: 2^6 = 64 pieces; once the base is coarser than the scan, an edge crosses at most a few
/// base triangles, so a continuous image always resolves well before this depth.
pub const MAX_BISECT_DEPTH: u32 = 6;

/// Two solutions closer than this (relative to dmax) are the same point found by two
/// triangles that share an edge or a vertex.
/// Why: barycentric tolerance BARY_EPS puts shared-edge duplicates within ~1e-9 of each other.
pub const SAME_SOLUTION_REL: f64 = 1e-7;

/// The directions used on the base mesh.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum NormalMode {
    /// `N(X) = a·N1 + b·N2 + c·N3` (the paper's interpolated normals).
    Interpolated,
    /// The face normal, constant per base face (paper §4).
    Constant,
}

/// Where a dense point maps on the base mesh.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Map {
    pub face: u32,
    pub bary: [f64; 3],
    pub d: f64,
}

/// Why a candidate collapse was rejected.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum Reject {
    /// The link condition fails (the collapse would break the manifold).
    Link,
    /// A boundary rule: an interior edge between two boundary vertices, or a boundary loop
    /// that would shrink below a triangle.
    Boundary,
    /// The edge's valence is not below the cap.
    Valence,
    /// A triangle of the collapsed fan flips or degenerates, or a vertex direction cannot see
    /// all of its faces.
    Foldover,
    /// A dense vertex has no solution satisfying condition (4) on the neighbourhood.
    Unmapped,
    /// A dense triangle's image is flipped.
    Flip,
    /// A dense edge's image is not continuous.
    Tear,
    /// (`--strict`) A dense vertex has more than one solution satisfying (4).
    Ambiguous,
}

impl Reject {
    pub fn name(self) -> &'static str {
        match self {
            Reject::Link => "link",
            Reject::Boundary => "boundary",
            Reject::Valence => "valence",
            Reject::Foldover => "foldover",
            Reject::Unmapped => "unmapped",
            Reject::Flip => "flip",
            Reject::Tear => "tear",
            Reject::Ambiguous => "ambiguous",
        }
    }
}

/// The triangles of a neighbourhood in flat arrays (the layout a GPU batch uses too).
#[derive(Clone, Debug, Default)]
pub struct Tris {
    pub ids: Vec<u32>,
    pub verts: Vec<[u32; 3]>,
    pub pos: Vec<[DVec3; 3]>,
    pub dir: Vec<[DVec3; 3]>,
    pub sphere: Vec<(DVec3, f64)>,
    /// (face id, index) sorted by id, for lookups; rebuilt by [`Tris::finish`].
    lookup: Vec<(u32, u32)>,
}

impl Tris {
    /// Builds the id lookup; call after the last push.
    pub fn finish(&mut self) {
        self.lookup.clear();
        self.lookup.extend(self.ids.iter().enumerate().map(|(i, &f)| (f, i as u32)));
        self.lookup.sort_unstable();
    }
    pub fn clear(&mut self) {
        self.ids.clear();
        self.verts.clear();
        self.pos.clear();
        self.dir.clear();
        self.sphere.clear();
        self.lookup.clear();
    }
    pub fn push(&mut self, id: u32, verts: [u32; 3], pos: [DVec3; 3], dir: [DVec3; 3]) {
        self.ids.push(id);
        self.verts.push(verts);
        self.sphere.push(triangle_sphere(&pos));
        self.pos.push(pos);
        self.dir.push(dir);
    }
    pub fn len(&self) -> usize {
        self.ids.len()
    }
    pub fn is_empty(&self) -> bool {
        self.ids.is_empty()
    }
    /// Index of base face `face` in these triangles (after [`Tris::finish`]).
    pub fn index_of(&self, face: u32) -> Option<usize> {
        if self.lookup.len() != self.ids.len() {
            return self.ids.iter().position(|&f| f == face);
        }
        self.lookup.binary_search_by_key(&face, |e| e.0).ok().map(|i| self.lookup[i].1 as usize)
    }
}

/// The outcome of searching one dense point over a neighbourhood.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Found {
    /// The primary solution: triangle index in the neighbourhood and the hit.
    Hit(usize, ShellHit),
    /// No solution with |d| ≤ dmax satisfying condition (4).
    None,
    /// (strict) more than one distinct solution satisfying condition (4).
    Ambiguous,
}

/// Solves one triangle of the neighbourhood in the given mode.
#[inline]
pub fn solve_tri(x: DVec3, tris: &Tris, t: usize, mode: NormalMode, dmax: f64) -> geometry::Hits {
    match mode {
        NormalMode::Interpolated => solve_shell(x, &tris.pos[t], &tris.dir[t], dmax),
        NormalMode::Constant => solve_constant(x, &tris.pos[t], dmax),
    }
}

/// The direction at a hit: interpolated, or the face normal in constant mode.
#[inline]
pub fn direction_at(tris: &Tris, t: usize, hit: &ShellHit, mode: NormalMode) -> DVec3 {
    match mode {
        NormalMode::Interpolated => interpolate_direction(&tris.dir[t], &hit.bary),
        NormalMode::Constant => {
            let p = &tris.pos[t];
            geometry::face_normal(p[0], p[1], p[2])
        }
    }
}

/// Reusable per-thread scratch space.
#[derive(Default)]
pub struct Scratch {
    bounds: Vec<f64>,
    found: Vec<DVec3>,
}

/// The primary solution of `x` over `tris` (SPEC §1): among solutions with |d| ≤ dmax that
/// satisfy condition (4) for `normals`, the one with the smallest |d|. Triangles are visited in
/// the order of a lower bound on |d| and the search stops as soon as no triangle can beat the
/// best hit. With `check4 == false` (pinched vertices) condition (4) is not applied. With
/// `strict`, every triangle within dmax is visited and distinct solutions are counted.
#[allow(clippy::too_many_arguments)]
pub fn find_primary(
    x: DVec3,
    normals: &[DVec3],
    tris: &Tris,
    mode: NormalMode,
    dmax: f64,
    check4: bool,
    strict: bool,
    scratch: &mut Scratch,
) -> Found {
    let m = tris.len();
    scratch.bounds.clear();
    scratch.bounds.extend((0..m).map(|t| sphere_lower_bound(x, tris.sphere[t].0, tris.sphere[t].1)));
    scratch.found.clear();
    let mut best: Option<(usize, ShellHit)> = None;
    loop {
        // Select the unvisited triangle with the smallest bound (ties: lowest index).
        let mut ti = usize::MAX;
        let mut tb = f64::INFINITY;
        for (t, &b) in scratch.bounds.iter().enumerate() {
            if b < tb {
                tb = b;
                ti = t;
            }
        }
        if ti == usize::MAX || tb > dmax {
            break;
        }
        let tie = SAME_SOLUTION_REL * dmax;
        if !strict {
            if let Some((_, h)) = best {
                if tb > h.d.abs() + tie {
                    break;
                }
            }
        }
        scratch.bounds[ti] = f64::INFINITY;
        let limit = match best {
            Some((_, h)) if !strict => h.d.abs() + tie,
            _ => dmax,
        };
        if triangle_distance(x, &tris.pos[ti]) > limit {
            continue;
        }
        let hits = solve_tri(x, tris, ti, mode, dmax);
        for h in hits.iter() {
            if check4 && !condition4(direction_at(tris, ti, &h, mode), normals.iter().copied()) {
                continue;
            }
            if strict {
                let p = interpolate_direction(&tris.pos[ti], &h.bary);
                if !scratch.found.iter().any(|q| q.distance(p) <= SAME_SOLUTION_REL * dmax) {
                    scratch.found.push(p);
                }
            }
            // Smallest |d|; a tie (the same point seen from faces sharing an edge or a vertex)
            // goes to the lowest face id, so that every search picks the same face.
            let better = match best {
                None => true,
                Some((bt, b)) => {
                    let (da, db) = (h.d.abs(), b.d.abs());
                    da < db - tie || (da <= db + tie && tris.ids[ti] < tris.ids[bt])
                }
            };
            if better {
                best = Some((ti, h));
            }
        }
    }
    if strict && scratch.found.len() > 1 {
        return Found::Ambiguous;
    }
    match best {
        Some((t, h)) => Found::Hit(t, h),
        None => Found::None,
    }
}

/// The best hit of `x` on triangle `t` alone, by the rule of [`find_primary`] (condition (4)
/// when `check4`, smallest |d|, the first of equal ones): the f64 answer on the triangle the GPU
/// chose.
pub fn best_on_triangle(x: DVec3, normals: &[DVec3], tris: &Tris, t: usize, mode: NormalMode, dmax: f64, check4: bool) -> Option<ShellHit> {
    let tie = SAME_SOLUTION_REL * dmax;
    let mut best: Option<ShellHit> = None;
    for h in solve_tri(x, tris, t, mode, dmax).iter() {
        if check4 && !condition4(direction_at(tris, t, &h, mode), normals.iter().copied()) {
            continue;
        }
        if best.is_none_or(|b| h.d.abs() < b.d.abs() - tie) {
            best = Some(h);
        }
    }
    best
}

/// Geometry of one base face as the checks see it.
#[derive(Clone, Copy, Debug)]
pub struct FaceInfo {
    pub verts: [u32; 3],
    pub pos: [DVec3; 3],
    pub dir: [DVec3; 3],
}

/// What the flip and tear checks need from their surroundings.
pub trait MapContext {
    /// The map of a dense vertex, `None` for a pinched vertex (exempt).
    fn map_of(&self, v: u32) -> Option<Map>;
    fn face_info(&self, face: u32) -> FaceInfo;
    /// A live base face containing all of `verts` (one to three vertices), if there is one.
    fn face_containing(&self, verts: &[u32]) -> Option<u32>;
    /// The primary solution of a point on a dense edge (condition (4) against `normals`),
    /// searched over the neighbourhood and around the base faces `fa` and `fb` of its ends.
    fn solve_point(&self, x: DVec3, normals: &[DVec3], fa: u32, fb: u32, scratch: &mut Scratch) -> Option<Map>;
}

fn image_point(info: &FaceInfo, bary: &[f64; 3]) -> DVec3 {
    interpolate_direction(&info.pos, bary)
}


/// Barycentric coordinates on face `target` of the point with `bary` on face `verts`, when the
/// point lies on `target` (its non-zero weights sit on vertices `target` shares).
fn on_face(verts: &[u32; 3], bary: &[f64; 3], target: &[u32; 3]) -> Option<[f64; 3]> {
    let mut out = [0.0; 3];
    for i in 0..3 {
        if bary[i] > geometry::BARY_EPS {
            let k = target.iter().position(|&w| w == verts[i])?;
            out[k] += bary[i];
        }
    }
    Some(out)
}

fn touch(a: &[u32; 3], b: &[u32; 3]) -> bool {
    a.iter().any(|v| b.contains(v))
}

/// Whether a dense triangle, drawn through its vertices' maps, keeps positive orientation.
/// One base triangle: its barycentric plane. Several: the images are projected onto the plane
/// orthogonal to the direction of their common base vertex (which sees every face of its fan),
/// or, without a common vertex, to the mean normal of the base faces involved.
pub fn image_positive<C: MapContext>(ctx: &C, m: [Map; 3]) -> bool {
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

/// Whether the image of the dense edge from `pa` (map `ma`) to `pb` (map `mb`) is continuous:
/// consecutive samples map to base triangles that share a vertex, bisecting where they do not.
#[allow(clippy::too_many_arguments)]
pub fn edge_continuous<C: MapContext>(
    ctx: &C,
    pa: DVec3,
    ma: Map,
    pb: DVec3,
    mb: Map,
    normals: &[DVec3],
    depth: u32,
    scratch: &mut Scratch,
) -> bool {
    if ma.face == mb.face {
        return true;
    }
    let (fa, fb) = (ctx.face_info(ma.face), ctx.face_info(mb.face));
    if touch(&fa.verts, &fb.verts) {
        return true;
    }
    // Points on vertices or edges: their stars may touch through another representation.
    let sup = [support(&fa, &ma), support(&fb, &mb)];
    let mut cands: Vec<u32> = fa.verts.iter().chain(fb.verts.iter()).copied().collect();
    cands.sort_unstable();
    cands.dedup();
    if (sup[0].len() < 3 || sup[1].len() < 3) && cands.into_iter().any(|v| star_direction(ctx, v, &sup).is_some()) {
        return true;
    }
    if depth == 0 {
        return false;
    }
    let mid = 0.5 * (pa + pb);
    let Some(mm) = ctx.solve_point(mid, normals, ma.face, mb.face, scratch) else {
        return false;
    };
    edge_continuous(ctx, pa, ma, mid, mm, normals, depth - 1, scratch)
        && edge_continuous(ctx, mid, mm, pb, mb, normals, depth - 1, scratch)
}

/// Checks the dense triangles `faces` (orientation) and their edges with at least one endpoint
/// in `tested` (continuity). Returns the first failure.
pub fn check_faces_and_edges<C: MapContext>(
    ctx: &C,
    dense: &DenseData,
    faces: &[u32],
    tested: impl Fn(u32) -> bool,
    scratch: &mut Scratch,
) -> Result<(), Reject> {
    let mut normals = Vec::new();
    for &f in faces {
        let fv = dense.faces[f as usize];
        let maps = [ctx.map_of(fv[0]), ctx.map_of(fv[1]), ctx.map_of(fv[2])];
        if let [Some(a), Some(b), Some(c)] = maps {
            if !image_positive(ctx, [a, b, c]) {
                return Err(Reject::Flip);
            }
        }
        for k in 0..3 {
            let (a, b) = (fv[k], fv[(k + 1) % 3]);
            // Each interior edge is seen from both faces; check it from the one where a < b,
            // or from this face when it is a boundary edge.
            if a > b && dense.faces_of(a).iter().filter(|&&g| dense.faces[g as usize].contains(&b)).count() == 2 {
                continue;
            }
            if !tested(a) && !tested(b) {
                continue;
            }
            let (Some(ma), Some(mb)) = (maps[k], maps[(k + 1) % 3]) else { continue };
            dense.edge_normals(a, b, &mut normals);
            if !edge_continuous(
                ctx,
                dense.pos[a as usize],
                ma,
                dense.pos[b as usize],
                mb,
                &normals,
                MAX_BISECT_DEPTH,
                scratch,
            ) {
                return Err(Reject::Tear);
            }
        }
    }
    Ok(())
}

/// An accepted candidate: which placement passed, and everything commit needs.
#[derive(Clone, Debug)]
pub struct Accepted {
    pub placement: usize,
    pub position: DVec3,
    /// New directions of the kept vertex and its ring.
    pub new_dirs: Vec<(u32, DVec3)>,
    /// New maps of `Candidate::dense`, in the same order.
    pub maps: Vec<Map>,
    /// Vertices associated outside the region whose primary moves onto it, ascending.
    pub extras: Vec<(u32, Map)>,
}

/// The result of evaluating one candidate: accepted, or the reason the first placement failed.
pub type Outcome = Result<Accepted, Reject>;

/// Evaluates batches of candidate collapses.
pub trait Evaluator: Sync {
    /// The backend and adapter, for reports.
    fn name(&self) -> String;
    /// Evaluates every candidate of a batch; outcomes in batch order. Fails only when the
    /// device fails (never for a candidate).
    fn evaluate(&self, state: &State, batch: &[Candidate]) -> Result<Vec<Outcome>, crate::gpu::GpuError>;
}

/// The reference evaluator: Rust, parallel over the batch with rayon.
pub struct CpuEvaluator;

impl Evaluator for CpuEvaluator {
    fn name(&self) -> String {
        format!("cpu ({} threads)", rayon::current_num_threads())
    }
    fn evaluate(&self, state: &State, batch: &[Candidate]) -> Result<Vec<Outcome>, crate::gpu::GpuError> {
        if batch.len() == 1 {
            return Ok(vec![state.evaluate_candidate(&batch[0])]);
        }
        Ok(batch.par_iter().map(|c| state.evaluate_candidate(c)).collect())
    }
}
