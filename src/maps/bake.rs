//! Baking the displacement map (SPEC §5): d sampled over the atlas of the base triangles (the
//! fold image's atlas), as the guarantee's inverse. Every texel of a face's side of its cell —
//! chart and gutter — stands for a point X of that face (gutter texels for the nearest point of
//! the chart). The fold image's rasterisation says which dense triangle's image covers X; d is
//! where the line X + d·N(X) meets that triangle (exact line–plane intersection). Not the
//! smallest-|d| crossing of the whole scan, which can lie on another sheet. Texels no dense
//! triangle covers (the scan's holes) have no d. Gutters hold their chart's own values, so a
//! bilinear lookup at a chart border is right.
//!
//! Three conventions ([`Kind`]): `scalar`, d along the unnormalised N(X) (SPEC §1);
//! `normalized`, d·|N(X)|, the distance along the normalised interpolated normal (what engines
//! do when they displace a tessellated mesh along interpolated vertex normals); `vector`, the
//! object-space vector d·N(X).

use crate::geometry::bvh::Bvh;
use crate::guarantee::{Map, NormalMode};
use crate::maps::fold::Atlas;
use crate::geometry::{clamp_bary, face_normal, interpolate_direction};
use crate::mesh::DenseData;
use crate::topology::Topology;
use crate::validate::Base;
use crate::Error;
use glam::DVec3;
use rayon::prelude::*;
use std::path::Path;

/// What a texel of the map holds (SPEC §5).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Kind {
    /// d, along the unnormalised interpolated direction N(X) (dispdec's own).
    #[default]
    Scalar,
    /// d·|N(X)|: the distance along the normalised interpolated normal.
    Normalized,
    /// The object-space vector d·N(X), three channels.
    Vector,
}

impl Kind {
    pub fn name(self) -> &'static str {
        match self {
            Kind::Scalar => "scalar",
            Kind::Normalized => "normalized",
            Kind::Vector => "vector",
        }
    }

    /// One sentence for file headers: how a tool applies the map.
    pub fn convention(self) -> &'static str {
        match self {
            Kind::Scalar => "x = X + d * N(X), N(X) = a*N1 + b*N2 + c*N3 (vertex normals, not renormalised)",
            Kind::Normalized => "x = X + d * normalize(N(X)), N(X) interpolated from the vertex normals",
            Kind::Vector => "x = X + (R, G, B), object space",
        }
    }
}

/// A baked displacement map: d per texel, row-major from the top; NaN where no chart is, or
/// where no dense triangle covers the point (a hole of the scan).
#[derive(Clone, Debug)]
pub struct DispMap {
    pub atlas: Atlas,
    pub d: Vec<f32>,
    /// N(X) per texel (the direction d is measured along), as baked; empty when read from a
    /// file (only `scalar` maps are read back).
    pub dir: Vec<[f32; 3]>,
    /// A difference between neighbouring texels above this is a jump, not a slope (see
    /// [`DispMap::sample`]): JUMP_FRACTION of the range of d.
    pub jump: f64,
}

/// Neighbouring texels differing by more than this fraction of the map's range of d are not
/// blended. Why: on a valid base d varies slowly within a chart; a step of 5 % of its whole range
/// between adjacent texels is a crease or another sheet.
pub const JUMP_FRACTION: f64 = 0.05;

/// A crossing of the line X + d·N(X) with the scan belongs to X when the crossing point's own
/// primary solution lies this close to X (a fraction of dmax). Why: both are solved in f64;
/// 1e-6 of dmax is far below a texel and far above rounding.
const BACK_PROJECTION_TOLERANCE: f64 = 1e-6;

/// A line meets a dense triangle found by its image when the crossing's barycentric
/// coordinates in it are at least this. Why: a texel can take its triangle from a neighbour up
/// to OWNER_SEARCH texels away, so the crossing may lie a little outside; far outside, the
/// plane of a steep triangle is met far from the scan, and the exact crossing search decides.
const OWNER_BARY_SLACK: f64 = -0.25;

