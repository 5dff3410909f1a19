//! `dispdec export`: a binary glTF 2.0 (`.glb`) of the base mesh and its displacement map, for
//! any viewer or engine. The document is built with `gltf-json`'s types; the container (a
//! 12-byte header, a JSON chunk, a BIN chunk) is the format's own, written here.
//!
//! - the base: one vertex per face corner (UVs are per corner), POSITION, NORMAL (the
//!   normalised direction N at the vertex), TEXCOORD_0 (the map's atlas; glTF's v runs down);
//! - the map, as a 16-bit PNG texture in the `normalized` convention (d·|N(X)|: the distance
//!   along the interpolated, normalised normal, as viewers displace tessellated meshes), its
//!   quantisation and convention in the material's `extras.dispdec_displacement` (glTF core has
//!   no displacement slot);
//! - with `levels`, the mesh rebuilt at that level as a second node, so any viewer shows the
//!   detail.

use crate::maps::bake::{DispMap, Kind, Quantisation};
use crate::guarantee::NormalMode;
use crate::maps::reconstruct::Rebuilt;
use crate::validate::Base;
use glam::DVec3;
use gltf_json as json;
use json::validation::{Checked::Valid, USize64};

/// What went into the file.
#[derive(Clone, Debug, serde::Serialize)]
pub struct Exported {
    pub bytes: usize,
    pub base_faces: usize,
    pub rebuilt_faces: Option<usize>,
    pub texture: Quantisation,
}

/// Appends `data` to the BIN buffer (4-byte aligned) as a buffer view; returns its index.
fn push_view(root: &mut json::Root, bin: &mut Vec<u8>, data: &[u8], target: Option<json::buffer::Target>) -> json::Index<json::buffer::View> {
    while !bin.len().is_multiple_of(4) {
        bin.push(0);
    }
    let view = json::buffer::View {
        buffer: json::Index::new(0),
        byte_length: USize64::from(data.len()),
        byte_offset: Some(USize64::from(bin.len())),
        byte_stride: None,
        extensions: None,
        extras: None,
        name: None,
        target: target.map(Valid),
    };
    bin.extend_from_slice(data);
    root.push(view)
}

fn push_accessor(
    root: &mut json::Root,
    view: json::Index<json::buffer::View>,
    count: usize,
    component: json::accessor::ComponentType,
    type_: json::accessor::Type,
    min_max: Option<([f32; 3], [f32; 3])>,
) -> json::Index<json::Accessor> {
    root.push(json::Accessor {
        buffer_view: Some(view),
        byte_offset: Some(USize64(0)),
        count: USize64::from(count),
        component_type: Valid(json::accessor::GenericComponentType(component)),
        extensions: None,
        extras: None,
        type_: Valid(type_),
        min: min_max.map(|m| serde_json::json!(m.0)),
        max: min_max.map(|m| serde_json::json!(m.1)),
        name: None,
        normalized: false,
        sparse: None,
    })
}

fn f32_bytes(v: &[[f32; 3]]) -> Vec<u8> {
    v.iter().flat_map(|p| p.iter().flat_map(|c| c.to_le_bytes())).collect()
}

fn bounds(v: &[[f32; 3]]) -> ([f32; 3], [f32; 3]) {
    let mut lo = [f32::INFINITY; 3];
    let mut hi = [f32::NEG_INFINITY; 3];
    for p in v {
        for k in 0..3 {
            lo[k] = lo[k].min(p[k]);
            hi[k] = hi[k].max(p[k]);
        }
    }
    (lo, hi)
}

