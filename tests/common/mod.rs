//! Shared helpers for the integration tests: the real binary, temp dirs, the real scans.
#![allow(dead_code)]

use glam::DVec3;
use std::collections::HashMap;
use std::path::{Path, PathBuf};
use std::process::{Command, Output};

pub fn bin() -> Command {
    let mut c = Command::new(env!("CARGO_BIN_EXE_dispdec"));
    c.env("NODEVICE_SELECT", "1");
    c
}

pub fn run(args: &[&str]) -> Output {
    bin().args(args).output().expect("run dispdec")
}

/// The 6k sample of README's modes tables (`dispdec sample --faces 6000 --seed 7`), written to
/// `dir`/`name`.
pub fn sample_6k(dir: &Path, name: &str) -> PathBuf {
    let scan = dir.join(name);
    let o = run(&["sample", "--faces", "6000", "--seed", "7", "-o", scan.to_str().unwrap()]);
    assert_eq!(o.status.code(), Some(0), "{}", String::from_utf8_lossy(&o.stderr));
    scan
}

/// A fresh, empty temporary directory for one test.
pub fn tempdir(name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("dispdec-test-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    std::fs::create_dir_all(&d).unwrap();
    d
}

/// The folder of the real scans: $DISPDEC_DATA, else ../shared/data beside the checkout.
pub fn data_dir() -> PathBuf {
    match std::env::var_os("DISPDEC_DATA") {
        Some(d) => PathBuf::from(d),
        None => Path::new(env!("CARGO_MANIFEST_DIR")).join("../shared/data"),
    }
}

/// Path of a real scan, or `None` (with a message saying where to put it) when it is missing
/// outside CI. Under `CI=true` a missing scan is a failure, never a skip.
pub fn real_scan(name: &str) -> Option<PathBuf> {
    let p = data_dir().join(name);
    if p.exists() {
        return Some(p);
    }
    let msg = format!(
        "real scan {name} not found at {}: put the scans of shared/data there, or set DISPDEC_DATA to their folder",
        p.display()
    );
    if std::env::var("CI").map(|v| v == "true" || v == "1").unwrap_or(false) {
        panic!("{msg} (CI=true: missing data is a failure)");
    }
    skipped(&msg);
    None
}

/// An icosahedron on the unit sphere (20 faces, outward winding).
pub fn icosahedron() -> (Vec<DVec3>, Vec<[u32; 3]>) {
    let t = (1.0 + 5f64.sqrt()) / 2.0;
    let v: Vec<DVec3> = [
        (-1.0, t, 0.0), (1.0, t, 0.0), (-1.0, -t, 0.0), (1.0, -t, 0.0),
        (0.0, -1.0, t), (0.0, 1.0, t), (0.0, -1.0, -t), (0.0, 1.0, -t),
        (t, 0.0, -1.0), (t, 0.0, 1.0), (-t, 0.0, -1.0), (-t, 0.0, 1.0),
    ]
    .iter()
    .map(|&(x, y, z)| DVec3::new(x, y, z).normalize())
    .collect();
    let f = vec![
        [0, 11, 5], [0, 5, 1], [0, 1, 7], [0, 7, 10], [0, 10, 11],
        [1, 5, 9], [5, 11, 4], [11, 10, 2], [10, 7, 6], [7, 1, 8],
        [3, 9, 4], [3, 4, 2], [3, 2, 6], [3, 6, 8], [3, 8, 9],
        [4, 9, 5], [2, 4, 11], [6, 2, 10], [8, 6, 7], [9, 8, 1],
    ];
    (v, f)
}

/// Loop-style 1-to-4 subdivision on the unit sphere, `levels` times.
pub fn icosphere(levels: u32) -> (Vec<DVec3>, Vec<[u32; 3]>) {
    let (mut v, mut f) = icosahedron();
    for _ in 0..levels {
        let mut mid: HashMap<(u32, u32), u32> = HashMap::new();
        let mut nf = Vec::with_capacity(f.len() * 4);
        for t in &f {
            let mut m = [0u32; 3];
            for k in 0..3 {
                let (a, b) = (t[k], t[(k + 1) % 3]);
                let key = (a.min(b), a.max(b));
                m[k] = *mid.entry(key).or_insert_with(|| {
                    v.push((v[a as usize] + v[b as usize]).normalize());
                    (v.len() - 1) as u32
                });
            }
            nf.extend([[t[0], m[0], m[2]], [t[1], m[1], m[0]], [t[2], m[2], m[1]], [m[0], m[1], m[2]]]);
        }
        f = nf;
    }
    (v, f)
}

pub fn write_obj(path: &Path, v: &[DVec3], f: &[[u32; 3]]) {
    let mut s = String::new();
    for p in v {
        s.push_str(&format!("v {} {} {}\n", p.x, p.y, p.z));
    }
    for t in f {
        s.push_str(&format!("f {} {} {}\n", t[0] + 1, t[1] + 1, t[2] + 1));
    }
    std::fs::write(path, s).unwrap();
}

/// A sphere with small bumps (a scan-like surface a coarse base can carry).
pub fn bumpy(p: DVec3) -> DVec3 {
    p * (1.0 + 0.03 * (5.0 * p.x).sin() * (4.0 * p.y).cos() + 0.01 * (13.0 * p.z).sin())
}

/// A level-4 icosphere shaped by `shape` (the scan) and the icosahedron (its base), as OBJ files.
pub fn sphere_files(dir: &Path, shape: fn(DVec3) -> DVec3) -> (PathBuf, PathBuf) {
    let (v, f) = icosphere(4);
    let high = dir.join("high.obj");
    write_obj(&high, &v.iter().map(|&p| shape(p)).collect::<Vec<_>>(), &f);
    let (bv, bf) = icosahedron();
    let base = dir.join("ico.obj");
    write_obj(&base, &bv, &bf);
    (high, base)
}

/// Says SKIPPED where cargo's output capture does not swallow it: straight to the process's
/// stderr (the capture only takes `print!`/`eprint!`), and fails under `CI=true`.
pub fn skipped(msg: &str) {
    use std::io::Write;
    if std::env::var("CI").map(|v| v == "true" || v == "1").unwrap_or(false) {
        panic!("{msg} (CI=true: a test that cannot run is a failure)");
    }
    let _ = writeln!(std::io::stderr(), "SKIPPED: {msg}");
}
