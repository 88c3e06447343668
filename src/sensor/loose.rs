//! Maps for scans without a native grid: which sensor model, where it looks, and a step of
//! about one pixel per point.

use super::{
    azimuth_elevation, frame_with_axis, ortho_depth0, sample_indices, seam_opposite, wrap_pi,
    MAX_PIXELS_PER_POINT, MAX_SIDE, MIN_PIXEL_CAP,
};
use crate::projection::{Model, Projection, SensorModel};
use glam::{DMat3, DVec3, Mat2, Vec2, Vec3};
use rayon::prelude::*;
use std::f64::consts::{FRAC_PI_2, TAU};

/// Chooses the model of an ungridded scan. A scanner sees every point it measured, so the
/// model under which the fewest points hide behind other points wins: the origin-centred model
/// the directions suggest (perspective inside a 60° cone, else equirectangular) against an
/// orthographic view along −z (the grid fit's convention), which triangulation and linear
/// scanners store in a frame whose origin is not where their rays meet.
pub(super) fn auto_model(points: &[Vec3]) -> (SensorModel, Option<Projection>, String) {
    let (model, why) = origin_model(points);
    let map = from_points(points, model);
    let hidden = |map: &Option<Projection>| map.as_ref().map_or(1.0, |p| hidden_share(points, p));
    let origin = hidden(&map);
    if origin <= ORTHO_MIN_GAIN {
        return (model, map, why);
    }
    let ortho_map = from_points(points, SensorModel::Ortho);
    let ortho = hidden(&ortho_map);
    if ortho < 0.5 * origin && origin - ortho > ORTHO_MIN_GAIN {
        let pc = |v: f64| 100.0 * v;
        let why = format!(
            "no grid; {:.1} % of the points hide behind others seen along −z, {:.1} % seen \
             from the origin ({model})",
            pc(ortho),
            pc(origin)
        );
        return (SensorModel::Ortho, ortho_map, why);
    }
    (model, map, why)
}

/// An orthographic view replaces the origin-centred model when it hides this share of the
/// points fewer (and half as many): the bunny's Cyberware scans hide 0.5–2.6 % seen along −z
/// and 7–34 % from their frame's origin; a camera or scanner in its own frame hides none.
const ORTHO_MIN_GAIN: f64 = 0.02;

/// Equirectangular or perspective from the spread of the point directions around the origin.
fn origin_model(points: &[Vec3]) -> (SensorModel, String) {
    let idx: Vec<usize> = sample_indices(points.len()).collect();
    let dirs: Vec<DVec3> = idx
        .iter()
        .filter_map(|&i| points[i].as_dvec3().try_normalize())
        .collect();
    let mean = dirs.iter().sum::<DVec3>();
    let Some(m) = mean.try_normalize() else {
        return (
            SensorModel::Equirect,
            "no grid; point directions surround the origin".into(),
        );
    };
    let mut ang: Vec<f64> = dirs
        .iter()
        .map(|d| d.dot(m).clamp(-1.0, 1.0).acos())
        .collect();
    ang.sort_by(f64::total_cmp);
    let q = ang[((ang.len() as f64 * 0.99) as usize).min(ang.len() - 1)].to_degrees();
    if q <= 60.0 {
        (
            SensorModel::Perspective,
            format!(
                "no grid; 99 % of point directions lie within {q:.0}° of their mean, a camera cone"
            ),
        )
    } else {
        (
            SensorModel::Equirect,
            format!("no grid; point directions spread {q:.0}° from their mean, wider than a camera (60°)"),
        )
    }
}

