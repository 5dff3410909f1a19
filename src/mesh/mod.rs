//! Mesh types, input (OBJ, PLY, plain or gzip), welding and repair, the input checks, and OBJ
//! output. The data flows one way: file → [`Mesh`] (as written) → weld → repair (when asked)
//! → checks → [`DenseMesh`].

mod gltf;
mod obj;
mod ply;
pub mod repair;
mod stl;
pub mod sample;

use crate::geometry::{face_normal, maxmin_direction};
use crate::topology::{Topology, TopologyError};
use crate::Error;
use glam::DVec3;
use rayon::prelude::*;
use repair::{Cleanup, Preparation, RepairError};
use std::io::{BufRead, BufReader, Read};
use std::path::Path;

pub use obj::SETTINGS_TAG;

/// A triangle mesh as read from a file, numbered as in the file.
#[derive(Clone, Debug, Default)]
pub struct Mesh {
    pub positions: Vec<DVec3>,
    pub faces: Vec<[u32; 3]>,
    /// One normal per position when the file gives them (OBJ `vn` referenced by every face
    /// corner), else empty.
    pub normals: Vec<DVec3>,
    /// The text of a `# dispdec-settings` line (a base mesh written by dispdec).
    pub settings: Option<String>,
    /// What the reader skipped and the user may want to know (never a failure).
    pub warnings: Vec<String>,
}

/// A checked dense mesh: referenced vertices only, manifold, consistently wound.
#[derive(Clone, Debug)]
pub struct DenseMesh {
    pub positions: Vec<DVec3>,
    pub faces: Vec<[u32; 3]>,
    /// For each vertex here, its vertex in the input file (the lowest of those welded into it).
    pub input_index: Vec<u32>,
    /// For each vertex of the input file, its vertex here (`u32::MAX`: unreferenced, or only
    /// on faces that `--repair` dropped). A vertex that repair split maps to its first fan.
    pub dense_of_input: Vec<u32>,
    /// Number of vertices in the input file (referenced or not).
    pub input_vertex_count: usize,
    /// Number of faces in the input file, triangulated.
    pub input_face_count: usize,
    pub topology: Topology,
    /// What welding and repair changed.
    pub cleanup: Cleanup,
    /// How many median edge lengths its bounding-box diagonal spans (at most
    /// [`MAX_EXTENT_IN_EDGES`]).
    pub extent_in_edges: f64,
    /// Where the scan was moved on load: `positions` are the file's less this ([`centre_for`];
    /// zero for a scan near the origin). Every output in the scan's coordinates adds it back.
    pub centre: DVec3,
    pub warnings: Vec<String>,
}

impl DenseMesh {
    /// The positions in the file's coordinates.
    pub fn world_positions(&self) -> Vec<DVec3> {
        translated(&self.positions, self.centre)
    }
}

impl Mesh {
    /// Axis-aligned bounding box of the referenced vertices.
    pub fn bbox_diagonal(&self) -> f64 {
        bbox_diagonal(self.faces.iter().flatten().map(|&v| self.positions[v as usize]))
    }
}

pub fn bbox_diagonal(points: impl Iterator<Item = DVec3>) -> f64 {
    let (lo, hi) = bbox(points);
    if lo.x > hi.x {
        0.0
    } else {
        (hi - lo).length()
    }
}

/// The axis-aligned bounding box's corners (lo > hi where there are no points).
pub fn bbox(points: impl Iterator<Item = DVec3>) -> (DVec3, DVec3) {
    points.fold((DVec3::INFINITY, DVec3::NEG_INFINITY), |(lo, hi), p| (lo.min(p), hi.max(p)))
}

fn input_err(path: &Path, msg: impl Into<String>) -> Error {
    Error::Input { path: path.display().to_string(), msg: msg.into() }
}

/// Opens a file as a buffered stream, transparently gunzipping it.
fn open_maybe_gz(path: &Path) -> Result<Box<dyn BufRead>, Error> {
    let cannot = |e: std::io::Error| input_err(path, format!("cannot read file: {e}"));
    let file = std::fs::File::open(path).map_err(cannot)?;
    if file.metadata().map_err(cannot)?.is_dir() {
        return Err(input_err(path, "cannot read file: it is a directory"));
    }
    let mut r = BufReader::with_capacity(1 << 20, file);
    let head = r.fill_buf().map_err(cannot)?;
    if head.len() >= 2 && head[0] == 0x1f && head[1] == 0x8b {
        Ok(Box::new(BufReader::with_capacity(1 << 20, GzErrors { inner: flate2::bufread::MultiGzDecoder::new(r) })))
    } else {
        Ok(Box::new(r))
    }
}

/// Marks decoder failures so that they read as what they are (corrupt gzip), not as PLY or
/// OBJ defects.
struct GzErrors<R> {
    inner: R,
}

impl<R: Read> Read for GzErrors<R> {
    fn read(&mut self, buf: &mut [u8]) -> std::io::Result<usize> {
        self.inner.read(buf).map_err(|e| std::io::Error::new(e.kind(), format!("corrupt or truncated gzip data: {e}")))
    }
}

/// The UTF-8 byte-order mark.
const UTF8_BOM: &[u8] = b"\xef\xbb\xbf";

