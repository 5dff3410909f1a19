//! glTF 2.0 input (`.glb`, or `.gltf` with its buffers embedded or beside it), as phone and
//! photogrammetry scanning apps export scans, through the gltf crate: every triangle primitive
//! of every mesh node of the scene (the default scene, else the first; without scenes, every
//! node), positions moved by the node's world transform, merged into one mesh in that order.
//! Points and lines are skipped with a warning; normals, UVs and textures are not read (the
//! winding decides, as for OBJ and PLY). Compressed or quantised geometry (Draco, meshopt,
//! KHR_mesh_quantization) is refused, naming the extension.

use super::{input_err, Mesh};
use crate::Error;
use glam::{DMat4, DVec3};
use gltf::accessor::{DataType, Dimensions};
use gltf::mesh::Mode;
use std::path::Path;

/// Required extensions that change how positions and indices are stored: not read here.
const GEOMETRY_EXTENSIONS: [&str; 3] = ["KHR_draco_mesh_compression", "EXT_meshopt_compression", "KHR_mesh_quantization"];

/// Reads a glTF or GLB file's bytes (already unzipped) into a [`Mesh`].
pub fn load_gltf(path: &Path, bytes: &[u8]) -> Result<Mesh, Error> {
    let invalid = |e: gltf::Error| input_err(path, format!("not a valid glTF file: {e}"));
    let g = gltf::Gltf::from_slice_without_validation(bytes).map_err(invalid)?;
    let root = g.document.into_json();
    // gltf-json's validation reads each POSITION accessor without checking its index (a
    // panic, found by garbling a .gltf at random): checked here before it runs.
    for (mi, m) in root.meshes.iter().enumerate() {
        for (pi, p) in m.primitives.iter().enumerate() {
            if let Some(a) = p.attributes.values().find(|a| a.value() >= root.accessors.len()) {
                return Err(input_err(path, format!("mesh {mi} primitive {pi} names accessor {}, but there are {}", a.value(), root.accessors.len())));
            }
        }
    }
    let document = gltf::Document::from_json(root).map_err(invalid)?;
    if let Some(ext) = document.extensions_required().find(|e| GEOMETRY_EXTENSIONS.contains(e)) {
        return Err(input_err(path, format!("its meshes are stored with {ext}, which dispdec does not read: export them uncompressed")));
    }
    let base = path.parent().map(|p| if p.as_os_str().is_empty() { Path::new(".") } else { p });
    let buffers = gltf::import_buffers(&document, base, g.blob).map_err(|e| input_err(path, format!("cannot read its buffers: {e}")))?;
    let mut mesh = Mesh::default();
    let mut skipped = 0usize;
    let mut visit = |node: &gltf::Node, world: DMat4, mesh: &mut Mesh| -> Result<(), Error> {
        let Some(m) = node.mesh() else { return Ok(()) };
        // A mirroring transform turns the winding: glTF says to turn it back.
        let mirror = world.determinant() < 0.0;
        for p in m.primitives() {
            let mode = p.mode();
            if !matches!(mode, Mode::Triangles | Mode::TriangleStrip | Mode::TriangleFan) {
                skipped += 1;
                continue;
            }
            let what = || format!("mesh {} primitive {}", m.index(), p.index());
            let Some(pos_acc) = p.get(&gltf::Semantic::Positions) else {
                return Err(input_err(path, format!("{} has no POSITION", what())));
            };
            let vec3_f32 = pos_acc.dimensions() == Dimensions::Vec3 && pos_acc.data_type() == DataType::F32;
            check_accessor(&pos_acc, vec3_f32, &buffers).map_err(|e| input_err(path, format!("{}: POSITION {e}", what())))?;
            if let Some(ia) = p.indices() {
                let scalar = ia.dimensions() == Dimensions::Scalar && matches!(ia.data_type(), DataType::U8 | DataType::U16 | DataType::U32);
                check_accessor(&ia, scalar, &buffers).map_err(|e| input_err(path, format!("{}: indices {e}", what())))?;
            }
            let reader = p.reader(|b| buffers.get(b.index()).map(|d| &d.0[..]));
            let Some(positions) = reader.read_positions() else {
                return Err(input_err(path, format!("{} has no POSITION", what())));
            };
            let first = mesh.positions.len() as u32;
            mesh.positions.extend(positions.map(|q| world.transform_point3(DVec3::new(q[0] as f64, q[1] as f64, q[2] as f64))));
            let count = mesh.positions.len() as u32 - first;
            let idx: Vec<u32> = match reader.read_indices() {
                Some(i) => i.into_u32().collect(),
                None => (0..count).collect(),
            };
            if let Some(&bad) = idx.iter().find(|&&i| i >= count) {
                return Err(input_err(path, format!("{} references vertex {bad}, but it has only {count}", what())));
            }
            let tri = |a: u32, b: u32, c: u32| if mirror { [first + a, first + c, first + b] } else { [first + a, first + b, first + c] };
            match mode {
                Mode::Triangles => mesh.faces.extend(idx.chunks_exact(3).map(|t| tri(t[0], t[1], t[2]))),
                Mode::TriangleStrip => mesh.faces.extend((2..idx.len()).map(|k| if k % 2 == 0 { tri(idx[k - 2], idx[k - 1], idx[k]) } else { tri(idx[k - 1], idx[k - 2], idx[k]) })),
                _ => mesh.faces.extend((2..idx.len()).map(|k| tri(idx[0], idx[k - 1], idx[k]))),
            }
        }
        Ok(())
    };
    // glTF's nodes form trees (a node has one parent at most): a node met twice (a cycle, or
    // one shared by two parents, which could multiply the walk) is refused.
    let mut seen = vec![false; document.nodes().len()];
    let mut stack: Vec<(gltf::Node, DMat4)> = Vec::new();
    match document.default_scene().or_else(|| document.scenes().next()) {
        Some(scene) => {
            stack.extend(scene.nodes().map(|n| (n, DMat4::IDENTITY)));
            stack.reverse();
            while let Some((node, parent)) = stack.pop() {
                if std::mem::replace(&mut seen[node.index()], true) {
                    return Err(input_err(path, format!("node {} appears twice in the scene (a glTF node has one parent at most)", node.index())));
                }
                let world = parent * local_transform(&node);
                visit(&node, world, &mut mesh)?;
                let at = stack.len();
                stack.extend(node.children().map(|c| (c, world)));
                stack[at..].reverse();
            }
        }
        None => {
            for node in document.nodes() {
                visit(&node, local_transform(&node), &mut mesh)?;
            }
        }
    }
    if skipped > 0 {
        mesh.warnings.push(format!("{}: {skipped} primitive(s) of points or lines skipped", path.display()));
    }
    if mesh.faces.is_empty() {
        return Err(input_err(path, "the glTF file has no triangles"));
    }
    Ok(mesh)
}

