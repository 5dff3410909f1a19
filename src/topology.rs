//! Half-edge topology on flat `u32` arrays (a corner table), with boundaries, the link
//! condition and edge collapse.
//!
//! Half-edge `h` lives in face `h / 3` and runs from `corner[h]` to `corner[next(h)]`;
//! `opp[h]` is the half-edge running the other way in the neighbouring face, or [`INVALID`]
//! on a boundary. A deleted face has `corner[3f] == INVALID`.

use std::collections::HashMap;

/// The sentinel for "no half-edge / no vertex / deleted".
pub const INVALID: u32 = u32::MAX;

#[inline]
pub fn next(h: u32) -> u32 {
    if h % 3 == 2 {
        h - 2
    } else {
        h + 1
    }
}
#[inline]
pub fn prev(h: u32) -> u32 {
    if h % 3 == 0 {
        h + 2
    } else {
        h - 1
    }
}
#[inline]
pub fn face_of(h: u32) -> u32 {
    h / 3
}

/// Why an input mesh is not a manifold surface we can decimate.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum TopologyError {
    /// More than two faces share an edge.
    NonManifoldEdge { a: u32, b: u32, faces: Vec<u32> },
    /// Two faces traverse an edge in the same direction.
    InconsistentWinding { a: u32, b: u32, faces: [u32; 2] },
    /// A vertex whose faces form more than one fan (a "bow tie").
    NonManifoldVertex { v: u32 },
}

impl std::fmt::Display for TopologyError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            TopologyError::NonManifoldEdge { a, b, faces } => write!(
                f,
                "non-manifold edge ({a}, {b}): shared by {} faces (faces {:?})",
                faces.len(),
                faces
            ),
            TopologyError::InconsistentWinding { a, b, faces } => write!(
                f,
                "inconsistent winding: faces {} and {} both traverse edge ({a} -> {b}) in the same direction",
                faces[0], faces[1]
            ),
            TopologyError::NonManifoldVertex { v } => {
                write!(f, "non-manifold vertex {v}: its faces form more than one fan")
            }
        }
    }
}

#[derive(Clone, Debug, Default)]
pub struct Topology {
    pub corner: Vec<u32>,
    pub opp: Vec<u32>,
    /// One outgoing half-edge per vertex, INVALID for isolated or removed vertices.
    pub vert_he: Vec<u32>,
}

impl Topology {
    /// Builds the corner table of a triangle list; fails on non-manifold edges or vertices and
    /// on inconsistent winding.
    pub fn build(num_vertices: usize, faces: &[[u32; 3]]) -> Result<Topology, TopologyError> {
        let nh = faces.len() * 3;
        let mut corner = Vec::with_capacity(nh);
        for f in faces {
            corner.extend_from_slice(f);
        }
        let key = |a: u32, b: u32| ((a as u64) << 32) | b as u64;
        // An edge with more than two faces is non-manifold whatever their winding: check that
        // first, reporting the one whose first face comes first.
        let mut undirected: Vec<(u64, u32)> = (0..nh as u32)
            .map(|h| {
                let (a, b) = (corner[h as usize], corner[next(h) as usize]);
                (key(a.min(b), a.max(b)), face_of(h))
            })
            .collect();
        undirected.sort_unstable();
        let mut worst: Option<(u64, Vec<u32>)> = None;
        for run in undirected.chunk_by(|x, y| x.0 == y.0) {
            if run.len() > 2 {
                let fs: Vec<u32> = run.iter().map(|x| x.1).collect();
                if worst.as_ref().is_none_or(|w| fs[0] < w.1[0]) {
                    worst = Some((run[0].0, fs));
                }
            }
        }
        if let Some((k, fs)) = worst {
            return Err(TopologyError::NonManifoldEdge { a: (k >> 32) as u32, b: k as u32, faces: fs });
        }
        let mut opp = vec![INVALID; nh];
        let mut directed: HashMap<u64, u32> = HashMap::with_capacity(nh);
        for h in 0..nh as u32 {
            let (a, b) = (corner[h as usize], corner[next(h) as usize]);
            if let Some(&other) = directed.get(&key(a, b)) {
                return Err(TopologyError::InconsistentWinding {
                    a,
                    b,
                    faces: [face_of(other), face_of(h)],
                });
            }
            directed.insert(key(a, b), h);
        }
        for h in 0..nh as u32 {
            let (a, b) = (corner[h as usize], corner[next(h) as usize]);
            if let Some(&o) = directed.get(&key(b, a)) {
                opp[h as usize] = o;
            }
        }
        let mut vert_he = vec![INVALID; num_vertices];
        let mut outgoing_count = vec![0u32; num_vertices];
        for h in 0..nh as u32 {
            let v = corner[h as usize] as usize;
            outgoing_count[v] += 1;
            if vert_he[v] == INVALID {
                vert_he[v] = h;
            }
        }
        let topo = Topology { corner, opp, vert_he };
        let mut fan = Vec::new();
        for v in 0..num_vertices as u32 {
            if topo.vert_he[v as usize] == INVALID {
                continue;
            }
            topo.outgoing(v, &mut fan);
            if fan.len() != outgoing_count[v as usize] as usize {
                return Err(TopologyError::NonManifoldVertex { v });
            }
        }
        Ok(topo)
    }

