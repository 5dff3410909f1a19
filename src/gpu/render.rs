//! `dispdec render`: meshes side by side in one image, headless (works on lavapipe), with a
//! fixed orthographic camera and flat two-sided shading — the README's Fig. 6 row.

use crate::gpu::{Gpu, GpuError};
use glam::{DMat3, DVec3};

/// WGSL of the render pipeline.
pub const RENDER_WGSL: &str = include_str!("../../shaders/render.wgsl");

/// One vertex as the shader reads it: clip-space position, the face normal and the albedo.
#[repr(C)]
#[derive(Clone, Copy, Debug, bytemuck::Pod, bytemuck::Zeroable)]
pub struct Vertex {
    pub position: [f32; 3],
    pub normal: [f32; 3],
    pub color: [f32; 3],
}

/// The meshes' albedo: a light blue-grey.
pub const MESH_COLOR: [f32; 3] = [0.74, 0.77, 0.84];

/// The albedo of marked triangles (`render --mark`): red, as the fold image's holes.
pub const MARK_COLOR: [f32; 3] = [0.9, 0.08, 0.06];

/// Camera and image options.
#[derive(Clone, Copy, Debug)]
pub struct View {
    /// Pixels per mesh (each mesh gets a size × size slot).
    pub size: u32,
    /// Rotation about the vertical axis, then about the horizontal one, in degrees.
    pub yaw: f64,
    pub pitch: f64,
}

/// Flat-shaded vertices of every mesh, fitted into its slot (slots left to right), then those
/// of `marks` in red, fitted as the first mesh is (so that triangles taken from it lie exactly
/// on it: drawn last at the same depth, they win the depth test).
pub fn layout(meshes: &[(Vec<DVec3>, Vec<[u32; 3]>)], marks: Option<&(Vec<DVec3>, Vec<[u32; 3]>)>, view: &View) -> Vec<Vertex> {
    let rot = DMat3::from_rotation_x(view.pitch.to_radians()) * DMat3::from_rotation_y(view.yaw.to_radians());
    let n = meshes.len().max(1) as f64;
    let mut out = Vec::new();
    // Slot i's fit of the rotated points `p` into clip space.
    let frame = |i: usize, p: &[DVec3]| {
        let lo = p.iter().fold(DVec3::splat(f64::INFINITY), |a, &b| a.min(b));
        let hi = p.iter().fold(DVec3::splat(f64::NEG_INFINITY), |a, &b| a.max(b));
        let c = 0.5 * (lo + hi);
        let r = (0.5 * (hi - lo)).max_element().max(1e-12);
        let depth = 0.5 * (hi - lo).length().max(1e-12);
        move |q: DVec3| -> [f32; 3] {
            let l = (q - c) / r * 0.92;
            [(((i as f64 + 0.5 + 0.5 * l.x) / n) * 2.0 - 1.0) as f32, l.y as f32, (0.5 - 0.45 * (q.z - c.z) / depth) as f32]
        }
    };
    let push = |out: &mut Vec<Vertex>, p: &[DVec3], faces: &[[u32; 3]], fit: &dyn Fn(DVec3) -> [f32; 3], color: [f32; 3]| {
        for f in faces {
            let t = f.map(|v| p[v as usize]);
            let nrm = (t[1] - t[0]).cross(t[2] - t[0]).normalize_or_zero();
            for q in t {
                out.push(Vertex { position: fit(q), normal: [nrm.x as f32, nrm.y as f32, nrm.z as f32], color });
            }
        }
    };
    let mut first_fit = None;
    for (i, (pos, faces)) in meshes.iter().enumerate() {
        let p: Vec<DVec3> = pos.iter().map(|&q| rot * q).collect();
        let fit = frame(i, &p);
        push(&mut out, &p, faces, &fit, MESH_COLOR);
        if i == 0 {
            first_fit = Some(fit);
        }
    }
    if let (Some((pos, faces)), Some(fit)) = (marks, first_fit) {
        let p: Vec<DVec3> = pos.iter().map(|&q| rot * q).collect();
        push(&mut out, &p, faces, &fit, MARK_COLOR);
    }
    out
}

