//! The only place that calls wgpu: device acquisition, kept apart from the work that uses it.

/// Why no GPU work could start.
#[derive(Debug, thiserror::Error)]
pub enum GpuError {
    #[error("no GPU adapter for backends {backends}: {reason} (on Linux, install Mesa's lavapipe: apt-get install mesa-vulkan-drivers libvulkan1)")]
    NoAdapter { backends: String, reason: String },
    #[error("cannot open the GPU device {adapter}: {reason}")]
    Device { adapter: String, reason: String },
    #[error("GPU readback failed: {0}")]
    Readback(String),
}

/// An opened device with its queue and the adapter's description.
pub struct Gpu {
    pub device: wgpu::Device,
    pub queue: wgpu::Queue,
    pub info: wgpu::AdapterInfo,
}

impl Gpu {
    /// Opens the first adapter of `backends` (tests ask for `Backends::VULKAN`, which lavapipe
    /// provides on headless machines).
    pub fn new(backends: wgpu::Backends) -> Result<Gpu, GpuError> {
        let mut desc = wgpu::InstanceDescriptor::new_without_display_handle();
        desc.backends = backends;
        let instance = wgpu::Instance::new(desc);
        let adapter = pollster::block_on(instance.request_adapter(&wgpu::RequestAdapterOptions {
            power_preference: wgpu::PowerPreference::HighPerformance,
            ..Default::default()
        }))
        .map_err(|e| GpuError::NoAdapter { backends: format!("{backends:?}"), reason: e.to_string() })?;
        let info = adapter.get_info();
        let (device, queue) = pollster::block_on(adapter.request_device(&wgpu::DeviceDescriptor {
            label: Some("dispdec"),
            required_features: wgpu::Features::empty(),
            required_limits: adapter.limits(),
            experimental_features: Default::default(),
            memory_hints: Default::default(),
            trace: Default::default(),
        }))
        .map_err(|e| GpuError::Device { adapter: info.name.clone(), reason: e.to_string() })?;
        Ok(Gpu { device, queue, info })
    }

    /// "name (backend)", for messages and reports.
    pub fn describe(&self) -> String {
        format!("{} ({:?})", self.info.name, self.info.backend)
    }
}
