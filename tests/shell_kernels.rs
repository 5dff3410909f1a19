//! The WGSL shell kernels: they parse and validate with wgpu's naga (no GPU needed), every
//! #[repr(C)] struct matches its WGSL struct, the GPU's decisions agree with the f64 oracle
//! outside the tolerance band on real batches (bunny and horse, at several stages and in every
//! mode), and the GPU backend gives the CPU backend's bytes end to end (a 6k sample, the bunny
//! and the horse; the ~1M-face sample in an ignored test, too long for CI). GPU tests request
//! Backends::VULKAN and assert it; with DISPDEC_REQUIRE_GPU=1 (the README's test command) a
//! missing adapter fails.

mod common;
use common::*;
use dispdec::decimate::{Options, State};
use dispdec::eval::{find_primary, CpuEvaluator, Evaluator, Found, NormalMode, Scratch};
use dispdec::gpu::{Gpu, GpuAnswer, GpuNode, GpuParams, GpuQuery, GpuTri};
use dispdec::gpu::eval::*;
use serde_json::Value;
use std::path::Path;
use wgpu::naga;

fn require_gpu() -> bool {
    std::env::var("DISPDEC_REQUIRE_GPU").map(|v| v == "1").unwrap_or(false)
}

/// A Vulkan adapter, or `None` (a skip, said out loud) when none is there and none is required.
fn vulkan() -> Option<Gpu> {
    match Gpu::new(wgpu::Backends::VULKAN) {
        Ok(g) => {
            assert_eq!(g.info.backend, wgpu::Backend::Vulkan, "{}", g.describe());
            eprintln!("adapter: {}", g.describe());
            Some(g)
        }
        Err(e) if !require_gpu() => {
            { use std::io::Write; let _ = writeln!(std::io::stderr(), "SKIPPED (set DISPDEC_REQUIRE_GPU=1 to make this a failure): {e}"); }
            None
        }
        Err(e) => panic!("DISPDEC_REQUIRE_GPU=1 but no Vulkan adapter: {e}"),
    }
}

fn module() -> naga::Module {
    let src = shell_source();
    let module = naga::front::wgsl::parse_str(&src).unwrap_or_else(|e| panic!("shell.wgsl: {}", e.emit_to_string(&src)));
    naga::valid::Validator::new(naga::valid::ValidationFlags::all(), naga::valid::Capabilities::all())
        .validate(&module)
        .unwrap_or_else(|e| panic!("shell.wgsl does not validate: {e:?}"));
    module
}

#[test]
fn shell_wgsl_parses_and_validates() {
    let m = module();
    for name in ["evaluate_candidates", "project_vertices"] {
        let ep = m.entry_points.iter().find(|e| e.name == name).unwrap_or_else(|| panic!("entry point {name}"));
        assert_eq!(ep.stage, naga::ShaderStage::Compute);
        assert_eq!(ep.workgroup_size, [dispdec::gpu::WORKGROUP_SIZE, 1, 1]);
    }
    // The constants come from Rust, once.
    let src = shell_source();
    assert!(src.contains(&format!("const BARY_EPS: f32 = {:e};", dispdec::geometry::BARY_EPS as f32)));
    assert!(!SHELL_WGSL.contains("const BAND_D"), "constants must be generated, not written in the WGSL");
    // The kernels mirror the Rust oracle's functions by name.
    for f in ["cubic_coeffs", "poly_eval", "quadratic_roots", "polish_root", "cubic_roots_in_unit", "barycentric", "clamp_bary", "solve_shell", "solve_constant", "interpolate_direction", "condition4", "triangle_distance"] {
        assert!(m.functions.iter().any(|(_, func)| func.name.as_deref() == Some(f)), "WGSL lacks {f}");
    }
}

/// (offset, size) of every member of WGSL struct `name`, and its span.
fn wgsl_struct(m: &naga::Module, name: &str) -> (Vec<(String, u32)>, u32) {
    for (_, ty) in m.types.iter() {
        if ty.name.as_deref() == Some(name) {
            if let naga::TypeInner::Struct { members, span } = &ty.inner {
                return (members.iter().map(|mb| (mb.name.clone().unwrap_or_default(), mb.offset)).collect(), *span);
            }
        }
    }
    panic!("no WGSL struct {name}");
}

