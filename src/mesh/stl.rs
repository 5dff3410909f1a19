//! STL input (binary and ASCII), as 3D scanners, phone scanning apps and
//! 3D-printing tools write it: a triangle soup, one vertex per face corner, which the load's
//! weld joins into a mesh (the report's `input_cleanup.welded_vertices` counts them; with
//! `--no-weld` every triangle stays apart). Facet normals are not read: the winding decides.
//!
//! Which of the two a file is: binary when its size is exactly what its header's facet count
//! says (84 + 50 bytes a facet), whatever its first bytes — exporters write "solid …" into a
//! binary header too, which would otherwise read as ASCII and fail; else ASCII when it starts
//! with `solid` and is text; else a binary file whose size does not match is an error saying
//! so. Binary STL through stl_io; ASCII STL read here, in f64 (stl_io keeps f32).

use super::{input_err, Mesh};
use crate::Error;
use glam::DVec3;
use std::path::Path;

/// The bytes of a binary STL's header (80) and facet count (4).
const BINARY_HEADER: usize = 84;
/// The bytes of one binary facet: normal and three corners (12 f32), a 2-byte attribute.
const BINARY_FACET: usize = 50;

/// The facet count a binary STL's header gives, when the file's size is exactly that.
fn binary_facets(bytes: &[u8]) -> Option<usize> {
    let n = u32::from_le_bytes(bytes.get(80..84)?.try_into().ok()?) as usize;
    (bytes.len() == BINARY_HEADER + n * BINARY_FACET).then_some(n)
}

/// Reads an STL file's bytes (already unzipped) into a [`Mesh`]: one vertex per face corner.
pub fn load_stl(path: &Path, mut bytes: Vec<u8>) -> Result<Mesh, Error> {
    let binary = binary_facets(&bytes);
    // Text has no NUL byte; a binary STL's header and first facet nearly always do (the facet
    // count's high byte below 16M facets, zeros in the normals and attributes).
    let text = !bytes[..bytes.len().min(BINARY_HEADER + BINARY_FACET)].contains(&0);
    let starts_solid = text && bytes.starts_with(b"solid") && bytes.get(5).is_none_or(|c| c.is_ascii_whitespace());
    if binary.is_none() && starts_solid {
        return load_ascii(path, &bytes);
    }
    if binary.is_none() {
        let what = match bytes.get(80..84) {
            Some(c) => format!(
                "a binary STL of {} facets is {} bytes, the file has {}",
                u32::from_le_bytes(c.try_into().unwrap()),
                BINARY_HEADER as u64 + u32::from_le_bytes(c.try_into().unwrap()) as u64 * BINARY_FACET as u64,
                bytes.len()
            ),
            None => format!("{} bytes are too few for a binary STL's 84-byte header", bytes.len()),
        };
        return Err(input_err(path, format!("not a valid STL file: not ASCII STL (text starting with 'solid'), and {what} (truncated?)")));
    }
    // stl_io reads a file whose first line starts with "solid " as ASCII: a binary header that
    // does is blanked (it is free text).
    bytes[..5].copy_from_slice(b"     ");
    let mut cursor = std::io::Cursor::new(bytes);
    let reader = stl_io::create_stl_reader(&mut cursor).map_err(|e| input_err(path, format!("not a valid binary STL file: {e}")))?;
    let mut mesh = Mesh::default();
    for (i, t) in reader.enumerate() {
        let t = t.map_err(|e| input_err(path, format!("binary STL facet {i}: {e}")))?;
        let first = mesh.positions.len() as u32;
        for v in t.vertices {
            let [x, y, z] = v.0;
            mesh.positions.push(DVec3::new(x as f64, y as f64, z as f64));
        }
        mesh.faces.push([first, first + 1, first + 2]);
    }
    if mesh.faces.is_empty() {
        return Err(input_err(path, "the binary STL file has no facets"));
    }
    Ok(mesh)
}

