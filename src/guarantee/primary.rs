//! The primary search of SPEC §1: the solutions of a dense point over a set of base triangles,
//! condition (4), and the smallest |d|. One function shared by the decimator's local test, its
//! re-check, the validator and the GPU's f64 settling.

use crate::geometry::{
    self, condition4, interpolate_direction, solve_constant, solve_shell, sphere_lower_bound, triangle_distance,
    triangle_sphere,
    ShellHit,
};
use glam::DVec3;
use std::cmp::Reverse;
use std::collections::BinaryHeap;

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
    /// Per triangle (unit normal n, max |Ni·n|, max |Ni − (Ni·n)n|): the shell bound of
    /// [`shell_lower_bound`].
    pub slope: Vec<(DVec3, f64, f64)>,
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
        self.slope.clear();
        self.lookup.clear();
    }
    pub fn push(&mut self, id: u32, verts: [u32; 3], pos: [DVec3; 3], dir: [DVec3; 3]) {
        self.ids.push(id);
        self.verts.push(verts);
        self.sphere.push(triangle_sphere(&pos));
        let n = geometry::face_normal(pos[0], pos[1], pos[2]);
        let nu = dir.iter().map(|d| d.dot(n).abs()).fold(0.0, f64::max);
        let tau = dir.iter().map(|d| (*d - n * d.dot(n)).length()).fold(0.0, f64::max);
        self.slope.push((n, nu, tau));
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

/// A lower bound on |d| of any solution of `x` on triangle `t`: with X on the triangle and
/// x − X = d·N(X), N(X) a convex combination of the Ni, the height h of x over the triangle's
/// plane is at most |d|·max|Ni·n| and the distance r of its foot to the triangle at most
/// |d|·max|Ni,tangential| (constant mode: N = n, so r must vanish). Far tighter than the
/// distance to the triangle where the directions are close to the normal.
#[inline]
pub fn shell_lower_bound(x: DVec3, tris: &Tris, t: usize, mode: NormalMode) -> f64 {
    let dist = triangle_distance(x, &tris.pos[t]);
    let (n, nu, tau) = match mode {
        NormalMode::Interpolated => tris.slope[t],
        NormalMode::Constant => (tris.slope[t].0, 1.0, 0.0),
    };
    let h = (x - tris.pos[t][0]).dot(n).abs().min(dist);
    let r = (dist * dist - h * h).max(0.0).sqrt();
    // Slack for rounding: BARY_EPS lets X sit that far outside the triangle.
    let size = tris.sphere[t].1;
    let r = (r - 1e-6 * size).max(0.0);
    let by_h = if h == 0.0 { 0.0 } else if nu > 0.0 { h / nu } else { f64::INFINITY };
    let by_r = if r == 0.0 { 0.0 } else if tau > 0.0 { r / tau } else { f64::INFINITY };
    dist.max(by_h.min(f64::MAX)).max(by_r) * (1.0 - 1e-9)
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

/// An integer key that orders f64 values as `f64::total_cmp` does.
#[inline]
fn total_order_key(x: f64) -> i64 {
    let bits = x.to_bits() as i64;
    bits ^ ((((bits >> 63) as u64) >> 1) as i64)
}

/// Reusable per-thread scratch space.
#[derive(Default)]
pub struct Scratch {
    bounds: Vec<f64>,
    /// Triangles within reach by (bound, index), smallest first.
    order: BinaryHeap<Reverse<(i64, u32)>>,
    found: Vec<DVec3>,
    /// Faces a caller's searches read beyond its own set (the decimator's footprint of a
    /// candidate, [`Scratch::record_within`]), each once; the caller takes them with
    /// [`Scratch::take_reads`].
    reads: Vec<u32>,
    /// Bit f: face f is in `reads` (a bisection's midpoints read the same faces millions of
    /// times over a run; a set, not a list of every read).
    read_bits: Vec<u64>,
}

impl Scratch {
    /// The sphere lower bound on |x − X| of every triangle of `tris` (the first cull of a
    /// search), kept for [`find_primary_bounded`].
    pub fn fill_bounds(&mut self, x: DVec3, tris: &Tris) -> &[f64] {
        self.bounds.clear();
        self.bounds.extend((0..tris.len()).map(|t| sphere_lower_bound(x, tris.sphere[t].0, tris.sphere[t].1)));
        &self.bounds
    }

    /// After [`Scratch::fill_bounds`] over `tris`: records in the read record ([`Scratch::take_reads`]) the faces whose
    /// bound is within `reach`, and returns how many there were.
    pub fn record_within(&mut self, tris: &Tris, reach: f64) -> usize {
        let mut within = 0;
        for (&b, &f) in self.bounds.iter().zip(&tris.ids) {
            if b > reach {
                continue;
            }
            within += 1;
            let (word, bit) = ((f / 64) as usize, 1u64 << (f % 64));
            if word >= self.read_bits.len() {
                self.read_bits.resize(word + 1, 0);
            }
            if self.read_bits[word] & bit == 0 {
                self.read_bits[word] |= bit;
                self.reads.push(f);
            }
        }
        within
    }

    /// The faces recorded by [`Scratch::record_within`] since the last take, each once, in the
    /// order first read; the record starts empty again.
    pub fn take_reads(&mut self) -> Vec<u32> {
        for &f in &self.reads {
            self.read_bits[(f / 64) as usize] &= !(1u64 << (f % 64));
        }
        std::mem::take(&mut self.reads)
    }
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
    find_primary_hinted(x, normals, tris, mode, dmax, check4, strict, &[], scratch)
}

/// [`find_primary`], visiting the triangles `hint` first (a bisection midpoint's ends' faces):
/// a good first hit culls the rest by their bounds. The answer is the same with any hint.
#[allow(clippy::too_many_arguments)]
pub fn find_primary_hinted(
    x: DVec3,
    normals: &[DVec3],
    tris: &Tris,
    mode: NormalMode,
    dmax: f64,
    check4: bool,
    strict: bool,
    hint: &[usize],
    scratch: &mut Scratch,
) -> Found {
    scratch.fill_bounds(x, tris);
    find_primary_bounded(x, normals, tris, mode, dmax, check4, strict, hint, scratch)
}

/// [`find_primary_hinted`] over bounds already in `scratch` ([`Scratch::fill_bounds`] for the
/// same `x` and `tris`): for a caller that reads them first.
#[allow(clippy::too_many_arguments)]
pub fn find_primary_bounded(
    x: DVec3,
    normals: &[DVec3],
    tris: &Tris,
    mode: NormalMode,
    dmax: f64,
    check4: bool,
    strict: bool,
    hint: &[usize],
    scratch: &mut Scratch,
) -> Found {
    let m = tris.len();
    debug_assert_eq!(scratch.bounds.len(), m);
    scratch.found.clear();
    let mut best: Option<(usize, ShellHit)> = None;
    let tie = SAME_SOLUTION_REL * dmax;
    // Solves triangle ti and keeps the better hit (smallest |d|; a tie — the same point seen
    // from faces sharing an edge or a vertex — goes to the lowest face id, so that every search
    // picks the same face).
    let visit = |ti: usize, best: &mut Option<(usize, ShellHit)>, found: &mut Vec<DVec3>| {
        let reach = match *best {
            Some((_, h)) if !strict => h.d.abs() + tie,
            _ => dmax,
        };
        if shell_lower_bound(x, tris, ti, mode) > reach {
            return;
        }
        for h in solve_tri(x, tris, ti, mode, dmax).iter() {
            if check4 && !condition4(direction_at(tris, ti, &h, mode), normals.iter().copied()) {
                continue;
            }
            if strict {
                let p = interpolate_direction(&tris.pos[ti], &h.bary);
                if !found.iter().any(|q| q.distance(p) <= SAME_SOLUTION_REL * dmax) {
                    found.push(p);
                }
            }
            let better = match *best {
                None => true,
                Some((bt, b)) => {
                    let (da, db) = (h.d.abs(), b.d.abs());
                    da < db - tie || (da <= db + tie && tris.ids[ti] < tris.ids[bt])
                }
            };
            if better {
                *best = Some((ti, h));
            }
        }
    };
    // The hints first (a hint out of reach is only marked visited)...
    for &ti in hint.iter().filter(|&&t| t < m) {
        let tb = scratch.bounds[ti];
        if !tb.is_finite() {
            continue; // a repeated hint
        }
        scratch.bounds[ti] = f64::INFINITY;
        if tb > dmax || (!strict && best.is_some_and(|(_, h)| tb > h.d.abs() + tie)) {
            continue;
        }
        visit(ti, &mut best, &mut scratch.found);
    }
    // ...then the others in the order of their bound (ties: lowest index), until no triangle
    // can beat the best hit. Only triangles within reach now can be within reach later.
    let reach = match best {
        Some((_, h)) if !strict => dmax.min(h.d.abs() + tie),
        _ => dmax,
    };
    // A heap, not a sort: the search mostly stops after a few triangles.
    scratch.order.clear();
    scratch.order.extend(scratch.bounds.iter().enumerate().filter(|(_, &b)| b <= reach).map(|(t, &b)| Reverse((total_order_key(b), t as u32))));
    while let Some(Reverse((_, ti))) = scratch.order.pop() {
        let tb = scratch.bounds[ti as usize];
        if !strict && best.is_some_and(|(_, h)| tb > h.d.abs() + tie) {
            break;
        }
        visit(ti as usize, &mut best, &mut scratch.found);
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


#[cfg(test)]
mod tests {
    use super::{total_order_key, Scratch, Tris};
    use glam::DVec3;

    #[test]
    fn the_read_record_holds_each_face_once_until_taken() {
        // Three unit triangles along x, faces 7, 130 and 64 (ids past one word of the bit set):
        //
        //   ·---·---·---·
        //   | 7 |130| 64|      x = (0.5, 0.5, 0) sits over face 7
        //   ·---·---·---·
        let mut tris = Tris::default();
        for (k, id) in [7u32, 130, 64].into_iter().enumerate() {
            let o = DVec3::new(k as f64, 0.0, 0.0);
            tris.push(id, [0, 1, 2], [o, o + DVec3::X, o + DVec3::Y], [DVec3::Z; 3]);
        }
        tris.finish();
        let mut sc = Scratch::default();
        let x = DVec3::new(0.5, 0.2, 0.0);
        sc.fill_bounds(x, &tris);
        // Sphere bounds 0, 0.10 and 1.09: reach 0.6 takes faces 7 and 130, not 64.
        assert_eq!(sc.record_within(&tris, 0.6), 2);
        // The same search again reads the same faces: counted, not listed twice.
        assert_eq!(sc.record_within(&tris, 0.6), 2);
        assert_eq!(sc.record_within(&tris, 10.0), 3);
        assert_eq!(sc.take_reads(), vec![7, 130, 64]);
        // Taken: the record starts empty and lists them again.
        assert!(sc.take_reads().is_empty());
        sc.fill_bounds(x, &tris);
        assert_eq!(sc.record_within(&tris, 0.6), 2);
        assert_eq!(sc.take_reads(), vec![7, 130]);
    }

    #[test]
    fn the_search_order_key_orders_as_total_cmp() {
        // The search visits triangles by (bound, index); the heap's integer key must give the
        // order the sort by `f64::total_cmp` gave, signed zeros and infinities included.
        let xs = [0.0, -0.0, 1e-300, 5e-324, 1.0, 0.5, 1.0 + f64::EPSILON, f64::INFINITY, -1.0, f64::MAX, 3.25e-7];
        for &a in &xs {
            for &b in &xs {
                assert_eq!(total_order_key(a).cmp(&total_order_key(b)), a.total_cmp(&b), "{a:e} vs {b:e}");
            }
        }
    }
}