macro_rules! same_layout {
    ($m:expr, $rust:ty, $wgsl:expr, [$($field:ident),+]) => {{
        let (members, span) = wgsl_struct(&$m, $wgsl);
        let rust: Vec<(String, u32)> = vec![$((stringify!($field).to_string(), std::mem::offset_of!($rust, $field) as u32)),+];
        assert_eq!(members, rust, "member offsets of {} vs WGSL {}", stringify!($rust), $wgsl);
        assert_eq!(std::mem::size_of::<$rust>() as u32, span, "size of {} vs WGSL {}", stringify!($rust), $wgsl);
    }};
}

#[test]
fn repr_c_structs_match_their_wgsl_structs() {
    let m = module();
    same_layout!(m, GpuTri, "Tri", [p0, p1, p2, n0, n1, n2, sphere]);
    same_layout!(m, GpuQuery, "Query", [x, vertex, tri_start, tri_count, flags, hint]);
    same_layout!(m, GpuAnswer, "Answer", [tri, status, d, second, bary]);
    same_layout!(m, GpuNode, "Node", [lo, a, hi, b]);
    same_layout!(m, GpuParams, "Params", [dmax, mode, query_count, node_count]);
}

#[derive(Default, Debug)]
struct Parity {
    compared: u64,
    band_tie: u64,
    band_marginal: u64,
    disagree: u64,
    max_d_err: f64,
}

/// Decimates a real scan on the CPU down to each stage, then sends one batch through both
/// evaluators: the kernel's raw answers against `find_primary` (f64) per query, and the two
/// evaluators' outcomes per candidate.
fn parity_on(name: &str, gpu: Gpu, opts: Options, stages: &[usize]) -> Parity {
    let path = real_scan(name).expect(name);
    let scan = dispdec::mesh::load_dense(&path).unwrap();
    let mut state = State::new(&scan, &opts);
    let ev = GpuEvaluator::new(gpu, &state.dense).unwrap();
    let mut p = Parity::default();
    for (k, &stage) in stages.iter().enumerate() {
        let o = Options { target_faces: stage, ..opts.clone() };
        state.run(&CpuEvaluator, &o, |_| {}).unwrap();
        let mut marks = vec![0u32; state.pos.len()];
        let batch = state.pick_collapses(64, &mut marks, u32::MAX - k as u32);
        assert!(!batch.is_empty());
        let (mut scratch, mut normals) = (Scratch::default(), Vec::new());
        for (ci, _pi, tris, answers) in ev.raw_answers(&state, &batch).unwrap() {
            let c = &batch[ci];
            for (i, a) in answers.iter().enumerate() {
                let v = c.dense[i];
                let pinched = state.dense.pinched[v as usize];
                state.dense.vertex_normals(v, &mut normals);
                let x = state.dense.pos[v as usize];
                let cpu = find_primary(x, &normals, &tris, state.mode, state.dmax, !pinched, state.strict && !pinched, &mut scratch);
                p.compared += 1;
                // A band answer is the GPU saying it cannot decide: counted apart, never as
                // agreement (the CPU decides those in f64).
                let agree = match (a.status, cpu) {
                    (STATUS_BAND_TIE, _) => {
                        p.band_tie += 1;
                        continue;
                    }
                    (STATUS_BAND_MARGINAL, _) => {
                        p.band_marginal += 1;
                        continue;
                    }
                    (STATUS_HIT, Found::Hit(t, h)) => {
                        let err = (h.d - a.d as f64).abs() / state.dmax;
                        p.max_d_err = p.max_d_err.max(err);
                        t == a.tri as usize && err <= BAND_D
                    }
                    (STATUS_NONE, Found::None) | (STATUS_AMBIGUOUS, Found::Ambiguous) => true,
                    _ => false,
                };
                if !agree {
                    p.disagree += 1;
                    eprintln!("disagreement at stage {stage}, vertex {v}: gpu {a:?}, cpu {cpu:?}");
                }
            }
        }
        // Whole outcomes: identical, band included (the band is settled in f64).
        let g = ev.evaluate(&state, &batch).unwrap();
        let c = CpuEvaluator.evaluate(&state, &batch).unwrap();
        for (i, (g, c)) in g.iter().zip(c.iter()).enumerate() {
            match (g, c) {
                (Ok(a), Ok(b)) => {
                    assert_eq!((a.placement, a.position, &a.new_dirs, &a.extras), (b.placement, b.position, &b.new_dirs, &b.extras), "candidate {i}");
                    assert_eq!(a.maps, b.maps, "candidate {i}");
                }
                (Err(a), Err(b)) => assert_eq!(a, b, "candidate {i}"),
                _ => panic!("candidate {i}: gpu {:?} vs cpu {:?}", g.as_ref().map(|a| a.placement), c.as_ref().map(|a| a.placement)),
            }
        }
    }
    p
}

