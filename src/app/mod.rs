//! One job per command, options in, files and report out: [`run`] (`decimate`, `validate`, and
//! the jobs on a base's map) and [`bench`] (`dispdec bench`); [`memory`] measures what they
//! hold; [`outputs`] keeps every command's outputs off its inputs.

pub mod bench;
pub mod memory;
pub mod outputs;
pub mod run;
