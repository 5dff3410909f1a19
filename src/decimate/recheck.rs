//! The decimator's from-scratch re-check of its own state (SPEC §2): every dense vertex solved
//! again over the 2-ring of its base face, then the exact orientation and continuity checks of
//! SPEC §1. The independent check is [`crate::validate`]; this one reads the decimator's state.

use crate::decimate::State;
use crate::guarantee::{check_face, CheckScratch, CheckStats, FaceCheck, FaceInfo, Found, Map, MapContext, NormalMode, Scratch, Tris, find_primary};
use glam::DVec3;
use rayon::prelude::*;

impl State {
    /// From-scratch re-check of the guarantee over every dense vertex's neighbourhood: each
    /// vertex is solved again over the 2-ring of the base face it is associated with, then
    /// every dense triangle's orientation and every dense edge's continuity are checked.
    pub fn recheck(&self) -> Recheck {
        let nf = self.topo.num_faces_total() as u32;
        let mut maps: Vec<Option<Map>> = vec![None; self.dense.pos.len()];
        let mut unmapped = Vec::new();
        let mut ambiguous = 0;
        // Base faces a slice at a time, so that only one slice's solutions wait to be written.
        let faces: Vec<u32> = (0..nf).filter(|&f| self.topo.face_alive(f) && !self.face_dense.is_empty(f)).collect();
        for slice in faces.chunks(RECHECK_SLICE_FACES) {
            let per_face: Vec<Vec<(u32, Option<Map>, bool)>> = slice
                .par_iter()
                .map(|&f| {
                    let mut tris = Tris::default();
                    self.two_ring_tris(f, &mut tris);
                    let mut scratch = Scratch::default();
                    let mut normals = Vec::new();
                    let dense = &self.dense;
                    self.face_dense
                        .iter(f)
                        .map(|v| {
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
            for (v, m, amb) in per_face.into_iter().flatten() {
                if m.is_none() && !self.dense.pinched[v as usize] {
                    unmapped.push(v);
                }
                ambiguous += amb as usize;
                maps[v as usize] = m;
            }
        }
        unmapped.sort_unstable();
        let ctx = GlobalContext { st: self, maps: &maps };
        let dense = &self.dense;
        // Summed as the threads go (integer counts and a maximum: the same in any order), with
        // only the failing triangles listed: one result per dense triangle would hold 5 MB on
        // the bunny, the run's peak.
        let (checks, mut flipped, mut torn) = (0..self.dense.faces.len() as u32)
            .into_par_iter()
            .fold(
                || (CheckStats::default(), Vec::new(), Vec::new(), CheckScratch::default()),
                |(mut stats, mut flipped, mut torn, mut sc), f| {
                    match check_face(&ctx, dense, f, false, &mut sc, &mut stats) {
                        FaceCheck::Flipped => flipped.push(f),
                        FaceCheck::Torn => torn.push(f),
                        FaceCheck::Fine | FaceCheck::Skipped => {}
                    }
                    (stats, flipped, torn, sc)
                },
            )
            .map(|(stats, flipped, torn, _)| (stats, flipped, torn))
            .reduce(
                || (CheckStats::default(), Vec::new(), Vec::new()),
                |(mut s, mut fa, mut ta), (t, fb, tb)| {
                    s.add(&t);
                    fa.extend(fb);
                    ta.extend(tb);
                    (s, fa, ta)
                },
            );
        flipped.sort_unstable();
        torn.sort_unstable();
        let max_abs_d = maps.iter().flatten().map(|m| m.d.abs()).fold(0.0, f64::max);
        Recheck {
            unmapped,
            flipped,
            torn,
            pinched: self.dense.pinched.iter().filter(|&&p| p).count(),
            ambiguous,
            max_abs_d,
            checks,
        }
    }

}

/// Base faces whose vertices [`State::recheck`] solves before it writes their maps.
/// Why: bounds what waits to be written (~56 bytes a vertex) while leaving each slice hundreds
/// of faces to share among the threads.
const RECHECK_SLICE_FACES: usize = 1024;

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
    /// Jump edges, largest jump, straddling triangles.
    pub checks: CheckStats,
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
    fn faces_around(&self, v: u32, out: &mut Vec<u32>) {
        let mut s = Vec::new();
        self.st.topo.faces_around(v, &mut s, out);
    }
    fn mode(&self) -> NormalMode {
        self.st.mode
    }
    fn dmax(&self) -> f64 {
        self.st.dmax
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
