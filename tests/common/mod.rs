//! Shared helpers for the integration tests: the real binary, temp dirs, the real scans.
#![allow(dead_code)]

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
    eprintln!("SKIPPED: {msg}");
    None
}
