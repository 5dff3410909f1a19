//! Real scans as they come: welding, explicit repair, tolerant readers, quiet defaults,
//! settings that travel, exit codes. Every test runs the real binary.

mod common;
use common::*;
use glam::DVec3;
use serde_json::Value;
use std::path::{Path, PathBuf};

fn s(p: &Path) -> &str {
    p.to_str().unwrap()
}

/// Decimates `input` with `extra` flags; returns (exit code, report, stderr, base bytes).
fn decimate(dir: &Path, input: &Path, tag: &str, extra: &[&str]) -> (i32, Value, String, Vec<u8>) {
    let out = dir.join(format!("{tag}.obj"));
    let rep = dir.join(format!("{tag}.json"));
    let mut args = vec!["decimate", s(input), "-o", s(&out), "--report", s(&rep), "--backend", "cpu"];
    args.extend_from_slice(extra);
    let o = run(&args);
    let err = String::from_utf8_lossy(&o.stderr).to_string();
    let code = o.status.code().unwrap();
    if code == 2 {
        return (code, Value::Null, err, Vec::new());
    }
    let r: Value = serde_json::from_slice(&std::fs::read(&rep).unwrap()).unwrap();
    (code, r, err, std::fs::read(&out).unwrap())
}

/// The lines of an OBJ that are not comments (the header names the input file).
fn geometry(obj: &[u8]) -> Vec<String> {
    String::from_utf8_lossy(obj).lines().filter(|l| !l.starts_with('#')).map(str::to_string).collect()
}

/// A level-3 bumpy icosphere (1,280 faces): small, closed, decimates in a fraction of a second.
fn bumpy_sphere() -> (Vec<DVec3>, Vec<[u32; 3]>) {
    let (v, f) = icosphere(3);
    (v.into_iter().map(bumpy).collect(), f)
}

/// Every vertex split per face, as STL converters and Blender's exporters with UV seams write
/// them. `keep_order`: the first copy of each vertex comes first, in the original order (so
/// welding gives back the very same numbering); else the copies are in face order.
fn split_per_face(v: &[DVec3], f: &[[u32; 3]], keep_order: bool) -> (Vec<DVec3>, Vec<[u32; 3]>) {
    let mut pos = Vec::with_capacity(3 * f.len());
    let mut faces = Vec::with_capacity(f.len());
    if keep_order {
        pos.extend_from_slice(v);
        let mut first = vec![true; v.len()];
        for t in f {
            faces.push(t.map(|w| {
                if std::mem::take(&mut first[w as usize]) {
                    w
                } else {
                    pos.push(v[w as usize]);
                    (pos.len() - 1) as u32
                }
            }));
        }
    } else {
        for t in f {
            faces.push(t.map(|w| {
                pos.push(v[w as usize]);
                (pos.len() - 1) as u32
            }));
        }
    }
    (pos, faces)
}

fn read_map(p: &Path) -> (u32, Vec<[u8; 24]>) {
    let b = std::fs::read(p).unwrap();
    assert_eq!(&b[..8], b"DISPMAP2");
    let n = u32::from_le_bytes(b[8..12].try_into().unwrap());
    let len = u32::from_le_bytes(b[24..28].try_into().unwrap()) as usize;
    let start = 28 + len.div_ceil(4) * 4;
    let recs = b[start..].chunks_exact(24).map(|c| c.try_into().unwrap()).collect();
    (n, recs)
}

