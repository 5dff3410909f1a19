//! The generator of scan-like sample meshes (`dispdec sample`): an open dome with
//! multi-frequency bumps, a thin fin, a mushroom-shaped overhang and scanner noise.
//!
//! The dome is a square grid mapped to a disk (Shirley–Chiu concentric map, no pole), lifted
//! onto a spherical cap; its rim is the open boundary.

use glam::DVec3;
use std::f64::consts::PI;

/// Sample mesh description.
#[derive(Clone, Copy, Debug)]
pub struct SampleSpec {
    /// Approximate number of faces (10k to 1M).
    pub faces: usize,
    pub seed: u64,
}

/// Concentric square-to-disk map.
fn square_to_disk(a: f64, b: f64) -> (f64, f64) {
    if a == 0.0 && b == 0.0 {
        return (0.0, 0.0);
    }
    let (r, phi) = if a.abs() > b.abs() { (a, PI / 4.0 * (b / a)) } else { (b, PI / 2.0 - PI / 4.0 * (a / b)) };
    (r * phi.cos(), r * phi.sin())
}

fn smoothstep(e0: f64, e1: f64, x: f64) -> f64 {
    let t = ((x - e0) / (e1 - e0)).clamp(0.0, 1.0);
    t * t * (3.0 - 2.0 * t)
}

/// Profile of the mushroom in (radius, height), as a function of the grid's radial parameter
/// ρ ∈ [0, 1]: cap top, cap rim, underside back inwards (the overhang), stem, foot.
fn mushroom_profile(rho: f64) -> (f64, f64) {
    const K: [(f64, f64, f64); 8] = [
        (0.0, 0.0, 1.0),
        (0.30, 0.85, 0.97),
        (0.42, 1.15, 0.82),
        (0.52, 1.0, 0.66),
        (0.62, 0.55, 0.58),
        (0.80, 0.45, 0.25),
        (0.92, 0.7, 0.04),
        (1.0, 1.0, 0.0),
    ];
    for w in K.windows(2) {
        let (r0, a0, h0) = w[0];
        let (r1, a1, h1) = w[1];
        if rho <= r1 {
            let t = smoothstep(0.0, 1.0, (rho - r0) / (r1 - r0));
            return (a0 + t * (a1 - a0), h0 + t * (h1 - h0));
        }
    }
    (rho, 0.0)
}

/// Deterministic hash noise in [-1, 1].
fn hash_noise(i: u64, seed: u64) -> f64 {
    let mut x = i.wrapping_mul(0x9E37_79B9_7F4A_7C15) ^ seed;
    x ^= x >> 30;
    x = x.wrapping_mul(0xBF58_476D_1CE4_E5B9);
    x ^= x >> 27;
    x = x.wrapping_mul(0x94D0_49BB_1331_11EB);
    x ^= x >> 31;
    (x >> 11) as f64 / (1u64 << 52) as f64 - 1.0
}

/// Generates the sample surface.
pub fn generate(spec: SampleSpec) -> crate::mesh::Mesh {
    let n = (((spec.faces as f64) / 2.0).sqrt().round() as usize + 1).max(8);
    let cap_r = 1.6; // sphere radius of the dome
    let mush_c = (0.25, 0.2);
    let mush_a = 0.17;
    let mush_h = 0.22;
    let mut positions = Vec::with_capacity(n * n);
    for j in 0..n {
        for i in 0..n {
            let a = 2.0 * i as f64 / (n - 1) as f64 - 1.0;
            let b = 2.0 * j as f64 / (n - 1) as f64 - 1.0;
            let (mut x, mut y) = square_to_disk(a, b);
            let mut lift = 0.0;
            // Mushroom: remap the disk around its centre radially, and lift by the profile.
            let (dx, dy) = (x - mush_c.0, y - mush_c.1);
            let rho = (dx * dx + dy * dy).sqrt() / mush_a;
            if rho < 1.0 {
                let (rr, hh) = mushroom_profile(rho);
                let s = if rho > 0.0 { rr / rho } else { 0.0 };
                x = mush_c.0 + dx * s;
                y = mush_c.1 + dy * s;
                lift += mush_h * hh;
            }
            // Multi-frequency bumps.
            let bumps = 0.040 * (3.1 * x + 0.4).sin() * (2.3 * y - 0.2).sin()
                + 0.015 * (9.0 * x + 4.0 * y).sin() * (7.0 * y - 1.0).cos()
                + 0.006 * (23.0 * x - 17.0 * y + 0.3).sin()
                + 0.0025 * (61.0 * x + 43.0 * y).sin() * (57.0 * y - 29.0 * x).cos();
            // A thin fin along y = -0.45.
            let fin = 0.18 * (-((y + 0.45) / 0.018).powi(2)).exp() * smoothstep(0.65, 0.35, x.abs());
            let noise = 0.0006 * hash_noise((j * n + i) as u64, spec.seed);
            let r2 = x * x + y * y;
            let z_dome = (cap_r * cap_r - r2).max(0.0).sqrt() - cap_r;
            let normal = DVec3::new(x, y, z_dome + cap_r).normalize();
            let base = DVec3::new(x, y, z_dome);
            let p = base + normal * (bumps + noise) + DVec3::Z * (fin + lift);
            positions.push(p);
        }
    }
    let mut faces = Vec::with_capacity(2 * (n - 1) * (n - 1));
    let id = |i: usize, j: usize| (j * n + i) as u32;
    for j in 0..n - 1 {
        for i in 0..n - 1 {
            let (a, b, c, d) = (id(i, j), id(i + 1, j), id(i + 1, j + 1), id(i, j + 1));
            if (i + j) % 2 == 0 {
                faces.push([a, b, c]);
                faces.push([a, c, d]);
            } else {
                faces.push([a, b, d]);
                faces.push([b, c, d]);
            }
        }
    }
    crate::mesh::Mesh { positions, faces, ..Default::default() }
}

/// OBJ text of a mesh (v/f only), the format of `data/sample.obj.gz`.
pub fn to_obj(mesh: &crate::mesh::Mesh, comment: &str) -> String {
    use std::fmt::Write;
    let mut s = String::with_capacity(40 * (mesh.positions.len() + mesh.faces.len()));
    let _ = writeln!(s, "# {comment}");
    for p in &mesh.positions {
        let _ = writeln!(s, "v {:.6} {:.6} {:.6}", p.x, p.y, p.z);
    }
    for f in &mesh.faces {
        let _ = writeln!(s, "f {} {} {}", f[0] + 1, f[1] + 1, f[2] + 1);
    }
    s
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sample_is_a_valid_open_disk() {
        let m = generate(SampleSpec { faces: 10_000, seed: 1 });
        assert!((9_000..11_000).contains(&m.faces.len()));
        let d = crate::mesh::check_and_compact(std::path::Path::new("sample"), m).unwrap();
        let (genus, loops) = crate::topology::topology_summary(d.positions.len(), &d.faces);
        assert_eq!((genus, loops), (0, 1));
    }
}