/// Where the line X + d·dir meets dense face `df` (its plane, near the triangle), within dmax.
fn line_meets(dense: &DenseData, df: u32, x: DVec3, dir: DVec3, dmax: f64) -> Option<f64> {
    let q = dense.faces[df as usize].map(|v| dense.pos[v as usize]);
    let nt = dense.normal[df as usize];
    let den = nt.dot(dir);
    if den.abs() <= 1e-12 * dir.length() {
        return None;
    }
    let d = nt.dot(q[0] - x) / den;
    if !(d.is_finite() && d.abs() <= dmax * (1.0 + 1e-9)) {
        return None;
    }
    let b = crate::geometry::barycentric(x + d * dir, q[0], q[1], q[2])?;
    b.iter().all(|&c| c >= OWNER_BARY_SLACK).then_some(d)
}

/// How far (texels) a texel looks for a covering dense triangle when none covers its own
/// centre. Why: pieces of dense triangles that straddle two base faces leave specks one or two
/// texels wide along chart diagonals and borders; the gutter is two texels wide.
const OWNER_SEARCH: i64 = 3;

fn jump_of(d: &[f32]) -> f64 {
    let (lo, hi) = d.iter().filter(|v| !v.is_nan()).fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), &v| (a.min(v as f64), b.max(v as f64)));
    if lo.is_finite() {
        JUMP_FRACTION * (hi - lo)
    } else {
        f64::INFINITY
    }
}

/// The sidecar of a map (`DISP.ext.json`): its kind and convention, and for a 16-bit PNG its
/// quantisation, d = offset + scale · value.
#[derive(Clone, Debug, serde::Serialize, serde::Deserialize, PartialEq)]
pub struct Quantisation {
    pub scale: f64,
    pub offset: f64,
    pub faces: u32,
    pub size: u32,
    /// PNG value of texels without a displacement (outside charts, or no crossing); float
    /// formats mark them NaN.
    pub missing: u16,
    #[serde(default)]
    pub kind: Kind,
    #[serde(default)]
    pub convention: String,
}

const SOURCE_OUTSIDE: u8 = 0;
const SOURCE_IMAGE: u8 = 1;
const SOURCE_GAP: u8 = 2;
const SOURCE_NONE: u8 = 3;

/// Where the texels' d came from (texels of charts and gutters).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize)]
pub struct BakeSources {
    /// The dense triangle whose image covers X: the guarantee's inverse.
    pub image: usize,
    /// A gap of the projection (no scan point maps to X): the d of the nearest covered texel of
    /// the same face ([`fill_gaps`]), else the nearest crossing of the line where the scan faces
    /// the way N does.
    pub gap: usize,
    /// Of those, the ones filled from the crossing: no covered texel of their face within
    /// GAP_FILL_RADIUS, or its d would put their point off the scan.
    pub gap_from_crossing: usize,
    /// No crossing within dmax (a hole of the scan): no d.
    pub none: usize,
}