/// Prints the parity figures; asserts no disagreement outside the band, at least `min_decided`
/// decisions made outside it, and the band's share within 5 points of the share measured
/// (`band_measured`; strict mode sends most of its queries to f64: any undecidable event within
/// dmax may be another solution).
fn report(name: &str, p: &Parity, band_measured: f64, min_decided: u64) {
    let band = p.band_tie + p.band_marginal;
    eprintln!(
        "parity {name}: {} decisions compared, {} disagreements outside the band, {} in the band ({:.1} %: {} ties, {} marginal), max |d| error {:.2e} dmax",
        p.compared,
        p.disagree,
        band,
        100.0 * band as f64 / p.compared.max(1) as f64,
        p.band_tie,
        p.band_marginal,
        p.max_d_err
    );
    let decided = p.compared - band;
    assert!(decided >= min_decided, "{name}: too few decisions made outside the band ({decided})");
    assert_eq!(p.disagree, 0, "{name}: GPU and CPU disagree outside the tolerance band");
    let share = band as f64 / p.compared as f64;
    assert!((share - band_measured).abs() <= 0.05, "{name}: band share {share:.3}, measured {band_measured}");
}

/// Band shares measured on this machine (lavapipe), `cargo test --release --test shell_kernels
/// -- parity --nocapture` (2026-12-07: 10.2 % interpolated, 88.7 % strict, 61.3 % constant; the
/// release before, whose runs took another order of collapses: 13.8 %, 90.1 %, 61.3 %).
const INTERP_BAND: f64 = 0.102;
/// Constant mode at 45,000 faces: 61.3 % in the band, nearly all ties (a dense vertex on a base
/// edge or vertex at d = 0, found by every face around it).
const CONST_BAND: f64 = 0.614;

/// Parity (`parity_on`) on `scan` for each (label, options, stages, band share measured,
/// fewest decisions outside the band) of `runs`, each on a fresh adapter; a skip, said out loud,
/// without a Vulkan adapter (none required) or without the scan (outside CI).
fn parity_runs(scan: &str, runs: &[(&str, Options, &[usize], f64, u64)]) {
    if vulkan().is_none() || real_scan(scan).is_none() {
        return;
    }
    for (label, opts, stages, band, min_decided) in runs {
        let p = parity_on(scan, vulkan().unwrap(), opts.clone(), stages);
        report(label, &p, *band, *min_decided);
    }
}

#[test]
fn parity_interpolated_bunny_early_and_late() {
    parity_runs("bunny.ply.gz", &[("interpolated", Options::default(), &[20_000, 1_000], INTERP_BAND, 1000)]);
}

#[test]
fn parity_strict_and_constant_bunny() {
    // Constant mode stops at ~38,600 faces on the bunny (README, Modes): a stage above it.
    let constant = Options { normals: NormalMode::Constant, ..Options::default() };
    parity_runs(
        "bunny.ply.gz",
        &[("strict", Options { strict: true, ..Options::default() }, &[30_000], 0.887, 500), ("constant", constant, &[45_000], CONST_BAND, 1000)],
    );
}

/// The horse (SPEC §1: wound inward, a thin part between its legs), as the bunny above: its
/// batches at two stages of the interpolated run, one of the strict run and one of the constant
/// run (constant mode stops at ~42,500 faces on the horse: README, Modes).
#[test]
fn parity_every_mode_horse() {
    let constant = Options { normals: NormalMode::Constant, ..Options::default() };
    parity_runs(
        "horse.ply.gz",
        &[
            ("horse interpolated", Options::default(), &[20_000, 1_000], HORSE_INTERP_BAND, 1000),
            ("horse strict", Options { strict: true, ..Options::default() }, &[30_000], HORSE_STRICT_BAND, 200),
            ("horse constant", constant, &[50_000], HORSE_CONST_BAND, 1000),
        ],
    );
}

/// The horse's band shares, measured as the bunny's (lavapipe, 2026-12-07: 9.1 % interpolated,
/// 89.2 % strict, 47.7 % constant; 0 disagreements in each; 2026-12-06: 8.0 %, 91.3 %, 47.7 %).
const HORSE_INTERP_BAND: f64 = 0.091;
const HORSE_STRICT_BAND: f64 = 0.892;
const HORSE_CONST_BAND: f64 = 0.477;

