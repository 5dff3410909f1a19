//! The only place that calls wgpu: device acquisition, kept apart from the work that uses it.

pub mod eval;
pub mod render;

pub use crate::error::GpuError;

/// An opened device with its queue and the adapter's description.
pub struct Gpu {
    pub device: wgpu::Device,
    pub queue: wgpu::Queue,
    pub info: wgpu::AdapterInfo,
}

impl Gpu {
    /// Opens the first adapter of the platform's primary backends (Vulkan, Metal, DX12, the
    /// browser's WebGPU): what the commands use.
    pub fn open_primary() -> Result<Gpu, GpuError> {
        Self::new(wgpu::Backends::PRIMARY)
    }

    /// The name of the best hardware adapter of the primary backends, if there is one (nothing
    /// is opened): `--backend auto`'s question.
    pub fn primary_hardware_adapter() -> Result<Option<String>, GpuError> {
        Ok(Self::hardware_adapter_info(wgpu::Backends::PRIMARY)?.map(|info| info.name))
    }

    /// Opens the first adapter of `backends` (tests ask for `Backends::VULKAN`, which lavapipe
    /// provides on headless machines).
    pub fn new(backends: wgpu::Backends) -> Result<Gpu, GpuError> {
        let adapter = Self::adapter(backends)?;
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

    /// The first hardware adapter of `backends` (discrete, integrated or virtual GPU), or
    /// `None` when there are only software ones; nothing is opened. This is all `--backend auto`
    /// needs to know.
    pub fn hardware_adapter_info(backends: wgpu::Backends) -> Result<Option<wgpu::AdapterInfo>, GpuError> {
        let mut desc = wgpu::InstanceDescriptor::new_without_display_handle();
        desc.backends = backends;
        let instance = wgpu::Instance::new(desc);
        let adapters = pollster::block_on(instance.enumerate_adapters(backends));
        if adapters.is_empty() {
            return Err(GpuError::NoAdapter { backends: format!("{backends:?}"), reason: "no adapter found".into() });
        }
        let rank = |t: wgpu::DeviceType| match t {
            wgpu::DeviceType::DiscreteGpu => 0,
            wgpu::DeviceType::IntegratedGpu => 1,
            wgpu::DeviceType::VirtualGpu => 2,
            _ => 3,
        };
        Ok(adapters.iter().map(|a| a.get_info()).filter(|i| rank(i.device_type) < 3).min_by_key(|i| rank(i.device_type)))
    }

    /// The high-performance adapter of `backends`.
    fn adapter(backends: wgpu::Backends) -> Result<wgpu::Adapter, GpuError> {
        let mut desc = wgpu::InstanceDescriptor::new_without_display_handle();
        desc.backends = backends;
        let instance = wgpu::Instance::new(desc);
        pollster::block_on(instance.request_adapter(&wgpu::RequestAdapterOptions {
            power_preference: wgpu::PowerPreference::HighPerformance,
            ..Default::default()
        }))
        .map_err(|e| GpuError::NoAdapter { backends: format!("{backends:?}"), reason: e.to_string() })
    }

    /// "name (backend)", for messages and reports.
    pub fn describe(&self) -> String {
        format!("{} ({:?})", self.info.name, self.info.backend)
    }
}

// ---------------------------------------------------------------------------------------------
// The shell kernels (shaders/shell.wgsl): the GPU layout of their inputs and outputs, and a
// reusable context that owns the pipelines and buffers.

/// One base triangle: corners, vertex directions, bounding sphere (centre, radius in w).
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, bytemuck::Pod, bytemuck::Zeroable)]
pub struct GpuTri {
    pub p0: [f32; 4],
    pub p1: [f32; 4],
    pub p2: [f32; 4],
    pub n0: [f32; 4],
    pub n1: [f32; 4],
    pub n2: [f32; 4],
    pub sphere: [f32; 4],
}

