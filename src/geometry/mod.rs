//! Pure geometric kernels: face normals, vertex directions, the shell inversion of SPEC §1,
//! condition (4) and the constant-normal projection.
//!
//! These functions are the oracle that any other evaluator (the WGSL kernels of the GPU issue)
//! must mirror: same names, same order of operations, same constants.

pub mod bvh;

use glam::DVec3;

/// A solution is accepted when all barycentric coordinates are at least `-BARY_EPS`.
/// Why: a point on an edge shared by two triangles must be found by both, despite rounding.
pub const BARY_EPS: f64 = 1e-9;

/// Roots of the shell cubic are polished until the Newton step is this small (in units of dmax).
/// Why: 1e-12·dmax is far below any scan's feature size and still well above f64 noise.
pub const ROOT_TOL: f64 = 1e-12;

/// A critical point of the cubic whose |value| is below this (coefficients normalised to 1)
/// is a double root: the shell touches the point tangentially.
/// Why: tangential contact is a real (borderline) solution; larger values are noise-free misses.
pub const TANGENT_TOL: f64 = 1e-12;

/// Squared length under which a triangle Q(d) counts as degenerate (relative to its edges).
/// Why: barycentric coordinates of a collapsed triangle are meaningless.
pub const DEGENERATE_REL: f64 = 1e-14;

/// Unnormalised normal (twice the area, oriented by winding).
#[inline]
pub fn face_cross(p0: DVec3, p1: DVec3, p2: DVec3) -> DVec3 {
    (p1 - p0).cross(p2 - p0)
}

/// Unit face normal, or zero for a degenerate triangle.
#[inline]
pub fn face_normal(p0: DVec3, p1: DVec3, p2: DVec3) -> DVec3 {
    face_cross(p0, p1, p2).normalize_or_zero()
}

/// One solution of the shell inversion: the point x lies at `X + d·N(X)` with
/// `X = bary[0]·P1 + bary[1]·P2 + bary[2]·P3`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ShellHit {
    pub d: f64,
    pub bary: [f64; 3],
}

/// At most three roots of the cubic, hence at most three hits per triangle.
#[derive(Clone, Copy, Debug, Default)]
pub struct Hits {
    pub n: usize,
    pub hit: [Option<ShellHit>; 3],
}

impl Hits {
    pub fn iter(&self) -> impl Iterator<Item = ShellHit> + '_ {
        self.hit[..self.n].iter().filter_map(|h| *h)
    }
    fn push(&mut self, h: ShellHit) {
        if self.n < 3 {
            self.hit[self.n] = Some(h);
            self.n += 1;
        }
    }
}

#[inline]
fn det3(a: DVec3, b: DVec3, c: DVec3) -> f64 {
    a.dot(b.cross(c))
}

/// Coefficients `[c0, c1, c2, c3]` of `det[Q1(d)−x, Q2(d)−x, Q3(d)−x]` (SPEC §1).
pub fn cubic_coeffs(x: DVec3, p: &[DVec3; 3], n: &[DVec3; 3]) -> [f64; 4] {
    let a1 = p[0] - x;
    let a2 = p[1] - x;
    let a3 = p[2] - x;
    let (n1, n2, n3) = (n[0], n[1], n[2]);
    let c0 = det3(a1, a2, a3);
    let c1 = det3(n1, a2, a3) + det3(a1, n2, a3) + det3(a1, a2, n3);
    let c2 = det3(a1, n2, n3) + det3(n1, a2, n3) + det3(n1, n2, a3);
    let c3 = det3(n1, n2, n3);
    [c0, c1, c2, c3]
}

#[inline]
fn poly_eval(c: &[f64; 4], t: f64) -> f64 {
    ((c[3] * t + c[2]) * t + c[1]) * t + c[0]
}

/// Real roots of `a t² + b t + c` (any of a, b may vanish), ascending, written into `out`.
fn quadratic_roots(a: f64, b: f64, c: f64, out: &mut [f64; 2]) -> usize {
    let scale = a.abs().max(b.abs()).max(c.abs());
    if scale == 0.0 {
        return 0;
    }
    if a.abs() <= 1e-14 * scale {
        if b.abs() <= 1e-14 * scale {
            return 0;
        }
        out[0] = -c / b;
        return 1;
    }
    let disc = b * b - 4.0 * a * c;
    if disc < 0.0 {
        return 0;
    }
    let sq = disc.sqrt();
    // Numerically stable pair (no cancellation between -b and sqrt).
    let q = -0.5 * (b + b.signum() * sq);
    let (mut r0, mut r1) = if q != 0.0 { (q / a, c / q) } else { (0.0, 0.0) };
    if r0 > r1 {
        std::mem::swap(&mut r0, &mut r1);
    }
    out[0] = r0;
    out[1] = r1;
    2
}

