//! Errors that cross module boundaries: what the GPU path can fail with, named here so that
//! the decimator, the evaluators and the validator can carry it without depending on [`crate::gpu`].

/// Why no GPU work could start.
#[derive(Debug, thiserror::Error, serde::Serialize, serde::Deserialize)]
pub enum GpuError {
    #[error("no GPU adapter for backends {backends}: {reason} (on Linux, install Mesa's lavapipe: apt-get install mesa-vulkan-drivers libvulkan1)")]
    NoAdapter { backends: String, reason: String },
    #[error("cannot open the GPU device {adapter}: {reason}")]
    Device { adapter: String, reason: String },
    #[error("GPU readback failed: {0}")]
    Readback(String),
    #[error("the GPU rejected the shell kernels: {0}")]
    Shader(String),
    #[error("{what} take {bytes} bytes, more than one GPU buffer binding may hold ({limit} bytes)")]
    TooLarge { what: String, bytes: u64, limit: u64 },
}