/// One dense point to solve: position, dense vertex (for condition (4)), triangle range
/// (candidate batches only) and flags (`FLAG_CHECK4`, `FLAG_STRICT`).
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, bytemuck::Pod, bytemuck::Zeroable)]
pub struct GpuQuery {
    pub x: [f32; 3],
    pub vertex: u32,
    pub tri_start: u32,
    pub tri_count: u32,
    pub flags: u32,
    /// Index in the range of the triangle to search first, or `INVALID`.
    pub hint: u32,
}

/// The kernel's answer for one query: a status, the chosen triangle (index into the uploaded
/// triangles), its d and barycentrics, and the smallest |d| found on another triangle.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, bytemuck::Pod, bytemuck::Zeroable)]
pub struct GpuAnswer {
    pub tri: u32,
    pub status: u32,
    pub d: f32,
    pub second: f32,
    pub bary: [f32; 4],
}

/// A BVH node: a leaf when `b` has `LEAF_BIT` (triangles `a .. a + count`), else children.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, bytemuck::Pod, bytemuck::Zeroable)]
pub struct GpuNode {
    pub lo: [f32; 3],
    pub a: u32,
    pub hi: [f32; 3],
    pub b: u32,
}

/// Per-dispatch parameters (a uniform).
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, bytemuck::Pod, bytemuck::Zeroable)]
pub struct GpuParams {
    pub dmax: f32,
    pub mode: u32,
    pub query_count: u32,
    pub node_count: u32,
}

/// Which entry point of shell.wgsl to run.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ShellEntry {
    /// `evaluate_candidates`: each query searches its own triangle range.
    Candidates,
    /// `project_vertices`: each query searches every triangle through the BVH.
    Project,
}

/// Threads per workgroup of the shell kernels (generated into the WGSL).
pub const WORKGROUP_SIZE: u32 = 64;

struct Buffers {
    tris: wgpu::Buffer,
    nodes: wgpu::Buffer,
    queries: wgpu::Buffer,
    answers: wgpu::Buffer,
    readback: wgpu::Buffer,
    params: wgpu::Buffer,
}

/// The shell kernels on one device: pipelines, the dense mesh's static data (face normals and
/// vertex→face lists, for condition (4)), and buffers grown on demand and reused.
pub struct ShellKernel {
    gpu: Gpu,
    layout: wgpu::BindGroupLayout,
    candidates: wgpu::ComputePipeline,
    project: wgpu::ComputePipeline,
    dense_normals: wgpu::Buffer,
    vf_start: wgpu::Buffer,
    vf: wgpu::Buffer,
    buffers: std::sync::Mutex<Buffers>,
}

fn storage_entry(binding: u32, read_only: bool) -> wgpu::BindGroupLayoutEntry {
    wgpu::BindGroupLayoutEntry {
        binding,
        visibility: wgpu::ShaderStages::COMPUTE,
        ty: wgpu::BindingType::Buffer {
            ty: wgpu::BufferBindingType::Storage { read_only },
            has_dynamic_offset: false,
            min_binding_size: None,
        },
        count: None,
    }
}

fn make_buffer(device: &wgpu::Device, label: &str, size: u64, usage: wgpu::BufferUsages) -> wgpu::Buffer {
    device.create_buffer(&wgpu::BufferDescriptor { label: Some(label), size: size.max(64), usage, mapped_at_creation: false })
}

fn storage_with(device: &wgpu::Device, queue: &wgpu::Queue, label: &str, data: &[u8]) -> wgpu::Buffer {
    let buf = make_buffer(device, label, data.len() as u64, wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_DST);
    queue.write_buffer(&buf, 0, data);
    buf
}