/// A node's own transform (relative to its parent), in f64.
fn local_transform(node: &gltf::Node) -> DMat4 {
    DMat4::from_cols_array_2d(&node.transform().matrix().map(|c| c.map(|x| x as f64)))
}

/// Whether accessor `a` can be read as it says: of the type its use needs (`typed`), not sparse,
/// and every element inside its buffer view and the view inside its buffer, at a stride no
/// shorter than an element. The gltf crate's reader asserts these (a panic on a garbled file,
/// found by garbling one at random) rather than reporting them.
fn check_accessor(a: &gltf::Accessor, typed: bool, buffers: &[gltf::buffer::Data]) -> Result<(), String> {
    let n = a.index();
    if !typed {
        return Err(format!("accessor {n} is of type {:?} {:?}, which dispdec does not read there", a.data_type(), a.dimensions()));
    }
    if a.sparse().is_some() {
        return Err(format!("accessor {n} is sparse, which dispdec does not read"));
    }
    let Some(view) = a.view() else { return Err(format!("accessor {n} has no buffer view")) };
    let size = a.size();
    let stride = view.stride().unwrap_or(size);
    let data = buffers.get(view.buffer().index()).map_or(0, |d| d.len());
    let view_end = view.offset().checked_add(view.length());
    let last = a.count().checked_sub(1).map(|k| k.checked_mul(stride).and_then(|x| x.checked_add(a.offset())).and_then(|x| x.checked_add(size)));
    let inside = match last {
        None => true,
        Some(end) => end.is_some_and(|e| e <= view.length()),
    };
    if stride < size || view_end.is_none_or(|e| e > data) || !inside {
        return Err(format!(
            "accessor {n} ({} elements of {size} bytes from byte {} at a stride of {stride}) does not fit its buffer view {} ({} bytes from byte {} of a buffer of {data})",
            a.count(),
            a.offset(),
            view.index(),
            view.length(),
            view.offset()
        ));
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn nodes_place_their_meshes_and_a_mirror_keeps_the_winding() {
        //   3 ─── 2
        //   │   ╱ │   a unit square: indexed triangles in node A (moved by +10 in x), and the
        //   0 ─── 1   same corners as a fan without indices in A's child B (mirrored in x)
        let dir = std::env::temp_dir().join(format!("dispdec-gltf-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let mut bin: Vec<u8> = [[0f32, 0., 0.], [1., 0., 0.], [1., 1., 0.], [0., 1., 0.]].iter().flatten().flat_map(|c| c.to_le_bytes()).collect();
        bin.extend([0u16, 1, 2, 0, 2, 3].iter().flat_map(|i| i.to_le_bytes()));
        std::fs::write(dir.join("square.bin"), &bin).unwrap();
        let json = r#"{"asset":{"version":"2.0"},"scene":0,"scenes":[{"nodes":[0]}],
          "nodes":[{"mesh":0,"translation":[10,0,0],"children":[1]},{"mesh":1,"scale":[-1,1,1]}],
          "meshes":[{"primitives":[{"attributes":{"POSITION":0},"indices":1}]},{"primitives":[{"attributes":{"POSITION":0},"mode":6},{"attributes":{"POSITION":0},"mode":1}]}],
          "accessors":[{"bufferView":0,"componentType":5126,"count":4,"type":"VEC3","min":[0,0,0],"max":[1,1,0]},
                       {"bufferView":1,"componentType":5123,"count":6,"type":"SCALAR"}],
          "bufferViews":[{"buffer":0,"byteOffset":0,"byteLength":48},{"buffer":0,"byteOffset":48,"byteLength":12}],
          "buffers":[{"uri":"square.bin","byteLength":60}]}"#;
        let path = dir.join("square.gltf");
        std::fs::write(&path, json).unwrap();
        let m = load_gltf(&path, json.as_bytes()).unwrap();
        assert_eq!(m.positions[..4], [DVec3::new(10., 0., 0.), DVec3::new(11., 0., 0.), DVec3::new(11., 1., 0.), DVec3::new(10., 1., 0.)]);
        assert_eq!(m.positions[5], DVec3::new(9., 0., 0.), "B: mirrored, then moved with A");
        // A's two triangles as written; B's fan (0 1 2, 0 2 3) turned back: the normals of both
        // squares point the same way (+z), as the mirrored square's do when drawn.
        assert_eq!(m.faces, vec![[0, 1, 2], [0, 2, 3], [4, 6, 5], [4, 7, 6]]);
        assert_eq!(m.warnings.len(), 1, "the lines primitive skipped: {:?}", m.warnings);
        // A POSITION naming an accessor that is not there: refused (gltf-json's validation
        // panicked on it).
        let e = load_gltf(&path, json.replacen(r#""POSITION":0"#, r#""POSITION":5"#, 1).as_bytes()).unwrap_err().to_string();
        assert!(e.contains("mesh 0 primitive 0 names accessor 5, but there are 2"), "{e}");
        // A stride shorter than a position (gltf's reader asserted on it): refused, saying so.
        let short = json.replacen(r#""byteOffset":0,"byteLength":48}"#, r#""byteOffset":0,"byteLength":48,"byteStride":4}"#, 1);
        let e = load_gltf(&path, short.as_bytes()).unwrap_err().to_string();
        assert!(e.contains("POSITION accessor 0 (4 elements of 12 bytes from byte 0 at a stride of 4) does not fit"), "{e}");
        // B also a root of the scene (two parents): refused, not walked twice.
        let twice = json.replace(r#""scenes":[{"nodes":[0]}]"#, r#""scenes":[{"nodes":[0,1]}]"#);
        let e = load_gltf(&path, twice.as_bytes()).unwrap_err().to_string();
        assert!(e.contains("node 1 appears twice"), "{e}");
        // A compressed file is refused by name.
        let draco = json.replace(r#""asset":{"version":"2.0"},"#, r#""asset":{"version":"2.0"},"extensionsUsed":["KHR_draco_mesh_compression"],"extensionsRequired":["KHR_draco_mesh_compression"],"#);
        let e = load_gltf(&path, draco.as_bytes()).unwrap_err().to_string();
        assert!(e.contains("square.gltf") && e.contains("KHR_draco_mesh_compression"), "{e}");
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
