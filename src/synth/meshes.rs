//! Built-in mesh scenes, generated in code so tests need no big files: each is a plain
//! triangle [`Mesh`] (z up, metres) with the station positions it is meant to be scanned
//! from. They exercise what the analytic room does not: grazing floors far from the scanner,
//! thin columns, arches and vaults, openings to the sky, millimetre relief.

use super::mesh::Mesh;
use glam::DVec3;
use serde::Serialize;
use std::f64::consts::PI;

/// A built-in mesh scene.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum MeshKind {
    /// [`colonnade`]: an arcade of thin columns and arches under open sky.
    Colonnade,
    /// [`vaulted_room`]: a barrel-vaulted hall with open doors and windows.
    Vault,
    /// [`relief`]: a 60 mm relief panel with millimetre grooves, pits and bosses.
    Relief,
    /// [`porch`]: a house front with a porch roof on thin posts, steps and a bench (kept
    /// apart for validation: not used while choosing the reference's rules).
    Porch,
}

impl MeshKind {
    /// Every built-in mesh scene.
    pub const ALL: [MeshKind; 4] = [
        MeshKind::Colonnade,
        MeshKind::Vault,
        MeshKind::Relief,
        MeshKind::Porch,
    ];

    /// Its name on the command line.
    pub fn name(self) -> &'static str {
        match self {
            MeshKind::Colonnade => "colonnade",
            MeshKind::Vault => "vault",
            MeshKind::Relief => "relief",
            MeshKind::Porch => "porch",
        }
    }

    /// The built-in of this name, if any.
    pub fn from_name(s: &str) -> Option<MeshKind> {
        MeshKind::ALL
            .into_iter()
            .find(|k| k.name().eq_ignore_ascii_case(s))
    }

    /// The mesh.
    pub fn mesh(self) -> Mesh {
        match self {
            MeshKind::Colonnade => colonnade(),
            MeshKind::Vault => vaulted_room(),
            MeshKind::Relief => relief(),
            MeshKind::Porch => porch(),
        }
    }

    /// Station positions (used in turn) and the point perspective stations look at.
    pub fn stations(self) -> (Vec<DVec3>, DVec3) {
        match self {
            MeshKind::Colonnade => (
                vec![
                    DVec3::new(-2.0, 1.5, 1.5),
                    DVec3::new(4.5, -4.0, 1.6),
                    DVec3::new(1.0, 6.5, 1.4),
                ],
                DVec3::new(0.0, 1.5, 1.5),
            ),
            MeshKind::Vault => (
                vec![
                    DVec3::new(-2.0, 0.6, 1.5),
                    DVec3::new(1.8, -0.9, 1.6),
                    DVec3::new(7.5, 0.4, 1.5),
                ],
                DVec3::new(0.0, 0.0, 1.5),
            ),
            MeshKind::Relief => (
                vec![
                    DVec3::new(0.0, -0.02, 0.25),
                    DVec3::new(0.09, 0.05, 0.22),
                    DVec3::new(-0.08, 0.07, 0.24),
                ],
                DVec3::ZERO,
            ),
            MeshKind::Porch => (
                vec![
                    DVec3::new(0.5, -3.5, 1.5),
                    DVec3::new(-3.5, -5.5, 1.6),
                    DVec3::new(2.8, -1.2, 1.5),
                ],
                DVec3::new(0.0, 0.0, 1.2),
            ),
        }
    }
}

/// A box with outward faces.
fn cuboid(m: &mut Mesh, lo: DVec3, hi: DVec3) {
    let c = |x: f64, y: f64, z: f64| DVec3::new(x, y, z);
    let (a, b) = (lo, hi);
    m.quad(
        c(a.x, a.y, a.z),
        c(a.x, b.y, a.z),
        c(b.x, b.y, a.z),
        c(b.x, a.y, a.z),
    );
    m.quad(
        c(a.x, a.y, b.z),
        c(b.x, a.y, b.z),
        c(b.x, b.y, b.z),
        c(a.x, b.y, b.z),
    );
    m.quad(
        c(a.x, a.y, a.z),
        c(b.x, a.y, a.z),
        c(b.x, a.y, b.z),
        c(a.x, a.y, b.z),
    );
    m.quad(
        c(a.x, b.y, a.z),
        c(a.x, b.y, b.z),
        c(b.x, b.y, b.z),
        c(b.x, b.y, a.z),
    );
    m.quad(
        c(a.x, a.y, a.z),
        c(a.x, a.y, b.z),
        c(a.x, b.y, b.z),
        c(a.x, b.y, a.z),
    );
    m.quad(
        c(b.x, a.y, a.z),
        c(b.x, b.y, a.z),
        c(b.x, b.y, b.z),
        c(b.x, a.y, b.z),
    );
}