/// Share of a sample of `points` lying behind another sampled point by more than
/// [`HIDDEN_DEPTH_CELLS`] cells' width, on a grid a few times coarser than `map` (so that
/// the sample fills it and uneven steps leave no holes); a point without an image counts as
/// hidden. A surface at up to 76° of incidence spans less depth than that within a cell.
fn hidden_share(points: &[Vec3], map: &Projection) -> f64 {
    let sample: Vec<Vec3> = sample_indices(points.len()).map(|i| points[i]).collect();
    let f = (2.0 * (points.len() as f64 / sample.len().max(1) as f64).sqrt()).max(2.0) as f32;
    let (cw, ch) = (
        (map.width as f32 / f) as usize + 1,
        (map.height as f32 / f) as usize + 1,
    );
    let cell = |x: f32, y: f32| {
        let (cx, cy) = ((x / f).floor(), (y / f).floor());
        (cx >= 0.0 && cy >= 0.0 && (cx as usize) < cw && (cy as usize) < ch)
            .then(|| cy as usize * cw + cx as usize)
    };
    let seen: Vec<Option<(usize, f32, f32)>> = sample
        .iter()
        .map(|&p| {
            let pr = map.project(p)?;
            let k = cell(pr.x, pr.y)?;
            // Width of one map pixel at the point, from the map's own inverse.
            let at = |dx: f32, dy: f32| map.unproject(pr.x + dx, pr.y + dy, pr.depth);
            let w = (at(1.0, 0.0) - at(0.0, 0.0))
                .length()
                .max((at(0.0, 1.0) - at(0.0, 0.0)).length());
            (pr.depth.is_finite() && w.is_finite()).then_some((k, pr.depth, w * f))
        })
        .collect();
    let mut front = vec![f32::INFINITY; cw * ch];
    for &(k, d, _) in seen.iter().flatten() {
        front[k] = front[k].min(d);
    }
    let hidden = seen
        .iter()
        .filter(|s| s.is_none_or(|(k, d, w)| d > front[k] + HIDDEN_DEPTH_CELLS * w))
        .count();
    hidden as f64 / sample.len().max(1) as f64
}

/// Depth (in cells' widths) behind the nearest point of a cell at which a point is hidden.
const HIDDEN_DEPTH_CELLS: f32 = 4.0;

/// Angular (or linear) step so that the occupied part of the map has about one pixel per
/// point. A scanner samples evenly in its own coordinates `uv` (azimuth and elevation, or image
/// plane), so the occupied area is counted there, unweighted, on coarse bins. A bin the points'
/// outline crosses counts whole, which overstates the area by about half a bin per unit of
/// outline: counted at two bin sizes, the overstatement is extrapolated away (a map too
/// coarse puts two points in a pixel and loses one; too fine, it leaves holes in surfaces).
fn step_from_occupancy(uv: &[(f64, f64)], n: usize, lo: (f64, f64), hi: (f64, f64)) -> f64 {
    let span = ((hi.0 - lo.0).max(1e-12), (hi.1 - lo.1).max(1e-12));
    // Aim at ~16 sample points per occupied bin (an even count, for the halved grid).
    let nb = 2 * ((uv.len() as f64 / 64.0).sqrt().clamp(2.0, 256.0) as usize);
    let mut occ = vec![false; nb * nb];
    for &(u, v) in uv {
        let i = (((u - lo.0) / span.0 * nb as f64) as usize).min(nb - 1);
        let j = (((v - lo.1) / span.1 * nb as f64) as usize).min(nb - 1);
        occ[j * nb + i] = true;
    }
    let fine = occ.iter().filter(|&&o| o).count() as f64;
    let half = nb / 2;
    let coarse = (0..half * half)
        .filter(|&c| {
            let (i, j) = (2 * (c % half), 2 * (c / half));
            occ[j * nb + i]
                || occ[j * nb + i + 1]
                || occ[(j + 1) * nb + i]
                || occ[(j + 1) * nb + i + 1]
        })
        .count() as f64;
    // Area in fine bins: the outline's share doubles with the bin side.
    let bins = (2.0 * fine - 4.0 * coarse).clamp(0.5 * fine, fine);
    let cell = span.0 / nb as f64 * span.1 / nb as f64;
    (bins * cell / n.max(1) as f64).sqrt() * MAP_STEP_MARGIN
}

/// A map built from loose points is this much coarser than the points' spacing as estimated.
/// Two points in one pixel cost little (each reads the pixel's AO); a surface pixel left
/// empty is a hole that the SSAO and the merge's border weight take for a depth edge. The
/// estimate is good to a few per cent: on three mesh scenes stripped of their grids
/// (`docs/design.md`), maps 3 % finer than the spacing raised the merged e_A by up to 45 %,
/// 3 % coarser came within 0–7 % of the native grid.
pub const MAP_STEP_MARGIN: f64 = 1.03;