/// ASCII STL, read here rather than by stl_io, which keeps its coordinates as f32: the text
/// carries what its writer printed (a scan in world coordinates, written with all its digits,
/// keeps them). `solid … endsolid` blocks (several in one file), each `facet` an `outer loop`
/// of three or more `vertex` lines (more are fanned), facet normals not read; an error names
/// the line.
fn load_ascii(path: &Path, bytes: &[u8]) -> Result<Mesh, Error> {
    let text = std::str::from_utf8(bytes).map_err(|e| input_err(path, format!("ASCII STL that is not text: {e}")))?;
    let mut mesh = Mesh::default();
    let mut corners: Vec<u32> = Vec::new();
    let mut in_loop = false;
    for (n, line) in text.lines().enumerate() {
        let err = |what: String| input_err(path, format!("ASCII STL line {}: {what}", n + 1));
        let mut tok = line.split_whitespace();
        match tok.next() {
            None | Some("solid") | Some("endsolid") | Some("facet") | Some("endfacet") => {}
            Some("outer") => {
                corners.clear();
                in_loop = true;
            }
            Some("vertex") if in_loop => {
                let mut c = [0.0f64; 3];
                for k in &mut c {
                    let t = tok.next().ok_or_else(|| err("a vertex needs three coordinates".into()))?;
                    *k = t.parse::<f64>().ok().filter(|x| x.is_finite()).ok_or_else(|| err(format!("'{t}' is not a finite number")))?;
                }
                corners.push(mesh.positions.len() as u32);
                mesh.positions.push(DVec3::from_array(c));
            }
            Some("endloop") if in_loop => {
                if corners.len() < 3 {
                    return Err(err(format!("a facet with {} vertices", corners.len())));
                }
                mesh.faces.extend((2..corners.len()).map(|k| [corners[0], corners[k - 1], corners[k]]));
                in_loop = false;
            }
            Some(w) => return Err(err(format!("'{w}' where a facet, a loop or a vertex was expected"))),
        }
    }
    if in_loop {
        return Err(input_err(path, "ASCII STL ends inside a facet (truncated?)"));
    }
    if mesh.faces.is_empty() {
        return Err(input_err(path, "the ASCII STL file has no facets"));
    }
    Ok(mesh)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A binary STL of `tris`, its header starting with `header`.
    pub(crate) fn binary(header: &[u8], tris: &[[[f32; 3]; 3]]) -> Vec<u8> {
        let mut b = vec![b' '; 80];
        b[..header.len()].copy_from_slice(header);
        b.extend_from_slice(&(tris.len() as u32).to_le_bytes());
        for t in tris {
            b.extend_from_slice(&[0u8; 12]);
            for v in t {
                for c in v {
                    b.extend_from_slice(&c.to_le_bytes());
                }
            }
            b.extend_from_slice(&[0u8; 2]);
        }
        b
    }

    //   3 ─── 2
    //   │  ╲  │    two triangles of a unit square, as a soup of six corners
    //   0 ─── 1
    const SQUARE: [[[f32; 3]; 3]; 2] = [[[0., 0., 0.], [1., 0., 0.], [1., 1., 0.]], [[0., 0., 0.], [1., 1., 0.], [0., 1., 0.]]];

    #[test]
    fn binary_and_ascii_stl_read_as_a_soup_of_corners() {
        let path = Path::new("square.stl");
        // Binary, its header starting with "solid" as some exporters write it.
        for header in [&b"binary square"[..], b"solid square, binary"] {
            let m = load_stl(path, binary(header, &SQUARE)).unwrap();
            assert_eq!(m.faces, vec![[0, 1, 2], [3, 4, 5]]);
            assert_eq!(m.positions[4], DVec3::new(1.0, 1.0, 0.0));
        }
        // ASCII, with and without a name after `solid`.
        let facet = |t: &[[f32; 3]; 3]| {
            let v: String = t.iter().map(|p| format!("      vertex {} {} {}\n", p[0], p[1], p[2])).collect();
            format!("  facet normal 0 0 1\n    outer loop\n{v}    endloop\n  endfacet\n")
        };
        let body: String = SQUARE.iter().map(facet).collect();
        for head in ["solid square\n", "solid\n"] {
            let m = load_stl(path, format!("{head}{body}endsolid\n").into_bytes()).unwrap();
            assert_eq!(m.faces.len(), 2);
            assert_eq!(m.positions[2], DVec3::new(1.0, 1.0, 0.0));
        }
        // A truncated binary file, a broken ASCII facet: errors naming what is wrong.
        let mut cut = binary(b"x", &SQUARE);
        cut.truncate(cut.len() - 10);
        let e = load_stl(path, cut).unwrap_err().to_string();
        assert!(e.contains("square.stl") && e.contains("a binary STL of 2 facets is 184 bytes, the file has 174"), "{e}");
        let e = load_stl(path, format!("solid s\n{}  facet normal 0 0 1\n    outer loop\n      vertex 0 0 x\n", facet(&SQUARE[0])).into_bytes()).unwrap_err().to_string();
        assert!(e.contains("ASCII STL line 11: 'x' is not a finite number"), "{e}");
        let e = load_stl(path, format!("solid s\n{}", &facet(&SQUARE[0])[..60]).into_bytes()).unwrap_err().to_string();
        assert!(e.contains("ends inside a facet"), "{e}");
        // ASCII keeps every digit written (f64), where binary holds f32.
        let far = "solid utm\nfacet normal 0 0 1\nouter loop\nvertex 5300000.123 512345.678 1\nvertex 5300001.123 512345.678 1\nvertex 5300000.123 512346.678 1\nendloop\nendfacet\nendsolid utm\n";
        assert_eq!(load_stl(path, far.as_bytes().to_vec()).unwrap().positions[0], DVec3::new(5300000.123, 512345.678, 1.0));
    }
}