/// The validator's projection: every dense vertex of the bunny against a meshoptimizer base
/// (many unmapped vertices, flips) and against dispdec's own, on both backends: equal verdicts.
#[test]
fn validate_projection_on_gpu_equals_cpu() {
    let Some(gpu) = vulkan() else { return };
    let Some(bunny) = real_scan("bunny.ply.gz") else { return };
    let scan = dispdec::mesh::load_dense(&bunny).unwrap();
    let dense = dispdec::mesh::DenseData::new(&scan.positions, &scan.faces);
    let verts: Vec<[f32; 3]> = scan.positions.iter().map(|p| [p.x as f32, p.y as f32, p.z as f32]).collect();
    let indices: Vec<u32> = scan.faces.iter().flatten().copied().collect();
    let adapter = meshopt::VertexDataAdapter::new(bytemuck::cast_slice(&verts), 12, 0).unwrap();
    let simplified = meshopt::simplify(&indices, &adapter, 400 * 3, 1.0, meshopt::SimplifyOptions::empty(), None);
    let faces: Vec<[u32; 3]> = simplified.chunks_exact(3).map(|t| [t[0], t[1], t[2]]).collect();
    let dir = tempdir("validate-parity");
    let qem = dir.join("qem.obj");
    write_obj(&qem, &scan.positions, &faces);
    let base = dispdec::app::run::load_base_with_directions(&qem).unwrap().base;
    let dmax = 0.1 * dispdec::mesh::bbox_diagonal(scan.positions.iter().copied());
    let ev = GpuEvaluator::new(gpu, &dense).unwrap();
    let (cv, cm) = dispdec::validate::validate_on(&dense, &base, &dispdec::validate::CheckOptions::new(NormalMode::Interpolated, dmax), None).unwrap();
    let (gv, gm) = dispdec::validate::validate_on(&dense, &base, &dispdec::validate::CheckOptions::new(NormalMode::Interpolated, dmax), Some(&ev as &dyn dispdec::validate::Project)).unwrap();
    let s = ev.stats();
    eprintln!(
        "validate parity (bunny, {} meshoptimizer faces): {} vertices; gpu decided {} hits + {} none; band {} ties + {} marginal ({:.2} %); disagreements {}; unmapped {} / {}, flipped {} / {}",
        base.faces.len(),
        s.queries,
        s.gpu_hit,
        s.gpu_none,
        s.band_tie,
        s.band_marginal,
        100.0 * s.band_fraction(),
        s.disagreements,
        cv.unmapped,
        gv.unmapped,
        cv.flipped,
        gv.flipped
    );
    assert!(cv.unmapped > 0, "the quadric base leaves vertices unmapped");
    assert_eq!(s.disagreements, 0);
    assert_eq!(cm, gm, "per-vertex maps");
    assert_eq!((cv.valid, cv.unmapped, cv.flipped, cv.torn), (gv.valid, gv.unmapped, gv.flipped, gv.torn));
}