#[test]
fn seam_split_mesh_gives_the_welded_base() {
    let d = tempdir("seams");
    let (v, f) = bumpy_sphere();
    let whole = d.join("whole.obj");
    write_obj(&whole, &v, &f);
    let (code, r0, err, base0) = decimate(&d, &whole, "whole-base", &["--map", s(&d.join("whole.map"))]);
    assert_eq!(code, 0, "{err}");
    assert_eq!(r0["input_cleanup"]["welded_vertices"], 0);

    // Split with the first copies in order: welding restores the very same mesh, so the base
    // is the same, byte for byte, and each vertex's record is its first copy's.
    let (sv, sf) = split_per_face(&v, &f, true);
    assert_eq!(sv.len(), 3 * f.len());
    let split = d.join("split.obj");
    write_obj(&split, &sv, &sf);
    let (code, r1, err, base1) = decimate(&d, &split, "split-base", &["--map", s(&d.join("split.map"))]);
    assert_eq!(code, 0, "{err}");
    assert_eq!(r1["input_cleanup"]["welded_vertices"], 3 * f.len() - v.len());
    assert_eq!(geometry(&base1), geometry(&base0), "same base as the welded mesh");
    let (n0, rec0) = read_map(&d.join("whole.map"));
    let (n1, rec1) = read_map(&d.join("split.map"));
    assert_eq!((n0 as usize, n1 as usize), (v.len(), sv.len()));
    assert_eq!(&rec1[..v.len()], &rec0[..], "the first copies carry the original records");
    for (k, t) in sf.iter().enumerate() {
        for c in 0..3 {
            assert_eq!(rec1[t[c] as usize], rec0[f[k][c] as usize], "every copy shares its vertex's record");
        }
    }

    // Split in face order (as exporters write it): a welded mesh again, numbered otherwise; the
    // base is valid, and on the 6,000-face sample it has the face count of the welded file's
    // base within 5 %.
    let (sv, sf) = split_per_face(&v, &f, false);
    let soup = d.join("soup.obj");
    write_obj(&soup, &sv, &sf);
    let (code, r2, err, _) = decimate(&d, &soup, "soup-base", &[]);
    assert_eq!(code, 0, "{err}");
    assert_eq!(r2["global"]["valid"], true);
    let sample = d.join("sample.obj");
    assert_eq!(run(&["sample", "-o", s(&sample), "--faces", "6000", "--seed", "2"]).status.code(), Some(0));
    let m = dispdec::mesh::load_dense(&sample).unwrap();
    let (sv, sf) = split_per_face(&m.positions, &m.faces, false);
    let sample_soup = d.join("sample-soup.obj");
    write_obj(&sample_soup, &sv, &sf);
    let (c1, a, e1, _) = decimate(&d, &sample, "sample-base", &[]);
    let (c2, b, e2, _) = decimate(&d, &sample_soup, "sample-soup-base", &[]);
    assert_eq!((c1, c2), (0, 0), "{e1}\n{e2}");
    let (a, b) = (a["faces_out"].as_f64().unwrap(), b["faces_out"].as_f64().unwrap());
    assert!((b - a).abs() <= 0.05 * a, "face-order split: {b} faces against {a}");

    // --no-weld keeps the triangles apart: 1,280 separate components, nothing collapses, and
    // the global check finds the soup invalid (coincident copies map onto one face of the two):
    // what happened to such files before welding.
    let (code, r3, err, _) = decimate(&d, &soup, "apart", &["--no-weld"]);
    assert_eq!(code, 1, "{err}");
    assert_eq!(r3["input_cleanup"]["components"], f.len());
    assert_eq!(r3["faces_out"], f.len());
    let g = &r3["global"];
    assert_eq!(g["valid"], false, "{g}");
    assert!(g["unmapped"].as_u64().unwrap() + g["flipped"].as_u64().unwrap() + g["torn"].as_u64().unwrap() > 0, "{g}");
}

/// The bumpy sphere with one defect of every kind `--repair` handles, and what it should count.
///
/// - a duplicate of face 0 (wound the other way) and a degenerate face (a repeated vertex);
/// - face 5 wound the wrong way;
/// - a fin: a fourth face on the edge of face 10, so that edge has three faces;
/// - a bow tie: a spike of two triangles touching the sphere at one vertex only (in a plane
///   through the centre, so neither sheet sees the other under condition (4));
/// - a fragment: a lone triangle floating outside.
fn damaged_sphere(dir: &Path) -> (PathBuf, usize) {
    let (mut v, mut f) = bumpy_sphere();
    let n0 = f.len();
    f.push([f[0][0], f[0][2], f[0][1]]);
    f.push([f[1][0], f[1][0], f[1][1]]);
    f[5].swap(1, 2);
    let (a, b) = (f[10][0], f[10][1]);
    v.push(v[a as usize] * 1.3);
    f.push([a, b, (v.len() - 1) as u32]);
    let tip = f[20][0];
    let r = v[tip as usize];
    let t = r.cross(DVec3::Z).normalize() * 0.05;
    v.extend([r * 1.2 + t, r * 1.2, r * 1.2 - t]);
    let q = v.len() as u32 - 3;
    f.push([tip, q, q + 1]);
    f.push([tip, q + 1, q + 2]);
    v.extend([DVec3::new(3.0, 0.0, 0.0), DVec3::new(3.1, 0.0, 0.0), DVec3::new(3.0, 0.1, 0.0)]);
    let k = v.len() as u32;
    f.push([k - 3, k - 2, k - 1]);
    let p = dir.join("damaged.obj");
    write_obj(&p, &v, &f);
    (p, n0)
}