/// A vertical cylinder's side (outward) and top cap, `seg` facets.
fn column(m: &mut Mesh, base: DVec3, r: f64, h: f64, seg: usize) {
    let at = |k: usize, z: f64| {
        let a = 2.0 * PI * k as f64 / seg as f64;
        base + DVec3::new(r * a.cos(), r * a.sin(), z)
    };
    for k in 0..seg {
        m.quad(at(k, 0.0), at(k + 1, 0.0), at(k + 1, h), at(k, h));
        m.tri(base + DVec3::Z * h, at(k, h), at(k + 1, h));
    }
}

/// A wall in the plane `y = y0` over `x ∈ [x0, x1]`, `z ∈ [z0, z1]`, with rectangular
/// openings `[xa, xb, za, zb]`, as a single sheet.
fn wall_y(m: &mut Mesh, y0: f64, x: [f64; 2], z: [f64; 2], holes: &[[f64; 4]]) {
    let mut xs = vec![x[0], x[1]];
    let mut zs = vec![z[0], z[1]];
    for h in holes {
        xs.extend([h[0], h[1]]);
        zs.extend([h[2], h[3]]);
    }
    for v in [&mut xs, &mut zs] {
        v.sort_by(f64::total_cmp);
        v.dedup();
    }
    for i in 0..xs.len() - 1 {
        for j in 0..zs.len() - 1 {
            let (cx, cz) = ((xs[i] + xs[i + 1]) / 2.0, (zs[j] + zs[j + 1]) / 2.0);
            if holes
                .iter()
                .any(|h| cx > h[0] && cx < h[1] && cz > h[2] && cz < h[3])
            {
                continue;
            }
            let p = |x: f64, z: f64| DVec3::new(x, y0, z);
            m.quad(
                p(xs[i], zs[j]),
                p(xs[i + 1], zs[j]),
                p(xs[i + 1], zs[j + 1]),
                p(xs[i], zs[j + 1]),
            );
        }
    }
}

/// [`wall_y`] turned into the plane `x = x0` (`x` of the holes and extent is y).
fn wall_x(m: &mut Mesh, x0: f64, y: [f64; 2], z: [f64; 2], holes: &[[f64; 4]]) {
    let mut w = Mesh::default();
    wall_y(&mut w, 0.0, y, z, holes);
    for v in &mut w.vertices {
        *v = DVec3::new(x0, v.x, v.z);
    }
    m.append(&w);
}

/// An arch bridging `x ∈ [x0, x1]` in the slab `y ∈ [y0, y1]`: semicircular intrados from the
/// spring line `zs`, spandrels up to `zt`, and the top.
fn arch(m: &mut Mesh, x: [f64; 2], y: [f64; 2], zs: f64, zt: f64, seg: usize) {
    let (xc, r) = ((x[0] + x[1]) / 2.0, (x[1] - x[0]) / 2.0);
    let arc = |k: usize| {
        let a = PI - PI * k as f64 / seg as f64;
        (xc + r * a.cos(), zs + r * a.sin())
    };
    for k in 0..seg {
        let ((xa, za), (xb, zb)) = (arc(k), arc(k + 1));
        let p = |x: f64, y: f64, z: f64| DVec3::new(x, y, z);
        m.quad(
            p(xa, y[0], za),
            p(xa, y[1], za),
            p(xb, y[1], zb),
            p(xb, y[0], zb),
        );
        for yy in y {
            m.quad(p(xa, yy, za), p(xb, yy, zb), p(xb, yy, zt), p(xa, yy, zt));
        }
    }
    let p = |x: f64, y: f64| DVec3::new(x, y, zt);
    m.quad(p(x[0], y[0]), p(x[1], y[0]), p(x[1], y[1]), p(x[0], y[1]));
}

