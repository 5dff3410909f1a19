//! The decimator on the real scans of `../shared/data` (or $DISPDEC_DATA), through the real
//! binary: the paper's face counts, the guarantee re-checked locally and globally, topology
//! preserved, deterministic bytes whatever the thread count.

mod common;
use common::*;
use serde_json::Value;
use std::path::Path;

fn decimate(input: &Path, dir: &Path, name: &str, extra: &[&str]) -> (Value, Vec<u8>, Vec<u8>) {
    decimate_expect(input, dir, name, extra, 0)
}

fn decimate_expect(input: &Path, dir: &Path, name: &str, extra: &[&str], code: i32) -> (Value, Vec<u8>, Vec<u8>) {
    let obj = dir.join(format!("{name}.obj"));
    let map = dir.join(format!("{name}.map"));
    let rep = dir.join(format!("{name}.json"));
    let mut args = vec![
        "decimate",
        input.to_str().unwrap(),
        "-o",
        obj.to_str().unwrap(),
        "--map",
        map.to_str().unwrap(),
        "--report",
        rep.to_str().unwrap(),
        "--quiet",
    ];
    args.extend_from_slice(extra);
    let o = run(&args);
    let err = String::from_utf8_lossy(&o.stderr);
    eprintln!("{err}");
    assert_eq!(o.status.code(), Some(code), "decimate {} {extra:?}: {err}", input.display());
    let report: Value = serde_json::from_slice(&std::fs::read(&rep).unwrap()).unwrap();
    (report, std::fs::read(&obj).unwrap(), std::fs::read(&map).unwrap())
}

fn assert_carries(r: &Value) {
    for part in ["recheck", "global"] {
        let p = &r[part];
        assert_eq!(p["valid"], Value::Bool(true), "{part} must pass: {p}");
        assert_eq!(p["unmapped"], 0, "{part}: {p}");
        assert_eq!(p["flipped"], 0, "{part}: {p}");
        assert_eq!(p["torn"], 0, "{part}: {p}");
        // SPEC §1: no dense edge's image jumps, no point of one is left without a solution.
        assert_eq!(p["checks"]["jump_edges"], 0, "{part}: {p}");
        assert_eq!(p["checks"]["gap_edges"], 0, "{part}: {p}");
    }
}

/// The face count within 5 % of README's figure (`bash scripts/results.sh`).
fn assert_near(name: &str, faces: u64, readme: u64) {
    let lo = (readme as f64 * 0.95).floor() as u64;
    let hi = (readme as f64 * 1.05).ceil() as u64;
    assert!((lo..=hi).contains(&faces), "{name}: {faces} faces, README says {readme} (±5 %: {lo}..{hi})");
}

/// The report's `collapses.levels`: one entry per halving of the base, from the scan's face
/// count down, each level's distinct dense triangles at most the scan's, and the tests of the
/// 2-ring checking each one again and again — README, Benchmark: the bunny 13.1 times per
/// halving over the run (11.4–16.9 by level), the horse 13.2 (8.1 in its last, partial
/// halving, 12.2–17.3 in the others): `expected`, asserted within 10 %.
fn assert_rechecks(name: &str, r: &Value, expected: f64) {
    let levels = r["collapses"]["levels"].as_array().unwrap();
    let faces_in = r["faces_in"].as_u64().unwrap();
    let faces_out = r["faces_out"].as_u64().unwrap();
    assert_eq!(levels[0]["faces_from"].as_u64(), Some(faces_in), "{name}: {levels:?}");
    // One level per halving from faces_in down to faces_out (the last one taken part way).
    let halvings = (faces_in as f64 / faces_out as f64).log2().ceil() as usize;
    assert!(levels.len() == halvings || levels.len() + 1 == halvings, "{name}: {} levels for {halvings} halvings", levels.len());
    let (mut checked, mut distinct) = (0, 0);
    for l in levels {
        assert!(l["distinct_dense_faces"].as_u64().unwrap() <= faces_in);
        checked += l["dense_faces_checked"].as_u64().unwrap();
        distinct += l["distinct_dense_faces"].as_u64().unwrap();
    }
    let ratio = checked as f64 / distinct as f64;
    let (lo, hi) = (expected * 0.9, expected * 1.1);
    assert!((lo..=hi).contains(&ratio), "{name}: each dense triangle checked {ratio:.2} times per halving (README: {expected} ± 10 %)");
}

