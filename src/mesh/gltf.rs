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
use gltf::mesh::Mode;
use std::path::Path;

/// Required extensions that change how positions and indices are stored: not read here.
const GEOMETRY_EXTENSIONS: [&str; 3] = ["KHR_draco_mesh_compression", "EXT_meshopt_compression", "KHR_mesh_quantization"];

/// Reads a glTF or GLB file's bytes (already unzipped) into a [`Mesh`].
pub fn load_gltf(path: &Path, bytes: &[u8]) -> Result<Mesh, Error> {
    let g = gltf::Gltf::from_slice(bytes).map_err(|e| input_err(path, format!("not a valid glTF file: {e}")))?;
    if let Some(ext) = g.document.extensions_required().find(|e| GEOMETRY_EXTENSIONS.contains(e)) {
        return Err(input_err(path, format!("its meshes are stored with {ext}, which dispdec does not read: export them uncompressed")));
    }
    let base = path.parent().map(|p| if p.as_os_str().is_empty() { Path::new(".") } else { p });
    let buffers = gltf::import_buffers(&g.document, base, g.blob.clone()).map_err(|e| input_err(path, format!("cannot read its buffers: {e}")))?;
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
    fn walk(node: gltf::Node, parent: DMat4, visit: &mut dyn FnMut(&gltf::Node, DMat4, &mut Mesh) -> Result<(), Error>, mesh: &mut Mesh, depth: usize) -> Result<(), Error> {
        let local = DMat4::from_cols_array_2d(&node.transform().matrix().map(|c| c.map(|x| x as f64)));
        let world = parent * local;
        visit(&node, world, mesh)?;
        // glTF node trees are acyclic (the crate validates it); the depth bound is a guard.
        if depth < 256 {
            for child in node.children() {
                walk(child, world, visit, mesh, depth + 1)?;
            }
        }
        Ok(())
    }
    match g.document.default_scene().or_else(|| g.document.scenes().next()) {
        Some(scene) => {
            for node in scene.nodes() {
                walk(node, DMat4::IDENTITY, &mut visit, &mut mesh, 0)?;
            }
        }
        None => {
            for node in g.document.nodes() {
                visit(&node, DMat4::from_cols_array_2d(&node.transform().matrix().map(|c| c.map(|x| x as f64))), &mut mesh)?;
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
        // A compressed file is refused by name.
        let draco = json.replace(r#""asset":{"version":"2.0"},"#, r#""asset":{"version":"2.0"},"extensionsUsed":["KHR_draco_mesh_compression"],"extensionsRequired":["KHR_draco_mesh_compression"],"#);
        let e = load_gltf(&path, draco.as_bytes()).unwrap_err().to_string();
        assert!(e.contains("square.gltf") && e.contains("KHR_draco_mesh_compression"), "{e}");
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
