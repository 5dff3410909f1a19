//! Baking the displacement map (SPEC §5): d sampled over the atlas of the base triangles (the
//! fold image's atlas). Every texel of a face's side of its cell — chart and gutter — stands for
//! a point X of that face (gutter texels for the nearest point of the chart), and d is where the
//! line X + d·N(X) meets the scan: of the crossings within dmax where the scan faces the way N
//! does (condition (4) for the crossed face), the one with the smallest |d| (a BVH over the
//! scan): exact, not interpolated from vertices. Gutters thus hold the chart's own values, so a
//! bilinear lookup at a chart border is right.

use crate::bvh::Bvh;
use crate::eval::NormalMode;
use crate::fold::Atlas;
use crate::geometry::{clamp_bary, face_normal, interpolate_direction};
use crate::mesh::DenseData;
use crate::validate::Base;
use crate::Error;
use rayon::prelude::*;
use std::path::Path;

/// A baked displacement map: d per texel, row-major from the top; NaN where no chart is, or
/// where the scan was not met within dmax.
#[derive(Clone, Debug)]
pub struct DispMap {
    pub atlas: Atlas,
    pub d: Vec<f32>,
    /// A difference between neighbouring texels above this is a jump, not a slope (see
    /// [`DispMap::sample`]): JUMP_FRACTION of the range of d.
    pub jump: f64,
}

/// Neighbouring texels differing by more than this fraction of the map's range of d are not
/// blended. Why: on a valid base d varies slowly within a chart; a step of 5 % of its whole range
/// between adjacent texels is a crease or another sheet.
pub const JUMP_FRACTION: f64 = 0.05;

fn jump_of(d: &[f32]) -> f64 {
    let (lo, hi) = d.iter().filter(|v| !v.is_nan()).fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), &v| (a.min(v as f64), b.max(v as f64)));
    if lo.is_finite() {
        JUMP_FRACTION * (hi - lo)
    } else {
        f64::INFINITY
    }
}

/// The sidecar of a 16-bit PNG: d = offset + scale · value.
#[derive(Clone, Debug, serde::Serialize, serde::Deserialize, PartialEq)]
pub struct Quantisation {
    pub scale: f64,
    pub offset: f64,
    pub faces: u32,
    pub size: u32,
    /// PNG value of texels without a displacement (outside charts, or no crossing).
    pub missing: u16,
}

/// Bakes d for every texel of `base`'s atlas.
pub fn bake(dense: &DenseData, base: &Base, mode: NormalMode, dmax: f64, size: u32) -> DispMap {
    let atlas = Atlas::new(base.faces.len(), size);
    let bvh = Bvh::build(&dense.pos, &dense.faces);
    let n = atlas.size;
    let d: Vec<f32> = (0..n * n)
        .into_par_iter()
        .map_init(Vec::new, |hits, i| {
            let (px, py) = (i % n, i / n);
            let Some((f, bary, _)) = atlas.texel_any(px, py) else { return f32::NAN };
            let bary = clamp_bary(bary);
            let t = base.faces[f as usize];
            let p = t.map(|v| base.positions[v as usize]);
            let x = interpolate_direction(&p, &bary);
            let dir = match mode {
                NormalMode::Interpolated => interpolate_direction(&t.map(|v| base.directions[v as usize]), &bary),
                NormalMode::Constant => face_normal(p[0], p[1], p[2]),
            };
            bvh.crossings(&dense.pos, &dense.faces, x, dir, -dmax, dmax, hits);
            // The scan must face the way N does there (condition (4) for the crossed face): a
            // crossing of the back of a thin part is another sheet, not this point's surface.
            hits.iter()
                .filter(|h| dense.normal[h.1 as usize].dot(dir) > 0.0)
                .map(|h| h.0)
                .min_by(|a, b| a.abs().total_cmp(&b.abs()))
                .map(|t| t as f32)
                .unwrap_or(f32::NAN)
        })
        .collect();
    let jump = jump_of(&d);
    DispMap { atlas, d, jump }
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

    /// 16-bit grayscale PNG and its quantisation (value 0 marks texels without d).
    pub fn to_png16(&self) -> (Vec<u8>, Quantisation) {
        let (lo, hi) = self.d.iter().filter(|v| !v.is_nan()).fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), &v| (a.min(v as f64), b.max(v as f64)));
        let (lo, hi) = if lo.is_finite() { (lo, hi) } else { (0.0, 0.0) };
        // Values 1..=65535 carry d; 0 is "missing".
        let scale = if hi > lo { (hi - lo) / 65534.0 } else { 1.0 };
        let q = Quantisation { scale, offset: lo - scale, faces: self.atlas.faces, size: self.atlas.size, missing: 0 };
        let mut raw = Vec::with_capacity(self.d.len() * 2);
        for &v in &self.d {
            let code: u16 = if v.is_nan() { 0 } else { (((v as f64 - q.offset) / scale).round()).clamp(1.0, 65535.0) as u16 };
            raw.extend_from_slice(&code.to_be_bytes());
        }
        let mut out = Vec::new();
        {
            let mut enc = png::Encoder::new(&mut out, self.atlas.size, self.atlas.size);
            enc.set_color(png::ColorType::Grayscale);
            enc.set_depth(png::BitDepth::Sixteen);
            let mut w = enc.write_header().expect("PNG header into memory");
            w.write_image_data(&raw).expect("PNG data into memory");
        }
        (out, q)
    }

    /// PFM (portable float map, little-endian, rows bottom to top); NaN marks texels without d.
    pub fn to_pfm(&self) -> Vec<u8> {
        let n = self.atlas.size as usize;
        let mut out = format!("Pf\n{n} {n}\n-1.0\n").into_bytes();
        for row in (0..n).rev() {
            for &v in &self.d[row * n..(row + 1) * n] {
                out.extend_from_slice(&v.to_le_bytes());
            }
        }
        out
    }

    /// Reads a map written by [`DispMap::to_pfm`], or a 16-bit PNG with its JSON sidecar
    /// (`DISP.png.json`); `faces` is the base mesh's face count.
    pub fn read(path: &Path, faces: usize) -> Result<DispMap, Error> {
        let err = |msg: String| Error::Input { path: path.display().to_string(), msg };
        let bytes = std::fs::read(path).map_err(|e| err(format!("cannot read file: {e}")))?;
        let (size, d) = if bytes.starts_with(b"Pf\n") {
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
            let side = path.with_extension("png.json");
            let q: Quantisation = serde_json::from_slice(
                &std::fs::read(&side).map_err(|e| err(format!("cannot read the sidecar {}: {e}", side.display())))?,
            )
            .map_err(|e| err(format!("bad sidecar {}: {e}", side.display())))?;
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
        Ok(DispMap { atlas, d, jump })
    }
}