/// Polishes a root of `c` on a monotone bracket [lo, hi] with `f(lo)`, `f(hi)` of opposite sign
/// (or one zero): Halley's method from the secant point, kept inside the bracket, falling back
/// to bisection; stops when the step is below ROOT_TOL.
fn polish_root(c: &[f64; 4], mut lo: f64, mut hi: f64, flo: f64, fhi: f64) -> f64 {
    if flo == 0.0 {
        return lo;
    }
    if fhi == 0.0 {
        return hi;
    }
    let rising = fhi > 0.0;
    let mut t = (lo * fhi - hi * flo) / (fhi - flo);
    if !(t > lo && t < hi) {
        t = 0.5 * (lo + hi);
    }
    for _ in 0..60 {
        let f = poly_eval(c, t);
        if f == 0.0 {
            return t;
        }
        if (f > 0.0) == rising {
            hi = t;
        } else {
            lo = t;
        }
        // Halley's step (cubic convergence: 5.9 steps a root on the bunny against Newton's 8.4).
        let df = (3.0 * c[3] * t + 2.0 * c[2]) * t + c[1];
        let ddf = 6.0 * c[3] * t + 2.0 * c[2];
        let den = 2.0 * df * df - f * ddf;
        let mut tn = if den != 0.0 { t - 2.0 * f * df / den } else { f64::NAN };
        if !(tn > lo && tn < hi) {
            tn = 0.5 * (lo + hi);
        }
        let step = (tn - t).abs();
        t = tn;
        if step <= ROOT_TOL || hi - lo <= ROOT_TOL {
            break;
        }
    }
    t
}

/// Real roots of the cubic `c` (normalised variable t ∈ [-1, 1]), ascending, deduplicated.
/// Robust where the cubic degenerates to a quadratic or a line (near-equal normals): the
/// interval is split at the real roots of the derivative and each monotone piece is bracketed.
pub fn cubic_roots_in_unit(c: &[f64; 4], out: &mut [f64; 3]) -> usize {
    cubic_roots_in_unit_within(c, f64::INFINITY, out)
}

/// A monotone piece of a cubic holding a root: (lo, hi, f(lo), f(hi)).
type Bracket = (f64, f64, f64, f64);

/// [`cubic_roots_in_unit`], where a monotone piece that lies wholly outside [-within, within]
/// gets NaN in its root's place instead of a polished root: the same number of roots, in the
/// same places, and each root inside that range exactly as [`cubic_roots_in_unit`] finds it.
/// (A root is deduplicated against its predecessor when within 1e-9 of it: a caller that
/// judges the roots against a range must leave that much margin beyond it.)
pub fn cubic_roots_in_unit_within(c: &[f64; 4], within: f64, out: &mut [f64; 3]) -> usize {
    cubic_roots_in_unit_between(c, -within, within, out)
}

