//! Choosing a scan's sensor model and map: fitted to the native grid when the scan has one
//! (the grid stays the range map; the fit only places foreign points and sizes the SSAO disk),
//! otherwise built from the point directions at about one pixel per point.

use crate::error::{Error, Result};
use crate::gbuffer::EMPTY;
use crate::projection::{Model, Projection, SensorModel, Warp};
use crate::scan::Scan;
use glam::{DMat3, DMat4, DVec3, DVec4, Mat2, Vec2};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use std::f64::consts::{PI, TAU};

mod loose;

pub use loose::MAP_STEP_MARGIN;
use loose::{auto_model, from_points};

/// What the user asked for with `--projection`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, clap::ValueEnum, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum ProjectionChoice {
    /// Decide from the data (grid fit, or the spread of point directions).
    #[default]
    Auto,
    /// Terrestrial laser scanner (azimuth × elevation).
    Equirect,
    /// Camera or triangulation scanner.
    Perspective,
    /// Linear-motion scanner.
    Ortho,
}

/// A scan's sensor: its projection, how its own points map to pixels, and why it was chosen.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct SensorSetup {
    /// The projection (model + map size).
    pub projection: Projection,
    /// Pixel of each valid point when the native grid is used as the map; `None` means the
    /// points are placed by projecting them.
    pub grid_pixels: Option<Vec<u32>>,
    /// RMS distance (pixels) between the fitted projection and the native grid positions.
    pub fit_rms_px: Option<f64>,
    /// One sentence on what was chosen and why (goes into the report).
    pub reason: String,
}

/// Largest map side (pixels) built from ungridded points.
pub(super) const MAX_SIDE: f64 = 16384.0;
/// A map built from points has at most this many pixels per point (or [`MIN_PIXEL_CAP`]):
/// points bunched in a few tiny patches of a wide field of view (a scanner position far from
/// where it really was) would otherwise ask for a map of gigabytes.
pub(super) const MAX_PIXELS_PER_POINT: f64 = 4.0;
/// The pixel cap for scans of few points.
pub(super) const MIN_PIXEL_CAP: f64 = 65536.0;
/// A native grid with more cells per valid point than this, and more than
/// [`MIN_GRID_CELL_CAP`] cells, is resampled instead (a header declaring a grid far larger
/// than its points). A scan that is mostly sky is sparse too, so the bound is loose.
const MAX_GRID_CELLS_PER_POINT: u64 = 64;
/// Native grids up to this many cells are kept however few points they hold.
const MIN_GRID_CELL_CAP: u64 = 1 << 24;
/// A grid fit worse than this (RMS pixels) is not used; the map is rebuilt from the points.
const MAX_FIT_RMS: f64 = 3.0;
/// Points used for fitting (a deterministic stride subsample beyond this).
const FIT_SAMPLE: usize = 60_000;

