//! Welding and the explicit clean-up of raw scans (`--repair`), as passes over flat face arrays.
//!
//! Every pass works on `faces: Vec<[u32; 3]>` over vertex ids that are either input vertices
//! or copies appended by `split_nonmanifold_vertices` (`origin` gives a copy's input vertex).
//! Each pass counts what it changed into [`Cleanup`], which the reports carry. The passes run
//! in the order of [`repair_faces`]: later ones rely on what earlier ones guarantee (orienting
//! needs at most two faces per edge; splitting fans needs consistent winding).

use crate::topology::DisjointSets;
use glam::DVec3;

/// How a scan is prepared before it is checked (SPEC §6).
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub struct Preparation {
    /// Weld exactly coincident vertex positions (default on; `--no-weld`).
    pub weld: bool,
    /// `--repair`: drop degenerate and duplicate faces, resolve non-manifold edges and
    /// vertices, orient each component, drop small components.
    pub repair: bool,
    /// With `repair`: drop components with fewer faces than this (0 keeps every one).
    pub min_component: usize,
}

impl Default for Preparation {
    fn default() -> Self {
        Preparation { weld: true, repair: false, min_component: 0 }
    }
}

/// What loading changed, counted (the reports' `input` section).
#[derive(Clone, Debug, Default, PartialEq, serde::Serialize)]
pub struct Cleanup {
    /// Input vertices merged into an earlier vertex at exactly the same position.
    pub welded_vertices: usize,
    pub repaired: bool,
    /// Faces repeating a vertex or of zero area, dropped.
    pub degenerate_faces: usize,
    /// Faces on the same three vertices as an earlier face (either winding), dropped.
    pub duplicate_faces: usize,
    /// Edges shared by more than two faces.
    pub non_manifold_edges: usize,
    /// Faces removed so that every edge has at most two.
    pub non_manifold_edge_faces_removed: usize,
    /// Faces whose winding was reversed to agree with their component.
    pub flipped_faces: usize,
    /// Vertices whose faces formed several fans, and the copies made of them (one per extra fan).
    pub non_manifold_vertices: usize,
    pub vertex_copies: usize,
    /// Connected components (by shared edges) of the mesh as decimated, and those dropped by
    /// `--min-component` with their faces.
    pub components: usize,
    pub components_dropped: usize,
    pub component_faces_dropped: usize,
    /// Faces of the largest and of the smallest component kept.
    pub largest_component: usize,
    pub smallest_component: usize,
}

/// A repair that would change more than this share of the faces is refused. Why: a scan with a
/// few defects loses a few faces; one that loses more is not a damaged surface but another kind
/// of mesh (a polygon soup, overlapping shells), and decimating it would misrepresent it.
pub const MAX_REPAIR_FACE_FRACTION: f64 = 0.01;

/// Why a repair could not be made.
#[derive(Debug)]
pub enum RepairError {
    /// Resolving the non-manifold edges would remove too many faces.
    TooManyRemoved { removed: usize, faces: usize, a: u32, b: u32, count: usize },
    /// A component cannot be wound consistently (a Möbius strip, a Klein bottle).
    NonOrientable { a: u32, b: u32 },
}

/// The position key for welding: the exact bits, with -0.0 read as 0.0.
fn weld_key(p: DVec3) -> [u64; 3] {
    let k = |x: f64| if x == 0.0 { 0u64 } else { x.to_bits() };
    [k(p.x), k(p.y), k(p.z)]
}

/// Welds exactly coincident referenced vertices: every face corner is replaced by the lowest
/// input vertex at the same position. Returns each vertex's representative (itself when it
/// was not merged) and the number of vertices merged away.
pub fn weld_vertices(positions: &[DVec3], faces: &mut [[u32; 3]]) -> (Vec<u32>, usize) {
    let mut used = vec![false; positions.len()];
    for f in faces.iter() {
        for &v in f {
            used[v as usize] = true;
        }
    }
    let mut order: Vec<u32> = (0..positions.len() as u32).filter(|&v| used[v as usize]).collect();
    order.sort_unstable_by_key(|&v| (weld_key(positions[v as usize]), v));
    let mut rep: Vec<u32> = (0..positions.len() as u32).collect();
    let mut merged = 0;
    for run in order.chunk_by(|&a, &b| weld_key(positions[a as usize]) == weld_key(positions[b as usize])) {
        for &v in &run[1..] {
            rep[v as usize] = run[0];
            merged += 1;
        }
    }
    if merged > 0 {
        for f in faces.iter_mut() {
            *f = f.map(|v| rep[v as usize]);
        }
    }
    (rep, merged)
}

