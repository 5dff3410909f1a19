//! The map in a real tool: Blender rebuilds the bunny and the horse from dispdec's base and
//! vector map with the README's settings (scripts/blender_displace.py), and the result is
//! measured against the scan both ways. Blender reads the EXR itself, so the test also checks
//! that an independent reader gets the PFM's values.
//!
//! Needs Blender (`apt-get install blender`): opt-in, run with
//! `cargo test --release --test blender -- --ignored`.

mod common;
use common::*;
use std::path::Path;

fn ok(args: &[&str]) -> String {
    let o = run(args);
    let err = String::from_utf8_lossy(&o.stderr).to_string();
    assert_eq!(o.status.code(), Some(0), "{args:?}: {err}");
    err
}

fn s(p: &Path) -> &str {
    p.to_str().unwrap()
}

/// A PFM's floats, rows bottom to top as stored (channels interleaved).
fn pfm_values(p: &Path) -> (usize, usize, Vec<f32>) {
    let b = std::fs::read(p).unwrap();
    let end = b.iter().enumerate().filter(|(_, &c)| c == b'\n').nth(2).unwrap().0 + 1;
    let head = String::from_utf8_lossy(&b[..end]).to_string();
    let mut it = head.split_whitespace();
    let channels = if it.next() == Some("PF") { 3 } else { 1 };
    let w: usize = it.next().unwrap().parse().unwrap();
    let v = b[end..].chunks_exact(4).map(|c| f32::from_le_bytes(c.try_into().unwrap())).collect();
    (w, channels, v)
}

fn rebuild_in_blender(scan_name: &str) {
    let Some(scan) = real_scan(scan_name) else { return };
    let dir = tempdir(&format!("blender-{scan_name}"));
    let base = dir.join("base.obj");
    let map = dir.join("base.map");
    ok(&["decimate", s(&scan), "-o", s(&base), "--map", s(&map), "-q"]);
    let exr = dir.join("disp.exr");
    ok(&["bake", s(&scan), s(&base), "-o", s(&exr), "--kind", "vector", "--resolution", "2048"]);
    let pfm = dir.join("disp-v.pfm");
    ok(&["bake", s(&scan), s(&base), "-o", s(&pfm), "--kind", "vector", "--resolution", "2048"]);
    let uv_obj = dir.join("disp.obj");
    assert!(uv_obj.exists(), "bake writes the base with UVs beside the map");
    let out = dir.join("blender.obj");
    let pixels = dir.join("pixels.f32");
    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("scripts/blender_displace.py");
    let o = std::process::Command::new("blender")
        .args(["-b", "--factory-startup", "--python", s(&script), "--", s(&uv_obj), s(&exr), s(&out), "5", s(&pixels)])
        .output();
    let o = match o {
        Ok(o) => o,
        Err(e) => panic!("Blender did not run ({e}): apt-get install blender"),
    };
    assert!(o.status.success() && out.exists(), "blender: {}", String::from_utf8_lossy(&o.stdout));

    // Blender's own EXR reader against the PFM: RGBA against RGB, both rows bottom to top.
    let (w, c, v) = pfm_values(&pfm);
    assert_eq!(c, 3);
    let px: Vec<f32> = std::fs::read(&pixels).unwrap().chunks_exact(4).map(|b| f32::from_le_bytes(b.try_into().unwrap())).collect();
    assert_eq!(px.len(), 4 * w * w);
    let mut same = 0;
    for i in 0..w * w {
        for k in 0..3 {
            let (a, b) = (v[3 * i + k], px[4 * i + k]);
            assert!(a.to_bits() == b.to_bits() || (a.is_nan() && b.is_nan()), "texel {i} channel {k}: PFM {a}, EXR in Blender {b}");
            same += 1;
        }
    }
    eprintln!("{scan_name}: EXR as Blender reads it = PFM, {same} values");

    // The evaluated mesh against the scan, both ways; NaN vertices (the scan's holes) dropped.
    let m = dispdec::mesh::load_raw(&out).unwrap();
    let mut id = vec![u32::MAX; m.positions.len()];
    let mut positions = Vec::new();
    for (i, p) in m.positions.iter().enumerate() {
        if p.is_finite() {
            id[i] = positions.len() as u32;
            positions.push(*p);
        }
    }
    let faces: Vec<[u32; 3]> = m.faces.iter().filter(|f| f.iter().all(|&v| id[v as usize] != u32::MAX)).map(|f| f.map(|v| id[v as usize])).collect();
    eprintln!("{scan_name}: {} of {} Blender vertices displaced (the rest lie over the scan's holes: NaN)", positions.len(), m.positions.len());
    let rebuilt = dispdec::maps::reconstruct::Rebuilt { positions, faces };
    let hi = dispdec::mesh::load_dense(&scan).unwrap();
    let d = dispdec::maps::reconstruct::compare(&rebuilt, 5, &hi.positions, &hi.faces);
    eprintln!("{scan_name}: Blender, Simple subdivision level 5 + Displace (vector EXR): {d:?}");
    // dispdec's own reconstruction at the same level, for comparison.
    let scalar = dir.join("disp-s.pfm");
    ok(&["bake", s(&scan), s(&base), "-o", s(&scalar), "--resolution", "2048"]);
    let said = ok(&["reconstruct", s(&base), s(&scalar), "--levels", "5", "-o", s(&dir.join("r5.obj")), "--compare", s(&scan)]);
    eprintln!("{scan_name}: dispdec reconstruct:\n{said}");
    assert!(d.rms_to_scan <= 1e-3 && d.rms_from_scan <= 1e-3, "{d:?}");
    assert!(d.hausdorff_to_scan <= 1e-2 && d.hausdorff_from_scan <= 1e-2, "{d:?}");
}

#[test]
#[ignore = "needs Blender: cargo test --release --test blender -- --ignored"]
fn blender_rebuilds_the_horse_from_the_vector_map() {
    rebuild_in_blender("horse.ply.gz");
}

#[test]
#[ignore = "needs Blender: cargo test --release --test blender -- --ignored"]
fn blender_rebuilds_the_bunny_from_the_vector_map() {
    rebuild_in_blender("bunny.ply.gz");
}
