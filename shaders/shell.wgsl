// dispdec shell kernels: the f32 mirror of src/geometry.rs (cubic_coeffs .. solve_shell,
// solve_constant, condition4, triangle_distance) and of eval::find_primary.
//
// One invocation per query (a dense vertex of a candidate's neighbourhood, or a dense vertex of
// a whole validation). Functions keep the Rust names and order of operations. Where f32 cannot
// decide what f64 would (a barycentric coordinate near 0, a dot product of condition (4) near 0,
// |d| near dmax, a near-tangent root, two triangles within BAND_D of the same |d|), the answer
// is STATUS_BAND and the CPU decides that query in f64 (the tolerance band of the README).
//
// A search keeps its roots, hits and solutions in named scalars, never in a local array indexed
// by a value that differs between invocations (see Roots); the validator's BVH stack is the one
// such array.
//
// The constants (BARY_EPS, BAND_*, STATUS_*, ...) are generated from Rust and prepended:
// see gpu_eval::shell_source.

struct Tri {
    p0: vec4<f32>,
    p1: vec4<f32>,
    p2: vec4<f32>,
    n0: vec4<f32>,
    n1: vec4<f32>,
    n2: vec4<f32>,
    // Bounding sphere: centre xyz, radius w.
    sphere: vec4<f32>,
}

struct Query {
    x: vec3<f32>,
    vertex: u32,
    tri_start: u32,
    tri_count: u32,
    flags: u32,
    // Index in the range of the triangle to search first (the vertex's current face), or INVALID.
    hint: u32,
}

struct Answer {
    tri: u32,
    status: u32,
    d: f32,
    second: f32,
    bary: vec4<f32>,
}

// A BVH node: leaf when b has LEAF_BIT (first triangle a, count b & ~LEAF_BIT), else children a, b.
struct Node {
    lo: vec3<f32>,
    a: u32,
    hi: vec3<f32>,
    b: u32,
}

struct Params {
    dmax: f32,
    mode: u32,
    query_count: u32,
    node_count: u32,
}

@group(0) @binding(0) var<uniform> params: Params;
@group(0) @binding(1) var<storage, read> tris: array<Tri>;
@group(0) @binding(2) var<storage, read> queries: array<Query>;
@group(0) @binding(3) var<storage, read> dense_normals: array<vec4<f32>>;
@group(0) @binding(4) var<storage, read> vf_start: array<u32>;
@group(0) @binding(5) var<storage, read> vf: array<u32>;
@group(0) @binding(6) var<storage, read> nodes: array<Node>;
@group(0) @binding(7) var<storage, read_write> answers: array<Answer>;

fn det3(a: vec3<f32>, b: vec3<f32>, c: vec3<f32>) -> f32 {
    return dot(a, cross(b, c));
}

fn cubic_coeffs(x: vec3<f32>, t: Tri) -> vec4<f32> {
    let a1 = t.p0.xyz - x;
    let a2 = t.p1.xyz - x;
    let a3 = t.p2.xyz - x;
    let n1 = t.n0.xyz;
    let n2 = t.n1.xyz;
    let n3 = t.n2.xyz;
    let c0 = det3(a1, a2, a3);
    let c1 = det3(n1, a2, a3) + det3(a1, n2, a3) + det3(a1, a2, n3);
    let c2 = det3(a1, n2, n3) + det3(n1, a2, n3) + det3(n1, n2, a3);
    let c3 = det3(n1, n2, n3);
    return vec4<f32>(c0, c1, c2, c3);
}

fn poly_eval(c: vec4<f32>, t: f32) -> f32 {
    return ((c.w * t + c.z) * t + c.y) * t + c.x;
}

struct Quadratic {
    n: u32,
    r0: f32,
    r1: f32,
}

fn quadratic_roots(a: f32, b: f32, c: f32) -> Quadratic {
    var out = Quadratic(0u, 0.0, 0.0);
    let scale = max(abs(a), max(abs(b), abs(c)));
    if (scale == 0.0) {
        return out;
    }
    if (abs(a) <= QUADRATIC_FLAT * scale) {
        if (abs(b) <= QUADRATIC_FLAT * scale) {
            return out;
        }
        out.n = 1u;
        out.r0 = -c / b;
        return out;
    }
    let disc = b * b - 4.0 * a * c;
    if (disc < 0.0) {
        return out;
    }
    let sq = sqrt(disc);
    var sb = 1.0;
    if (b < 0.0) {
        sb = -1.0;
    }
    let q = -0.5 * (b + sb * sq);
    var r0 = 0.0;
    var r1 = 0.0;
    if (q != 0.0) {
        r0 = q / a;
        r1 = c / q;
    }
    out.n = 2u;
    out.r0 = min(r0, r1);
    out.r1 = max(r0, r1);
    return out;
}

