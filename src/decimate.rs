//! The decimation of SPEC §2 as rounds of `pick_collapses → evaluate → commit_collapses`.
//!
//! The CPU owns the base mesh topology, the association of dense vertices to base faces and the
//! edge queue; an [`Evaluator`] tests a batch of independent candidates; passing candidates are
//! committed in queue order. A batch of one is exactly the paper's serial algorithm.

use crate::eval::{
    check_faces_and_edges, find_primary, Accepted, DenseAdjacency, Evaluator, FaceInfo, Found, Map, MapContext,
    NormalMode, Outcome, Reject, Scratch, Tris,
};
use crate::geometry::{face_cross, face_normal, maxmin_direction, vertex_direction};
use crate::mesh::DenseMesh;
use crate::topology::{face_of, Topology, INVALID};
use glam::DVec3;
use rayon::prelude::*;
use std::cmp::Ordering;
use std::collections::{BinaryHeap, HashSet};
use std::time::Instant;

/// The default cap on an edge's valence (the paper's 12).
pub const DEFAULT_MAX_VALENCE: u32 = 12;

/// dmax as a fraction of the dense mesh's bounding-box diagonal (paper §4, SPEC §2).
pub const DEFAULT_DMAX_FRACTION: f64 = 0.1;

/// How many queue entries a round may look at per batch slot before it stops picking.
/// Why: deep scans for independent candidates cost more than they gain once the front is busy.
const PICK_LOOKAHEAD: usize = 4;

/// Options of one decimation run (the CLI fills these).
#[derive(Clone, Debug)]
pub struct Options {
    pub normals: NormalMode,
    /// Stop at or below this many faces (0: no target).
    pub target_faces: usize,
    pub max_valence: u32,
    /// Largest |d| accepted; `None`: DEFAULT_DMAX_FRACTION × bbox diagonal.
    pub dmax: Option<f64>,
    pub strict: bool,
    /// Candidates per round (1 = the paper's serial algorithm).
    pub batch: usize,
}

impl Default for Options {
    fn default() -> Self {
        Options {
            normals: NormalMode::Interpolated,
            target_faces: 0,
            max_valence: DEFAULT_MAX_VALENCE,
            dmax: None,
            strict: false,
            batch: 16,
        }
    }
}

/// A candidate collapse as picked from the queue: half-edge `he` from `u` (kept) to `w`
/// (removed), with its footprint.
#[derive(Clone, Debug)]
pub struct Candidate {
    pub he: u32,
    pub u: u32,
    pub w: u32,
    pub placements: Vec<DVec3>,
    /// Faces deleted by the collapse.
    pub removed: [u32; 2],
    /// Faces whose direction field changes (incident to u, w or their ring), before collapse.
    pub region: Vec<u32>,
    /// Unchanged faces bordering the region.
    pub border: Vec<u32>,
    /// Vertices whose directions are recomputed: u and the ring of u ∪ w.
    pub changed: Vec<u32>,
    /// Dense vertices associated with the region, ascending.
    pub dense: Vec<u32>,
    /// Indices into `dense`, in the order of the region's faces (neighbours fail together).
    pub order: Vec<u32>,
    /// Dense faces touching `dense`, ascending.
    pub dense_faces: Vec<u32>,
}

/// A uniform grid over the (static) dense vertex positions, to find the vertices near a
/// changed region whatever face they are associated with.
pub struct DenseGrid {
    lo: DVec3,
    cell: f64,
    dims: [usize; 3],
    start: Vec<u32>,
    items: Vec<u32>,
}

/// Cells along the bounding box's longest side of the dense grid.
/// Why: late in a run a region spans a tenth of the model; 64 keeps its query to a few hundred cells.
const GRID_RESOLUTION: f64 = 64.0;

impl DenseGrid {
    pub fn new(pos: &[DVec3]) -> DenseGrid {
        let mut lo = DVec3::splat(f64::INFINITY);
        let mut hi = DVec3::splat(f64::NEG_INFINITY);
        for p in pos {
            lo = lo.min(*p);
            hi = hi.max(*p);
        }
        let ext = (hi - lo).max(DVec3::splat(1e-12));
        let cell = ext.max_element() / GRID_RESOLUTION;
        let dims = [0, 1, 2].map(|k| ((ext[k] / cell).floor() as usize + 1).max(1));
        let mut g = DenseGrid { lo, cell, dims, start: vec![0; dims[0] * dims[1] * dims[2] + 1], items: vec![0; pos.len()] };
        let ids: Vec<usize> = pos.iter().map(|p| g.cell_index(g.coords(*p))).collect();
        for &c in &ids {
            g.start[c + 1] += 1;
        }
        for i in 0..g.start.len() - 1 {
            g.start[i + 1] += g.start[i];
        }
        let mut fill = g.start.clone();
        for (v, &c) in ids.iter().enumerate() {
            g.items[fill[c] as usize] = v as u32;
            fill[c] += 1;
        }
        g
    }
    fn coords(&self, p: DVec3) -> [usize; 3] {
        [0, 1, 2].map(|k| (((p[k] - self.lo[k]) / self.cell).floor().max(0.0) as usize).min(self.dims[k] - 1))
    }
    fn cell_index(&self, c: [usize; 3]) -> usize {
        (c[2] * self.dims[1] + c[1]) * self.dims[0] + c[0]
    }
    /// Calls `f` for every vertex in the cells overlapping the box [lo, hi].
    pub fn query(&self, lo: DVec3, hi: DVec3, mut f: impl FnMut(u32)) {
        let a = self.coords(lo);
        let b = self.coords(hi);
        for z in a[2]..=b[2] {
            for y in a[1]..=b[1] {
                for x in a[0]..=b[0] {
                    let c = self.cell_index([x, y, z]);
                    for &v in &self.items[self.start[c] as usize..self.start[c + 1] as usize] {
                        f(v);
                    }
                }
            }
        }
    }
}

