//! `BASE.map`: per dense vertex, the base triangle, barycentrics and d, and the settings the
//! base was made with.
//!
//! Little-endian binary:
//!
//! | offset     | type      | field                                                        |
//! |-----------:|-----------|--------------------------------------------------------------|
//! | 0          | [u8; 8]   | magic `DISPMAP2`                                             |
//! | 8          | u32       | number of dense vertices N (as in the input file)            |
//! | 12         | u32       | number of base faces F (as in BASE.obj)                      |
//! | 16         | f32       | dmax                                                         |
//! | 20         | u32       | flags: bit 0 = constant-normal mode, bit 1 = strict          |
//! | 24         | u32       | L, the length of the settings text                           |
//! | 28         | L bytes   | the settings as JSON (UTF-8, as in BASE.obj's header), zero-padded to a multiple of 4 |
//! | 28 + L'    | N records | 24 bytes each: u32 face, u32 status, f32 a, f32 b, f32 c, f32 d |
//!
//! `face` indexes BASE.obj's faces (0-based); `status` is 0 mapped, 1 pinched (exempt from
//! condition (4); its map is the best solution found, possibly none), 2 unreferenced by the
//! input's faces, or only on faces `--repair` dropped (face = 0xFFFFFFFF). The point is
//! `a·P1 + b·P2 + c·P3 + d·(a·N1 + b·N2 + c·N3)`. Vertices welded together, and the copies of
//! a vertex that `--repair` split, share one record. Files of the first format (`DISPMAP1`: no
//! settings, records at offset 24) are still read.

use crate::settings::Settings;
use crate::Error;
use std::path::Path;

pub const MAGIC: &[u8; 8] = b"DISPMAP2";
pub const MAGIC_V1: &[u8; 8] = b"DISPMAP1";
pub const STATUS_MAPPED: u32 = 0;
pub const STATUS_PINCHED: u32 = 1;
pub const STATUS_UNREFERENCED: u32 = 2;

#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Record {
    pub face: u32,
    pub status: u32,
    pub bary: [f32; 3],
    pub d: f32,
}

#[derive(Clone, Debug, PartialEq)]
pub struct MapFile {
    pub base_faces: u32,
    pub dmax: f32,
    pub constant_normals: bool,
    pub strict: bool,
    /// `None` only for a file of the first format.
    pub settings: Option<Settings>,
    pub records: Vec<Record>,
}

impl MapFile {
    pub fn to_bytes(&self) -> Vec<u8> {
        let text = self.settings.as_ref().map(|s| serde_json::to_string(s).expect("settings serialise")).unwrap_or_default();
        let padded = text.len().div_ceil(4) * 4;
        let mut out = Vec::with_capacity(28 + padded + 24 * self.records.len());
        out.extend_from_slice(MAGIC);
        out.extend_from_slice(&(self.records.len() as u32).to_le_bytes());
        out.extend_from_slice(&self.base_faces.to_le_bytes());
        out.extend_from_slice(&self.dmax.to_le_bytes());
        out.extend_from_slice(&(self.constant_normals as u32 | (self.strict as u32) << 1).to_le_bytes());
        out.extend_from_slice(&(text.len() as u32).to_le_bytes());
        out.extend_from_slice(text.as_bytes());
        out.resize(28 + padded, 0);
        for r in &self.records {
            out.extend_from_slice(&r.face.to_le_bytes());
            out.extend_from_slice(&r.status.to_le_bytes());
            for b in r.bary {
                out.extend_from_slice(&b.to_le_bytes());
            }
            out.extend_from_slice(&r.d.to_le_bytes());
        }
        out
    }

    pub fn read(path: &Path) -> Result<MapFile, Error> {
        let err = |msg: String| Error::Input { path: path.display().to_string(), msg };
        let b = std::fs::read(path).map_err(|e| err(format!("cannot read file: {e}")))?;
        let v2 = b.len() >= 28 && &b[..8] == MAGIC;
        let v1 = b.len() >= 24 && &b[..8] == MAGIC_V1;
        if !v2 && !v1 {
            return Err(err("not a dispdec map file (bad magic)".into()));
        }
        let u = |o: usize| u32::from_le_bytes(b[o..o + 4].try_into().unwrap());
        let f = |o: usize| f32::from_le_bytes(b[o..o + 4].try_into().unwrap());
        let n = u(8) as usize;
        let (start, settings) = if v2 {
            let len = u(24) as usize;
            let start = 28 + len.div_ceil(4) * 4;
            if b.len() < start {
                return Err(err(format!("truncated: the settings announce {len} bytes, {} present", b.len() - 28)));
            }
            let text = std::str::from_utf8(&b[28..28 + len]).map_err(|_| err("the settings are not UTF-8".into()))?;
            let s = if text.is_empty() { None } else { Some(Settings::parse(text).map_err(err)?) };
            (start, s)
        } else {
            (24, None)
        };
        if b.len() != start + 24 * n {
            return Err(err(format!("truncated: {} records announced, {} bytes present", n, b.len())));
        }
        let records = (0..n)
            .map(|i| {
                let o = start + 24 * i;
                Record { face: u(o), status: u(o + 4), bary: [f(o + 8), f(o + 12), f(o + 16)], d: f(o + 20) }
            })
            .collect();
        Ok(MapFile { base_faces: u(12), dmax: f(16), constant_normals: u(20) & 1 == 1, strict: u(20) & 2 == 2, settings, records })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn map_round_trips_with_settings_and_reads_the_first_format() {
        let settings = Settings {
            normals: crate::guarantee::NormalMode::Interpolated,
            dmax: 0.25,
            strict: false,
            scan: "s.obj".into(),
            scan_faces: 7,
            preparation: Default::default(),
            fine_loops: false,
        };
        let m = MapFile {
            base_faces: 3,
            dmax: 0.25,
            constant_normals: false,
            strict: true,
            settings: Some(settings),
            records: vec![Record { face: 1, status: 0, bary: [0.25, 0.25, 0.5], d: -0.5 }; 3],
        };
        let dir = std::env::temp_dir().join(format!("dispdec-map-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let p = dir.join("m.map");
        let bytes = m.to_bytes();
        assert_eq!((bytes.len() - 28) % 4, 0, "records start 4-aligned");
        std::fs::write(&p, &bytes).unwrap();
        assert_eq!(MapFile::read(&p).unwrap(), m);
        // The first format: the same header without settings, records at 24.
        let mut v1 = b"DISPMAP1".to_vec();
        v1.extend_from_slice(&bytes[8..24]);
        v1.extend_from_slice(&bytes[bytes.len() - 72..]);
        std::fs::write(&p, &v1).unwrap();
        let r = MapFile::read(&p).unwrap();
        assert_eq!((r.settings, r.records), (None, m.records));
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
