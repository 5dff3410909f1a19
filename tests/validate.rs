//! `dispdec validate`: constructed cases with known answers, a quadric-error base that must
//! fail, and the command's contract (exit codes, reports, fold image).

mod common;
use common::*;
use glam::DVec3;
use serde_json::Value;
use std::path::Path;

/// Half-angle of the mushroom cap around +z, in radians.
const MUSHROOM: f64 = 0.45;

/// The bumpy sphere with a mushroom around +z: the cap's rim folds back over its stem, so
/// directions from any smooth base see the rim twice.
fn mushroom(p: DVec3) -> DVec3 {
    let q = bumpy(p);
    let theta = p.z.clamp(-1.0, 1.0).acos();
    if theta >= MUSHROOM {
        return q;
    }
    let rho = theta / MUSHROOM;
    // (polar-angle scale, radial lift) along the profile: cap, rim, underside back inwards, stem.
    let keys = [(0.0, 0.0, 0.35), (0.35, 0.9, 0.33), (0.5, 1.25, 0.22), (0.62, 0.9, 0.12), (0.75, 0.45, 0.1), (1.0, 1.0, 0.0)];
    let mut out = (rho, 0.0);
    for w in keys.windows(2) {
        let ((r0, a0, h0), (r1, a1, h1)) = (w[0], w[1]);
        if rho <= r1 {
            let t = (rho - r0) / (r1 - r0);
            out = (a0 + t * (a1 - a0), h0 + t * (h1 - h0));
            break;
        }
    }
    let new_theta = MUSHROOM * out.0;
    let phi = p.y.atan2(p.x);
    let dir = DVec3::new(new_theta.sin() * phi.cos(), new_theta.sin() * phi.sin(), new_theta.cos());
    dir * (q.length() + out.1)
}

fn validate(dir: &Path, high: &Path, base: &Path, extra: &[&str]) -> (i32, Value, String) {
    let json = dir.join("v.json");
    let png = dir.join("fold.png");
    let mut args = vec![
        "validate",
        high.to_str().unwrap(),
        base.to_str().unwrap(),
        "--json",
        json.to_str().unwrap(),
        "--fold-image",
        png.to_str().unwrap(),
        "--resolution",
        "256",
    ];
    args.extend_from_slice(extra);
    let o = run(&args);
    let err = String::from_utf8_lossy(&o.stderr).to_string();
    eprintln!("{err}");
    let code = o.status.code().unwrap();
    if code == 2 {
        return (code, Value::Null, err);
    }
    let png_bytes = std::fs::read(&png).expect("fold image written");
    assert_eq!(&png_bytes[1..4], b"PNG");
    (code, serde_json::from_slice(&std::fs::read(&json).unwrap()).unwrap(), err)
}

#[test]
fn bumpy_sphere_over_icosahedron_is_valid() {
    let dir = tempdir("val-bumpy");
    let (high, base) = sphere_files(&dir, bumpy);
    let (code, r, err) = validate(&dir, &high, &base, &[]);
    assert_eq!(code, 0, "{err}");
    let v = &r["verdict"];
    assert_eq!(v["valid"], true);
    assert_eq!(v["unmapped"], 0);
    assert_eq!(v["flipped"], 0);
    assert_eq!(v["torn"], 0);
    assert_eq!(r["directions"], "computed", "no vn in the base: directions are computed");
    assert!(err.contains("no vn"), "says so: {err}");
    assert_eq!(r["base_faces"], 20);
    // Every base face is covered exactly once but for specks where pieces of dense triangles
    // straddling two base faces meet (under 3 % of the ~1,500 chart texels per face at 256²).
    let cov = &r["coverage"];
    assert!(cov["min"].as_f64().unwrap() > 0.95 && cov["max"].as_f64().unwrap() < 1.05, "{cov}");
    let texels: u64 = 20 * 1500;
    let specks = cov["folded_texels"].as_u64().unwrap() + cov["hole_texels"].as_u64().unwrap();
    assert!(specks * 100 < 3 * texels, "{specks} of ~{texels} texels");
}

