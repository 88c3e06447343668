//! Sensor models: a scan-local point ↔ a continuous pixel position and depth, the pixel radius
//! of a sphere at a given depth, and where the sensor is. Holds no buffers or points.
//!
//! Conventions (scan-local frame, metres):
//! - **Equirectangular** (terrestrial laser scanner at the origin): `rot` turns local
//!   coordinates into the sensor frame whose +z is the pole. Azimuth `az = atan2(y, x)` taken
//!   relative to `az_ref` (so the seam lies where the scan has no data), elevation
//!   `el = atan2(z, hypot(x, y))`; `x_px = sx·az + ox`, `y_px = sy·el + oy` (signed scales).
//!   A map covering the whole circle wraps in x.
//! - **Perspective** (camera or triangulation scanner at the origin): sensor frame looks along
//!   +z; `(u, v) = (X/Z, Y/Z)` and `(x_px, y_px) = A·(u, v) + c`.
//! - **Orthographic** (linear-motion scanner): `x_px = a·p + a0`, `y_px = b·p + b0`, a
//!   parallel projection along `a × b`; the sensor is at infinity in direction `toward`.
//!
//! Depth is the distance to the sensor (equirect, perspective) or the distance along the
//! view axis from the scan's nearest point (orthographic). Pixel `i` spans `[i, i+1)`.

use glam::{DVec2, DVec3, Mat2, Mat3, Vec2, Vec3, Vec4};
use serde::{Deserialize, Serialize};
use std::sync::Arc;

/// Which sensor model a scan uses.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum SensorModel {
    /// Azimuth × elevation map of a scanner at the origin.
    Equirect,
    /// Pinhole camera at the origin.
    Perspective,
    /// Parallel projection (linear sweep).
    Ortho,
}

impl std::fmt::Display for SensorModel {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            SensorModel::Equirect => "equirect",
            SensorModel::Perspective => "perspective",
            SensorModel::Ortho => "ortho",
        })
    }
}

/// Model-specific parameters of a [`Projection`].
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub enum Model {
    /// See the module docs.
    Equirect {
        /// Local → sensor frame (pole = +z).
        rot: Mat3,
        /// Azimuth (radians) mapped to the middle of the seam's opposite side.
        az_ref: f32,
        /// Pixels per radian of azimuth (signed).
        sx: f32,
        /// x offset.
        ox: f32,
        /// Pixels per radian of elevation (signed).
        sy: f32,
        /// y offset.
        oy: f32,
    },
    /// See the module docs.
    Perspective {
        /// Local → sensor frame (looks along +z).
        rot: Mat3,
        /// Image-plane affine (pixels per unit of X/Z, Y/Z).
        a: Mat2,
        /// Principal point offset.
        c: Vec2,
    },
    /// See the module docs.
    Ortho {
        /// x_px gradient (pixels per metre).
        a: Vec3,
        /// x_px offset.
        a0: f32,
        /// y_px gradient.
        b: Vec3,
        /// y_px offset.
        b0: f32,
        /// Unit direction from the surface towards the sensor.
        toward: Vec3,
        /// Depth of a point = `depth0 - toward·p`.
        depth0: f32,
    },
}

/// A monotone piecewise-linear correction of one pixel axis: a native grid whose rows (or
/// columns) were not taken at even angular steps (a scanner head turning at varying speed)
/// is mapped exactly, where a single linear fit would be off by pixels.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Warp {
    /// `knots[k]` = the linear-model coordinate of grid index `k`'s centre, strictly increasing.
    knots: Arc<[f32]>,
}

impl Warp {
    /// A warp from strictly increasing knots; `None` if they are not (or fewer than 2).
    pub fn new(knots: Vec<f32>) -> Option<Warp> {
        let ok = knots.len() >= 2
            && knots.iter().all(|k| k.is_finite())
            && knots.windows(2).all(|w| w[1] > w[0]);
        ok.then(|| Warp {
            knots: knots.into(),
        })
    }

