//! The CPU reference evaluator of candidate collapses, [`CpuEvaluator`] (rayon over the batch).
//! The interface it implements ([`Evaluator`], [`Outcome`]) belongs to the decimator that calls
//! it ([`crate::decimate::outcome`]); the predicates every test shares live in
//! [`crate::guarantee`]. Both are re-exported here for callers of the evaluators.

pub use crate::decimate::outcome::{Accepted, Evaluator, Outcome, Rejected};
pub use crate::guarantee::*;
use crate::decimate::{Candidate, State};
use rayon::prelude::*;


/// The reference evaluator: Rust, parallel over the batch with rayon.
pub struct CpuEvaluator;

impl Evaluator for CpuEvaluator {
    fn name(&self) -> String {
        format!("cpu ({} threads)", rayon::current_num_threads())
    }
    fn evaluate(&self, state: &State, batch: &[Candidate]) -> Result<Vec<Outcome>, crate::error::GpuError> {
        if batch.len() == 1 {
            return Ok(vec![state.evaluate_candidate(&batch[0])]);
        }
        Ok(batch.par_iter().map(|c| state.evaluate_candidate(c)).collect())
    }
}