/// Chooses the sensor model and map for `scan`.
pub fn setup(scan: &Scan, choice: ProjectionChoice) -> Result<SensorSetup> {
    if scan.is_empty() {
        return Err(Error::scan(&scan.name, "has no valid point"));
    }
    let declared = choice == ProjectionChoice::Auto && scan.sensor_hint.is_some();
    let choice = match (choice, scan.sensor_hint) {
        (ProjectionChoice::Auto, Some(SensorModel::Equirect)) => ProjectionChoice::Equirect,
        (ProjectionChoice::Auto, Some(SensorModel::Perspective)) => ProjectionChoice::Perspective,
        (ProjectionChoice::Auto, Some(SensorModel::Ortho)) => ProjectionChoice::Ortho,
        (c, _) => c,
    };
    let sparse = grid_too_sparse(scan);
    if let Some(grid) = scan.grid.as_ref().filter(|_| !sparse) {
        let mut fits = fit_grid(scan, choice);
        fits.par_iter_mut().for_each(|f| add_warps(f, scan, grid));
        let best = fits
            .into_iter()
            .min_by(|a, b| a.score().total_cmp(&b.score()));
        if let Some(fit) = best {
            if fit.rms <= MAX_FIT_RMS {
                let (w, h) = if fit.swap {
                    (grid.rows, grid.cols)
                } else {
                    (grid.cols, grid.rows)
                };
                let mut projection = fit.projection.clone();
                projection.width = w as usize;
                projection.height = h as usize;
                projection.wrap_x = is_full_circle(&projection);
                // A point without a cell goes where the fitted model puts it.
                let pixels = (0..scan.len())
                    .into_par_iter()
                    .map(|i| {
                        if !grid.has_cell(i) {
                            return projection
                                .project(scan.points[i])
                                .and_then(|pr| projection.pixel_index(pr.x, pr.y))
                                .map_or(EMPTY, |v| v as u32);
                        }
                        let (r, c) = (grid.row[i], grid.col[i]);
                        let (x, y) = if fit.swap { (r, c) } else { (c, r) };
                        y * w + x
                    })
                    .collect();
                let reason = format!(
                    "native {}x{} grid fits the {} model{} within {:.2} px RMS{}",
                    grid.cols,
                    grid.rows,
                    projection.sensor_model(),
                    if fit.warped {
                        " with uneven row/column steps"
                    } else {
                        ""
                    },
                    fit.rms,
                    if declared {
                        " (model declared by the input)"
                    } else if choice == ProjectionChoice::Auto {
                        " (best of the models tried)"
                    } else {
                        " (model given by --projection)"
                    }
                );
                return Ok(SensorSetup {
                    projection,
                    grid_pixels: Some(pixels),
                    fit_rms_px: Some(fit.rms),
                    reason,
                });
            }
        }
    }
    let given = if declared {
        "declared by the input"
    } else {
        "given by --projection"
    };
    let fixed = |model| (model, from_points(&scan.points, model), given.to_string());
    let (model, projection, why) = match choice {
        ProjectionChoice::Auto => auto_model(&scan.points),
        ProjectionChoice::Equirect => fixed(SensorModel::Equirect),
        ProjectionChoice::Perspective => fixed(SensorModel::Perspective),
        ProjectionChoice::Ortho => fixed(SensorModel::Ortho),
    };
    let projection = projection
        .ok_or_else(|| Error::scan(&scan.name, format!("no {model} map fits its points")))?;
    let gridnote = if sparse {
        "native grid has far more cells than points, so it is resampled; "
    } else if scan.grid.is_some() {
        "native grid fits no model within 3 px, so it is resampled; "
    } else {
        ""
    };
    Ok(SensorSetup {
        reason: format!(
            "{gridnote}{model} map of {}x{} px at about one pixel per point: {why}",
            projection.width, projection.height
        ),
        projection,
        grid_pixels: None,
        fit_rms_px: None,
    })
}

/// True when the scan's native grid has far more cells than points (a header declaring a
/// grid far larger than its points), so the map is built from the points instead.
pub fn grid_too_sparse(scan: &Scan) -> bool {
    scan.grid.as_ref().is_some_and(|g| {
        u64::from(g.rows) * u64::from(g.cols)
            > (MAX_GRID_CELLS_PER_POINT * scan.len() as u64).max(MIN_GRID_CELL_CAP)
    })
}

/// True when an equirect map's width spans the whole circle (to half a pixel).
fn is_full_circle(p: &Projection) -> bool {
    match p.model {
        Model::Equirect { sx, .. } => ((sx.abs() as f64) * TAU - p.width as f64).abs() < 0.5,
        _ => false,
    }
}

/// Every `step`-th point, so fits see at most [`FIT_SAMPLE`] points.
pub(super) fn sample_indices(n: usize) -> impl Iterator<Item = usize> {
    let step = n.div_ceil(FIT_SAMPLE).max(1);
    (0..n).step_by(step)
}

/// An orthonormal local → sensor rotation whose third row is `axis`.
pub(super) fn frame_with_axis(axis: DVec3) -> DMat3 {
    let z = axis.normalize();
    let helper = if z.z.abs() < 0.9 { DVec3::Z } else { DVec3::X };
    let x = helper.cross(z).normalize();
    let y = z.cross(x);
    DMat3::from_cols(x, y, z).transpose()
}