/// The binary end to end on lavapipe: `--backend gpu` writes the CPU backend's bytes, and
/// `validate --backend gpu` finds the base valid with the GPU named in its report.
#[test]
fn decimate_and_validate_with_backend_gpu_match_cpu() {
    let Some(_) = vulkan() else { return };
    let dir = tempdir("backend-gpu");
    let scan = sample_6k(&dir, "scan.obj");
    let mut bytes = Vec::new();
    for backend in ["cpu", "gpu"] {
        let (b, m, r) = (dir.join(format!("{backend}.obj")), dir.join(format!("{backend}.map")), dir.join(format!("{backend}.json")));
        let o = run(&[
            "decimate", scan.to_str().unwrap(), "-o", b.to_str().unwrap(), "--map", m.to_str().unwrap(),
            "--report", r.to_str().unwrap(), "--backend", backend, "-q",
        ]);
        assert_eq!(o.status.code(), Some(0), "{backend}: {}", String::from_utf8_lossy(&o.stderr));
        let rep: Value = serde_json::from_slice(&std::fs::read(&r).unwrap()).unwrap();
        assert_eq!(rep["backend"], backend);
        if backend == "gpu" {
            assert!(rep["adapter"].as_str().unwrap().contains("Vulkan"), "{}", rep["adapter"]);
            let band = &rep["gpu_band"];
            assert!(band["queries"].as_u64().unwrap() > 0);
            assert_eq!(band["disagreements"], 0);
            assert_eq!(rep["global"]["valid"], true);
        }
        bytes.push((std::fs::read(&b).unwrap(), std::fs::read(&m).unwrap()));
    }
    assert!(bytes[0] == bytes[1], "--backend gpu must write the same base and map as --backend cpu");
    let j = dir.join("v.json");
    let o = run(&["validate", scan.to_str().unwrap(), dir.join("gpu.obj").to_str().unwrap(), "--backend", "gpu", "--json", j.to_str().unwrap()]);
    assert_eq!(o.status.code(), Some(0), "{}", String::from_utf8_lossy(&o.stderr));
    let rep: Value = serde_json::from_slice(&std::fs::read(&j).unwrap()).unwrap();
    assert!(rep["backend"].as_str().unwrap().starts_with("gpu"), "{}", rep["backend"]);
    assert_eq!(rep["verdict"]["valid"], true);

    // `--fine-loops` (the checks walk passing loops finer): the same bytes on both paths, and a
    // base that `validate --fine-loops --backend gpu` finds valid.
    let fine = on_both_backends(&scan, &dir, "fine-", &["--fine-loops", "-q"]);
    assert!(fine[0] == fine[1], "--backend gpu --fine-loops must write the CPU path's bytes");
    let o = run(&["validate", scan.to_str().unwrap(), dir.join("fine-gpu.obj").to_str().unwrap(), "--backend", "gpu", "--fine-loops", "--json", j.to_str().unwrap()]);
    assert_eq!(o.status.code(), Some(0), "{}", String::from_utf8_lossy(&o.stderr));

    // `--ring-directions keep` (a smaller region for every candidate): the same bytes on both
    // paths too.
    let mut kept = Vec::new();
    for backend in ["cpu", "gpu"] {
        let (b, m) = (dir.join(format!("keep-{backend}.obj")), dir.join(format!("keep-{backend}.map")));
        let o = run(&["decimate", scan.to_str().unwrap(), "-o", b.to_str().unwrap(), "--map", m.to_str().unwrap(), "--backend", backend, "--ring-directions", "keep", "-q"]);
        assert_eq!(o.status.code(), Some(0), "{backend} --ring-directions keep: {}", String::from_utf8_lossy(&o.stderr));
        kept.push((std::fs::read(&b).unwrap(), std::fs::read(&m).unwrap()));
    }
    assert!(kept[0] == kept[1], "--backend gpu --ring-directions keep must write the CPU path's bytes");
    assert!(kept[0] != bytes[0], "keeping the ring's directions makes another base");
}

/// Issue 11: on real scans the GPU path writes the CPU path's bytes — the bunny and the horse,
/// default options, two threads, through the binary (lavapipe: about 45 s and 60 s for both
/// paths of each; the 1M sample's GPU run takes longer than CI allows and is the bench's). The
/// GPU run must have asked the kernel (its band counters) and met no disagreement.
#[test]
fn bunny_and_horse_gpu_write_the_cpu_bytes() {
    let Some(_) = vulkan() else { return };
    let dir = tempdir("real-gpu");
    // One dispatch a round: the kernel answers the first placements, the f64 search the later
    // ones. Measured: bunny 4,383,691 queries to 1,257,373 later-placement vertices (3.49),
    // horse 5,013,155 to 1,002,099 (5.00); between 3 and 6 (−14 %, +20 %).
    for name in ["bunny.ply.gz", "horse.ply.gz"] {
        let Some(scan) = real_scan(name) else { continue };
        gpu_writes_the_cpu_bytes(name, &scan, &dir, (3.0, 6.0));
    }
}

/// Decimates `scan` with `--backend cpu` and `--backend gpu` and `extra` (exit 0 asserted), into
/// `dir`/`{tag}{backend}.obj` and `.map`; returns their bytes, CPU first.
fn on_both_backends(scan: &Path, dir: &Path, tag: &str, extra: &[&str]) -> Vec<(Vec<u8>, Vec<u8>)> {
    ["cpu", "gpu"]
        .iter()
        .map(|backend| {
            let (b, m) = (dir.join(format!("{tag}{backend}.obj")), dir.join(format!("{tag}{backend}.map")));
            let mut args = vec!["decimate", scan.to_str().unwrap(), "-o", b.to_str().unwrap(), "--map", m.to_str().unwrap(), "--backend", backend];
            args.extend_from_slice(extra);
            let o = run(&args);
            assert_eq!(o.status.code(), Some(0), "{backend} {extra:?}: {}", String::from_utf8_lossy(&o.stderr));
            (std::fs::read(&b).unwrap(), std::fs::read(&m).unwrap())
        })
        .collect()
}