/// Bakes every texel of `base`'s atlas from the dense triangles' images: `maps[v]` is dense
/// vertex v's primary solution over the whole base (the validator's projection); `topo` is the
/// scan's topology (where its holes are).
pub fn bake(dense: &DenseData, topo: &Topology, base: &Base, maps: &[Option<Map>], mode: NormalMode, dmax: f64, size: u32) -> (DispMap, BakeSources) {
    let owners = crate::maps::fold::cover_owners(dense, base, maps, mode, dmax, size);
    let atlas = owners.atlas;
    let n = atlas.size;
    // The covering dense triangles nearest a texel on face f's chart, within OWNER_SEARCH texels.
    let owners_at = |f: u32, px: i64, py: i64| -> Option<[u32; 2]> {
        nearest_texel(n as i64, px, py, 0..=OWNER_SEARCH, RingStop::FirstRing, |x, y| {
            let o = owners.owner[(y * n as i64 + x) as usize];
            (o[0] != u32::MAX && atlas.texel(x as u32, y as u32).map(|t| t.0) == Some(f)).then_some(o)
        })
    };
    let bvh = Bvh::build(&dense.pos, &dense.faces);
    let base_index = crate::validate::BaseIndex::new(base);
    let texels: Vec<(f32, [f32; 3], u8)> = (0..n * n)
        .into_par_iter()
        .map_init(|| std::cell::RefCell::new((Vec::new(), crate::guarantee::Scratch::default(), Vec::new(), crate::guarantee::Tris::default())), |scratch, i| {
            let (px, py) = (i % n, i / n);
            let Some((f, bary, x, dir)) = texel_point_bary(&atlas, base, mode, px, py) else { return (f32::NAN, [f32::NAN; 3], SOURCE_OUTSIDE) };
            let dir32 = [dir.x as f32, dir.y as f32, dir.z as f32];
            // Gutter texels take the owner at their nearest chart point.
            let (cx, cy) = atlas.position(f, bary[1], bary[2]);
            // Where the image folds two sheets cover X: the smaller |d|, as for primaries.
            let on_owner = owners_at(f, cx.floor() as i64, cy.floor() as i64).and_then(|o| {
                let (a, b) = (line_meets(dense, o[0], x, dir, dmax), line_meets(dense, o[1], x, dir, dmax));
                match (a, b) {
                    (Some(a), Some(b)) => Some(if b.abs() < a.abs() { b } else { a }),
                    (a, b) => a.or(b),
                }
            });
            if let Some(d) = on_owner {
                return (d as f32, dir32, SOURCE_IMAGE);
            }
            // No covering triangle drawn near X: the crossings of the line, nearest first. The
            // one whose point maps back to X is X's own (a speck where pieces of straddling
            // dense triangles meet); with none, X is in a gap of the projection (no scan point
            // maps there, e.g. where it jumps between overlapping shells): [`fill_gaps`] gives it
            // the nearest covered texel's d, and where none is near, the nearest crossing where
            // the scan faces the way N does (kept here).
            let (hits, scratch, near, tris) = &mut *scratch.borrow_mut();
            bvh.crossings(&dense.pos, &dense.faces, x, dir, -dmax, dmax, hits);
            hits.retain(|h| dense.normal[h.1 as usize].dot(dir) > 0.0);
            hits.sort_by(|a, b| a.0.abs().total_cmp(&b.0.abs()).then(a.1.cmp(&b.1)));
            let own = hits.iter().copied().find(|&(t, df)| {
                let m = crate::validate::primary_global(&base_index, x + t * dir, &[dense.normal[df as usize]], mode, dmax, true, scratch, near, tris);
                m.is_some_and(|m| {
                    let c = base.faces[m.face as usize].map(|v| base.positions[v as usize]);
                    interpolate_direction(&c, &m.bary).distance(x) <= BACK_PROJECTION_TOLERANCE * dmax
                })
            });
            match (own, hits.first()) {
                (Some((t, _)), _) => (t as f32, dir32, SOURCE_IMAGE),
                (None, Some(&(t, _))) => (t as f32, dir32, SOURCE_GAP),
                (None, None) => (f32::NAN, dir32, SOURCE_NONE),
            }
        })
        .collect();
    let (texels, filled) = fill_gaps(&atlas, base, mode, dense, topo, &bvh, texels);
    let mut sources = BakeSources::default();
    for t in &texels {
        match t.2 {
            SOURCE_IMAGE => sources.image += 1,
            SOURCE_GAP => sources.gap += 1,
            SOURCE_NONE => sources.none += 1,
            _ => {}
        }
    }
    sources.gap_from_crossing = sources.gap - filled;
    let d: Vec<f32> = texels.iter().map(|t| t.0).collect();
    let dir = texels.iter().map(|t| t.1).collect();
    let jump = jump_of(&d);
    (DispMap { atlas, d, dir, jump }, sources)
}

