//! One test per bad-input class (issue: mesh input): exit code 2, a message naming the file and
//! the problem, and no output file.

mod common;
use common::*;
use std::path::Path;

/// Runs `decimate` on `input`, asserts exit 2, a message with the file name and `needle`, and
/// that none of the outputs exists.
fn expect_rejected(dir: &Path, input: &Path, needle: &str) {
    let out = dir.join("base.obj");
    let map = dir.join("base.map");
    let rep = dir.join("r.json");
    let o = run(&[
        "decimate",
        input.to_str().unwrap(),
        "-o",
        out.to_str().unwrap(),
        "--map",
        map.to_str().unwrap(),
        "--report",
        rep.to_str().unwrap(),
    ]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(2), "exit code for {}: stderr {err}", input.display());
    let fname = input.file_name().unwrap().to_string_lossy();
    assert!(err.contains(fname.as_ref()), "message must name the file {fname}: {err}");
    assert!(err.to_lowercase().contains(&needle.to_lowercase()), "message must say '{needle}': {err}");
    assert!(!err.contains("panicked"), "no panic on user input: {err}");
    for p in [&out, &map, &rep] {
        assert!(!p.exists(), "no output file may be left: {}", p.display());
    }
    let leftovers: Vec<_> = std::fs::read_dir(dir).unwrap().flatten().map(|e| e.file_name()).collect();
    let inputs = leftovers.iter().filter(|n| n.to_string_lossy().contains(".tmp")).count();
    assert_eq!(inputs, 0, "no temporary files left: {leftovers:?}");
}

fn write(dir: &Path, name: &str, text: &str) -> std::path::PathBuf {
    let p = dir.join(name);
    std::fs::write(&p, text).unwrap();
    p
}

//  A closed tetrahedron, consistently wound outward: the smallest valid closed mesh.
const TET_V: &str = "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\n";

#[test]
fn missing_file() {
    let d = tempdir("missing");
    expect_rejected(&d, &d.join("nope.obj"), "cannot read");
}

#[test]
fn unreadable_file() {
    let d = tempdir("unreadable");
    let p = d.join("adir.obj");
    std::fs::create_dir(&p).unwrap();
    expect_rejected(&d, &p, "cannot read");
}

#[test]
fn malformed_obj() {
    let d = tempdir("malformed");
    let p = write(&d, "bad.obj", "v 0 0 0\nv 1 zero 0\nv 0 1 0\nf 1 2 3\n");
    expect_rejected(&d, &p, "line 2");
}

#[test]
fn truncated_binary_ply() {
    let d = tempdir("truncated");
    let mut b = b"ply\nformat binary_little_endian 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\nelement face 1\nproperty list uchar int vertex_indices\nend_header\n".to_vec();
    for v in [0.0f32, 0.0, 0.0, 1.0, 0.0, 0.0] {
        b.extend_from_slice(&v.to_le_bytes());
    }
    let p = d.join("cut.ply");
    std::fs::write(&p, b).unwrap();
    expect_rejected(&d, &p, "truncated");
}

#[test]
fn truncated_gzip() {
    let d = tempdir("truncgz");
    use std::io::Write;
    let mut e = flate2::write::GzEncoder::new(Vec::new(), flate2::Compression::default());
    e.write_all(format!("{TET_V}f 1 3 2\nf 1 2 4\nf 1 4 3\nf 2 3 4\n").as_bytes()).unwrap();
    let full = e.finish().unwrap();
    let p = d.join("cut.obj.gz");
    std::fs::write(&p, &full[..full.len() / 2]).unwrap();
    expect_rejected(&d, &p, "gzip");
}

#[test]
fn index_out_of_range() {
    let d = tempdir("range");
    let p = write(&d, "range.obj", &format!("{TET_V}f 1 3 2\nf 1 2 9\n"));
    expect_rejected(&d, &p, "vertex 9");
    let ply = "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\nelement face 1\nproperty list uchar int vertex_indices\nend_header\n0 0 0\n1 0 0\n0 1 0\n3 0 1 7\n";
    let p = write(&d, "range.ply", ply);
    expect_rejected(&d, &p, "face 0");
}

#[test]
fn nan_coordinate() {
    let d = tempdir("nan");
    let p = write(&d, "nan.obj", "v 0 0 0\nv 1 0 0\nv 0 NaN 0\nv 0 0 1\nf 1 3 2\nf 1 2 4\nf 1 4 3\nf 2 3 4\n");
    expect_rejected(&d, &p, "non-finite");
    let p = write(&d, "inf.obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 inf\nf 1 3 2\nf 1 2 4\nf 1 4 3\nf 2 3 4\n");
    expect_rejected(&d, &p, "non-finite");
}

