//! dispdec: mesh decimation for displacement mapping (Collins & Hilton), with the guarantee
//! checked.
//!
//! Modules, in the order the data flows (file → mesh checks → dense data → rounds of pick →
//! evaluate → commit → checks → outputs):
//! - [`mesh`]: mesh types, OBJ/PLY input, welding and `--repair` ([`mesh::repair`]), input
//!   checks, the dense adjacency, OBJ output, the sample generator ([`mesh::sample`]);
//! - [`topology`]: half-edges on flat `u32` arrays, link condition, edge collapse;
//! - [`geometry`]: pure kernels (normals, shell inversion, condition (4)) and the triangle BVH
//!   ([`geometry::bvh`]);
//! - [`guarantee`]: the predicates of SPEC §1 every check shares (primary search, continuity,
//!   orientation in intrinsic charts);
//! - [`decimate`]: queue, association, rounds, commit; what each stage of the candidate test
//!   does for one (candidate, placement) ([`decimate::local`]), the re-check of its own state ([`decimate::recheck`]), the dense
//!   vertices of each base face ([`decimate::members`]), the grids of its searches
//!   ([`decimate::grid`]), the stage clocks ([`decimate::stages`]) and the
//!   interface its rounds call ([`decimate::outcome`]: [`decimate::Evaluator`], outcomes);
//! - [`eval`]: the candidate test as stages over a round ([`eval::pipeline`]: gather, hints,
//!   primaries, reach, checks), shared by both evaluators, and the CPU evaluator (the GPU's
//!   primaries stage is [`gpu::eval`]);
//! - [`gpu`]: the only place that calls wgpu (device, shell kernel context, buffers), the GPU
//!   evaluator and projection ([`gpu::eval`]) and the headless render ([`gpu::render`]);
//! - [`validate`]: the independent, global check of a (scan, base) pair;
//! - [`maps`]: atlas and fold image, bake, `BASE.map`, glTF export, reconstruction, plot;
//! - [`settings`]: the settings a base records (BASE.obj, BASE.map) and their resolution
//!   against flags;
//! - [`error`]: the GPU error every layer can carry without depending on [`gpu`];
//! - [`app`]: one job per command (`decimate`, `validate`, `bake`, …, `bench`) and its report;
//!   the process's peak memory and allocator setting ([`app::memory`]).

pub mod app;
pub mod decimate;
pub mod error;
pub mod eval;
pub mod geometry;
pub mod gpu;
pub mod guarantee;
pub mod maps;
pub mod mesh;
pub mod settings;
pub mod topology;
pub mod validate;

/// Library errors. `Input` and `Usage` are the user's to fix (exit code 2). Serializable: a
/// bench run's process hands its error to the bench's (`app::bench::RunOutcome`).
#[derive(Debug, thiserror::Error, serde::Serialize, serde::Deserialize)]
pub enum Error {
    #[error("{path}: {msg}")]
    Input { path: String, msg: String },
    #[error("{0}")]
    Usage(String),
    #[error("cannot write {path}: {msg}")]
    Output { path: String, msg: String },
    #[error(transparent)]
    Gpu(#[from] error::GpuError),
}

impl Error {
    /// The process exit code for this error (SPEC §6).
    pub fn exit_code(&self) -> i32 {
        match self {
            Error::Input { .. } | Error::Usage(_) => 2,
            Error::Output { .. } => 2,
            // The machine cannot do what was asked (no adapter, a device failure): not a
            // verdict, so not 1.
            Error::Gpu(_) => 2,
        }
    }
}