/// A scan in world coordinates (moved to the origin on load, its midpoints rounded to the
/// world's grid: `mesh::centre_for`) on both backends, byte for byte, and valid where it lies:
/// a level-4 bumpy icosphere (5,120 faces) at a UTM-like place, its coordinates rounded there.
#[test]
fn a_world_coordinate_scan_gpu_writes_the_cpu_bytes() {
    let Some(_) = vulkan() else { return };
    let dir = tempdir("world-gpu");
    let (v, f) = icosphere(4);
    let t = glam::DVec3::new(512_345.678_9, 5_300_000.123_4, 250.5);
    let scan = dir.join("utm.obj");
    write_obj(&scan, &v.iter().map(|&p| bumpy(p) + t).collect::<Vec<_>>(), &f);
    let out = on_both_backends(&scan, &dir, "", &["--threads", "2"]);
    assert!(out[0] == out[1], "the GPU path writes the CPU path's base and map");
    let o = run(&["validate", scan.to_str().unwrap(), dir.join("gpu.obj").to_str().unwrap(), "--backend", "gpu"]);
    assert_eq!(o.status.code(), Some(0), "{}", String::from_utf8_lossy(&o.stderr));
}

/// The ~1M-face sample (`dispdec sample --faces 1000000 --seed 1`, the bench's `sample1m`) on
/// both backends, byte for byte. Ignored by default: on lavapipe its two runs take ~17 minutes
/// on this 2-core machine, beyond what CI is given; run it with
/// `cargo test --release --test shell_kernels -- --ignored sample1m`.
#[test]
#[ignore = "~17 minutes on lavapipe; run with --ignored"]
fn sample1m_gpu_writes_the_cpu_bytes() {
    let Some(_) = vulkan() else { return };
    let dir = tempdir("sample1m-gpu");
    let scan = dir.join("sample1m.obj");
    let o = run(&["sample", "--faces", "1000000", "--seed", "1", "-o", scan.to_str().unwrap()]);
    assert_eq!(o.status.code(), Some(0), "{}", String::from_utf8_lossy(&o.stderr));
    // Measured (2026-12-06): 59,448,768 queries to 5,180,257 later-placement vertices (11.48),
    // 4,339 faces, valid, the same bytes; between −15 % and +15 % of that ratio.
    gpu_writes_the_cpu_bytes("sample1m", &scan, &dir, (0.85 * RATIO_1M, 1.15 * RATIO_1M));
}

/// Queries over later-placement vertices of the 1M sample's GPU run (measured once, see above).
const RATIO_1M: f64 = 11.48;

/// Decimates `scan` with `--backend cpu` and `--backend gpu` (two threads) and asserts the same
/// base and map bytes; on the GPU run, no disagreement and the kernel's queries over the
/// later-placement vertices (solved in f64) within `ratio`.
fn gpu_writes_the_cpu_bytes(name: &str, scan: &Path, dir: &Path, ratio: (f64, f64)) {
    let mut bytes = Vec::new();
    for backend in ["cpu", "gpu"] {
        let (b, m, r) = (dir.join(format!("{backend}.obj")), dir.join(format!("{backend}.map")), dir.join(format!("{backend}.json")));
        let o = run(&[
            "decimate", scan.to_str().unwrap(), "-o", b.to_str().unwrap(), "--map", m.to_str().unwrap(),
            "--report", r.to_str().unwrap(), "--backend", backend, "--threads", "2", "-q",
        ]);
        assert_eq!(o.status.code(), Some(0), "{name} {backend}: {}", String::from_utf8_lossy(&o.stderr));
        let rep: Value = serde_json::from_slice(&std::fs::read(&r).unwrap()).unwrap();
        if backend == "gpu" {
            let band = &rep["gpu_band"];
            let (q, later) = (band["queries"].as_u64().unwrap(), band["later_placement_vertices"].as_u64().unwrap());
            let measured = q as f64 / later.max(1) as f64;
            println!("{name}: {q} queries, {later} later-placement vertices ({measured:.2})");
            assert!(measured > ratio.0 && measured < ratio.1, "{name}: {q} queries, {later} later-placement vertices: {measured:.2} outside {ratio:?}");
            assert_eq!(band["disagreements"], 0, "{name}");
        }
        println!("{name} {backend}: {} faces, valid {}", rep["faces_out"], rep["global"]["valid"]);
        assert_eq!(rep["global"]["valid"], true, "{name} {backend}");
        bytes.push((std::fs::read(&b).unwrap(), std::fs::read(&m).unwrap()));
    }
    assert!(bytes[0] == bytes[1], "{name}: --backend gpu must write the same base and map as --backend cpu");
}