#[test]
fn repair_is_explicit_counted_and_judged_against_what_was_decimated() {
    let d = tempdir("repair");
    let (p, n0) = damaged_sphere(&d);
    // Without --repair: exit 2, the first defect named with the option that fixes it.
    let (code, _, err, _) = decimate(&d, &p, "refused", &[]);
    assert_eq!(code, 2, "{err}");
    assert!(err.contains("damaged.obj") && err.contains("--repair"), "{err}");
    assert!(!d.join("refused.obj").exists());

    let repaired = d.join("repaired.obj");
    let (code, r, err, _) = decimate(&d, &p, "base", &["--repair", "--min-component", "2", "--repaired", s(&repaired)]);
    assert_eq!(code, 0, "{err}");
    let c = &r["input_cleanup"];
    eprintln!("{c}");
    assert_eq!(c["repaired"], true);
    assert_eq!(c["degenerate_faces"], 1);
    assert_eq!(c["duplicate_faces"], 1);
    assert_eq!(c["non_manifold_edges"], 1);
    assert_eq!(c["non_manifold_edge_faces_removed"], 1, "one fin face removed, the fewest");
    assert_eq!(c["flipped_faces"], 1);
    assert_eq!((c["non_manifold_vertices"].as_u64(), c["vertex_copies"].as_u64()), (Some(1), Some(1)));
    assert_eq!((c["components_dropped"].as_u64(), c["component_faces_dropped"].as_u64()), (Some(1), Some(1)));
    // Kept: the sphere and the spike (now a component of its own).
    assert_eq!(c["components"], 2);
    assert_eq!(r["faces_in"], n0 + 2);
    assert_eq!(r["global"]["valid"], true);

    // The scan as repaired is a valid input in its own right, and the base is valid against it
    // (a fresh, independent check), and against the raw file repaired again from the settings.
    let m = dispdec::mesh::load_dense(&repaired).expect("the repaired scan loads without --repair");
    assert_eq!(m.faces.len(), n0 + 2);
    for high in [&repaired, &p] {
        let o = run(&["validate", s(high), s(&d.join("base.obj")), "--backend", "cpu"]);
        assert_eq!(o.status.code(), Some(0), "{}", String::from_utf8_lossy(&o.stderr));
    }
    // Refused when a repair would change too much: a mesh that is mostly fins.
    let (v, f) = icosphere(1);
    let mut f2 = f.clone();
    let mut v2 = v.clone();
    for t in &f {
        v2.push(v[t[0] as usize] * 1.5);
        f2.push([t[0], t[1], (v2.len() - 1) as u32]);
    }
    let fins = d.join("fins.obj");
    write_obj(&fins, &v2, &f2);
    let (code, _, err, _) = decimate(&d, &fins, "fins-base", &["--repair"]);
    assert_eq!(code, 2, "{err}");
    assert!(err.contains("more than 1 %") && err.contains("edge between vertices"), "{err}");
}

/// The same tetrahedron-capped sphere written plainly and with what real exporters add.
#[test]
fn obj_readers_tolerate_what_exporters_write() {
    let d = tempdir("obj-tolerance");
    let (v, f) = bumpy_sphere();
    let plain = d.join("plain.obj");
    write_obj(&plain, &v, &f);
    let (code, _, err, want) = decimate(&d, &plain, "plain-base", &[]);
    assert_eq!(code, 0, "{err}");
    let want = geometry(&want);

    let mut vs = String::new();
    for (i, p) in v.iter().enumerate() {
        // Colours on some vertices only (tobj refuses that on its own).
        if i % 3 == 0 {
            vs.push_str(&format!("v {} {} {} 0.5 0.25 1\n", p.x, p.y, p.z));
        } else {
            vs.push_str(&format!("v {} {} {}\n", p.x, p.y, p.z));
        }
    }
    let fs = |with: &dyn Fn(u32, usize) -> String| -> String {
        f.iter().enumerate().map(|(k, t)| format!("f {} {} {}\n", with(t[0], k), with(t[1], k), with(t[2], k))).collect()
    };
    let cases: Vec<(&str, Vec<u8>)> = vec![
        // A material name in Latin-1 (not UTF-8): "Gr\xfcn".
        ("latin1.obj", [b"mtllib missing.mtl\nusemtl Gr\xfcn\n".to_vec(), vs.clone().into_bytes(), fs(&|w, _| (w + 1).to_string()).into_bytes()].concat()),
        ("empty-usemtl.obj", format!("usemtl\n{vs}{}", fs(&|w, _| (w + 1).to_string())).into_bytes()),
        ("groups.obj", format!("o scan\ng a\ns 1\n{vs}{}", fs(&|w, _| (w + 1).to_string())).replace("f ", "g b\nusemtl x\nf ").into_bytes()),
        (
            "uv-normals.obj",
            format!(
                "{vs}{}{}{}",
                v.iter().map(|_| "vt 0.5 0.5\n").collect::<String>(),
                v.iter().map(|p| format!("vn {} {} {}\n", p.x, p.y, p.z)).collect::<String>(),
                fs(&|w, _| format!("{0}/{0}/{0}", w + 1))
            )
            .into_bytes(),
        ),
        ("relative.obj", format!("{vs}{}", fs(&|w, _| format!("{}", w as i64 - v.len() as i64))).into_bytes()),
        (
            "unknown.obj",
            format!("cstype bezier\nvp 0.1 0.2\n{vs}l 1 2\np 3\n{}curv 0 1 1 2\nend\n", fs(&|w, _| (w + 1).to_string())).into_bytes(),
        ),
        ("crlf-continued.obj", format!("{vs}{}", fs(&|w, _| (w + 1).to_string())).replace("\n", "\r\n").replacen("f ", "f \\\r\n", 1).into_bytes()),
        // A UTF-8 byte-order mark before the first `v` (it hid that vertex: "face references
        // vertex N, but only N−1 are defined").
        ("bom.obj", format!("\u{feff}{vs}{}", fs(&|w, _| (w + 1).to_string())).into_bytes()),
    ];
    for (name, bytes) in cases {
        let p = d.join(name);
        std::fs::write(&p, bytes).unwrap();
        let (code, _, err, got) = decimate(&d, &p, name, &[]);
        assert_eq!(code, 0, "{name}: {err}");
        assert_eq!(geometry(&got), want, "{name} gives the plain file's base");
    }
    // A real error still names its line.
    let bad = d.join("bad.obj");
    std::fs::write(&bad, format!("usemtl Gr\u{fc}n\nv 0 0 0\nv 1 x 0\n{}", "f 1 2 3\n")).unwrap();
    let (code, _, err, _) = decimate(&d, &bad, "bad-base", &[]);
    assert_eq!(code, 2);
    assert!(err.contains("line 3") && err.contains("'x' is not a number"), "{err}");
}