/// Degenerate: a repeated vertex, or exactly zero area.
pub fn is_degenerate(positions: &[DVec3], f: [u32; 3]) -> bool {
    if f[0] == f[1] || f[1] == f[2] || f[0] == f[2] {
        return true;
    }
    let [a, b, c] = f.map(|v| positions[v as usize]);
    (b - a).cross(c - a).length_squared() == 0.0
}

/// The live faces keyed by their sorted vertices, sorted: a run of equal keys is one set of
/// duplicates (either winding), lowest face first.
fn keyed_by_vertices(faces: &[[u32; 3]], alive: &[bool]) -> Vec<([u32; 3], u32)> {
    let mut keyed: Vec<([u32; 3], u32)> =
        faces.iter().enumerate().filter(|(i, _)| alive[*i]).map(|(i, f)| (sorted(*f), i as u32)).collect();
    keyed.sort_unstable();
    keyed
}

/// The first pair of faces on the same three vertices (either winding), if any.
pub fn first_duplicate(faces: &[[u32; 3]]) -> Option<(u32, u32)> {
    let keyed = keyed_by_vertices(faces, &vec![true; faces.len()]);
    keyed.chunk_by(|x, y| x.0 == y.0).filter(|r| r.len() > 1).map(|r| (r[0].1, r[1].1)).min_by_key(|p| p.1)
}

fn sorted(mut f: [u32; 3]) -> [u32; 3] {
    f.sort_unstable();
    f
}

/// Every face's three undirected edges as (lo, hi, face), sorted: runs share an edge.
fn edge_list(faces: &[[u32; 3]], alive: &[bool]) -> Vec<(u32, u32, u32)> {
    let mut e = Vec::with_capacity(faces.len() * 3);
    for (fi, f) in faces.iter().enumerate() {
        if !alive[fi] {
            continue;
        }
        for k in 0..3 {
            let (a, b) = (f[k], f[(k + 1) % 3]);
            e.push((a.min(b), a.max(b), fi as u32));
        }
    }
    e.sort_unstable();
    e
}

/// Whether face `f` runs from `a` to `b`.
fn runs(f: [u32; 3], a: u32, b: u32) -> bool {
    (0..3).any(|k| f[k] == a && f[(k + 1) % 3] == b)
}

/// The result of [`repair_faces`]: the faces kept (over input vertices and copies), and for
/// each copy (vertex id `n_input + i`) its input vertex.
pub struct Repaired {
    pub faces: Vec<[u32; 3]>,
    /// The input face each kept face comes from.
    pub source_face: Vec<u32>,
    pub copies: Vec<u32>,
    /// Where each copy lies: its input vertex moved by [`SPLIT_NUDGE`] into its own fan.
    pub copy_positions: Vec<DVec3>,
}

/// A copy made by splitting a non-manifold vertex moves this fraction of the way from the
/// vertex to the centroid of its fan. Why: two copies at one point are the same point to every
/// search (its primary solution ties between the fans, and the projection tears there); 1e-3 of
/// an edge is far below a scan's noise, yet lets each copy map onto its own fan.
pub const SPLIT_NUDGE: f64 = 1e-3;

