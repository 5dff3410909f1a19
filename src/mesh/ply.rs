//! PLY input (ASCII, binary little or big endian), streamed element by element through
//! ply-rs-bw into flat arrays: a vertex keeps x, y, z and nothing else, so a 2M-face scan costs
//! its positions and faces, not a map of properties per element. Header lines that are not PLY
//! keywords are skipped with a warning; unknown elements and properties are read past.

use super::{input_err, Mesh};
use crate::Error;
use glam::DVec3;
use ply_rs_bw::parser::{Parser, Reader};
use ply_rs_bw::ply::{Property, PropertyAccess, PropertyAccessResult};
use std::io::{BufRead, Read};
use std::path::Path;

/// The header keywords of the PLY format; any other header line is skipped.
const HEADER_KEYWORDS: [&str; 7] = ["ply", "format", "comment", "obj_info", "element", "property", "end_header"];

fn scalar(p: &Property) -> Option<f64> {
    Some(match *p {
        Property::Char(v) => v as f64,
        Property::UChar(v) => v as f64,
        Property::Short(v) => v as f64,
        Property::UShort(v) => v as f64,
        Property::Int(v) => v as f64,
        Property::UInt(v) => v as f64,
        Property::Float(v) => v as f64,
        Property::Double(v) => v,
        _ => return None,
    })
}

fn int_list(p: Property) -> Option<Vec<i64>> {
    Some(match p {
        Property::ListChar(v) => v.into_iter().map(|x| x as i64).collect(),
        Property::ListUChar(v) => v.into_iter().map(|x| x as i64).collect(),
        Property::ListShort(v) => v.into_iter().map(|x| x as i64).collect(),
        Property::ListUShort(v) => v.into_iter().map(|x| x as i64).collect(),
        Property::ListInt(v) => v.into_iter().map(|x| x as i64).collect(),
        Property::ListUInt(v) => v.into_iter().map(|x| x as i64).collect(),
        _ => return None,
    })
}

/// A vertex: x, y, z (NaN until set, so a missing coordinate is seen).
struct PlyVertex([f64; 3]);

impl PropertyAccess for PlyVertex {
    fn new() -> Self {
        PlyVertex([f64::NAN; 3])
    }
    fn set_property(&mut self, name: &str, p: Property) -> PropertyAccessResult {
        let k = match name {
            "x" => 0,
            "y" => 1,
            "z" => 2,
            _ => return PropertyAccessResult::Ignored,
        };
        match scalar(&p) {
            Some(v) => {
                self.0[k] = v;
                PropertyAccessResult::Set
            }
            None => PropertyAccessResult::Ignored,
        }
    }
}

/// A face or a triangle strip: its vertex index list (`vertex_indices` or `vertex_index`).
struct PlyList(Option<Vec<i64>>);

impl PropertyAccess for PlyList {
    fn new() -> Self {
        PlyList(None)
    }
    fn set_property(&mut self, name: &str, p: Property) -> PropertyAccessResult {
        if name != "vertex_indices" && name != "vertex_index" {
            return PropertyAccessResult::Ignored;
        }
        match int_list(p) {
            Some(v) => {
                self.0 = Some(v);
                PropertyAccessResult::Set
            }
            None => PropertyAccessResult::Ignored,
        }
    }
}

/// Any other element: read past.
struct Skip;

impl PropertyAccess for Skip {
    fn new() -> Self {
        Skip
    }
}

/// Reads the header lines up to `end_header`, dropping those that are not PLY keywords.
fn filtered_header(path: &Path, source: &mut dyn BufRead, warnings: &mut Vec<String>) -> Result<Vec<u8>, Error> {
    let mut out = Vec::new();
    let mut line = Vec::new();
    for lineno in 1.. {
        line.clear();
        let n = source.read_until(b'\n', &mut line).map_err(|e| input_err(path, format!("cannot read file: {e}")))?;
        if n == 0 {
            return Err(input_err(path, "malformed PLY: the file ends inside the header (no 'end_header')"));
        }
        let text = String::from_utf8_lossy(&line);
        let word = text.split_whitespace().next().unwrap_or("");
        if word.is_empty() || HEADER_KEYWORDS.contains(&word) {
            if !word.is_empty() {
                // ply-rs wants '\n' line ends; keep the keyword lines as they are otherwise.
                out.extend_from_slice(text.trim_end_matches(['\r', '\n']).as_bytes());
                out.push(b'\n');
            }
            if word == "end_header" {
                break;
            }
        } else {
            warnings.push(format!("{}: PLY header line {lineno} is not a PLY keyword and was skipped: '{}'", path.display(), text.trim_end()));
        }
    }
    Ok(out)
}