/// Builds a map of the given model from ungridded points (about one pixel per point).
pub(super) fn from_points(points: &[Vec3], model: SensorModel) -> Option<Projection> {
    let idx: Vec<usize> = sample_indices(points.len()).collect();
    let pts: Vec<DVec3> = idx
        .iter()
        .map(|&i| points[i].as_dvec3())
        .filter(|p| p.length() > 0.0)
        .collect();
    if pts.is_empty() {
        return None;
    }
    let n = points.len();
    match model {
        SensorModel::Equirect => {
            let rot = equirect_pole(&pts);
            let az_ref = seam_opposite(pts.iter().map(|p| azimuth_elevation(rot * *p).0));
            let uv_of = |p: Vec3| {
                let q = rot * p.as_dvec3();
                (q.length() > 0.0).then(|| {
                    let (az, el) = azimuth_elevation(q);
                    (wrap_pi(az - az_ref), el)
                })
            };
            let ae: Vec<(f64, f64)> = pts.iter().filter_map(|p| uv_of(p.as_vec3())).collect();
            // Azimuth and elevation are the scanner's own axes: no rotation.
            let grid = Sampling::measure(points, ae, uv_of, false, true).fit(
                TAU,
                (MAX_SIDE, MAX_SIDE / 2.0),
                cap(n),
            );
            let (lo, hi, su, sv) = (grid.lo, grid.hi, grid.su, grid.sv);
            let full = hi.0 - lo.0 > TAU - 3.0 * su.max(TAU / 720.0);
            let (width, ox) = if full {
                let w = (TAU / su).ceil();
                (w, w / 2.0)
            } else {
                ((hi.0 - lo.0) / su + 1.0, -lo.0 / su + 0.5)
            };
            Some(Projection {
                model: Model::Equirect {
                    rot: rot.as_mat3(),
                    az_ref: az_ref as f32,
                    sx: (if full { width / TAU } else { 1.0 / su }) as f32,
                    ox: ox as f32,
                    sy: (-1.0 / sv) as f32,
                    oy: (hi.1 / sv + 0.5) as f32,
                },
                width: width.ceil() as usize,
                height: ((hi.1 - lo.1) / sv + 1.0).ceil() as usize,
                wrap_x: full,
                warp_x: None,
                warp_y: None,
            })
        }
        SensorModel::Perspective => {
            let axis = pts
                .iter()
                .map(|p| p.normalize())
                .sum::<DVec3>()
                .try_normalize()?;
            let rot = frame_with_axis(axis);
            let uv_of = |p: Vec3| {
                let s = rot * p.as_dvec3();
                (s.z > 0.0).then(|| (s.x / s.z, s.y / s.z))
            };
            let uv: Vec<(f64, f64)> = pts.iter().filter_map(|p| uv_of(p.as_vec3())).collect();
            if uv.is_empty() {
                return None;
            }
            let g = Sampling::measure(points, uv, uv_of, true, true).fit(
                0.0,
                (MAX_SIDE, MAX_SIDE),
                cap(n),
            );
            let (c, s) = (g.theta.cos(), g.theta.sin());
            Some(Projection {
                model: Model::Perspective {
                    rot: rot.as_mat3(),
                    a: Mat2::from_cols(
                        Vec2::new((c / g.su) as f32, (-s / g.sv) as f32),
                        Vec2::new((s / g.su) as f32, (c / g.sv) as f32),
                    ),
                    c: Vec2::new((-g.lo.0 / g.su + 0.5) as f32, (-g.lo.1 / g.sv + 0.5) as f32),
                },
                width: g.width(),
                height: g.height(),
                wrap_x: false,
                warp_x: None,
                warp_y: None,
            })
        }
        SensorModel::Ortho => {
            let uv_of = |p: Vec3| Some((p.x as f64, -(p.y as f64)));
            let xy: Vec<(f64, f64)> = pts.iter().filter_map(|p| uv_of(p.as_vec3())).collect();
            let g = Sampling::measure(points, xy, uv_of, true, false).fit(
                0.0,
                (MAX_SIDE, MAX_SIDE),
                cap(n),
            );
            let (c, s) = (g.theta.cos(), g.theta.sin());
            // (u, v) = (x, −y) rotated by −θ, then scaled per axis.
            let a = DVec3::new(c, -s, 0.0) / g.su;
            let b = DVec3::new(-s, -c, 0.0) / g.sv;
            let depth0 = ortho_depth0(&pts, DVec3::Z) as f32;
            Some(Projection {
                model: Model::Ortho {
                    a: a.as_vec3(),
                    a0: (-g.lo.0 / g.su + 0.5) as f32,
                    b: b.as_vec3(),
                    b0: (-g.lo.1 / g.sv + 0.5) as f32,
                    toward: Vec3::Z,
                    depth0,
                },
                width: g.width(),
                height: g.height(),
                wrap_x: false,
                warp_x: None,
                warp_y: None,
            })
        }
    }
}

