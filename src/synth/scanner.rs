//! The virtual scanner: a [`Station`] (pose + sensor model), its [`Projection`], and ray
//! casting one ray per pixel centre into a [`Scene`].
//!
//! Rays are generated in f64 from the same parameters the f32 [`Projection`] is built from,
//! so `project(point)` maps every scanned point back to the centre of its pixel.

use super::mesh::MeshScene;
use super::scene::{Hit, Scene, T_EPS};
use crate::error::{Error, Result};
use crate::projection::{Model, Projection, SensorModel};
use crate::rng::SplitMix64;
use crate::scan::{Grid, Scan};
use glam::{DMat3, DMat4, DVec2, DVec3, Mat2, Vec3};
use rayon::prelude::*;
use std::f64::consts::{FRAC_PI_2, TAU};

/// A scanner position and its sensor. The scan-local frame is the world frame rotated by
/// `yaw` about world z and moved to `position` (its pose is [`Station::pose`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Station {
    /// Sensor origin in world coordinates (for ortho: a point of the sensor plane).
    pub position: DVec3,
    /// Rotation of the local frame about world z (radians).
    pub yaw: f64,
    /// Which sensor model scans.
    pub model: SensorModel,
    /// Map width in pixels.
    pub width: usize,
    /// Map height in pixels.
    pub height: usize,
    /// Perspective: elevation of the optical axis above the local xy plane (radians); the
    /// axis points along local +x when zero. Image x runs along local -y, image y downwards.
    pub pitch: f64,
    /// Perspective: horizontal field of view (radians, square pixels).
    pub fov: f64,
    /// Equirect: elevation band `[min, max]` (radians) covered by the rows, top row = max.
    /// Azimuth always covers the full circle (local +x at the centre column, decreasing to
    /// the right).
    pub elevation: [f64; 2],
    /// Ortho: half extents (metres) of the scanned rectangle along local x and y, centred
    /// on `position`; the sensor looks down local -z (row 0 at local +y).
    pub half_extent: DVec2,
    /// Hits farther than this (metres along the ray) are not recorded.
    pub max_range: f64,
}

impl Station {
    fn base(position: DVec3, yaw: f64, model: SensorModel, width: usize, height: usize) -> Self {
        Station {
            position,
            yaw,
            model,
            width,
            height,
            pitch: 0.0,
            fov: 70f64.to_radians(),
            elevation: [-FRAC_PI_2, FRAC_PI_2],
            half_extent: DVec2::ONE,
            max_range: 200.0,
        }
    }

    /// A full-sphere equirectangular scanner (terrestrial laser scanner).
    pub fn equirect(position: DVec3, yaw: f64, width: usize, height: usize) -> Self {
        Self::base(position, yaw, SensorModel::Equirect, width, height)
    }

    /// A pinhole camera at `position` looking at `target` with horizontal field of view
    /// `fov` (radians).
    pub fn perspective(
        position: DVec3,
        target: DVec3,
        fov: f64,
        width: usize,
        height: usize,
    ) -> Self {
        let d = target - position;
        let mut s = Self::base(
            position,
            d.y.atan2(d.x),
            SensorModel::Perspective,
            width,
            height,
        );
        s.pitch = d.z.atan2(d.x.hypot(d.y));
        s.fov = fov;
        s
    }

    /// A parallel projection looking down, over the rectangle `position ± half_extent` of
    /// the local frame (rotated by `yaw`).
    pub fn ortho(
        position: DVec3,
        yaw: f64,
        half_extent: DVec2,
        width: usize,
        height: usize,
    ) -> Self {
        let mut s = Self::base(position, yaw, SensorModel::Ortho, width, height);
        s.half_extent = half_extent;
        s
    }

    /// Local → world transform: translation to `position` after rotation by `yaw` about z.
    pub fn pose(&self) -> DMat4 {
        DMat4::from_translation(self.position) * DMat4::from_rotation_z(self.yaw)
    }

