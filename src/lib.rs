//! dispdec: mesh decimation for displacement mapping (Collins & Hilton), with the guarantee
//! checked.
//!
//! Modules, one concern each:
//! - [`mesh`]: mesh types, OBJ/PLY input, welding and `--repair` ([`mesh::repair`]), input
//!   checks, OBJ output;
//! - [`topology`]: half-edges on flat `u32` arrays, link condition, edge collapse;
//! - [`fold`]: the fold image (coverage of the base by the scan, per texel);
//! - [`geometry`]: pure kernels (normals, shell inversion, condition (4));
//! - [`guarantee`]: the predicates of SPEC §1 every check shares (primary search, continuity,
//!   orientation in intrinsic charts);
//! - [`eval`]: the [`eval::Evaluator`] trait and the CPU evaluator;
//! - [`local`]: the local test of one candidate collapse;
//! - [`bench`]: `dispdec bench`, CPU and GPU paths side by side, with meshoptimizer as reference;
//! - [`bake`]: the displacement map over the atlas, the guarantee's inverse (EXR, PFM, PNG16;
//!   scalar, normalized and vector conventions);
//! - [`export`]: the binary glTF of a base with its map;
//! - [`bvh`]: a triangle BVH (distance and line queries);
//! - [`decimate`]: queue, association, batch scheduler, commit;
//! - [`gpu`]: the only place that calls wgpu (device, shell kernel context, buffers);
//! - [`gpu_eval`]: the GPU evaluator and projection, their tolerance band, the WGSL constants;
//! - [`grid`]: uniform grids over dense vertices and base faces (the searches for smaller |d|);
//! - [`mapfile`]: the `BASE.map` binary format;
//! - [`plot`]: the error-against-level chart (PNG);
//! - [`recheck`]: the decimator's re-check of its own state;
//! - [`reconstruct`]: subdivision + displacement, and distances to the scan;
//! - [`render`]: headless wgpu render of meshes side by side;
//! - [`run`]: the library side of the `decimate` command (options in, files and report out);
//! - [`sample`]: the generator of the scan-like sample meshes in `data/`;
//! - [`stages`]: CPU clocks of the candidate test's stages (report, bench);
//! - [`settings`]: the settings a base records (BASE.obj, BASE.map) and their resolution
//!   against flags;
//! - [`validate`]: the independent, global check of a (scan, base) pair.

pub mod bake;
pub mod bench;
pub mod bvh;
pub mod decimate;
pub mod eval;
pub mod export;
pub mod fold;
pub mod geometry;
pub mod gpu;
pub mod gpu_eval;
pub mod grid;
pub mod guarantee;
pub mod local;
pub mod mapfile;
pub mod mesh;
pub mod plot;
pub mod recheck;
pub mod reconstruct;
pub mod render;
pub mod run;
pub mod sample;
pub mod settings;
pub mod stages;
pub mod topology;
pub mod validate;

/// Library errors. `Input` and `Usage` are the user's to fix (exit code 2).
#[derive(Debug, thiserror::Error)]
pub enum Error {
    #[error("{path}: {msg}")]
    Input { path: String, msg: String },
    #[error("{0}")]
    Usage(String),
    #[error("cannot write {path}: {msg}")]
    Output { path: String, msg: String },
    #[error(transparent)]
    Gpu(#[from] gpu::GpuError),
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
