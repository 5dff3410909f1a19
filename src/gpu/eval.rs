//! The GPU evaluator: candidate batches and whole validations solved by the WGSL shell kernels
//! (`shaders/shell.wgsl`), one invocation per (candidate placement, dense vertex) pair or per
//! dense vertex, with the CPU keeping topology, queue, and the final word. For candidates it
//! is the primaries stage of [`crate::eval::pipeline`]: the other stages are the CPU's.
//!
//! The kernels run in f32 and mirror `geometry.rs` and [`find_primary`] 1:1. What f32 cannot
//! decide the way f64 would — a barycentric coordinate within `BAND_BARY` of 0, a condition (4)
//! dot product within `BAND_DOT`, |d| within `BAND_T` of dmax, a near-tangent root, or a second
//! triangle within `BAND_D`·dmax of the best |d| — comes back as the *tolerance band*, and the
//! CPU solves that query in f64. Outside the band, the GPU's choice of triangle is taken and its
//! barycentrics and d are recomputed in f64 on that one triangle. So the GPU path gives the same
//! decisions, maps and output bytes as the CPU path; the counters say how much work fell in the
//! band.

use crate::decimate::{Candidate, Snapshot};
use crate::decimate::{Evaluator, Outcome};
use crate::eval::pipeline::{self, Item, Primaries, Solved};
use crate::guarantee::{best_on_triangle, find_primary, Found, Map, NormalMode, Scratch, Tris};
use crate::geometry::ShellHit;
use crate::gpu::{Gpu, GpuAnswer, GpuError, GpuNode, GpuQuery, GpuTri, ShellEntry, ShellKernel, WORKGROUP_SIZE};
use crate::mesh::DenseData;
use crate::topology::INVALID;
use glam::DVec3;
use rayon::prelude::*;
use std::sync::Mutex;
use std::time::Instant;

/// The WGSL source of the shell kernels, before the generated constants.
pub const SHELL_WGSL: &str = include_str!("../../shaders/shell.wgsl");

/// Two triangles whose best |d| differ by less than this (× dmax) are a tie f32 cannot order.
/// Why: f32 roots carry errors near 1e-6·dmax on scan-scale triangles; 100× margin.
pub const BAND_D: f64 = 1e-4;
/// |d| within this fraction of dmax is "at the limit".
/// Why: the same root error as BAND_D, at the edge of the search interval.
pub const BAND_T: f64 = 1e-4;
/// A barycentric coordinate within ±this of 0 is on an edge as far as f32 can tell.
/// Why: f32 relative coordinates give barycentric errors near 1e-6 on the smallest triangles.
pub const BAND_BARY: f64 = 1e-4;
/// Condition (4) dot products within ±this × |N| are undecided.
/// Why: a barycentric error of BAND_BARY moves N by up to 2·BAND_BARY; 5× margin.
pub const BAND_DOT: f64 = 1e-3;
/// A critical value of the normalised cubic below this is a possible double root.
/// Why: f32 evaluation of the normalised cubic is good to ~1e-6; 100× margin.
pub const BAND_TANGENT: f64 = 1e-4;
/// Q(d) with |n|² below this × (longest edge)⁴ is too thin for f32 barycentrics.
/// Why: below it the barycentric quotients lose more than half of f32's digits.
pub const BAND_DEGENERATE: f64 = 1e-6;
/// Strict mode: two solutions closer than this (× dmax) may be one point seen twice.
/// Why: as BAND_D; f64 merges them below SAME_SOLUTION_REL.
pub const BAND_POS: f64 = 1e-4;
/// Newton polishing in f32 stops at this step (in units of dmax).
/// Why: about f32's resolution on [-1, 1].
pub const F32_ROOT_TOL: f64 = 1e-7;
/// Roots of neighbouring monotone pieces closer than this are one root (units of dmax).
/// Why: f32 twin of the f64 1e-9 merge.
pub const F32_ROOT_DEDUP: f64 = 1e-6;
/// Polishing steps at most. Why: bisection halves a unit bracket to 1e-7 in 24 steps.
pub const POLISH_ITERATIONS: u32 = 40;
/// A quadratic whose leading coefficient is below this × the largest is solved as linear.
/// Why: only critical points inside [-1, 1] matter, and those come from the linear part then.
pub const QUADRATIC_FLAT: f64 = 1e-6;
/// BVH traversal stack of the projection kernel. Why: a median-split BVH of n leaves has
/// depth log2(n) + 1, far below 64 for any mesh that fits in memory.
pub const BVH_STACK: u32 = 64;
/// Marks a leaf in `GpuNode::b`.
pub const LEAF_BIT: u32 = 0x8000_0000;