#[test]
fn mushroom_overhang_is_invalid_and_found() {
    let dir = tempdir("val-mushroom");
    let (high, base) = sphere_files(&dir, mushroom);
    let (code, r, err) = validate(&dir, &high, &base, &[]);
    assert_eq!(code, 1, "{err}");
    let v = &r["verdict"];
    assert_eq!(v["valid"], false);
    let bad = v["unmapped"].as_u64().unwrap() + v["flipped"].as_u64().unwrap() + v["torn"].as_u64().unwrap();
    assert!(bad > 0, "{v}");
    // The failures are on the mushroom (around +z), not elsewhere on the sphere.
    let fails = r["first_failures"].as_array().unwrap();
    assert!(!fails.is_empty());
    for f in fails {
        let p = &f["position"];
        let q = DVec3::new(p[0].as_f64().unwrap(), p[1].as_f64().unwrap(), p[2].as_f64().unwrap());
        let theta = (q.z / q.length()).acos();
        assert!(theta < MUSHROOM + 0.05, "failure outside the overhang: {f}");
    }
}

#[test]
fn base_equal_to_scan_is_valid_with_zero_displacement() {
    let dir = tempdir("val-identity");
    let (v, f) = icosphere(3);
    let high = dir.join("s.obj");
    write_obj(&high, &v.iter().map(|&p| bumpy(p)).collect::<Vec<_>>(), &f);
    let (code, r, err) = validate(&dir, &high, &high, &["--strict"]);
    assert_eq!(code, 0, "{err}");
    let v = &r["verdict"];
    assert_eq!(v["valid"], true);
    assert_eq!(v["strict"], true);
    assert!(v["max_abs_d"].as_f64().unwrap() < 1e-9, "{v}");
    // Walked finer, every loop of the scan on itself stays positive and every edge continuous.
    let (code, r, err) = validate(&dir, &high, &high, &["--fine-loops"]);
    assert_eq!(code, 0, "{err}");
    assert_eq!(r["verdict"]["fine_loops"], true);
    let c = &r["verdict"]["checks"];
    assert_eq!((c["fine_flipped"].as_u64(), c["fine_torn"].as_u64()), (Some(0), Some(0)), "{c}");
}

#[test]
fn validate_bad_input_is_exit_2_without_outputs() {
    let dir = tempdir("val-bad");
    let (high, _) = sphere_files(&dir, bumpy);
    let missing = dir.join("nope.obj");
    let json = dir.join("v.json");
    let o = run(&["validate", high.to_str().unwrap(), missing.to_str().unwrap(), "--json", json.to_str().unwrap()]);
    assert_eq!(o.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&o.stderr).contains("nope.obj"));
    assert!(!json.exists());
}