    /// Linear-model coordinate → grid coordinate (pixel `k` spans `[k, k+1)`), extrapolating
    /// with the end slopes.
    #[inline]
    pub fn apply(&self, u: f32) -> f32 {
        let k = &self.knots;
        let n = k.len();
        let i = k.partition_point(|&v| v <= u).clamp(1, n - 1);
        let (a, b) = (k[i - 1], k[i]);
        (i - 1) as f32 + 0.5 + (u - a) / (b - a)
    }

    /// Grid pixels per linear-model unit around grid coordinate `x`.
    #[inline]
    pub fn slope_at(&self, x: f32) -> f32 {
        let k = &self.knots;
        let i = ((x - 0.5).floor().max(0.0) as usize).min(k.len() - 2);
        1.0 / (k[i + 1] - k[i])
    }

    /// Grid coordinate → linear-model coordinate (inverse of [`apply`](Self::apply)).
    #[inline]
    pub fn invert(&self, x: f32) -> f32 {
        let k = &self.knots;
        let n = k.len();
        let t = x - 0.5;
        let i = (t.floor().max(0.0) as usize).min(n - 2);
        k[i] + (t - i as f32) * (k[i + 1] - k[i])
    }
}

/// A sensor model with its map size: everything needed to go between a scan's local points
/// and its G-buffer pixels.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Projection {
    /// Parameters.
    pub model: Model,
    /// Map width in pixels.
    pub width: usize,
    /// Map height in pixels.
    pub height: usize,
    /// True when x wraps around (a full-circle equirectangular map).
    pub wrap_x: bool,
    /// Optional correction of x after the model (native grids with uneven steps).
    pub warp_x: Option<Warp>,
    /// Optional correction of y after the model.
    pub warp_y: Option<Warp>,
}

/// A projected point: continuous pixel coordinates and depth.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Projected {
    /// Continuous x (pixel `floor(x)`).
    pub x: f32,
    /// Continuous y.
    pub y: f32,
    /// Distance to the sensor (see module docs), metres.
    pub depth: f32,
}

/// `floor(v)` as an integer without a libm call (hot in the SSAO and merge loops);
/// NaN maps to `i64::MIN`, which is outside every map.
#[inline]
pub fn floor_i64(v: f32) -> i64 {
    if v.is_nan() {
        return i64::MIN;
    }
    // `as` saturates at the i64 range, so ±∞ and huge values stay far outside any map.
    let t = v as i64;
    if (t as f32) > v {
        t.saturating_sub(1)
    } else {
        t
    }
}

/// `floor(v)` as an integer without a libm call (baseline x86-64 has no rounding
/// instruction): same as `v.floor() as i64`, saturating, NaN → 0.
#[inline]
pub fn floor_f64(v: f64) -> i64 {
    let t = v as i64;
    if (t as f64) > v {
        t.saturating_sub(1)
    } else {
        t
    }
}

/// Wraps an angle into (-π, π].
#[inline]
pub fn wrap_angle(a: f32) -> f32 {
    use std::f32::consts::{PI, TAU};
    // The common case (a difference of two angles) needs no division.
    if a > -PI && a <= PI {
        return a;
    }
    let mut r = if a.abs() < 2.0 * TAU { a } else { a % TAU };
    if r > PI {
        r -= TAU;
    } else if r <= -PI {
        r += TAU;
    }
    if r > PI {
        r -= TAU;
    } else if r <= -PI {
        r += TAU;
    }
    r
}

impl Projection {
    /// Whether the map reaches every azimuth around the sensor (a full-circle equirectangular
    /// station): what the sensor saw, it saw in every direction.
    pub fn all_round(&self) -> bool {
        matches!(self.model, Model::Equirect { .. }) && self.wrap_x
    }

    /// Which of the three models this is.
    pub fn sensor_model(&self) -> SensorModel {
        match self.model {
            Model::Equirect { .. } => SensorModel::Equirect,
            Model::Perspective { .. } => SensorModel::Perspective,
            Model::Ortho { .. } => SensorModel::Ortho,
        }
    }

