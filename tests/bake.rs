//! `dispdec bake` and `dispdec reconstruct`: the two map formats agree, level 0 is the base,
//! reconstructions are closed where the base is, and on the horse the error falls with every
//! level to the paper's Fig. 6 quality.

mod common;
use common::*;
use dispdec::maps::bake::DispMap;

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
    let q: dispdec::maps::bake::Quantisation = serde_json::from_slice(&std::fs::read(dir.join("d.png.json")).unwrap()).unwrap();
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

/// The RMS and the largest |d difference| of `bake --map`'s agreement line ("... RMS r, max m; ...").
fn agreement(said: &str) -> (f64, f64) {
    let field = |after: &str, until: char| -> f64 {
        said.split(after).nth(1).and_then(|t| t.split(until).next()).and_then(|t| t.trim().parse().ok()).unwrap_or_else(|| panic!("no '{after}' in the agreement line: {said}"))
    };
    (field("RMS ", ','), field(", max ", ';'))
}

#[test]
fn horse_rebuilt_at_level_five_matches_the_scan() {
    let Some(horse) = real_scan("horse.ply.gz") else { return };
    let dir = tempdir("rebuild-horse");
    let base = dir.join("h.obj");
    let map = dir.join("h.map");
    ok(&["decimate", horse.to_str().unwrap(), "-o", base.to_str().unwrap(), "--map", map.to_str().unwrap(), "-q"]);
    let disp = dir.join("h-disp.pfm");
    let said = ok(&["bake", horse.to_str().unwrap(), base.to_str().unwrap(), "--map", map.to_str().unwrap(), "-o", disp.to_str().unwrap()]);
    // The baked map reproduces the decimator's per-vertex d (RMS well below 1 % of dmax).
    let (rms, max) = agreement(&said);
    // Measured on the 366-face base: RMS 1.71e-5, max 1.15e-3 (where the image folds and two
    // sheets cover a point; on the 308-face base of the release before 2.19e-5 and 1.01e-3, on
    // the 326-face base before it 2.02e-5 and 1.40e-3, on the 336-face base before exact ties
    // 3.53e-5 and 3.33e-3, on the 338-face base before the fold rule 2.1e-5 and 1.6e-3); bounds
    // about 1.4x the larger of the last two bases' figures (the base moves with the order of
    // collapses).
    assert!(rms < 3.0e-5, "{said}");
    assert!(max < 1.6e-3, "{said}");
    assert!(said.contains(" 0 where the map has no d"), "{said}");
    let b = dispdec::app::run::load_base_with_directions(&base).unwrap().base;
    let map = DispMap::read(&disp, b.faces.len()).unwrap();
    let scan = dispdec::mesh::load_dense(&horse).unwrap();
    let mut last_rms = f64::INFINITY;
    for level in 0..=5 {
        let r = dispdec::maps::reconstruct::reconstruct(&b, &map, level, dispdec::eval::NormalMode::Interpolated);
        let d = dispdec::maps::reconstruct::compare(&r, level, &scan.positions, &scan.faces);
        eprintln!("{d:?}");
        let rms = d.rms_to_scan.max(d.rms_from_scan);
        assert!(rms < last_rms, "the error falls with every level: {d:?}");
        last_rms = rms;
        if level == 5 {
            // Measured on the 366-face base: RMS 1.41e-5 / 1.01e-4, Hausdorff 3.7e-4 / 1.42e-3
            // (to / from the scan; the 308-face base before: 1.6e-5 / 1.19e-4, 7.6e-4 / 2.0e-3;
            // the 326-face base before it: 1.5e-5 / 1.15e-4, 6.4e-4 / 1.5e-3); bounds about 2x
            // the largest of those, well inside the paper's 0.1 % and 1 %.
            assert!(d.rms_to_scan <= 3.5e-5 && d.rms_from_scan <= 2.5e-4, "{d:?}");
            assert!(d.hausdorff_to_scan <= 1.6e-3 && d.hausdorff_from_scan <= 4e-3, "{d:?}");
        }
    }
}