#[test]
fn ply_header_lines_that_are_not_keywords_are_skipped_with_a_warning() {
    let d = tempdir("ply-header");
    let (v, f) = bumpy_sphere();
    let body = |extra: &str| {
        let mut t = format!("ply\nformat ascii 1.0\n{extra}element vertex {}\nproperty float x\nproperty float y\nproperty float z\nelement face {}\nproperty list uchar int vertex_indices\nend_header\n", v.len(), f.len());
        for p in &v {
            t.push_str(&format!("{} {} {}\n", p.x as f32, p.y as f32, p.z as f32));
        }
        for t3 in &f {
            t.push_str(&format!("3 {} {} {}\n", t3[0], t3[1], t3[2]));
        }
        t
    };
    let good = d.join("good.ply");
    std::fs::write(&good, body("comment fine\n")).unwrap();
    let odd = d.join("odd.ply");
    std::fs::write(&odd, body("author: a scanner\nTextureFile scan.png\n")).unwrap();
    let bom = d.join("bom.ply");
    std::fs::write(&bom, format!("\u{feff}{}", body("comment fine\n"))).unwrap();
    let (c0, r0, e0, b0) = decimate(&d, &good, "good", &[]);
    let (c1, r1, e1, b1) = decimate(&d, &odd, "odd", &[]);
    let (c2, _, e2, b2) = decimate(&d, &bom, "bom", &[]);
    assert_eq!((c0, c1, c2), (0, 0, 0), "{e0}\n{e1}\n{e2}");
    assert_eq!(geometry(&b0), geometry(&b1));
    assert_eq!(geometry(&b0), geometry(&b2), "a byte-order mark before 'ply' is no part of it");
    assert_eq!(r0["warnings"].as_array().unwrap().len(), 0);
    let w = r1["warnings"].as_array().unwrap();
    assert_eq!(w.len(), 2, "{w:?}");
    assert!(w[0].as_str().unwrap().contains("PLY header line 3"), "{w:?}");
    assert!(e1.contains("warning") && e1.contains("TextureFile"), "{e1}");
}

/// stderr of a default run on a machine without XDG_RUNTIME_DIR, Vulkan loader and layers as
/// installed: only the one-line summary.
#[test]
fn default_runs_print_one_line_and_quiet_prints_none() {
    let d = tempdir("quiet");
    let (v, f) = bumpy_sphere();
    let high = d.join("high.obj");
    write_obj(&high, &v, &f);
    let base = d.join("base.obj");
    let noisy = |args: &[&str]| {
        let mut c = std::process::Command::new(env!("CARGO_BIN_EXE_dispdec"));
        c.env_remove("NODEVICE_SELECT").env_remove("XDG_RUNTIME_DIR").args(args);
        let o = c.output().unwrap();
        (o.status.code().unwrap(), String::from_utf8_lossy(&o.stderr).to_string())
    };
    for (args, what) in [
        (vec!["decimate", s(&high), "-o", s(&base)], "decimate"),
        (vec!["validate", s(&high), s(&base)], "validate"),
    ] {
        let (code, err) = noisy(&args);
        assert_eq!(code, 0, "{err}");
        assert_eq!(err.lines().count(), 1, "{what}: one line, got:\n{err}");
        assert!(!err.contains("XDG_RUNTIME_DIR") && !err.contains("--backend auto"), "{err}");
        let mut q = args.clone();
        q.push("--quiet");
        let (code, err) = noisy(&q);
        assert_eq!((code, err.as_str()), (0, ""), "{what} --quiet");
        let mut v = args.clone();
        v.push("--verbose");
        let (_, err) = noisy(&v);
        assert!(err.contains("--backend auto: using"), "{what} --verbose says what auto chose: {err}");
    }
}

