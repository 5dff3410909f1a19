//! What an evaluator answers for a candidate collapse, and the [`Evaluator`] interface the
//! rounds call: owned by the decimator, implemented by [`crate::eval::CpuEvaluator`] and the
//! GPU evaluator, so that the decimator depends on no evaluator.

use super::{Candidate, Snapshot};
use crate::error::GpuError;
use crate::guarantee::{FailAt, Map, Reject};
use glam::DVec3;

/// An accepted candidate: which placement passed, and everything commit needs.
#[derive(Clone, Debug)]
pub struct Accepted {
    pub placement: usize,
    pub position: DVec3,
    /// New directions of the kept vertex and its ring.
    pub new_dirs: Vec<(u32, DVec3)>,
    /// New maps of `Candidate::dense`, in the same order.
    pub maps: Vec<Map>,
    /// Vertices associated outside the region whose primary moves onto it, ascending.
    pub extras: Vec<(u32, Map)>,
    /// Base faces outside the neighbourhood that the test read (far primaries, bisection
    /// midpoints), ascending: a commit that changes one of them first makes this stale.
    pub read_faces: Vec<u32>,
    /// Dense vertices whose maps the test read, ascending: every corner of the candidate's
    /// dense faces among them (a commit's stale test reads this list alone).
    pub read_vertices: Vec<u32>,
    /// Seconds the candidate's test took, all placements tried (as the stage clock counts a
    /// candidate: wall time on the thread that ran it; on the GPU path the CPU side of each
    /// placement, the shared dispatch not counted): what a deferral throws away.
    pub test_s: f64,
}

/// A candidate whose every placement failed.
#[derive(Clone, Debug, PartialEq)]
pub struct Rejected {
    /// Why the first placement failed.
    pub reason: Reject,
    /// Where the checks failed: the next try of the same collapse tests these first.
    pub at: Vec<FailAt>,
}

/// The result of evaluating one candidate: accepted, or rejected.
pub type Outcome = Result<Accepted, Rejected>;

/// Evaluates batches of candidate collapses.
pub trait Evaluator: Sync {
    /// The backend and adapter, for reports.
    fn name(&self) -> String;
    /// Evaluates every candidate of a batch against the round's snapshot of the state (the
    /// queue, fail memo and counters out of its reach); outcomes in batch order. Fails only
    /// when the device fails (never for a candidate).
    fn evaluate(&self, snap: &Snapshot, batch: &[Candidate]) -> Result<Vec<Outcome>, GpuError>;
}