    /// Whether face `f` has an edge on a boundary (an edge no other face shares).
    #[inline]
    pub fn face_on_boundary(&self, f: u32) -> bool {
        (3 * f..3 * f + 3).any(|h| self.opp[h as usize] == INVALID)
    }

    #[inline]
    pub fn num_faces_total(&self) -> usize {
        self.corner.len() / 3
    }
    #[inline]
    pub fn face_alive(&self, f: u32) -> bool {
        self.corner[3 * f as usize] != INVALID
    }
    #[inline]
    pub fn face(&self, f: u32) -> [u32; 3] {
        let i = 3 * f as usize;
        [self.corner[i], self.corner[i + 1], self.corner[i + 2]]
    }
    #[inline]
    pub fn from(&self, h: u32) -> u32 {
        self.corner[h as usize]
    }
    #[inline]
    pub fn to(&self, h: u32) -> u32 {
        self.corner[next(h) as usize]
    }

    /// The outgoing half-edges of `v`, walking the fan both ways from `vert_he[v]`.
    pub fn outgoing(&self, v: u32, out: &mut Vec<u32>) {
        out.clear();
        self.find_outgoing(v, |h| {
            out.push(h);
            false
        });
    }

    /// The first outgoing half-edge of `v` that `pred` holds for, in the order of
    /// [`Topology::outgoing`], without collecting them.
    pub fn find_outgoing(&self, v: u32, mut pred: impl FnMut(u32) -> bool) -> Option<u32> {
        let start = self.vert_he[v as usize];
        if start == INVALID {
            return None;
        }
        if pred(start) {
            return Some(start);
        }
        // Forward: rot(h) = opp(prev(h)).
        let mut h = start;
        loop {
            let o = self.opp[prev(h) as usize];
            if o == INVALID {
                break;
            }
            if o == start {
                return None; // closed fan
            }
            if pred(o) {
                return Some(o);
            }
            h = o;
        }
        // Hit a boundary: walk backwards from start: rot_back(h) = next(opp(h)).
        let mut h = start;
        loop {
            let o = self.opp[h as usize];
            if o == INVALID {
                return None;
            }
            let n = next(o);
            if pred(n) {
                return Some(n);
            }
            h = n;
        }
    }

    /// Whether `v` lies on a boundary.
    pub fn is_boundary_vertex(&self, v: u32, scratch: &mut Vec<u32>) -> bool {
        self.outgoing(v, scratch);
        scratch.iter().any(|&h| self.opp[h as usize] == INVALID || self.opp[prev(h) as usize] == INVALID)
    }

    /// Neighbouring vertices of `v` (one per outgoing half-edge, plus the far end of a
    /// boundary fan).
    pub fn neighbours(&self, v: u32, scratch: &mut Vec<u32>, out: &mut Vec<u32>) {
        self.outgoing(v, scratch);
        out.clear();
        for &h in scratch.iter() {
            out.push(self.to(h));
            let p = prev(h);
            if self.opp[p as usize] == INVALID {
                out.push(self.from(p));
            }
        }
        out.sort_unstable();
        out.dedup();
    }

    /// Faces around `v`.
    pub fn faces_around(&self, v: u32, scratch: &mut Vec<u32>, out: &mut Vec<u32>) {
        self.outgoing(v, scratch);
        out.clear();
        out.extend(scratch.iter().map(|&h| face_of(h)));
    }

    /// Finds the half-edge from `a` to `b`, if any.
    pub fn find_half_edge(&self, a: u32, b: u32, scratch: &mut Vec<u32>) -> Option<u32> {
        self.outgoing(a, scratch);
        scratch.iter().copied().find(|&h| self.to(h) == b)
    }

    /// Length (in edges) of the boundary loop through boundary half-edge `h` (opp[h] == INVALID),
    /// counted up to `max` + 1 (the decimator asks only whether a loop is a triangle; a scan's
    /// outer boundary runs to thousands of edges).
    pub fn boundary_loop_len(&self, h: u32, max: usize, scratch: &mut Vec<u32>) -> usize {
        let mut len = 0;
        let mut cur = h;
        loop {
            len += 1;
            // Next boundary half-edge: leaves to(cur); the outgoing half-edge of to(cur) whose
            // opp is INVALID.
            let v = self.to(cur);
            self.outgoing(v, scratch);
            let nb = scratch.iter().copied().find(|&g| self.opp[g as usize] == INVALID);
            match nb {
                Some(g) if g != h => cur = g,
                _ => break,
            }
            if len > self.corner.len().min(max) {
                break;
            }
        }
        len
    }