/// Loads an OBJ, PLY, STL or glTF file (plain or gzip-compressed) as written, without checks.
pub fn load_raw(path: &Path) -> Result<Mesh, Error> {
    let mut r = open_maybe_gz(path)?;
    let mut head = r.fill_buf().map_err(|e| input_err(path, e.to_string()))?;
    // A UTF-8 byte-order mark (some Windows exporters write one) is no part of the first line:
    // read as text it hid the first `v` (and every face then named one vertex too many).
    if head.starts_with(UTF8_BOM) {
        r.consume(UTF8_BOM.len());
        head = r.fill_buf().map_err(|e| input_err(path, e.to_string()))?;
    }
    if head.is_empty() {
        return Err(input_err(path, "file is empty"));
    }
    if head.starts_with(b"ply") {
        return ply::load_ply(path, r);
    }
    let name = path.to_string_lossy().to_ascii_lowercase();
    let name = name.strip_suffix(".gz").unwrap_or(&name);
    let gltf = name.ends_with(".glb") || name.ends_with(".gltf") || head.starts_with(b"glTF");
    let stl = !gltf && (name.ends_with(".stl") || head.starts_with(b"solid"));
    if !gltf && !stl && name.ends_with(".ply") {
        return Err(input_err(path, "not a PLY file: the first line is not 'ply'"));
    }
    // The other readers take the whole file.
    let mut bytes = Vec::new();
    r.read_to_end(&mut bytes).map_err(|e| input_err(path, e.to_string()))?;
    if gltf {
        gltf::load_gltf(path, &bytes)
    } else if stl {
        stl::load_stl(path, bytes)
    } else {
        obj::load_obj(path, &bytes)
    }
}

/// Loads and checks a dense input mesh with the default preparation (welded, not repaired).
pub fn load_dense(path: &Path) -> Result<DenseMesh, Error> {
    load_scan(path, &Preparation::default())
}

/// Loads a dense input mesh, welds and repairs it as `prep` says, and checks it (SPEC §2, §6:
/// unreferenced vertices are ignored; every other defect is an error naming the first
/// offending element and the option that would fix it).
pub fn load_scan(path: &Path, prep: &Preparation) -> Result<DenseMesh, Error> {
    let mesh = load_raw(path)?;
    prepare(path, mesh, prep)
}

/// A base mesh to be judged: it may come from any decimator, so only what the check needs is
/// required (valid indices, finite coordinates, no degenerate face); `topology` is the manifold
/// check's verdict, an error message when the base is not a manifold.
pub struct LoadedBase {
    pub positions: Vec<DVec3>,
    pub faces: Vec<[u32; 3]>,
    pub normals: Vec<DVec3>,
    pub manifold: Result<(), String>,
    /// The `# dispdec-settings` line, when dispdec wrote the file.
    pub settings: Option<String>,
}

/// Loads a base mesh for validation (see [`LoadedBase`]). Its vertices are never welded: a
/// base is taken exactly as written.
pub fn load_base(path: &Path) -> Result<LoadedBase, Error> {
    let mesh = load_raw(path)?;
    let settings = mesh.settings.clone();
    check_indices(path, &mesh)?;
    check_finite(path, &mesh)?;
    let (positions, faces, input_index) = compact(&mesh.positions, &mesh.faces, &[], &[]);
    if let Some(fi) = faces.iter().position(|f| repair::is_degenerate(&positions, *f)) {
        return Err(degenerate_err(path, faces[fi], fi, false, None));
    }
    let normals = if mesh.normals.len() == mesh.positions.len() { input_index.iter().map(|&v| mesh.normals[v as usize]).collect() } else { Vec::new() };
    let manifold = Topology::build(positions.len(), &faces).map(|_| ()).map_err(|e| e.to_string());
    Ok(LoadedBase { positions, faces, normals, manifold, settings })
}

/// Checks a mesh as read with the default preparation (used by the sample generator's tests).
pub fn check_and_compact(path: &Path, mesh: Mesh) -> Result<DenseMesh, Error> {
    prepare(path, mesh, &Preparation::default())
}

fn check_indices(path: &Path, mesh: &Mesh) -> Result<(), Error> {
    let n = mesh.positions.len();
    if mesh.faces.is_empty() {
        return Err(input_err(path, "the mesh has no faces"));
    }
    for (fi, f) in mesh.faces.iter().enumerate() {
        for &v in f {
            if v as usize >= n {
                return Err(input_err(path, format!("face {fi} references vertex {v}, but the file has only {n} vertices")));
            }
        }
    }
    Ok(())
}

/// Every vertex a face references has finite coordinates (whatever the options: no repair can
/// guess a coordinate).
fn check_finite(path: &Path, mesh: &Mesh) -> Result<(), Error> {
    match mesh.faces.iter().flatten().find(|&&v| !mesh.positions[v as usize].is_finite()) {
        Some(&v) => {
            let p = mesh.positions[v as usize];
            Err(input_err(path, format!("vertex {v} has a non-finite coordinate ({}, {}, {})", p.x, p.y, p.z)))
        }
        None => Ok(()),
    }
}

/// The longest a scan's bounding-box diagonal may be, in median edge lengths.
/// Why: dmax and the checks' tolerances scale with the box (SPEC: dmax by default 0.1 × the
/// diagonal), the detail with the edges. The scans in ../shared/data span 171–391 median edges,
/// the 1M-face sample 858 (`input_extent_in_edges` in a decimate report). One stray vertex far
/// off — a scanner's "no data" marker left in a face — breaks the proportion. Measured on the
/// 968-face `dispdec sample --faces 1000 --seed 3` with its vertex 458 moved away in z: valid
/// bases at 9.3e3 and 2.8e4 edges; bases with torn dense edges at 9.3e4 and 2.8e5 (the final
/// check fails, exit 1); past two minutes without an end at 9.3e5 and 1.2e19 (stopped). Ten
/// times the widest scan here, and below the first failure measured.
pub const MAX_EXTENT_IN_EDGES: f64 = 1e4;

/// The median edge length of `faces`, over every face's three edges (an interior edge counted
/// twice); `faces` is not empty.
fn median_edge(positions: &[DVec3], faces: &[[u32; 3]]) -> f64 {
    let mut edges: Vec<f64> = faces.iter().flat_map(|f| (0..3).map(move |k| (f[k], f[(k + 1) % 3]))).map(|(a, b)| positions[a as usize].distance(positions[b as usize])).collect();
    let mid = edges.len() / 2;
    *edges.select_nth_unstable_by(mid, f64::total_cmp).1
}

