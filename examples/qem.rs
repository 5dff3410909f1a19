//! A quadric-error base mesh (meshoptimizer's `simplify`, no displacement guarantee) of a given
//! face count, for comparison with dispdec's bases under `dispdec validate`:
//!
//!     cargo run --release --example qem -- SCAN FACES OUT.obj

fn main() {
    let args: Vec<String> = std::env::args().collect();
    if args.len() != 4 {
        eprintln!("usage: qem SCAN FACES OUT.obj");
        std::process::exit(2);
    }
    let scan = match dispdec::mesh::load_dense(std::path::Path::new(&args[1])) {
        Ok(m) => m,
        Err(e) => {
            eprintln!("qem: {e}");
            std::process::exit(2);
        }
    };
    let Ok(faces) = args[2].parse::<usize>() else {
        eprintln!("qem: FACES must be a number, got {}", args[2]);
        std::process::exit(2);
    };
    let verts: Vec<[f32; 3]> = scan.positions.iter().map(|p| [p.x as f32, p.y as f32, p.z as f32]).collect();
    let indices: Vec<u32> = scan.faces.iter().flatten().copied().collect();
    let adapter = meshopt::VertexDataAdapter::new(bytemuck::cast_slice(&verts), 12, 0).expect("vertex layout");
    let t = std::time::Instant::now();
    let out = meshopt::simplify(&indices, &adapter, faces * 3, 1.0, meshopt::SimplifyOptions::empty(), None);
    let ms = t.elapsed().as_secs_f64() * 1e3;
    let mut s = String::new();
    for p in &scan.positions {
        s.push_str(&format!("v {} {} {}\n", p.x, p.y, p.z));
    }
    for t in out.chunks_exact(3) {
        s.push_str(&format!("f {} {} {}\n", t[0] + 1, t[1] + 1, t[2] + 1));
    }
    if let Err(e) = dispdec::mesh::write_atomic(std::path::Path::new(&args[3]), s.as_bytes()) {
        eprintln!("qem: {e}");
        std::process::exit(2);
    }
    eprintln!("{}: {} -> {} faces in {ms:.1} ms (meshoptimizer simplify, one thread)", args[1], scan.faces.len(), out.len() / 3);
}