/// The `v` lines of an OBJ, parsed.
fn vertices(obj: &[u8]) -> Vec<DVec3> {
    String::from_utf8_lossy(obj)
        .lines()
        .filter_map(|l| l.strip_prefix("v "))
        .map(|l| {
            let c: Vec<f64> = l.split_whitespace().map(|x| x.parse().unwrap()).collect();
            DVec3::new(c[0], c[1], c[2])
        })
        .collect()
}

#[test]
fn a_scan_in_world_coordinates_is_decimated_where_it_lies() {
    // The bumpy sphere (radius ~1) at a UTM-like place, 5.3e6 of its diagonals from the origin
    // (x an easting, y a northing, z about 0), its coordinates multiples of 2^-20 so that the
    // midpoints a run places are exact in both frames (the file at 5.3e6 holds 2^-30).
    let d = tempdir("world");
    let (v, f) = bumpy_sphere();
    let q = |x: f64| (x * 1048576.0).round() / 1048576.0;
    let t = DVec3::new(512_345.0, 5_300_000.0, 0.0);
    let world_v: Vec<DVec3> = v.iter().map(|p| DVec3::new(q(p.x) + t.x, q(p.y) + t.y, q(p.z))).collect();
    let world = d.join("utm.obj");
    write_obj(&world, &world_v, &f);
    let repaired = d.join("as-decimated.obj");
    let map = d.join("world.map");
    let (code, r, err, obj) = decimate(&d, &world, "world", &["--map", s(&map), "--repaired", s(&repaired)]);
    assert_eq!(code, 0, "{err}");
    // Moved by its box's middle in x and y on load (exactly), and back on every output.
    let c: Vec<f64> = r["input_centre"].as_array().unwrap().iter().map(|x| x.as_f64().unwrap()).collect();
    let c = DVec3::new(c[0], c[1], c[2]);
    assert!((c - DVec3::new(t.x, t.y, 0.0)).abs().max_element() < 0.1 && c.z == 0.0, "centre {c}");
    assert_eq!(vertices(&std::fs::read(&repaired).unwrap()), world_v, "--repaired writes the scan where it lies");
    let base_v = vertices(&obj);
    assert!(base_v.iter().all(|p| (*p - t).abs().max_element() < 1.1), "the base lies on the scan");
    // The same scan moved to the origin by hand gives the same base, moved back: the run
    // computed in the scan's own frame.
    let centred = d.join("at-origin.obj");
    write_obj(&centred, &world_v.iter().map(|&p| p - c).collect::<Vec<_>>(), &f);
    let (code, rc, err, obj_c) = decimate(&d, &centred, "centred", &[]);
    assert_eq!(code, 0, "{err}");
    assert_eq!(rc["input_centre"], serde_json::json!([0.0, 0.0, 0.0]));
    assert_eq!(r["faces_out"], rc["faces_out"]);
    assert_eq!(base_v.iter().map(|&p| p - c).collect::<Vec<_>>(), vertices(&obj_c));
    let (g, gc) = (geometry(&obj), geometry(&obj_c));
    let not_v = |g: &[String]| g.iter().filter(|l| !l.starts_with("v ")).cloned().collect::<Vec<_>>();
    assert_eq!(not_v(&g), not_v(&gc), "the same directions and faces");
    // validate judges the written base against the world scan as the decimator's own check did;
    // bake writes the base with its UVs where it lies.
    let json = d.join("v.json");
    let o = run(&["validate", s(&world), s(&d.join("world.obj")), "--json", s(&json)]);
    assert_eq!(o.status.code(), Some(0), "{}", String::from_utf8_lossy(&o.stderr));
    let v0: Value = serde_json::from_slice(&std::fs::read(&json).unwrap()).unwrap();
    for k in ["mapped", "ambiguous", "far_hits", "max_abs_d"] {
        assert_eq!(v0["verdict"][k], r["global"][k], "{k}");
    }
    let disp = d.join("d.pfm");
    let o = run(&["bake", s(&world), s(&d.join("world.obj")), "-o", s(&disp), "--resolution", "256", "--map", s(&map)]);
    assert_eq!(o.status.code(), Some(0), "{}", String::from_utf8_lossy(&o.stderr));
    assert_eq!(vertices(&std::fs::read(d.join("d.obj")).unwrap()), base_v);
    // export: glTF's f32 positions relative to a node translation (at 5.3e6 an f32 position is
    // rounded to 0.5), so the base read back lies where it was written to f32 at its own size.
    let glb = d.join("world.glb");
    let o = run(&["export", s(&d.join("d.obj")), s(&disp), "-o", s(&glb)]);
    assert_eq!(o.status.code(), Some(0), "{}", String::from_utf8_lossy(&o.stderr));
    let meshes = dispdec::maps::export::read_glb_meshes(&std::fs::read(&glb).unwrap()).unwrap();
    let faces: Vec<[u32; 3]> = geometry(&obj).iter().filter_map(|l| l.strip_prefix("f ")).map(|l| {
        let v: Vec<u32> = l.split_whitespace().map(|c| c.split('/').next().unwrap().parse::<u32>().unwrap() - 1).collect();
        [v[0], v[1], v[2]]
    }).collect();
    let corners: Vec<DVec3> = faces.iter().flatten().map(|&v| base_v[v as usize]).collect();
    assert_eq!(meshes[0].0.len(), corners.len());
    let off = meshes[0].0.iter().zip(&corners).map(|(a, b)| a.distance(*b)).fold(0.0, f64::max);
    assert!(off < 1e-6, "the glTF base lies on the written base: {off}");
}