/// README's results table (`bash scripts/results.sh`).
const BUNNY_FACES: u64 = 143;
const HORSE_FACES: u64 = 308;

/// The base OBJ: `v`, one `vn` per `v`, `f v//vn`; a manifold with the given genus and loops.
fn assert_base_obj(bytes: &[u8], faces: u64, genus: i64, loops: u64) {
    let text = String::from_utf8_lossy(bytes);
    let nv = text.lines().filter(|l| l.starts_with("v ")).count();
    let nvn = text.lines().filter(|l| l.starts_with("vn ")).count();
    let nf = text.lines().filter(|l| l.starts_with("f ")).count();
    assert_eq!(nv, nvn, "one vn per v");
    assert_eq!(nf as u64, faces);
    assert!(text.lines().filter(|l| l.starts_with("f ")).all(|l| l.split_whitespace().skip(1).all(|c| {
        let (a, b) = c.split_once("//").unwrap();
        a == b
    })));
    let dir = tempdir("base-obj");
    let p = dir.join("b.obj");
    std::fs::write(&p, bytes).unwrap();
    let m = dispdec::mesh::load_dense(&p).expect("base mesh is a valid manifold mesh");
    assert_eq!(m.positions.len(), nv, "no unreferenced vertices in the base");
    let (g, l) = dispdec::topology::topology_summary(m.positions.len(), &m.faces);
    assert_eq!((g, l as u64), (genus, loops), "genus and boundary loops preserved");
}

#[test]
fn bunny_reaches_the_paper_and_carries_the_scan() {
    let Some(bunny) = real_scan("bunny.ply.gz") else { return };
    let dir = tempdir("bunny");
    let (r, obj, map) = decimate(&bunny, &dir, "b", &[]);
    let faces = r["faces_out"].as_u64().unwrap();
    assert_eq!(r["faces_in"], 69451);
    assert!(faces <= 388, "bunny: {faces} faces, the paper reached 388");
    assert_near("bunny", faces, BUNNY_FACES);
    assert_carries(&r);
    // Candidates of one round that read what an earlier commit changed were deferred.
    assert!(r["collapses"]["deferred"].as_u64().unwrap() > 0, "{}", r["collapses"]);
    assert_rechecks("bunny", &r, 13.1);
    assert_eq!(r["genus"], 0);
    assert_eq!(r["boundary_loops_in"], 5);
    assert_eq!(r["boundary_loops_out"], 5);
    assert_base_obj(&obj, faces, 0, 5);
    // The map covers every input vertex, referenced or not.
    let mf = dispdec::maps::mapfile::MapFile::read(&dir.join("b.map")).unwrap();
    assert_eq!(mf.records.len(), 35947);
    assert_eq!(mf.base_faces as u64, faces);
    let unref = mf.records.iter().filter(|x| x.status == dispdec::maps::mapfile::STATUS_UNREFERENCED).count();
    assert_eq!(unref, 1113);
    assert!(mf.records.iter().filter(|x| x.status == 0).all(|x| (x.face as u64) < faces && x.d.abs() <= mf.dmax));

    // Determinism: the same bytes with one thread as with all of them.
    let (r1, obj1, map1) = decimate(&bunny, &dir, "b1", &["--threads", "1"]);
    assert!(obj == obj1 && map == map1, "--threads 1 must give the same bytes");
    // (All but each halving's wall seconds: its counts and its checks' refusals.)
    let counts = |r: &Value| {
        let mut levels = r["collapses"]["levels"].clone();
        levels.as_array_mut().unwrap().iter_mut().for_each(|l| drop(l.as_object_mut().unwrap().remove("seconds")));
        levels
    };
    assert_eq!(counts(&r1), counts(&r), "the re-check counts do not depend on the threads");
}