/// An arcade under open sky on a 24 × 20 m ground: two rows of seven columns (radius
/// 0.15 m, 3 m high, 2.5 m apart) along x at y = 0 and y = 3, each row carrying round arches
/// (crown 4.1 m) and a wall band to 4.5 m, a roof slab over the 3 m walk between the rows,
/// and a low wall (0.9 m) along the back of the ground.
pub fn colonnade() -> Mesh {
    let mut m = Mesh::default();
    m.quad(
        DVec3::new(-12.0, -10.0, 0.0),
        DVec3::new(12.0, -10.0, 0.0),
        DVec3::new(12.0, 10.0, 0.0),
        DVec3::new(-12.0, 10.0, 0.0),
    );
    let (r, h, step, n) = (0.15, 3.0, 2.5, 7);
    for row_y in [0.0, 3.0] {
        for i in 0..n {
            let x = -7.5 + step * i as f64;
            column(&mut m, DVec3::new(x, row_y, 0.0), r, h, 16);
            if i + 1 < n {
                arch(
                    &mut m,
                    [x + r, x + step - r],
                    [row_y - r, row_y + r],
                    h,
                    4.5,
                    16,
                );
            }
        }
    }
    // Roof over the walk, a little above the arch bands.
    cuboid(
        &mut m,
        DVec3::new(-7.8, -0.2, 4.5),
        DVec3::new(7.8, 3.2, 4.7),
    );
    cuboid(
        &mut m,
        DVec3::new(-10.0, 8.0, 0.0),
        DVec3::new(10.0, 8.3, 0.9),
    );
    m
}

/// A hall of 8 × 5 m, walls 3 m high under a barrel vault (radius 2.5 m, crown 5.5 m) along
/// x, on a 30 × 30 m ground. Open: a door 1.4 × 2.4 m and a window in the south wall, two
/// windows in the north wall, a door 2 × 2.6 m in the east wall whose lunette is left open,
/// and a window in the west wall (sill 1 m).
pub fn vaulted_room() -> Mesh {
    let mut m = Mesh::default();
    m.quad(
        DVec3::new(-15.0, -15.0, 0.0),
        DVec3::new(15.0, -15.0, 0.0),
        DVec3::new(15.0, 15.0, 0.0),
        DVec3::new(-15.0, 15.0, 0.0),
    );
    let (x0, x1, y0, y1, h, r) = (-4.0, 4.0, -2.5, 2.5, 3.0, 2.5);
    wall_y(
        &mut m,
        y0,
        [x0, x1],
        [0.0, h],
        &[[-1.0, 0.4, 0.0, 2.4], [1.5, 2.7, 1.0, 2.4]],
    );
    wall_y(
        &mut m,
        y1,
        [x0, x1],
        [0.0, h],
        &[[-3.0, -1.8, 1.0, 2.4], [1.0, 2.2, 1.0, 2.4]],
    );
    wall_x(&mut m, x1, [y0, y1], [0.0, h], &[[-1.0, 1.0, 0.0, 2.6]]);
    wall_x(&mut m, x0, [y0, y1], [0.0, h], &[[-0.6, 0.6, 1.0, 2.2]]);
    let seg = 24;
    let at = |k: usize, x: f64| {
        let a = PI * k as f64 / seg as f64;
        DVec3::new(x, r * a.cos(), h + r * a.sin())
    };
    for k in 0..seg {
        m.quad(at(k, x0), at(k, x1), at(k + 1, x1), at(k + 1, x0));
        // West lunette closes the vault; the east one stays open.
        m.tri(DVec3::new(x0, 0.0, h), at(k, x0), at(k + 1, x0));
    }
    m
}

/// Depth (metres, ≤ 0) of the relief panel's surface at `(x, y)` (see [`relief`]).
fn relief_depth(x: f64, y: f64) -> f64 {
    let mm = 1e-3;
    let mut z = 0.0f64;
    // Three grooves along y, 1.5, 1 and 2.5 mm wide, 3 mm deep.
    for (gx, w) in [(-15.0, 1.5), (-5.0, 1.0), (22.0, 2.5)] {
        if (x / mm - gx).abs() < w / 2.0 && y.abs() < 25.0 * mm {
            z = -3.0 * mm;
        }
    }
    // A row of square pits 2 mm wide, 2 mm deep.
    for k in 0..5 {
        let (px, py) = ((-20.0 + 8.0 * k as f64) * mm, -18.0 * mm);
        if (x - px).abs() < 1.0 * mm && (y - py).abs() < 1.0 * mm {
            z = -2.0 * mm;
        }
    }
    // Two bosses (spherical caps, radius 6 mm) set 3 mm into a 2 mm-deep field.
    for (bx, by) in [(5.0, 12.0), (12.0, -2.0)] {
        let d2 = (x / mm - bx).powi(2) + (y / mm - by).powi(2);
        if d2 < 49.0 {
            z = z.min(-2.0 * mm);
            if d2 < 36.0 {
                z = z.max(((36.0 - d2).sqrt() - 3.0) * mm);
            }
        }
    }
    z
}