pub(super) fn load_ply(path: &Path, mut source: Box<dyn BufRead + '_>) -> Result<Mesh, Error> {
    let mut warnings = Vec::new();
    let header_bytes = filtered_header(path, &mut source, &mut warnings)?;
    let mut reader = Reader::new(std::io::BufReader::new(std::io::Cursor::new(header_bytes).chain(source)));
    let malformed = |e: ply_rs_bw::parser::ParseError| {
        let what = match e.kind() {
            std::io::ErrorKind::UnexpectedEof => "the file is truncated",
            _ => "malformed PLY",
        };
        input_err(path, format!("{what}: {e}"))
    };
    let header = Parser::<Skip>::new().read_header(&mut reader).map_err(malformed)?;
    let mut positions: Vec<DVec3> = Vec::new();
    let mut faces = Vec::new();
    let (mut have_vertex, mut have_faces) = (false, false);
    let to_u32 = |i: i64| i as u32;
    for (name, def) in &header.elements {
        match name.as_str() {
            "vertex" => {
                have_vertex = true;
                let vs = Parser::<PlyVertex>::new().read_payload_for_element(&mut reader, def, &header).map_err(malformed)?;
                for (i, v) in vs.iter().enumerate() {
                    for (k, axis) in ["x", "y", "z"].iter().enumerate() {
                        if v.0[k].is_nan() && !def.properties.contains_key(*axis) {
                            return Err(input_err(path, format!("vertex {i} has no numeric property '{axis}'")));
                        }
                    }
                }
                positions = vs.into_iter().map(|v| DVec3::from_array(v.0)).collect();
            }
            "face" => {
                have_faces = true;
                let fs = Parser::<PlyList>::new().read_payload_for_element(&mut reader, def, &header).map_err(malformed)?;
                for (fi, f) in fs.into_iter().enumerate() {
                    let idx = f.0.ok_or_else(|| input_err(path, format!("face {fi} has no integer list 'vertex_indices'")))?;
                    if idx.len() < 3 {
                        return Err(input_err(path, format!("face {fi} has {} vertices and cannot be triangulated", idx.len())));
                    }
                    for (k, &i) in idx.iter().enumerate() {
                        if i < 0 || i as usize >= positions.len() {
                            return Err(input_err(
                                path,
                                format!("face {fi} (corner {k}) references vertex {i}, but the file has only {} vertices", positions.len()),
                            ));
                        }
                    }
                    // Fan triangulation of polygons.
                    for k in 1..idx.len() - 1 {
                        faces.push([to_u32(idx[0]), to_u32(idx[k]), to_u32(idx[k + 1])]);
                    }
                }
            }
            "tristrips" => {
                have_faces = true;
                let ss = Parser::<PlyList>::new().read_payload_for_element(&mut reader, def, &header).map_err(malformed)?;
                for (si, s) in ss.into_iter().enumerate() {
                    let idx = s.0.ok_or_else(|| input_err(path, format!("tristrips {si} has no integer list 'vertex_indices'")))?;
                    decode_strip(path, si, &idx, positions.len(), &mut faces)?;
                }
            }
            _ => {
                Parser::<Skip>::new().read_payload_for_element(&mut reader, def, &header).map_err(malformed)?;
            }
        }
    }
    if !have_vertex {
        return Err(input_err(path, "no 'vertex' element"));
    }
    if !have_faces {
        return Err(input_err(path, "no 'face' or 'tristrips' element"));
    }
    Ok(Mesh { positions, faces, normals: Vec::new(), settings: None, warnings })
}

/// A triangle strip with -1 restarts; every other triangle is reversed so that all keep the
/// strip's winding, and the strip-joining degenerate triangles are dropped.
fn decode_strip(path: &Path, si: usize, idx: &[i64], nv: usize, faces: &mut Vec<[u32; 3]>) -> Result<(), Error> {
    let mut strip: Vec<u32> = Vec::new();
    let flush = |strip: &mut Vec<u32>, faces: &mut Vec<[u32; 3]>| {
        for i in 0..strip.len().saturating_sub(2) {
            let (a, b, c) = (strip[i], strip[i + 1], strip[i + 2]);
            if a == b || b == c || a == c {
                continue;
            }
            faces.push(if i % 2 == 0 { [a, b, c] } else { [b, a, c] });
        }
        strip.clear();
    };
    for (k, &i) in idx.iter().enumerate() {
        if i == -1 {
            flush(&mut strip, faces);
        } else if i < 0 || i as usize >= nv {
            return Err(input_err(path, format!("tristrips {si} entry {k} references vertex {i}, but the file has only {nv} vertices")));
        } else {
            strip.push(i as u32);
        }
    }
    flush(&mut strip, faces);
    Ok(())
}