fn polish_root(c: vec4<f32>, lo_in: f32, hi_in: f32, flo: f32, fhi: f32) -> f32 {
    var lo = lo_in;
    var hi = hi_in;
    if (flo == 0.0) {
        return lo;
    }
    if (fhi == 0.0) {
        return hi;
    }
    let rising = fhi > 0.0;
    var t = (lo * fhi - hi * flo) / (fhi - flo);
    if (!(t > lo && t < hi)) {
        t = 0.5 * (lo + hi);
    }
    for (var i = 0u; i < POLISH_ITERATIONS; i++) {
        let f = poly_eval(c, t);
        if (f == 0.0) {
            return t;
        }
        if ((f > 0.0) == rising) {
            hi = t;
        } else {
            lo = t;
        }
        let df = (3.0 * c.w * t + 2.0 * c.z) * t + c.y;
        var tn = 0.5 * (lo + hi);
        if (df != 0.0) {
            let newton = t - f / df;
            if (newton > lo && newton < hi) {
                tn = newton;
            }
        }
        let step = abs(tn - t);
        t = tn;
        if (step <= F32_ROOT_TOL || hi - lo <= F32_ROOT_TOL) {
            break;
        }
    }
    return t;
}

// Roots in t ∈ [-T_END, T_END] (T_END = 1 + BAND_T: roots just past dmax are reported so that
// the caller can mark them), ascending, with the smallest |t| of a near-tangent critical point.
// (Scalars, not an array: a local array indexed by a varying index costs a loop over the lanes
// on a CPU adapter such as lavapipe, and local memory on a GPU.)
struct Roots {
    n: u32,
    r0: f32,
    r1: f32,
    r2: f32,
    tangent: f32,
}

// Root i (< n) of `roots`.
fn root_at(roots: Roots, i: u32) -> f32 {
    if (i == 0u) {
        return roots.r0;
    }
    if (i == 1u) {
        return roots.r1;
    }
    return roots.r2;
}

fn push_root(roots: ptr<function, Roots>, r: f32) {
    let n = (*roots).n;
    if (n > 0u && abs(r - root_at(*roots, n - 1u)) <= F32_ROOT_DEDUP) {
        return;
    }
    if (n == 0u) {
        (*roots).r0 = r;
    } else if (n == 1u) {
        (*roots).r1 = r;
    } else if (n == 2u) {
        (*roots).r2 = r;
    }
    if (n < 3u) {
        (*roots).n = n + 1u;
    }
}

// One monotone piece [lo, hi] of the normalised cubic (values flo, fhi): its root, if any; a
// piece that starts at a critical point (not the first) notes a near-tangent contact.
fn root_piece(roots: ptr<function, Roots>, c: vec4<f32>, lo: f32, hi: f32, flo: f32, fhi: f32, first: bool) {
    if (!first && abs(flo) <= BAND_TANGENT) {
        // Near-tangent contact: f64 may see a double root here, or none, or two.
        (*roots).tangent = min((*roots).tangent, abs(lo));
    }
    if (flo == 0.0) {
        push_root(roots, lo);
        return;
    }
    if ((flo < 0.0) != (fhi < 0.0) || fhi == 0.0) {
        push_root(roots, polish_root(c, lo, hi, flo, fhi));
    }
}