/// A relief panel of 60 × 60 mm in the plane z = 0 facing +z, sampled every 0.25 mm: three
/// grooves 3 mm deep and 1–2.5 mm wide, five pits 2 mm square and deep, and two bosses rising
/// from sunken rings. Walls are steep (one sample wide), as on a carved stone.
pub fn relief() -> Mesh {
    let n = 240usize;
    let step = 0.06 / n as f64;
    let mut m = Mesh::default();
    for j in 0..=n {
        for i in 0..=n {
            let (x, y) = (-0.03 + i as f64 * step, -0.03 + j as f64 * step);
            m.vertices.push(DVec3::new(x, y, relief_depth(x, y)));
        }
    }
    let id = |i: usize, j: usize| (j * (n + 1) + i) as u32;
    for j in 0..n {
        for i in 0..n {
            m.triangles.push([id(i, j), id(i + 1, j), id(i + 1, j + 1)]);
            m.triangles.push([id(i, j), id(i + 1, j + 1), id(i, j + 1)]);
        }
    }
    m
}

/// A house front (6 × 4 × 3 m box) on a 24 × 24 m ground with a porch roof (6 × 2 m slab at
/// 2.6 m) on four posts of radius 0.08 m, three steps before the door, and a bench on the
/// porch.
pub fn porch() -> Mesh {
    let mut m = Mesh::default();
    m.quad(
        DVec3::new(-12.0, -12.0, 0.0),
        DVec3::new(12.0, -12.0, 0.0),
        DVec3::new(12.0, 12.0, 0.0),
        DVec3::new(-12.0, 12.0, 0.0),
    );
    cuboid(
        &mut m,
        DVec3::new(-3.0, 0.0, 0.0),
        DVec3::new(3.0, 4.0, 3.0),
    );
    cuboid(
        &mut m,
        DVec3::new(-3.0, -2.0, 0.0),
        DVec3::new(3.0, 0.0, 0.45),
    );
    cuboid(
        &mut m,
        DVec3::new(-3.2, -2.2, 2.6),
        DVec3::new(3.2, 0.0, 2.8),
    );
    for x in [-2.85, -0.95, 0.95, 2.85] {
        column(&mut m, DVec3::new(x, -1.85, 0.45), 0.08, 2.15, 12);
    }
    for k in 0..3 {
        let z = 0.15 * k as f64;
        cuboid(
            &mut m,
            DVec3::new(-0.8, -2.9 + 0.3 * k as f64, 0.0),
            DVec3::new(0.8, -2.0, z + 0.15),
        );
    }
    cuboid(
        &mut m,
        DVec3::new(1.2, -0.5, 0.45),
        DVec3::new(2.6, -0.1, 0.9),
    );
    m
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::synth::mesh::MeshScene;

    #[test]
    fn builtin_meshes_have_their_openings() {
        for k in MeshKind::ALL {
            assert_eq!(MeshKind::from_name(k.name()), Some(k));
            let m = k.mesh();
            assert!(!m.triangles.is_empty());
            let sc = MeshScene::new(&m);
            let (st, _) = k.stations();
            // Building stations stand above the ground: straight down meets a surface.
            for p in st.into_iter().filter(|_| k != MeshKind::Relief) {
                assert!(sc
                    .intersect_skip(p, DVec3::NEG_Z, 0.0, 1e3, u32::MAX)
                    .is_some());
            }
        }
        // The colonnade's walk is roofed, the ground beside it open to the sky.
        let sc = MeshScene::new(&colonnade());
        assert!(sc
            .intersect_skip(DVec3::new(0.0, 1.5, 0.1), DVec3::Z, 0.0, 1e3, u32::MAX)
            .is_some());
        assert!(sc
            .intersect_skip(DVec3::new(0.0, 6.0, 0.1), DVec3::Z, 0.0, 1e3, u32::MAX)
            .is_none());
        // The hall's east door is open.
        let sc = MeshScene::new(&vaulted_room());
        assert!(sc
            .intersect_skip(DVec3::new(0.0, 0.0, 1.0), DVec3::X, 0.0, 1e3, u32::MAX)
            .is_none());
        assert!(sc
            .intersect_skip(DVec3::new(0.0, 0.0, 1.0), DVec3::NEG_X, 0.0, 1e3, u32::MAX)
            .is_some());
        assert!((relief_depth(-0.015, 0.0) + 0.003).abs() < 1e-12);
        assert_eq!(relief_depth(0.0, 0.028), 0.0);
    }
}
