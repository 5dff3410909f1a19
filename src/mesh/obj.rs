//! OBJ input. tobj parses the geometry; this module first reads the file line by line, names
//! the line of any real defect, and hands tobj only what a decimator needs (`v` with three
//! coordinates, `vn`, `f` with absolute indices). Materials, groups, colours, texture
//! coordinates, free-form statements and bytes that are not UTF-8 outside numbers never fail a
//! load: they are not passed on.

use super::{input_err, Mesh};
use crate::Error;
use glam::DVec3;
use std::io::BufReader;
use std::path::Path;

/// The comment line of BASE.obj that carries the settings it was made with (SPEC §6).
pub const SETTINGS_TAG: &str = "# dispdec-settings ";

/// A face corner as written: vertex and (optional) normal, 0-based, resolved.
#[derive(Clone, Copy)]
struct Corner {
    v: u32,
    vn: Option<u32>,
}

fn parse_index(tok: &[u8], count: usize) -> Option<i64> {
    let i: i64 = std::str::from_utf8(tok).ok()?.parse().ok()?;
    let resolved = if i < 0 { count as i64 + i } else { i - 1 };
    (i != 0 && resolved >= 0 && resolved < count as i64).then_some(resolved)
}

fn parse_f64(tok: &[u8]) -> Option<f64> {
    std::str::from_utf8(tok).ok()?.parse().ok()
}

/// Splits a line on ASCII whitespace (bytes: a Latin-1 name elsewhere on it is no error).
fn tokens(line: &[u8]) -> impl Iterator<Item = &[u8]> {
    line.split(|c| c.is_ascii_whitespace()).filter(|t| !t.is_empty())
}