/// A bunny base with a vertex standing on a spike of the scan (d = 0 there): the dense
/// triangles around the spike all map onto the other faces around that vertex, so one face's
/// chart is covered by no image for several texels around its corner (a gap of the
/// projection). The gap takes its covered neighbours' d where that point lies on the scan,
/// not the nearest crossing of the line (another sheet, d = −0.022), which put the dense
/// vertex's d 0.022 off and a point of Blender's level-5 rebuild 1.6 % of the diagonal in
/// the air. The base is pinned (`data/tests/bunny-157-spike.obj`, the 157-face base dispdec
/// 97acdbb wrote): which base a decimation ends with moves with every change to the order of
/// collapses, and on the 151-face base of the release after it no dense vertex reads a filled
/// texel (its agreement is the same with and without the fill).
#[test]
fn a_gap_at_a_spike_takes_its_neighbours_d_not_another_sheets() {
    let Some(bunny) = real_scan("bunny.ply.gz") else { return };
    let dir = tempdir("bake-bunny-gap");
    let base = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("data/tests/bunny-157-spike.obj");
    let disp = dir.join("b-disp.pfm");
    let s = |p: &std::path::Path| p.to_str().unwrap().to_string();
    let said = ok(&["bake", &s(&bunny), &s(&base), "-o", &s(&disp), "--resolution", "2048"]);
    assert!(said.contains("the pair is valid"), "{said}");
    // Gap texels whose neighbour's d would leave their point over a hole of the scan hold no d,
    // as the hole's own texels do: measured 116,286 without d (114,242 when they kept another
    // sheet's crossing).
    let none: usize = said.split(" without d").next().and_then(|t| t.rsplit(' ').next()).and_then(|t| t.parse().ok()).unwrap_or_else(|| panic!("no texel count without d: {said}"));
    assert!((116_000..=116_600).contains(&none), "{said}");
    let loaded = dispdec::app::run::load_base_with_directions(&base).unwrap();
    let dmax = loaded.settings.expect("the base records its settings").dmax;
    let b = loaded.base;
    let m = DispMap::read(&disp, b.faces.len()).unwrap();
    let scan = dispdec::mesh::load_dense(&bunny).unwrap();
    // The baked map against what it inverts: every dense vertex's primary over the whole base
    // (the validator's projection; the base's own dmax).
    let dense = dispdec::mesh::DenseData::new(&scan.positions, &scan.faces);
    let opts = dispdec::validate::CheckOptions::new(dispdec::eval::NormalMode::Interpolated, dmax);
    let (verdict, maps) = dispdec::validate::validate_on(&dense, &b, &opts, None).unwrap();
    assert!(verdict.valid);
    let diffs: Vec<f64> = maps.iter().flatten().filter_map(|p| m.sample(p.face, p.bary[1], p.bary[2]).map(|d| (d - p.d).abs())).collect();
    assert!(diffs.len() > 34_800, "{} vertices sampled", diffs.len());
    let rms = (diffs.iter().map(|x| x * x).sum::<f64>() / diffs.len() as f64).sqrt();
    let max = diffs.iter().copied().fold(0.0, f64::max);
    // Measured: RMS 1.86e-5, max 6.93e-4 (against the decimator's map 1.85e-5 and 6.93e-4; the
    // nearest crossing instead: 1.20e-4 and 2.21e-2); bounds about 1.4x.
    assert!(rms < 2.6e-5 && max < 1.0e-3, "RMS {rms:.3e}, max {max:.3e}");
    // The level-5 rebuild stays on the scan: Hausdorff to the scan 1.96e-3 of the diagonal
    // (filling every gap whose point lies within a whole dense edge of the scan: 6.07e-3).
    let r = dispdec::maps::reconstruct::reconstruct(&b, &m, 5, dispdec::eval::NormalMode::Interpolated);
    let d = dispdec::maps::reconstruct::compare(&r, 5, &scan.positions, &scan.faces);
    eprintln!("RMS {rms:.3e}, max {max:.3e}; {d:?}");
    assert!(d.hausdorff_to_scan <= 2.5e-3, "{d:?}");
}