/// `--strict` and `--normals constant` on the 6,050-face generated sample (seed 7): strict is
/// verified end to end (the global check runs strict: ambiguous = 0 over the whole base);
/// constant mode exempts what the scan itself cannot map — 63 vertices and 99 edges (two faces
/// folded by more than 90°: the fin's rim) — and the base is valid: nothing else unmapped,
/// flipped or torn, 0 jump edges.
#[test]
fn strict_and_constant_modes_on_the_sample() {
    let dir = tempdir("sample-modes");
    let scan = sample_6k(&dir, "scan.obj");
    let (r, obj, _) = decimate(&scan, &dir, "s", &["--strict"]);
    assert_eq!(r["strict"], true);
    assert_carries(&r);
    assert_eq!(r["global"]["strict"], true);
    assert_eq!(r["global"]["ambiguous"], 0, "{}", r["global"]);
    let fs = r["faces_out"].as_u64().unwrap();
    assert_near("sample --strict", fs, 516);
    assert_base_obj(&obj, fs, 0, 1);
    let (r, _, _) = decimate(&scan, &dir, "c", &["--normals", "constant"]);
    assert_eq!(r["normals"], "constant");
    assert_eq!(r["unmapped_at_start"], 63);
    assert_carries(&r);
    let g = &r["global"];
    assert_eq!(g["pinched"], 63, "exempt like pinched vertices: {g}");
    assert_eq!(g["exempt_edges"], 99, "{g}");
    // 3,582 (3,594 before the triangles near a region were judged whole, 3,598 before the
    // closed-form crossing, 3,590 before jumps at folds counted); 2,224 when a walk leaving one face's prism
    // was taken to enter the next at the same point (crossings count only where the two prisms
    // meet, at d = 0).
    assert_near("sample --normals constant", r["faces_out"].as_u64().unwrap(), 3582);
}

/// The same modes on the bunny (opt-in: ~25 min here): strict verified globally (README,
/// Modes: 387 faces); constant mode valid (exit 0: the re-check agrees with the global check
/// since near-ties of |d| go by the exact value) with only what the scan itself cannot map
/// exempt — its 13 vertices and 20 edges — at README's 38,648 faces.
#[test]
#[ignore = "slow (~25 min on 2 cores): cargo test --release --test real_data -- --ignored"]
fn bunny_strict_and_constant_modes() {
    let Some(bunny) = real_scan("bunny.ply.gz") else { return };
    let dir = tempdir("bunny-modes");
    let (r, obj, _) = decimate(&bunny, &dir, "s", &["--strict"]);
    assert_carries(&r);
    assert_eq!(r["global"]["strict"], true);
    assert_eq!(r["global"]["ambiguous"], 0, "{}", r["global"]);
    let fs = r["faces_out"].as_u64().unwrap();
    assert_near("bunny --strict", fs, 387);
    assert_base_obj(&obj, fs, 0, 5);
    let (r, _, _) = decimate(&bunny, &dir, "c", &["--normals", "constant"]);
    assert_carries(&r);
    assert_eq!(r["unmapped_at_start"], 13);
    assert_eq!(r["global"]["pinched"], 13);
    assert_eq!(r["global"]["exempt_edges"], 20);
    assert_near("bunny --normals constant", r["faces_out"].as_u64().unwrap(), 38648);
}