    /// A projection without warps.
    pub fn new(model: Model, width: usize, height: usize, wrap_x: bool) -> Projection {
        Projection {
            model,
            width,
            height,
            wrap_x,
            warp_x: None,
            warp_y: None,
        }
    }

    /// Projects a local point. `None` when the point has no image (at the sensor, behind a
    /// perspective camera, or non-finite). The result may lie outside the map.
    #[inline]
    pub fn project(&self, p: Vec3) -> Option<Projected> {
        self.project_linear(p).map(|pr| self.warped(pr))
    }

    /// `pr` through the grid warps, where there are any.
    #[inline]
    fn warped(&self, mut pr: Projected) -> Projected {
        if let Some(w) = &self.warp_x {
            pr.x = w.apply(pr.x);
        }
        if let Some(w) = &self.warp_y {
            pr.y = w.apply(pr.y);
        }
        pr
    }

    /// [`Projection::project`] of four points at once: the same values, bit for bit (a test
    /// checks it), with the arithmetic of an equirect model done on SIMD lanes (its two
    /// arctangents and square roots four at a time); other models go one point at a time.
    #[inline]
    pub fn project4(&self, p: [Vec3; 4]) -> [Option<Projected>; 4] {
        let Model::Equirect {
            rot,
            az_ref,
            sx,
            ox,
            sy,
            oy,
        } = self.model
        else {
            return p.map(|p| self.project(p));
        };
        let lane = |f: fn(&Vec3) -> f32| Vec4::new(f(&p[0]), f(&p[1]), f(&p[2]), f(&p[3]));
        let (px, py, pz) = (lane(|v| v.x), lane(|v| v.y), lane(|v| v.z));
        let c = Vec4::splat;
        // `rot * p` as glam computes it: (x_axis·x + y_axis·y) + z_axis·z.
        let (a, b, d) = (rot.x_axis, rot.y_axis, rot.z_axis);
        let s_x = c(a.x) * px + c(b.x) * py + c(d.x) * pz;
        let s_y = c(a.y) * px + c(b.y) * py + c(d.y) * pz;
        let s_z = c(a.z) * px + c(b.z) * py + c(d.z) * pz;
        let r2 = s_x * s_x + s_y * s_y;
        let depth = sqrt4(r2 + s_z * s_z);
        let ok = (depth.cmpgt(Vec4::ZERO) & depth.is_finite_mask()).bitmask();
        let az = atan2_4(s_y, s_x) - c(az_ref);
        let el = atan2_4(s_z, sqrt4(r2));
        let (az, el, depth) = (az.to_array(), el.to_array(), depth.to_array());
        let mut out = [None; 4];
        for (l, o) in out.iter_mut().enumerate() {
            if ok & (1 << l) == 0 {
                continue;
            }
            *o = Some(self.warped(Projected {
                x: sx * wrap_angle(az[l]) + ox,
                y: sy * el[l] + oy,
                depth: depth[l],
            }));
        }
        out
    }

    /// The model's projection before any warp.
    #[inline]
    pub fn project_linear(&self, p: Vec3) -> Option<Projected> {
        match self.model {
            Model::Equirect {
                rot,
                az_ref,
                sx,
                ox,
                sy,
                oy,
            } => {
                let s = rot * p;
                let r2 = s.x * s.x + s.y * s.y;
                let depth = (r2 + s.z * s.z).sqrt();
                if !(depth > 0.0 && depth.is_finite()) {
                    return None;
                }
                let az = wrap_angle(fast_atan2(s.y, s.x) - az_ref);
                let el = fast_atan2(s.z, r2.sqrt());
                Some(Projected {
                    x: sx * az + ox,
                    y: sy * el + oy,
                    depth,
                })
            }
            Model::Perspective { rot, a, c } => {
                let s = rot * p;
                if !(s.z > 0.0 && s.is_finite()) {
                    return None;
                }
                let uv = Vec2::new(s.x / s.z, s.y / s.z);
                let px = a * uv + c;
                Some(Projected {
                    x: px.x,
                    y: px.y,
                    depth: s.length(),
                })
            }
            Model::Ortho {
                a,
                a0,
                b,
                b0,
                toward,
                depth0,
            } => {
                if !p.is_finite() {
                    return None;
                }
                Some(Projected {
                    x: a.dot(p) + a0,
                    y: b.dot(p) + b0,
                    depth: depth0 - toward.dot(p),
                })
            }
        }
    }