/// The vertex farthest from the coordinate-wise median point of `positions` (not empty).
fn farthest_from_median(positions: &[DVec3]) -> usize {
    let axis_median = |k: usize| {
        let mut c: Vec<f64> = positions.iter().map(|p| p[k]).collect();
        let m = c.len() / 2;
        *c.select_nth_unstable_by(m, f64::total_cmp).1
    };
    let centre = DVec3::new(axis_median(0), axis_median(1), axis_median(2));
    (0..positions.len()).max_by(|&a, &b| positions[a].distance_squared(centre).total_cmp(&positions[b].distance_squared(centre))).unwrap_or(0)
}

/// The scan's extent is within [`MAX_EXTENT_IN_EDGES`] of its median edge: no stray vertex far
/// off sets dmax and the checks' tolerances out of all proportion to its detail.
/// `diag` is the box's diagonal, `median` the median edge ([`median_edge`]); returns the span.
fn check_extent(path: &Path, diag: f64, median: f64, positions: &[DVec3], input_index: &[u32]) -> Result<f64, Error> {
    let ratio = diag / median;
    if ratio <= MAX_EXTENT_IN_EDGES {
        return Ok(ratio);
    }
    let far = farthest_from_median(positions);
    let p = positions[far];
    Err(input_err(
        path,
        format!(
            "its bounding box spans {ratio:.3e} median edge lengths (at most {MAX_EXTENT_IN_EDGES:.0e}): something far off sets the box, dmax and the checks' tolerances out of proportion to the scan's detail, and the guarantee cannot be checked reliably; the vertex farthest from the rest is {} at ({}, {}, {}) — a stray vertex? Remove it and its faces",
            input_index[far], p.x, p.y, p.z
        ),
    ))
}

/// How far a scan may lie from the origin, in its own bounding-box diagonals (its largest
/// coordinate's magnitude over the diagonal), before it is moved to the origin on load.
/// Why: f64 keeps 16 digits of a coordinate and the checks compare positions to 1e-12 of dmax
/// (`SAME_POINT_REL`): computed where they lie, scans in world coordinates lose that. Measured
/// on the 968-face `dispdec sample --faces 1000 --seed 3` (diagonal 2.9) moved by (t, t, t), as
/// the release of 2026-12-07 decimated it in place: a base with 4 torn dense faces at t = 3e6
/// (1.0e6 diagonals off), torn ones at 1e8, 1e9 and 1e12; the bunny moved by 1e6 (4.0e6
/// diagonals): 308 faces in 300.5 s, 6 torn (133 faces in ~11 s at its own place). Well below
/// any of that, and above every scan made at its own origin (the scans in ../shared/data lie
/// 0.32–2.94 of their diagonals from it, the turbine blade farthest; the shipped sample
/// 0.35), whose numbers stay exactly those of earlier releases.
pub const CENTRE_BEYOND_DIAGONALS: f64 = 16.0;

/// Where a scan with bounding box [lo, hi] is moved on load: its coordinates less this vector.
/// Zero for a scan within [`CENTRE_BEYOND_DIAGONALS`] of the origin. Else, on each axis whose
/// coordinates all lie within a factor of two of the box's middle, that middle; 0 on the others
/// (those lie within about a diagonal of the origin). So every coordinate's shift x − c is exact
/// (Sterbenz's lemma: y/2 ≤ x ≤ 2y makes x − y exact), and (x − c) + c gives x back, bit for bit.
pub fn centre_for(lo: DVec3, hi: DVec3) -> DVec3 {
    let (diag, far) = (lo.distance(hi), lo.abs().max(hi.abs()).max_element());
    if far <= CENTRE_BEYOND_DIAGONALS * diag {
        return DVec3::ZERO;
    }
    let axis = |lo: f64, hi: f64| {
        let mid = 0.5 * lo + 0.5 * hi;
        let within_two = |x: f64| 0.5 * mid <= x && x <= 2.0 * mid || 2.0 * mid <= x && x <= 0.5 * mid;
        if within_two(lo) && within_two(hi) {
            mid
        } else {
            0.0
        }
    };
    DVec3::new(axis(lo.x, hi.x), axis(lo.y, hi.y), axis(lo.z, hi.z))
}

/// A point moved by the scan's centre (`p` − `centre`, the scan's own frame), rounded so that
/// it comes back exactly: `(p + centre) − centre` on each moved axis. A point made in the
/// scan's frame (a midpoint placement) is written at p + centre; rounded this way, that
/// written point read back and moved is `p` itself, so a base checked is the base written.
/// Unchanged where `centre` is zero.
pub fn on_world_grid(p: DVec3, centre: DVec3) -> DVec3 {
    let axis = |x: f64, c: f64| if c == 0.0 { x } else { (x + c) - c };
    DVec3::new(axis(p.x, centre.x), axis(p.y, centre.y), axis(p.z, centre.z))
}

/// `points` moved by `by` (added), in place; nothing where `by` is zero.
pub fn translate(points: &mut [DVec3], by: DVec3) {
    if by != DVec3::ZERO {
        points.iter_mut().for_each(|p| *p += by);
    }
}

/// A copy of `points` moved by `by` ([`translate`]).
pub fn translated(points: &[DVec3], by: DVec3) -> Vec<DVec3> {
    let mut p = points.to_vec();
    translate(&mut p, by);
    p
}

/// `hint`: name `--repair`; `note`: why the faces collapsed ([`f32_grid_note`]), said instead.
fn degenerate_err(path: &Path, f: [u32; 3], fi: usize, hint: bool, note: Option<String>) -> Error {
    let how = if f[0] == f[1] || f[1] == f[2] || f[0] == f[2] { "it repeats a vertex" } else { "it has zero area" };
    let fix = match note {
        Some(n) => format!(", and {n}"),
        None if hint => " (--repair drops degenerate faces)".into(),
        None => String::new(),
    };
    input_err(path, format!("face {fi} is degenerate: {how}{fix}"))
}