/// How far (texels) a texel in a gap of the projection looks for a texel of its own face's side
/// of the cell that a dense triangle's image covers. Why: the gaps worth filling so are a few
/// texels wide (at a base vertex standing on a spike of the scan, whose triangles all map onto
/// the other faces around it: wider than OWNER_SEARCH on the bunny at 2048); a value from
/// farther away would not continue the scan.
const GAP_FILL_RADIUS: i64 = 24;

/// A gap texel takes its covered neighbour's d only where the point it then stands for lies
/// within this many mean dense edge lengths of the scan. Why: the point is then on the scan well
/// within its sampling (the bunny's spike corner: 0.05), while a fill over a hole of the scan,
/// hovering above it, is refused (1.0 let 1,390 more bunny texels through and tripled the
/// level-5 rebuild's Hausdorff distance, 0.196 % → 0.607 %).
const GAP_FILL_TOLERANCE_EDGES: f64 = 0.25;

/// How far (mean dense edge lengths) a refused gap texel's point looks for the scan face nearest
/// it, to tell a point over a hole of the scan (nearest a boundary face) from one off the scan
/// elsewhere. Why: beyond a few edges from any scan face the point is not at a hole's rim, and
/// the texel keeps its crossing as before.
const GAP_HOLE_SEARCH_EDGES: f64 = 8.0;

/// Gives a texel in a gap of the projection the d of the nearest texel of the same face that a
/// dense triangle's image covers (the smallest squared distance, then the lowest index), where
/// the point X + d·N(X) then lies on the scan (GAP_FILL_TOLERANCE_EDGES), so that the map
/// continues the scan's own values across the gap instead of jumping to a crossing of the line
/// on another sheet (on the bunny's 157-face base a chart corner held d = −0.022 where the scan
/// has 0, and a bilinear lookup there rebuilt a point in the air). Where that point would hover
/// over a hole of the scan instead (the scan face nearest it has an edge on the scan's boundary)
/// the texel holds no d, as a hole's texels with no crossing do: the crossing there lies on
/// another sheet (on the bunny's 151-face base, d ≈ −0.022 at the rim of a bottom hole, and
/// Blender's bilinear lookup across it rebuilt a point 2.35 % of the diagonal off the scan).
/// Other gaps keep the nearest crossing; returns how many were filled from a neighbour.
fn fill_gaps(atlas: &Atlas, base: &Base, mode: NormalMode, dense: &DenseData, topo: &Topology, bvh: &Bvh, texels: Vec<(f32, [f32; 3], u8)>) -> (Vec<(f32, [f32; 3], u8)>, usize) {
    let n = atlas.size as i64;
    let face_of = |x: i64, y: i64| atlas.texel_any(x as u32, y as u32).map(|t| t.0);
    let edges: f64 = dense.faces.iter().map(|f| (0..3).map(|k| dense.pos[f[k] as usize].distance(dense.pos[f[(k + 1) % 3] as usize])).sum::<f64>()).sum();
    let mean_edge = edges / (3 * dense.faces.len()).max(1) as f64;
    let tolerance = GAP_FILL_TOLERANCE_EDGES * mean_edge;
    // (texel, its d, SOURCE_GAP: filled from a neighbour, or SOURCE_NONE: over a hole)
    let filled: Vec<(usize, f32, u8)> = (0..texels.len())
        .into_par_iter()
        .filter(|&i| texels[i].2 == SOURCE_GAP)
        .map_init(Vec::new, |near, i| {
            let (px, py) = (i as i64 % n, i as i64 / n);
            let f = face_of(px, py)?;
            let j = nearest_texel(n, px, py, 1..=GAP_FILL_RADIUS, RingStop::Nearest, |x, y| {
                let j = (y * n + x) as usize;
                (texels[j].2 == SOURCE_IMAGE && face_of(x, y) == Some(f)).then_some(j)
            })?;
            let d = texels[j].0;
            let (_, _, x, dir) = texel_point_bary(atlas, base, mode, px as u32, py as u32)?;
            let p = x + d as f64 * dir;
            bvh.near(&dense.pos, &dense.faces, p, tolerance, near);
            if !near.is_empty() {
                return Some((i, d, SOURCE_GAP));
            }
            bvh.near(&dense.pos, &dense.faces, p, GAP_HOLE_SEARCH_EDGES * mean_edge, near);
            near.first().is_some_and(|&(_, g)| topo.face_on_boundary(g)).then_some((i, f32::NAN, SOURCE_NONE))
        })
        .flatten()
        .collect();
    let count = filled.iter().filter(|t| t.2 == SOURCE_GAP).count();
    let mut texels = texels;
    for (i, d, source) in filled {
        texels[i].0 = d;
        texels[i].2 = source;
    }
    (texels, count)
}

