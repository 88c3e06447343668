//! Leaves out the cells of scan i that a view cannot match because every point the view
//! stored where they project lies nearer or farther from its sensor than eq. 7 allows.
//!
//! [`super::cull`] asks whether a view stored any point near a cell; on a real site most of
//! what it keeps is surface the view saw only from behind something else (the other side of
//! a wall, the floor under a table). Such a point projects onto the occluder, which fails
//! eq. 7's distance test, yet costs a projection and a G-buffer read.
//!
//! The test uses distances to the view's sensor (for an orthographic view, the coordinate along
//! its view axis). They change by at most the distance moved, so eq. 7,
//! `‖q − p_ij‖ < 2·max(rad_i, rad_ij)`, needs `|range(q) − range(p_ij)| < 2·rad_i + 2·rad_ij`.
//! Each 8×8 tile of the view keeps the interval of `range(p) ± 2·rad(p)` over its pixels. A
//! cell is a ball in the view's frame: its range interval, widened by twice the largest radius
//! of its points, must meet the interval of some tile its projection (plus the merge's
//! neighbourhood) touches. When it meets none, no point of the cell can pass eq. 7 in this
//! view. Like the cell test, this one may keep a pair that finds nothing, never the reverse.

use super::cull::PointCells;
use crate::projection::{Footprint, Model, Projection};
use glam::{DMat4, DVec3, Vec3, Vec4};
use rayon::prelude::*;

/// Tile side in pixels.
const TILE: usize = 8;

/// How far a view's stored points are from its sensor, per tile of the map.
#[derive(Debug, Clone, Default)]
pub struct RangeTiles {
    /// Map width, height.
    width: usize,
    height: usize,
    /// Tiles per row.
    across: usize,
    /// Per tile, the smallest `range − 2·rad` and the largest `range + 2·rad` (an empty tile
    /// holds `+∞, −∞`).
    lo: Vec<f32>,
    hi: Vec<f32>,
    /// What `range` measures; `None`: the test is off for this view.
    axis: Option<Axis>,
}

/// The quantity whose change is bounded by the distance moved.
#[derive(Debug, Clone, Copy)]
enum Axis {
    /// Distance to a sensor at the local origin (equirect, perspective).
    Origin,
    /// Coordinate along a unit view axis (orthographic).
    Along(Vec3),
}

impl Axis {
    fn of(proj: &Projection) -> Option<Axis> {
        match proj.model {
            Model::Ortho { toward, .. } => {
                let len = toward.length();
                (len > 0.0 && len.is_finite()).then(|| Axis::Along(toward / len))
            }
            _ => Some(Axis::Origin),
        }
    }

    #[inline]
    fn range(self, p: Vec3) -> f32 {
        match self {
            Axis::Origin => p.length(),
            Axis::Along(u) => u.dot(p),
        }
    }

    fn range64(self, p: DVec3) -> f64 {
        match self {
            Axis::Origin => p.length(),
            Axis::Along(u) => u.as_dvec3().dot(p),
        }
    }
}

impl RangeTiles {
    /// The tiles of a view's packed positions and radii (`near`, row-major, `width` wide;
    /// radius −∞ marks an empty pixel).
    pub fn new(proj: &Projection, width: usize, near: &[Vec4]) -> RangeTiles {
        let axis = Axis::of(proj);
        let height = near.len().checked_div(width).unwrap_or(0);
        let Some(ax) = axis.filter(|_| width > 0 && height > 0) else {
            return RangeTiles::default();
        };
        let across = width.div_ceil(TILE);
        let down = height.div_ceil(TILE);
        let mut lo = vec![f32::INFINITY; across * down];
        let mut hi = vec![f32::NEG_INFINITY; across * down];
        lo.par_chunks_mut(across)
            .zip(hi.par_chunks_mut(across))
            .enumerate()
            .for_each(|(ty, (lo, hi))| {
                let rows = ty * TILE..((ty + 1) * TILE).min(height);
                for row in near[rows.start * width..rows.end * width].chunks_exact(width) {
                    for (x, p) in row.iter().enumerate() {
                        if p.w == f32::NEG_INFINITY {
                            continue;
                        }
                        let r = ax.range(p.truncate());
                        // A NaN radius is no reach (eq. 7's max ignores it); a NaN range
                        // could be anything.
                        let reach = 2.0 * if p.w > 0.0 { p.w } else { 0.0 };
                        let (a, b) = if r.is_nan() {
                            (f32::NEG_INFINITY, f32::INFINITY)
                        } else {
                            (r - reach, r + reach)
                        };
                        let t = x / TILE;
                        lo[t] = lo[t].min(a);
                        hi[t] = hi[t].max(b);
                    }
                }
            });
        RangeTiles {
            width,
            height,
            across,
            lo,
            hi,
            axis,
        }
    }

    /// Heap bytes held.
    pub fn heap_bytes(&self) -> u64 {
        4 * (self.lo.capacity() + self.hi.capacity()) as u64
    }

    /// Whether a tile the footprint touches has an interval meeting `(lo, hi)`.
    fn meets(&self, fp: &Footprint, lo: f64, hi: f64) -> bool {
        let (r0, r1) = (fp.rows.0 / TILE, fp.rows.1.min(self.height - 1) / TILE);
        fp.col_spans().iter().any(|&(c0, c1)| {
            let (c0, c1) = (c0 / TILE, c1.min(self.width - 1) / TILE);
            (r0..=r1).any(|ty| {
                let row = ty * self.across;
                (row + c0..=row + c1)
                    .any(|t| f64::from(self.lo[t]) < hi && f64::from(self.hi[t]) > lo)
            })
        })
    }
}

/// Clears `keep[c]` for each cell `c` of scan i (`t`) that view j cannot match: view j is
/// placed by `pose` (local → world), projects with `proj`, stored `tiles`, and the merge reads
/// a `(2·half + 1)²` neighbourhood around each projection. Does nothing when the view's pose
/// is not rigid (its frame would not keep distances) or its tiles are off.
pub fn cull_hidden(
    keep: &mut [bool],
    t: &PointCells,
    pose: DMat4,
    proj: &Projection,
    tiles: &RangeTiles,
    half: i64,
) {
    let Some(axis) = tiles.axis else {
        return;
    };
    if tiles.width != proj.width || tiles.height != proj.height || !rigid(pose) {
        return;
    }
    let to_view = pose.inverse();
    // One more pixel than the neighbourhood: the merge floors an f32 projection.
    let pad = half + 1;
    keep.par_iter_mut().enumerate().for_each(|(i, k)| {
        if !*k {
            return;
        }
        let (centre, radius, rmax) = t.ball(i);
        if rmax.is_nan() {
            return;
        }
        let c = to_view.transform_point3(centre);
        // The merge transforms points in f32 (rounding grows with the distances involved).
        let r = radius + 1e-5 * (c.length() + 1e-3);
        let Some(fp) = proj.footprint(c, r, pad) else {
            return;
        };
        let m = axis.range64(c);
        let reach = r + 2.0 * f64::from(rmax.max(0.0)) * (1.0 + 1e-5) + 1e-6 * m.abs();
        *k = fp.spans > 0 && tiles.meets(&fp, m - reach, m + reach);
    });
}

/// True when the linear part of `pose` is a rotation (to 10⁻⁶), so it keeps distances.
fn rigid(pose: DMat4) -> bool {
    let m = glam::DMat3::from_mat4(pose);
    let g = m.transpose() * m;
    (g - glam::DMat3::IDENTITY)
        .to_cols_array()
        .iter()
        .all(|v| v.abs() < 1e-6)
}