    /// Checks that the parameters describe a usable sensor.
    pub fn validate(&self) -> Result<()> {
        let bad = |m: String| Err(Error::Param(format!("synthetic station: {m}")));
        if self.width == 0 || self.height == 0 || self.width > 1 << 16 || self.height > 1 << 16 {
            return bad(format!(
                "map size {}x{} out of 1..65536",
                self.width, self.height
            ));
        }
        if !(self.position.is_finite() && self.yaw.is_finite()) {
            return bad("position and yaw must be finite".into());
        }
        if self.max_range.is_nan() || self.max_range <= 0.0 {
            return bad(format!("max range {} must be positive", self.max_range));
        }
        match self.model {
            SensorModel::Equirect => {
                let [lo, hi] = self.elevation;
                if !(lo >= -FRAC_PI_2 && lo < hi && hi <= FRAC_PI_2) {
                    return bad(format!(
                        "elevation band [{lo}, {hi}] not within [-pi/2, pi/2]"
                    ));
                }
            }
            SensorModel::Perspective => {
                let fov_ok = self.fov > 0.0 && self.fov < 3.1;
                if !(fov_ok && self.pitch.abs() <= FRAC_PI_2) {
                    return bad(format!(
                        "fov {} or pitch {} out of range",
                        self.fov, self.pitch
                    ));
                }
            }
            SensorModel::Ortho => {
                if !(self.half_extent.x > 0.0 && self.half_extent.y > 0.0) {
                    return bad(format!(
                        "ortho extent {} must be positive",
                        self.half_extent
                    ));
                }
            }
        }
        Ok(())
    }

    /// The station's sensor model with its map size, mapping scan-local points to pixels.
    /// Ortho depth is measured from the sensor plane (`depth0 = 0`).
    pub fn projection(&self) -> Projection {
        let model = match self.sensor() {
            Sensor::Equirect { sx, ox, sy, oy } => Model::Equirect {
                rot: glam::Mat3::IDENTITY,
                az_ref: 0.0,
                sx: sx as f32,
                ox: ox as f32,
                sy: sy as f32,
                oy: oy as f32,
            },
            Sensor::Perspective { rot, f, c } => Model::Perspective {
                rot: rot.as_mat3(),
                a: Mat2::from_diagonal(f.as_vec2()),
                c: c.as_vec2(),
            },
            Sensor::Ortho { a, a0, b, b0 } => Model::Ortho {
                a: a.as_vec3(),
                a0: a0 as f32,
                b: b.as_vec3(),
                b0: b0 as f32,
                toward: Vec3::Z,
                depth0: 0.0,
            },
        };
        Projection {
            model,
            width: self.width,
            height: self.height,
            wrap_x: self.model == SensorModel::Equirect,
            warp_x: None,
            warp_y: None,
        }
    }

    /// f64 parameters of the sensor (the [`Projection`] is their f32 rounding).
    fn sensor(&self) -> Sensor {
        let (w, h) = (self.width as f64, self.height as f64);
        match self.model {
            SensorModel::Equirect => {
                let [lo, hi] = self.elevation;
                let sy = -h / (hi - lo);
                Sensor::Equirect {
                    sx: -w / TAU,
                    ox: w / 2.0,
                    sy,
                    oy: -sy * hi,
                }
            }
            SensorModel::Perspective => {
                let (sp, cp) = self.pitch.sin_cos();
                let right = DVec3::NEG_Y;
                let down = DVec3::new(sp, 0.0, -cp);
                let fwd = DVec3::new(cp, 0.0, sp);
                let fx = w / 2.0 / (self.fov / 2.0).tan();
                Sensor::Perspective {
                    rot: DMat3::from_cols(right, down, fwd).transpose(),
                    f: DVec2::splat(fx),
                    c: DVec2::new(w / 2.0, h / 2.0),
                }
            }
            SensorModel::Ortho => Sensor::Ortho {
                a: DVec3::new(w / (2.0 * self.half_extent.x), 0.0, 0.0),
                a0: w / 2.0,
                b: DVec3::new(0.0, -h / (2.0 * self.half_extent.y), 0.0),
                b0: h / 2.0,
            },
        }
    }
}