/// Where a ring search stops: at the end of the first ring that holds an accepted texel, or
/// once no farther ring can hold a nearer one (the exact nearest).
#[derive(Clone, Copy)]
enum RingStop {
    FirstRing,
    Nearest,
}

/// The texel nearest (px, py) of the n × n atlas that `keep` accepts, searched ring by
/// ring of Chebyshev radius in `rings`: of the texels found, the smallest (squared distance,
/// `keep`'s value), which breaks ties deterministically.
fn nearest_texel<T: Ord + Copy>(n: i64, px: i64, py: i64, rings: std::ops::RangeInclusive<i64>, stop: RingStop, keep: impl Fn(i64, i64) -> Option<T>) -> Option<T> {
    let mut best: Option<(i64, T)> = None;
    for r in rings {
        match (stop, best) {
            (RingStop::FirstRing, Some((_, v))) => return Some(v),
            // A texel of ring r is at least r away.
            (RingStop::Nearest, Some((k, _))) if k < r * r => break,
            _ => {}
        }
        for dy in -r..=r {
            for dx in -r..=r {
                let (x, y) = (px + dx, py + dy);
                if dx.abs().max(dy.abs()) != r || x < 0 || y < 0 || x >= n || y >= n {
                    continue;
                }
                if let Some(v) = keep(x, y) {
                    let k = dx * dx + dy * dy;
                    if best.is_none_or(|b| (k, v) < b) {
                        best = Some((k, v));
                    }
                }
            }
        }
    }
    best.map(|(_, v)| v)
}

/// The point X a texel stands for (gutter texels: the nearest point of the chart) and N(X):
/// (face, X, N(X)).
pub fn texel_point(atlas: &Atlas, base: &Base, mode: NormalMode, px: u32, py: u32) -> Option<(u32, DVec3, DVec3)> {
    texel_point_bary(atlas, base, mode, px, py).map(|(f, _, x, dir)| (f, x, dir))
}

fn texel_point_bary(atlas: &Atlas, base: &Base, mode: NormalMode, px: u32, py: u32) -> Option<(u32, [f64; 3], DVec3, DVec3)> {
    let (f, bary, _) = atlas.texel_any(px, py)?;
    let bary = clamp_bary(bary);
    let t = base.faces[f as usize];
    let p = t.map(|v| base.positions[v as usize]);
    let x = interpolate_direction(&p, &bary);
    let dir = match mode {
        NormalMode::Interpolated => interpolate_direction(&t.map(|v| base.directions[v as usize]), &bary),
        NormalMode::Constant => face_normal(p[0], p[1], p[2]),
    };
    Some((f, bary, x, dir))
}