/// [`cubic_roots_in_unit_within`] for the range [`from`, `to`] (not necessarily around 0).
pub fn cubic_roots_in_unit_between(c: &[f64; 4], from: f64, to: f64, out: &mut [f64; 3]) -> usize {
    let scale = c.iter().fold(0.0f64, |m, v| m.max(v.abs()));
    if scale == 0.0 || !scale.is_finite() {
        return 0;
    }
    let c = [c[0] / scale, c[1] / scale, c[2] / scale, c[3] / scale];
    // Split points: -1, the derivative's roots inside (-1, 1), 1.
    let mut crit = [0.0f64; 2];
    let nc = quadratic_roots(3.0 * c[3], 2.0 * c[2], c[1], &mut crit);
    let mut knots = [-1.0f64; 4];
    let mut nk = 1;
    for &t in &crit[..nc] {
        if t > -1.0 && t < 1.0 {
            knots[nk] = t;
            nk += 1;
        }
    }
    knots[nk] = 1.0;
    nk += 1;
    // Each kept root, or (NaN here, its piece's bracket in `skipped`) for a piece outside the
    // range. A root is merged into its predecessor within 1e-9 of it; where a skipped
    // predecessor might be that near, it is polished after all, so that exactly the roots of
    // the full search are kept.
    let mut n = 0usize;
    let mut skipped: [Option<Bracket>; 3] = [None; 3];
    let resolve = |i: usize, out: &mut [f64; 3], skipped: &mut [Option<Bracket>; 3]| {
        if let Some((lo, hi, flo, fhi)) = skipped[i].take() {
            out[i] = polish_root(&c, lo, hi, flo, fhi);
        }
    };
    // Pushes root r (ascending: r ≥ every root before it).
    let push = |r: f64, n: &mut usize, out: &mut [f64; 3], skipped: &mut [Option<Bracket>; 3]| {
        if *n > 0 {
            if skipped[*n - 1].is_some_and(|p| r - p.1 <= 1e-9) {
                resolve(*n - 1, out, skipped);
            }
            if skipped[*n - 1].is_none() && (r - out[*n - 1]).abs() <= 1e-9 {
                return;
            }
        }
        if *n < 3 {
            out[*n] = r;
            skipped[*n] = None;
            *n += 1;
        }
    };
    let mut f_prev = poly_eval(&c, knots[0]);
    for k in 0..nk - 1 {
        let (lo, hi) = (knots[k], knots[k + 1]);
        let flo = f_prev;
        let fhi = poly_eval(&c, hi);
        f_prev = fhi;
        if k > 0 && flo.abs() <= TANGENT_TOL && flo != 0.0 {
            // Tangential contact at an interior critical point (a double root).
            push(lo, &mut n, out, &mut skipped);
        }
        if flo == 0.0 {
            push(lo, &mut n, out, &mut skipped);
            continue;
        }
        if (flo < 0.0) != (fhi < 0.0) || fhi == 0.0 {
            let outside = lo > to || hi < from;
            let prev_hi = match n {
                0 => f64::NEG_INFINITY,
                _ => skipped[n - 1].map_or(out[n - 1], |p| p.1),
            };
            if outside && lo - prev_hi > 1e-9 {
                // Its root, whatever it is, is kept: a place held, not polished.
                if n < 3 {
                    out[n] = f64::NAN;
                    skipped[n] = Some((lo, hi, flo, fhi));
                    n += 1;
                }
            } else {
                let r = polish_root(&c, lo, hi, flo, fhi);
                push(r, &mut n, out, &mut skipped);
            }
        }
    }
    n
}

/// Barycentric coordinates of `x` with respect to triangle (q0, q1, q2), measured in the
/// triangle's plane; `None` when the triangle is degenerate.
#[inline]
pub fn barycentric(x: DVec3, q0: DVec3, q1: DVec3, q2: DVec3) -> Option<[f64; 3]> {
    let nq = face_cross(q0, q1, q2);
    let nn = nq.length_squared();
    let e = (q1 - q0).length_squared().max((q2 - q0).length_squared());
    if !(nn > DEGENERATE_REL * e * e) {
        return None;
    }
    let a = (q1 - x).cross(q2 - x).dot(nq) / nn;
    let b = (q2 - x).cross(q0 - x).dot(nq) / nn;
    let c = (q0 - x).cross(q1 - x).dot(nq) / nn;
    Some([a, b, c])
}

/// The shell inversion (SPEC §1): every `(d, bary)` with |d| ≤ dmax such that
/// `x = X + d·N(X)` on triangle (p, n), with all barycentrics ≥ −BARY_EPS.
pub fn solve_shell(x: DVec3, p: &[DVec3; 3], n: &[DVec3; 3], dmax: f64) -> Hits {
    solve_shell_within(x, p, n, dmax, f64::INFINITY)
}

/// How far beyond a search's reach (relative to dmax) a root is still polished. Why: roots
/// within 1e-9·dmax of each other are merged ([`cubic_roots_in_unit`]), so a root just beyond
/// reach can decide whether one just inside is kept; 4e-9 covers that and the rounding of d.
pub const WITHIN_MARGIN_REL: f64 = 4e-9;

/// [`solve_shell`], leaving out the solutions with |d| > `within` (+ WITHIN_MARGIN_REL·dmax):
/// their roots are not polished. Every solution it returns is one [`solve_shell`] returns, and
/// it returns every one with |d| ≤ `within`, bit for bit: for a search that keeps only
/// solutions within its reach.
pub fn solve_shell_within(x: DVec3, p: &[DVec3; 3], n: &[DVec3; 3], dmax: f64, within: f64) -> Hits {
    let mut hits = Hits::default();
    let c = cubic_coeffs(x, p, n);
    // Substitute d = dmax·t so that the search interval is t ∈ [-1, 1].
    let s = dmax;
    let ct = [c[0], c[1] * s, c[2] * s * s, c[3] * s * s * s];
    let mut roots = [0.0f64; 3];
    let nr = cubic_roots_in_unit_within(&ct, within / s + WITHIN_MARGIN_REL, &mut roots);
    for &t in &roots[..nr] {
        if t.is_nan() {
            continue;
        }
        let d = t * s;
        let q0 = p[0] + d * n[0];
        let q1 = p[1] + d * n[1];
        let q2 = p[2] + d * n[2];
        if let Some(b) = barycentric(x, q0, q1, q2) {
            if b[0] >= -BARY_EPS && b[1] >= -BARY_EPS && b[2] >= -BARY_EPS {
                hits.push(ShellHit { d, bary: clamp_bary(b) });
            }
        }
    }
    hits
}