/// A candidate fit of a projection to the native grid.
struct Fit {
    projection: Projection,
    swap: bool,
    rms: f64,
    /// Preference among near-equal fits (simpler/more common models first).
    rank: f64,
    /// True when per-axis warps correct uneven grid steps.
    warped: bool,
}

impl Fit {
    fn score(&self) -> f64 {
        self.rms * (1.0 + 0.1 * self.rank)
    }
}

/// Least squares `y ≈ Σ c_k f_k` for small systems; `None` if singular.
fn lstsq<const K: usize>(rows: &[([f64; K], f64)]) -> Option<[f64; K]> {
    let mut ata = [[0.0f64; K]; K];
    let mut atb = [0.0f64; K];
    for (f, y) in rows {
        for i in 0..K {
            atb[i] += f[i] * y;
            for j in 0..K {
                ata[i][j] += f[i] * f[j];
            }
        }
    }
    // Tiny ridge so coplanar data (one wall) still solves; its effect is far below a pixel.
    let tr: f64 = (0..K).map(|i| ata[i][i]).sum::<f64>() / K as f64;
    for (i, row) in ata.iter_mut().enumerate() {
        row[i] += 1e-12 * tr.max(1e-300);
    }
    solve(ata, atb)
}

/// Gaussian elimination with partial pivoting.
fn solve<const K: usize>(mut a: [[f64; K]; K], mut b: [f64; K]) -> Option<[f64; K]> {
    for c in 0..K {
        let p = (c..K).max_by(|&i, &j| a[i][c].abs().total_cmp(&a[j][c].abs()))?;
        if a[p][c].abs() < 1e-300 || !a[p][c].is_finite() {
            return None;
        }
        a.swap(c, p);
        b.swap(c, p);
        let pivot = a[c];
        for r in c + 1..K {
            let f = a[r][c] / pivot[c];
            for (ark, pk) in a[r][c..].iter_mut().zip(&pivot[c..]) {
                *ark -= f * pk;
            }
            b[r] -= f * b[c];
        }
    }
    let mut x = [0.0; K];
    for c in (0..K).rev() {
        let s: f64 = (c + 1..K).map(|k| a[c][k] * x[k]).sum();
        x[c] = (b[c] - s) / a[c][c];
    }
    x.iter().all(|v| v.is_finite()).then_some(x)
}

fn rms_of(sq: f64, n: usize) -> f64 {
    if n == 0 {
        f64::INFINITY
    } else {
        (sq / n as f64).sqrt()
    }
}

