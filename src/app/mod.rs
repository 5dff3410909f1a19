//! One job per command, options in, files and report out: [`run`] (`decimate`, `validate`, and
//! the jobs on a base's map) and [`bench`] (`dispdec bench`).

pub mod bench;
pub mod run;