/// Constant-normal mode (paper §4): orthogonal projection along the unit face normal.
pub fn solve_constant(x: DVec3, p: &[DVec3; 3], dmax: f64) -> Hits {
    let mut hits = Hits::default();
    let nf = face_normal(p[0], p[1], p[2]);
    if nf == DVec3::ZERO {
        return hits;
    }
    let d = (x - p[0]).dot(nf);
    if d.abs() > dmax {
        return hits;
    }
    let xp = x - d * nf;
    if let Some(b) = barycentric(xp, p[0], p[1], p[2]) {
        if b[0] >= -BARY_EPS && b[1] >= -BARY_EPS && b[2] >= -BARY_EPS {
            hits.push(ShellHit { d, bary: clamp_bary(b) });
        }
    }
    hits
}

/// Clamps tiny negative barycentrics to zero and renormalises to sum 1.
#[inline]
pub fn clamp_bary(b: [f64; 3]) -> [f64; 3] {
    let a = [b[0].max(0.0), b[1].max(0.0), b[2].max(0.0)];
    let s = a[0] + a[1] + a[2];
    if s > 0.0 {
        [a[0] / s, a[1] / s, a[2] / s]
    } else {
        [1.0 / 3.0; 3]
    }
}

/// The interpolated direction `N(X) = a·N1 + b·N2 + c·N3` (not renormalised).
#[inline]
pub fn interpolate_direction(n: &[DVec3; 3], bary: &[f64; 3]) -> DVec3 {
    bary[0] * n[0] + bary[1] * n[1] + bary[2] * n[2]
}

/// Condition (4): `N · n_i > 0` for every incident dense face normal.
#[inline]
pub fn condition4(dir: DVec3, incident_normals: impl IntoIterator<Item = DVec3>) -> bool {
    incident_normals.into_iter().all(|ni| dir.dot(ni) > 0.0)
}

/// Closest point to the origin on triangle (a, b, c) (Ericson, Real-Time Collision Detection).
fn closest_to_origin_on_triangle(a: DVec3, b: DVec3, c: DVec3) -> DVec3 {
    let p = DVec3::ZERO;
    let ab = b - a;
    let ac = c - a;
    let ap = p - a;
    let d1 = ab.dot(ap);
    let d2 = ac.dot(ap);
    if d1 <= 0.0 && d2 <= 0.0 {
        return a;
    }
    let bp = p - b;
    let d3 = ab.dot(bp);
    let d4 = ac.dot(bp);
    if d3 >= 0.0 && d4 <= d3 {
        return b;
    }
    let vc = d1 * d4 - d3 * d2;
    if vc <= 0.0 && d1 >= 0.0 && d3 <= 0.0 {
        let v = d1 / (d1 - d3);
        return a + v * ab;
    }
    let cp = p - c;
    let d5 = ab.dot(cp);
    let d6 = ac.dot(cp);
    if d6 >= 0.0 && d5 <= d6 {
        return c;
    }
    let vb = d5 * d2 - d1 * d6;
    if vb <= 0.0 && d2 >= 0.0 && d6 <= 0.0 {
        let w = d2 / (d2 - d6);
        return a + w * ac;
    }
    let va = d3 * d6 - d5 * d4;
    if va <= 0.0 && (d4 - d3) >= 0.0 && (d5 - d6) >= 0.0 {
        let w = (d4 - d3) / ((d4 - d3) + (d5 - d6));
        return b + w * (c - b);
    }
    let denom = 1.0 / (va + vb + vc);
    let v = vb * denom;
    let w = vc * denom;
    a + ab * v + ac * w
}