impl DispMap {
    /// Bilinear lookup of d at barycentric (u, v) of `face`, from that face's side of its cell;
    /// `None` where the texel nearest the point has no d (the scan was not met there: a hole).
    pub fn sample(&self, face: u32, u: f64, v: f64) -> Option<f64> {
        let (x, y) = self.atlas.position(face, u, v);
        let (x, y) = (x - 0.5, y - 0.5);
        let (x0, y0) = (x.floor(), y.floor());
        let (fx, fy) = (x - x0, y - y0);
        let n = self.atlas.size as i64;
        let at = |xi: i64, yi: i64| -> Option<f64> {
            if xi < 0 || yi < 0 || xi >= n || yi >= n {
                return None;
            }
            let v = self.d[(yi * n + xi) as usize];
            if v.is_nan() {
                None
            } else {
                Some(v as f64)
            }
        };
        let (xi, yi) = (x0 as i64, y0 as i64);
        let nearest = at((x + 0.5).floor() as i64, (y + 0.5).floor() as i64)?;
        let mut acc = 0.0;
        let mut w = 0.0;
        let (mut lo, mut hi) = (f64::INFINITY, f64::NEG_INFINITY);
        for (dx, dy, wt) in [(0, 0, (1.0 - fx) * (1.0 - fy)), (1, 0, fx * (1.0 - fy)), (0, 1, (1.0 - fx) * fy), (1, 1, fx * fy)] {
            if let Some(v) = at(xi + dx, yi + dy) {
                acc += wt * v;
                w += wt;
                lo = lo.min(v);
                hi = hi.max(v);
            }
        }
        // A jump between neighbouring texels is a crease of the scan, not a slope: blending
        // across it would put a point in the air, so take the nearest texel there.
        if hi - lo > self.jump {
            return Some(nearest);
        }
        if w > 0.0 {
            Some(acc / w)
        } else {
            None
        }
    }

    /// Texels with a value.
    pub fn defined(&self) -> usize {
        self.d.iter().filter(|v| !v.is_nan()).count()
    }

    /// The texel values of `kind`: one channel (scalar, normalized) or three (vector),
    /// interleaved, row-major from the top. Needs the directions of a freshly baked map.
    pub fn channels(&self, kind: Kind) -> (usize, Vec<f32>) {
        let len = |v: &[f32; 3]| ((v[0] as f64).powi(2) + (v[1] as f64).powi(2) + (v[2] as f64).powi(2)).sqrt();
        match kind {
            Kind::Scalar => (1, self.d.clone()),
            Kind::Normalized => (1, self.d.iter().zip(&self.dir).map(|(&d, n)| (d as f64 * len(n)) as f32).collect()),
            Kind::Vector => (3, self.d.iter().zip(&self.dir).flat_map(|(&d, n)| n.map(|c| (d as f64 * c as f64) as f32)).collect()),
        }
    }

    /// The sidecar of a map of `kind` written as a float image (no quantisation).
    pub fn sidecar(&self, kind: Kind) -> Quantisation {
        Quantisation { scale: 1.0, offset: 0.0, faces: self.atlas.faces, size: self.atlas.size, missing: 0, kind, convention: kind.convention().into() }
    }

    /// 16-bit grayscale PNG of one channel and its quantisation (value 0 marks texels without d).
    pub fn to_png16(&self, kind: Kind) -> (Vec<u8>, Quantisation) {
        let (_, values) = self.channels(kind);
        png16(&values, self.atlas.size, self.atlas.faces, kind)
    }

    /// PFM (portable float map, little-endian, rows bottom to top): `Pf` for one channel, `PF`
    /// (RGB) for the vector kind; NaN marks texels without d.
    pub fn to_pfm(&self, kind: Kind) -> Vec<u8> {
        let (c, values) = self.channels(kind);
        let n = self.atlas.size as usize;
        let mut out = format!("{}\n{n} {n}\n-1.0\n", if c == 3 { "PF" } else { "Pf" }).into_bytes();
        for row in (0..n).rev() {
            for &v in &values[row * n * c..(row + 1) * n * c] {
                out.extend_from_slice(&v.to_le_bytes());
            }
        }
        out
    }