/// Adds per-axis warps to a fit when the grid's steps are uneven (and the warps reduce the
/// residual), and updates its RMS.
fn add_warps(fit: &mut Fit, scan: &Scan, grid: &crate::scan::Grid) {
    let (w, h) = if fit.swap {
        (grid.rows as usize, grid.cols as usize)
    } else {
        (grid.cols as usize, grid.rows as usize)
    };
    if w < 2 || h < 2 {
        return;
    }
    let idx: Vec<usize> = sample_indices(scan.len()).collect();
    // (grid index, linear coordinate) per axis; medians per index are robust to the odd point
    // whose linear coordinate is meaningless (a point on an equirect pole has no azimuth).
    let mut per = [Vec::with_capacity(idx.len()), Vec::with_capacity(idx.len())];
    let mut obs = Vec::with_capacity(idx.len());
    for &i in &idx {
        let Some(pr) = fit.projection.project_linear(scan.points[i]) else {
            continue;
        };
        let (gx, gy) = if fit.swap {
            (grid.row[i] as usize, grid.col[i] as usize)
        } else {
            (grid.col[i] as usize, grid.row[i] as usize)
        };
        if gx < w && gy < h {
            per[0].push((gx, pr.x));
            per[1].push((gy, pr.y));
            obs.push((pr.x, pr.y, gx as f32 + 0.5, gy as f32 + 0.5));
        }
    }
    let err = |wx: Option<&Warp>, wy: Option<&Warp>| -> f64 {
        let sq: f64 = obs
            .iter()
            .map(|&(x, y, gx, gy)| {
                let x = wx.map_or(x, |w| w.apply(x));
                let y = wy.map_or(y, |w| w.apply(y));
                ((x - gx) as f64).powi(2) + ((y - gy) as f64).powi(2)
            })
            .sum();
        rms_of(sq, obs.len())
    };
    let base = err(None, None);
    // An evenly stepped grid fits linearly: no warp to look for.
    if base <= 0.3 {
        return;
    }
    let knots = |v: &[(usize, f32)], n: usize| -> Option<Warp> {
        // The median of each index's values: grouped by a counting sort (indices are below
        // `n`), the middle one selected in each group, where a full sort of the pairs cost
        // most of the sensor fit of a small scan.
        if n == 0 {
            return None;
        }
        let mut start = vec![0usize; n + 1];
        for &(k, _) in v {
            start[k.min(n - 1) + 1] += 1;
        }
        for k in 0..n {
            start[k + 1] += start[k];
        }
        let mut vals = vec![0.0f32; v.len()];
        let mut fill = start.clone();
        for &(k, x) in v {
            let k = k.min(n - 1);
            vals[fill[k]] = x;
            fill[k] += 1;
        }
        let mut known: Vec<(usize, f64)> = Vec::new();
        for k in 0..n {
            let group = &mut vals[start[k]..start[k + 1]];
            if group.is_empty() {
                continue;
            }
            let mid = group.len() / 2;
            let (_, m, _) = group.select_nth_unstable_by(mid, f32::total_cmp);
            known.push((k, f64::from(*m)));
        }
        if known.len() < 2 {
            return None;
        }
        // Fill missing indices by linear interpolation (or extrapolation with the end slopes).
        let mut out = vec![0.0f32; n];
        let mut j = 0usize;
        for (k, o) in out.iter_mut().enumerate() {
            while j + 2 < known.len() && known[j + 1].0 < k {
                j += 1;
            }
            let (k0, v0) = known[j];
            let (k1, v1) = known[(j + 1).min(known.len() - 1)];
            let t = (k as f64 - k0 as f64) / (k1 as f64 - k0 as f64).max(1e-12);
            *o = (v0 + t * (v1 - v0)) as f32;
        }
        Warp::new(out)
    };
    let [px, py] = per;
    let wx = knots(&px, w);
    let wy = knots(&py, h);
    let warped = err(wx.as_ref(), wy.as_ref());
    // Keep warps only where they clearly help (an evenly stepped grid fits linearly).
    if warped < 0.8 * base && base > 0.3 {
        fit.projection.warp_x = wx;
        fit.projection.warp_y = wy;
        fit.rms = warped;
        fit.warped = true;
    }
}

/// Fits the models allowed by `choice` to the scan's native grid.
fn fit_grid(scan: &Scan, choice: ProjectionChoice) -> Vec<Fit> {
    let Some(grid) = &scan.grid else {
        return Vec::new();
    };
    let idx: Vec<usize> = sample_indices(scan.len())
        .filter(|&i| grid.has_cell(i))
        .collect();
    if idx.len() < 8 {
        return Vec::new();
    }
    let pts: Vec<DVec3> = idx.iter().map(|&i| scan.points[i].as_dvec3()).collect();
    let rc: Vec<(f64, f64)> = idx
        .iter()
        .map(|&i| (grid.row[i] as f64 + 0.5, grid.col[i] as f64 + 0.5))
        .collect();
    let mut fits = Vec::new();
    let want = |m: ProjectionChoice| choice == ProjectionChoice::Auto || choice == m;
    if want(ProjectionChoice::Equirect) {
        let per_axis: Vec<Vec<Fit>> = [DVec3::X, DVec3::Y, DVec3::Z]
            .par_iter()
            .map(|&axis| fit_equirect(&pts, &rc, axis, (grid.rows, grid.cols)))
            .collect();
        fits.extend(per_axis.into_iter().flatten());
    }
    if want(ProjectionChoice::Perspective) {
        let mean = pts.iter().map(|p| p.normalize_or_zero()).sum::<DVec3>();
        let mut axes = vec![
            DVec3::X,
            DVec3::NEG_X,
            DVec3::Y,
            DVec3::NEG_Y,
            DVec3::Z,
            DVec3::NEG_Z,
        ];
        if mean.length() > 1e-9 {
            axes.push(mean.normalize());
        }
        let per_axis: Vec<Option<Fit>> = axes
            .par_iter()
            .map(|&axis| fit_perspective(&pts, &rc, axis))
            .collect();
        fits.extend(per_axis.into_iter().flatten());
    }
    if want(ProjectionChoice::Ortho) {
        fits.extend(fit_ortho(&pts, &rc));
    }
    fits
}