/// f64 sensor parameters, same meaning as in [`Model`].
#[derive(Debug, Clone, Copy)]
enum Sensor {
    Equirect {
        sx: f64,
        ox: f64,
        sy: f64,
        oy: f64,
    },
    Perspective {
        rot: DMat3,
        f: DVec2,
        c: DVec2,
    },
    Ortho {
        a: DVec3,
        a0: f64,
        b: DVec3,
        b0: f64,
    },
}

impl Sensor {
    /// Local ray (origin, unit direction) through continuous pixel `(x, y)`; `o + t·d` has
    /// depth `t`.
    #[inline]
    fn ray(&self, x: f64, y: f64) -> (DVec3, DVec3) {
        match *self {
            Sensor::Equirect { sx, ox, sy, oy } => {
                let az = (x - ox) / sx;
                let el = (y - oy) / sy;
                let (se, ce) = el.sin_cos();
                let (sa, ca) = az.sin_cos();
                (DVec3::ZERO, DVec3::new(ce * ca, ce * sa, se))
            }
            Sensor::Perspective { rot, f, c } => {
                let uv = (DVec2::new(x, y) - c) / f;
                (DVec3::ZERO, rot.transpose() * uv.extend(1.0).normalize())
            }
            Sensor::Ortho { a, a0, b, b0 } => {
                let o = a * ((x - a0) / a.length_squared()) + b * ((y - b0) / b.length_squared());
                (o, DVec3::NEG_Z)
            }
        }
    }
}

/// One recorded pixel.
#[derive(Clone, Copy)]
struct Sample {
    p: Vec3,
    n: Vec3,
    col: u32,
    truth: Truth,
}

/// What the virtual scanner can scan: nearest hits along rays, and solid interiors (where a
/// ray that starts records nothing).
pub trait Geometry: Sync {
    /// Nearest hit of `origin + t·dir` with `t ∈ (t_min, t_max)`.
    fn intersect_range(&self, origin: DVec3, dir: DVec3, t_min: f64, t_max: f64) -> Option<Hit>;
    /// True when `p` lies strictly inside a solid.
    fn inside_solid(&self, _p: DVec3) -> bool {
        false
    }
}

impl Geometry for Scene {
    fn intersect_range(&self, origin: DVec3, dir: DVec3, t_min: f64, t_max: f64) -> Option<Hit> {
        Scene::intersect_range(self, origin, dir, t_min, t_max)
    }
    fn inside_solid(&self, p: DVec3) -> bool {
        Scene::inside_solid(self, p)
    }
}

impl Geometry for MeshScene {
    fn intersect_range(&self, origin: DVec3, dir: DVec3, t_min: f64, t_max: f64) -> Option<Hit> {
        self.intersect_skip(origin, dir, t_min, t_max, u32::MAX)
    }
}

/// The exact surface under a scanned point: where the pixel's ray met the geometry before
/// any noise, in world coordinates.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Truth {
    /// Noise-free world position.
    pub p: DVec3,
    /// Unit world normal of the primitive hit, turned towards the sensor.
    pub n: DVec3,
    /// Index of the primitive hit ([`Hit::prim`]).
    pub prim: u32,
}

/// Scans `scene` from `station`: one ray per pixel centre `(x + 0.5, y + 0.5)`, the nearest
/// hit within `station.max_range` becomes a point (scan-local, f32) with its exact normal
/// turned towards the sensor, in row-major pixel order with its grid cell. `noise_sigma`
/// (metres) adds Gaussian noise to the range along the ray, deterministic for `seed`; the
/// noisy range is kept positive. Pixels whose ray starts inside a solid record nothing. An
/// invalid station (see [`Station::validate`]) yields an empty scan.
pub fn scan_scene(
    scene: &Scene,
    station: &Station,
    noise_sigma: f64,
    seed: u64,
    name: &str,
) -> Scan {
    scan_with_truth(scene, station, noise_sigma, seed, name).0
}