/// Local → sensor rotation of an ungridded equirectangular scan: the pole along local z,
/// unless another axis makes the sampling far more even. A scanner steps evenly in its own
/// azimuth and elevation, so the sample's counts over the occupied inner bins of an
/// azimuth × elevation histogram vary little about the true pole (coefficient of variation
/// 0.00–0.10 on synthetic stations and the 3DTK ones, whose pole is local y) and by 0.8–1.5
/// about a wrong one.
fn equirect_pole(pts: &[DVec3]) -> DMat3 {
    let unevenness = |rot: DMat3| {
        let nb = 2 * ((pts.len() as f64 / 64.0).sqrt().clamp(2.0, 256.0) as usize);
        let ae: Vec<(f64, f64)> = pts.iter().map(|p| azimuth_elevation(rot * *p)).collect();
        let (lo, hi) = bounds2(&ae);
        let bin = |x: f64, lo: f64, hi: f64| {
            (((x - lo) / (hi - lo).max(1e-12) * nb as f64) as usize).min(nb - 1)
        };
        let mut count = vec![0u32; nb * nb];
        for &(a, e) in &ae {
            count[bin(e, lo.1, hi.1) * nb + bin(a, lo.0, hi.0)] += 1;
        }
        let occupied = |i: usize, j: usize| count[j * nb + i % nb] > 0;
        let (mut n, mut sum, mut sq) = (0.0, 0.0, 0.0);
        for j in 1..nb - 1 {
            for i in 0..nb {
                let inner = occupied(i, j)
                    && occupied(i + 1, j)
                    && occupied(i + nb - 1, j)
                    && occupied(i, j - 1)
                    && occupied(i, j + 1);
                if inner {
                    let c = f64::from(count[j * nb + i]);
                    (n, sum, sq) = (n + 1.0, sum + c, sq + c * c);
                }
            }
        }
        if n < 16.0 {
            return f64::INFINITY;
        }
        let mean = sum / n;
        ((sq / n - mean * mean).max(0.0)).sqrt() / mean
    };
    let z = unevenness(DMat3::IDENTITY);
    [DVec3::Y, DVec3::X]
        .into_iter()
        .map(|axis| {
            let rot = frame_with_axis(axis);
            (unevenness(rot), rot)
        })
        .filter(|&(u, _)| u < 0.5 * z && u < z - 0.2)
        .min_by(|a, b| a.0.total_cmp(&b.0))
        .map_or(DMat3::IDENTITY, |(_, rot)| rot)
}

/// Pixel cap of a map built from `n` points.
fn cap(n: usize) -> f64 {
    (MAX_PIXELS_PER_POINT * n as f64).max(MIN_PIXEL_CAP)
}

/// How a loose scan samples its sensor coordinates `(u, v)`: the area per point (from
/// occupancy, see [`step_from_occupancy`]) split into two steps by the ratio of the
/// spacings along and across the direction at angle `theta` of the u axis, where the points'
/// nearest neighbours lie. Linear and triangulation scanners step their sweep and their line
/// differently (3.2 : 1 in a synthetic orthographic survey, 1.45 : 1 in the bunny's Cyberware
/// scans); an isotropic map then leaves holes across the coarse axis and doubles points along
/// the fine one.
struct Sampling {
    /// Sample points in (u, v).
    uv: Vec<(f64, f64)>,
    /// Side of a square pixel with the same area per point.
    step: f64,
    /// Coarse step over fine step (1 for isotropic sampling).
    ratio: f64,
    theta: f64,
}

/// A map's axes and steps in sensor coordinates: pixel x = (u' − lo.0) / su, y likewise, with
/// (u', v') the sensor coordinates rotated by −θ.
struct MapGrid {
    lo: (f64, f64),
    hi: (f64, f64),
    su: f64,
    sv: f64,
    theta: f64,
}

impl MapGrid {
    fn width(&self) -> usize {
        ((self.hi.0 - self.lo.0) / self.su + 1.0).ceil() as usize
    }
    fn height(&self) -> usize {
        ((self.hi.1 - self.lo.1) / self.sv + 1.0).ceil() as usize
    }
}

/// Sampling ratios below this are treated as even steps (the estimate's own scatter).
const MIN_STEP_RATIO: f64 = 1.15;
/// Largest step ratio the neighbour search can resolve.
const MAX_STEP_RATIO: f64 = 8.0;