/// A quadric-error base (meshoptimizer, no guarantee) of the same face count as dispdec's is
/// judged by the same validator; dispdec's passes, the quadric one is expected to fail.
#[test]
fn quadric_error_base_of_the_bunny_fails_where_dispdecs_passes() {
    let Some(bunny) = real_scan("bunny.ply.gz") else { return };
    let dir = tempdir("val-qem");
    let ours = dir.join("ours.obj");
    let o = run(&["decimate", bunny.to_str().unwrap(), "-o", ours.to_str().unwrap(), "-q"]);
    assert_eq!(o.status.code(), Some(0), "{}", String::from_utf8_lossy(&o.stderr));
    let (code, r, err) = validate(&dir, &bunny, &ours, &[]);
    assert_eq!(code, 0, "{err}");
    assert_eq!(r["verdict"]["checks"]["jump_edges"], 0);
    // The brute-force mode agrees.
    let (code, rx, err) = validate(&dir, &bunny, &ours, &["--exhaustive"]);
    assert_eq!(code, 0, "{err}");
    for k in ["mapped", "unmapped", "flipped", "torn", "ambiguous", "far_hits"] {
        assert_eq!(rx["verdict"][k], r["verdict"][k], "{k}");
    }
    assert_eq!(rx["verdict"]["checks"], r["verdict"]["checks"]);
    let faces = r["base_faces"].as_u64().unwrap() as usize;
    // Walked at 8 pieces an edge (`--fine-loops`), the 143-face base is torn where the sampled
    // walk sees nothing: one dense triangle (66359), on a boundary edge of the scan whose
    // points from about 0.02 % to 23 % of its length have no solution on the base (measured
    // by brute force at 4,096 points); its two ends lie on one base face and the piece is
    // consistent with their stretch, so the sampled walk takes it whole. Measured: 1 torn, 1
    // of them a gap, 0 flipped.
    let fine_failures = dir.join("fine-failures.obj");
    let (code, rf, err) = validate(&dir, &bunny, &ours, &["--fine-loops", "--failures", fine_failures.to_str().unwrap()]);
    assert_eq!(code, 1, "{err}");
    let c = &rf["verdict"]["checks"];
    assert_eq!((c["fine_flipped"].as_u64(), c["fine_torn"].as_u64(), c["fine_gaps"].as_u64()), (Some(0), Some(1), Some(1)), "{c}");
    assert_eq!(rf["first_failures"][0]["index"], 66359, "{}", rf["first_failures"]);
    assert_eq!(c["straddling"], r["verdict"]["checks"]["straddling"], "the sampled verdicts are the same");

    // `--failures` draws that one triangle where it lies on the scan.
    let scan = dispdec::mesh::load_dense(&bunny).unwrap();
    let groups = failure_groups(&fine_failures);
    assert_eq!(groups.len(), 1, "{groups:?}");
    assert_eq!(groups[0].0, "torn");
    assert_eq!(groups[0].1, vec![scan.faces[66359].map(|v| scan.positions[v as usize])]);

    let verts: Vec<[f32; 3]> = scan.positions.iter().map(|p| [p.x as f32, p.y as f32, p.z as f32]).collect();
    let indices: Vec<u32> = scan.faces.iter().flatten().copied().collect();
    let adapter = meshopt::VertexDataAdapter::new(bytemuck::cast_slice(&verts), 12, 0).unwrap();
    let simplified = meshopt::simplify(&indices, &adapter, faces * 3, 1.0, meshopt::SimplifyOptions::empty(), None);
    let qem_faces: Vec<[u32; 3]> = simplified.chunks_exact(3).map(|t| [t[0], t[1], t[2]]).collect();
    assert!(qem_faces.len() <= faces + 2 && qem_faces.len() + 40 >= faces, "{} vs {faces}", qem_faces.len());
    let qem = dir.join("qem.obj");
    write_obj(&qem, &scan.positions, &qem_faces);
    let qem_failures = dir.join("qem-failures.obj.gz");
    let (code, r, err) = validate(&dir, &bunny, &qem, &["--failures", qem_failures.to_str().unwrap()]);
    assert_eq!(code, 1, "the quadric base must be found invalid: {err}");
    let v = &r["verdict"];
    assert!(v["unmapped"].as_u64().unwrap() + v["flipped"].as_u64().unwrap() + v["torn"].as_u64().unwrap() > 0);
    // Its failures mesh holds every flipped and torn triangle and every triangle with an
    // unmapped corner, each at the scan's own positions (the first failures of the report
    // among them).
    let groups = failure_groups(&qem_failures);
    let count = |name: &str| groups.iter().find(|g| g.0 == name).map_or(0, |g| g.1.len()) as u64;
    assert_eq!(count("flipped"), v["flipped"].as_u64().unwrap());
    assert_eq!(count("torn"), v["torn"].as_u64().unwrap());
    let by_corners: std::collections::HashSet<[[u64; 3]; 3]> =
        groups.iter().flat_map(|g| g.1.iter()).map(|t| t.map(|p| [p.x.to_bits(), p.y.to_bits(), p.z.to_bits()])).collect();
    for f in r["first_failures"].as_array().unwrap().iter().filter(|f| f["kind"] != "unmapped") {
        let t = scan.faces[f["index"].as_u64().unwrap() as usize].map(|v| scan.positions[v as usize]);
        assert!(by_corners.contains(&t.map(|p| [p.x.to_bits(), p.y.to_bits(), p.z.to_bits()])), "{f}");
    }
    let around: Vec<&[glam::DVec3; 3]> = groups.iter().filter(|g| g.0 == "unmapped").flat_map(|g| g.1.iter()).collect();
    assert_eq!(around.is_empty(), v["unmapped"] == 0);
    for f in r["first_failures"].as_array().unwrap().iter().filter(|f| f["kind"] == "unmapped") {
        let p = glam::DVec3::from_array(serde_json::from_value(f["position"].clone()).unwrap());
        // (serde_json reads floats to within an ulp, not always exactly.)
        assert!(around.iter().any(|t| t.iter().any(|q| q.distance(p) < 1e-12)), "{f}");
    }
}