pub(super) fn load_obj(path: &Path, bytes: &[u8]) -> Result<Mesh, Error> {
    let mut positions_text = String::new();
    let mut scanned: Vec<DVec3> = Vec::new();
    let mut normals_text = String::new();
    // Face corners, flat: face k is corners[face_start[k]..face_start[k + 1]].
    let mut corners: Vec<Corner> = Vec::new();
    let mut face_start: Vec<usize> = vec![0];
    let (mut nv, mut nn) = (0usize, 0usize);
    let mut settings = None;
    let mut pending: Vec<u8> = Vec::new();
    for (lineno, raw) in (1usize..).zip(bytes.split(|&c| c == b'\n')) {
        let raw = raw.strip_suffix(b"\r").unwrap_or(raw);
        // A trailing backslash continues the statement on the next line.
        if let Some(head) = raw.strip_suffix(b"\\") {
            pending.extend_from_slice(head);
            pending.push(b' ');
            continue;
        }
        let joined;
        let line: &[u8] = if pending.is_empty() {
            raw
        } else {
            pending.extend_from_slice(raw);
            joined = std::mem::take(&mut pending);
            &joined
        };
        if let Some(rest) = line.strip_prefix(SETTINGS_TAG.as_bytes()) {
            settings = Some(String::from_utf8_lossy(rest).trim().to_string());
            continue;
        }
        let mut it = tokens(line);
        let Some(tag) = it.next() else { continue };
        let at = |msg: String| input_err(path, format!("line {lineno}: {msg}"));
        match tag {
            b"v" => {
                let mut c = [0.0f64; 3];
                for (k, slot) in c.iter_mut().enumerate() {
                    let tok = it.next().ok_or_else(|| at(format!("vertex {nv} has {k} coordinates, expected 3")))?;
                    *slot = parse_f64(tok)
                        .ok_or_else(|| at(format!("vertex {nv}: '{}' is not a number", String::from_utf8_lossy(tok))))?;
                }
                // Anything after x y z (a w, or per-vertex colours) is not geometry.
                use std::fmt::Write;
                let _ = writeln!(positions_text, "v {:?} {:?} {:?}", c[0], c[1], c[2]);
                scanned.push(DVec3::from_array(c));
                nv += 1;
            }
            b"vn" => {
                let mut c = [0.0f64; 3];
                for (k, slot) in c.iter_mut().enumerate() {
                    // A malformed normal makes the normals unusable, not the mesh.
                    *slot = it.next().and_then(parse_f64).unwrap_or(if k == 2 { 1.0 } else { 0.0 });
                }
                use std::fmt::Write;
                let _ = writeln!(normals_text, "vn {:?} {:?} {:?}", c[0], c[1], c[2]);
                nn += 1;
            }
            b"f" => {
                let first = corners.len();
                for r in it {
                    let mut parts = r.split(|&c| c == b'/');
                    let vtok = parts.next().unwrap_or(b"");
                    let v = parse_index(vtok, nv).ok_or_else(|| {
                        let s = String::from_utf8_lossy(vtok);
                        match std::str::from_utf8(vtok).ok().and_then(|t| t.parse::<i64>().ok()) {
                            None => at(format!("face vertex '{}' is not an index", String::from_utf8_lossy(r))),
                            Some(_) => at(format!("face references vertex {s}, but only {nv} vertices are defined before it")),
                        }
                    })?;
                    let _vt = parts.next();
                    let vn = parts.next().and_then(|t| parse_index(t, nn)).map(|i| i as u32);
                    corners.push(Corner { v: v as u32, vn });
                }
                if corners.len() - first < 3 {
                    return Err(at(format!("face with {} vertices cannot be triangulated (needs at least 3)", corners.len() - first)));
                }
                face_start.push(corners.len());
            }
            // Materials, groups, smoothing, texture coordinates, lines, points, free-form
            // geometry, unknown statements: not geometry a decimator uses.
            _ => {}
        }
    }
    let with_normals = nn > 0 && corners.iter().all(|c| c.vn.is_some());
    // The text tobj parses: geometry only, absolute 1-based indices.
    let mut text = positions_text;
    if with_normals {
        text.push_str(&normals_text);
    }
    let mut first_seen: Vec<u32> = Vec::with_capacity(nv);
    let mut seen = vec![false; nv];
    {
        use std::fmt::Write;
        for w in face_start.windows(2) {
            text.push('f');
            for c in &corners[w[0]..w[1]] {
                match (with_normals, c.vn) {
                    (true, Some(n)) => {
                        let _ = write!(text, " {}//{}", c.v + 1, n + 1);
                    }
                    _ => {
                        let _ = write!(text, " {}", c.v + 1);
                    }
                }
                if !seen[c.v as usize] {
                    seen[c.v as usize] = true;
                    first_seen.push(c.v);
                }
            }
            text.push('\n');
        }
    }
    let opts = tobj::LoadOptions { triangulate: true, single_index: false, ignore_points: true, ignore_lines: true };
    let mut reader = BufReader::new(text.as_bytes());
    let (models, _) = tobj::load_obj_buf(&mut reader, &opts, |_| Err(tobj::LoadError::OpenFileFailed))
        .map_err(|e| input_err(path, format!("OBJ parse error: {e}")))?;
    // tobj numbers a model's vertices in the order the faces first use them; map them back to
    // the file's numbering, so BASE.map and every message speak of the file's vertices.
    // The positions are the file's, numbered as in the file (unreferenced ones included).
    let positions = scanned;
    let mut out_faces = Vec::new();
    let mut normals = if with_normals { vec![DVec3::ZERO; nv] } else { Vec::new() };
    if let Some(m) = models.first() {
        let mesh = &m.mesh;
        let same = models.len() == 1
            && mesh.positions.len() == 3 * first_seen.len()
            && mesh.positions.chunks_exact(3).zip(&first_seen).all(|(p, &v)| {
                let q = positions[v as usize].to_array();
                (0..3).all(|k| p[k].to_bits() == q[k].to_bits())
            });
        if !same {
            return Err(input_err(path, "OBJ parse error: the geometry read back does not match the file"));
        }
        for t in mesh.indices.chunks_exact(3) {
            out_faces.push([t[0], t[1], t[2]].map(|i| first_seen[i as usize]));
        }
        if with_normals {
            for (k, &pi) in mesh.indices.iter().enumerate() {
                let ni = mesh.normal_indices[k] as usize;
                let n = &mesh.normals[3 * ni..3 * ni + 3];
                normals[first_seen[pi as usize] as usize] = DVec3::new(n[0], n[1], n[2]);
            }
        }
    }
    Ok(Mesh { positions, faces: out_faces, normals, settings, warnings: Vec::new() })
}