/// `--repair`: the passes in order, each counted into `cleanup`.
pub fn repair_faces(
    positions: &[DVec3],
    faces: Vec<[u32; 3]>,
    min_component: usize,
    cleanup: &mut Cleanup,
) -> Result<Repaired, RepairError> {
    cleanup.repaired = true;
    let n_in = faces.len();
    let mut alive = vec![true; faces.len()];
    drop_degenerate_faces(positions, &faces, &mut alive, cleanup);
    drop_duplicate_faces(&faces, &mut alive, cleanup);
    resolve_nonmanifold_edges(&faces, &mut alive, n_in, cleanup)?;
    let mut faces = faces;
    orient_components(&mut faces, &alive, cleanup)?;
    let copies = split_nonmanifold_vertices(positions.len(), &mut faces, &alive, cleanup);
    let copy_positions = nudge_copies(positions, &faces, &alive, &copies);
    drop_small_components(&faces, &mut alive, min_component, cleanup);
    let source_face: Vec<u32> = (0..faces.len() as u32).filter(|&f| alive[f as usize]).collect();
    let faces = source_face.iter().map(|&f| faces[f as usize]).collect();
    Ok(Repaired { faces, source_face, copies, copy_positions })
}

/// The position of every copy: [`SPLIT_NUDGE`] of the way to the mean centroid of its faces.
fn nudge_copies(positions: &[DVec3], faces: &[[u32; 3]], alive: &[bool], copies: &[u32]) -> Vec<DVec3> {
    let nv = positions.len();
    let pos = |v: u32| positions[if (v as usize) < nv { v as usize } else { copies[v as usize - nv] as usize }];
    let mut sum = vec![(DVec3::ZERO, 0u32); copies.len()];
    for (f, t) in faces.iter().enumerate() {
        if !alive[f] {
            continue;
        }
        for &v in t {
            if v as usize >= nv {
                let c = (pos(t[0]) + pos(t[1]) + pos(t[2])) / 3.0;
                let s = &mut sum[v as usize - nv];
                s.0 += c;
                s.1 += 1;
            }
        }
    }
    copies
        .iter()
        .zip(&sum)
        .map(|(&v, &(c, n))| {
            let p = positions[v as usize];
            if n == 0 {
                p
            } else {
                p + SPLIT_NUDGE * (c / n as f64 - p)
            }
        })
        .collect()
}

fn drop_degenerate_faces(positions: &[DVec3], faces: &[[u32; 3]], alive: &mut [bool], cleanup: &mut Cleanup) {
    for (fi, f) in faces.iter().enumerate() {
        if alive[fi] && is_degenerate(positions, *f) {
            alive[fi] = false;
            cleanup.degenerate_faces += 1;
        }
    }
}

/// Keeps the first of the faces on the same three vertices, whatever their winding.
fn drop_duplicate_faces(faces: &[[u32; 3]], alive: &mut [bool], cleanup: &mut Cleanup) {
    let keyed = keyed_by_vertices(faces, alive);
    for run in keyed.chunk_by(|x, y| x.0 == y.0) {
        for &(_, f) in &run[1..] {
            alive[f as usize] = false;
            cleanup.duplicate_faces += 1;
        }
    }
}

/// Leaves at most two faces on every edge, removing the fewest: of an edge's faces it keeps the
/// first and the first that runs the other way (so the pair can be wound consistently), else the
/// first two. Refuses when that would remove more than [`MAX_REPAIR_FACE_FRACTION`].
fn resolve_nonmanifold_edges(faces: &[[u32; 3]], alive: &mut [bool], n_in: usize, cleanup: &mut Cleanup) -> Result<(), RepairError> {
    let edges = edge_list(faces, alive);
    let mut first_bad: Option<(u32, u32, usize)> = None;
    for run in edges.chunk_by(|x, y| (x.0, x.1) == (y.0, y.1)) {
        let live: Vec<u32> = run.iter().map(|e| e.2).filter(|&f| alive[f as usize]).collect();
        if run.len() <= 2 {
            continue;
        }
        cleanup.non_manifold_edges += 1;
        first_bad.get_or_insert((run[0].0, run[0].1, run.len()));
        if live.len() <= 2 {
            continue; // an earlier removal already fixed this edge
        }
        let (a, b) = (run[0].0, run[0].1);
        let f0 = live[0];
        let dir0 = runs(faces[f0 as usize], a, b);
        let partner = live[1..].iter().copied().find(|&g| runs(faces[g as usize], a, b) != dir0).unwrap_or(live[1]);
        for &g in &live[1..] {
            if g != partner {
                alive[g as usize] = false;
                cleanup.non_manifold_edge_faces_removed += 1;
            }
        }
    }
    let removed = cleanup.non_manifold_edge_faces_removed;
    if removed as f64 > MAX_REPAIR_FACE_FRACTION * n_in as f64 {
        let (a, b, count) = first_bad.unwrap_or((0, 0, 0));
        return Err(RepairError::TooManyRemoved { removed, faces: n_in, a, b, count });
    }
    Ok(())
}