/// A uniform grid over the base faces' bounding boxes, updated as faces change, to find the
/// faces outside a candidate's neighbourhood that could hold a smaller solution.
pub struct FaceGrid {
    lo: DVec3,
    cell: f64,
    dims: [usize; 3],
    cells: Vec<Vec<u32>>,
    /// Cell range of each face as inserted ([lo; 3], [hi; 3]); empty for deleted faces.
    range: Vec<Option<([usize; 3], [usize; 3])>>,
}

/// Cells along the longest side of the face grid.
/// Why: late in a run a base face spans a few cells; early faces share a cell with tens of others.
const FACE_GRID_RESOLUTION: f64 = 32.0;

impl FaceGrid {
    fn new(pos: &[DVec3], topo: &Topology) -> FaceGrid {
        let mut lo = DVec3::splat(f64::INFINITY);
        let mut hi = DVec3::splat(f64::NEG_INFINITY);
        for p in pos {
            lo = lo.min(*p);
            hi = hi.max(*p);
        }
        let ext = (hi - lo).max(DVec3::splat(1e-12));
        let cell = ext.max_element() / FACE_GRID_RESOLUTION;
        let dims = [0, 1, 2].map(|k| ((ext[k] / cell).floor() as usize + 1).max(1));
        let nf = topo.num_faces_total();
        let mut g = FaceGrid { lo, cell, dims, cells: vec![Vec::new(); dims[0] * dims[1] * dims[2]], range: vec![None; nf] };
        for f in 0..nf as u32 {
            if topo.face_alive(f) {
                g.insert(f, topo.face(f).map(|v| pos[v as usize]));
            }
        }
        g
    }
    fn coords(&self, p: DVec3) -> [usize; 3] {
        [0, 1, 2].map(|k| (((p[k] - self.lo[k]) / self.cell).floor().max(0.0) as usize).min(self.dims[k] - 1))
    }
    fn for_cells(&self, a: [usize; 3], b: [usize; 3], mut f: impl FnMut(usize)) {
        for z in a[2]..=b[2] {
            for y in a[1]..=b[1] {
                for x in a[0]..=b[0] {
                    f((z * self.dims[1] + y) * self.dims[0] + x);
                }
            }
        }
    }
    fn insert(&mut self, f: u32, p: [DVec3; 3]) {
        let a = self.coords(p[0].min(p[1]).min(p[2]));
        let b = self.coords(p[0].max(p[1]).max(p[2]));
        let mut ids = Vec::new();
        self.for_cells(a, b, |c| ids.push(c));
        for c in ids {
            self.cells[c].push(f);
        }
        self.range[f as usize] = Some((a, b));
    }
    fn remove(&mut self, f: u32) {
        if let Some((a, b)) = self.range[f as usize].take() {
            let mut ids = Vec::new();
            self.for_cells(a, b, |c| ids.push(c));
            for c in ids {
                self.cells[c].retain(|&g| g != f);
            }
        }
    }
    /// Faces whose cells overlap the box [lo, hi], ascending, without repeats.
    fn query(&self, lo: DVec3, hi: DVec3, out: &mut Vec<u32>) {
        out.clear();
        self.for_cells(self.coords(lo), self.coords(hi), |c| out.extend_from_slice(&self.cells[c]));
        out.sort_unstable();
        out.dedup();
    }
}

/// Counters for the report.
#[derive(Clone, Debug, Default, serde::Serialize)]
pub struct Stats {
    pub rounds: u64,
    pub tried: u64,
    pub accepted: u64,
    pub rejected: std::collections::BTreeMap<String, u64>,
    /// Accepted collapses per placement: [kept endpoint, other endpoint, midpoint].
    pub placement_wins: [u64; 3],
    pub time_pick_s: f64,
    pub time_evaluate_s: f64,
    pub time_commit_s: f64,
}

/// The whole decimation state: dense mesh (immutable), base mesh, association, queue.
pub struct State {
    pub mode: NormalMode,
    pub dmax: f64,
    pub strict: bool,
    pub max_valence: u32,
    // Dense mesh.
    pub dpos: Vec<DVec3>,
    pub dfaces: Vec<[u32; 3]>,
    pub dnormal: Vec<DVec3>,
    pub vf_start: Vec<u32>,
    pub vf: Vec<u32>,
    pub pinched: Vec<bool>,
    // Base mesh.
    pub pos: Vec<DVec3>,
    pub dir: Vec<DVec3>,
    pub topo: Topology,
    pub face_count: usize,
    // Association.
    pub assoc: Vec<Map>,
    pub face_dense: Vec<Vec<u32>>,
    /// Static grid over the dense vertices.
    pub grid: DenseGrid,
    /// Dynamic grid over the base faces.
    pub face_grid: FaceGrid,
    /// An upper bound on |d| over all associations (grows as the base coarsens).
    pub max_abs_d: f64,
    // Queue.
    heap: BinaryHeap<QueueEntry>,
    queued: HashSet<u64>,
    pub stats: Stats,
}

#[derive(Clone, Copy, Debug)]
struct QueueEntry {
    len: f64,
    a: u32,
    b: u32,
}
impl PartialEq for QueueEntry {
    fn eq(&self, o: &Self) -> bool {
        self.cmp(o) == Ordering::Equal
    }
}
impl Eq for QueueEntry {}
impl PartialOrd for QueueEntry {
    fn partial_cmp(&self, o: &Self) -> Option<Ordering> {
        Some(self.cmp(o))
    }
}
impl Ord for QueueEntry {
    /// Max-heap order reversed: shortest edge first, ties by vertex ids.
    fn cmp(&self, o: &Self) -> Ordering {
        o.len.total_cmp(&self.len).then(o.a.cmp(&self.a)).then(o.b.cmp(&self.b))
    }
}

fn edge_key(a: u32, b: u32) -> u64 {
    ((a.min(b) as u64) << 32) | a.max(b) as u64
}