/// Query flags.
pub const FLAG_CHECK4: u32 = 1;
pub const FLAG_STRICT: u32 = 2;

/// Answer statuses.
pub const STATUS_HIT: u32 = 0;
pub const STATUS_NONE: u32 = 1;
pub const STATUS_AMBIGUOUS: u32 = 2;
pub const STATUS_BAND_TIE: u32 = 3;
pub const STATUS_BAND_MARGINAL: u32 = 4;

/// `GpuParams::mode`.
pub const MODE_INTERPOLATED: u32 = 0;
pub const MODE_CONSTANT: u32 = 1;

/// The constants shared by the Rust kernels and the WGSL, as WGSL source.
pub fn shell_constants() -> String {
    let f = |name: &str, v: f64| format!("const {name}: f32 = {:e};\n", v as f32);
    let u = |name: &str, v: u32| format!("const {name}: u32 = {v}u;\n");
    let mut s = String::from("// Generated from Rust (gpu::eval::shell_constants): do not edit.\n");
    s += &f("BARY_EPS", crate::geometry::BARY_EPS);
    s += &f("BAND_D", BAND_D);
    s += &f("BAND_T", BAND_T);
    s += &f("T_END", 1.0 + BAND_T);
    s += &f("BAND_BARY", BAND_BARY);
    s += &f("BAND_DOT", BAND_DOT);
    s += &f("BAND_TANGENT", BAND_TANGENT);
    s += &f("BAND_DEGENERATE", BAND_DEGENERATE);
    s += &f("BAND_POS", BAND_POS);
    s += &f("F32_ROOT_TOL", F32_ROOT_TOL);
    s += &f("F32_ROOT_DEDUP", F32_ROOT_DEDUP);
    s += &f("QUADRATIC_FLAT", QUADRATIC_FLAT);
    s += &f("F32_MAX", 3.0e38);
    s += &f("F32_INF", f32::MAX as f64);
    s += &u("POLISH_ITERATIONS", POLISH_ITERATIONS);
    s += &u("BVH_STACK", BVH_STACK);
    s += &u("LEAF_BIT", LEAF_BIT);
    s += &u("INVALID", INVALID);
    s += &u("FLAG_CHECK4", FLAG_CHECK4);
    s += &u("FLAG_STRICT", FLAG_STRICT);
    s += &u("STATUS_HIT", STATUS_HIT);
    s += &u("STATUS_NONE", STATUS_NONE);
    s += &u("STATUS_AMBIGUOUS", STATUS_AMBIGUOUS);
    s += &u("STATUS_BAND_TIE", STATUS_BAND_TIE);
    s += &u("STATUS_BAND_MARGINAL", STATUS_BAND_MARGINAL);
    s += &u("MODE_INTERPOLATED", MODE_INTERPOLATED);
    s += &u("MODE_CONSTANT", MODE_CONSTANT);
    s += &u("WORKGROUP_SIZE", WORKGROUP_SIZE);
    s
}

/// The complete shell kernel source: generated constants, then `shaders/shell.wgsl`.
pub fn shell_source() -> String {
    shell_constants() + SHELL_WGSL
}