    /// The image-space derivative of [`Projection::project`] at `p` along `d` (pixels per unit
    /// of `d`), in closed form for an equirect model without warps; `None` for the other
    /// models (callers take a finite difference) and where it is undefined (on the pole).
    #[inline]
    pub fn image_derivative(&self, p: Vec3, d: Vec3) -> Option<(f32, f32)> {
        let Model::Equirect { rot, sx, sy, .. } = self.model else {
            return None;
        };
        if self.warp_x.is_some() || self.warp_y.is_some() {
            return None;
        }
        let (s, ds) = (rot * p, rot * d);
        let r2 = s.x * s.x + s.y * s.y;
        let d2 = r2 + s.z * s.z;
        if !(r2 > 0.0 && d2.is_finite()) {
            return None;
        }
        let r = r2.sqrt();
        // d(az) = (x dy − y dx)/r², d(el) = (r² dz − z (x dx + y dy))/(r·|s|²).
        let daz = (s.x * ds.y - s.y * ds.x) / r2;
        let del = (r2 * ds.z - s.z * (s.x * ds.x + s.y * ds.y)) / (r * d2);
        let out = (sx * daz, sy * del);
        (out.0.is_finite() && out.1.is_finite()).then_some(out)
    }

    /// The pixel index (row-major) holding continuous position `(x, y)`, wrapping x on a
    /// full-circle map; `None` outside the map.
    #[inline]
    pub fn pixel_index(&self, x: f32, y: f32) -> Option<usize> {
        if !(x.is_finite() && y.is_finite()) {
            return None;
        }
        self.pixel_at(floor_i64(x), floor_i64(y))
    }

    /// The index of integer pixel `(ix, iy)`, wrapping x on a full-circle map.
    #[inline]
    pub fn pixel_at(&self, ix: i64, iy: i64) -> Option<usize> {
        let (w, h) = (self.width as i64, self.height as i64);
        if iy < 0 || iy >= h || w == 0 {
            return None;
        }
        let ix = if self.wrap_x {
            // One wrap covers every disk on the map; the division is the rare fallback.
            if ix < 0 && ix >= -w {
                ix + w
            } else if ix >= w && ix < 2 * w {
                ix - w
            } else {
                ix.rem_euclid(w)
            }
        } else if ix < 0 || ix >= w {
            return None;
        } else {
            ix
        };
        Some((iy * w + ix) as usize)
    }

    /// Inverse of [`project`](Self::project): the local point at continuous pixel `(x, y)` and
    /// `depth`. Used by the virtual scanner and round-trip tests.
    pub fn unproject(&self, x: f32, y: f32, depth: f32) -> Vec3 {
        self.ray(x, y)
            .map(|(o, d)| o + d * depth)
            .unwrap_or(Vec3::ZERO)
    }