impl State {
    /// Step 1 of SPEC §2: the base starts as a copy of the dense mesh; every dense vertex is
    /// associated with one of its own faces at d = 0; all edges are queued by length.
    pub fn new(dense: &DenseMesh, opts: &Options) -> State {
        let nv = dense.positions.len();
        let dnormal: Vec<DVec3> = dense
            .faces
            .iter()
            .map(|f| face_normal(dense.positions[f[0] as usize], dense.positions[f[1] as usize], dense.positions[f[2] as usize]))
            .collect();
        let mut vf_start = vec![0u32; nv + 1];
        for f in &dense.faces {
            for &v in f {
                vf_start[v as usize + 1] += 1;
            }
        }
        for i in 0..nv {
            vf_start[i + 1] += vf_start[i];
        }
        let mut fill = vf_start.clone();
        let mut vf = vec![0u32; vf_start[nv] as usize];
        for (fi, f) in dense.faces.iter().enumerate() {
            for &v in f {
                vf[fill[v as usize] as usize] = fi as u32;
                fill[v as usize] += 1;
            }
        }
        let pinched: Vec<bool> = (0..nv)
            .into_par_iter()
            .map(|v| {
                let ns: Vec<DVec3> =
                    vf[vf_start[v] as usize..vf_start[v + 1] as usize].iter().map(|&f| dnormal[f as usize]).collect();
                let mean = ns.iter().copied().sum::<DVec3>().normalize_or_zero();
                if ns.iter().all(|n| n.dot(mean) > 0.0) {
                    return false;
                }
                maxmin_direction(&ns).is_none()
            })
            .collect();
        let dmax = opts.dmax.unwrap_or_else(|| {
            DEFAULT_DMAX_FRACTION * crate::mesh::bbox_diagonal(dense.positions.iter().copied())
        });
        let topo = dense.topology.clone();
        let nf = dense.faces.len();
        let mut st = State {
            mode: opts.normals,
            dmax,
            strict: opts.strict,
            max_valence: opts.max_valence,
            dpos: dense.positions.clone(),
            dfaces: dense.faces.clone(),
            dnormal,
            vf_start,
            vf,
            pinched,
            pos: dense.positions.clone(),
            dir: vec![DVec3::ZERO; nv],
            topo,
            face_count: nf,
            assoc: Vec::with_capacity(nv),
            face_dense: vec![Vec::new(); nf],
            grid: DenseGrid::new(&dense.positions),
            face_grid: FaceGrid::new(&dense.positions, &dense.topology),
            max_abs_d: 0.0,
            heap: BinaryHeap::new(),
            queued: HashSet::new(),
            stats: Stats::default(),
        };
        st.dir = (0..nv as u32).into_par_iter().map(|v| st.compute_dir(v)).collect();
        for v in 0..nv as u32 {
            let f = st.vf[st.vf_start[v as usize] as usize];
            let k = st.dfaces[f as usize].iter().position(|&x| x == v).unwrap();
            let mut bary = [0.0; 3];
            bary[k] = 1.0;
            st.assoc.push(Map { face: f, bary, d: 0.0 });
            st.face_dense[f as usize].push(v);
        }
        for h in 0..st.topo.corner.len() as u32 {
            let (a, b) = (st.topo.from(h), st.topo.to(h));
            if a < b || st.topo.opp[h as usize] == INVALID {
                st.push_edge(a, b);
            }
        }
        st
    }