/// Winds every component consistently: a breadth-first walk over shared edges gives each face
/// the winding its neighbour implies; the minority of each component is reversed.
fn orient_components(faces: &mut [[u32; 3]], alive: &[bool], cleanup: &mut Cleanup) -> Result<(), RepairError> {
    let edges = edge_list(faces, alive);
    // Neighbours across each edge, as CSR (three slots per face).
    let mut nbr = vec![u32::MAX; faces.len() * 3];
    let slot = |f: u32, a: u32, b: u32, faces: &[[u32; 3]]| -> usize {
        let t = faces[f as usize];
        3 * f as usize + (0..3).find(|&k| (t[k].min(t[(k + 1) % 3]), t[k].max(t[(k + 1) % 3])) == (a, b)).unwrap_or(0)
    };
    for run in edges.chunk_by(|x, y| (x.0, x.1) == (y.0, y.1)) {
        if let [x, y] = run {
            nbr[slot(x.2, x.0, x.1, faces)] = y.2;
            nbr[slot(y.2, y.0, y.1, faces)] = x.2;
        }
    }
    // sign: 0 unvisited, 1 keep, 2 reverse.
    let mut sign = vec![0u8; faces.len()];
    let mut queue = std::collections::VecDeque::new();
    let mut component = Vec::new();
    for seed in 0..faces.len() {
        if !alive[seed] || sign[seed] != 0 {
            continue;
        }
        sign[seed] = 1;
        queue.push_back(seed as u32);
        component.clear();
        while let Some(f) = queue.pop_front() {
            component.push(f);
            let t = faces[f as usize];
            let flip_f = sign[f as usize] == 2;
            for k in 0..3 {
                let g = nbr[3 * f as usize + k];
                if g == u32::MAX {
                    continue;
                }
                // f, as it will be wound, runs a -> b; g must run b -> a.
                let (mut a, mut b) = (t[k], t[(k + 1) % 3]);
                if flip_f {
                    std::mem::swap(&mut a, &mut b);
                }
                let want = if runs(faces[g as usize], b, a) { 1 } else { 2 };
                match sign[g as usize] {
                    0 => {
                        sign[g as usize] = want;
                        queue.push_back(g);
                    }
                    s if s != want => return Err(RepairError::NonOrientable { a: a.min(b), b: a.max(b) }),
                    _ => {}
                }
            }
        }
        let reversed = component.iter().filter(|&&f| sign[f as usize] == 2).count();
        let flip_when = if 2 * reversed > component.len() { 1 } else { 2 };
        for &f in &component {
            if sign[f as usize] == flip_when {
                faces[f as usize].swap(1, 2);
                cleanup.flipped_faces += 1;
            }
        }
    }
    Ok(())
}

/// Gives every fan of a vertex but the first its own copy of the vertex (at the same position).
/// Corners are joined across every edge two faces share; each class of corners around a vertex
/// is one fan. Returns, per copy, its input vertex.
fn split_nonmanifold_vertices(nv: usize, faces: &mut [[u32; 3]], alive: &[bool], cleanup: &mut Cleanup) -> Vec<u32> {
    let mut sets = DisjointSets::new(faces.len() * 3);
    let corner = |f: u32, v: u32, faces: &[[u32; 3]]| 3 * f + faces[f as usize].iter().position(|&w| w == v).unwrap_or(0) as u32;
    let edges = edge_list(faces, alive);
    for run in edges.chunk_by(|x, y| (x.0, x.1) == (y.0, y.1)) {
        if let [x, y] = run {
            for v in [x.0, x.1] {
                sets.join(corner(x.2, v, faces), corner(y.2, v, faces));
            }
        }
    }
    // First fan seen at each vertex keeps it; the others get copies, in corner order.
    let mut first_root = vec![u32::MAX; nv];
    let mut copy_of_root: std::collections::HashMap<u32, u32> = std::collections::HashMap::new();
    let mut copies = Vec::new();
    let mut split = vec![false; nv];
    for f in 0..faces.len() as u32 {
        if !alive[f as usize] {
            continue;
        }
        for k in 0..3 {
            let v = faces[f as usize][k];
            let r = sets.find(3 * f + k as u32);
            if first_root[v as usize] == u32::MAX {
                first_root[v as usize] = r;
            } else if first_root[v as usize] != r {
                let id = *copy_of_root.entry(r).or_insert_with(|| {
                    copies.push(v);
                    (nv + copies.len() - 1) as u32
                });
                faces[f as usize][k] = id;
                split[v as usize] = true;
            }
        }
    }
    cleanup.non_manifold_vertices = split.iter().filter(|&&s| s).count();
    cleanup.vertex_copies = copies.len();
    copies
}