    /// The viewing ray through continuous pixel `(x, y)`: origin `o` and direction `d` such that
    /// `o + t·d` has depth `t` (`d` is a unit vector for point sensors, and for an orthographic
    /// sensor whose view axis is perpendicular to its image axes). `None` for a degenerate model.
    pub fn ray(&self, x: f32, y: f32) -> Option<(Vec3, Vec3)> {
        let x = self.warp_x.as_ref().map_or(x, |w| w.invert(x));
        let y = self.warp_y.as_ref().map_or(y, |w| w.invert(y));
        match self.model {
            Model::Equirect {
                rot,
                az_ref,
                sx,
                ox,
                sy,
                oy,
            } => {
                if sx == 0.0 || sy == 0.0 {
                    return None;
                }
                let az = (x - ox) / sx + az_ref;
                let el = (y - oy) / sy;
                let s = Vec3::new(el.cos() * az.cos(), el.cos() * az.sin(), el.sin());
                Some((Vec3::ZERO, rot.transpose() * s))
            }
            Model::Perspective { rot, a, c } => {
                if a.determinant() == 0.0 {
                    return None;
                }
                let uv = a.inverse() * (Vec2::new(x, y) - c);
                let s = Vec3::new(uv.x, uv.y, 1.0).normalize();
                Some((Vec3::ZERO, rot.transpose() * s))
            }
            Model::Ortho {
                a,
                a0,
                b,
                b0,
                toward,
                depth0,
            } => {
                let m = Mat3::from_cols(a, b, toward).transpose();
                if !(m.determinant().abs() > 1e-20) {
                    return None;
                }
                let inv = m.inverse();
                let o = inv * Vec3::new(x - a0, y - b0, depth0);
                Some((o, inv * Vec3::new(0.0, 0.0, -1.0)))
            }
        }
    }

    /// Unit direction from local point `p` towards the sensor (zero at the sensor itself).
    #[inline]
    pub fn toward_sensor(&self, p: Vec3) -> Vec3 {
        match self.model {
            Model::Ortho { toward, .. } => toward,
            _ => (-p).normalize_or_zero(),
        }
    }

    /// The sensor as a homogeneous local point: `(x, y, z, 1)` for a sensor at a point,
    /// `(dx, dy, dz, 0)` for one at infinity in direction `d`. Transforms with a 4×4 pose.
    pub fn sensor_homogeneous(&self) -> Vec4 {
        match self.model {
            Model::Ortho { toward, .. } => toward.extend(0.0),
            _ => Vec4::new(0.0, 0.0, 0.0, 1.0),
        }
    }

    /// Pixel radii `(rx, ry)` of a sphere of radius `r` (metres) at `depth`, seen at continuous
    /// pixel `(x, y)`: the paper's depth-adaptive disk, widened in x near an equirect map's poles so
    /// that it stays a disk on the sphere.
    #[inline]
    pub fn disk_radius(&self, r: f32, depth: f32, x: f32, y: f32) -> (f32, f32) {
        let (rx, ry) =
            self.disk_radius_linear(r, depth, self.warp_y.as_ref().map_or(y, |w| w.invert(y)));
        // A warp stretches pixels locally: scale by its slope here.
        let sx = self.warp_x.as_ref().map_or(1.0, |w| w.slope_at(x));
        let sy = self.warp_y.as_ref().map_or(1.0, |w| w.slope_at(y));
        ((rx * sx).min(self.width as f32 * 0.5), ry * sy)
    }

    #[inline]
    fn disk_radius_linear(&self, r: f32, depth: f32, y: f32) -> (f32, f32) {
        match self.model {
            Model::Equirect { sx, sy, oy, .. } => {
                let beta = angular_radius(r, depth);
                let el = if sy != 0.0 { (y - oy) / sy } else { 0.0 };
                let c = el.cos().max(1e-3);
                let ry = beta * sy.abs();
                let rx = (beta * sx.abs() / c).min(self.width as f32 * 0.5);
                (rx, ry)
            }
            Model::Perspective { a, .. } => {
                let t = angular_radius(r, depth).tan();
                (t * a.row(0).length(), t * a.row(1).length())
            }
            Model::Ortho { a, b, .. } => (r * a.length(), r * b.length()),
        }
    }
}