/// The coarsest spacing of 32-bit floats a scan's coordinates may lie on, in its median edge
/// lengths, before a load says the file has lost its detail.
/// Why: a scan written as 32-bit floats far from its origin lies on f32's grid there (2^-23 of
/// the coordinate: 0.5 at 5.3e6). Measured on the bunny (median edge 1.47e-3) moved in y and
/// rounded to f32 (`decimate --ring-directions keep --threads 2`): at 1e3 (a grid of 0.04
/// edges) 125 faces, at 3e3 (0.17) 139, as at its place (133); at 1e4 (0.69) 297 faces with 10
/// pinched vertices; at 3e4 (1.3) 2,672 faces with 701 pinched; at a UTM place (a grid of 0.5,
/// 799 of the median edge left) its first face degenerate, and thousands more.
pub const F32_GRID_MAX_IN_EDGES: f64 = 0.25;

/// When every coordinate of `positions` is exactly a 32-bit float (a file of f32: binary PLY
/// or STL floats, or text written from them) and f32's spacing at the largest one exceeds
/// [`F32_GRID_MAX_IN_EDGES`] of the median edge `median`: what that means, for the user.
fn f32_grid_note(positions: &[DVec3], median: f64) -> Option<String> {
    let far = positions.iter().fold(0.0f64, |m, p| m.max(p.abs().max_element()));
    let far32 = far as f32;
    let grid = (f32::from_bits(far32.to_bits() + 1) - far32) as f64;
    if grid <= F32_GRID_MAX_IN_EDGES * median || !positions.iter().all(|p| p.to_array().iter().all(|&c| c as f32 as f64 == c)) {
        return None;
    }
    Some(format!(
        "its coordinates are all 32-bit floats, which {far} from the origin lie on a grid of {grid}, {:.2} of its median edge ({median:.3e}): the file has lost the scan's detail there (write it with 64-bit coordinates, or nearer the origin)",
        grid / median
    ))
}

/// The referenced vertices in input order (copies made by repair right after their input
/// vertex), faces renumbered onto them, and each one's input vertex.
fn compact(positions: &[DVec3], faces: &[[u32; 3]], copies: &[u32], copy_positions: &[DVec3]) -> (Vec<DVec3>, Vec<[u32; 3]>, Vec<u32>) {
    let n = positions.len();
    let origin = |v: u32| if (v as usize) < n { v } else { copies[v as usize - n] };
    let mut used = vec![false; n + copies.len()];
    for f in faces {
        for &v in f {
            used[v as usize] = true;
        }
    }
    let mut order: Vec<u32> = (0..used.len() as u32).filter(|&v| used[v as usize]).collect();
    order.sort_unstable_by_key(|&v| (origin(v), v));
    let mut remap = vec![u32::MAX; used.len()];
    for (i, &v) in order.iter().enumerate() {
        remap[v as usize] = i as u32;
    }
    let input_index: Vec<u32> = order.iter().map(|&v| origin(v)).collect();
    let out_pos = order.iter().map(|&v| if (v as usize) < n { positions[v as usize] } else { copy_positions[v as usize - n] }).collect();
    let out_faces = faces.iter().map(|f| f.map(|v| remap[v as usize])).collect();
    (out_pos, out_faces, input_index)
}

/// Weld, repair (if asked), compact, check.
fn prepare(path: &Path, mesh: Mesh, prep: &Preparation) -> Result<DenseMesh, Error> {
    check_indices(path, &mesh)?;
    check_finite(path, &mesh)?;
    let n = mesh.positions.len();
    let input_face_count = mesh.faces.len();
    let mut cleanup = Cleanup::default();
    let mut faces = mesh.faces;
    let mut weld_rep = Vec::new();
    if prep.weld {
        let (rep, merged) = repair::weld_vertices(&mesh.positions, &mut faces);
        cleanup.welded_vertices = merged;
        weld_rep = rep;
    }
    let (mut copies, mut copy_positions) = (Vec::new(), Vec::new());
    if prep.repair {
        let r = repair::repair_faces(&mesh.positions, faces, prep.min_component, &mut cleanup).map_err(|e| match e {
            RepairError::TooManyRemoved { removed, faces, a, b, count } => input_err(
                path,
                format!(
                    "--repair would remove {removed} of {faces} faces ({:.2} %, more than {} %) to resolve non-manifold edges (first: the edge between vertices {a} and {b}, shared by {count} faces); this is not a scan with a few defects",
                    100.0 * removed as f64 / faces as f64,
                    100.0 * repair::MAX_REPAIR_FACE_FRACTION
                ),
            ),
            RepairError::NonOrientable { a, b } => input_err(
                path,
                format!("--repair cannot wind a component consistently: it is not orientable (at the edge between vertices {a} and {b})"),
            ),
        })?;
        faces = r.faces;
        copies = r.copies;
        copy_positions = r.copy_positions;
        if faces.is_empty() {
            return Err(input_err(path, "no faces are left after --repair"));
        }
    }
    let (mut positions, faces, input_index) = compact(&mesh.positions, &faces, &copies, &copy_positions);
    if !prep.repair {
        if let Some(fi) = faces.iter().position(|f| repair::is_degenerate(&positions, *f)) {
            // Coordinates rounded far from the origin make degenerate faces by the thousand: say
            // so rather than suggest a repair that would drop them all.
            let note = f32_grid_note(&positions, median_edge(&positions, &faces));
            return Err(degenerate_err(path, faces[fi], fi, true, note));
        }
        if let Some((f, g)) = repair::first_duplicate(&faces) {
            return Err(input_err(path, format!("faces {f} and {g} are duplicates: the same three vertices (--repair drops duplicate faces)")));
        }
    }
    let (lo, hi) = bbox(positions.iter().copied());
    let median = median_edge(&positions, &faces);
    let extent_in_edges = check_extent(path, lo.distance(hi), median, &positions, &input_index)?;
    let mut warnings = mesh.warnings;
    warnings.extend(f32_grid_note(&positions, median).map(|n| format!("{}: {n}", path.display())));
    let centre = centre_for(lo, hi);
    translate(&mut positions, -centre);
    let topology = topology_checked(path, &positions, &faces, &input_index, prep, cleanup.welded_vertices)?;
    repair::count_components(&faces, &mut cleanup);
    let mut dense_of_input = vec![u32::MAX; n];
    for (d, &i) in input_index.iter().enumerate().rev() {
        dense_of_input[i as usize] = d as u32;
    }
    // A welded-away vertex maps where the vertex it was merged into does.
    for (i, &r) in weld_rep.iter().enumerate() {
        if dense_of_input[i] == u32::MAX {
            dense_of_input[i] = dense_of_input[r as usize];
        }
    }
    Ok(DenseMesh {
        positions,
        faces,
        input_index,
        dense_of_input,
        input_vertex_count: n,
        input_face_count,
        topology,
        cleanup,
        extent_in_edges,
        centre,
        warnings,
    })
}

