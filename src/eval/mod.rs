//! The candidate test as stages over a round ([`pipeline`]) and the CPU reference evaluator,
//! [`CpuEvaluator`], which runs them in Rust (rayon over each stage's items).
//! The interface it implements ([`Evaluator`], [`Outcome`]) belongs to the decimator that calls
//! it ([`crate::decimate::outcome`]); the predicates every test shares live in
//! [`crate::guarantee`]. Both are re-exported here for callers of the evaluators.

pub use crate::decimate::outcome::{Accepted, Evaluator, Outcome, Rejected};
pub use crate::guarantee::*;
use crate::decimate::{Candidate, Snapshot};
pub mod pipeline;
use rayon::prelude::*;


/// The reference evaluator: the stages of [`pipeline`] in Rust, each parallel over its
/// items with rayon, with the f64 primaries stage ([`pipeline::CpuPrimaries`]).
pub struct CpuEvaluator;

impl Evaluator for CpuEvaluator {
    fn name(&self) -> String {
        format!("cpu ({} threads)", rayon::current_num_threads())
    }
    fn evaluate(&self, snap: &Snapshot, batch: &[Candidate]) -> Result<Vec<Outcome>, crate::error::GpuError> {
        // Each candidate's waves on their own (a round of one): a candidate whose placement
        // fails goes on to its next at once, not after the round's slowest first placement.
        let rounds: Result<Vec<Vec<Outcome>>, _> = batch.par_iter().map(|c| pipeline::evaluate_round(snap, std::slice::from_ref(c), &pipeline::CpuPrimaries)).collect();
        Ok(rounds?.into_iter().flatten().collect())
    }
}