impl Sampling {
    /// `uv`: the sample's sensor coordinates; `uv_of` maps any point (all of `points` are
    /// read in a window around the sample's middle, where their full density shows the steps).
    /// `rotate`: the map may turn to the sampling's direction; `angular`: `uv` are angles (or
    /// a unit image plane), so a cone around the window's direction holds the window.
    fn measure(
        points: &[Vec3],
        uv: Vec<(f64, f64)>,
        uv_of: impl Fn(Vec3) -> Option<(f64, f64)> + Sync,
        rotate: bool,
        angular: bool,
    ) -> Sampling {
        let (lo, hi) = bounds2(&uv);
        let step = step_from_occupancy(&uv, points.len(), lo, hi);
        let (mut ratio, mut theta) =
            neighbour_steps(points, &uv, &uv_of, step, angular).unwrap_or((1.0, 0.0));
        if !rotate {
            // Snap to the nearer axis; a sampling oblique to fixed axes stays isotropic.
            let snapped = (theta / FRAC_PI_2).round() * FRAC_PI_2;
            if (theta - snapped).abs() > 10f64.to_radians() {
                ratio = 1.0;
            }
            theta = snapped;
        }
        if ratio < MIN_STEP_RATIO {
            (ratio, theta) = (1.0, 0.0);
        }
        Sampling {
            uv,
            step,
            ratio,
            theta,
        }
    }

    /// Steps and bounds, each side at most `max_side` pixels and the map at most `cap` pixels
    /// (over a u span of `u_span`, or the data's own span when 0).
    fn fit(&self, u_span: f64, max_side: (f64, f64), cap: f64) -> MapGrid {
        let (c, s) = (self.theta.cos(), self.theta.sin());
        let rotated: Vec<(f64, f64)> = self
            .uv
            .iter()
            .map(|&(u, v)| (c * u + s * v, -s * u + c * v))
            .collect();
        let (lo, hi) = bounds2(&rotated);
        let span = ((hi.0 - lo.0).max(0.0), (hi.1 - lo.1).max(0.0));
        let k = self.ratio.sqrt();
        let (mut su, mut sv) = (self.step / k, self.step * k);
        su = su.max(span.0 / max_side.0);
        sv = sv.max(span.1 / max_side.1);
        let area = if u_span > 0.0 { u_span } else { span.0 } * span.1;
        let grow = (area / cap / (su * sv)).sqrt();
        if grow > 1.0 {
            (su, sv) = (su * grow, sv * grow);
        }
        MapGrid {
            lo,
            hi,
            su: su.max(1e-9),
            sv: sv.max(1e-9),
            theta: self.theta,
        }
    }
}

/// Points read around the sample's middle to measure the steps.
const STEP_WINDOW_POINTS: f64 = 4096.0;