/// Connected components by shared edges; those below `min_faces` faces are dropped.
pub fn component_sizes(faces: &[[u32; 3]], alive: &[bool]) -> (Vec<u32>, Vec<usize>) {
    let mut sets = DisjointSets::new(faces.len());
    let edges = edge_list(faces, alive);
    for run in edges.chunk_by(|x, y| (x.0, x.1) == (y.0, y.1)) {
        for w in run.windows(2) {
            sets.join(w[0].2, w[1].2);
        }
    }
    let mut label = vec![u32::MAX; faces.len()];
    let mut sizes = Vec::new();
    let mut id_of_root = std::collections::HashMap::new();
    for f in 0..faces.len() as u32 {
        if !alive[f as usize] {
            continue;
        }
        let r = sets.find(f);
        let id = *id_of_root.entry(r).or_insert_with(|| {
            sizes.push(0);
            sizes.len() as u32 - 1
        });
        label[f as usize] = id;
        sizes[id as usize] += 1;
    }
    (label, sizes)
}

fn drop_small_components(faces: &[[u32; 3]], alive: &mut [bool], min_faces: usize, cleanup: &mut Cleanup) {
    let (label, sizes) = component_sizes(faces, alive);
    for f in 0..faces.len() {
        if alive[f] && sizes[label[f] as usize] < min_faces {
            alive[f] = false;
            cleanup.component_faces_dropped += 1;
        }
    }
    cleanup.components_dropped = sizes.iter().filter(|&&s| s < min_faces).count();
}