fn topology_checked(path: &Path, positions: &[DVec3], faces: &[[u32; 3]], input_index: &[u32], prep: &Preparation, welded: usize) -> Result<Topology, Error> {
    Topology::build(positions.len(), faces).map_err(|e| {
        let msg = match &e {
            TopologyError::NonManifoldEdge { a, b, faces } => format!(
                "non-manifold edge between vertices {} and {}: shared by {} faces (first: face {}){}",
                input_index[*a as usize],
                input_index[*b as usize],
                faces.len(),
                faces[0],
                if prep.repair { "" } else { " (--repair removes the fewest faces that resolve it)" }
            ),
            TopologyError::InconsistentWinding { a, b, faces } => format!(
                "inconsistent winding: faces {} and {} both run along the edge from vertex {} to vertex {}{}",
                faces[0],
                faces[1],
                input_index[*a as usize],
                input_index[*b as usize],
                if prep.repair { "" } else { " (--repair winds each component consistently)" }
            ),
            TopologyError::NonManifoldVertex { v } => {
                let weld = if welded > 0 { "; or --no-weld: welding coincident vertices may have joined two sheets here" } else { "" };
                format!(
                    "non-manifold vertex {}: its faces form more than one fan{}{}",
                    input_index[*v as usize],
                    if prep.repair { "" } else { " (--repair splits it into one vertex per fan" },
                    if prep.repair { String::new() } else { format!("{weld})") }
                )
            }
        };
        input_err(path, msg)
    })
}

/// Faces around each vertex, as CSR arrays (start, faces).
pub fn vertex_faces(nv: usize, faces: &[[u32; 3]]) -> (Vec<u32>, Vec<u32>) {
    let mut start = vec![0u32; nv + 1];
    for f in faces {
        for &v in f {
            start[v as usize + 1] += 1;
        }
    }
    for i in 0..nv {
        start[i + 1] += start[i];
    }
    let mut fill = start.clone();
    let mut vf = vec![0u32; start[nv] as usize];
    for (fi, f) in faces.iter().enumerate() {
        for &v in f {
            vf[fill[v as usize] as usize] = fi as u32;
            fill[v as usize] += 1;
        }
    }
    (start, vf)
}

/// A dense mesh as the checks use it: unit face normals, faces around each vertex (CSR) and the
/// pinched vertices, whose own face normals admit no common direction.
#[derive(Clone)]
pub struct DenseData {
    pub pos: Vec<DVec3>,
    pub faces: Vec<[u32; 3]>,
    pub normal: Vec<DVec3>,
    pub vf_start: Vec<u32>,
    pub vf: Vec<u32>,
    pub pinched: Vec<bool>,
    /// (constant mode) Dense edges (lower, higher id), ascending, whose points the scan itself
    /// cannot map: exempt from continuity, their triangles from orientation (SPEC §1's exempt
    /// vertices, for the points of an edge). Empty in interpolated mode.
    pub exempt_edges: Vec<(u32, u32)>,
}

/// Whether one of `normals` has a positive dot product with all of them: with constant normals,
/// a scan point on these faces only (a vertex's, an edge's inner points) is then mapped on the
/// scan itself, at d = 0.
fn one_face_normal_sees_all(normals: &[DVec3]) -> bool {
    normals.iter().any(|n| normals.iter().all(|ni| n.dot(*ni) > 0.0))
}

impl DenseData {
    pub fn new(pos: &[DVec3], faces: &[[u32; 3]]) -> DenseData {
        let nv = pos.len();
        let normal: Vec<DVec3> = faces
            .iter()
            .map(|f| face_normal(pos[f[0] as usize], pos[f[1] as usize], pos[f[2] as usize]))
            .collect();
        let (vf_start, vf) = vertex_faces(nv, faces);
        let pinched = (0..nv)
            .into_par_iter()
            .map(|v| {
                let ns: Vec<DVec3> =
                    vf[vf_start[v] as usize..vf_start[v + 1] as usize].iter().map(|&f| normal[f as usize]).collect();
                let mean = ns.iter().copied().sum::<DVec3>().normalize_or_zero();
                if ns.iter().all(|n| n.dot(mean) > 0.0) {
                    return false;
                }
                maxmin_direction(&ns).is_none()
            })
            .collect();
        DenseData { pos: pos.to_vec(), faces: faces.to_vec(), normal, vf_start, vf, pinched, exempt_edges: Vec::new() }
    }