/// Step ratio and direction of the fine step from the nearest neighbours of the points in a
/// window at full density: per point the nearest neighbour, and the nearest one more than 60°
/// away from it. `None` when too few points or when the fine direction is not consistent
/// (an irregular or isotropic sampling).
fn neighbour_steps(
    points: &[Vec3],
    uv: &[(f64, f64)],
    uv_of: &(impl Fn(Vec3) -> Option<(f64, f64)> + Sync),
    step: f64,
    angular: bool,
) -> Option<(f64, f64)> {
    if !(step > 0.0) || uv.is_empty() {
        return None;
    }
    // The sample point nearest the coordinatewise median: a window on data, not in a hole.
    let med = |f: fn(&(f64, f64)) -> f64| {
        let mut v: Vec<f64> = uv.iter().map(f).collect();
        v.sort_by(f64::total_cmp);
        v[v.len() / 2]
    };
    let m = (med(|p| p.0), med(|p| p.1));
    let centre = *uv.iter().min_by(|a, b| {
        let d = |p: &(f64, f64)| (p.0 - m.0).powi(2) + (p.1 - m.1).powi(2);
        d(a).total_cmp(&d(b))
    })?;
    let half = 0.5 * STEP_WINDOW_POINTS.sqrt() * step;
    let cells = (2.0 * half / step).ceil() as usize + 1;
    // Angles between directions are at most twice the window's half-side in either angular
    // coordinate: a dot product skips the trigonometry of points far from the window.
    let cone = angular
        .then(|| {
            sample_indices(points.len())
                .map(|i| points[i])
                .find(|&p| uv_of(p) == Some(centre))
                .and_then(|p| p.as_dvec3().try_normalize())
        })
        .flatten()
        .filter(|_| 2.0 * half < 1.0)
        .map(|dir| (dir, (2.0 * half).cos()));
    let win: Vec<(f64, f64)> = points
        .par_iter()
        .filter(|p| {
            cone.is_none_or(|(dir, cos)| {
                let p = p.as_dvec3();
                p.dot(dir) >= cos * p.length()
            })
        })
        .filter_map(|&p| uv_of(p))
        .map(|(u, v)| (u - centre.0, v - centre.1))
        .filter(|&(u, v)| u.abs() < half && v.abs() < half)
        .collect();
    if win.len() < 64 || win.len() > 16 * STEP_WINDOW_POINTS as usize {
        return None;
    }
    let cell_of = |(u, v): (f64, f64)| {
        let c = |x: f64| (((x + half) / step) as usize).min(cells - 1);
        (c(u), c(v))
    };
    let mut start = vec![0usize; cells * cells + 1];
    for &p in &win {
        let (i, j) = cell_of(p);
        start[j * cells + i + 1] += 1;
    }
    for k in 1..start.len() {
        start[k] += start[k - 1];
    }
    let mut fill = start.clone();
    let mut order = vec![0usize; win.len()];
    for (idx, &p) in win.iter().enumerate() {
        let (i, j) = cell_of(p);
        order[fill[j * cells + i]] = idx;
        fill[j * cells + i] += 1;
    }
    const REACH: isize = 4;
    let near = |idx: usize, away_from: Option<(f64, f64)>| {
        let p = win[idx];
        let (ci, cj) = cell_of(p);
        let mut best: Option<(f64, (f64, f64))> = None;
        for dj in -REACH..=REACH {
            for di in -REACH..=REACH {
                let (i, j) = (ci as isize + di, cj as isize + dj);
                if i < 0 || j < 0 || i >= cells as isize || j >= cells as isize {
                    continue;
                }
                let k = j as usize * cells + i as usize;
                for &o in &order[start[k]..start[k + 1]] {
                    let d = (win[o].0 - p.0, win[o].1 - p.1);
                    let l2 = d.0 * d.0 + d.1 * d.1;
                    if l2 <= (1e-6 * step).powi(2) || best.is_some_and(|b| b.0 <= l2) {
                        continue;
                    }
                    if let Some(a) = away_from {
                        let cos =
                            (d.0 * a.0 + d.1 * a.1).abs() / (l2 * (a.0 * a.0 + a.1 * a.1)).sqrt();
                        if cos >= 0.5 {
                            continue;
                        }
                    }
                    best = Some((l2, d));
                }
            }
        }
        best
    };
    let (mut fine, mut coarse) = (Vec::new(), Vec::new());
    let (mut c2, mut s2) = (0.0, 0.0);
    for (idx, p) in win.iter().enumerate() {
        if p.0.abs() > 0.5 * half || p.1.abs() > 0.5 * half {
            continue;
        }
        let Some((l1, d1)) = near(idx, None) else {
            continue;
        };
        let Some((l2, _)) = near(idx, Some(d1)) else {
            continue;
        };
        fine.push(l1.sqrt());
        coarse.push(l2.sqrt());
        let phi = d1.1.atan2(d1.0);
        c2 += (2.0 * phi).cos();
        s2 += (2.0 * phi).sin();
    }
    if fine.len() < 32 || c2.hypot(s2) < 0.5 * fine.len() as f64 {
        return None;
    }
    let median = |v: &mut Vec<f64>| {
        v.sort_by(f64::total_cmp);
        v[v.len() / 2]
    };
    let ratio = median(&mut coarse) / median(&mut fine).max(f64::MIN_POSITIVE);
    Some((ratio.clamp(1.0, MAX_STEP_RATIO), 0.5 * s2.atan2(c2)))
}

fn bounds2(v: &[(f64, f64)]) -> ((f64, f64), (f64, f64)) {
    let mut lo = (f64::INFINITY, f64::INFINITY);
    let mut hi = (f64::NEG_INFINITY, f64::NEG_INFINITY);
    for &(a, b) in v {
        lo = (lo.0.min(a), lo.1.min(b));
        hi = (hi.0.max(a), hi.1.max(b));
    }
    (lo, hi)
}