/// The pixels a ball of local points can be read at: [`Projection::footprint`].
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Footprint {
    /// First and last row (inclusive).
    pub rows: (usize, usize),
    /// Column spans (inclusive), the first `spans` of them: more than one where the ball
    /// straddles the seam of a map that wraps.
    pub cols: [(usize, usize); 4],
    /// Number of column spans in use (0: the ball projects outside the map).
    pub spans: usize,
}

impl Footprint {
    /// The column spans in use.
    pub fn col_spans(&self) -> &[(usize, usize)] {
        &self.cols[..self.spans]
    }
}

/// Margin on angles computed in f64 for the f32 projection (whose `atan2` is within 3·10⁻⁷
/// rad and whose rounding is a few ulps of π).
const ANGLE_MARGIN: f64 = 1e-5;

impl Projection {
    /// Every pixel within `pad` pixels (along each axis) of where a point of the ball with
    /// centre `c` and radius `r` (local frame) projects. Computed in f64 with margins for the
    /// f32 projection's rounding, so a pad of one pixel more than the neighbourhood read around
    /// a projection covers every pixel a merge reads for a point of the ball. `None` when no
    /// bound exists: the ball holds the sensor, crosses a camera's image plane, or is not
    /// finite. A footprint with no column span: the ball projects outside the map.
    pub fn footprint(&self, c: DVec3, r: f64, pad: i64) -> Option<Footprint> {
        use std::f64::consts::{FRAC_PI_2, PI, TAU};
        if !(c.is_finite() && r >= 0.0 && r.is_finite()) {
            return None;
        }
        // Continuous pre-warp ranges: up to two along x (either side of a seam), one along y.
        let mut xs = [(0.0f64, 0.0f64); 2];
        let nx;
        let ys;
        match self.model {
            Model::Equirect {
                rot,
                az_ref,
                sx,
                ox,
                sy,
                oy,
            } => {
                let s = rot.as_dmat3() * c;
                let dist = s.length();
                if !(dist > r * (1.0 + 1e-6) + 1e-9) {
                    return None;
                }
                let alpha = (r / dist).asin() + ANGLE_MARGIN;
                let el = s.z.atan2(s.x.hypot(s.y));
                let (el0, el1) = ((el - alpha).max(-FRAC_PI_2), (el + alpha).min(FRAC_PI_2));
                let (sx, ox, sy, oy) = (sx as f64, ox as f64, sy as f64, oy as f64);
                ys = sorted(sy * el0 + oy, sy * el1 + oy);
                // Azimuths of the cap: all of them round a pole, else ±asin(sin α / cos el)
                // (the meridians tangent to the cap).
                let full = el + alpha >= FRAC_PI_2 || el - alpha <= -FRAC_PI_2;
                let half = if full {
                    PI
                } else {
                    (alpha.sin() / el.cos()).min(1.0).asin() + ANGLE_MARGIN
                };
                let az = s.y.atan2(s.x) - az_ref as f64;
                let az = az - TAU * ((az + PI) / TAU).floor();
                let (lo, hi) = (az - half, az + half);
                let mut n = 0;
                if hi - lo >= TAU {
                    xs[0] = sorted(sx * -PI + ox, sx * PI + ox);
                    n = 1;
                } else {
                    // The projection wraps azimuths into (−π, π]: the interval and its copies
                    // a turn either way, as far as they meet that range.
                    for k in [-TAU, 0.0, TAU] {
                        let (a, b) = ((lo + k).max(-PI), (hi + k).min(PI));
                        if a <= b && n < 2 {
                            xs[n] = sorted(sx * a + ox, sx * b + ox);
                            n += 1;
                        }
                    }
                }
                nx = n;
            }
            Model::Perspective { rot, a, c: c0 } => {
                let s = rot.as_dmat3() * c;
                // The ball's bounding box, wholly in front of the image plane: its image lies in
                // the hull of its corners' images.
                if !(s.z - r > 1e-9 * (1.0 + s.z.abs())) {
                    return None;
                }
                let (mut u0, mut u1, mut v0, mut v1) = (f64::MAX, f64::MIN, f64::MAX, f64::MIN);
                for k in 0..8 {
                    let sign = |b: usize| if k & b == 0 { -r } else { r };
                    let p = s + DVec3::new(sign(1), sign(2), sign(4));
                    let (u, v) = (p.x / p.z, p.y / p.z);
                    (u0, u1, v0, v1) = (u0.min(u), u1.max(u), v0.min(v), v1.max(v));
                }
                let (a, c0) = (a.as_dmat2(), c0.as_dvec2());
                let (mut x, mut y) = ((f64::MAX, f64::MIN), (f64::MAX, f64::MIN));
                for uv in [(u0, v0), (u0, v1), (u1, v0), (u1, v1)] {
                    let px = a * DVec2::new(uv.0, uv.1) + c0;
                    x = (x.0.min(px.x), x.1.max(px.x));
                    y = (y.0.min(px.y), y.1.max(px.y));
                }
                // Relative rounding of the f32 division and affine map.
                let grow = |(lo, hi): (f64, f64)| {
                    let m = 1e-5 * (1.0 + lo.abs().max(hi.abs()));
                    (lo - m, hi + m)
                };
                xs[0] = grow(x);
                ys = grow(y);
                nx = 1;
            }
            Model::Ortho { a, a0, b, b0, .. } => {
                let (a, b) = (a.as_dvec3(), b.as_dvec3());
                let grow = |g: DVec3, o: f32| {
                    let m = g.dot(c) + o as f64;
                    let e = g.length() * r + 1e-5 * (1.0 + m.abs());
                    (m - e, m + e)
                };
                xs[0] = grow(a, a0);
                ys = grow(b, b0);
                nx = 1;
            }
        }
        let warp = |w: &Option<Warp>, (lo, hi): (f64, f64)| match w {
            Some(w) => (w.apply(lo as f32) as f64, w.apply(hi as f32) as f64),
            None => (lo, hi),
        };
        // Integer pixel spans, `pad` pixels wider (saturating far outside any map).
        let span = |(lo, hi): (f64, f64)| {
            let f = |v: f64| v.floor().clamp(-1e15, 1e15) as i64;
            (f(lo).saturating_sub(pad), f(hi).saturating_add(pad))
        };
        let (w, h) = (self.width as i64, self.height as i64);
        let mut fp = Footprint {
            rows: (0, 0),
            cols: [(0, 0); 4],
            spans: 0,
        };
        if !(ys.0.is_finite() && ys.1.is_finite()) {
            return None;
        }
        let (r0, r1) = span(warp(&self.warp_y, ys));
        if w == 0 || r1 < 0 || r0 >= h {
            return Some(fp);
        }
        fp.rows = (r0.max(0) as usize, r1.min(h - 1) as usize);
        for &x in &xs[..nx] {
            if !(x.0.is_finite() && x.1.is_finite()) {
                return None;
            }
            let (c0, c1) = span(warp(&self.warp_x, x));
            let mut push = |a: i64, b: i64| {
                if a <= b && fp.spans < 4 {
                    fp.cols[fp.spans] = (a as usize, b as usize);
                    fp.spans += 1;
                }
            };
            if !self.wrap_x {
                push(c0.max(0), c1.min(w - 1));
            } else if c1 - c0 + 1 >= w {
                fp.cols[0] = (0, w as usize - 1);
                fp.spans = 1;
                return Some(fp);
            } else {
                let (a, b) = (c0.rem_euclid(w), c1.rem_euclid(w));
                if a <= b {
                    push(a, b);
                } else {
                    push(a, w - 1);
                    push(0, b);
                }
            }
        }
        Some(fp)
    }
}