#[test]
fn stl_binary_and_ascii_give_the_base_of_the_same_mesh_as_obj() {
    // The bumpy sphere as STL writes it: a soup, one vertex per face corner, in f32; and the
    // same mesh as an OBJ with its vertices in the order of their first corner (the order the
    // weld keeps) and the same f32 values.
    let d = tempdir("stl");
    let (v, f) = bumpy_sphere();
    let v32: Vec<[f32; 3]> = v.iter().map(|p| [p.x as f32, p.y as f32, p.z as f32]).collect();
    let mut bin = b"solid bumpy sphere (a binary header that starts like ASCII)".to_vec();
    bin.resize(80, b' ');
    bin.extend_from_slice(&(f.len() as u32).to_le_bytes());
    let mut ascii = String::from("solid bumpy\n");
    for t in &f {
        bin.extend_from_slice(&[0u8; 12]);
        ascii.push_str("facet normal 0 0 0\n outer loop\n");
        for &w in t {
            let p = v32[w as usize];
            p.iter().for_each(|c| bin.extend_from_slice(&c.to_le_bytes()));
            // The f32 values' own digits: ASCII is read in f64, as written.
            ascii.push_str(&format!("  vertex {:e} {:e} {:e}\n", p[0] as f64, p[1] as f64, p[2] as f64));
        }
        bin.extend_from_slice(&[0u8; 2]);
        ascii.push_str(" endloop\nendfacet\n");
    }
    ascii.push_str("endsolid bumpy\n");
    let (b_path, a_path) = (d.join("bin.stl"), d.join("text.stl"));
    std::fs::write(&b_path, &bin).unwrap();
    std::fs::write(&a_path, &ascii).unwrap();
    let mut order = vec![u32::MAX; v.len()];
    let mut first = Vec::new();
    for &w in f.iter().flatten() {
        if order[w as usize] == u32::MAX {
            order[w as usize] = first.len() as u32;
            first.push(w);
        }
    }
    let obj = d.join("mesh.obj");
    let as_f64 = |p: [f32; 3]| DVec3::new(p[0] as f64, p[1] as f64, p[2] as f64);
    write_obj(&obj, &first.iter().map(|&w| as_f64(v32[w as usize])).collect::<Vec<_>>(), &f.iter().map(|t| t.map(|w| order[w as usize])).collect::<Vec<_>>());
    let (code, r_obj, err, base_obj) = decimate(&d, &obj, "from-obj", &[]);
    assert_eq!(code, 0, "{err}");
    for (path, tag) in [(&b_path, "from-bin"), (&a_path, "from-text")] {
        let (code, r, err, base) = decimate(&d, path, tag, &[]);
        assert_eq!(code, 0, "{tag}: {err}");
        assert_eq!(geometry(&base), geometry(&base_obj), "{tag}: the OBJ's base");
        assert_eq!(r["input_cleanup"]["welded_vertices"], 3 * f.len() - v.len(), "{tag}: every corner but one per vertex welded");
        assert_eq!(r["faces_out"], r_obj["faces_out"]);
    }
    // A truncated binary STL: exit 2, saying so.
    let cut = d.join("cut.stl");
    std::fs::write(&cut, &bin[..bin.len() - 7]).unwrap();
    let (code, _, err, _) = decimate(&d, &cut, "cut", &[]);
    assert!(code == 2 && err.contains("cut.stl") && err.contains("(truncated?)"), "{err}");
}