/// A triangle mesh primitive from flat arrays (normals and UVs optional).
#[allow(clippy::too_many_arguments)]
fn push_mesh(
    root: &mut json::Root,
    bin: &mut Vec<u8>,
    name: &str,
    positions: &[[f32; 3]],
    normals: Option<&[[f32; 3]]>,
    uvs: Option<&[[f32; 2]]>,
    indices: &[u32],
    material: Option<json::Index<json::Material>>,
) -> json::Index<json::Mesh> {
    use json::accessor::{ComponentType as C, Type as T};
    use json::buffer::Target;
    let mut attributes = std::collections::BTreeMap::new();
    let v = push_view(root, bin, &f32_bytes(positions), Some(Target::ArrayBuffer));
    let a = push_accessor(root, v, positions.len(), C::F32, T::Vec3, Some(bounds(positions)));
    attributes.insert(Valid(json::mesh::Semantic::Positions), a);
    if let Some(n) = normals {
        let v = push_view(root, bin, &f32_bytes(n), Some(Target::ArrayBuffer));
        let a = push_accessor(root, v, n.len(), C::F32, T::Vec3, None);
        attributes.insert(Valid(json::mesh::Semantic::Normals), a);
    }
    if let Some(t) = uvs {
        let bytes: Vec<u8> = t.iter().flat_map(|p| p.iter().flat_map(|c| c.to_le_bytes())).collect();
        let v = push_view(root, bin, &bytes, Some(Target::ArrayBuffer));
        let a = push_accessor(root, v, t.len(), C::F32, T::Vec2, None);
        attributes.insert(Valid(json::mesh::Semantic::TexCoords(0)), a);
    }
    let bytes: Vec<u8> = indices.iter().flat_map(|i| i.to_le_bytes()).collect();
    let v = push_view(root, bin, &bytes, Some(Target::ElementArrayBuffer));
    let idx = push_accessor(root, v, indices.len(), C::U32, T::Scalar, None);
    root.push(json::Mesh {
        extensions: None,
        extras: None,
        name: Some(name.into()),
        primitives: vec![json::mesh::Primitive {
            attributes,
            extensions: None,
            extras: None,
            indices: Some(idx),
            material,
            mode: Valid(json::mesh::Mode::Triangles),
            targets: None,
        }],
        weights: None,
    })
}