/// `(a, b)` in ascending order.
#[inline]
fn sorted(a: f64, b: f64) -> (f64, f64) {
    if a <= b {
        (a, b)
    } else {
        (b, a)
    }
}

/// Angle subtended by the radius of a sphere of radius `r` at distance `depth` (radians),
/// capped at 89° when the sensor is inside the sphere.
#[inline]
pub fn angular_radius(r: f32, depth: f32) -> f32 {
    if depth <= r || depth <= 0.0 {
        return 89f32.to_radians();
    }
    (r / depth).asin().min(89f32.to_radians())
}

/// Coefficients of [`fast_atan2`]'s polynomial in `s = q²`, lowest first: `atan q ≈ q·P(s)`
/// on `[0, 1]`. Shared with the SIMD version in the horizon SSAO, which must give the same bits.
pub(crate) const ATAN_COEFFS: [f32; 7] = [
    0.999_996_1,
    -0.333_173_7,
    0.198_078_34,
    -0.132_334_12,
    0.079_624_95,
    -0.033_605_33,
    0.006_812_162,
];

/// [`fast_atan2`] on four lanes: the same operations, with selects where it branches.
#[inline(always)]
pub fn atan2_4(y: Vec4, x: Vec4) -> Vec4 {
    use std::f32::consts::{FRAC_PI_2, PI};
    let (ax, ay) = (x.abs(), y.abs());
    let swap = ax.cmplt(ay);
    let (mn, mx) = (Vec4::select(swap, ax, ay), Vec4::select(swap, ay, ax));
    let q = mn / mx;
    let s = q * q;
    let c = Vec4::splat;
    let (&top, rest) = ATAN_COEFFS.split_last().unwrap_or((&0.0, &[]));
    let mut r = q * rest.iter().rev().fold(c(top), |acc, &k| c(k) + s * acc);
    r = Vec4::select(ay.cmpgt(ax), c(FRAC_PI_2) - r, r);
    let left = x.cmplt(Vec4::ZERO);
    r = Vec4::select(left, c(PI) - r, r);
    // −0 has the sign bit set and compares equal to 0.
    let negative_zero = x.cmpeq(Vec4::ZERO) & Vec4::ONE.copysign(x).cmplt(Vec4::ZERO);
    let special = Vec4::select(left | negative_zero, c(PI), Vec4::ZERO);
    Vec4::select(mx.cmpgt(Vec4::ZERO), r, special).copysign(y)
}