/// How the GPU's answers fell: decided on the GPU, or in the band and decided in f64.
#[derive(Clone, Debug, Default, serde::Serialize)]
pub struct BandStats {
    /// Queries answered by the kernels.
    pub queries: u64,
    /// Decided on the GPU: a primary (its triangle kept, d and barycentrics redone in f64),
    /// no solution, or (strict) ambiguous.
    pub gpu_hit: u64,
    pub gpu_none: u64,
    pub gpu_ambiguous: u64,
    /// In the tolerance band, solved again in f64: a tie between triangles, or an undecidable
    /// barycentric / condition (4) / |d| / tangency.
    pub band_tie: u64,
    pub band_marginal: u64,
    /// GPU hits whose triangle had no f64 solution (then solved in full in f64): disagreements
    /// outside the band. Expected 0.
    pub disagreements: u64,
    /// Region vertices of placements after a candidate's first (tried when the first failed),
    /// solved by the f64 search on the CPU rather than in another dispatch: not in `queries`.
    pub later_placement_vertices: u64,
    /// Seconds in the kernels (upload, dispatch, readback).
    pub kernel_s: f64,
}

impl BandStats {
    fn count(&mut self, answers: &[GpuAnswer]) {
        self.queries += answers.len() as u64;
        for a in answers {
            match a.status {
                STATUS_HIT => self.gpu_hit += 1,
                STATUS_NONE => self.gpu_none += 1,
                STATUS_AMBIGUOUS => self.gpu_ambiguous += 1,
                STATUS_BAND_TIE => self.band_tie += 1,
                _ => self.band_marginal += 1,
            }
        }
    }
    /// Fraction of queries that fell in the band.
    pub fn band_fraction(&self) -> f64 {
        if self.queries == 0 {
            0.0
        } else {
            (self.band_tie + self.band_marginal) as f64 / self.queries as f64
        }
    }
}

fn v4(p: DVec3) -> [f32; 4] {
    [p.x as f32, p.y as f32, p.z as f32, 0.0]
}

fn v3(p: DVec3) -> [f32; 3] {
    [p.x as f32, p.y as f32, p.z as f32]
}

/// One triangle of `tris` in the kernel's layout, relative to `origin` (f32 keeps its digits for
/// the small differences that matter).
pub fn gpu_tri(tris: &Tris, t: usize, origin: DVec3) -> GpuTri {
    let p = tris.pos[t].map(|q| q - origin);
    let n = tris.dir[t];
    let (c, r) = tris.sphere[t];
    let mut sphere = v4(c - origin);
    sphere[3] = r as f32;
    GpuTri { p0: v4(p[0]), p1: v4(p[1]), p2: v4(p[2]), n0: v4(n[0]), n1: v4(n[1]), n2: v4(n[2]), sphere }
}

fn mode_code(mode: NormalMode) -> u32 {
    match mode {
        NormalMode::Interpolated => MODE_INTERPOLATED,
        NormalMode::Constant => MODE_CONSTANT,
    }
}

/// The f64 decision for one kernel answer over `tris`: outside the band, the GPU's triangle
/// redone in f64; in the band (or for an answer out of range), `full`, the whole f64 search.
/// A GPU hit whose triangle has no f64 solution is a disagreement: counted, then `full`.
#[allow(clippy::too_many_arguments)]
fn settle(
    a: &GpuAnswer,
    x: DVec3,
    normals: &[DVec3],
    tris: &Tris,
    mode: NormalMode,
    dmax: f64,
    check4: bool,
    disagreements: &mut u64,
    full: impl FnOnce() -> Found,
) -> Found {
    match a.status {
        STATUS_HIT if (a.tri as usize) < tris.len() => match best_on_triangle(x, normals, tris, a.tri as usize, mode, dmax, check4) {
            Some(h) => Found::Hit(a.tri as usize, h),
            None => {
                *disagreements += 1;
                full()
            }
        },
        STATUS_NONE => Found::None,
        STATUS_AMBIGUOUS => Found::Ambiguous,
        _ => full(),
    }
}