/// The objects of a `validate --failures` OBJ (or .obj.gz): (name, triangles by their corners).
fn failure_groups(path: &std::path::Path) -> Vec<(String, Vec<[glam::DVec3; 3]>)> {
    let bytes = std::fs::read(path).unwrap();
    let text = if path.to_string_lossy().ends_with(".gz") {
        let mut s = String::new();
        std::io::Read::read_to_string(&mut flate2::read::GzDecoder::new(&bytes[..]), &mut s).unwrap();
        s
    } else {
        String::from_utf8(bytes).unwrap()
    };
    let mut verts = Vec::new();
    let mut groups: Vec<(String, Vec<[glam::DVec3; 3]>)> = Vec::new();
    for line in text.lines() {
        let mut it = line.split_whitespace();
        match it.next() {
            Some("v") => {
                let c: Vec<f64> = it.map(|t| t.parse().unwrap()).collect();
                verts.push(glam::DVec3::new(c[0], c[1], c[2]));
            }
            Some("o") => groups.push((it.next().unwrap().to_string(), Vec::new())),
            Some("f") => {
                let c: Vec<usize> = it.map(|t| t.parse::<usize>().unwrap() - 1).collect();
                groups.last_mut().unwrap().1.push([verts[c[0]], verts[c[1]], verts[c[2]]]);
            }
            _ => {}
        }
    }
    groups
}

/// The bases of `../shared/fixtures`, made outside the project, judged by SPEC §1's exact
/// rule: none carries its scan (jumps count as tears). The figures are this validator's (see
/// README, "Bases made elsewhere"); the brute-force mode gives the same verdict and counts,
/// second solutions (ambiguous, far hits) included.
#[test]
fn fixtures_are_judged_and_the_exhaustive_mode_agrees() {
    let fixtures = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../shared/fixtures");
    // (fixture, scan, unmapped, pinched, flipped, torn, jump edges, gap edges)
    let expected = [
        ("bunny_ref419.obj", "bunny.ply.gz", 0, 0, 0, 83, 77, 7),
        ("bunny_qem388.obj", "bunny.ply.gz", 91, 0, 1, 358, 350, 4),
        ("horse_ref2046.obj", "horse.ply.gz", 0, 1, 0, 158, 140, 0),
        ("horse_qem502.obj", "horse.ply.gz", 124, 1, 69, 444, 421, 0),
    ];
    let dir = tempdir("val-fixtures");
    for (fx, scan, unmapped, pinched, flipped, torn, jumps, gaps) in expected {
        let base = fixtures.join(fx);
        if !base.exists() {
            skipped(&format!("fixture {} not found", base.display()));
            continue;
        }
        let Some(high) = real_scan(scan) else { continue };
        let modes: &[&[&str]] = if fx.starts_with("bunny") { &[&["--backend", "cpu"], &["--exhaustive"]] } else { &[&["--backend", "cpu"]] };
        let mut cpu_verdict = Value::Null;
        for extra in modes {
            let (code, r, err) = validate(&dir, &high, &base, extra);
            assert_eq!(code, 1, "{fx} {extra:?}: {err}");
            let v = &r["verdict"];
            if extra.contains(&"cpu") {
                cpu_verdict = v.clone();
            }
            let got = (
                v["unmapped"].as_u64().unwrap(),
                v["pinched"].as_u64().unwrap(),
                v["flipped"].as_u64().unwrap(),
                v["torn"].as_u64().unwrap(),
                v["checks"]["jump_edges"].as_u64().unwrap(),
                v["checks"]["gap_edges"].as_u64().unwrap(),
            );
            assert_eq!(got, (unmapped, pinched, flipped, torn, jumps, gaps), "{fx} {extra:?}: {v}");
            assert_eq!(v["exhaustive"], extra.contains(&"--exhaustive"));
            // Second solutions by brute force (every base triangle) against the fast path's
            // (the BVH within dmax, culled by the triangles' bounds): the same counts.
            if extra.contains(&"--exhaustive") {
                for key in ["ambiguous", "far_hits"] {
                    assert_eq!(v[key], cpu_verdict[key], "{fx}: {key} by brute force and by the fast path");
                }
            }
        }
        // The same base with its `f` lines in reverse order gets the same verdict, every count
        // and list alike: where two distinct solutions' |d| nearly tie, the primary goes by the
        // exact |d|, not the face id. (While a tolerance of 1e-7·dmax gave such ties to the
        // lower face id, reversing the lines moved horse_qem502 from 441 to 444 torn dense faces
        // and bunny_qem388 from 359 to 358.)
        if fx.contains("qem") {
            let text = std::fs::read_to_string(&base).unwrap();
            let (faces, other): (Vec<&str>, Vec<&str>) = text.lines().partition(|l| l.starts_with("f "));
            let reversed = dir.join(format!("reversed-{fx}"));
            let body: Vec<&str> = other.into_iter().chain(faces.into_iter().rev()).collect();
            std::fs::write(&reversed, body.join("\n") + "\n").unwrap();
            let (code, rr, err) = validate(&dir, &high, &reversed, &["--backend", "cpu"]);
            assert_eq!(code, 1, "{fx} reversed: {err}");
            assert_eq!(rr["verdict"], cpu_verdict, "{fx}: the order of the f lines moved the verdict");
        }
    }
}

