//! `dispdec bake` and `dispdec reconstruct`: the two map formats agree, level 0 is the base,
//! reconstructions are closed where the base is, and on the horse the error falls with every
//! level to the paper's Fig. 6 quality.

mod common;
use common::*;
use dispdec::bake::DispMap;

fn ok(args: &[&str]) -> String {
    let o = run(args);
    let err = String::from_utf8_lossy(&o.stderr).to_string();
    assert_eq!(o.status.code(), Some(0), "{args:?}: {err}");
    err
}

#[test]
fn png16_and_pfm_decode_to_the_same_d_within_quantisation() {
    let dir = tempdir("bake-formats");
    let (high, base) = sphere_files(&dir, bumpy);
    let (png, pfm) = (dir.join("d.png"), dir.join("d.pfm"));
    ok(&["bake", high.to_str().unwrap(), base.to_str().unwrap(), "-o", png.to_str().unwrap(), "--resolution", "256"]);
    ok(&["bake", high.to_str().unwrap(), base.to_str().unwrap(), "-o", pfm.to_str().unwrap(), "--resolution", "256"]);
    assert!(dir.join("d.png.json").exists(), "the PNG's scale and offset sidecar");
    let a = DispMap::read(&png, 20).unwrap();
    let b = DispMap::read(&pfm, 20).unwrap();
    let q: dispdec::bake::Quantisation = serde_json::from_slice(&std::fs::read(dir.join("d.png.json")).unwrap()).unwrap();
    assert_eq!(a.d.len(), b.d.len());
    let mut compared = 0;
    for (x, y) in a.d.iter().zip(&b.d) {
        assert_eq!(x.is_nan(), y.is_nan());
        if !x.is_nan() {
            assert!(((x - y) as f64).abs() <= 0.5 * q.scale + 1e-6, "{x} vs {y}, step {}", q.scale);
            compared += 1;
        }
    }
    // Every chart texel of the closed sphere has a displacement (|d| up to 0.2 here).
    assert!(compared > a.d.len() / 2, "{compared} of {}", a.d.len());
    assert!(b.d.iter().filter(|x| !x.is_nan()).all(|x| x.abs() < 0.3));
}

#[test]
fn level_zero_is_the_base_and_closed_bases_stay_closed() {
    let dir = tempdir("rebuild");
    let (high, base) = sphere_files(&dir, bumpy);
    let disp = dir.join("d.pfm");
    ok(&["bake", high.to_str().unwrap(), base.to_str().unwrap(), "-o", disp.to_str().unwrap(), "--resolution", "512"]);
    let r0 = dir.join("r0.obj");
    ok(&["reconstruct", base.to_str().unwrap(), disp.to_str().unwrap(), "--levels", "0", "-o", r0.to_str().unwrap()]);
    let m0 = dispdec::mesh::load_dense(&r0).unwrap();
    let b0 = dispdec::mesh::load_dense(&base).unwrap();
    // The same triangles in the same order (the files number their vertices differently: the
    // base in its own order, the reconstruction in the order its faces first use them).
    let tri = |m: &dispdec::mesh::DenseMesh| -> Vec<[glam::DVec3; 3]> { m.faces.iter().map(|f| f.map(|v| m.positions[v as usize])).collect() };
    assert_eq!(tri(&m0), tri(&b0), "level 0 is the base mesh itself");
    let r3 = dir.join("r3.obj");
    let table = ok(&[
        "reconstruct",
        base.to_str().unwrap(),
        disp.to_str().unwrap(),
        "--levels",
        "3",
        "-o",
        r3.to_str().unwrap(),
        "--compare",
        high.to_str().unwrap(),
        "--plot",
        dir.join("err.png").to_str().unwrap(),
    ]);
    assert_eq!(&std::fs::read(dir.join("err.png")).unwrap()[1..4], b"PNG", "the error chart");
    let m3 = dispdec::mesh::load_dense(&r3).expect("a manifold, consistently wound mesh");
    assert_eq!(m3.faces.len(), 20 * 64);
    let (genus, loops) = dispdec::topology::topology_summary(m3.positions.len(), &m3.faces);
    assert_eq!((genus, loops), (0, 0), "watertight: no cracks along base edges");
    assert!(table.contains("level"), "{table}");
}

#[test]
fn horse_rebuilt_at_level_five_matches_the_scan() {
    let Some(horse) = real_scan("horse.ply.gz") else { return };
    let dir = tempdir("rebuild-horse");
    let base = dir.join("h.obj");
    let map = dir.join("h.map");
    ok(&["decimate", horse.to_str().unwrap(), "-o", base.to_str().unwrap(), "--map", map.to_str().unwrap(), "-q"]);
    let disp = dir.join("h.pfm");
    let said = ok(&["bake", horse.to_str().unwrap(), base.to_str().unwrap(), "--map", map.to_str().unwrap(), "-o", disp.to_str().unwrap()]);
    // The baked map reproduces the decimator's per-vertex d (RMS well below 1 % of dmax).
    let rms: f64 = said
        .split("RMS ")
        .nth(1)
        .and_then(|t| t.split(',').next())
        .and_then(|t| t.trim().parse().ok())
        .unwrap_or_else(|| panic!("no agreement line: {said}"));
    assert!(rms < 2.5e-4, "{said}");
    assert!(said.contains(" 0 where the map has no d"), "{said}");
    let b = dispdec::run::load_base_with_directions(&base).unwrap().base;
    let map = DispMap::read(&disp, b.faces.len()).unwrap();
    let scan = dispdec::mesh::load_dense(&horse).unwrap();
    let mut last_rms = f64::INFINITY;
    for level in 0..=5 {
        let r = dispdec::reconstruct::reconstruct(&b, &map, level, dispdec::eval::NormalMode::Interpolated);
        let d = dispdec::reconstruct::compare(&r, level, &scan.positions, &scan.faces);
        eprintln!("{d:?}");
        let rms = d.rms_to_scan.max(d.rms_from_scan);
        assert!(rms < last_rms, "the error falls with every level: {d:?}");
        last_rms = rms;
        if level == 5 {
            assert!(d.rms_to_scan <= 1e-3 && d.rms_from_scan <= 1e-3, "{d:?}");
            assert!(d.hausdorff_to_scan <= 1e-2 && d.hausdorff_from_scan <= 1e-2, "{d:?}");
        }
    }
}
