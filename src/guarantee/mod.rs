//! The guarantee of SPEC §1 as predicates that every check shares — the decimator's local test,
//! its re-check and the validator — so that all three judge by one definition:
//! - [`primary`]: the primary solution of a dense point over a set of base triangles;
//! - [`check`]: continuity of every dense edge's image and orientation of every dense
//!   triangle's image loop in an intrinsic chart of the base;
//! - [`chord`]: the first release's chord rule, kept only to report where it differs;
//! - [`ids`]: where an id (a base face, a dense vertex) sits in a list, in one probe;
//! - [`chunks`]: how a check splits its items over the threads and still reports the first
//!   failure in item order.

pub mod check;
pub mod chord;
pub mod chunks;
pub mod ids;
pub mod primary;

pub use check::{check_alone, check_face, check_faces, CheckOut, edge_image, loop_positive, CheckScratch, CheckStats, FailAt, FaceCheck, LoopSampling, MapContext, Sample};
pub use primary::*;