    pub fn dense(&self) -> DenseAdjacency<'_> {
        DenseAdjacency {
            pos: &self.dpos,
            faces: &self.dfaces,
            face_normal: &self.dnormal,
            vf_start: &self.vf_start,
            vf: &self.vf,
        }
    }

    /// Direction of base vertex `v` from its current fan (the README's rule).
    fn compute_dir(&self, v: u32) -> DVec3 {
        let mut s = Vec::new();
        let mut fs = Vec::new();
        self.topo.faces_around(v, &mut s, &mut fs);
        let cross: Vec<DVec3> = fs
            .iter()
            .map(|&f| {
                let t = self.topo.face(f);
                face_cross(self.pos[t[0] as usize], self.pos[t[1] as usize], self.pos[t[2] as usize])
            })
            .collect();
        vertex_direction(&cross)
    }

    fn push_edge(&mut self, a: u32, b: u32) {
        let k = edge_key(a, b);
        if self.queued.insert(k) {
            let len = self.pos[a as usize].distance(self.pos[b as usize]);
            self.heap.push(QueueEntry { len, a: a.min(b), b: a.max(b) });
        }
    }

    fn count_reject(&mut self, r: Reject) {
        *self.stats.rejected.entry(r.name().to_string()).or_insert(0) += 1;
    }

    /// Topological admissibility of collapsing edge (a, b): link condition, boundary rules,
    /// valence cap. Returns the oriented half-edge (kept → removed) and the placements.
    fn admissible(&self, a: u32, b: u32, s: &mut Vec<u32>, n1: &mut Vec<u32>, n2: &mut Vec<u32>) -> Result<(u32, Vec<DVec3>), Reject> {
        let h_ab = self.topo.find_half_edge(a, b, s);
        let h_ba = self.topo.find_half_edge(b, a, s);
        if h_ab.is_none() && h_ba.is_none() {
            return Err(Reject::Link);
        }
        let boundary_edge = h_ab.is_none() || h_ba.is_none();
        let a_bd = self.topo.is_boundary_vertex(a, s);
        let b_bd = self.topo.is_boundary_vertex(b, s);
        if !boundary_edge && a_bd && b_bd {
            return Err(Reject::Boundary);
        }
        if boundary_edge {
            let hb = h_ab.or(h_ba).unwrap();
            if self.topo.boundary_loop_len(hb, s) <= 3 {
                return Err(Reject::Boundary);
            }
        }
        // Link condition: the common neighbours are exactly the vertices opposite the edge.
        self.topo.neighbours(a, s, n1);
        self.topo.neighbours(b, s, n2);
        let common = n1.iter().filter(|v| n2.binary_search(v).is_ok()).count();
        let opposite = if boundary_edge { 1 } else { 2 };
        if common != opposite {
            return Err(Reject::Link);
        }
        let valence = (n1.len() + n2.len()) as u32 - 1;
        if valence >= self.max_valence {
            return Err(Reject::Valence);
        }
        // Orientation: keep a boundary vertex where exactly one end is on the boundary; a
        // boundary edge exists as a half-edge in one direction only.
        let (mut u, mut w) = if b_bd && !a_bd { (b, a) } else { (a, b) };
        let he = match self.topo.find_half_edge(u, w, s) {
            Some(h) => h,
            None => {
                std::mem::swap(&mut u, &mut w);
                self.topo.find_half_edge(u, w, s).ok_or(Reject::Link)?
            }
        };
        let (pu, pw) = (self.pos[u as usize], self.pos[w as usize]);
        if a_bd != b_bd {
            Ok((he, vec![pu]))
        } else {
            Ok((he, vec![pu, pw, 0.5 * (pu + pw)]))
        }
    }

    /// Gathers a candidate's footprint: region, border, changed vertices, dense vertices.
    fn gather(&self, he: u32, placements: Vec<DVec3>, s: &mut Vec<u32>, tmp: &mut Vec<u32>) -> Candidate {
        let u = self.topo.from(he);
        let w = self.topo.to(he);
        let ho = self.topo.opp[he as usize];
        let removed = [face_of(he), if ho == INVALID { INVALID } else { face_of(ho) }];
        let mut ring = Vec::new();
        self.topo.neighbours(u, s, tmp);
        ring.extend_from_slice(tmp);
        self.topo.neighbours(w, s, tmp);
        ring.extend_from_slice(tmp);
        ring.retain(|&v| v != u && v != w);
        ring.sort_unstable();
        ring.dedup();
        let mut region = Vec::new();
        for &v in [u, w].iter().chain(ring.iter()) {
            self.topo.faces_around(v, s, tmp);
            region.extend_from_slice(tmp);
        }
        region.sort_unstable();
        region.dedup();
        let mut ring2 = Vec::new();
        for &f in &region {
            for v in self.topo.face(f) {
                if v != u && v != w && ring.binary_search(&v).is_err() {
                    ring2.push(v);
                }
            }
        }
        ring2.sort_unstable();
        ring2.dedup();
        let mut border = Vec::new();
        for &v in &ring2 {
            self.topo.faces_around(v, s, tmp);
            border.extend(tmp.iter().copied().filter(|f| region.binary_search(f).is_err()));
        }
        border.sort_unstable();
        border.dedup();
        let mut changed = vec![u];
        changed.extend_from_slice(&ring);
        Candidate {
            he,
            u,
            w,
            placements,
            removed,
            region,
            border,
            changed,
            dense: Vec::new(),
            order: Vec::new(),
            dense_faces: Vec::new(),
        }
    }

    /// Fills a picked candidate's dense lists: the vertices associated with its region (their
    /// faces change), the test order, and the dense faces around them.
    fn fill_dense(&self, c: &mut Candidate) {
        let mut order_vs: Vec<u32> = Vec::new();
        for &f in c.region.iter() {
            order_vs.extend_from_slice(&self.face_dense[f as usize]);
        }
        let mut dense = order_vs.clone();
        dense.sort_unstable();
        c.order = order_vs.iter().map(|v| dense.binary_search(v).unwrap() as u32).collect();
        let dadj = self.dense();
        let mut dense_faces: Vec<u32> = dense.iter().flat_map(|&v| dadj.faces_of(v).iter().copied()).collect();
        dense_faces.sort_unstable();
        dense_faces.dedup();
        c.dense = dense;
        c.dense_faces = dense_faces;

    }

    /// Vertices touched by a candidate (for picking independent sets): all vertices of its
    /// region and border faces.
    fn footprint_vertices(&self, c: &Candidate, out: &mut Vec<u32>) {
        out.clear();
        for &f in c.region.iter().chain(c.border.iter()) {
            out.extend_from_slice(&self.topo.face(f));
        }
    }

    /// Picks the next batch of independent candidates from the front of the queue.
    pub fn pick_collapses(&mut self, batch: usize, marks: &mut Vec<u32>, round: u32) -> Vec<Candidate> {
        let mut out = Vec::new();
        let mut deferred = Vec::new();
        let (mut s, mut n1, mut n2, mut fp) = (Vec::new(), Vec::new(), Vec::new(), Vec::new());
        let mut examined = 0;
        while out.len() < batch && examined < PICK_LOOKAHEAD * batch.max(1) {
            let Some(e) = self.heap.pop() else { break };
            let k = edge_key(e.a, e.b);
            self.queued.remove(&k);
            if self.topo.vert_he[e.a as usize] == INVALID || self.topo.vert_he[e.b as usize] == INVALID {
                continue;
            }
            let len = self.pos[e.a as usize].distance(self.pos[e.b as usize]);
            if len != e.len {
                // A stale entry (an endpoint moved): queue it again at its current length.
                self.push_edge(e.a, e.b);
                continue;
            }
            examined += 1;
            match self.admissible(e.a, e.b, &mut s, &mut n1, &mut n2) {
                Err(r) => {
                    self.stats.tried += 1;
                    self.count_reject(r);
                }
                Ok((he, placements)) => {
                    let c = self.gather(he, placements, &mut s, &mut n1);
                    self.footprint_vertices(&c, &mut fp);
                    if fp.iter().any(|&v| marks[v as usize] == round) {
                        deferred.push(e);
                        continue;
                    }
                    for &v in &fp {
                        marks[v as usize] = round;
                    }
                    out.push(c);
                }
            }
        }
        for e in deferred {
            self.push_edge(e.a, e.b);
        }
        let this = &*self;
        out.par_iter_mut().for_each(|c| this.fill_dense(c));
        out
    }

    /// Builds the neighbourhood of a candidate after collapse with `placement`: region (less
    /// the deleted faces) and border, with the new directions. Fails on a fold-over.
    fn build_neighbourhood(&self, c: &Candidate, p: DVec3, tris: &mut Tris) -> Result<(Vec<(u32, DVec3)>, usize), Reject> {
        tris.clear();
        let relabel = |v: u32| if v == c.w { c.u } else { v };
        let pos_of = |v: u32| if v == c.u { p } else { self.pos[v as usize] };
        let mut crosses: Vec<Vec<DVec3>> = vec![Vec::new(); c.changed.len()];
        let changed_idx = |v: u32| c.changed.iter().position(|&x| x == v);
        let mut post: Vec<(u32, [u32; 3], [DVec3; 3])> = Vec::with_capacity(c.region.len() + c.border.len());
        for &f in c.region.iter().chain(c.border.iter()) {
            if f == c.removed[0] || f == c.removed[1] {
                continue;
            }
            let old = self.topo.face(f);
            let verts = old.map(relabel);
            let pos = verts.map(pos_of);
            let cr = face_cross(pos[0], pos[1], pos[2]);
            if verts.contains(&c.u) {
                // Fold-over: the moved fan must keep its orientation and stay non-degenerate.
                let oc = face_cross(self.pos[old[0] as usize], self.pos[old[1] as usize], self.pos[old[2] as usize]);
                if cr.dot(oc) <= 0.0 || cr.length_squared() <= 1e-30 * oc.length_squared().max(1e-300) {
                    return Err(Reject::Foldover);
                }
            }
            for &v in &verts {
                if let Some(i) = changed_idx(v) {
                    crosses[i].push(cr);
                }
            }
            post.push((f, verts, pos));
        }
        let n_region = c.region.iter().filter(|&&f| f != c.removed[0] && f != c.removed[1]).count();
        let mut new_dirs = Vec::with_capacity(c.changed.len());
        for (i, &v) in c.changed.iter().enumerate() {
            let d = vertex_direction(&crosses[i]);
            if self.mode == NormalMode::Interpolated && !crosses[i].iter().all(|cr| cr.dot(d) > 0.0) {
                return Err(Reject::Foldover);
            }
            new_dirs.push((v, d));
        }
        let dir_of = |v: u32| match new_dirs.iter().find(|(x, _)| *x == v) {
            Some((_, d)) => *d,
            None => self.dir[v as usize],
        };
        for (f, verts, pos) in post {
            tris.push(f, verts, pos, verts.map(dir_of));
        }
        tris.finish();
        Ok((new_dirs, n_region))
    }

    /// Tests one candidate, placement by placement (SPEC §2 step 5). The first passing
    /// placement wins; otherwise the first placement's reason is reported.
    pub fn evaluate_candidate(&self, c: &Candidate) -> Outcome {
        let mut first_reason = None;
        let mut tris = Tris::default();
        let mut scratch = Scratch::default();
        for (pi, &p) in c.placements.iter().enumerate() {
            match self.evaluate_placement(c, p, &mut tris, &mut scratch) {
                Ok(acc) => {
                    return Ok(Accepted { placement: pi, ..acc });
                }
                Err(r) => {
                    first_reason.get_or_insert(r);
                }
            }
        }
        Err(first_reason.unwrap_or(Reject::Link))
    }

    fn evaluate_placement(&self, c: &Candidate, p: DVec3, tris: &mut Tris, scratch: &mut Scratch) -> Result<Accepted, Reject> {
        let (new_dirs, n_region) = self.build_neighbourhood(c, p, tris)?;
        let dense = self.dense();
        let mut maps = vec![Map { face: INVALID, bary: [0.0; 3], d: 0.0 }; c.dense.len()];
        let mut normals = Vec::new();
        for &i in &c.order {
            let v = c.dense[i as usize];
            let x = self.dpos[v as usize];
            dense.vertex_normals(v, &mut normals);
            let pinched = self.pinched[v as usize];
            match find_primary(x, &normals, tris, self.mode, self.dmax, !pinched, self.strict && !pinched, scratch) {
                Found::Hit(t, h) => maps[i as usize] = Map { face: tris.ids[t], bary: h.bary, d: h.d },
                Found::Ambiguous => return Err(Reject::Ambiguous),
                Found::None if pinched => maps[i as usize] = self.nearest_fallback(x, tris),
                Found::None => return Err(Reject::Unmapped),
            }
        }
        self.far_primaries(c, tris, &mut maps, scratch);
        let extras = self.moved_primaries(c, tris, n_region, scratch);
        let faces_owned;
        let faces: &[u32] = if extras.is_empty() {
            &c.dense_faces
        } else {
            let mut f = c.dense_faces.clone();
            for &(v, _) in &extras {
                f.extend_from_slice(dense.faces_of(v));
            }
            f.sort_unstable();
            f.dedup();
            faces_owned = f;
            &faces_owned
        };
        let ctx = CandidateContext { st: self, c, tris, maps: &maps, extras: &extras };
        let tested = |v: u32| c.dense.binary_search(&v).is_ok() || extras.binary_search_by_key(&v, |e| e.0).is_ok();
        check_faces_and_edges(&ctx, &dense, faces, tested, scratch)?;
        Ok(Accepted { placement: 0, position: p, new_dirs, maps, extras })
    }

    /// The region's vertices were solved over region ∪ border; a face outside (the far side of
    /// a thin part) may hold a solution with a smaller |d|. Any such face lies within |d| of the
    /// vertex, so one grid query with the largest |d| finds every candidate face.
    fn far_primaries(&self, c: &Candidate, tris: &Tris, maps: &mut [Map], scratch: &mut Scratch) {
        let mut lo = DVec3::splat(f64::INFINITY);
        let mut hi = DVec3::splat(f64::NEG_INFINITY);
        let mut reach: f64 = 0.0;
        for (i, &v) in c.dense.iter().enumerate() {
            if self.pinched[v as usize] || maps[i].d == 0.0 {
                continue;
            }
            let x = self.dpos[v as usize];
            lo = lo.min(x);
            hi = hi.max(x);
            reach = reach.max(maps[i].d.abs());
        }
        if reach == 0.0 {
            return;
        }
        let mut faces = Vec::new();
        self.face_grid.query(lo - DVec3::splat(reach), hi + DVec3::splat(reach), &mut faces);
        let mut far = Tris::default();
        for f in faces {
            if tris.index_of(f).is_some() || c.region.binary_search(&f).is_ok() || !self.topo.face_alive(f) {
                continue;
            }
            let info = self.face_info_current(f);
            let (ctr, r) = crate::geometry::triangle_sphere(&info.pos);
            // Skip faces beyond every vertex's reach.
            let q = ctr.clamp(lo, hi);
            if q.distance(ctr) - r > reach {
                continue;
            }
            far.push(f, info.verts, info.pos, info.dir);
        }
        if far.is_empty() {
            return;
        }
        far.finish();
        let dense = self.dense();
        let mut normals = Vec::new();
        let tie = crate::eval::SAME_SOLUTION_REL * self.dmax;
        for (i, &v) in c.dense.iter().enumerate() {
            let cur = maps[i];
            if self.pinched[v as usize] || cur.d == 0.0 {
                continue;
            }
            let x = self.dpos[v as usize];
            dense.vertex_normals(v, &mut normals);
            if let Found::Hit(t, h) = find_primary(x, &normals, &far, self.mode, cur.d.abs() + tie, true, false, scratch) {
                let (da, db) = (h.d.abs(), cur.d.abs());
                if da < db - tie || (da <= db + tie && far.ids[t] < cur.face) {
                    maps[i] = Map { face: far.ids[t], bary: h.bary, d: h.d };
                }
            }
        }
    }

    /// Dense vertices associated outside the region whose primary solution moves onto it: a
    /// vertex can only gain a solution on a changed triangle T if its distance to T is below
    /// its current |d| (|x − X| ≤ |d|), so the grid finds every candidate. Returns their new
    /// maps, ascending by vertex.
    fn moved_primaries(&self, c: &Candidate, tris: &Tris, n_region: usize, scratch: &mut Scratch) -> Vec<(u32, Map)> {
        let reach = self.max_abs_d;
        if reach <= 0.0 || n_region == 0 {
            return Vec::new();
        }
        let mut lo = DVec3::splat(f64::INFINITY);
        let mut hi = DVec3::splat(f64::NEG_INFINITY);
        for t in 0..n_region {
            for q in tris.pos[t] {
                lo = lo.min(q);
                hi = hi.max(q);
            }
        }
        let (blo, bhi) = (lo - DVec3::splat(reach), hi + DVec3::splat(reach));
        let mut cand = Vec::new();
        self.grid.query(blo, bhi, |v| {
            let dv = self.assoc[v as usize].d.abs();
            if dv == 0.0 || self.pinched[v as usize] {
                return;
            }
            let x = self.dpos[v as usize];
            if x.clamp(lo, hi).distance(x) >= dv || c.dense.binary_search(&v).is_ok() {
                return;
            }
            cand.push(v);
        });
        if cand.is_empty() {
            return Vec::new();
        }
        cand.sort_unstable();
        let mut region = Tris::default();
        for t in 0..n_region {
            region.push(tris.ids[t], tris.verts[t], tris.pos[t], tris.dir[t]);
        }
        region.finish();
        let dense = self.dense();
        let mut normals = Vec::new();
        let mut out = Vec::new();
        for v in cand {
            let cur = self.assoc[v as usize];
            let x = self.dpos[v as usize];
            dense.vertex_normals(v, &mut normals);
            if let Found::Hit(t, h) = find_primary(x, &normals, &region, self.mode, cur.d.abs(), true, false, scratch) {
                if h.d.abs() < cur.d.abs() {
                    out.push((v, Map { face: region.ids[t], bary: h.bary, d: h.d }));
                }
            }
        }
        out
    }

    /// Association of a pinched vertex without any solution: the nearest triangle's centre.
    fn nearest_fallback(&self, x: DVec3, tris: &Tris) -> Map {
        let mut best = (f64::INFINITY, 0usize);
        for t in 0..tris.len() {
            let d = x.distance(tris.sphere[t].0);
            if d < best.0 {
                best = (d, t);
            }
        }
        Map { face: tris.ids[best.1], bary: [1.0 / 3.0; 3], d: 0.0 }
    }

    /// Applies accepted candidates in batch order (SPEC §2 step 6). A candidate whose dense
    /// vertices were re-associated by an earlier commit of the same round is stale: it goes
    /// back to the queue untried.
    pub fn commit_collapses(&mut self, batch: Vec<Candidate>, outcomes: Vec<Outcome>, vmark: &mut [u32], round: u32) {
        let (mut s, mut t1, mut t2) = (Vec::new(), Vec::new(), Vec::new());
        for (c, o) in batch.into_iter().zip(outcomes) {
            let stale = {
                let dfaces = &self.dfaces;
                let touched = |v: u32| vmark[v as usize] == round;
                c.dense_faces.iter().any(|&f| dfaces[f as usize].iter().any(|&v| touched(v)))
                    || o.as_ref().map(|a| a.extras.iter().any(|&(v, _)| touched(v))).unwrap_or(false)
            };
            if stale {
                self.push_edge(c.u, c.w);
                continue;
            }
            self.stats.tried += 1;
            let acc = match o {
                Ok(a) => a,
                Err(r) => {
                    self.count_reject(r);
                    continue; // parked until its neighbourhood changes
                }
            };
            self.stats.accepted += 1;
            self.stats.placement_wins[acc.placement.min(2)] += 1;
            let removed = self.topo.collapse(c.he);
            self.face_count -= removed.iter().filter(|&&f| f != INVALID).count();
            self.pos[c.u as usize] = acc.position;
            for &f in &c.region {
                self.face_grid.remove(f);
                if self.topo.face_alive(f) {
                    let p = self.topo.face(f).map(|v| self.pos[v as usize]);
                    self.face_grid.insert(f, p);
                }
            }
            for (v, d) in acc.new_dirs {
                self.dir[v as usize] = d;
            }
            for &f in c.region.iter() {
                self.face_dense[f as usize].clear();
            }
            for (i, &v) in c.dense.iter().enumerate() {
                let m = acc.maps[i];
                self.assoc[v as usize] = m;
                self.face_dense[m.face as usize].push(v);
                self.max_abs_d = self.max_abs_d.max(m.d.abs());
                vmark[v as usize] = round;
            }
            for &(v, m) in &acc.extras {
                let old = self.assoc[v as usize].face;
                self.face_dense[old as usize].retain(|&x| x != v);
                self.assoc[v as usize] = m;
                self.face_dense[m.face as usize].push(v);
                vmark[v as usize] = round;
            }
            // Re-queue the edges whose neighbourhood changed: those around the 2-ring of u.
            self.topo.neighbours(c.u, &mut s, &mut t1);
            let mut verts = t1.clone();
            verts.push(c.u);
            for &v in &t1 {
                self.topo.neighbours(v, &mut s, &mut t2);
                verts.extend_from_slice(&t2);
            }
            verts.sort_unstable();
            verts.dedup();
            for &v in &verts {
                self.topo.neighbours(v, &mut s, &mut t2);
                for &x in t2.clone().iter() {
                    self.push_edge(v, x);
                }
            }
        }
    }

    /// Runs rounds until the queue is empty or the target is reached.
    pub fn run(&mut self, evaluator: &dyn Evaluator, opts: &Options, mut progress: impl FnMut(usize)) {
        let mut marks = vec![0u32; self.pos.len()];
        let mut vmark = vec![0u32; self.dpos.len()];
        let mut round = 0u32;
        while self.face_count > opts.target_faces.max(1) {
            round += 1;
            self.stats.rounds += 1;
            let t0 = Instant::now();
            let batch = self.pick_collapses(opts.batch.max(1), &mut marks, round);
            let t1 = Instant::now();
            if batch.is_empty() {
                if self.heap.is_empty() {
                    break;
                }
                continue;
            }
            let outcomes = evaluator.evaluate(self, &batch);
            let t2 = Instant::now();
            // With a target, never commit past it.
            let mut outcomes = outcomes;
            let mut faces_left = self.face_count;
            for (c, o) in batch.iter().zip(outcomes.iter_mut()) {
                if o.is_ok() {
                    let k = if c.removed[1] == INVALID { 1 } else { 2 };
                    if opts.target_faces > 0 && faces_left <= opts.target_faces {
                        *o = Err(Reject::Link);
                        continue;
                    }
                    faces_left -= k;
                }
            }
            self.commit_collapses(batch, outcomes, &mut vmark, round);
            let t3 = Instant::now();
            self.stats.time_pick_s += (t1 - t0).as_secs_f64();
            self.stats.time_evaluate_s += (t2 - t1).as_secs_f64();
            self.stats.time_commit_s += (t3 - t2).as_secs_f64();
            progress(self.face_count);
        }
    }

    /// The base mesh, compacted: positions, directions, faces, and the map from internal face
    /// ids to output face ids.
    pub fn compact(&self) -> BaseMesh {
        let mut vmap = vec![INVALID; self.pos.len()];
        let mut positions = Vec::new();
        let mut directions = Vec::new();
        let mut faces = Vec::new();
        let mut face_map = vec![INVALID; self.topo.num_faces_total()];
        for f in 0..self.topo.num_faces_total() as u32 {
            if !self.topo.face_alive(f) {
                continue;
            }
            let t = self.topo.face(f).map(|v| {
                if vmap[v as usize] == INVALID {
                    vmap[v as usize] = positions.len() as u32;
                    positions.push(self.pos[v as usize]);
                    directions.push(self.dir[v as usize]);
                }
                vmap[v as usize]
            });
            face_map[f as usize] = faces.len() as u32;
            faces.push(t);
        }
        if self.mode == NormalMode::Constant {
            // Constant mode uses face normals; the per-vertex output directions are the
            // area-weighted ones, for viewers.
            let mut acc = vec![DVec3::ZERO; positions.len()];
            for t in &faces {
                let c = face_cross(positions[t[0] as usize], positions[t[1] as usize], positions[t[2] as usize]);
                for &v in t {
                    acc[v as usize] += c;
                }
            }
            directions = acc.into_iter().map(|a| a.normalize_or_zero()).collect();
        }
        BaseMesh { positions, directions, faces, face_map }
    }

    /// From-scratch re-check of the guarantee over every dense vertex's neighbourhood: each
    /// vertex is solved again over the 2-ring of the base face it is associated with, then
    /// every dense triangle's orientation and every dense edge's continuity are checked.
    pub fn recheck(&self) -> Recheck {
        let nf = self.topo.num_faces_total() as u32;
        let per_face: Vec<Vec<(u32, Option<Map>)>> = (0..nf)
            .into_par_iter()
            .map(|f| {
                if !self.topo.face_alive(f) || self.face_dense[f as usize].is_empty() {
                    return Vec::new();
                }
                let mut tris = Tris::default();
                self.two_ring_tris(f, &mut tris);
                let mut scratch = Scratch::default();
                let mut normals = Vec::new();
                let dense = self.dense();
                self.face_dense[f as usize]
                    .iter()
                    .map(|&v| {
                        dense.vertex_normals(v, &mut normals);
                        let pinched = self.pinched[v as usize];
                        let r = match find_primary(self.dpos[v as usize], &normals, &tris, self.mode, self.dmax, !pinched, self.strict && !pinched, &mut scratch) {
                            Found::Hit(t, h) => Some(Map { face: tris.ids[t], bary: h.bary, d: h.d }),
                            _ => None,
                        };
                        (v, r)
                    })
                    .collect()
            })
            .collect();
        let mut maps: Vec<Option<Map>> = vec![None; self.dpos.len()];
        let mut unmapped = Vec::new();
        for (v, m) in per_face.into_iter().flatten() {
            if m.is_none() && !self.pinched[v as usize] {
                unmapped.push(v);
            }
            maps[v as usize] = m;
        }
        unmapped.sort_unstable();
        let ctx = GlobalContext { st: self, maps: &maps };
        let dense = self.dense();
        let failures: Vec<(u32, Reject)> = (0..self.dfaces.len() as u32)
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
            pinched: self.pinched.iter().filter(|&&p| p).count(),
            max_abs_d,
        }
    }

    /// Triangles of the 2-ring around face `f` (faces sharing a vertex with f, and theirs).
    pub fn two_ring_tris(&self, f: u32, tris: &mut Tris) {
        let (mut s, mut tmp) = (Vec::new(), Vec::new());
        let mut ring1 = Vec::new();
        for v in self.topo.face(f) {
            self.topo.faces_around(v, &mut s, &mut tmp);
            ring1.extend_from_slice(&tmp);
        }
        ring1.sort_unstable();
        ring1.dedup();
        let mut verts: Vec<u32> = ring1.iter().flat_map(|&g| self.topo.face(g)).collect();
        verts.sort_unstable();
        verts.dedup();
        let mut faces = Vec::new();
        for v in verts {
            self.topo.faces_around(v, &mut s, &mut tmp);
            faces.extend_from_slice(&tmp);
        }
        faces.sort_unstable();
        faces.dedup();
        tris.clear();
        for g in faces {
            let info = self.face_info_current(g);
            tris.push(g, info.verts, info.pos, info.dir);
        }
        tris.finish();
    }

    /// A live face containing all of `verts`.
    pub fn face_containing(&self, verts: &[u32]) -> Option<u32> {
        let (mut s, mut fs) = (Vec::new(), Vec::new());
        self.topo.faces_around(verts[0], &mut s, &mut fs);
        fs.into_iter().find(|&f| verts.iter().all(|v| self.topo.face(f).contains(v)))
    }

    fn face_info_current(&self, f: u32) -> FaceInfo {
        let verts = self.topo.face(f);
        FaceInfo { verts, pos: verts.map(|v| self.pos[v as usize]), dir: verts.map(|v| self.dir[v as usize]) }
    }

}

