//! `BASE.map`: per dense vertex, the base triangle, barycentrics and d.
//!
//! Little-endian binary:
//!
//! | offset | type      | field                                                        |
//! |-------:|-----------|--------------------------------------------------------------|
//! | 0      | [u8; 8]   | magic `DISPMAP1`                                             |
//! | 8      | u32       | number of dense vertices N (as in the input file)            |
//! | 12     | u32       | number of base faces F (as in BASE.obj)                      |
//! | 16     | f32       | dmax                                                         |
//! | 20     | u32       | flags: bit 0 = constant-normal mode                          |
//! | 24     | N records | 24 bytes each: u32 face, u32 status, f32 a, f32 b, f32 c, f32 d |
//!
//! `face` indexes BASE.obj's faces (0-based); `status` is 0 mapped, 1 pinched (exempt from
//! condition (4); its map is the best solution found, possibly none), 2 unreferenced by the
//! input's faces (face = 0xFFFFFFFF). The point is `a·P1 + b·P2 + c·P3 + d·(a·N1 + b·N2 + c·N3)`.

use crate::Error;
use std::path::Path;

pub const MAGIC: &[u8; 8] = b"DISPMAP1";
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
    pub records: Vec<Record>,
}

impl MapFile {
    pub fn to_bytes(&self) -> Vec<u8> {
        let mut out = Vec::with_capacity(24 + 24 * self.records.len());
        out.extend_from_slice(MAGIC);
        out.extend_from_slice(&(self.records.len() as u32).to_le_bytes());
        out.extend_from_slice(&self.base_faces.to_le_bytes());
        out.extend_from_slice(&self.dmax.to_le_bytes());
        out.extend_from_slice(&(self.constant_normals as u32).to_le_bytes());
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
        if b.len() < 24 || &b[..8] != MAGIC {
            return Err(err("not a dispdec map file (bad magic)".into()));
        }
        let u = |o: usize| u32::from_le_bytes(b[o..o + 4].try_into().unwrap());
        let f = |o: usize| f32::from_le_bytes(b[o..o + 4].try_into().unwrap());
        let n = u(8) as usize;
        if b.len() != 24 + 24 * n {
            return Err(err(format!("truncated: {} records announced, {} bytes present", n, b.len())));
        }
        let records = (0..n)
            .map(|i| {
                let o = 24 + 24 * i;
                Record { face: u(o), status: u(o + 4), bary: [f(o + 8), f(o + 12), f(o + 16)], d: f(o + 20) }
            })
            .collect();
        Ok(MapFile { base_faces: u(12), dmax: f(16), constant_normals: u(20) & 1 == 1, records })
    }
}