/// A jump at a fold of the solution path is a tear. `data/tests/sample6k-413-before-fold-rule.obj`
/// is the 413-face base dispdec made of the 6k sample (`dispdec sample --faces 6000 --seed 7`)
/// while a piece of an edge's image counted as continuous whenever its gap was within the
/// *larger* of its ends' stretches: at a fold (two roots of the cubic meet and vanish, and the
/// primary moves to another sheet) the stretch on the fold's side grows without bound, so that
/// rule passed any gap there, and that base's own global check found it valid. With the smaller
/// stretch such pieces are bisected until the jump is certain: 100 jump edges, 145 torn
/// triangles (measured; no other failure). Since pieces whose ends' faces share only a vertex
/// are split where the image leaves its face instead of at their midpoints, 104 and 151: those
/// samples land on 4 jumps the midpoints passed over.
#[test]
fn a_jump_at_a_fold_of_the_solution_path_is_a_tear() {
    let dir = tempdir("val-fold");
    let scan = sample_6k(&dir, "s6k.obj");
    let base = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("data/tests/sample6k-413-before-fold-rule.obj");
    let (code, r, err) = validate(&dir, &scan, &base, &["--backend", "cpu"]);
    assert_eq!(code, 1, "{err}");
    let v = &r["verdict"];
    assert_eq!((v["unmapped"].as_u64(), v["flipped"].as_u64(), v["torn"].as_u64()), (Some(0), Some(0), Some(151)), "{v}");
    assert_eq!(v["checks"]["jump_edges"], 104, "{v}");
    assert_eq!(v["checks"]["gap_edges"], 0, "{v}");
}

/// A base equal to its scan carries it: every dense point lies on L (d = 0) and each dense
/// triangle's image is its own base face. A point on a base vertex is labelled with one of
/// the faces around it (the lowest); the image loop of face 3 carries none of its own label,
/// so the one-triangle chart must also try the face that holds the loop's vertices (before,
/// the loop went to the star of vertex 0, whose boundary it runs along backwards: flipped, and
/// `decimate` of an irreducible mesh exited 1).
///
/// ```text
///          3             faces 0 (0,1,2), 1 (0,2,3), 2 (0,3,1), 3 (1,3,2)
///         /|\            labels: vertex 0 → face 0, 1 → 0, 2 → 0, 3 → 1
///        / | \           face 3 = (1,3,2) holds none of 0, 0, 1
///       0--+--2
///        \ | /
///          1
/// ```
#[test]
fn a_base_equal_to_its_scan_is_valid() {
    let dir = tempdir("val-identity");
    let tet = dir.join("tet.obj");
    let v = [DVec3::ZERO, DVec3::X, DVec3::Y, DVec3::Z];
    write_obj(&tet, &v, &[[0, 1, 2], [0, 2, 3], [0, 3, 1], [1, 3, 2]]);
    let (code, r, err) = validate(&dir, &tet, &tet, &[]);
    assert_eq!(code, 0, "{err}");
    let verdict = &r["verdict"];
    assert_eq!((verdict["flipped"].as_u64(), verdict["torn"].as_u64(), verdict["unmapped"].as_u64()), (Some(0), Some(0), Some(0)), "{verdict}");
    assert_eq!(verdict["max_abs_d"].as_f64(), Some(0.0));
    // Nothing to collapse (a tetrahedron): the base is the scan, and the run says it carries it.
    let out = dir.join("base.obj");
    let o = run(&["decimate", tet.to_str().unwrap(), "-o", out.to_str().unwrap(), "--quiet"]);
    assert_eq!(o.status.code(), Some(0), "{}", String::from_utf8_lossy(&o.stderr));
}