/// The GPU evaluator: the shell kernels on one device, for one dense mesh.
pub struct GpuEvaluator {
    kernel: ShellKernel,
    stats: Mutex<BandStats>,
}

impl GpuEvaluator {
    /// Opens the shell kernels on `gpu` and uploads the dense mesh's normals.
    pub fn new(gpu: Gpu, dense: &DenseData) -> Result<GpuEvaluator, GpuError> {
        let normals: Vec<[f32; 4]> = dense.normal.iter().map(|&n| v4(n)).collect();
        let kernel = ShellKernel::new(gpu, &shell_source(), &normals, &dense.vf_start, &dense.vf)?;
        Ok(GpuEvaluator { kernel, stats: Mutex::new(BandStats::default()) })
    }

    /// The adapter, as "name (backend)".
    pub fn adapter(&self) -> String {
        self.kernel.gpu().describe()
    }

    /// The band counters so far.
    pub fn stats(&self) -> BandStats {
        self.stats.lock().map(|s| s.clone()).unwrap_or_default()
    }

    fn add_stats(&self, answers: &[GpuAnswer], disagreements: u64, seconds: f64) {
        if let Ok(mut s) = self.stats.lock() {
            s.count(answers);
            s.disagreements += disagreements;
            s.kernel_s += seconds;
        }
    }

    fn add_later_placement(&self, vertices: usize) {
        if let Ok(mut s) = self.stats.lock() {
            s.later_placement_vertices += vertices as u64;
        }
    }