    pub fn faces_of(&self, v: u32) -> &[u32] {
        &self.vf[self.vf_start[v as usize] as usize..self.vf_start[v as usize + 1] as usize]
    }
    /// Unit normals of the faces around `v` (condition (4) of a vertex).
    pub fn vertex_normals(&self, v: u32, out: &mut Vec<DVec3>) {
        out.clear();
        out.extend(self.faces_of(v).iter().map(|&f| self.normal[f as usize]));
    }
    /// Constant-normal mode (SPEC §1): the vertices (not pinched) that no base can map, because
    /// on the scan itself none of their own faces' normals sees all of their faces, become
    /// exempt like pinched vertices. Returns how many were added.
    pub fn exempt_for_constant_mode(&mut self) -> usize {
        // An edge's inner points lie on its own (one or two) faces only: with constant
        // normals they are mapped on the scan itself iff one of those faces' normals sees all of
        // them, as for a vertex. Two faces folded by more than 90° (n1·n2 ≤ 0, a sharp crease or
        // a thin fin's edge) leave the edge's points without a solution on the scan: no decimated
        // base of it can be continuous there either.
        let mut edges = Vec::new();
        let mut normals = Vec::new();
        for f in &self.faces {
            for k in 0..3 {
                let (a, b) = (f[k], f[(k + 1) % 3]);
                if a > b {
                    continue;
                }
                self.edge_normals(a, b, &mut normals);
                if !one_face_normal_sees_all(&normals) {
                    edges.push((a, b));
                }
            }
        }
        edges.sort_unstable();
        edges.dedup();
        self.exempt_edges = edges;
        let mut added = 0;
        for v in 0..self.pos.len() {
            if self.pinched[v] {
                continue;
            }
            self.vertex_normals(v as u32, &mut normals);
            if !one_face_normal_sees_all(&normals) {
                self.pinched[v] = true;
                added += 1;
            }
        }
        added
    }
    /// Whether the edge (a, b) (either order) is exempt ([`DenseData::exempt_edges`]).
    pub fn is_exempt_edge(&self, a: u32, b: u32) -> bool {
        !self.exempt_edges.is_empty() && self.exempt_edges.binary_search(&(a.min(b), a.max(b))).is_ok()
    }
    /// Whether dense triangle `f` has an exempt edge (it cannot be drawn: it is skipped, like a
    /// triangle at a pinched vertex).
    pub fn has_exempt_edge(&self, f: u32) -> bool {
        let t = self.faces[f as usize];
        !self.exempt_edges.is_empty() && (0..3).any(|k| self.is_exempt_edge(t[k], t[(k + 1) % 3]))
    }
    /// The (one or two) faces on edge (a, b).
    pub fn edge_faces(&self, a: u32, b: u32) -> impl Iterator<Item = u32> + '_ {
        self.faces_of(a).iter().copied().filter(move |&f| self.faces[f as usize].contains(&b))
    }
    /// Unit normals of the (one or two) faces on edge (a, b).
    pub fn edge_normals(&self, a: u32, b: u32, out: &mut Vec<DVec3>) {
        out.clear();
        out.extend(self.edge_faces(a, b).map(|f| self.normal[f as usize]));
    }
}


// ---------------------------------------------------------------------------------------------
// Output

/// Writes `bytes` to `path` atomically: a temporary file beside it, then a rename, so that a
/// failed run leaves no partial file. A target that exists and is not a regular file (a device
/// such as `/dev/null`, a FIFO) is written in place: renaming over it would replace it.
pub fn write_atomic(path: &Path, bytes: &[u8]) -> Result<(), Error> {
    use std::io::Write;
    let out_err = |e: std::io::Error| Error::Output { path: path.display().to_string(), msg: e.to_string() };
    if let Ok(meta) = std::fs::metadata(path) {
        if !meta.is_file() {
            if meta.is_dir() {
                return Err(Error::Output { path: path.display().to_string(), msg: "is a directory".into() });
            }
            let mut f = std::fs::OpenOptions::new().write(true).open(path).map_err(out_err)?;
            return f.write_all(bytes).map_err(out_err);
        }
    }
    let dir = path.parent().filter(|p| !p.as_os_str().is_empty()).unwrap_or(Path::new("."));
    let name = path.file_name().map(|s| s.to_string_lossy().to_string()).unwrap_or_else(|| "out".into());
    let tmp = dir.join(format!(".{name}.tmp{}", std::process::id()));
    let res = (|| -> std::io::Result<()> {
        let mut f = std::fs::File::create(&tmp)?;
        f.write_all(bytes)?;
        f.sync_all()?;
        std::fs::rename(&tmp, path)
    })();
    res.map_err(|e| {
        let _ = std::fs::remove_file(&tmp);
        out_err(e)
    })
}

/// OBJ text with `v`, one `vn` per `v`, and `f v//vn` (no `vn` and `f v` when `normals` is
/// empty). Header lines become comments; a line that already is one (the settings) stays as it is.
pub fn obj_with_normals(positions: &[DVec3], normals: &[DVec3], faces: &[[u32; 3]], header: &str) -> String {
    obj_text(positions, normals, faces, None, header)
}

/// The same with one `vt` per face corner (`uv(face, corner)`) and `f v/vt/vn`: what other tools
/// need to sample a map where dispdec wrote it.
pub fn obj_with_uvs(positions: &[DVec3], normals: &[DVec3], faces: &[[u32; 3]], uv: impl Fn(u32, usize) -> (f64, f64), header: &str) -> String {
    obj_text(positions, normals, faces, Some(&uv), header)
}

/// An OBJ of some of a mesh's faces, one object (`o name`) per group in the order given (an
/// empty group is left out), with only the vertices those faces use, in the order first used.
/// Blender and MeshLab open each group as an object of its own, in the mesh's coordinates, so
/// that it lies on the mesh it was taken from.
pub fn obj_groups(positions: &[DVec3], faces: &[[u32; 3]], groups: &[(&str, &[u32])], header: &str) -> String {
    use std::fmt::Write;
    let mut s = String::new();
    write_header(&mut s, header);
    let mut index = vec![u32::MAX; positions.len()];
    let mut used = 0u32;
    for &(_, list) in groups {
        for &f in list {
            for v in faces[f as usize] {
                if index[v as usize] == u32::MAX {
                    index[v as usize] = used;
                    used += 1;
                    let p = positions[v as usize];
                    let _ = writeln!(s, "v {} {} {}", p.x, p.y, p.z);
                }
            }
        }
    }
    for &(name, list) in groups.iter().filter(|g| !g.1.is_empty()) {
        let _ = writeln!(s, "o {name}");
        for &f in list {
            let [a, b, c] = faces[f as usize].map(|v| index[v as usize] + 1);
            let _ = writeln!(s, "f {a} {b} {c}");
        }
    }
    s
}

/// An OBJ's header: each non-empty line of `header` as a comment (`# ` added where missing).
fn write_header(s: &mut String, header: &str) {
    use std::fmt::Write;
    for line in header.lines().filter(|l| !l.is_empty()) {
        if line.starts_with('#') {
            let _ = writeln!(s, "{line}");
        } else {
            let _ = writeln!(s, "# {line}");
        }
    }
}