#[test]
fn horse_reaches_the_paper_and_carries_the_scan() {
    let Some(horse) = real_scan("horse.ply.gz") else { return };
    let dir = tempdir("horse");
    let (r, obj, _) = decimate(&horse, &dir, "h", &[]);
    let faces = r["faces_out"].as_u64().unwrap();
    assert_eq!(r["faces_in"], 96966);
    assert!(faces <= 502, "horse: {faces} faces, the paper reached 502");
    assert_near("horse", faces, HORSE_FACES);
    assert_carries(&r);
    assert_rechecks("horse", &r, 13.2);
    assert_base_obj(&obj, faces, 0, 0);

    // The fold image of the valid base: the scan covers each base face about once. Measured on
    // the 308-face base: 2,923 folded texels, the most covered face 1.032 (the 366-face base of
    // the release before: 2,938 and 1.047; the 308-face base of 97acdbb: 3,063 and 1.047; the 326-face base before it: 3,613 and 1.123; before pieces that straddle two faces were unfolded
    // into each face's chart: 14,330 and 2.24, slivers drawn over); the least 0.0, the 4 faces
    // around the 1 pinched vertex, whose triangles are not drawn. Bounds: 10 % and 0.03 above.
    let (json, png) = (dir.join("hv.json"), dir.join("hv.png"));
    let base = dir.join("h.obj");
    let o = run(&[
        "validate",
        horse.to_str().unwrap(),
        base.to_str().unwrap(),
        "--backend",
        "cpu",
        "--quiet",
        "--json",
        json.to_str().unwrap(),
        "--fold-image",
        png.to_str().unwrap(),
    ]);
    assert_eq!(o.status.code(), Some(0), "{}", String::from_utf8_lossy(&o.stderr));
    let v: Value = serde_json::from_slice(&std::fs::read(&json).unwrap()).unwrap();
    let cov = &v["coverage"];
    assert!(cov["folded_texels"].as_u64().unwrap() <= 3_215, "{cov}");
    assert!(cov["max"].as_f64().unwrap() <= 1.062, "{cov}");
    let pinched_holes = cov["per_face"].as_array().unwrap().iter().filter(|c| c.as_f64().unwrap() < 0.5).count();
    assert_eq!(pinched_holes, 4, "{cov}");

    // Walked at 8 pieces an edge (and 64 where that is negative), one loop that passes as
    // sampled is flipped: dense triangle 25804, the one stop 60 found (README, The exact
    // guarantee: SPEC's sampled image against finer walks). Measured on the 308-face base.
    let o = run(&["validate", horse.to_str().unwrap(), base.to_str().unwrap(), "--backend", "cpu", "--quiet", "--fine-loops", "--json", json.to_str().unwrap()]);
    assert_eq!(o.status.code(), Some(1), "{}", String::from_utf8_lossy(&o.stderr));
    let v: Value = serde_json::from_slice(&std::fs::read(&json).unwrap()).unwrap();
    let c = &v["verdict"]["checks"];
    assert_eq!((c["fine_flipped"].as_u64(), c["fine_torn"].as_u64()), (Some(1), Some(0)), "{c}");
    assert_eq!(v["first_failures"][0]["index"], 25804, "{}", v["first_failures"]);
}

/// `--ring-directions keep` on the horse (README, Results: Keeping the ring's directions): a
/// collapse gives only its kept vertex a new direction, so its test checks the faces around
/// the edge, not the 2-ring. Measured (2026-12-07): 280 faces (the default 308), both checks
/// passing, each dense triangle checked 4.2 times per halving (the default 13.2), the report
/// naming the rule. Bounds: the faces within 5 %, the checks within 10 %, fewer faces than the
/// default's figure.
#[test]
fn the_horse_with_its_rings_directions_kept_goes_further_and_carries_the_scan() {
    let Some(horse) = real_scan("horse.ply.gz") else { return };
    let dir = tempdir("horse-keep");
    let (r, obj, _) = decimate(&horse, &dir, "k", &["--ring-directions", "keep"]);
    assert_eq!(r["ring_directions"], "keep");
    let faces = r["faces_out"].as_u64().unwrap();
    assert_near("horse, --ring-directions keep", faces, 280);
    assert!(faces < HORSE_FACES, "{faces} faces, the default's {HORSE_FACES}");
    assert_carries(&r);
    assert_rechecks("horse, --ring-directions keep", &r, 4.2);
    assert_base_obj(&obj, faces, 0, 0);
}

/// `--target-faces 5000` on `scan` stops there (a collapse removes one or two faces), with
/// both final checks passing and the topology kept (genus 0, `loops` boundary loops).
fn stops_at_5000_faces_and_carries(scan: &str, loops: u64) {
    let Some(input) = real_scan(scan) else { return };
    let dir = tempdir(&format!("{scan}-target"));
    let (r, obj, _) = decimate(&input, &dir, "t", &["--target-faces", "5000"]);
    let faces = r["faces_out"].as_u64().unwrap();
    assert!((4998..=5000).contains(&faces), "{scan}: {faces}");
    assert_carries(&r);
    assert_base_obj(&obj, faces, 0, loops);
}

#[test]
fn target_faces_stops_there() {
    stops_at_5000_faces_and_carries("bunny.ply.gz", 5);
}

/// The horse stopped at 5,000 faces passes its final checks (exit 0, the re-check and the global
/// check valid). Until 2026-12-07 it ended with both checks finding dense triangle 25804 flipped
/// (exit 1): a vertex on a base vertex kept a face label that no test moved (the search asking
/// whether its primary moves onto a region ran over a range of |d| = 0), and the decimator's
/// loop through it had one sample more than the checks' — README, The exact guarantee.
#[test]
fn the_horse_stopped_at_5000_faces_passes_its_final_checks() {
    stops_at_5000_faces_and_carries("horse.ply.gz", 0);
}