/// Renders the meshes into an RGBA8 image (width = size × meshes, height = size).
/// `marks` (if any) are drawn in red over the first mesh ([`layout`]).
pub fn render(gpu: &Gpu, meshes: &[(Vec<DVec3>, Vec<[u32; 3]>)], marks: Option<&(Vec<DVec3>, Vec<[u32; 3]>)>, view: &View) -> Result<(u32, u32, Vec<u8>), GpuError> {
    let (w, h) = (view.size * meshes.len().max(1) as u32, view.size);
    let device = &gpu.device;
    let verts = layout(meshes, marks, view);
    let module = device.create_shader_module(wgpu::ShaderModuleDescriptor {
        label: Some("render.wgsl"),
        source: wgpu::ShaderSource::Wgsl(RENDER_WGSL.into()),
    });
    let vbuf = device.create_buffer(&wgpu::BufferDescriptor {
        label: Some("vertices"),
        size: (std::mem::size_of::<Vertex>() * verts.len().max(1)) as u64,
        usage: wgpu::BufferUsages::VERTEX | wgpu::BufferUsages::COPY_DST,
        mapped_at_creation: false,
    });
    gpu.queue.write_buffer(&vbuf, 0, bytemuck::cast_slice(&verts));
    let layout = device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
        label: Some("render"),
        bind_group_layouts: &[],
        immediate_size: 0,
    });
    let format = wgpu::TextureFormat::Rgba8Unorm;
    let attrs = wgpu::vertex_attr_array![0 => Float32x3, 1 => Float32x3, 2 => Float32x3];
    let pipeline = device.create_render_pipeline(&wgpu::RenderPipelineDescriptor {
        label: Some("render"),
        layout: Some(&layout),
        vertex: wgpu::VertexState {
            module: &module,
            entry_point: Some("vs_main"),
            compilation_options: Default::default(),
            buffers: &[Some(wgpu::VertexBufferLayout {
                array_stride: std::mem::size_of::<Vertex>() as u64,
                step_mode: wgpu::VertexStepMode::Vertex,
                attributes: &attrs,
            })],
        },
        primitive: wgpu::PrimitiveState { cull_mode: None, ..Default::default() },
        depth_stencil: Some(wgpu::DepthStencilState {
            format: wgpu::TextureFormat::Depth32Float,
            depth_write_enabled: Some(true),
            // LessEqual: a marked triangle, drawn after the mesh it was taken from at the same depth,
            // covers it.
            depth_compare: Some(wgpu::CompareFunction::LessEqual),
            stencil: Default::default(),
            bias: Default::default(),
        }),
        multisample: Default::default(),
        fragment: Some(wgpu::FragmentState {
            module: &module,
            entry_point: Some("fs_main"),
            compilation_options: Default::default(),
            targets: &[Some(wgpu::ColorTargetState { format, blend: None, write_mask: wgpu::ColorWrites::ALL })],
        }),
        multiview_mask: None,
        cache: None,
    });
    let extent = wgpu::Extent3d { width: w, height: h, depth_or_array_layers: 1 };
    let target = device.create_texture(&wgpu::TextureDescriptor {
        label: Some("color"),
        size: extent,
        mip_level_count: 1,
        sample_count: 1,
        dimension: wgpu::TextureDimension::D2,
        format,
        usage: wgpu::TextureUsages::RENDER_ATTACHMENT | wgpu::TextureUsages::COPY_SRC,
        view_formats: &[],
    });
    let depth = device.create_texture(&wgpu::TextureDescriptor {
        label: Some("depth"),
        size: extent,
        mip_level_count: 1,
        sample_count: 1,
        dimension: wgpu::TextureDimension::D2,
        format: wgpu::TextureFormat::Depth32Float,
        usage: wgpu::TextureUsages::RENDER_ATTACHMENT,
        view_formats: &[],
    });
    let (tview, dview) = (target.create_view(&Default::default()), depth.create_view(&Default::default()));
    let row = (4 * w).div_ceil(256) * 256;
    let readback = device.create_buffer(&wgpu::BufferDescriptor {
        label: Some("readback"),
        size: (row * h) as u64,
        usage: wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
        mapped_at_creation: false,
    });
    let mut enc = device.create_command_encoder(&wgpu::CommandEncoderDescriptor { label: Some("render") });
    {
        let mut pass = enc.begin_render_pass(&wgpu::RenderPassDescriptor {
            label: Some("render"),
            color_attachments: &[Some(wgpu::RenderPassColorAttachment {
                view: &tview,
                depth_slice: None,
                resolve_target: None,
                ops: wgpu::Operations { load: wgpu::LoadOp::Clear(wgpu::Color::WHITE), store: wgpu::StoreOp::Store },
            })],
            depth_stencil_attachment: Some(wgpu::RenderPassDepthStencilAttachment {
                view: &dview,
                depth_ops: Some(wgpu::Operations { load: wgpu::LoadOp::Clear(1.0), store: wgpu::StoreOp::Store }),
                stencil_ops: None,
            }),
            timestamp_writes: None,
            occlusion_query_set: None,
            multiview_mask: None,
        });
        pass.set_pipeline(&pipeline);
        pass.set_vertex_buffer(0, vbuf.slice(..));
        pass.draw(0..verts.len() as u32, 0..1);
    }
    enc.copy_texture_to_buffer(
        wgpu::TexelCopyTextureInfo { texture: &target, mip_level: 0, origin: wgpu::Origin3d::ZERO, aspect: wgpu::TextureAspect::All },
        wgpu::TexelCopyBufferInfo {
            buffer: &readback,
            layout: wgpu::TexelCopyBufferLayout { offset: 0, bytes_per_row: Some(row), rows_per_image: Some(h) },
        },
        extent,
    );
    gpu.queue.submit([enc.finish()]);
    let (tx, rx) = std::sync::mpsc::channel();
    readback.map_async(wgpu::MapMode::Read, .., move |r| {
        let _ = tx.send(r);
    });
    device.poll(wgpu::PollType::wait_indefinitely()).map_err(|e| GpuError::Readback(e.to_string()))?;
    rx.recv().map_err(|e| GpuError::Readback(e.to_string()))?.map_err(|e| GpuError::Readback(e.to_string()))?;
    let data = readback.get_mapped_range(..).map_err(|e| GpuError::Readback(e.to_string()))?;
    let mut rgba = Vec::with_capacity((4 * w * h) as usize);
    for y in 0..h as usize {
        rgba.extend_from_slice(&data[y * row as usize..y * row as usize + 4 * w as usize]);
    }
    drop(data);
    readback.unmap();
    Ok((w, h, rgba))
}

/// RGBA8 pixels as a PNG.
pub fn png_rgba(w: u32, h: u32, rgba: &[u8]) -> Vec<u8> {
    let mut out = Vec::new();
    {
        let mut enc = png::Encoder::new(&mut out, w, h);
        enc.set_color(png::ColorType::Rgba);
        enc.set_depth(png::BitDepth::Eight);
        let mut wr = enc.write_header().expect("PNG header into memory");
        wr.write_image_data(rgba).expect("PNG data into memory");
    }
    out
}
