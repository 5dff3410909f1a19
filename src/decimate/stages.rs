//! CPU clocks of the candidate test's stages, summed over threads (issue 10's per-stage
//! timers): where evaluation time goes, and how much of it is spent on candidates that fail.
//!
//! The clocks are atomics on the decimator's state, so parallel evaluation adds to them without
//! locks (the walks' counts, added once per placement, under a mutex); they are read once at the
//! end of a run. They never influence a decision.

use crate::guarantee::{PointWork, Reject};
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::Mutex;
use std::time::Instant;

/// The stages of one placement's test, in the order they run.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Stage {
    /// The collapsed neighbourhood and its new directions (fold-over test).
    Neighbourhood = 0,
    /// Primary solutions of the region's dense vertices.
    Primaries,
    /// Faces outside the neighbourhood that may hold a smaller |d|, vertices whose primary
    /// moves onto the region, (strict) second solutions on the ring.
    Reach,
    /// Continuity: every dense edge of the triangles around changed maps and around the
    /// vertices whose edges pass near the region, walked once (with the elements where the last
    /// try failed, tested first).
    Continuity,
    /// Orientation: every such triangle's image loop.
    Orientation,
}

const STAGES: [(Stage, &str); 5] = [
    (Stage::Neighbourhood, "neighbourhood"),
    (Stage::Primaries, "primaries"),
    (Stage::Reach, "reach"),
    (Stage::Continuity, "continuity"),
    (Stage::Orientation, "orientation"),
];

/// Nanoseconds per stage, plus the CPU time of whole candidates by outcome.
#[derive(Default)]
pub struct StageClock {
    ns: [AtomicU64; 5],
    accepted_ns: AtomicU64,
    rejected_ns: AtomicU64,
    placements: AtomicU64,
    /// Failed placements by reason (`Reject as usize`): count and nanoseconds.
    failed: [(AtomicU64, AtomicU64); 8],
    /// Dense triangles handed to the check, and of them those around vertices associated
    /// outside the region.
    faces: AtomicU64,
    near_faces: AtomicU64,
    /// What the continuity walks did (added once per placement).
    work: Mutex<PointWork>,
    /// Placements failed at a vertex an earlier try found unmapped, tested before the rest.
    unmapped_at_hint: AtomicU64,
    /// Placements failed at a dense triangle or edge an earlier try found torn or flipped,
    /// checked before the rest.
    torn_at_hint: AtomicU64,
    /// The longest whole-candidate time since [`StageClock::take_round_slowest`] last read it.
    round_slowest_ns: AtomicU64,
}

impl StageClock {
    /// Adds the time since `since` to `stage`; returns now (the next stage's start).
    pub fn lap(&self, stage: Stage, since: Instant) -> Instant {
        let now = Instant::now();
        self.ns[stage as usize].fetch_add((now - since).as_nanos() as u64, Ordering::Relaxed);
        now
    }

    /// Adds `ns` nanoseconds (measured by the stage itself, summed over its threads) to `stage`.
    pub fn add(&self, stage: Stage, ns: u64) {
        self.ns[stage as usize].fetch_add(ns, Ordering::Relaxed);
    }

    /// Adds a whole candidate's time (all its placements) by outcome.
    pub fn candidate(&self, accepted: bool, placements: usize, seconds: f64) {
        let ns = (seconds * 1e9) as u64;
        let slot = if accepted { &self.accepted_ns } else { &self.rejected_ns };
        slot.fetch_add(ns, Ordering::Relaxed);
        self.placements.fetch_add(placements as u64, Ordering::Relaxed);
        self.round_slowest_ns.fetch_max(ns, Ordering::Relaxed);
    }

    /// The longest time one candidate took (as [`StageClock::candidate`] measures it) since the
    /// last call, in seconds, and starts over: called once a round, after its evaluation.
    pub fn take_round_slowest(&self) -> f64 {
        self.round_slowest_ns.swap(0, Ordering::Relaxed) as f64 * 1e-9
    }

    /// Counts the dense triangles one placement hands to the check, and of them those around
    /// vertices associated outside the region.
    pub fn items(&self, faces: usize, near_faces: usize) {
        self.faces.fetch_add(faces as u64, Ordering::Relaxed);
        self.near_faces.fetch_add(near_faces as u64, Ordering::Relaxed);
    }

    /// Adds what one placement's continuity walks did.
    pub fn work(&self, w: &PointWork) {
        self.work.lock().unwrap_or_else(|e| e.into_inner()).add(w);
    }

    /// Counts a placement failed at an unmapped vertex tested first (see `unmapped_at_hint`).
    pub fn unmapped_at_hint(&self) {
        self.unmapped_at_hint.fetch_add(1, Ordering::Relaxed);
    }