/// The unit direction that maximises the smallest dot product with the given unit normals,
/// with that smallest dot product; `None` when no direction has a positive dot product with
/// all of them (the normals "pinch": the origin lies in their convex hull).
///
/// By duality the answer is the point of the normals' convex hull nearest the origin,
/// normalised. With few normals (a vertex fan), the nearest point lies on a triangle of three
/// of them; the optimal candidate is the one every normal lies beyond.
pub fn maxmin_direction(normals: &[DVec3]) -> Option<(DVec3, f64)> {
    let k = normals.len();
    if k == 0 {
        return None;
    }
    let mut best: Option<DVec3> = None;
    let consider = |q: DVec3, best: &mut Option<DVec3>| {
        let qq = q.length_squared();
        if qq <= 1e-24 {
            return;
        }
        if let Some(b) = best {
            if qq >= b.length_squared() {
                return;
            }
        }
        // Optimality: every normal lies in the half-space {y : y·q ≥ |q|²}.
        if normals.iter().all(|ni| ni.dot(q) >= qq * (1.0 - 1e-9) - 1e-15) {
            *best = Some(q);
        }
    };
    for i in 0..k {
        consider(normals[i], &mut best);
        for j in i + 1..k {
            let (a, b) = (normals[i], normals[j]);
            let ab = b - a;
            let t = if ab.length_squared() > 0.0 {
                (-a.dot(ab) / ab.length_squared()).clamp(0.0, 1.0)
            } else {
                0.0
            };
            consider(a + t * ab, &mut best);
            for l in j + 1..k {
                consider(closest_to_origin_on_triangle(a, b, normals[l]), &mut best);
            }
        }
    }
    best.map(|q| {
        let len = q.length();
        let dir = q / len;
        let m = normals.iter().map(|ni| ni.dot(dir)).fold(f64::INFINITY, f64::min);
        (dir, m)
    })
}

/// The vertex direction rule of the README (SPEC §2): the normalised area-weighted mean of the
/// incident face normals, unless it has a non-positive dot product with one of those faces;
/// then the max-min direction. `cross` are the faces' unnormalised normals (2·area·n).
pub fn vertex_direction(cross: &[DVec3]) -> DVec3 {
    let sum: DVec3 = cross.iter().copied().sum();
    let n = sum.normalize_or_zero();
    let ok = n != DVec3::ZERO && cross.iter().all(|c| c.dot(n) > 0.0);
    if ok {
        return n;
    }
    let units: Vec<DVec3> = cross
        .iter()
        .map(|c| c.normalize_or_zero())
        .filter(|u| *u != DVec3::ZERO)
        .collect();
    match maxmin_direction(&units) {
        Some((dir, _)) => dir,
        None => n,
    }
}

/// Lower bound on |d| for any solution on a triangle: |x − X| = |d|·|N(X)| ≤ |d| because
/// N(X) is a convex combination of unit vectors. The bound uses a bounding sphere.
#[inline]
pub fn sphere_lower_bound(x: DVec3, center: DVec3, radius: f64) -> f64 {
    (x.distance(center) - radius).max(0.0)
}

/// Euclidean distance from `x` to triangle `p` (a lower bound on |d| of any solution on it,
/// for the same reason as [`sphere_lower_bound`], and a much tighter one).
#[inline]
pub fn triangle_distance(x: DVec3, p: &[DVec3; 3]) -> f64 {
    closest_to_origin_on_triangle(p[0] - x, p[1] - x, p[2] - x).length()
}

/// Whether triangle `p` lies farther than `reach` from `x` by its bounding box alone: true only
/// where [`triangle_distance`] exceeds `reach` too, so that a search passing over such triangles
/// keeps every one the exact distance keeps. No square root: the cull before that distance.
/// The box gap is a lower bound on the distance; the margin (1e-9 of the reach, 1e-12 of the
/// coordinates' size) covers the rounding of the exact distance (its closest point lies in the
/// box up to a few ulps of the coordinates).
#[inline]
pub fn beyond_box(x: DVec3, p: &[DVec3; 3], reach: f64) -> bool {
    let lo = p[0].min(p[1]).min(p[2]);
    let hi = p[0].max(p[1]).max(p[2]);
    let gap = (lo - x).max(x - hi).max(DVec3::ZERO);
    let scale = x.abs().max(lo.abs()).max(hi.abs()).max_element();
    let lim = reach * (1.0 + 1e-9) + 1e-12 * scale;
    gap.length_squared() > lim * lim
}

/// Bounding sphere of a triangle (centroid and the largest distance to a corner).
#[inline]
pub fn triangle_sphere(p: &[DVec3; 3]) -> (DVec3, f64) {
    let c = (p[0] + p[1] + p[2]) / 3.0;
    let r = c.distance(p[0]).max(c.distance(p[1])).max(c.distance(p[2]));
    (c, r)
}