    /// OpenEXR, 32-bit float: channel `Y` (scalar, normalized) or `R`, `G`, `B` (vector); NaN
    /// marks texels without d. The kind, its convention and dmax are header attributes too.
    pub fn to_exr(&self, kind: Kind, dmax: f64) -> Result<Vec<u8>, String> {
        use exr::prelude::*;
        let (c, values) = self.channels(kind);
        let n = self.atlas.size as usize;
        let names: &[&str] = if c == 3 { &["R", "G", "B"] } else { &["Y"] };
        let list: SmallVec<[AnyChannel<FlatSamples>; 4]> = names
            .iter()
            .enumerate()
            .map(|(k, name)| AnyChannel::new(*name, FlatSamples::F32((0..n * n).map(|i| values[i * c + k]).collect())))
            .collect();
        let mut attrs = LayerAttributes::named("displacement");
        attrs.other.insert(Text::new_or_panic("dispdec_kind"), AttributeValue::Text(Text::new_or_panic(kind.name())));
        attrs.other.insert(Text::new_or_panic("dispdec_convention"), AttributeValue::Text(Text::new_or_panic(kind.convention())));
        attrs.other.insert(Text::new_or_panic("dispdec_dmax"), AttributeValue::F64(dmax));
        attrs.other.insert(Text::new_or_panic("dispdec_faces"), AttributeValue::I32(self.atlas.faces as i32));
        let layer = Layer::new((n, n), attrs, Encoding::SMALL_LOSSLESS, AnyChannels::sort(list));
        let mut buf = std::io::Cursor::new(Vec::new());
        Image::from_layer(layer).write().to_buffered(&mut buf).map_err(|e| e.to_string())?;
        Ok(buf.into_inner())
    }

    /// Reads a scalar map written by dispdec: PFM, EXR, or a 16-bit PNG with its JSON sidecar
    /// (`DISP.png.json`); `faces` is the base mesh's face count. A sidecar or EXR header that
    /// names another kind is refused (those maps are for other tools).
    pub fn read(path: &Path, faces: usize) -> Result<DispMap, Error> {
        let err = |msg: String| Error::Input { path: path.display().to_string(), msg };
        let bytes = std::fs::read(path).map_err(|e| err(format!("cannot read file: {e}")))?;
        let side = sidecar_path(path);
        let sidecar: Option<Quantisation> = match std::fs::read(&side) {
            Ok(b) => Some(serde_json::from_slice(&b).map_err(|e| err(format!("bad sidecar {}: {e}", side.display())))?),
            Err(_) => None,
        };
        let refuse = |k: Kind| err(format!("a {} map; reconstruct and export read scalar maps (bake --kind scalar)", k.name()));
        if let Some(k) = sidecar.as_ref().map(|q| q.kind).filter(|&k| k != Kind::Scalar) {
            return Err(refuse(k));
        }
        let (size, d) = if bytes.starts_with(b"\x76\x2f\x31\x01") {
            read_exr(&bytes).map_err(|e| match e {
                Ok(k) => refuse(k),
                Err(m) => err(m),
            })?
        } else if bytes.starts_with(b"Pf\n") {
            let text_end = bytes.iter().enumerate().filter(|(_, &c)| c == b'\n').nth(2).map(|(i, _)| i + 1).ok_or_else(|| err("truncated PFM header".into()))?;
            let header = String::from_utf8_lossy(&bytes[..text_end]).to_string();
            let mut it = header.split_whitespace().skip(1);
            let w: usize = it.next().and_then(|s| s.parse().ok()).ok_or_else(|| err("bad PFM width".into()))?;
            let h: usize = it.next().and_then(|s| s.parse().ok()).ok_or_else(|| err("bad PFM height".into()))?;
            let scale: f64 = it.next().and_then(|s| s.parse().ok()).ok_or_else(|| err("bad PFM scale".into()))?;
            if w != h || scale >= 0.0 || bytes.len() != text_end + 4 * w * h {
                return Err(err(format!("expected a square little-endian PFM of {w}x{h} floats")));
            }
            let mut d = vec![0f32; w * h];
            for row in 0..h {
                for col in 0..w {
                    let o = text_end + 4 * ((h - 1 - row) * w + col);
                    d[row * w + col] = f32::from_le_bytes(bytes[o..o + 4].try_into().unwrap());
                }
            }
            (w, d)
        } else {
            let q = sidecar.ok_or_else(|| err(format!("cannot read the sidecar {}", side.display())))?;
            let dec = png::Decoder::new(std::io::Cursor::new(&bytes));
            let mut reader = dec.read_info().map_err(|e| err(format!("not a PNG: {e}")))?;
            let mut buf = vec![0u8; reader.output_buffer_size().unwrap_or(0)];
            let info = reader.next_frame(&mut buf).map_err(|e| err(format!("bad PNG data: {e}")))?;
            if info.bit_depth != png::BitDepth::Sixteen || info.color_type != png::ColorType::Grayscale || info.width != info.height {
                return Err(err("expected a square 16-bit grayscale PNG".into()));
            }
            let d = buf[..info.buffer_size()]
                .chunks_exact(2)
                .map(|c| {
                    let code = u16::from_be_bytes([c[0], c[1]]);
                    if code == q.missing {
                        f32::NAN
                    } else {
                        (q.offset + q.scale * code as f64) as f32
                    }
                })
                .collect();
            (info.width as usize, d)
        };
        let atlas = Atlas::new(faces, size as u32);
        if atlas.size as usize != size {
            return Err(err(format!("a {size}-texel map does not fit the atlas of a {faces}-face base")));
        }
        let jump = jump_of(&d);
        Ok(DispMap { atlas, d, dir: Vec::new(), jump })
    }
}

