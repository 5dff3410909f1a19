//! Measures the fixed cost of one shell-kernel dispatch (upload, dispatch, readback) on the
//! first adapter, with 1 and with 10,000 trivial queries.
use dispdec::gpu::{Gpu, GpuQuery, GpuTri, ShellEntry, ShellKernel};
use std::time::Instant;

fn main() {
    let gpu = Gpu::new(wgpu::Backends::PRIMARY).expect("adapter");
    println!("adapter: {}", gpu.describe());
    let normals = vec![[0.0f32, 0.0, 1.0, 0.0]; 4];
    let k = ShellKernel::new(gpu, &dispdec::gpu::eval::shell_source(), &normals, &[0, 1, 2, 3], &[0, 1, 2]).expect("kernel");
    let tri = GpuTri { p0: [0.0, 0.0, 0.0, 0.0], p1: [1.0, 0.0, 0.0, 0.0], p2: [0.0, 1.0, 0.0, 0.0], n0: [0.0, 0.0, 1.0, 0.0], n1: [0.0, 0.0, 1.0, 0.0], n2: [0.0, 0.0, 1.0, 0.0], sphere: [0.3, 0.3, 0.0, 0.8] };
    for n in [1usize, 10_000] {
        let q = vec![GpuQuery { x: [0.2, 0.2, 0.1], vertex: 0, tri_start: 0, tri_count: 1, flags: 1, hint: u32::MAX }; n];
        let _ = k.run(ShellEntry::Candidates, 1.0, 0, &[tri], &[], &q).unwrap();
        let t = Instant::now();
        for _ in 0..200 {
            let _ = k.run(ShellEntry::Candidates, 1.0, 0, &[tri], &[], &q).unwrap();
        }
        println!("{n} queries: {:.3} ms per dispatch", t.elapsed().as_secs_f64() * 1000.0 / 200.0);
    }
}