fn obj_text(positions: &[DVec3], normals: &[DVec3], faces: &[[u32; 3]], uv: Option<&dyn Fn(u32, usize) -> (f64, f64)>, header: &str) -> String {
    use std::fmt::Write;
    let mut s = String::with_capacity(96 * (positions.len() + faces.len()));
    write_header(&mut s, header);
    // Shortest round-trip decimal: reading the file back gives the very numbers checked.
    for p in positions {
        let _ = writeln!(s, "v {} {} {}", p.x, p.y, p.z);
    }
    for n in normals {
        let _ = writeln!(s, "vn {} {} {}", n.x, n.y, n.z);
    }
    if let Some(uv) = uv {
        for f in 0..faces.len() as u32 {
            for k in 0..3 {
                let (u, v) = uv(f, k);
                let _ = writeln!(s, "vt {u} {v}");
            }
        }
    }
    for (i, f) in faces.iter().enumerate() {
        let [a, b, c] = f.map(|v| v + 1);
        let t = 3 * i + 1;
        let _ = match (uv.is_some(), normals.is_empty()) {
            (true, _) => writeln!(s, "f {a}/{t}/{a} {b}/{}/{b} {c}/{}/{c}", t + 1, t + 2),
            (false, true) => writeln!(s, "f {a} {b} {c}"),
            (false, false) => writeln!(s, "f {a}//{a} {b}//{b} {c}//{c}"),
        };
    }
    s
}

/// Writes several outputs, each atomically; if one fails, those already written are removed.
pub fn write_all_atomic(files: &[(&Path, &[u8])]) -> Result<(), Error> {
    for (i, (p, b)) in files.iter().enumerate() {
        if let Err(e) = write_atomic(p, b) {
            for (q, _) in &files[..i] {
                let _ = std::fs::remove_file(q);
            }
            return Err(e);
        }
    }
    Ok(())
}