/// The `.glb` of `base` with `map` (a scalar map, as `bake --kind scalar` writes it) and,
/// when given, the mesh rebuilt at some level.
pub fn export_glb(base: &Base, mode: NormalMode, map: &DispMap, rebuilt: Option<(u32, &Rebuilt)>) -> (Vec<u8>, Exported) {
    let atlas = map.atlas;
    let mut root = json::Root {
        asset: json::Asset { generator: Some(format!("dispdec {}", env!("CARGO_PKG_VERSION"))), version: "2.0".into(), ..Default::default() },
        ..Default::default()
    };
    let mut bin: Vec<u8> = Vec::new();

    // The texture: d·|N(X)| per texel, 16-bit.
    let normalized: Vec<f32> = (0..atlas.size * atlas.size)
        .map(|i| {
            let d = map.d[i as usize];
            match crate::maps::bake::texel_point(&atlas, base, mode, i % atlas.size, i / atlas.size) {
                Some((_, _, dir)) if !d.is_nan() => (d as f64 * dir.length()) as f32,
                _ => f32::NAN,
            }
        })
        .collect();
    let (png, q) = crate::maps::bake::png16(&normalized, atlas.size, atlas.faces, Kind::Normalized);
    let image_view = push_view(&mut root, &mut bin, &png, None);
    let image = root.push(json::Image {
        buffer_view: Some(image_view),
        mime_type: Some(json::image::MimeType("image/png".into())),
        name: Some("displacement (normalized, 16-bit)".into()),
        uri: None,
        extensions: None,
        extras: None,
    });
    let sampler = root.push(json::texture::Sampler {
        mag_filter: Some(Valid(json::texture::MagFilter::Linear)),
        min_filter: Some(Valid(json::texture::MinFilter::Linear)),
        wrap_s: Valid(json::texture::WrappingMode::ClampToEdge),
        wrap_t: Valid(json::texture::WrappingMode::ClampToEdge),
        ..Default::default()
    });
    let texture = root.push(json::Texture { name: Some("displacement".into()), sampler: Some(sampler), source: image, extensions: None, extras: None });
    let extras = serde_json::json!({
        "dispdec_displacement": {
            "texture": texture.value(),
            "texCoord": 0,
            "kind": "normalized",
            "convention": Kind::Normalized.convention(),
            "value": "d = offset + scale * texel (16-bit integer value); texel 0 = no displacement (a hole of the scan)",
            "scale": q.scale,
            "offset": q.offset,
            "missing": q.missing,
        }
    });
    let material = root.push(json::Material {
        name: Some("dispdec base".into()),
        double_sided: true,
        extras: Some(serde_json::value::to_raw_value(&extras).expect("extras serialise")),
        ..Default::default()
    });

    // The base, one vertex per face corner; far from the origin, relative to its nodes' place.
    let (place, translation) = node_place(&base.positions);
    let mut pos = Vec::with_capacity(3 * base.faces.len());
    let mut nrm = Vec::with_capacity(3 * base.faces.len());
    let mut uv = Vec::with_capacity(3 * base.faces.len());
    let f3 = |v: DVec3| [v.x as f32, v.y as f32, v.z as f32];
    for (fi, t) in base.faces.iter().enumerate() {
        let p = t.map(|v| base.positions[v as usize]);
        let face_n = crate::geometry::face_normal(p[0], p[1], p[2]);
        for k in 0..3 {
            pos.push(f3(p[k] - place));
            let n = match mode {
                NormalMode::Interpolated => base.directions[t[k] as usize].normalize_or_zero(),
                NormalMode::Constant => face_n,
            };
            nrm.push(f3(n));
            let (u, v) = atlas.uv_up(fi as u32, k);
            uv.push([u as f32, (1.0 - v) as f32]);
        }
    }
    let indices: Vec<u32> = (0..pos.len() as u32).collect();
    let base_mesh = push_mesh(&mut root, &mut bin, "base", &pos, Some(&nrm), Some(&uv), &indices, Some(material));
    let mut nodes = vec![root.push(json::Node { mesh: Some(base_mesh), name: Some("base".into()), translation, ..Default::default() })];
    let rebuilt_faces = rebuilt.map(|(level, r)| {
        let p: Vec<[f32; 3]> = r.positions.iter().map(|&v| f3(v - place)).collect();
        let idx: Vec<u32> = r.faces.iter().flatten().copied().collect();
        let m = push_mesh(&mut root, &mut bin, &format!("rebuilt at level {level}"), &p, None, None, &idx, None);
        nodes.push(root.push(json::Node { mesh: Some(m), name: Some(format!("rebuilt at level {level}")), translation, ..Default::default() }));
        r.faces.len()
    });
    while !bin.len().is_multiple_of(4) {
        bin.push(0);
    }
    root.push(json::Buffer { byte_length: USize64::from(bin.len()), name: None, uri: None, extensions: None, extras: None });
    let scene = root.push(json::Scene { extensions: None, extras: None, name: Some("dispdec".into()), nodes });
    root.scene = Some(scene);

    let mut text = root.to_vec().expect("glTF JSON serialises");
    while !text.len().is_multiple_of(4) {
        text.push(b' ');
    }
    let total = 12 + 8 + text.len() + 8 + bin.len();
    let mut out = Vec::with_capacity(total);
    out.extend_from_slice(b"glTF");
    out.extend_from_slice(&2u32.to_le_bytes());
    out.extend_from_slice(&(total as u32).to_le_bytes());
    out.extend_from_slice(&(text.len() as u32).to_le_bytes());
    out.extend_from_slice(b"JSON");
    out.extend_from_slice(&text);
    out.extend_from_slice(&(bin.len() as u32).to_le_bytes());
    out.extend_from_slice(b"BIN\0");
    out.extend_from_slice(&bin);
    let info = Exported { bytes: out.len(), base_faces: base.faces.len(), rebuilt_faces, texture: q };
    (out, info)
}

/// Where the meshes' nodes are placed: zero (no translation) for a base near the origin; for
/// one in world coordinates ([`crate::mesh::centre_for`]: more than 16 of its diagonals off)
/// its box's middle rounded to f32, the node's `translation`, and the vertices relative to it.
/// glTF's positions are f32: at a UTM northing of 5.3e6 m they would be rounded to 0.5 m; this
/// way the mesh keeps f32's precision at its own size and a viewer that adds the translation
/// in f64 puts it where it lies.
fn node_place(positions: &[DVec3]) -> (DVec3, Option<[f32; 3]>) {
    let (lo, hi) = crate::mesh::bbox(positions.iter().copied());
    let c = crate::mesh::centre_for(lo, hi);
    if c == DVec3::ZERO {
        return (DVec3::ZERO, None);
    }
    let t = [c.x as f32, c.y as f32, c.z as f32];
    (DVec3::new(t[0] as f64, t[1] as f64, t[2] as f64), Some(t))
}