#[test]
fn a_glb_scan_gives_the_base_of_the_same_mesh_as_obj() {
    // The bumpy sphere as a GLB (indexed u32 triangles, f32 positions, one node placed by a
    // translation, as scanning apps export) and as an OBJ of the same f32 values, moved.
    let d = tempdir("glb");
    let (v, f) = bumpy_sphere();
    let v32: Vec<[f32; 3]> = v.iter().map(|p| [p.x as f32, p.y as f32, p.z as f32]).collect();
    let mut bin: Vec<u8> = v32.iter().flatten().flat_map(|c| c.to_le_bytes()).collect();
    let idx_at = bin.len();
    bin.extend(f.iter().flatten().flat_map(|i| i.to_le_bytes()));
    let json = format!(
        r#"{{"asset":{{"version":"2.0"}},"scene":0,"scenes":[{{"nodes":[0]}}],"nodes":[{{"mesh":0,"translation":[0.5,-2,3]}}],"meshes":[{{"primitives":[{{"attributes":{{"POSITION":0}},"indices":1}}]}}],"accessors":[{{"bufferView":0,"componentType":5126,"count":{nv},"type":"VEC3","min":[-2,-2,-2],"max":[2,2,2]}},{{"bufferView":1,"componentType":5125,"count":{ni},"type":"SCALAR"}}],"bufferViews":[{{"buffer":0,"byteOffset":0,"byteLength":{idx_at}}},{{"buffer":0,"byteOffset":{idx_at},"byteLength":{nb}}}],"buffers":[{{"byteLength":{len}}}]}}"#,
        nv = v.len(),
        ni = 3 * f.len(),
        nb = bin.len() - idx_at,
        len = bin.len()
    );
    let mut json = json.into_bytes();
    while json.len() % 4 != 0 {
        json.push(b' ');
    }
    let mut glb = b"glTF".to_vec();
    glb.extend(2u32.to_le_bytes());
    glb.extend(((12 + 8 + json.len() + 8 + bin.len()) as u32).to_le_bytes());
    glb.extend((json.len() as u32).to_le_bytes());
    glb.extend(b"JSON");
    glb.extend(&json);
    glb.extend((bin.len() as u32).to_le_bytes());
    glb.extend(b"BIN\0");
    glb.extend(&bin);
    let scan = d.join("scan.glb");
    std::fs::write(&scan, &glb).unwrap();
    let t = DVec3::new(0.5, -2.0, 3.0);
    let obj = d.join("scan.obj");
    write_obj(&obj, &v32.iter().map(|p| DVec3::new(p[0] as f64, p[1] as f64, p[2] as f64) + t).collect::<Vec<_>>(), &f);
    let (code, r_obj, err, base_obj) = decimate(&d, &obj, "from-obj", &[]);
    assert_eq!(code, 0, "{err}");
    let (code, r, err, base) = decimate(&d, &scan, "from-glb", &[]);
    assert_eq!(code, 0, "{err}");
    assert_eq!(geometry(&base), geometry(&base_obj), "the OBJ's base, byte for byte");
    assert_eq!((r["faces_in"].clone(), r["input_cleanup"]["welded_vertices"].clone()), (r_obj["faces_in"].clone(), 0.into()));
    // validate reads it too; a GLB cut short is refused (exit 2) naming the file.
    let o = run(&["validate", s(&scan), s(&d.join("from-glb.obj"))]);
    assert_eq!(o.status.code(), Some(0), "{}", String::from_utf8_lossy(&o.stderr));
    let cut = d.join("cut.glb");
    std::fs::write(&cut, &glb[..glb.len() - 100]).unwrap();
    let (code, _, err, _) = decimate(&d, &cut, "cut", &[]);
    assert!(code == 2 && err.contains("cut.glb") && !err.contains("panicked"), "{err}");
}