/// The map's UVs, the EXR, and the three conventions on the sphere fixture: every format and
/// kind holds the same displacement, and DISP.obj lets any tool find it.
#[test]
fn bake_writes_uvs_exr_and_the_three_kinds() {
    let dir = tempdir("bake-kinds");
    let (high, base) = sphere_files(&dir, bumpy);
    let s = |p: &std::path::Path| p.to_str().unwrap().to_string();
    let bake = |name: &str, kind: &str| {
        let p = dir.join(name);
        ok(&["bake", &s(&high), &s(&base), "-o", &s(&p), "--resolution", "256", "--kind", kind]);
        p
    };
    let (spfm, sexr, npfm, vpfm, vexr) =
        (bake("s.pfm", "scalar"), bake("s.exr", "scalar"), bake("n.pfm", "normalized"), bake("v.pfm", "vector"), bake("v.exr", "vector"));
    // DISP.obj: the base with one vt per corner, in [0, 1], and f v/vt/vn.
    let uv = std::fs::read_to_string(dir.join("s.obj")).unwrap();
    let vts: Vec<(f64, f64)> = uv
        .lines()
        .filter_map(|l| l.strip_prefix("vt "))
        .map(|t| {
            let c: Vec<f64> = t.split_whitespace().map(|x| x.parse().unwrap()).collect();
            (c[0], c[1])
        })
        .collect();
    assert_eq!(vts.len(), 3 * 20);
    assert!(vts.iter().all(|&(u, v)| (0.0..=1.0).contains(&u) && (0.0..=1.0).contains(&v)));
    assert!(uv.lines().any(|l| l.starts_with("f 1/1/1 ")) || uv.lines().filter(|l| l.starts_with("f ")).all(|l| l.matches('/').count() == 6));
    let b = dispdec::app::run::load_base_with_directions(&dir.join("s.obj")).unwrap().base;
    let b0 = dispdec::app::run::load_base_with_directions(&base).unwrap().base;
    assert_eq!((&b.positions, &b.faces, &b.directions), (&b0.positions, &b0.faces, &b0.directions), "DISP.obj is the base");
    // The corner's UV finds the texel of that corner: the map read there equals DispMap::sample.
    let m = DispMap::read(&spfm, 20).unwrap();
    for f in 0..20u32 {
        let (u, v) = vts[3 * f as usize + 1];
        let (x, y) = ((u * m.atlas.size as f64) as u32, ((1.0 - v) * m.atlas.size as f64) as u32);
        let (x, y) = (x.min(m.atlas.size - 1), y.min(m.atlas.size - 1));
        assert_eq!(m.atlas.texel_any(x, y).map(|t| t.0), Some(f), "corner 1 of face {f} lies on its own side of the cell");
    }
    // EXR and PFM: the same floats.
    let e = DispMap::read(&sexr, 20).unwrap();
    assert!(m.d.iter().zip(&e.d).all(|(a, b)| a.to_bits() == b.to_bits()), "scalar EXR = PFM");
    // normalized = d·|N(X)|, vector = d·N(X), texel by texel (f32 rounding).
    let pfm = |p: &std::path::Path| -> Vec<f32> {
        let bytes = std::fs::read(p).unwrap();
        let end = bytes.iter().enumerate().filter(|(_, &c)| c == b'\n').nth(2).unwrap().0 + 1;
        bytes[end..].chunks_exact(4).map(|c| f32::from_le_bytes(c.try_into().unwrap())).collect()
    };
    let (nv, vv) = (pfm(&npfm), pfm(&vpfm));
    let n = m.atlas.size as usize;
    let mut checked = 0;
    for row in 0..n {
        for col in 0..n {
            let d = m.d[row * n + col];
            let Some((_, _, dir)) = dispdec::maps::bake::texel_point(&m.atlas, &b0, dispdec::eval::NormalMode::Interpolated, col as u32, row as u32) else { continue };
            let k = (n - 1 - row) * n + col; // PFM rows run bottom to top
            if d.is_nan() {
                assert!(nv[k].is_nan() && vv[3 * k].is_nan());
                continue;
            }
            let want = d as f64 * dir.length();
            assert!((nv[k] as f64 - want).abs() <= 1e-6 * want.abs() + 1e-9, "normalized at ({col}, {row})");
            for c in 0..3 {
                let want = d as f64 * dir[c];
                assert!((vv[3 * k + c] as f64 - want).abs() <= 1e-6 * d.abs() as f64 + 1e-9, "vector at ({col}, {row})");
            }
            checked += 1;
        }
    }
    assert!(checked > n * n / 2, "{checked}");
    // The vector EXR: R, G, B as in the PFM, its kind in the header; dispdec reads scalar maps only.
    let img = exr::prelude::read_all_flat_layers_from_file(&vexr).unwrap();
    let layer = &img.layer_data[0];
    let kind = layer.attributes.other.get(&exr::prelude::Text::new_or_panic("dispdec_kind"));
    assert!(matches!(kind, Some(exr::meta::attribute::AttributeValue::Text(t)) if t.to_string() == "vector"), "{kind:?}");
    let ch = |name: &str| layer.channel_data.list.iter().find(|c| c.name.to_string() == name).unwrap().sample_data.values_as_f32().collect::<Vec<f32>>();
    let (r, g, bb) = (ch("R"), ch("G"), ch("B"));
    for row in 0..n {
        for col in 0..n {
            let (i, k) = (row * n + col, (n - 1 - row) * n + col);
            for (c, v) in [&r, &g, &bb].iter().enumerate() {
                assert!(v[i].to_bits() == vv[3 * k + c].to_bits() || (v[i].is_nan() && vv[3 * k + c].is_nan()));
            }
        }
    }
    let err = DispMap::read(&vexr, 20).unwrap_err().to_string();
    assert!(err.contains("vector map"), "{err}");
    // A map named like the base would overwrite it with DISP.obj: refused, the base untouched.
    let before = std::fs::read(&base).unwrap();
    let o = run(&["bake", &s(&high), &s(&base), "-o", &s(&base.with_extension("pfm")), "--resolution", "64"]);
    assert_eq!(o.status.code(), Some(2), "{}", String::from_utf8_lossy(&o.stderr));
    assert_eq!(std::fs::read(&base).unwrap(), before);
}