/// `--backend auto` always runs (GPU or CPU) and says which in one line.
#[test]
fn backend_auto_says_what_it_uses() {
    let dir = tempdir("backend-auto");
    let scan = dir.join("scan.obj");
    assert_eq!(run(&["sample", "--faces", "2000", "-o", scan.to_str().unwrap()]).status.code(), Some(0));
    let rep = dir.join("r.json");
    let o = run(&["decimate", scan.to_str().unwrap(), "-o", dir.join("b.obj").to_str().unwrap(), "--backend", "auto", "--verbose", "--report", rep.to_str().unwrap()]);
    assert_eq!(o.status.code(), Some(0));
    let err = String::from_utf8_lossy(&o.stderr);
    let line = err.lines().find(|l| l.contains("--backend auto")).expect("with --verbose, a line about the backend");
    assert!(line.contains("using the CPU") || line.contains("using the GPU"), "{line}");
    // The report says the same, whatever the verbosity.
    let r: serde_json::Value = serde_json::from_slice(&std::fs::read(&rep).unwrap()).unwrap();
    assert!(line.ends_with(r["backend_note"].as_str().unwrap()), "{line} / {}", r["backend_note"]);
}

/// Largest extra peak memory (MB, the report's `peak_rss_mb`) that `--backend auto` may add to
/// a run that chooses the CPU. Why: measured 0.0 MB (10.85 against 10.90 MB on a 2,000-face
/// sample); before the probe left the process, lavapipe's driver stayed resident: 70.2 against
/// 10.7 MB. 3 MB is the allocator's run-to-run spread with room.
const AUTO_EXTRA_MB: f64 = 3.0;

/// `--backend auto` on a machine with only a software adapter (lavapipe) chooses the CPU and
/// holds no Vulkan driver in the decimating process: its peak memory is the CPU backend's.
#[test]
fn backend_auto_choosing_the_cpu_holds_no_gpu_driver() {
    let Some(g) = vulkan() else { return };
    if g.info.device_type != wgpu::DeviceType::Cpu {
        eprintln!("SKIPPED: a hardware adapter ({}): --backend auto uses it", g.describe());
        return;
    }
    drop(g);
    let dir = tempdir("backend-auto-memory");
    let scan = dir.join("scan.obj");
    assert_eq!(run(&["sample", "--faces", "2000", "-o", scan.to_str().unwrap()]).status.code(), Some(0));
    let mut peak = Vec::new();
    for backend in ["auto", "cpu"] {
        let rep = dir.join(format!("{backend}.json"));
        let o = run(&["decimate", scan.to_str().unwrap(), "-o", dir.join(format!("{backend}.obj")).to_str().unwrap(), "--backend", backend, "--report", rep.to_str().unwrap(), "-q"]);
        assert_eq!(o.status.code(), Some(0), "{}", String::from_utf8_lossy(&o.stderr));
        let r: Value = serde_json::from_slice(&std::fs::read(&rep).unwrap()).unwrap();
        assert_eq!(r["backend"], "cpu", "{backend}: {r}");
        if backend == "auto" {
            assert!(r["backend_note"].as_str().unwrap().contains("no hardware adapter"), "{}", r["backend_note"]);
        }
        peak.push(r["peak_rss_mb"].as_f64().expect("peak_rss_mb on Linux"));
    }
    eprintln!("peak memory: --backend auto {:.2} MB, --backend cpu {:.2} MB", peak[0], peak[1]);
    assert!(peak[0] <= peak[1] + AUTO_EXTRA_MB, "--backend auto {:.1} MB against cpu {:.1} MB: the GPU probe's driver stayed in the process", peak[0], peak[1]);
}