#[test]
fn settings_travel_from_the_base_to_validate_bake_and_reconstruct() {
    let d = tempdir("settings");
    let (v, f) = bumpy_sphere();
    let high = d.join("high.obj");
    write_obj(&high, &v, &f);
    let map = d.join("base.map");
    let (code, r, err, obj) = decimate(&d, &high, "base", &["--normals", "constant", "--dmax", "0.125", "--map", s(&map)]);
    assert!(code == 0 || code == 1, "{err}");
    let line = String::from_utf8_lossy(&obj).lines().find(|l| l.starts_with("# dispdec-settings ")).unwrap().to_string();
    let settings: Value = serde_json::from_str(line.trim_start_matches("# dispdec-settings ")).unwrap();
    assert_eq!(settings["normals"], "constant");
    assert_eq!(settings["dmax"], 0.125);
    assert_eq!(settings["scan"], "high.obj");
    assert_eq!(settings["scan_faces"], f.len());
    assert_eq!(settings, r["settings"]);
    // The map carries the same settings.
    let b = std::fs::read(&map).unwrap();
    let len = u32::from_le_bytes(b[24..28].try_into().unwrap()) as usize;
    assert_eq!(serde_json::from_slice::<Value>(&b[28..28 + len]).unwrap(), settings);
    assert_eq!(u32::from_le_bytes(b[20..24].try_into().unwrap()), 1, "flags: constant, not strict");

    let base = d.join("base.obj");
    let json = d.join("v.json");
    let o = run(&["validate", s(&high), s(&base), "--json", s(&json)]);
    let v0: Value = serde_json::from_slice(&std::fs::read(&json).unwrap()).unwrap();
    assert_eq!((v0["normals"].as_str(), v0["verdict"]["dmax"].as_f64()), (Some("constant"), Some(0.125)), "validate uses the settings");
    assert!(!String::from_utf8_lossy(&o.stderr).contains("warning"));
    assert_eq!(v0["verdict"]["valid"], r["global"]["valid"], "the same verdict as the decimator's own check");
    // A flag overrides, with a warning.
    let o = run(&["validate", s(&high), s(&base), "--normals", "interpolated", "--json", s(&json)]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(err.contains("warning") && err.contains("was made with --normals constant"), "{err}");
    let v1: Value = serde_json::from_slice(&std::fs::read(&json).unwrap()).unwrap();
    assert_eq!(v1["normals"], "interpolated");
    // Another scan: a warning naming the one the base was made from.
    let (v2, f2) = icosphere(2);
    let other = d.join("other.obj");
    write_obj(&other, &v2, &f2);
    let o = run(&["validate", s(&other), s(&base)]);
    assert!(String::from_utf8_lossy(&o.stderr).contains("was made from high.obj"), "{}", String::from_utf8_lossy(&o.stderr));

    // bake in constant mode, then reconstruct with it: the rebuilt level 3 lies on the scan.
    let disp = d.join("d.pfm");
    let o = run(&["bake", s(&high), s(&base), "-o", s(&disp), "--resolution", "256", "--map", s(&map)]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(0), "{err}");
    assert!(err.contains("constant normals, dmax 0.1250"), "{err}");
    let rec = d.join("r.obj");
    let o = run(&["reconstruct", s(&base), s(&disp), "--levels", "3", "-o", s(&rec), "--compare", s(&high)]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(0), "{err}");
    let l3 = err.lines().find(|l| l.trim_start().starts_with("3 ")).unwrap();
    let rms_to: f64 = l3.split_whitespace().nth(2).unwrap().parse().unwrap();
    assert!(rms_to < 2e-3, "constant-mode reconstruction lies on the scan: {l3}");
}

#[test]
fn exit_code_one_only_for_a_failed_check() {
    let d = tempdir("exits");
    let (v, f) = bumpy_sphere();
    let high = d.join("high.obj");
    write_obj(&high, &v, &f);
    // An output that cannot be written is not a verdict: 2, and nothing left behind.
    let o = run(&["decimate", s(&high), "-o", s(&d.join("no/such/dir/base.obj")), "--backend", "cpu"]);
    assert_eq!(o.status.code(), Some(2), "{}", String::from_utf8_lossy(&o.stderr));
    let o = run(&["sample", "-o", s(&d.join("no/such/dir/s.obj")), "--faces", "1000"]);
    assert_eq!(o.status.code(), Some(2), "{}", String::from_utf8_lossy(&o.stderr));
    assert!(String::from_utf8_lossy(&o.stderr).contains("no/such/dir"));
    // A map file that is not one: 2.
    let junk = d.join("junk.map");
    std::fs::write(&junk, b"not a map").unwrap();
    let base = d.join("b.obj");
    assert_eq!(run(&["decimate", s(&high), "-o", s(&base), "--backend", "cpu"]).status.code(), Some(0));
    let o = run(&["bake", s(&high), s(&base), "--map", s(&junk), "-o", s(&d.join("x.pfm")), "--resolution", "64"]);
    assert_eq!(o.status.code(), Some(2));
}

#[test]
fn a_strict_base_is_judged_strictly_unless_told_otherwise() {
    let d = tempdir("strict-settings");
    let (v, f) = bumpy_sphere();
    let high = d.join("high.obj");
    write_obj(&high, &v, &f);
    let (code, _, err, _) = decimate(&d, &high, "base", &["--strict"]);
    assert_eq!(code, 0, "{err}");
    let base = d.join("base.obj");
    let json = d.join("v.json");
    let judged = |extra: &[&str]| {
        let mut args = vec!["validate", s(&high), s(&base), "--json", s(&json), "--backend", "cpu"];
        args.extend_from_slice(extra);
        let o = run(&args);
        let v: Value = serde_json::from_slice(&std::fs::read(&json).unwrap()).unwrap();
        (v["strict"].as_bool().unwrap(), String::from_utf8_lossy(&o.stderr).to_string())
    };
    let (strict, err) = judged(&[]);
    assert!(strict, "the settings say strict: {err}");
    assert!(!err.contains("warning"), "{err}");
    let (strict, err) = judged(&["--no-strict"]);
    assert!(!strict);
    assert!(err.contains("was made with --strict; judging it without the uniqueness rule"), "{err}");
}
