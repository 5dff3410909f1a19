//! The rule every command keeps before it starts work: its outputs overwrite none of its inputs
//! and none of one another. Without it `dispdec decimate scan.obj -o scan.obj` replaced a
//! 2M-face scan with its 300-face base (the rename of an atomic write goes through), and
//! `-o b.obj --map b.obj` left the map where the base should be.

use crate::Error;
use std::path::{Path, PathBuf};

/// Refuses (a usage error, exit 2, before anything is read or written) a run in which an output
/// is one of `inputs` — the same file under any name: a symlink, a hard link, `./x` for `x` —
/// or the same file as an earlier output. `outputs` are (what it is, where), in the order the
/// command writes them. Devices and pipes (`/dev/null`, `/dev/stdout`) are never refused: they
/// are written in place, and several outputs may go to one.
pub fn check_outputs(inputs: &[&Path], outputs: &[(&str, &Path)]) -> Result<(), Error> {
    for (i, &(what, out)) in outputs.iter().enumerate() {
        if let Some(input) = inputs.iter().find(|&&input| same_file(out, input)) {
            return Err(Error::Usage(format!(
                "{}: {what} would overwrite the input {}; write it elsewhere",
                out.display(),
                input.display()
            )));
        }
        if let Some((other, _)) = outputs[..i].iter().find(|&&(_, earlier)| same_file(out, earlier)) {
            return Err(Error::Usage(format!("{}: both {other} and {what} would be written there; give them different names", out.display())));
        }
    }
    Ok(())
}

/// Refuses (a usage error, exit 2, before anything is read or written) to write an output the
/// user did not name — `what` at `path`, which a command writes beside a named one — over a
/// regular file that is there and is not that command's own (`ours`, given its first bytes):
/// `bake -o D.exr` writes D.obj and D.exr.json, and D.obj may be the user's own mesh. A file
/// the command wrote before is replaced, as a named output is.
pub fn check_beside(path: &Path, what: &str, named: &Path, ours: impl Fn(&[u8]) -> bool) -> Result<(), Error> {
    let Ok(meta) = std::fs::metadata(path) else { return Ok(()) };
    if !meta.is_file() {
        return Ok(());
    }
    let mut head = Vec::new();
    let readable = std::fs::File::open(path).and_then(|f| std::io::Read::read_to_end(&mut std::io::Read::take(f, BESIDE_HEAD), &mut head));
    if readable.is_ok() && ours(&head) {
        return Ok(());
    }
    Err(Error::Usage(format!(
        "{}: {what} goes beside {}, and a file that dispdec did not write is there; move it, or name the output otherwise",
        path.display(),
        named.display()
    )))
}

/// How much of a file [`check_beside`] reads to tell whether it is the command's own. Why: the
/// marks it looks for are in a file's first line or first few keys.
const BESIDE_HEAD: u64 = 4096;

/// Whether writing to `a` would replace what `b` names. Two existing paths: the same file
/// (device and inode; elsewhere, the same canonical path). Otherwise the same place once the
/// folders are resolved. A path that exists as anything but a regular file never is.
fn same_file(a: &Path, b: &Path) -> bool {
    let (ma, mb) = (std::fs::metadata(a), std::fs::metadata(b));
    if [&ma, &mb].iter().any(|m| m.as_ref().is_ok_and(|m| !m.is_file())) {
        return false;
    }
    match (ma, mb) {
        (Ok(x), Ok(y)) => {
            #[cfg(unix)]
            {
                use std::os::unix::fs::MetadataExt;
                x.dev() == y.dev() && x.ino() == y.ino()
            }
            #[cfg(not(unix))]
            {
                let _ = (x, y);
                resolved(a) == resolved(b)
            }
        }
        _ => resolved(a) == resolved(b),
    }
}

/// `p` with its folder made canonical (the file itself need not exist); `p` as given where the
/// folder cannot be resolved.
fn resolved(p: &Path) -> PathBuf {
    if let Ok(c) = std::fs::canonicalize(p) {
        return c;
    }
    let dir = match p.parent() {
        Some(d) if !d.as_os_str().is_empty() => d,
        _ => Path::new("."),
    };
    match (std::fs::canonicalize(dir), p.file_name()) {
        (Ok(d), Some(name)) => d.join(name),
        _ => p.to_path_buf(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn dir(name: &str) -> PathBuf {
        let d = std::env::temp_dir().join(format!("dispdec-outputs-{name}-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&d);
        std::fs::create_dir_all(&d).unwrap();
        d
    }

    #[cfg(unix)]
    #[test]
    fn an_output_on_an_input_under_any_name_is_refused() {
        let d = dir("names");
        let scan = d.join("scan.obj");
        std::fs::write(&scan, "v 0 0 0\n").unwrap();
        let link = d.join("link.obj");
        std::os::unix::fs::symlink(&scan, &link).unwrap();
        let hard = d.join("hard.obj");
        std::fs::hard_link(&scan, &hard).unwrap();
        let dotted = d.join(".").join("scan.obj");
        for out in [&scan, &link, &hard, &dotted] {
            let e = check_outputs(&[&scan], &[("the base mesh", out)]).unwrap_err();
            assert_eq!(e.exit_code(), 2);
            assert!(e.to_string().contains("would overwrite the input"), "{e}");
        }
        // A new file beside it, and a device, are fine.
        assert!(check_outputs(&[&scan], &[("the base mesh", &d.join("base.obj"))]).is_ok());
        assert!(check_outputs(&[&scan], &[("a", Path::new("/dev/null")), ("b", Path::new("/dev/null"))]).is_ok());
    }

    #[test]
    fn a_file_beside_an_output_is_replaced_only_when_ours() {
        let d = dir("beside");
        let named = d.join("d.exr");
        let beside = d.join("d.obj");
        let ours = |head: &[u8]| head.starts_with(b"# ours");
        // Nothing there, a device, or our own file: written.
        assert!(check_beside(&beside, "the base with the map's UVs", &named, ours).is_ok());
        assert!(check_beside(Path::new("/dev/null"), "the base with the map's UVs", &named, ours).is_ok());
        std::fs::write(&beside, "# ours\nv 0 0 0\n").unwrap();
        assert!(check_beside(&beside, "the base with the map's UVs", &named, ours).is_ok());
        // Someone else's: refused, naming both files.
        std::fs::write(&beside, "v 1 2 3\n").unwrap();
        let e = check_beside(&beside, "the base with the map's UVs", &named, ours).unwrap_err();
        assert_eq!(e.exit_code(), 2);
        let msg = e.to_string();
        assert!(msg.contains("d.obj") && msg.contains("d.exr") && msg.contains("did not write"), "{msg}");
    }

    #[test]
    fn two_outputs_on_one_new_file_are_refused() {
        let d = dir("twice");
        let base = d.join("b.obj");
        let same = d.join("sub").join("..").join("b.obj");
        std::fs::create_dir_all(d.join("sub")).unwrap();
        let e = check_outputs(&[], &[("the base mesh", &base), ("the map", &same)]).unwrap_err();
        assert!(e.to_string().contains("both the base mesh and the map"), "{e}");
        assert!(check_outputs(&[], &[("the base mesh", &base), ("the map", &d.join("b.map"))]).is_ok());
    }
}