/// Azimuth (from +x toward +y) and elevation of a sensor-frame point whose pole is z.
pub(super) fn azimuth_elevation(s: DVec3) -> (f64, f64) {
    (s.y.atan2(s.x), s.z.atan2(s.x.hypot(s.y)))
}

/// Equirect fit with pole `axis`: x from azimuth, y from elevation, each a 1-D linear map of
/// row or column (both assignments tried).
fn fit_equirect(pts: &[DVec3], rc: &[(f64, f64)], axis: DVec3, dims: (u32, u32)) -> Vec<Fit> {
    let rot = frame_with_axis(axis);
    let ang: Vec<(f64, f64)> = pts.iter().map(|p| azimuth_elevation(rot * *p)).collect();
    let mut out = Vec::new();
    for swap in [false, true] {
        // The grid's middle (in the azimuth index) maps to azimuth 0, so the ±π seam falls at
        // the grid's edges, where a full-circle scan has its own seam.
        // Data straddling the grid's own seam (a facade behind the scanner occupies the first
        // and last columns) is unwrapped into one run first.
        let width = if swap { dims.0 } else { dims.1 } as f64;
        let xs: Vec<f64> = rc.iter().map(|&(r, c)| if swap { r } else { c }).collect();
        let cut = circular_gap_end(&xs, width);
        let unwrap = |x: f64| if x < cut { x + width } else { x };
        let xs: Vec<f64> = xs.iter().map(|&x| unwrap(x)).collect();
        let az_ref = grid_middle_azimuth(&ang, &xs);
        let mut ax = Vec::with_capacity(ang.len());
        let mut ay = Vec::with_capacity(ang.len());
        for ((az, el), &(r, c)) in ang.iter().zip(rc) {
            let (px, py) = if swap { (unwrap(r), c) } else { (unwrap(c), r) };
            // Azimuth is undefined at the poles: such points only inform the elevation fit.
            if el.cos() > 0.02 {
                ax.push(([wrap_pi(az - az_ref), 1.0], px));
            }
            ay.push(([*el, 1.0], py));
        }
        // Fit the azimuth away from the seam, where a full circle's ±π ambiguity cannot
        // split a column; judge residuals modulo the period.
        let inner: Vec<([f64; 2], f64)> = ax
            .iter()
            .copied()
            .filter(|(f, _)| f[0].abs() < 0.75 * PI)
            .collect();
        let (Some(fx), Some(fy)) = (
            lstsq(if inner.len() >= 8 { &inner } else { &ax }),
            lstsq(&ay),
        ) else {
            continue;
        };
        let period = TAU * fx[0].abs();
        let sqx: f64 = ax
            .iter()
            .map(|(f, x)| {
                let d = (fx[0] * f[0] + fx[1] - x).rem_euclid(period.max(1e-9));
                d.min(period - d).powi(2)
            })
            .sum();
        let sqy: f64 = ay
            .iter()
            .map(|(g, y)| (fy[0] * g[0] + fy[1] - y).powi(2))
            .sum();
        let rms = (rms_of(sqx, ax.len()).powi(2) + rms_of(sqy, ay.len()).powi(2)).sqrt();
        out.push(Fit {
            projection: Projection {
                model: Model::Equirect {
                    rot: rot.as_mat3(),
                    az_ref: az_ref as f32,
                    sx: fx[0] as f32,
                    ox: fx[1] as f32,
                    sy: fy[0] as f32,
                    oy: fy[1] as f32,
                },
                width: 0,
                height: 0,
                wrap_x: false,
                warp_x: None,
                warp_y: None,
            },
            swap,
            rms,
            rank: 0.0,
            warped: false,
        });
    }
    out
}