/// What the randomised tests share.
#[cfg(test)]
pub(crate) mod testing {
    use glam::DVec3;

    /// Deterministic xorshift for the randomised tests.
    pub(crate) struct Rng(pub u64);
    impl Rng {
        /// Uniform in [0, 1).
        pub(crate) fn next(&mut self) -> f64 {
            self.0 ^= self.0 << 13;
            self.0 ^= self.0 >> 7;
            self.0 ^= self.0 << 17;
            (self.0 >> 11) as f64 / (1u64 << 53) as f64
        }
        pub(crate) fn sym(&mut self) -> f64 {
            2.0 * self.next() - 1.0
        }
        pub(crate) fn vec(&mut self) -> DVec3 {
            DVec3::new(self.sym(), self.sym(), self.sym())
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    use crate::geometry::testing::Rng;

    #[test]
    fn a_triangle_beyond_by_its_box_is_beyond_by_its_distance() {
        // Random triangles (some slivers, some far from the origin, where rounding is coarser)
        // and points; the reach set at the exact distance, a hair either side, and at random.
        // Wherever the box says beyond, the exact distance must exceed the reach; and the box
        // must pass over most triangles beyond twice their distance's reach.
        let mut rng = Rng(0xD1B54A32D192ED03);
        let (mut beyond, mut far, mut culled) = (0, 0, 0);
        for i in 0..40_000 {
            let offset = [0.0, 1e3, 1e6][i % 3] * DVec3::new(1.0, -0.5, 0.25);
            let a = offset + rng.vec();
            let (b, c) = if i % 5 == 0 { (a + rng.vec(), a + 1e-9 * rng.vec()) } else { (a + 0.3 * rng.vec(), a + 0.3 * rng.vec()) };
            let p = [a, b, c];
            let x = offset + 2.0 * rng.vec();
            let dist = triangle_distance(x, &p);
            for reach in [dist, dist * (1.0 - 1e-15), dist * (1.0 + 1e-15), 0.0, 3.0 * rng.next()] {
                if beyond_box(x, &p, reach) {
                    beyond += 1;
                    assert!(dist > reach, "triangle {i}: box beyond {reach}, distance {dist}");
                }
            }
            let reach = 0.5 * dist;
            if reach > 0.0 {
                far += 1;
                culled += usize::from(beyond_box(x, &p, reach));
            }
        }
        // Measured: 65,152 beyond, 39,822 of 40,000 culled at half the distance (bounds: 10 %
        // below the first, 97 % for the second).
        println!("{beyond} beyond, {culled} of {far} culled at half the distance");
        assert!(beyond > 58_600 && culled * 100 > far * 97, "{beyond} beyond, {culled} of {far} culled at half the distance");
    }

    //      P3
    //      | \        flat triangle in z = 0, all normals +z:
    //      |  \       x = (0.2, 0.3, 0.5) sits at d = 0.5 above bary (0.5, 0.2, 0.3)
    //      P1--P2
    #[test]
    fn flat_triangle_constant_normals_is_linear() {
        let p = [DVec3::ZERO, DVec3::X, DVec3::Y];
        let n = [DVec3::Z; 3];
        let x = DVec3::new(0.2, 0.3, 0.5);
        let c = cubic_coeffs(x, &p, &n);
        assert_eq!(c[3], 0.0);
        assert_eq!(c[2], 0.0);
        let h: Vec<_> = solve_shell(x, &p, &n, 1.0).iter().collect();
        assert_eq!(h.len(), 1);
        assert!((h[0].d - 0.5).abs() < 1e-12);
        let b = h[0].bary;
        assert!((b[0] - 0.5).abs() < 1e-12 && (b[1] - 0.2).abs() < 1e-12 && (b[2] - 0.3).abs() < 1e-12);
        // Out of range: d = 0.5 > dmax 0.4.
        assert_eq!(solve_shell(x, &p, &n, 0.4).n, 0);
        // Outside the triangle.
        assert_eq!(solve_shell(DVec3::new(0.8, 0.8, 0.1), &p, &n, 1.0).n, 0);
    }

    #[test]
    fn spreading_normals_give_quadratic_case() {
        // Two normals equal, one tilted: c3 = 0 (det of two equal columns), c2 ≠ 0.
        let p = [DVec3::ZERO, DVec3::X, DVec3::Y];
        let n = [DVec3::Z, DVec3::Z, DVec3::new(0.0, 0.6, 0.8)];
        let x = DVec3::new(0.1, 0.2, 0.3);
        let c = cubic_coeffs(x, &p, &n);
        assert!(c[3].abs() < 1e-15);
        let h: Vec<_> = solve_shell(x, &p, &n, 1.0).iter().collect();
        assert_eq!(h.len(), 1);
        let hit = h[0];
        let xr = interpolate_direction(&[p[0], p[1], p[2]], &hit.bary) + hit.d * interpolate_direction(&n, &hit.bary);
        assert!(xr.distance(x) < 1e-10, "reconstructed {xr:?} vs {x:?}");
    }

    #[test]
    fn point_on_shared_edge_found_by_both_triangles() {
        //  P3 ---- P4
        //  |  \  B  |     x lies above the diagonal P2–P3 of the square
        //  | A  \   |
        //  P1 ---- P2
        let p1 = DVec3::ZERO;
        let p2 = DVec3::X;
        let p3 = DVec3::Y;
        let p4 = DVec3::new(1.0, 1.0, 0.0);
        let n = [DVec3::Z; 3];
        let x = DVec3::new(0.5, 0.5, 0.1);
        assert_eq!(solve_shell(x, &[p1, p2, p3], &n, 1.0).n, 1);
        assert_eq!(solve_shell(x, &[p2, p4, p3], &n, 1.0).n, 1);
    }

    #[test]
    fn roots_within_a_range_are_the_full_search_roots_bit_for_bit() {
        // Cubics with roots spread, clustered (within 1e-9: merged), doubled (tangent) and near
        // the ends of the range; ranges around 0 and around a root. Each root inside the range
        // is the full search's to the bit, in the same place; a root left out lies outside it.
        let mut rng = Rng(99);
        let (mut left_out, mut kept) = (0, 0);
        for case in 0..20_000 {
            let r1 = rng.sym();
            let r2 = match case % 4 {
                0 => rng.sym(),
                1 => r1 + 1e-9 * (rng.sym()),
                2 => r1,
                _ => r1 + 1e-3 * rng.next(),
            };
            let r3 = if case % 3 == 0 { r2 + 2e-9 * rng.next() } else { 3.0 * rng.next() - 1.5 };
            let a = 0.5 + rng.next();
            // a(t − r1)(t − r2)(t − r3)
            let (s1, s2, s3) = (r1 + r2 + r3, r1 * r2 + r1 * r3 + r2 * r3, r1 * r2 * r3);
            let c = [-a * s3, a * s2, -a * s1, a];
            let mut full = [0.0; 3];
            let nf = cubic_roots_in_unit(&c, &mut full);
            let within = match case % 5 {
                0 => r1.abs(),
                1 => r2.abs() + 5e-10,
                2 => 1.5 * rng.next(),
                3 => 0.0,
                _ => r3.abs() - 1e-10,
            };
            // Around 0, and around a root (the window a crossing's Newton step solves in).
            let centre = [0.0, r2, r1 + 2e-9][case % 3];
            let (from, to) = (centre - within, centre + within);
            let mut part = [0.0; 3];
            let np = if case % 3 == 0 {
                cubic_roots_in_unit_within(&c, within, &mut part)
            } else {
                cubic_roots_in_unit_between(&c, from, to, &mut part)
            };
            assert_eq!(np, nf, "case {case}: {c:?}");
            for i in 0..nf {
                if part[i].is_nan() {
                    assert!(full[i] < from || full[i] > to, "case {case}: root {} left out, range {from}..{to}", full[i]);
                    left_out += 1;
                } else {
                    assert_eq!(part[i].to_bits(), full[i].to_bits(), "case {case}: {c:?}");
                    kept += 1;
                }
            }
        }
        // Measured: 6,796 roots left out, 39,434 kept (bounds 10 % below).
        assert!(left_out > 6_100 && kept > 35_400, "{left_out} left out, {kept} kept");
    }

    fn oracle_roots(x: DVec3, p: &[DVec3; 3], n: &[DVec3; 3], dmax: f64) -> Vec<f64> {
        // Brute force: sample det(d) densely, bisect every sign change.
        let f = |d: f64| {
            let q: Vec<DVec3> = (0..3).map(|i| p[i] + d * n[i] - x).collect();
            det3(q[0], q[1], q[2])
        };
        let steps = 4000;
        let mut roots = vec![];
        let mut prev_d = -dmax;
        let mut prev = f(prev_d);
        for i in 1..=steps {
            let d = -dmax + 2.0 * dmax * i as f64 / steps as f64;
            let v = f(d);
            if prev == 0.0 {
                roots.push(prev_d);
            } else if (prev < 0.0) != (v < 0.0) && v != 0.0 {
                let (mut lo, mut hi) = (prev_d, d);
                for _ in 0..200 {
                    let m = 0.5 * (lo + hi);
                    if (f(m) < 0.0) == (f(lo) < 0.0) {
                        lo = m;
                    } else {
                        hi = m;
                    }
                }
                roots.push(0.5 * (lo + hi));
            }
            prev = v;
            prev_d = d;
        }
        roots
    }

    #[test]
    fn random_triangles_match_brute_force_oracle() {
        let mut rng = Rng(0x9E3779B97F4A7C15);
        let mut compared = 0;
        let mut with_hits = 0;
        for _ in 0..5000 {
            let p = [rng.vec(), rng.vec(), rng.vec()];
            let fnrm = face_normal(p[0], p[1], p[2]);
            if fnrm == DVec3::ZERO {
                continue;
            }
            // Directions near the face normal, as on a real base mesh.
            let n = [
                (fnrm + 0.5 * rng.vec()).normalize(),
                (fnrm + 0.5 * rng.vec()).normalize(),
                (fnrm + 0.5 * rng.vec()).normalize(),
            ];
            let b = [rng.next(), rng.next(), rng.next()];
            let s = b[0] + b[1] + b[2];
            let bary = [b[0] / s, b[1] / s, b[2] / s];
            let d_true = 0.8 * rng.sym();
            let x = interpolate_direction(&p, &bary) + d_true * interpolate_direction(&n, &bary);
            let dmax = 1.0;
            let c = cubic_coeffs(x, &p, &n);
            let ct = [c[0], c[1] * dmax, c[2] * dmax * dmax, c[3] * dmax.powi(3)];
            let mut r = [0.0; 3];
            let nr = cubic_roots_in_unit(&ct, &mut r);
            let oracle = oracle_roots(x, &p, &n, dmax);
            // Every simple root the oracle sees, we see (double roots may be missed by sampling).
            for o in &oracle {
                assert!(
                    r[..nr].iter().any(|t| (t * dmax - o).abs() < 1e-7),
                    "oracle root {o} missing from {:?}",
                    &r[..nr]
                );
            }
            // The constructed solution is always found.
            let hits: Vec<_> = solve_shell(x, &p, &n, dmax).iter().collect();
            assert!(
                hits.iter().any(|h| (h.d - d_true).abs() < 1e-7),
                "true d {d_true} not in {hits:?}"
            );
            compared += 1;
            with_hits += hits.len();
        }
        assert!(compared > 4900 && with_hits >= compared);
    }

    #[test]
    fn constant_mode_projects_orthogonally() {
        let p = [DVec3::ZERO, DVec3::X, DVec3::Y];
        let h: Vec<_> = solve_constant(DVec3::new(0.25, 0.25, -0.3), &p, 1.0).iter().collect();
        assert_eq!(h.len(), 1);
        assert!((h[0].d + 0.3).abs() < 1e-12);
    }

    #[test]
    fn maxmin_direction_recovers_fold() {
        // Three normals around +z tilted so that their mean is fine, plus one facing sideways.
        let ns = [
            DVec3::new(0.0, 0.0, 1.0),
            DVec3::new(0.9, 0.0, 0.1).normalize(),
            DVec3::new(-0.2, 0.9, 0.1).normalize(),
        ];
        let (dir, m) = maxmin_direction(&ns).unwrap();
        assert!(m > 0.0);
        for n in ns {
            assert!(dir.dot(n) >= m - 1e-12);
        }
        // Opposite normals pinch: no direction sees both.
        assert!(maxmin_direction(&[DVec3::Z, -DVec3::Z]).is_none());
        assert!(maxmin_direction(&[DVec3::X, DVec3::Y, DVec3::Z, -DVec3::ONE.normalize()]).is_none());
    }

    #[test]
    fn vertex_direction_falls_back_when_mean_fails() {
        // A large face facing +x dominates the area-weighted mean; a small face facing -x·0.2+y.
        let big = DVec3::new(10.0, 0.0, 1.0);
        let small = DVec3::new(-0.5, 0.0, 0.05);
        let mean = (big + small).normalize();
        assert!(mean.dot(small) < 0.0);
        let dir = vertex_direction(&[big, small]);
        assert!(dir.dot(big) > 0.0 && dir.dot(small) > 0.0);
    }
}
