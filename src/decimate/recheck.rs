//! The decimator's from-scratch re-check of its own state (SPEC §2): every dense vertex solved
//! again over the 2-ring of its base face, then the exact orientation and continuity checks of
//! SPEC §1. The independent check is [`crate::validate`]; this one reads the decimator's state.

use crate::decimate::State;
use crate::topology::INVALID;
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
                    match check_face(&ctx, dense, f, false, self.loops, &mut sc, &mut stats) {
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

/// Base faces whose 2-ring and bounds a [`PointMemo`] keeps, direct-mapped by face id. Why: a
/// re-check's bisection and exit points mostly ask for the faces of the few before them (the
/// bunny stopped at 34,725 faces: the re-check 3.7 s without a memo, most of it assembling
/// 2-rings again); 1,024 slots hold ~0.4 MB a scratch.
const POINT_MEMO_SLOTS: usize = 1024;

/// What the re-check keeps between its point searches on one scratch: the last point's
/// triangles and their faces, and base faces' 2-rings and bounds.
#[derive(Default)]
struct PointMemo {
    key: Option<(u32, u32)>,
    tris: Tris,
    rings: Vec<(u32, Vec<u32>)>,
    bounds: Vec<Option<(u32, crate::guarantee::TriBounds)>>,
    both: Vec<u32>,
}

impl PointMemo {
    /// Face `f`'s 2-ring (ascending), from its slot or computed into it.
    fn ring(&mut self, st: &State, f: u32) -> &[u32] {
        if self.rings.is_empty() {
            self.rings = vec![(INVALID, Vec::new()); POINT_MEMO_SLOTS];
        }
        let slot = &mut self.rings[f as usize % POINT_MEMO_SLOTS];
        if slot.0 != f {
            st.two_ring_faces(f, &mut slot.1);
            slot.0 = f;
        }
        &slot.1
    }

    /// Face `f`'s bounds ([`crate::decimate::Snapshot::bounds_of`]), from its slot or derived
    /// into it.
    fn bounds(&mut self, st: &State, f: u32) -> crate::guarantee::TriBounds {
        if self.bounds.is_empty() {
            self.bounds = vec![None; POINT_MEMO_SLOTS];
        }
        let slot = &mut self.bounds[f as usize % POINT_MEMO_SLOTS];
        match *slot {
            Some((g, b)) if g == f => b,
            _ => {
                let b = st.bounds_of(f);
                *slot = Some((f, b));
                b
            }
        }
    }

    /// The triangles of fa's 2-ring, then those of fb's that are not in it, into `tris`.
    fn assemble(&mut self, st: &State, fa: u32, fb: u32, tris: &mut Tris) {
        let mut both = std::mem::take(&mut self.both);
        both.clear();
        both.extend_from_slice(self.ring(st, fa));
        let n = both.len();
        if fb != fa {
            for &g in self.ring(st, fb) {
                if both[..n].binary_search(&g).is_err() {
                    both.push(g);
                }
            }
        }
        tris.clear();
        for &g in &both {
            let b = self.bounds(st, g);
            st.push_face(tris, g, &b);
        }
        tris.finish();
        self.both = both;
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
        // The 2-ring of fa, then the faces of fb's 2-ring not in it (each part ascending),
        // from the scratch's memo (it lives within one re-check: the state does not change
        // under it).
        let mut memo: Box<PointMemo> = scratch.take_context_memo();
        let mut tris = std::mem::take(&mut memo.tris);
        if memo.key != Some((fa, fb)) {
            memo.assemble(self.st, fa, fb, &mut tris);
            memo.key = Some((fa, fb));
        }
        let r = match find_primary(x, normals, &tris, self.st.mode, self.st.dmax, true, false, scratch) {
            Found::Hit(t, h) => Some(Map { face: tris.ids[t], bary: h.bary, d: h.d }),
            _ => None,
        };
        memo.tris = tris;
        scratch.keep_context_memo(memo);
        r
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::decimate::Options;
    use crate::eval::CpuEvaluator;

    /// The memo's triangles for a point between faces fa and fb are what assembling the two
    /// 2-rings afresh gives, face for face and bound for bound (the re-check's verdicts hang on
    /// the order: ties between faces go by it), whatever the memo held before: pairs in an
    /// order that evicts its slots.
    #[test]
    fn the_point_memo_assembles_what_the_two_rings_give() {
        let mesh = crate::mesh::sample::generate(crate::mesh::sample::SampleSpec { faces: 3000, seed: 7 });
        let dense = crate::mesh::check_and_compact(std::path::Path::new("sample"), mesh).unwrap();
        let opts = Options { target_faces: 1200, ..Options::default() };
        let mut st = State::new(&dense, &opts);
        st.run(&CpuEvaluator, &opts, |_| {}).unwrap();
        let live: Vec<u32> = (0..st.topo.num_faces_total() as u32).filter(|&f| st.topo.face_alive(f)).collect();
        assert!(live.len() > POINT_MEMO_SLOTS, "enough faces to evict the memo's slots");
        // The reference: fa's 2-ring, then fb's faces not in it, each from `two_ring_tris`.
        let fresh = |fa: u32, fb: u32| {
            let (mut a, mut b) = (Tris::default(), Tris::default());
            st.two_ring_tris(fa, &mut a);
            st.two_ring_tris(fb, &mut b);
            for t in 0..b.len() {
                if a.index_of(b.ids[t]).is_none() {
                    a.push(b.ids[t], b.verts[t], b.pos[t], b.dir[t]);
                }
            }
            a
        };
        let mut memo = PointMemo::default();
        let mut tris = Tris::default();
        let mut pairs = 0;
        for (i, &fa) in live.iter().enumerate() {
            // A neighbour's face, the same face, and one far off in the list.
            let (mut s, mut around) = (Vec::new(), Vec::new());
            st.topo.faces_around(st.topo.face(fa)[0], &mut s, &mut around);
            let neighbour = around.into_iter().filter(|&g| g != fa).max().unwrap_or(fa);
            for fb in [neighbour, fa, live[(i * 7 + 13) % live.len()]] {
                memo.assemble(&st, fa, fb, &mut tris);
                let want = fresh(fa, fb);
                assert_eq!(tris.ids, want.ids, "faces {fa}, {fb}");
                let bits = |t: &Tris| t.sphere.iter().map(|(c, r)| (c.to_array().map(f64::to_bits), r.to_bits())).collect::<Vec<_>>();
                assert_eq!(bits(&tris), bits(&want), "bounds of faces {fa}, {fb}");
                pairs += 1;
            }
        }
        assert!(pairs >= 3 * POINT_MEMO_SLOTS);
    }
}