    /// The kernel's buffers for a round's first wave (or the parity test's placements): each
    /// item's neighbourhood (relative to its first corner) and one query per region vertex
    /// (`Candidate::dense` order), and where each item's queries start.
    fn queries<'a>(snap: &Snapshot, batch: &[Candidate], items: impl Iterator<Item = (usize, &'a Tris)>) -> (Vec<GpuTri>, Vec<GpuQuery>, Vec<usize>) {
        let (mut gtris, mut queries, mut first) = (Vec::new(), Vec::new(), Vec::new());
        for (ci, tris) in items {
            let c = &batch[ci];
            first.push(queries.len());
            let origin = tris.pos[0][0];
            let tri_start = gtris.len() as u32;
            gtris.extend((0..tris.len()).map(|t| gpu_tri(tris, t, origin)));
            for &v in &c.dense {
                let pinched = snap.dense.pinched[v as usize];
                let mut flags = 0;
                if !pinched {
                    flags |= FLAG_CHECK4;
                    if snap.strict {
                        flags |= FLAG_STRICT;
                    }
                }
                queries.push(GpuQuery {
                    x: v3(snap.dense.pos[v as usize] - origin),
                    vertex: v,
                    tri_start,
                    tri_count: tris.len() as u32,
                    flags,
                    hint: tris.index_of(snap.assoc[v as usize].face).map_or(INVALID, |t| t as u32),
                });
            }
        }
        (gtris, queries, first)
    }

    /// The kernel's raw answers for every (candidate, placement, dense vertex) of a batch, with
    /// each placement's neighbourhood: for the parity test, which compares them with
    /// [`find_primary`] on the same neighbourhoods.
    pub fn raw_answers(&self, snap: &Snapshot, batch: &[Candidate]) -> Result<Vec<(usize, usize, Tris, Vec<GpuAnswer>)>, GpuError> {
        let waves = batch.iter().map(|c| c.placements.len()).max().unwrap_or(0);
        let mut built = Vec::new();
        for pi in 0..waves {
            let cands: Vec<usize> = (0..batch.len()).filter(|&ci| pi < batch[ci].placements.len()).collect();
            built.extend(pipeline::stage_neighbourhoods(snap, batch, pi, &cands).into_iter().filter_map(|(it, _)| it.ok()).map(|it| (it.candidate, pi, it.tris)));
        }
        let (gtris, queries, first) = Self::queries(snap, batch, built.iter().map(|(ci, _, t)| (*ci, t)));
        let answers = self.kernel.run(ShellEntry::Candidates, snap.dmax as f32, mode_code(snap.mode), &gtris, &[], &queries)?;
        Ok(built
            .into_iter()
            .zip(first)
            .map(|((ci, pi, tris), q)| (ci, pi, tris, answers[q..q + batch[ci].dense.len()].to_vec()))
            .collect())
    }

    /// Projects every dense vertex onto the whole base (the validator's first step): the
    /// primary solution of each, `None` when it has none.
    fn project_impl(&self, dense: &DenseData, index: &crate::validate::BaseIndex, mode: NormalMode, dmax: f64) -> Result<Vec<Option<Map>>, GpuError> {
        let t0 = Instant::now();
        let (base, bvh) = (index.base, &index.bvh);
        let (lo, hi) = base.positions.iter().fold((DVec3::splat(f64::INFINITY), DVec3::splat(f64::NEG_INFINITY)), |(l, h), &p| (l.min(p), h.max(p)));
        let origin = if base.positions.is_empty() { DVec3::ZERO } else { 0.5 * (lo + hi) };
        // Triangles in BVH order, so that a leaf is a contiguous range.
        let order = bvh.order();
        let mut all = Tris::default();
        for &f in order {
            let t = base.faces[f as usize];
            all.push(f, t, t.map(|v| base.positions[v as usize]), t.map(|v| base.directions[v as usize]));
        }
        all.finish();
        let gtris: Vec<GpuTri> = (0..all.len()).map(|t| gpu_tri(&all, t, origin)).collect();
        let nodes: Vec<GpuNode> = bvh
            .nodes()
            .iter()
            .map(|n| GpuNode {
                lo: v3(n.lo - origin),
                hi: v3(n.hi - origin),
                a: n.a,
                b: if n.count > 0 { n.count | LEAF_BIT } else { n.b },
            })
            .collect();
        let queries: Vec<GpuQuery> = (0..dense.pos.len() as u32)
            .map(|v| GpuQuery {
                x: v3(dense.pos[v as usize] - origin),
                vertex: v,
                tri_start: 0,
                tri_count: 0,
                flags: if dense.pinched[v as usize] { 0 } else { FLAG_CHECK4 },
                hint: INVALID,
            })
            .collect();
        let answers = self.kernel.run(ShellEntry::Project, dmax as f32, mode_code(mode), &gtris, &nodes, &queries)?;
        let kernel_s = t0.elapsed().as_secs_f64();
        let results: Vec<(Option<Map>, u64)> = answers
            .par_iter()
            .enumerate()
            .map_init(
                || (Vec::new(), Scratch::default(), Vec::new(), Tris::default()),
                |(normals, scratch, near, tris), (v, a)| {
                    dense.vertex_normals(v as u32, normals);
                    let x = dense.pos[v];
                    let check4 = !dense.pinched[v];
                    let mut dis = 0;
                    let found = settle(a, x, normals, &all, mode, dmax, check4, &mut dis, || {
                        match crate::validate::primary_global(index, x, normals, mode, dmax, check4, scratch, near, tris) {
                            Some(m) => all.index_of(m.face).map_or(Found::None, |t| Found::Hit(t, ShellHit { d: m.d, bary: m.bary })),
                            None => Found::None,
                        }
                    });
                    match found {
                        Found::Hit(t, h) => (Some(Map { face: all.ids[t], bary: h.bary, d: h.d }), dis),
                        _ => (None, dis),
                    }
                },
            )
            .collect();
        self.add_stats(&answers, results.iter().map(|r| r.1).sum(), kernel_s);
        Ok(results.into_iter().map(|r| r.0).collect())
    }
}

impl crate::validate::Project for GpuEvaluator {
    fn project(&self, dense: &DenseData, index: &crate::validate::BaseIndex, mode: NormalMode, dmax: f64) -> Result<Vec<Option<Map>>, GpuError> {
        self.project_impl(dense, index, mode, dmax)
    }
}