/// The JSON sidecar beside a map: `DISP.png.json`, `DISP.pfm.json`, `DISP.exr.json`.
pub fn sidecar_path(map: &Path) -> std::path::PathBuf {
    let mut s = map.as_os_str().to_os_string();
    s.push(".json");
    std::path::PathBuf::from(s)
}

/// 16-bit grayscale PNG of `values` (NaN: value 0) and its quantisation.
pub fn png16(values: &[f32], size: u32, faces: u32, kind: Kind) -> (Vec<u8>, Quantisation) {
    let (lo, hi) = values.iter().filter(|v| !v.is_nan()).fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), &v| (a.min(v as f64), b.max(v as f64)));
    let (lo, hi) = if lo.is_finite() { (lo, hi) } else { (0.0, 0.0) };
    // Values 1..=65535 carry d; 0 is "missing".
    let scale = if hi > lo { (hi - lo) / 65534.0 } else { 1.0 };
    let q = Quantisation { scale, offset: lo - scale, faces, size, missing: 0, kind, convention: kind.convention().into() };
    let mut raw = Vec::with_capacity(values.len() * 2);
    for &v in values {
        let code: u16 = if v.is_nan() { 0 } else { (((v as f64 - q.offset) / scale).round()).clamp(1.0, 65535.0) as u16 };
        raw.extend_from_slice(&code.to_be_bytes());
    }
    let mut out = Vec::new();
    {
        let mut enc = png::Encoder::new(&mut out, size, size);
        enc.set_color(png::ColorType::Grayscale);
        enc.set_depth(png::BitDepth::Sixteen);
        let mut w = enc.write_header().expect("PNG header into memory");
        w.write_image_data(&raw).expect("PNG data into memory");
    }
    (out, q)
}

/// A one-channel EXR as dispdec writes it: (size, values); `Err(Ok(kind))` for another kind.
fn read_exr(bytes: &[u8]) -> Result<(usize, Vec<f32>), Result<Kind, String>> {
    use exr::prelude::*;
    let image = read().no_deep_data().largest_resolution_level().all_channels().first_valid_layer().all_attributes()
        .from_buffered(std::io::Cursor::new(bytes))
        .map_err(|e| Err(format!("not a readable EXR: {e}")))?;
    let layer = &image.layer_data;
    if let Some(AttributeValue::Text(t)) = layer.attributes.other.get(&Text::new_or_panic("dispdec_kind")) {
        let k = t.to_string();
        if k != "scalar" {
            return Err(Ok(if k == "vector" { Kind::Vector } else { Kind::Normalized }));
        }
    }
    let size = layer.size;
    if size.0 != size.1 || layer.channel_data.list.len() != 1 {
        return Err(Err("expected a square one-channel EXR".into()));
    }
    Ok((size.0, layer.channel_data.list[0].sample_data.values_as_f32().collect()))
}