/// The bytes as they go to `path`: gzip-compressed when its name ends in `.gz`.
pub fn maybe_gzip(path: &Path, bytes: Vec<u8>) -> Vec<u8> {
    if !path.to_string_lossy().ends_with(".gz") {
        return bytes;
    }
    use std::io::Write;
    let mut enc = flate2::GzBuilder::new().write(Vec::new(), flate2::Compression::best());
    // Writing to memory cannot fail.
    enc.write_all(&bytes).expect("gzip to memory");
    enc.finish().expect("gzip to memory")
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Two groups of a strip of four triangles; vertex 5 is used by no group's face.
    ///
    /// ```text
    ///   3-----4-----5
    ///   | \ 1 | \ 3 |
    ///   | 0 \ | 2 \ |
    ///   0-----1-----2
    /// ```
    #[test]
    fn obj_groups_keeps_only_the_vertices_its_faces_use() {
        let positions: Vec<DVec3> = [(0., 0.), (1., 0.), (2., 0.), (0., 1.), (1., 1.), (2., 1.)].map(|(x, y)| DVec3::new(x, y, 0.0)).to_vec();
        let faces = [[0, 1, 3], [1, 4, 3], [1, 2, 4], [2, 5, 4]];
        let text = obj_groups(&positions, &faces, &[("torn", &[2, 0]), ("none", &[]), ("flipped", &[1])], "two kinds\n");
        let want = "# two kinds\nv 1 0 0\nv 2 0 0\nv 1 1 0\nv 0 0 0\nv 0 1 0\no torn\nf 1 2 3\nf 4 1 5\no flipped\nf 1 3 5\n";
        assert_eq!(text, want);
        // Read back as a mesh: the same triangles, in the scan's coordinates.
        let dir = std::env::temp_dir().join(format!("dispdec-groups-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let p = dir.join("g.obj");
        std::fs::write(&p, &text).unwrap();
        let m = load_raw(&p).unwrap();
        assert_eq!(m.faces.len(), 3);
        let corner = |f: usize, k: usize| m.positions[m.faces[f][k] as usize];
        assert_eq!((corner(0, 0), corner(1, 0), corner(2, 2)), (positions[1], positions[0], positions[3]));
        std::fs::remove_dir_all(&dir).unwrap();
    }

    /// A 4 × 4 grid of unit squares, two triangles each, flat in z = 0:
    ///
    /// ```text
    ///   20--21--22--23--24
    ///   | / | / | / | / |
    ///   15--16--17--18--19        median edge 1 (sides; diagonals √2)
    ///   | / | / | / | / |         diagonal of the box √32 ≈ 5.7
    ///   10--11--12--13--14
    ///   | / | / | / | / |         vertex 12 lifted to z = h: a spike
    ///   5---6---7---8---9
    ///   | / | / | / | / |
    ///   0---1---2---3---4
    /// ```
    fn grid_with_spike(h: f64) -> Mesh {
        let mut positions: Vec<DVec3> = (0..25).map(|i| DVec3::new((i % 5) as f64, (i / 5) as f64, 0.0)).collect();
        positions[12].z = h;
        let mut faces = Vec::new();
        for y in 0..4u32 {
            for x in 0..4u32 {
                let v = 5 * y + x;
                faces.push([v, v + 1, v + 6]);
                faces.push([v, v + 6, v + 5]);
            }
        }
        Mesh { positions, faces, ..Mesh::default() }
    }

    #[test]
    fn a_stray_vertex_far_off_is_refused_and_named() {
        let path = Path::new("spike.obj");
        // Flat: the box's diagonal over the median edge, √32 / 1.
        let flat = check_and_compact(path, grid_with_spike(0.0)).unwrap();
        assert!((flat.extent_in_edges - 32f64.sqrt()).abs() < 1e-12, "{}", flat.extent_in_edges);
        // A spike within the limit (its 8 edges are ~h long, the median stays 1): accepted.
        let tall = check_and_compact(path, grid_with_spike(0.5 * MAX_EXTENT_IN_EDGES)).unwrap();
        assert!(tall.extent_in_edges > 0.49 * MAX_EXTENT_IN_EDGES && tall.extent_in_edges <= MAX_EXTENT_IN_EDGES);
        // Beyond it: refused, naming the file, the span and the vertex (its input number).
        let err = check_and_compact(path, grid_with_spike(-1.25e18)).unwrap_err().to_string();
        assert!(err.contains("spike.obj") && err.contains("1.250e18 median edge lengths") && err.contains("is 12 at (2, 2, -1250000000000000000)"), "{err}");
    }

    #[test]
    fn a_scan_far_from_the_origin_is_moved_to_it_and_back_exactly() {
        // The grid (x, y in 0..4, z = 0 but for a spike of 1 at its middle) moved by `t`.
        let moved = |t: DVec3| {
            let mut m = grid_with_spike(1.0);
            m.positions.iter_mut().for_each(|p| *p += t);
            m
        };
        let path = Path::new("far.obj");
        // Within 16 diagonals of the origin: not moved, every coordinate as read.
        let t = DVec3::new(CENTRE_BEYOND_DIAGONALS * 33f64.sqrt() - 4.0, 0.0, 0.0);
        let near = check_and_compact(path, moved(t)).unwrap();
        assert_eq!(near.centre, DVec3::ZERO);
        assert_eq!(near.positions, moved(t).positions);
        // A UTM-like place (easting, northing; z near 0): x and y moved by their box's middle,
        // z (−0.25..0.75) left; each coordinate moved exactly and back.
        let t = DVec3::new(512_345.678_9, 5_300_000.123_4, -0.25);
        let (input, far) = (moved(t), check_and_compact(path, moved(t)).unwrap());
        assert_eq!(far.centre, DVec3::new(input.positions[0].x + 2.0, input.positions[0].y + 2.0, 0.0), "the box's middle in x and y");
        for (p, q) in far.positions.iter().zip(&input.positions) {
            assert!(p.abs().max_element() <= 2.0 && *p + far.centre == *q, "{p} + {} != {q}", far.centre);
        }
        assert_eq!(far.world_positions(), input.positions);
        // A midpoint made in the moved frame, rounded to what the file will hold: written at
        // p + centre, read back and moved, it is p again.
        let m = on_world_grid(0.5 * (far.positions[0] + far.positions[6]), far.centre);
        assert_eq!((m + far.centre) - far.centre, m);
        assert!(m.distance(0.5 * (far.positions[0] + far.positions[6])) < 1e-9);
        assert_eq!(on_world_grid(DVec3::new(0.1, -0.0, 3.0), DVec3::ZERO).to_array().map(f64::to_bits), [0.1f64, -0.0, 3.0].map(f64::to_bits));
    }

    #[test]
    fn a_scan_of_32_bit_floats_far_off_is_said_to_have_lost_its_detail() {
        // The grid (edges of 1) at 5e6, where f32's grid is 0.5 (half an edge): every
        // coordinate an f32, so the file says so; at 1e6 (a grid of 0.0625) it does not, nor
        // at 5e6 with a coordinate that is no f32 (a file of 64-bit values).
        let at = |t: f64, nudge: f64| {
            let mut m = grid_with_spike(1.0);
            m.positions.iter_mut().for_each(|p| *p += DVec3::new(t, t, 0.0));
            m.positions[0].x += nudge;
            check_and_compact(Path::new("f32.ply"), m).unwrap().warnings
        };
        let w = at(5e6, 0.0);
        assert!(w.len() == 1 && w[0].contains("f32.ply: its coordinates are all 32-bit floats, which 5000004 from the origin lie on a grid of 0.5, 0.50 of its median edge"), "{w:?}");
        assert!(at(1e6, 0.0).is_empty());
        assert!(at(5e6, 0.1).is_empty());
        // Rounded to f32 far off, a fine scan's faces collapse: the error says why.
        let mut fine = grid_with_spike(1.0);
        fine.positions.iter_mut().for_each(|p| *p = (*p * 0.2 + DVec3::splat(5.3e6)).as_vec3().as_dvec3());
        let e = check_and_compact(Path::new("utm.ply"), fine).unwrap_err().to_string();
        assert!(e.contains("is degenerate") && e.contains("are all 32-bit floats") && !e.contains("--repair"), "{e}");
    }

    #[test]
    fn atomic_write_keeps_special_files() {
        // Writing to /dev/null must not replace the device with a regular file.
        write_atomic(Path::new("/dev/null"), b"hello").unwrap();
        let meta = std::fs::metadata("/dev/null").unwrap();
        assert!(!meta.is_file(), "/dev/null must stay a device");
        let dir = std::env::temp_dir().join(format!("dispdec-atomic-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let p = dir.join("a.txt");
        write_atomic(&p, b"one").unwrap();
        write_atomic(&p, b"two").unwrap();
        assert_eq!(std::fs::read(&p).unwrap(), b"two");
        assert_eq!(std::fs::read_dir(&dir).unwrap().count(), 1, "no temporary file left");
        assert!(write_atomic(&dir, b"x").is_err(), "a directory is refused");
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn tristrip_decoding_alternates_winding() {
        let dir = std::env::temp_dir().join(format!("dispdec-strip-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let p = dir.join("s.ply");
        // 0--2--4
        // | /| /|     strip 0 1 2 3 4 5 gives (0,1,2) (2,1,3) (2,3,4) (4,3,5)
        // 1--3--5
        let text = "ply\nformat ascii 1.0\nelement vertex 6\nproperty float x\nproperty float y\nproperty float z\n\
                    element tristrips 1\nproperty list int int vertex_indices\nend_header\n\
                    0 1 0\n0 0 0\n1 1 0\n1 0 0\n2 1 0\n2 0 0\n6 0 1 2 3 4 5\n";
        std::fs::write(&p, text).unwrap();
        let m = load_raw(&p).unwrap();
        assert_eq!(m.faces, vec![[0, 1, 2], [2, 1, 3], [2, 3, 4], [4, 3, 5]]);
        let d = check_and_compact(&p, m).unwrap();
        assert_eq!(d.faces.len(), 4);
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