/// (genus, boundary loops) of a single-component mesh from its Euler characteristic.
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
    let chi = nv as i64 - e as i64 + faces.len() as i64;
    // chi = 2 - 2g - b for one component.
    let genus = (2 - chi - loops as i64) / 2;
    (genus, loops)
}

/// The compacted base mesh.
#[derive(Clone, Debug)]
pub struct BaseMesh {
    pub positions: Vec<DVec3>,
    pub directions: Vec<DVec3>,
    pub faces: Vec<[u32; 3]>,
    /// Internal face id → output face id (INVALID for deleted faces).
    pub face_map: Vec<u32>,
}

/// Result of [`State::recheck`].
#[derive(Clone, Debug, serde::Serialize)]
pub struct Recheck {
    pub unmapped: Vec<u32>,
    pub flipped: Vec<u32>,
    pub torn: Vec<u32>,
    pub pinched: usize,
    pub max_abs_d: f64,
}

impl Recheck {
    pub fn ok(&self) -> bool {
        self.unmapped.is_empty() && self.flipped.is_empty() && self.torn.is_empty()
    }
}

/// Map context during a candidate's evaluation: tested vertices use the new maps and the
/// collapsed neighbourhood; everything else the committed state.
struct CandidateContext<'a> {
    st: &'a State,
    c: &'a Candidate,
    tris: &'a Tris,
    maps: &'a [Map],
    extras: &'a [(u32, Map)],
}