/// [`scan_scene`] of any [`Geometry`], with the exact surface under every point (same
/// order as the scan's points).
pub fn scan_with_truth<G: Geometry>(
    scene: &G,
    station: &Station,
    noise_sigma: f64,
    seed: u64,
    name: &str,
) -> (Scan, Vec<Truth>) {
    let (w, h) = (station.width, station.height);
    let valid = station.validate().is_ok();
    let sensor = station.sensor();
    let rot = DMat3::from_rotation_z(station.yaw);
    let rot_inv = rot.transpose();
    let sigma = if noise_sigma.is_finite() && noise_sigma > 0.0 {
        noise_sigma
    } else {
        0.0
    };
    let ortho = station.model == SensorModel::Ortho;
    let origin_blocked = !ortho && scene.inside_solid(station.position);
    let rows: Vec<Vec<Sample>> = (0..if valid { h } else { 0 })
        .into_par_iter()
        .map(|y| {
            let mut out = Vec::new();
            if origin_blocked {
                return out;
            }
            for x in 0..w {
                let (o, d) = sensor.ray(x as f64 + 0.5, y as f64 + 0.5);
                let ow = station.position + rot * o;
                if ortho && scene.inside_solid(ow) {
                    continue;
                }
                let Some(hit) = scene.intersect_range(ow, rot * d, T_EPS, station.max_range) else {
                    continue;
                };
                let mut t = hit.t;
                if sigma > 0.0 {
                    let g = SplitMix64::new(seed, (y * w + x) as u64).gaussian();
                    t = (t + sigma * g).max(t * 1e-3);
                }
                let mut n = rot_inv * hit.normal;
                if n.dot(d) > 0.0 {
                    n = -n;
                }
                out.push(Sample {
                    p: (o + d * t).as_vec3(),
                    n: n.as_vec3().normalize_or_zero(),
                    col: x as u32,
                    truth: Truth {
                        p: ow + rot * d * hit.t,
                        n: (rot * n).normalize_or_zero(),
                        prim: hit.prim as u32,
                    },
                });
            }
            out
        })
        .collect();
    let total: usize = rows.iter().map(Vec::len).sum();
    let mut points = Vec::with_capacity(total);
    let mut normals = Vec::with_capacity(total);
    let mut row = Vec::with_capacity(total);
    let mut col = Vec::with_capacity(total);
    let mut truth = Vec::with_capacity(total);
    for (y, samples) in rows.iter().enumerate() {
        for s in samples {
            truth.push(s.truth);
            points.push(s.p);
            normals.push(s.n);
            row.push(y as u32);
            col.push(s.col);
        }
    }
    let scan = Scan {
        name: name.to_string(),
        path: None,
        points,
        source_index: (0..total as u32).collect(),
        vertex_count: total,
        normals: Some(normals),
        grid: Some(Grid {
            rows: h as u32,
            cols: w as u32,
            row,
            col,
        }),
        pose: station.pose(),
        skipped_nonfinite: 0,
        sensor_hint: Some(station.model),
        warnings: Vec::new(),
    };
    (scan, truth)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn stations() -> [Station; 3] {
        let pos = DVec3::new(0.3, -0.2, 1.5);
        [
            Station::equirect(pos, 0.7, 360, 180),
            Station::perspective(pos, DVec3::new(2.0, 1.0, 0.5), 1.2, 320, 240),
            Station::ortho(
                DVec3::new(0.0, 0.0, 2.9),
                0.4,
                DVec2::new(3.0, 2.0),
                300,
                160,
            ),
        ]
    }

    #[test]
    fn pixel_ray_project_round_trip_all_models() {
        for st in stations() {
            st.validate().unwrap();
            let proj = st.projection();
            let sensor = st.sensor();
            let (w, h) = (st.width, st.height);
            for y in (0..h).step_by(7).chain([h - 1]) {
                for x in (0..w).step_by(11).chain([w - 1]) {
                    let (px, py) = (x as f64 + 0.5, y as f64 + 0.5);
                    let (o, d) = sensor.ray(px, py);
                    assert!((d.length() - 1.0).abs() < 1e-12);
                    // The f32 projection's own ray agrees with the f64 one.
                    let (o32, d32) = proj.ray(px as f32, py as f32).unwrap();
                    assert!(
                        d32.as_dvec3().distance(d) < 1e-5,
                        "{:?} {d} {d32}",
                        st.model
                    );
                    assert!(o32.as_dvec3().distance(o) < 1e-4);
                    for t in [0.5, 3.7, 20.0] {
                        let p = (o + d * t).as_vec3();
                        let q = proj.project(p).unwrap();
                        let dx = (q.x as f64 - px).rem_euclid(w as f64);
                        let dx = dx.min(w as f64 - dx);
                        assert!(
                            dx < 1e-2 && (q.y as f64 - py).abs() < 1e-2,
                            "{:?} {q:?}",
                            st.model
                        );
                        assert!((q.depth as f64 - t).abs() < 1e-4 * t.max(1.0), "{q:?} {t}");
                        assert_eq!(proj.pixel_index(q.x, q.y), Some(y * w + x));
                    }
                }
            }
        }
    }

    #[test]
    fn room_from_centre_sees_all_six_surfaces_normals_face_sensor() {
        let scene = Scene::room();
        let st = Station::equirect(DVec3::new(0.0, 0.0, 1.5), 0.3, 360, 180);
        let scan = scan_scene(&scene, &st, 0.0, 1, "c");
        assert!(scan.len() > 360 * 170, "{}", scan.len());
        let normals = scan.normals.as_ref().unwrap();
        let mut seen = [0usize; 6];
        for (p, n) in scan.points.iter().zip(normals) {
            assert!(n.dot(-*p) > 0.0, "normal {n} at {p} faces away");
            assert!((n.length() - 1.0).abs() < 1e-5);
            let wp = scan.pose.transform_point3(p.as_dvec3());
            let on = |a: f64, b: f64| (a - b).abs() < 1e-5;
            let checks = [on(wp.z, 0.0), on(wp.z, 3.0), on(wp.x, -4.0), on(wp.x, 4.0)];
            for (k, c) in checks
                .into_iter()
                .chain([on(wp.y, -3.0), on(wp.y, 3.0)])
                .enumerate()
            {
                seen[k] += c as usize;
            }
        }
        assert!(seen.iter().all(|&c| c > 100), "{seen:?}");
        let g = scan.grid.as_ref().unwrap();
        assert_eq!((g.rows, g.cols, g.row.len()), (180, 360, scan.len()));
        assert_eq!(scan.vertex_count, scan.len());
        assert_eq!(
            scan.source_index.last().copied(),
            Some(scan.len() as u32 - 1)
        );
        // Row-major order.
        let keys: Vec<u64> = g
            .row
            .iter()
            .zip(&g.col)
            .map(|(&r, &c)| (r as u64) << 32 | c as u64)
            .collect();
        assert!(keys.windows(2).all(|k| k[0] < k[1]));
    }

    #[test]
    fn scan_is_deterministic_for_a_seed() {
        let scene = Scene::courtyard();
        let st = Station::equirect(DVec3::new(4.0, 3.0, 1.5), 1.0, 200, 100);
        let a = scan_scene(&scene, &st, 0.01, 42, "a");
        let b = scan_scene(&scene, &st, 0.01, 42, "b");
        let c = scan_scene(&scene, &st, 0.01, 43, "c");
        assert_eq!(a.points, b.points);
        assert_eq!(a.normals, b.normals);
        assert_eq!(a.grid, b.grid);
        assert_ne!(a.points, c.points);
        // Open sky: the upper rows miss.
        assert!(a.len() < 200 * 100 && a.len() > 200 * 40);
    }

    #[test]
    fn range_noise_statistics() {
        let scene = Scene::room();
        let st = Station::equirect(DVec3::new(-0.5, 0.4, 1.5), 0.0, 400, 200);
        let sigma = 0.01;
        let clean = scan_scene(&scene, &st, 0.0, 7, "clean");
        let noisy = scan_scene(&scene, &st, sigma, 7, "noisy");
        assert_eq!(clean.grid, noisy.grid);
        let errs: Vec<f64> = clean
            .points
            .iter()
            .zip(&noisy.points)
            .map(|(c, n)| n.as_dvec3().length() - c.as_dvec3().length())
            .collect();
        let n = errs.len() as f64;
        let mean = errs.iter().sum::<f64>() / n;
        let std = (errs.iter().map(|e| (e - mean).powi(2)).sum::<f64>() / n).sqrt();
        assert!(mean.abs() < 4.0 * sigma / n.sqrt(), "mean {mean}");
        assert!((std / sigma - 1.0).abs() < 0.02, "std {std}");
        // Noise moves points along their rays only.
        for (c, m) in clean.points.iter().zip(&noisy.points).step_by(97) {
            assert!(c.normalize().dot(m.normalize()) > 1.0 - 1e-6);
        }
    }

    #[test]
    fn perspective_and_ortho_scans_in_local_frame() {
        let scene = Scene::room();
        // Camera looking straight at the east wall (x = 4) from x = 1 at a height of 1.5 m.
        let st = Station::perspective(
            DVec3::new(1.0, 0.5, 1.5),
            DVec3::new(4.0, 0.5, 1.5),
            1.0,
            64,
            48,
        );
        let scan = scan_scene(&scene, &st, 0.0, 0, "p");
        assert_eq!(scan.len(), 64 * 48);
        let g = scan.grid.as_ref().unwrap();
        // The centre pixel sees the wall 3 m ahead along local +x.
        let i = g
            .row
            .iter()
            .zip(&g.col)
            .position(|(&r, &c)| r == 24 && c == 32)
            .unwrap();
        let p = scan.points[i];
        assert!(
            (p.x - 3.0).abs() < 1e-3 && p.y.abs() < 0.05 && p.z.abs() < 0.05,
            "{p}"
        );
        // Top-down ortho under the ceiling: depth = 2.9 m on the open floor, column skipped.
        let st = Station::ortho(DVec3::new(0.0, 0.0, 2.9), 0.0, DVec2::new(4.0, 3.0), 80, 60);
        let scan = scan_scene(&scene, &st, 0.0, 0, "o");
        assert!(scan.len() < 80 * 60 && scan.len() > 80 * 58);
        // Everything seen from above is horizontal except the ball (about 28 pixels).
        let normals = scan.normals.as_ref().unwrap();
        let flat = normals
            .iter()
            .filter(|n| n.abs_diff_eq(Vec3::Z, 1e-6))
            .count();
        assert!(flat + 40 > scan.len() && normals.iter().all(|n| n.z > 0.0));
        assert!(scan.points.iter().any(|p| (p.z + 2.9).abs() < 1e-5));
        assert!(scan.points.iter().all(|p| p.z < 0.0 && p.z >= -2.9 - 1e-5));
    }

    #[test]
    fn invalid_station_gives_empty_scan() {
        let mut st = Station::equirect(DVec3::ZERO, 0.0, 0, 10);
        assert!(st.validate().is_err());
        assert!(scan_scene(&Scene::room(), &st, 0.0, 0, "x").is_empty());
        st.width = 10;
        st.elevation = [0.5, 0.1];
        assert!(st.validate().is_err());
    }
}