impl ShellKernel {
    /// Compiles `source` (the generated shell.wgsl) and uploads the dense mesh's face normals
    /// (xyz, w unused) and its vertex→face lists (CSR).
    pub fn new(gpu: Gpu, source: &str, dense_normals: &[[f32; 4]], vf_start: &[u32], vf: &[u32]) -> Result<ShellKernel, GpuError> {
        let limit = gpu.device.limits().max_storage_buffer_binding_size;
        let biggest = (std::mem::size_of_val(dense_normals)).max(std::mem::size_of_val(vf)) as u64;
        if biggest > limit {
            return Err(GpuError::TooLarge { what: "dense mesh".into(), bytes: biggest, limit });
        }
        let device = &gpu.device;
        let scope = device.push_error_scope(wgpu::ErrorFilter::Validation);
        let module = device.create_shader_module(wgpu::ShaderModuleDescriptor {
            label: Some("shell.wgsl"),
            source: wgpu::ShaderSource::Wgsl(source.into()),
        });
        let mut entries = vec![wgpu::BindGroupLayoutEntry {
            binding: 0,
            visibility: wgpu::ShaderStages::COMPUTE,
            ty: wgpu::BindingType::Buffer { ty: wgpu::BufferBindingType::Uniform, has_dynamic_offset: false, min_binding_size: None },
            count: None,
        }];
        for b in 1..=6 {
            entries.push(storage_entry(b, true));
        }
        entries.push(storage_entry(7, false));
        let layout = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor { label: Some("shell"), entries: &entries });
        let pl = device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
            label: Some("shell"),
            bind_group_layouts: &[Some(&layout)],
            immediate_size: 0,
        });
        let pipeline = |entry: &str| {
            device.create_compute_pipeline(&wgpu::ComputePipelineDescriptor {
                label: Some(entry),
                layout: Some(&pl),
                module: &module,
                entry_point: Some(entry),
                compilation_options: Default::default(),
                cache: None,
            })
        };
        let candidates = pipeline("evaluate_candidates");
        let project = pipeline("project_vertices");
        if let Some(e) = pollster::block_on(scope.pop()) {
            return Err(GpuError::Shader(e.to_string()));
        }
        let queue = &gpu.queue;
        let dense_normals = storage_with(device, queue, "dense normals", bytemuck::cast_slice(dense_normals));
        let vf_start = storage_with(device, queue, "vf_start", bytemuck::cast_slice(vf_start));
        let vf = storage_with(device, queue, "vf", bytemuck::cast_slice(vf));
        let buffers = Buffers {
            tris: make_buffer(device, "tris", 0, wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_DST),
            nodes: make_buffer(device, "nodes", 0, wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_DST),
            queries: make_buffer(device, "queries", 0, wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_DST),
            answers: make_buffer(device, "answers", 0, wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_SRC),
            readback: make_buffer(device, "readback", 0, wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST),
            params: make_buffer(device, "params", 0, wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST),
        };
        Ok(ShellKernel {
            gpu,
            layout,
            candidates,
            project,
            dense_normals,
            vf_start,
            vf,
            buffers: std::sync::Mutex::new(buffers),
        })
    }

    pub fn gpu(&self) -> &Gpu {
        &self.gpu
    }

    /// Most queries one dispatch may carry: the workgroup-count limit and the largest binding.
    pub fn max_queries_per_dispatch(&self) -> usize {
        let l = self.gpu.device.limits();
        let by_groups = l.max_compute_workgroups_per_dimension as u64 * WORKGROUP_SIZE as u64;
        let by_bytes = l.max_storage_buffer_binding_size / std::mem::size_of::<GpuQuery>() as u64;
        by_groups.min(by_bytes).min(1 << 22) as usize
    }

    /// Runs `entry` over `queries` (split into dispatches that respect the adapter's limits)
    /// against `tris` (and `nodes` for [`ShellEntry::Project`]); one answer per query.
    pub fn run(
        &self,
        entry: ShellEntry,
        dmax: f32,
        mode: u32,
        tris: &[GpuTri],
        nodes: &[GpuNode],
        queries: &[GpuQuery],
    ) -> Result<Vec<GpuAnswer>, GpuError> {
        let device = &self.gpu.device;
        let queue = &self.gpu.queue;
        let limit = device.limits().max_storage_buffer_binding_size;
        for (what, bytes) in [("triangles", std::mem::size_of_val(tris)), ("BVH", std::mem::size_of_val(nodes))] {
            if bytes as u64 > limit {
                return Err(GpuError::TooLarge { what: what.into(), bytes: bytes as u64, limit });
            }
        }
        let mut out = Vec::with_capacity(queries.len());
        if queries.is_empty() {
            return Ok(out);
        }
        let mut bufs = self.buffers.lock().map_err(|_| GpuError::Readback("buffer lock poisoned".into()))?;
        let grow = |buf: &mut wgpu::Buffer, label: &str, need: u64, usage: wgpu::BufferUsages| {
            if buf.size() < need {
                *buf = make_buffer(device, label, need.next_power_of_two(), usage);
            }
        };
        let storage = wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_DST;
        grow(&mut bufs.tris, "tris", std::mem::size_of_val(tris) as u64, storage);
        grow(&mut bufs.nodes, "nodes", std::mem::size_of_val(nodes) as u64, storage);
        queue.write_buffer(&bufs.tris, 0, bytemuck::cast_slice(tris));
        queue.write_buffer(&bufs.nodes, 0, bytemuck::cast_slice(nodes));
        let chunk = self.max_queries_per_dispatch();
        let qsize = std::mem::size_of::<GpuQuery>() as u64;
        let asize = std::mem::size_of::<GpuAnswer>() as u64;
        let n_first = queries.len().min(chunk) as u64;
        grow(&mut bufs.queries, "queries", n_first * qsize, storage);
        grow(&mut bufs.answers, "answers", n_first * asize, wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_SRC);
        grow(&mut bufs.readback, "readback", n_first * asize, wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST);
        let bind = device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some("shell"),
            layout: &self.layout,
            entries: &[
                wgpu::BindGroupEntry { binding: 0, resource: bufs.params.as_entire_binding() },
                wgpu::BindGroupEntry { binding: 1, resource: bufs.tris.as_entire_binding() },
                wgpu::BindGroupEntry { binding: 2, resource: bufs.queries.as_entire_binding() },
                wgpu::BindGroupEntry { binding: 3, resource: self.dense_normals.as_entire_binding() },
                wgpu::BindGroupEntry { binding: 4, resource: self.vf_start.as_entire_binding() },
                wgpu::BindGroupEntry { binding: 5, resource: self.vf.as_entire_binding() },
                wgpu::BindGroupEntry { binding: 6, resource: bufs.nodes.as_entire_binding() },
                wgpu::BindGroupEntry { binding: 7, resource: bufs.answers.as_entire_binding() },
            ],
        });
        let pipeline = match entry {
            ShellEntry::Candidates => &self.candidates,
            ShellEntry::Project => &self.project,
        };
        for part in queries.chunks(chunk) {
            let params = GpuParams { dmax, mode, query_count: part.len() as u32, node_count: nodes.len() as u32 };
            queue.write_buffer(&bufs.params, 0, bytemuck::bytes_of(&params));
            queue.write_buffer(&bufs.queries, 0, bytemuck::cast_slice(part));
            let bytes = part.len() as u64 * asize;
            let mut enc = device.create_command_encoder(&wgpu::CommandEncoderDescriptor { label: Some("shell") });
            {
                let mut pass = enc.begin_compute_pass(&wgpu::ComputePassDescriptor { label: Some("shell"), timestamp_writes: None });
                pass.set_pipeline(pipeline);
                pass.set_bind_group(0, &bind, &[]);
                pass.dispatch_workgroups((part.len() as u32).div_ceil(WORKGROUP_SIZE), 1, 1);
            }
            enc.copy_buffer_to_buffer(&bufs.answers, 0, &bufs.readback, 0, bytes);
            queue.submit([enc.finish()]);
            let (tx, rx) = std::sync::mpsc::channel();
            bufs.readback.slice(..bytes).map_async(wgpu::MapMode::Read, move |r| {
                let _ = tx.send(r);
            });
            device.poll(wgpu::PollType::wait_indefinitely()).map_err(|e| GpuError::Readback(e.to_string()))?;
            rx.recv().map_err(|e| GpuError::Readback(e.to_string()))?.map_err(|e| GpuError::Readback(e.to_string()))?;
            {
                let data = bufs.readback.get_mapped_range(..bytes).map_err(|e| GpuError::Readback(e.to_string()))?;
                out.extend_from_slice(bytemuck::cast_slice(&data));
            }
            bufs.readback.unmap();
        }
        Ok(out)
    }
}