/// Perspective fit looking along `axis`: pixel = 2×2 affine of (X/Z, Y/Z) plus offset.
fn fit_perspective(pts: &[DVec3], rc: &[(f64, f64)], axis: DVec3) -> Option<Fit> {
    let rot = frame_with_axis(axis);
    let mut ax = Vec::with_capacity(pts.len());
    let mut ay = Vec::with_capacity(pts.len());
    for (p, &(r, c)) in pts.iter().zip(rc) {
        let s = rot * *p;
        if s.z <= 0.05 * s.length() {
            return None; // not all points in front of this camera
        }
        let f = [s.x / s.z, s.y / s.z, 1.0];
        ax.push((f, c));
        ay.push((f, r));
    }
    let fx = lstsq(&ax)?;
    let fy = lstsq(&ay)?;
    let sq: f64 = ax
        .iter()
        .zip(&ay)
        .map(|((f, x), (_, y))| {
            (fx[0] * f[0] + fx[1] * f[1] + fx[2] - x).powi(2)
                + (fy[0] * f[0] + fy[1] * f[1] + fy[2] - y).powi(2)
        })
        .sum();
    Some(Fit {
        projection: Projection {
            model: Model::Perspective {
                rot: rot.as_mat3(),
                a: Mat2::from_cols(
                    Vec2::new(fx[0] as f32, fy[0] as f32),
                    Vec2::new(fx[1] as f32, fy[1] as f32),
                ),
                c: Vec2::new(fx[2] as f32, fy[2] as f32),
            },
            width: 0,
            height: 0,
            wrap_x: false,
            warp_x: None,
            warp_y: None,
        },
        swap: false,
        rms: rms_of(sq, ax.len()),
        rank: 1.0,
        warped: false,
    })
}

/// Orthographic fit: each pixel coordinate an affine function of the 3-D point.
fn fit_ortho(pts: &[DVec3], rc: &[(f64, f64)]) -> Option<Fit> {
    // Centred coordinates keep the constant term apart from the coordinates, so a coplanar
    // scan (no information along its normal) gets no gradient along the normal.
    let mu = pts.iter().sum::<DVec3>() / pts.len().max(1) as f64;
    let feats: Vec<[f64; 4]> = pts
        .iter()
        .map(|p| {
            let q = *p - mu;
            [q.x, q.y, q.z, 1.0]
        })
        .collect();
    let ax: Vec<([f64; 4], f64)> = feats.iter().zip(rc).map(|(f, rc)| (*f, rc.1)).collect();
    let ay: Vec<([f64; 4], f64)> = feats.iter().zip(rc).map(|(f, rc)| (*f, rc.0)).collect();
    let fx = lstsq(&ax)?;
    let fy = lstsq(&ay)?;
    let a = DVec3::new(fx[0], fx[1], fx[2]);
    let b = DVec3::new(fy[0], fy[1], fy[2]);
    let (a0, b0) = (fx[3] - a.dot(mu), fy[3] - b.dot(mu));
    let toward = orient_toward(a.cross(b))?;
    let sq: f64 = pts
        .iter()
        .zip(rc)
        .map(|(p, &(r, c))| (a.dot(*p) + a0 - c).powi(2) + (b.dot(*p) + b0 - r).powi(2))
        .sum();
    let depth0 = ortho_depth0(pts, toward);
    Some(Fit {
        projection: Projection {
            model: Model::Ortho {
                a: a.as_vec3(),
                a0: a0 as f32,
                b: b.as_vec3(),
                b0: b0 as f32,
                toward: toward.as_vec3(),
                depth0: depth0 as f32,
            },
            width: 0,
            height: 0,
            wrap_x: false,
            warp_x: None,
            warp_y: None,
        },
        swap: false,
        rms: rms_of(sq, pts.len()),
        rank: 2.0,
        warped: false,
    })
}

