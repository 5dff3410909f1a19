//! The batch evaluator of candidate collapses: the [`Evaluator`] trait and the CPU reference
//! [`CpuEvaluator`] (rayon over the batch). The predicates every test shares live in
//! [`crate::guarantee`].

pub use crate::guarantee::*;
use crate::decimate::{Candidate, State};
use glam::DVec3;
use rayon::prelude::*;


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
    /// Dense vertices whose maps the test read, ascending.
    pub read_vertices: Vec<u32>,
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
    /// Evaluates every candidate of a batch; outcomes in batch order. Fails only when the
    /// device fails (never for a candidate).
    fn evaluate(&self, state: &State, batch: &[Candidate]) -> Result<Vec<Outcome>, crate::gpu::GpuError>;
}

/// The reference evaluator: Rust, parallel over the batch with rayon.
pub struct CpuEvaluator;

impl Evaluator for CpuEvaluator {
    fn name(&self) -> String {
        format!("cpu ({} threads)", rayon::current_num_threads())
    }
    fn evaluate(&self, state: &State, batch: &[Candidate]) -> Result<Vec<Outcome>, crate::gpu::GpuError> {
        if batch.len() == 1 {
            return Ok(vec![state.evaluate_candidate(&batch[0])]);
        }
        Ok(batch.par_iter().map(|c| state.evaluate_candidate(c)).collect())
    }
}