fn cubic_roots_in_unit(c_in: vec4<f32>) -> Roots {
    var roots = Roots(0u, 0.0, 0.0, 0.0, F32_INF);
    let scale = max(max(abs(c_in.x), abs(c_in.y)), max(abs(c_in.z), abs(c_in.w)));
    if (!(scale > 0.0) || scale > F32_MAX) {
        return roots;
    }
    let c = c_in / scale;
    let crit = quadratic_roots(3.0 * c.w, 2.0 * c.z, c.y);
    // The pieces between -T_END, the critical points inside, and T_END.
    var lo = -T_END;
    var flo = poly_eval(c, lo);
    var first = true;
    if (crit.n >= 1u && crit.r0 > -T_END && crit.r0 < T_END) {
        let fhi = poly_eval(c, crit.r0);
        root_piece(&roots, c, lo, crit.r0, flo, fhi, first);
        lo = crit.r0;
        flo = fhi;
        first = false;
    }
    if (crit.n >= 2u && crit.r1 > -T_END && crit.r1 < T_END) {
        let fhi = poly_eval(c, crit.r1);
        root_piece(&roots, c, lo, crit.r1, flo, fhi, first);
        lo = crit.r1;
        flo = fhi;
        first = false;
    }
    root_piece(&roots, c, lo, T_END, flo, poly_eval(c, T_END), first);
    return roots;
}

// Barycentric coordinates of x in (q0, q1, q2); w = 1 when the triangle is degenerate in f32's
// eyes (then f64 must decide), else 0.
fn barycentric(x: vec3<f32>, q0: vec3<f32>, q1: vec3<f32>, q2: vec3<f32>) -> vec4<f32> {
    let nq = cross(q1 - q0, q2 - q0);
    let nn = dot(nq, nq);
    let e = max(dot(q1 - q0, q1 - q0), dot(q2 - q0, q2 - q0));
    if (!(nn > BAND_DEGENERATE * e * e)) {
        return vec4<f32>(0.0, 0.0, 0.0, 1.0);
    }
    let a = dot(cross(q1 - x, q2 - x), nq) / nn;
    let b = dot(cross(q2 - x, q0 - x), nq) / nn;
    let c = dot(cross(q0 - x, q1 - x), nq) / nn;
    return vec4<f32>(a, b, c, 0.0);
}

fn clamp_bary(b: vec3<f32>) -> vec3<f32> {
    let a = max(b, vec3<f32>(0.0));
    let s = a.x + a.y + a.z;
    if (s > 0.0) {
        return a / s;
    }
    return vec3<f32>(1.0 / 3.0);
}

// Up to three hits of one triangle (barycentrics xyz, d in w), and the smallest |d| of an event
// f32 cannot decide. (Scalars, not arrays: see Roots.)
struct Hits {
    n: u32,
    h0: vec4<f32>,
    h1: vec4<f32>,
    h2: vec4<f32>,
    marginal: f32,
}

fn no_hits() -> Hits {
    return Hits(0u, vec4<f32>(0.0), vec4<f32>(0.0), vec4<f32>(0.0), F32_INF);
}

// Hit i (< n) of `hits`: barycentrics xyz, d in w.
fn hit_at(hits: Hits, i: u32) -> vec4<f32> {
    if (i == 0u) {
        return hits.h0;
    }
    if (i == 1u) {
        return hits.h1;
    }
    return hits.h2;
}

// Classifies one candidate solution (d, raw barycentrics) as f64 would, noting undecidable ones.
fn push_hit(hits: ptr<function, Hits>, d: f32, b: vec4<f32>, dmax: f32) {
    let ad = abs(d);
    if (b.w != 0.0) {
        (*hits).marginal = min((*hits).marginal, ad);
        return;
    }
    let mb = min(b.x, min(b.y, b.z));
    if (mb < -BAND_BARY) {
        return;
    }
    if (mb < BAND_BARY || ad > dmax * (1.0 - BAND_T)) {
        (*hits).marginal = min((*hits).marginal, ad);
    }
    if (mb >= -BARY_EPS && ad <= dmax && (*hits).n < 3u) {
        let n = (*hits).n;
        let h = vec4<f32>(clamp_bary(b.xyz), d);
        if (n == 0u) {
            (*hits).h0 = h;
        } else if (n == 1u) {
            (*hits).h1 = h;
        } else {
            (*hits).h2 = h;
        }
        (*hits).n = n + 1u;
    }
}