impl MapContext for CandidateContext<'_> {
    fn map_of(&self, v: u32) -> Option<Map> {
        if self.st.pinched[v as usize] {
            return None;
        }
        if let Ok(i) = self.c.dense.binary_search(&v) {
            return Some(self.maps[i]);
        }
        match self.extras.binary_search_by_key(&v, |e| e.0) {
            Ok(i) => Some(self.extras[i].1),
            Err(_) => Some(self.st.assoc[v as usize]),
        }
    }
    fn face_info(&self, face: u32) -> FaceInfo {
        match self.tris.index_of(face) {
            Some(t) => FaceInfo { verts: self.tris.verts[t], pos: self.tris.pos[t], dir: self.tris.dir[t] },
            None => self.st.face_info_current(face),
        }
    }
    fn face_containing(&self, verts: &[u32]) -> Option<u32> {
        let holds = |t: &[u32; 3]| verts.iter().all(|v| t.contains(v));
        if let Some(t) = self.tris.verts.iter().position(holds) {
            return Some(self.tris.ids[t]);
        }
        // Unchanged faces: around a vertex whose fan did not change, outside the region (a
        // changed vertex's faces are all in the neighbourhood).
        let v0 = verts[0];
        if v0 == self.c.w || self.c.changed.contains(&v0) || verts.contains(&self.c.w) {
            return None;
        }
        let (mut s, mut fs) = (Vec::new(), Vec::new());
        self.st.topo.faces_around(v0, &mut s, &mut fs);
        fs.into_iter().find(|&f| holds(&self.st.topo.face(f)) && self.c.region.binary_search(&f).is_err())
    }
    fn solve_point(&self, x: DVec3, normals: &[DVec3], fa: u32, fb: u32, scratch: &mut Scratch) -> Option<Map> {
        // The neighbourhood, plus the (unchanged) faces around an end that maps outside it.
        if self.tris.index_of(fa).is_some() && self.tris.index_of(fb).is_some() {
            return match find_primary(x, normals, self.tris, self.st.mode, self.st.dmax, true, false, scratch) {
                Found::Hit(t, h) => Some(Map { face: self.tris.ids[t], bary: h.bary, d: h.d }),
                _ => None,
            };
        }
        let mut tris = self.tris.clone();
        let (mut s, mut tmp) = (Vec::new(), Vec::new());
        for f in [fa, fb] {
            if self.tris.index_of(f).is_some() {
                continue;
            }
            for v in self.st.topo.face(f) {
                self.st.topo.faces_around(v, &mut s, &mut tmp);
                for &g in &tmp {
                    if tris.index_of(g).is_none() {
                        let info = self.st.face_info_current(g);
                        tris.push(g, info.verts, info.pos, info.dir);
                    }
                }
            }
        }
        tris.finish();
        match find_primary(x, normals, &tris, self.st.mode, self.st.dmax, true, false, scratch) {
            Found::Hit(t, h) => Some(Map { face: tris.ids[t], bary: h.bary, d: h.d }),
            _ => None,
        }
    }
}

/// Map context of the re-check: recomputed maps, current base mesh.
struct GlobalContext<'a> {
    st: &'a State,
    maps: &'a [Option<Map>],
}

impl MapContext for GlobalContext<'_> {
    fn map_of(&self, v: u32) -> Option<Map> {
        if self.st.pinched[v as usize] {
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