    /// Collapses the edge of half-edge `h` (u → w), keeping `u` and removing `w`; the faces on
    /// both sides of the edge are deleted. The caller checks [`Topology::link_condition`]
    /// first. Returns the deleted faces.
    pub fn collapse(&mut self, h: u32) -> [u32; 2] {
        let u = self.from(h);
        let w = self.to(h);
        let mut fan_w = Vec::new();
        self.outgoing(w, &mut fan_w);
        let ho = self.opp[h as usize];
        let mut removed = [INVALID; 2];
        let mut repair: Vec<u32> = Vec::with_capacity(4);
        // Relabel w's corners to u.
        for &g in &fan_w {
            self.corner[g as usize] = u;
        }
        for (slot, he) in [h, ho].into_iter().enumerate() {
            if he == INVALID {
                continue;
            }
            let n = next(he);
            let p = prev(he);
            let on = self.opp[n as usize];
            let op = self.opp[p as usize];
            if on != INVALID {
                self.opp[on as usize] = op;
            }
            if op != INVALID {
                self.opp[op as usize] = on;
            }
            repair.extend([on, op]);
            let f = face_of(he);
            for i in 0..3 {
                self.corner[3 * f as usize + i] = INVALID;
                self.opp[3 * f as usize + i] = INVALID;
            }
            removed[slot] = f;
        }
        self.vert_he[w as usize] = INVALID;
        // Re-seat vert_he of every vertex of the glued edges onto a live half-edge.
        for &g in &repair {
            if g == INVALID || !self.face_alive(face_of(g)) {
                continue;
            }
            for he in [g, next(g), prev(g)] {
                let v = self.from(he) as usize;
                let cur = self.vert_he[v];
                if cur == INVALID || !self.face_alive(face_of(cur)) || self.corner[cur as usize] as usize != v {
                    self.vert_he[v] = he;
                }
            }
        }
        // u may still point at a deleted face when both glued edges were boundaries.
        let cur = self.vert_he[u as usize];
        if cur == INVALID || !self.face_alive(face_of(cur)) || self.corner[cur as usize] != u {
            let replacement = fan_w
                .iter()
                .copied()
                .find(|&g| self.face_alive(face_of(g)) && self.corner[g as usize] == u);
            self.vert_he[u as usize] = replacement.unwrap_or(INVALID);
        }
        removed
    }
}

/// Union–find over `0..n`; a class is named by its lowest member, so results do not depend on
/// the order of the joins.
pub struct DisjointSets {
    parent: Vec<u32>,
}

impl DisjointSets {
    pub fn new(n: usize) -> DisjointSets {
        DisjointSets { parent: (0..n as u32).collect() }
    }

    pub fn find(&mut self, mut x: u32) -> u32 {
        while self.parent[x as usize] != x {
            self.parent[x as usize] = self.parent[self.parent[x as usize] as usize];
            x = self.parent[x as usize];
        }
        x
    }

    pub fn join(&mut self, a: u32, b: u32) {
        let (ra, rb) = (self.find(a), self.find(b));
        if ra != rb {
            self.parent[ra.max(rb) as usize] = ra.min(rb);
        }
    }
}

/// (genus, boundary loops) from the Euler characteristic; the genus is summed over the
/// components (each has chi = 2 - 2g - b).
pub fn topology_summary(nv: usize, faces: &[[u32; 3]]) -> (i64, usize) {
    let topo = Topology::build(nv, faces).expect("base mesh stays manifold");
    let mut seen = vec![false; topo.corner.len()];
    let mut loops = 0;
    let mut s = Vec::new();
    let mut edges2 = 0usize;
    for h in 0..topo.corner.len() as u32 {
        if topo.opp[h as usize] == INVALID {
            edges2 += 2;
            if !seen[h as usize] {
                loops += 1;
                // Mark the loop.
                let mut cur = h;
                loop {
                    seen[cur as usize] = true;
                    topo.outgoing(topo.to(cur), &mut s);
                    match s.iter().copied().find(|&g| topo.opp[g as usize] == INVALID) {
                        Some(g) if !seen[g as usize] => cur = g,
                        _ => break,
                    }
                }
            }
        } else {
            edges2 += 1;
        }
    }
    let e = edges2 / 2;
    let used = {
        let mut u = vec![false; nv];
        for &v in faces.iter().flatten() {
            u[v as usize] = true;
        }
        u.iter().filter(|&&x| x).count()
    };
    let chi = used as i64 - e as i64 + faces.len() as i64;
    // Components: faces joined across interior edges.
    let mut sets = DisjointSets::new(faces.len());
    for h in 0..topo.corner.len() as u32 {
        let o = topo.opp[h as usize];
        if o != INVALID {
            sets.join(face_of(h), face_of(o));
        }
    }
    let components = (0..faces.len() as u32).filter(|&f| sets.find(f) == f).count() as i64;
    let genus = (2 * components - chi - loops as i64) / 2;
    (genus, loops)
}