/// `f32::sqrt` on four lanes (correctly rounded, as the scalar one).
#[inline(always)]
pub fn sqrt4(v: Vec4) -> Vec4 {
    #[cfg(all(target_arch = "x86_64", target_feature = "sse2"))]
    {
        use std::arch::x86_64::_mm_sqrt_ps;
        // SAFETY: SSE2 is enabled (checked by the cfg).
        Vec4::from(unsafe { _mm_sqrt_ps(v.into()) })
    }
    #[cfg(not(all(target_arch = "x86_64", target_feature = "sse2")))]
    {
        Vec4::from_array(v.to_array().map(f32::sqrt))
    }
}

/// `atan2(y, x)` in `(−π, π]` to within 3·10⁻⁷ rad (odd minimax-fitted polynomial of degree
/// 13 on `[0, 1]` after octant reduction).
#[inline]
pub fn fast_atan2(y: f32, x: f32) -> f32 {
    let (ax, ay) = (x.abs(), y.abs());
    let (mn, mx) = if ax < ay { (ax, ay) } else { (ay, ax) };
    if !(mx > 0.0) {
        return if x < 0.0 || (x == 0.0 && x.is_sign_negative()) {
            std::f32::consts::PI.copysign(y)
        } else {
            0.0f32.copysign(y)
        };
    }
    let q = mn / mx;
    let s = q * q;
    // Horner's rule, innermost (highest) coefficient first.
    let (&top, rest) = ATAN_COEFFS.split_last().unwrap_or((&0.0, &[]));
    let mut r = q * rest.iter().rev().fold(top, |acc, &c| c + s * acc);
    if ay > ax {
        r = std::f32::consts::FRAC_PI_2 - r;
    }
    if x < 0.0 {
        r = std::f32::consts::PI - r;
    }
    r.copysign(y)
}