fn solve_shell(x: vec3<f32>, t: Tri, dmax: f32) -> Hits {
    var hits = no_hits();
    let c = cubic_coeffs(x, t);
    let s = dmax;
    let ct = vec4<f32>(c.x, c.y * s, c.z * s * s, c.w * s * s * s);
    let roots = cubic_roots_in_unit(ct);
    if (roots.tangent < F32_INF) {
        hits.marginal = roots.tangent * s;
    }
    for (var i = 0u; i < roots.n; i++) {
        let d = root_at(roots, i) * s;
        let q0 = t.p0.xyz + d * t.n0.xyz;
        let q1 = t.p1.xyz + d * t.n1.xyz;
        let q2 = t.p2.xyz + d * t.n2.xyz;
        push_hit(&hits, d, barycentric(x, q0, q1, q2), dmax);
    }
    return hits;
}

fn face_normal(t: Tri) -> vec3<f32> {
    let cr = cross(t.p1.xyz - t.p0.xyz, t.p2.xyz - t.p0.xyz);
    let l = length(cr);
    if (l > 0.0) {
        return cr / l;
    }
    return vec3<f32>(0.0);
}

fn solve_constant(x: vec3<f32>, t: Tri, dmax: f32) -> Hits {
    var hits = no_hits();
    let nf = face_normal(t);
    if (all(nf == vec3<f32>(0.0))) {
        return hits;
    }
    let d = dot(x - t.p0.xyz, nf);
    if (abs(d) > dmax * (1.0 + BAND_T)) {
        return hits;
    }
    let xp = x - d * nf;
    push_hit(&hits, d, barycentric(xp, t.p0.xyz, t.p1.xyz, t.p2.xyz), dmax);
    return hits;
}

fn interpolate_direction(n0: vec3<f32>, n1: vec3<f32>, n2: vec3<f32>, b: vec3<f32>) -> vec3<f32> {
    return b.x * n0 + b.y * n1 + b.z * n2;
}

fn direction_at(t: Tri, b: vec3<f32>) -> vec3<f32> {
    if (params.mode == MODE_CONSTANT) {
        return face_normal(t);
    }
    return interpolate_direction(t.n0.xyz, t.n1.xyz, t.n2.xyz, b);
}

// Condition (4) as a margin: the smallest N·n_i over the vertex's incident dense faces.
fn condition4(dir: vec3<f32>, vertex: u32) -> f32 {
    var m = F32_INF;
    for (var k = vf_start[vertex]; k < vf_start[vertex + 1u]; k++) {
        m = min(m, dot(dir, dense_normals[vf[k]].xyz));
    }
    return m;
}

// Closest point to the origin on triangle (a, b, c) (Ericson), as in geometry.rs.
fn closest_to_origin_on_triangle(a: vec3<f32>, b: vec3<f32>, c: vec3<f32>) -> vec3<f32> {
    let ab = b - a;
    let ac = c - a;
    let ap = -a;
    let d1 = dot(ab, ap);
    let d2 = dot(ac, ap);
    if (d1 <= 0.0 && d2 <= 0.0) {
        return a;
    }
    let bp = -b;
    let d3 = dot(ab, bp);
    let d4 = dot(ac, bp);
    if (d3 >= 0.0 && d4 <= d3) {
        return b;
    }
    let vc = d1 * d4 - d3 * d2;
    if (vc <= 0.0 && d1 >= 0.0 && d3 <= 0.0) {
        return a + (d1 / (d1 - d3)) * ab;
    }
    let cp = -c;
    let d5 = dot(ab, cp);
    let d6 = dot(ac, cp);
    if (d6 >= 0.0 && d5 <= d6) {
        return c;
    }
    let vb = d5 * d2 - d1 * d6;
    if (vb <= 0.0 && d2 >= 0.0 && d6 <= 0.0) {
        return a + (d2 / (d2 - d6)) * ac;
    }
    let va = d3 * d6 - d5 * d4;
    if (va <= 0.0 && (d4 - d3) >= 0.0 && (d5 - d6) >= 0.0) {
        return b + ((d4 - d3) / ((d4 - d3) + (d5 - d6))) * (c - b);
    }
    let denom = 1.0 / (va + vb + vc);
    return a + ab * (vb * denom) + ac * (vc * denom);
}

fn triangle_distance(x: vec3<f32>, t: Tri) -> f32 {
    return length(closest_to_origin_on_triangle(t.p0.xyz - x, t.p1.xyz - x, t.p2.xyz - x));
}