#[cfg(test)]
mod tests {
    use super::*;

    //   3 ------- 2
    //   | \     / |
    //   |   \ /   |      a square fan around centre 4; boundary square 0-1-2-3
    //   |   4     |
    //   |  / \    |
    //   0 ------- 1
    fn fan() -> Vec<[u32; 3]> {
        vec![[0, 1, 4], [1, 2, 4], [2, 3, 4], [3, 0, 4]]
    }

    #[test]
    fn faces_on_the_boundary_have_an_edge_of_one_face() {
        // A tetrahedron is closed: no face on a boundary. Without its bottom face (0 2 1) the
        // three faces around the hole each have one edge of one face.
        //        3
        //       /|\
        //      0-+-2
        //       \|/
        //        1
        let tet = [[0, 1, 3], [1, 2, 3], [2, 0, 3], [0, 2, 1]];
        let closed = Topology::build(4, &tet).unwrap();
        assert!((0..4).all(|f| !closed.face_on_boundary(f)));
        let open = Topology::build(4, &tet[..3]).unwrap();
        assert!((0..3).all(|f| open.face_on_boundary(f)));
        // The fan below: every face has one outer edge.
        let t = Topology::build(5, &fan()).unwrap();
        assert!((0..4).all(|f| t.face_on_boundary(f)));
    }

    #[test]
    fn fan_walk_and_boundary() {
        let t = Topology::build(5, &fan()).unwrap();
        let mut s = Vec::new();
        let mut n = Vec::new();
        t.neighbours(4, &mut s, &mut n);
        assert_eq!(n, vec![0, 1, 2, 3]);
        assert!(!t.is_boundary_vertex(4, &mut s));
        assert!(t.is_boundary_vertex(0, &mut s));
        t.neighbours(0, &mut s, &mut n);
        assert_eq!(n, vec![1, 3, 4]);
        let hb = t.find_half_edge(0, 1, &mut s).unwrap();
        assert_eq!(t.opp[hb as usize], INVALID);
        assert_eq!(t.boundary_loop_len(hb, usize::MAX, &mut s), 4);
        assert_eq!(t.boundary_loop_len(hb, 2, &mut s), 3);
    }

    #[test]
    fn rejects_bad_topology() {
        // Two faces over the same directed edge.
        let e = Topology::build(4, &[[0, 1, 2], [0, 1, 3]]).unwrap_err();
        assert!(matches!(e, TopologyError::InconsistentWinding { .. }));
        // Three faces on edge 0-1 (a fin).
        let e = Topology::build(5, &[[0, 1, 2], [1, 0, 3], [1, 0, 4]]).unwrap_err();
        assert!(matches!(e, TopologyError::InconsistentWinding { .. } | TopologyError::NonManifoldEdge { .. }));
        // Bow tie: two triangles meeting at vertex 0 only.
        let e = Topology::build(5, &[[0, 1, 2], [0, 3, 4]]).unwrap_err();
        assert_eq!(e, TopologyError::NonManifoldVertex { v: 0 });
    }

    #[test]
    fn collapse_interior_edge() {
        let t0 = Topology::build(5, &fan()).unwrap();
        let mut t = t0.clone();
        let mut s = Vec::new();
        // Collapse 4 -> 0... keep 0 (boundary), remove 4 (interior).
        let h = t.find_half_edge(0, 4, &mut s).unwrap();
        let removed = t.collapse(h);
        let mut r = removed.to_vec();
        r.sort();
        assert_eq!(r, vec![0, 3]);
        let live: Vec<_> = (0..4).filter(|&f| t.face_alive(f)).map(|f| t.face(f)).collect();
        assert_eq!(live, vec![[1, 2, 0], [2, 3, 0]]);
        let mut n = Vec::new();
        t.neighbours(0, &mut s, &mut n);
        assert_eq!(n, vec![1, 2, 3]);
        // The glued edge 0-2 is interior now.
        let h02 = t.find_half_edge(0, 2, &mut s).or_else(|| t.find_half_edge(2, 0, &mut s)).unwrap();
        assert_ne!(t.opp[h02 as usize], INVALID);
    }
}