/// An orthographic sensor has no position; its "depth" is measured from a plane placed one
/// scan extent beyond the nearest point, so depths are positive and depth ratios (the
/// border field's relative Laplacian) are well defined.
pub(super) fn ortho_depth0(pts: &[DVec3], toward: DVec3) -> f64 {
    let (mut lo, mut hi) = (DVec3::splat(f64::INFINITY), DVec3::splat(f64::NEG_INFINITY));
    let mut top = f64::NEG_INFINITY;
    for p in pts {
        lo = lo.min(*p);
        hi = hi.max(*p);
        top = top.max(toward.dot(*p));
    }
    top + (hi - lo).length().max(1e-3)
}

/// Unit view axis pointing to the sensor side: by convention an orthographic sensor looks
/// along −z of its local frame (sensor on the +z side), falling back to +y, then +x.
fn orient_toward(v: DVec3) -> Option<DVec3> {
    let v = v.try_normalize()?;
    for e in [DVec3::Z, DVec3::Y, DVec3::X] {
        let d = v.dot(e);
        if d.abs() > 1e-6 {
            return Some(if d > 0.0 { v } else { -v });
        }
    }
    Some(v)
}

/// Wraps an angle into (-π, π] in f64.
pub(super) fn wrap_pi(a: f64) -> f64 {
    let mut r = a % TAU;
    if r > PI {
        r -= TAU;
    } else if r <= -PI {
        r += TAU;
    }
    r
}

/// The first occupied index after the largest circular gap of the occupied indices `xs`
/// (pixel centres in `[0, width)`); 0 when the largest gap already spans the grid's edge.
fn circular_gap_end(xs: &[f64], width: f64) -> f64 {
    let n = width.max(1.0) as usize;
    let mut occ = vec![false; n];
    for &x in xs {
        occ[(x.max(0.0) as usize).min(n - 1)] = true;
    }
    let (mut best_len, mut best_end, mut run) = (0usize, 0usize, 0usize);
    for k in 0..2 * n {
        if occ[k % n] {
            if run > best_len {
                best_len = run;
                best_end = k % n;
            }
            run = 0;
        } else {
            run += 1;
        }
    }
    if best_len == 0 || best_len >= n {
        return 0.0;
    }
    best_end as f64
}

/// Circular mean azimuth of the points whose grid index `xs` is the median index.
fn grid_middle_azimuth(ang: &[(f64, f64)], xs: &[f64]) -> f64 {
    let mut sorted: Vec<f64> = xs.to_vec();
    sorted.sort_by(f64::total_cmp);
    let mid = sorted[sorted.len() / 2];
    let (mut sx, mut sy) = (0.0, 0.0);
    for ((az, el), x) in ang.iter().zip(xs) {
        if (x - mid).abs() < 0.5 && el.cos() > 0.02 {
            sx += az.cos();
            sy += az.sin();
        }
    }
    if sx == 0.0 && sy == 0.0 {
        return seam_opposite(ang.iter().map(|a| a.0));
    }
    sy.atan2(sx)
}

/// The azimuth opposite the largest gap in `az` (so the map's seam falls where no data is).
pub(super) fn seam_opposite(az: impl Iterator<Item = f64>) -> f64 {
    const BINS: usize = 1440;
    let mut hist = [false; BINS];
    for a in az {
        if a.is_finite() {
            let k = (((a + PI) / TAU) * BINS as f64) as usize;
            hist[k.min(BINS - 1)] = true;
        }
    }
    // Longest circular run of empty bins.
    let (mut best_len, mut best_start) = (0usize, 0usize);
    let mut run = 0usize;
    for k in 0..2 * BINS {
        if !hist[k % BINS] {
            run += 1;
            if run > best_len && run <= BINS {
                best_len = run;
                best_start = k + 1 - run;
            }
        } else {
            run = 0;
        }
    }
    if best_len == 0 {
        return 0.0; // full circle: any seam
    }
    let mid = (best_start as f64 + best_len as f64 / 2.0) / BINS as f64 * TAU - PI;
    wrap_pi(mid + PI)
}

/// The sensor of a local projection seen from another scan: the homogeneous sensor point
/// transformed by `rel` (local of this scan → local of the other).
pub fn sensor_in(rel: &DMat4, p: &Projection) -> DVec4 {
    *rel * p.sensor_homogeneous().as_dvec4()
}