/// `dispdec export`: a .glb with the base, the texture and the rebuilt mesh, valid by the
/// Khronos glTF-Validator.
#[test]
fn export_writes_a_glb_the_khronos_validator_accepts() {
    let dir = tempdir("export");
    let (high, base) = sphere_files(&dir, bumpy);
    let s = |p: &std::path::Path| p.to_str().unwrap().to_string();
    let disp = dir.join("d.pfm");
    ok(&["bake", &s(&high), &s(&base), "-o", &s(&disp), "--resolution", "256"]);
    let glb = dir.join("out.glb");
    ok(&["export", &s(&base), &s(&disp), "-o", &s(&glb), "--levels", "2"]);
    let bytes = std::fs::read(&glb).unwrap();
    assert_eq!(&bytes[..4], b"glTF");
    assert_eq!(u32::from_le_bytes(bytes[8..12].try_into().unwrap()) as usize, bytes.len());
    let meshes = dispdec::maps::export::read_glb_meshes(&bytes).unwrap();
    assert_eq!(meshes.len(), 2);
    assert_eq!((meshes[0].0.len(), meshes[0].1.len()), (60, 20), "the base, one vertex per corner");
    assert_eq!(meshes[1].1.len(), 20 * 16, "the mesh rebuilt at level 2");
    let json_len = u32::from_le_bytes(bytes[12..16].try_into().unwrap()) as usize;
    let doc: serde_json::Value = serde_json::from_slice(&bytes[20..20 + json_len]).unwrap();
    let extras = &doc["materials"][0]["extras"]["dispdec_displacement"];
    assert_eq!(extras["kind"], "normalized");
    assert!(extras["scale"].as_f64().unwrap() > 0.0);
    assert_eq!(doc["images"][0]["mimeType"], "image/png");
    // The Khronos validator (npm gltf-validator; .ci/run installs it into target/).
    let modules = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("target/gltf-validator/node_modules");
    let script = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("scripts/gltf-validate.js");
    let o = std::process::Command::new("node").arg(&script).arg(&glb).env("NODE_PATH", &modules).output();
    match o {
        Ok(o) if o.status.code() != Some(2) && modules.join("gltf-validator").exists() => {
            let report: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap_or_else(|_| panic!("{}", String::from_utf8_lossy(&o.stdout)));
            eprintln!("{report}");
            assert_eq!(report["errors"], 0, "{report}");
            assert_eq!(report["warnings"], 0, "{report}");
        }
        _ => {
            let msg = format!("glTF-Validator not found at {}: npm install --prefix target/gltf-validator gltf-validator", modules.display());
            if std::env::var("CI").map(|v| v == "true" || v == "1").unwrap_or(false) {
                panic!("{msg} (CI=true: a missing tool is a failure)");
            }
            skipped(&msg);
        }
    }
}