    /// Counts a placement failed at a torn or flipped element tested first (see `torn_at_hint`).
    pub fn torn_at_hint(&self) {
        self.torn_at_hint.fetch_add(1, Ordering::Relaxed);
    }

    /// Adds one failed placement's time by the reason it failed.
    pub fn failed(&self, reason: Reject, seconds: f64) {
        let (n, ns) = &self.failed[reason as usize];
        n.fetch_add(1, Ordering::Relaxed);
        ns.fetch_add((seconds * 1e9) as u64, Ordering::Relaxed);
    }

    /// Placements failed so far by a flipped or torn dense triangle.
    pub fn flipped_or_torn(&self) -> u64 {
        [Reject::Flip, Reject::Tear].iter().map(|&r| self.failed[r as usize].0.load(Ordering::Relaxed)).sum()
    }

    /// The clocks in seconds, for the report.
    pub fn summary(&self) -> StageSummary {
        let s = |a: &AtomicU64| a.load(Ordering::Relaxed) as f64 * 1e-9;
        StageSummary {
            stages_cpu_s: STAGES.iter().map(|&(st, name)| (name.to_string(), s(&self.ns[st as usize]))).collect(),
            accepted_cpu_s: s(&self.accepted_ns),
            rejected_cpu_s: s(&self.rejected_ns),
            placements_tested: self.placements.load(Ordering::Relaxed),
            faces_checked: self.faces.load(Ordering::Relaxed),
            near_faces_checked: self.near_faces.load(Ordering::Relaxed),
            work: *self.work.lock().unwrap_or_else(|e| e.into_inner()),
            unmapped_at_hint: self.unmapped_at_hint.load(Ordering::Relaxed),
            torn_at_hint: self.torn_at_hint.load(Ordering::Relaxed),
            failed_placements: REASONS
                .iter()
                .filter(|&&r| self.failed[r as usize].0.load(Ordering::Relaxed) > 0)
                .map(|&r| {
                    let (n, ns) = &self.failed[r as usize];
                    (r.name().to_string(), n.load(Ordering::Relaxed), s(ns))
                })
                .collect(),
        }
    }
}

/// Where the candidate test's CPU time went (seconds summed over threads).
#[derive(Clone, Debug, Default, serde::Serialize)]
pub struct StageSummary {
    /// Per stage of a placement's test, in the order they run.
    pub stages_cpu_s: Vec<(String, f64)>,
    /// Whole candidates that passed (all placements tried until one passed). Measured from a
    /// candidate's start to its end on its thread: while its check waits for its chunks on
    /// other threads, that thread may run another candidate's work, so with more than one
    /// thread these two are upper bounds.
    pub accepted_cpu_s: f64,
    /// Whole candidates that failed every placement.
    pub rejected_cpu_s: f64,
    /// Placements tested (a candidate tests them in order until one passes).
    pub placements_tested: u64,
    /// Dense triangles (orientation and continuity) handed to the check, over all placements (a
    /// check stops at its first failure); of them, those around the vertices associated
    /// outside the region (whose primary moves onto it, or whose edges pass near it).
    pub faces_checked: u64,
    pub near_faces_checked: u64,
    /// What the continuity walks did over all placements: dense edges walked, and the points
    /// they solved — at exits from a base triangle and at bisection midpoints — of which
    /// how many searched the face grid beyond the candidate's outer faces.
    pub work: PointWork,
    /// Of the placements failed as unmapped, those failed at a vertex where an earlier
    /// placement or try of the same collapse found no solution, tested alone before the region's
    /// other vertices (the same verdict, without solving the rest).
    pub unmapped_at_hint: u64,
    /// Of the placements failed as torn or flipped, those failed at a dense triangle or edge
    /// where an earlier placement or try found a tear or flip, checked alone before the region's
    /// solve (the same verdict, without solving the rest).
    pub torn_at_hint: u64,
    /// Failed placements by reason: (reason, count, CPU seconds).
    pub failed_placements: Vec<(String, u64, f64)>,
}

const REASONS: [Reject; 8] = [
    Reject::Link,
    Reject::Boundary,
    Reject::Valence,
    Reject::Foldover,
    Reject::Unmapped,
    Reject::Flip,
    Reject::Tear,
    Reject::Ambiguous,
];

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_round_keeps_its_slowest_candidate_and_the_next_starts_over() {
        let clock = StageClock::default();
        let ago = |ms: u64| ms as f64 * 1e-3;
        clock.candidate(true, 1, ago(5));
        clock.candidate(false, 3, ago(20));
        clock.candidate(true, 2, ago(1));
        let slowest = clock.take_round_slowest();
        // The 20 ms candidate.
        assert_eq!(slowest, 0.020, "slowest {slowest}");
        assert_eq!(clock.take_round_slowest(), 0.0, "read once a round");
        clock.candidate(true, 1, ago(2));
        assert_eq!(clock.take_round_slowest(), 0.002);
    }
}