impl Evaluator for GpuEvaluator {
    fn name(&self) -> String {
        format!("gpu: {}", self.adapter())
    }

    /// One dispatch a round: every candidate's first placement gathered and hinted over the
    /// round, and the regions of those that pass solved by the kernel at once; then each
    /// candidate on its own, as on the CPU path ([`pipeline::Round::finish_each_alone`]): its
    /// first placement's primaries settled from the kernel's answers, a later placement's
    /// (after the first failed) by the f64 search, at once, rather than wait for the round's
    /// next dispatch.
    fn evaluate(&self, snap: &Snapshot, batch: &[Candidate]) -> Result<Vec<Outcome>, GpuError> {
        let mut round = pipeline::Round::new(snap, batch);
        let Some(first) = round.gather(snap, batch, 0) else {
            return round.finish_each_alone(snap, batch, Default::default(), |_| FirstPlacement { gpu: self, answers: &[] });
        };
        let (gtris, queries, starts) = Self::queries(snap, batch, first.items().iter().map(|it| (it.candidate, &it.tris)));
        let t0 = Instant::now();
        let answers = self.kernel.run(ShellEntry::Candidates, snap.dmax as f32, mode_code(snap.mode), &gtris, &[], &queries)?;
        self.add_stats(&answers, 0, t0.elapsed().as_secs_f64());
        // Where each candidate's answers lie (a candidate with no item has none).
        let mut at = vec![(0, 0); batch.len()];
        for (it, q) in first.items().iter().zip(starts) {
            at[it.candidate] = (q, q + batch[it.candidate].dense.len());
        }
        round.finish_each_alone(snap, batch, first, |ci| FirstPlacement { gpu: self, answers: &answers[at[ci].0..at[ci].1] })
    }
}

/// The primaries stage of one candidate on the GPU path: its first placement's regions
/// settled from the kernel's answers ([`settle`]: outside the band the kernel's triangle redone
/// in f64, in it the whole f64 search); a later placement's by the f64 search
/// ([`pipeline::CpuPrimaries`]).
struct FirstPlacement<'a> {
    gpu: &'a GpuEvaluator,
    /// The kernel's answers for the candidate's first placement (`Candidate::dense` order).
    answers: &'a [GpuAnswer],
}

impl Primaries for FirstPlacement<'_> {
    fn solve(&self, snap: &Snapshot, batch: &[Candidate], items: &[Item]) -> Result<Vec<(Solved, f64, f64)>, GpuError> {
        items
            .iter()
            .map(|it| {
                let c = &batch[it.candidate];
                if it.placement != 0 {
                    // A later placement, tried because the first failed: the f64 search now
                    // rather than another dispatch.
                    self.gpu.add_later_placement(c.dense.len());
                    return pipeline::CpuPrimaries.solve(snap, batch, std::slice::from_ref(it)).map(|mut r| r.remove(0));
                }
                let t = Instant::now();
                let tris = &it.tris;
                let (solved, states, excess) = snap.solve_region_vertices(
                    c,
                    tris,
                    || (Scratch::default(), Vec::new(), 0u64),
                    |(scratch, normals, disagreements), i, x, pinched| {
                        snap.dense.vertex_normals(c.dense[i], normals);
                        let (check4, strict) = (!pinched, snap.strict && !pinched);
                        settle(&self.answers[i], x, normals, tris, snap.mode, snap.dmax, check4, disagreements, || {
                            find_primary(x, normals, tris, snap.mode, snap.dmax, check4, strict, scratch)
                        })
                    },
                );
                let disagreements: u64 = states.iter().map(|s| s.2).sum();
                if disagreements > 0 {
                    self.gpu.add_stats(&[], disagreements, 0.0);
                }
                let wall = t.elapsed().as_secs_f64();
                Ok((solved, wall, excess.cpu_seconds(wall)))
            })
            .collect()
    }
}