#[test]
fn a_stray_vertex_far_off_is_refused() {
    // Found by mutating files at random: the 968-face sample with one vertex's z replaced by
    // -1.25e18 (a binary PLY's float garbled) made decimate run on past minutes, every search
    // reaching every face; nearer (9.3e4 median edges off) it wrote a base that failed the
    // final check. Now it is refused before any work: exit 2, the vertex named.
    let d = tempdir("stray");
    let s = d.join("s.obj");
    let o = run(&["-q", "sample", "--faces", "1000", "--seed", "3", "-o", s.to_str().unwrap()]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let text = std::fs::read_to_string(&s).unwrap();
    let mut k = 0;
    let moved: Vec<String> = text
        .lines()
        .map(|l| {
            if !l.starts_with("v ") {
                return l.to_string();
            }
            k += 1;
            if k != 459 {
                return l.to_string();
            }
            let p: Vec<&str> = l.split_whitespace().collect();
            format!("v {} {} -1.25e18", p[1], p[2])
        })
        .collect();
    let p = write(&d, "stray.obj", &(moved.join("\n") + "\n"));
    expect_rejected(&d, &p, "median edge lengths (at most 1e4)");
    let err = String::from_utf8_lossy(&run(&["decimate", p.to_str().unwrap(), "-o", d.join("b.obj").to_str().unwrap()]).stderr).to_string();
    assert!(err.contains("vertex farthest from the rest is 458 at") && err.contains("stray vertex?"), "{err}");
    // validate reads the scan the same way.
    let o = run(&["validate", p.to_str().unwrap(), s.to_str().unwrap()]);
    assert_eq!(o.status.code(), Some(2), "{}", String::from_utf8_lossy(&o.stderr));
}

#[test]
fn a_scan_of_32_bit_floats_far_off_is_refused_saying_why() {
    // A 5×5 grid of 0.2 spacing at a UTM-like place, written as f32 values (as a binary PLY or
    // STL would hold it): f32's grid there is 0.5, vertices fall onto one another and faces
    // collapse. The message says why, rather than suggest --repair.
    let d = tempdir("f32far");
    let mut text = String::new();
    for y in 0..5 {
        for x in 0..5 {
            let c = |k: i32| (5.3e6 + 0.2 * k as f64) as f32 as f64;
            text.push_str(&format!("v {} {} 0\n", c(x), c(y)));
        }
    }
    for y in 0..4 {
        for x in 0..4 {
            let a = 5 * y + x + 1;
            text.push_str(&format!("f {a} {} {}\nf {a} {} {}\n", a + 1, a + 6, a + 6, a + 5));
        }
    }
    let p = write(&d, "utm-f32.obj", &text);
    expect_rejected(&d, &p, "its coordinates are all 32-bit floats, which 5300001 from the origin lie on a grid of 0.5");
    let err = String::from_utf8_lossy(&run(&["decimate", p.to_str().unwrap(), "-o", d.join("b.obj").to_str().unwrap()]).stderr).to_string();
    assert!(err.contains("is degenerate") && !err.contains("--repair"), "{err}");
}

#[test]
fn face_that_cannot_be_triangulated() {
    let d = tempdir("twogon");
    let p = write(&d, "twogon.obj", &format!("{TET_V}f 1 3 2\nf 1 2\n"));
    expect_rejected(&d, &p, "cannot be triangulated");
}

#[test]
fn degenerate_faces() {
    let d = tempdir("degen");
    let p = write(&d, "repeat.obj", &format!("{TET_V}f 1 3 2\nf 1 1 4\n"));
    expect_rejected(&d, &p, "degenerate");
    // Zero area: three collinear points.
    let p = write(&d, "flat.obj", "v 0 0 0\nv 1 0 0\nv 2 0 0\nf 1 2 3\n");
    expect_rejected(&d, &p, "zero area");
}

#[test]
fn non_manifold_edge() {
    let d = tempdir("nmedge");
    //   three triangles hinged on edge 1-2 (a "book" with three pages)
    let p = write(
        &d,
        "book.obj",
        "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 -1 0\nv 0 0 1\nf 1 2 3\nf 2 1 4\nf 1 2 5\n",
    );
    let o = run(&["decimate", p.to_str().unwrap(), "-o", d.join("x.obj").to_str().unwrap()]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(2), "{err}");
    // Three pages: either the edge is shared by three faces or two run the same way.
    assert!(err.contains("non-manifold edge") || err.contains("inconsistent winding"), "{err}");
    // A consistent book with three pages cannot be wound consistently; a fan of four faces
    // around one edge, alternating, is a pure non-manifold edge.
    let p = write(
        &d,
        "book4.obj",
        "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 -1 0\nv 0 0 1\nv 0 0 -1\nf 1 2 3\nf 2 1 4\nf 1 2 5\nf 2 1 6\n",
    );
    expect_rejected(&d, &p, "non-manifold edge");
}

#[test]
fn non_manifold_vertex() {
    let d = tempdir("nmvert");
    // Two triangles touching at vertex 1 only (a bow tie).
    let p = write(&d, "bowtie.obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\nv -1 0 0\nv 0 -1 0\nf 1 2 3\nf 1 4 5\n");
    expect_rejected(&d, &p, "non-manifold vertex");
}

#[test]
fn inconsistent_winding() {
    let d = tempdir("winding");
    // Two triangles sharing edge 1-2, both running 1 -> 2.
    let p = write(&d, "wind.obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 -1 0\nf 1 2 3\nf 1 2 4\n");
    expect_rejected(&d, &p, "inconsistent winding");
}

#[test]
fn empty_mesh() {
    let d = tempdir("empty");
    let p = write(&d, "empty.obj", "# nothing here\nv 0 0 0\n");
    expect_rejected(&d, &p, "no faces");
    let p = write(&d, "zero.ply", "");
    expect_rejected(&d, &p, "empty");
}

#[test]
fn bad_options_are_usage_errors() {
    let d = tempdir("usage");
    let p = write(&d, "tet.obj", &format!("{TET_V}f 1 3 2\nf 1 2 4\nf 1 4 3\nf 2 3 4\n"));
    let out = d.join("o.obj");
    let o = run(&["decimate", p.to_str().unwrap(), "-o", out.to_str().unwrap(), "--dmax", "-1"]);
    assert_eq!(o.status.code(), Some(2));
    assert!(!out.exists());
    let o = run(&["decimate", p.to_str().unwrap(), "-o", out.to_str().unwrap(), "--normals", "sideways"]);
    assert_eq!(o.status.code(), Some(2));
    assert!(!out.exists());
}

/// `dispdec bench` reports bad input as `decimate` does — exit 2, the file and the problem
/// named — both where its own process finds it (a scan it cannot read) and where a run's
/// process does (`dispdec bench-run`, here unable to write its base): the child's error comes
/// back as the error it is, not as a failed child.
#[test]
fn bench_reports_bad_input_from_either_process() {
    let d = tempdir("bench-bad");
    //   four triangles hinged on edge 1-2, alternating: a pure non-manifold edge
    let p = write(
        &d,
        "book4.obj",
        "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 -1 0\nv 0 0 1\nv 0 0 -1\nf 1 2 3\nf 2 1 4\nf 1 2 5\nf 2 1 6\n",
    );
    let o = run(&["bench", "--meshes", p.to_str().unwrap(), "--work", d.join("work").to_str().unwrap()]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(2), "{err}");
    assert!(err.contains("book4.obj") && err.contains("non-manifold edge"), "{err}");
    // A valid tetrahedron whose run cannot write its base: a folder sits where the base goes.
    let tet = write(&d, "tet.obj", &format!("{TET_V}f 1 3 2\nf 1 2 4\nf 1 4 3\nf 2 3 4\n"));
    let work = d.join("work2");
    std::fs::create_dir_all(work.join("tet.obj-Cpu1.obj")).unwrap();
    let o = run(&["bench", "--meshes", tet.to_str().unwrap(), "--configs", "cpu1", "--work", work.to_str().unwrap()]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(2), "{err}");
    assert!(err.contains("cannot write") && err.contains("tet.obj-Cpu1.obj"), "{err}");
    assert!(!err.contains("panicked") && !err.contains("bench process"), "{err}");
}

/// Never lose the user's data: an output named like an input — the same path, a symlink to it —
/// or like another output is refused before any work (exit 2, both named), and the input stays
/// byte for byte. Before this, `decimate scan.obj -o scan.obj` replaced the scan by its base.
/// The files `bake` writes beside its map (D.obj, D.ext.json) replace only an earlier bake's.
#[test]
fn an_output_on_an_input_is_refused_and_the_input_kept() {
    let d = tempdir("output-on-input");
    let scan = write(&d, "scan.obj", &format!("{TET_V}f 1 3 2\nf 1 2 4\nf 1 4 3\nf 2 3 4\n"));
    let before = std::fs::read(&scan).unwrap();
    let s = scan.to_str().unwrap();
    let link = d.join("link.obj");
    std::os::unix::fs::symlink(&scan, &link).unwrap();
    let base = d.join("base.obj");
    let refused = |args: &[&str], named: &str, says: &str| {
        let o = run(args);
        let err = String::from_utf8_lossy(&o.stderr);
        assert_eq!(o.status.code(), Some(2), "{args:?}: {err}");
        assert!(err.contains(named) && err.contains(says), "{args:?} must name {named} and say '{says}': {err}");
        assert_eq!(std::fs::read(&scan).unwrap(), before, "{args:?} changed the scan");
    };
    refused(&["decimate", s, "-o", s], "scan.obj", "would overwrite the input");
    refused(&["decimate", s, "-o", base.to_str().unwrap(), "--report", link.to_str().unwrap()], "link.obj", "would overwrite the input");
    refused(&["decimate", s, "-o", base.to_str().unwrap(), "--map", base.to_str().unwrap()], "base.obj", "both the base mesh and the map");
    assert!(!base.exists(), "nothing written by a refused run");
    // A real base, then the other commands pointed back at their inputs.
    let o = run(&["decimate", s, "-o", base.to_str().unwrap(), "-q"]);
    assert_eq!(o.status.code(), Some(0), "{}", String::from_utf8_lossy(&o.stderr));
    let base_before = std::fs::read(&base).unwrap();
    let b = base.to_str().unwrap();
    refused(&["validate", s, b, "--json", b], "base.obj", "would overwrite the input");
    refused(&["validate", s, b, "--fold-image", s], "scan.obj", "would overwrite the input");
    refused(&["validate", s, b, "--failures", b], "base.obj", "would overwrite the input");
    let (fold, fails) = (d.join("f.png"), d.join("f.obj"));
    refused(&["validate", s, b, "--fold-image", fold.to_str().unwrap(), "--failures", fold.to_str().unwrap()], "f.png", "both the fold image and the failures mesh");
    // An unwritable report: neither the fold image nor the failures mesh is left behind.
    let o = run(&["validate", s, b, "--fold-image", fold.to_str().unwrap(), "--failures", fails.to_str().unwrap(), "--json", d.join("no/such/dir/r.json").to_str().unwrap()]);
    assert_eq!(o.status.code(), Some(2), "{}", String::from_utf8_lossy(&o.stderr));
    assert!(!fold.exists() && !fails.exists(), "no partial output");
    let disp = d.join("disp.png");
    let o = run(&["bake", s, b, "-o", disp.to_str().unwrap(), "--resolution", "64"]);
    assert_eq!(o.status.code(), Some(0), "{}", String::from_utf8_lossy(&o.stderr));
    refused(&["reconstruct", b, disp.to_str().unwrap(), "--levels", "1", "-o", b], "base.obj", "would overwrite the input");
    // The files bake writes beside a map replace an earlier bake's, never a file of the user's.
    let baked_obj = std::fs::read(d.join("disp.obj")).unwrap();
    let o = run(&["bake", s, b, "-o", disp.to_str().unwrap(), "--resolution", "64"]);
    assert_eq!(o.status.code(), Some(0), "baked again over its own outputs: {}", String::from_utf8_lossy(&o.stderr));
    assert_eq!(std::fs::read(d.join("disp.obj")).unwrap(), baked_obj, "the same base with UVs");
    let (mine, mine_map) = (d.join("mine.obj"), d.join("mine.exr"));
    std::fs::write(&mine, "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n").unwrap();
    refused(&["bake", s, b, "-o", mine_map.to_str().unwrap(), "--resolution", "64"], "mine.obj", "did not write");
    assert_eq!(std::fs::read_to_string(&mine).unwrap(), "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n", "the user's mesh is kept");
    assert!(!mine_map.exists(), "nothing written by a refused bake");
    let side = d.join("side.exr.json");
    std::fs::write(&side, "my notes\n").unwrap();
    refused(&["bake", s, b, "-o", d.join("side.exr").to_str().unwrap(), "--resolution", "64"], "side.exr.json", "did not write");
    assert!(!d.join("side.obj").exists() && std::fs::read_to_string(&side).unwrap() == "my notes\n");
    refused(&["bench", "--meshes", s, "--configs", "cpu1", "--json", s, "--work", d.join("work").to_str().unwrap()], "scan.obj", "would overwrite the input");
    assert_eq!(std::fs::read(&base).unwrap(), base_before, "the base is kept");
}