// The state of one primary search (eval::find_primary): the best hit, the smallest |d| on any
// other triangle, the smallest |d| of an undecidable event, and (strict) the distinct solutions.
struct Search {
    best_tri: u32,
    best_d: f32,
    best_abs: f32,
    second: f32,
    marginal: f32,
    count: u32,
    close: u32,
    best_bary: vec3<f32>,
    // The first four distinct solutions (strict), as scalars (see Roots).
    found0: vec3<f32>,
    found1: vec3<f32>,
    found2: vec3<f32>,
    found3: vec3<f32>,
}

// Whether strict search `s` already holds the solution at image point p (one of its first
// four, within BAND_POS·dmax).
fn found_before(s: ptr<function, Search>, p: vec3<f32>) -> bool {
    let n = (*s).count;
    let near = BAND_POS * params.dmax;
    return (n > 0u && distance((*s).found0, p) <= near) || (n > 1u && distance((*s).found1, p) <= near)
        || (n > 2u && distance((*s).found2, p) <= near) || (n > 3u && distance((*s).found3, p) <= near);
}

fn search_limit(s: ptr<function, Search>, strict: bool) -> f32 {
    if (strict || (*s).best_tri == INVALID) {
        return params.dmax * (1.0 + BAND_T);
    }
    return (*s).best_abs + BAND_D * params.dmax;
}

fn visit_triangle(s: ptr<function, Search>, x: vec3<f32>, q: Query, ti: u32) {
    let strict = (q.flags & FLAG_STRICT) != 0u;
    let check4 = (q.flags & FLAG_CHECK4) != 0u;
    let limit = search_limit(s, strict);
    let slack = BAND_D * params.dmax;
    // The sphere alone first: most triangles go no further.
    let sphere = tris[ti].sphere;
    if (distance(x, sphere.xyz) - sphere.w - slack > limit) {
        return;
    }
    let t = tris[ti];
    if (triangle_distance(x, t) - slack > limit) {
        return;
    }
    var hits: Hits;
    if (params.mode == MODE_CONSTANT) {
        hits = solve_constant(x, t, params.dmax);
    } else {
        hits = solve_shell(x, t, params.dmax);
    }
    (*s).marginal = min((*s).marginal, hits.marginal);
    for (var i = 0u; i < hits.n; i++) {
        let h = hit_at(hits, i);
        let d = h.w;
        let ad = abs(d);
        let b = h.xyz;
        if (check4) {
            let dir = direction_at(t, b);
            let m = condition4(dir, q.vertex);
            if (abs(m) <= BAND_DOT * length(dir)) {
                (*s).marginal = min((*s).marginal, ad);
            }
            if (!(m > 0.0)) {
                continue;
            }
        }
        if (strict) {
            let p = interpolate_direction(t.p0.xyz, t.p1.xyz, t.p2.xyz, b);
            if (found_before(s, p)) {
                (*s).close = 1u;
            } else {
                let n = (*s).count;
                if (n == 0u) {
                    (*s).found0 = p;
                } else if (n == 1u) {
                    (*s).found1 = p;
                } else if (n == 2u) {
                    (*s).found2 = p;
                } else if (n == 3u) {
                    (*s).found3 = p;
                }
                (*s).count = n + 1u;
            }
        }
        if ((*s).best_tri == INVALID) {
            (*s).best_tri = ti;
            (*s).best_d = d;
            (*s).best_abs = ad;
            (*s).best_bary = b;
        } else if (ti == (*s).best_tri) {
            if (ad < (*s).best_abs) {
                (*s).best_d = d;
                (*s).best_abs = ad;
                (*s).best_bary = b;
            }
        } else if (ad < (*s).best_abs) {
            (*s).second = min((*s).second, (*s).best_abs);
            (*s).best_tri = ti;
            (*s).best_d = d;
            (*s).best_abs = ad;
            (*s).best_bary = b;
        } else {
            (*s).second = min((*s).second, ad);
        }
    }
}

fn new_search() -> Search {
    var s: Search;
    s.best_tri = INVALID;
    s.best_d = 0.0;
    s.best_abs = F32_INF;
    s.second = F32_INF;
    s.marginal = F32_INF;
    s.count = 0u;
    s.close = 0u;
    s.best_bary = vec3<f32>(0.0);
    return s;
}