/// `dispdec bench` on a small generated mesh, every path, three runs: the JSON has a row per
/// path with medians, equal faces out on every path, the adapter, and the meshoptimizer ratio.
#[test]
fn bench_compares_the_paths_on_the_same_input() {
    let gpu = vulkan().is_some();
    let dir = tempdir("bench");
    let scan = dir.join("small.obj");
    assert_eq!(run(&["sample", "--faces", "3000", "--seed", "2", "-o", scan.to_str().unwrap()]).status.code(), Some(0));
    let j = dir.join("bench.json");
    let o = run(&[
        "bench", "--meshes", scan.to_str().unwrap(), "--runs", "3", "--configs", "cpu1,cpu,gpu", "--json", j.to_str().unwrap(),
        "--work", dir.join("work").to_str().unwrap(),
    ]);
    let (out, err) = (String::from_utf8_lossy(&o.stdout), String::from_utf8_lossy(&o.stderr));
    assert_eq!(o.status.code(), Some(0), "{err}");
    eprintln!("{out}");
    assert!(out.contains("| mesh | faces in | path |"), "{out}");
    let r: Value = serde_json::from_slice(&std::fs::read(&j).unwrap()).unwrap();
    let rows = r["rows"].as_array().unwrap();
    assert_eq!(rows.len(), if gpu { 3 } else { 2 }, "{r}");
    let faces: Vec<&Value> = rows.iter().map(|row| &row["faces_out"]).collect();
    for row in rows {
        assert_eq!(row["runs_total_s"].as_array().unwrap().len(), 3);
        assert_eq!(row["valid"], true);
        assert_eq!(&row["faces_out"], faces[0], "every path and run gives the same base");
        assert!(row["median"]["total_s"].as_f64().unwrap() > 0.0);
        assert!(row["meshopt_s"].as_f64().unwrap() > 0.0);
        assert!(row["ratio_to_meshopt"].as_f64().unwrap() > 1.0);
        if cfg!(target_os = "linux") {
            // Each run's peak, measured in its own process (`dispdec bench-run`).
            assert!(row["peak_rss_mb"].as_f64().is_some_and(|p| p > 0.0), "{row}");
        }
    }
    assert_eq!(rows[0]["threads"], 1);
    // The per-stage timers, in the JSON and in the printed stage table.
    let stages: Vec<&str> = rows[0]["median"]["stages_cpu_s"].as_array().unwrap().iter().map(|s| s[0].as_str().unwrap()).collect();
    assert_eq!(stages, ["neighbourhood", "primaries", "reach", "continuity", "orientation"]);
    assert!(out.contains("| continuity | orientation | pick | commit |"), "{out}");
    if gpu {
        assert!(rows[2]["adapter"].as_str().unwrap().contains("Vulkan"));
        assert!(rows[2]["band_fraction"].as_f64().is_some());
    }
    assert!(r["machine"].as_str().unwrap().contains("cores"));
    assert_eq!(r["batch"], 16);
    assert!(!out.contains("--batch"), "the default width goes unnamed: {out}");
    // `--batch N` decimates every run at that width and names it: at 1, the paper's serial
    // order, the 334 faces `tests/sample_mesh.rs` pins for this sample.
    let j1 = dir.join("bench1.json");
    let o = run(&[
        "bench", "--meshes", scan.to_str().unwrap(), "--configs", "cpu1", "--batch", "1", "--json", j1.to_str().unwrap(),
        "--work", dir.join("work1").to_str().unwrap(),
    ]);
    let out = String::from_utf8_lossy(&o.stdout);
    assert_eq!(o.status.code(), Some(0), "{}", String::from_utf8_lossy(&o.stderr));
    assert!(out.lines().next().is_some_and(|l| l.ends_with("; --batch 1")), "{out}");
    let r: Value = serde_json::from_slice(&std::fs::read(&j1).unwrap()).unwrap();
    assert_eq!(r["batch"], 1);
    assert_eq!(r["rows"][0]["faces_out"], serde_json::json!([334]), "{r}");
    let o = run(&["bench", "--meshes", scan.to_str().unwrap(), "--batch", "0", "--work", dir.join("work0").to_str().unwrap()]);
    assert_eq!(o.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&o.stderr).contains("--batch must be at least 1"));
    let o = run(&["bench", "--meshes", scan.to_str().unwrap(), "--runs", "0", "--work", dir.join("work0").to_str().unwrap()]);
    assert_eq!(o.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&o.stderr).contains("--runs must be at least 1"));
}