/// One mesh of a `.glb`: positions and triangles.
pub type GlbMesh = (Vec<DVec3>, Vec<[u32; 3]>);

/// The triangle meshes of a `.glb` (every node's mesh, in scene order, moved by the node's
/// translation; positions and u32 or u16 indices), for `dispdec render` and the tests. Only
/// what dispdec writes is needed: embedded BIN chunk, tightly packed accessors.
pub fn read_glb_meshes(bytes: &[u8]) -> Result<Vec<GlbMesh>, String> {
    let u = |o: usize| -> Result<u32, String> {
        bytes.get(o..o + 4).map(|b| u32::from_le_bytes(b.try_into().unwrap())).ok_or_else(|| "truncated GLB".to_string())
    };
    if bytes.len() < 20 || &bytes[..4] != b"glTF" || u(4)? != 2 {
        return Err("not a binary glTF 2.0 file".into());
    }
    let json_len = u(12)? as usize;
    if &bytes[16..20] != b"JSON" || bytes.len() < 20 + json_len + 8 {
        return Err("no JSON chunk".into());
    }
    let root: json::Root = serde_json::from_slice(&bytes[20..20 + json_len]).map_err(|e| format!("bad glTF JSON: {e}"))?;
    let bin_at = 20 + json_len;
    let bin_len = u(bin_at)? as usize;
    let bin = bytes.get(bin_at + 8..bin_at + 8 + bin_len).ok_or("truncated BIN chunk")?;
    let view_bytes = |a: &json::Accessor, size: usize| -> Result<&[u8], String> {
        let v = root.buffer_views.get(a.buffer_view.ok_or("accessor without a view")?.value()).ok_or("bad buffer view")?;
        let start = v.byte_offset.map_or(0, |o| o.0 as usize) + a.byte_offset.map_or(0, |o| o.0 as usize);
        bin.get(start..start + size * a.count.0 as usize).ok_or_else(|| "accessor beyond the buffer".to_string())
    };
    let mut out = Vec::new();
    for node in &root.nodes {
        let Some(mi) = node.mesh else { continue };
        let mesh = root.meshes.get(mi.value()).ok_or("bad mesh index")?;
        for p in &mesh.primitives {
            let pos_acc = p.attributes.get(&Valid(json::mesh::Semantic::Positions)).ok_or("no POSITION")?;
            let a = root.accessors.get(pos_acc.value()).ok_or("bad accessor")?;
            let positions: Vec<DVec3> = view_bytes(a, 12)?
                .chunks_exact(12)
                .map(|c| {
                    let f = |k: usize| f32::from_le_bytes(c[4 * k..4 * k + 4].try_into().unwrap()) as f64;
                    let t = node.translation.unwrap_or_default().map(f64::from);
                    DVec3::new(f(0) + t[0], f(1) + t[1], f(2) + t[2])
                })
                .collect();
            let ia = root.accessors.get(p.indices.ok_or("no indices")?.value()).ok_or("bad accessor")?;
            let wide = matches!(ia.component_type, Valid(json::accessor::GenericComponentType(json::accessor::ComponentType::U32)));
            let idx: Vec<u32> = if wide {
                view_bytes(ia, 4)?.chunks_exact(4).map(|c| u32::from_le_bytes(c.try_into().unwrap())).collect()
            } else {
                view_bytes(ia, 2)?.chunks_exact(2).map(|c| u16::from_le_bytes(c.try_into().unwrap()) as u32).collect()
            };
            if idx.iter().any(|&i| i as usize >= positions.len()) {
                return Err("index beyond the vertices".into());
            }
            out.push((positions, idx.chunks_exact(3).map(|t| [t[0], t[1], t[2]]).collect()));
        }
    }
    Ok(out)
}