// The answer of a finished search: a hit f64 would choose too, none, ambiguous, or the band.
fn finish_search(s: ptr<function, Search>, strict: bool) -> Answer {
    var a = Answer(INVALID, STATUS_NONE, (*s).best_d, (*s).second, vec4<f32>((*s).best_bary, 0.0));
    let band = BAND_D * params.dmax;
    // Marginal events are only ever recorded at |d| <= T_END·dmax.
    let any_marginal = (*s).marginal <= T_END * params.dmax;
    if (strict) {
        if (any_marginal || (*s).close != 0u) {
            a.status = STATUS_BAND_MARGINAL;
            return a;
        }
        if ((*s).count >= 2u) {
            a.status = STATUS_AMBIGUOUS;
            return a;
        }
    }
    if ((*s).best_tri == INVALID) {
        if (any_marginal) {
            a.status = STATUS_BAND_MARGINAL;
        }
        return a;
    }
    a.tri = (*s).best_tri;
    if ((*s).second <= (*s).best_abs + band) {
        a.status = STATUS_BAND_TIE;
    } else if ((*s).marginal <= (*s).best_abs + band) {
        a.status = STATUS_BAND_MARGINAL;
    } else {
        a.status = STATUS_HIT;
    }
    return a;
}

// Candidate batches: each query searches its own range of triangles (a candidate's collapsed
// neighbourhood); the answer's triangle is an index into that range.
@compute @workgroup_size(WORKGROUP_SIZE)
fn evaluate_candidates(@builtin(global_invocation_id) gid: vec3<u32>) {
    let i = gid.x;
    if (i >= params.query_count) {
        return;
    }
    let q = queries[i];
    var s = new_search();
    // The hinted triangle first: its hit usually is the primary, and then the bound culls
    // nearly every other triangle before any cubic is solved.
    if (q.hint < q.tri_count) {
        visit_triangle(&s, q.x, q, q.tri_start + q.hint);
    }
    let end = q.tri_start + q.tri_count;
    for (var t = q.tri_start; t < end; t++) {
        if (t - q.tri_start != q.hint) {
            visit_triangle(&s, q.x, q, t);
        }
    }
    var a = finish_search(&s, (q.flags & FLAG_STRICT) != 0u);
    if (a.tri != INVALID) {
        a.tri -= q.tri_start;
    }
    answers[i] = a;
}

// Validation: each query searches the whole base through the BVH, nearer child first, pruning
// boxes farther than the search limit (a lower bound on |d|, as on the CPU).
@compute @workgroup_size(WORKGROUP_SIZE)
fn project_vertices(@builtin(global_invocation_id) gid: vec3<u32>) {
    let i = gid.x;
    if (i >= params.query_count) {
        return;
    }
    let q = queries[i];
    var s = new_search();
    let strict = (q.flags & FLAG_STRICT) != 0u;
    var stack: array<u32, BVH_STACK>;
    var top = 0u;
    if (params.node_count > 0u) {
        stack[0] = 0u;
        top = 1u;
    }
    let slack = BAND_D * params.dmax;
    while (top > 0u) {
        top -= 1u;
        let node = nodes[stack[top]];
        let gap = distance(clamp(q.x, node.lo, node.hi), q.x);
        if (gap - slack > search_limit(&s, strict)) {
            continue;
        }
        if ((node.b & LEAF_BIT) != 0u) {
            let end = node.a + (node.b & ~LEAF_BIT);
            for (var t = node.a; t < end; t++) {
                visit_triangle(&s, q.x, q, t);
            }
        } else if (top + 2u <= BVH_STACK) {
            // Push the farther child first so that the nearer one is searched first.
            let na = nodes[node.a];
            let nb = nodes[node.b];
            let ga = distance(clamp(q.x, na.lo, na.hi), q.x);
            let gb = distance(clamp(q.x, nb.lo, nb.hi), q.x);
            if (ga <= gb) {
                stack[top] = node.b;
                stack[top + 1u] = node.a;
            } else {
                stack[top] = node.a;
                stack[top + 1u] = node.b;
            }
            top += 2u;
        } else {
            // Deeper than the stack (cannot happen for a median-split BVH of < 2^60 leaves):
            // give the query to the CPU rather than answer wrongly.
            s.marginal = 0.0;
        }
    }
    answers[i] = finish_search(&s, strict);
}