/// Counts the components of the mesh as it will be decimated (with or without `--repair`).
pub fn count_components(faces: &[[u32; 3]], cleanup: &mut Cleanup) {
    let (_, sizes) = component_sizes(faces, &vec![true; faces.len()]);
    cleanup.components = sizes.len();
    cleanup.largest_component = sizes.iter().copied().max().unwrap_or(0);
    cleanup.smallest_component = sizes.iter().copied().min().unwrap_or(0);
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn weld_merges_exact_copies_only() {
        // 0 and 2 coincide (one written -0.0), 1 is 1e-12 away from 0: not welded.
        let p = vec![DVec3::new(0.0, 0.0, 0.0), DVec3::new(1e-12, 0.0, 0.0), DVec3::new(-0.0, 0.0, 0.0), DVec3::X, DVec3::Y];
        let mut f = vec![[0, 3, 4], [2, 4, 1]];
        assert_eq!(weld_vertices(&p, &mut f).1, 1);
        assert_eq!(f, vec![[0, 3, 4], [0, 4, 1]]);
    }

    #[test]
    fn nonmanifold_edge_keeps_a_consistent_pair() {
        //  three pages on edge 0-1: faces 0 (0->1), 1 (0->1, same way), 2 (1->0)
        //  keeps 0 and 2 (they can be wound consistently), removes 1
        let p = vec![DVec3::ZERO, DVec3::X, DVec3::Y, DVec3::NEG_Y, DVec3::Z];
        let faces = vec![[0, 1, 2], [0, 1, 4], [1, 0, 3]];
        let mut c = Cleanup::default();
        let r = repair_faces(&p, faces, 0, &mut c);
        // 1 of 3 faces is far above the 1 % limit: refused, naming the edge.
        match r {
            Err(RepairError::TooManyRemoved { removed: 1, a: 0, b: 1, count: 3, .. }) => {}
            _ => panic!("expected a refusal"),
        }
        // Beside a 200-face strip (so one removed face is 0.5 %), the same book is repaired.
        //  1---3---5 ...
        //  | \ | \ |
        //  0---2---4 ...
        let mut faces = vec![[0, 1, 2], [0, 1, 4], [1, 0, 3]];
        let mut p = p;
        let base = p.len() as u32;
        p.extend((0..202).map(|i| DVec3::new((i / 2) as f64, (i % 2) as f64, 10.0)));
        for i in 0..200u32 {
            let v = base + i;
            faces.push(if i % 2 == 0 { [v, v + 2, v + 1] } else { [v, v + 1, v + 2] });
        }
        let mut c = Cleanup::default();
        let r = repair_faces(&p, faces, 0, &mut c).unwrap_or_else(|_| panic!("repaired"));
        assert_eq!(c.non_manifold_edges, 1);
        assert_eq!(c.non_manifold_edge_faces_removed, 1);
        assert!(!r.source_face.contains(&1), "the face running the same way as the first is removed");
        assert!(r.source_face.contains(&0) && r.source_face.contains(&2));
    }

    #[test]
    fn orientation_follows_the_majority() {
        //  3---2
        //  | / |   faces 0 = (0,1,2), 1 = (0,2,3) agree; 2 = (1,4,2) disagrees with 0 on 1-2
        //  0---1---4 (4 is to the right; face 2 winds the wrong way)
        let p = vec![DVec3::ZERO, DVec3::X, DVec3::new(1.0, 1.0, 0.0), DVec3::Y, DVec3::new(2.0, 0.0, 0.0)];
        let mut c = Cleanup::default();
        let r = repair_faces(&p, vec![[0, 1, 2], [0, 2, 3], [1, 2, 4]], 0, &mut c).unwrap_or_else(|_| panic!());
        assert_eq!(c.flipped_faces, 1);
        assert_eq!(r.faces[2], [1, 4, 2]);
        assert!(crate::topology::Topology::build(5, &r.faces).is_ok());
    }

    #[test]
    fn bow_tie_is_split_into_two_fans() {
        //  2       4
        //  | \   / |
        //  |  \ /  |     two triangles touching at vertex 0 only
        //  1---0---3
        let p = vec![DVec3::ZERO, DVec3::NEG_X, DVec3::new(-1.0, 1.0, 0.0), DVec3::X, DVec3::new(1.0, 1.0, 0.0)];
        let mut c = Cleanup::default();
        let r = repair_faces(&p, vec![[0, 2, 1], [0, 3, 4]], 0, &mut c).unwrap_or_else(|_| panic!());
        assert_eq!((c.non_manifold_vertices, c.vertex_copies), (1, 1));
        assert_eq!(r.copies, vec![0]);
        assert_eq!(r.faces[1][0], 5, "the second fan gets the copy");
        assert!(crate::topology::Topology::build(6, &r.faces).is_ok());
    }

    #[test]
    fn degenerate_duplicate_and_small_components() {
        // A quad (two faces), a repeated-index face, a copy of face 0 wound the other way, and
        // a lone triangle far away (a fragment).
        let p = vec![DVec3::ZERO, DVec3::X, DVec3::new(1.0, 1.0, 0.0), DVec3::Y, DVec3::splat(5.0), DVec3::new(6.0, 5.0, 5.0), DVec3::new(5.0, 6.0, 5.0)];
        let faces = vec![[0, 1, 2], [0, 2, 3], [1, 1, 2], [0, 2, 1], [4, 5, 6]];
        let mut c = Cleanup::default();
        let r = repair_faces(&p, faces, 2, &mut c).unwrap_or_else(|_| panic!());
        assert_eq!((c.degenerate_faces, c.duplicate_faces), (1, 1));
        assert_eq!((c.components_dropped, c.component_faces_dropped), (1, 1));
        assert_eq!(r.source_face, vec![0, 1]);
    }
}
