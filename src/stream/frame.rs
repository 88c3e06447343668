//! One frame's geometry and occlusion: camera-frame points, normals and radii from the
//! cleaned depth map, the G-buffer and pinhole projection the per-view estimator reads
//! (the same `ssao::compute` as `merge`), optionally at a reduced resolution, and the
//! per-pixel weights `w_d·w_n` of the integration.

use super::frames::Intrinsics;
use crate::gbuffer::{GBuffer, EMPTY};
use crate::projection::{Model, Projection};
use crate::ssao::{self, SsaoParams};
use glam::{Mat2, Mat3, Vec2, Vec3};
use rayon::prelude::*;

/// A frame's per-pixel geometry in the camera frame (x right, y down, z forward).
#[derive(Debug, Clone, Default)]
pub struct FrameGeometry {
    /// Width in pixels.
    pub width: usize,
    /// Height in pixels.
    pub height: usize,
    /// Camera-frame point; zero where the pixel has no depth.
    pub points: Vec<Vec3>,
    /// Unit normal facing the camera; zero where it could not be estimated.
    pub normals: Vec<Vec3>,
}

impl FrameGeometry {
    /// True when pixel `i` has a point and a normal.
    #[inline]
    pub fn is_valid(&self, i: usize) -> bool {
        self.points[i].z > 0.0 && self.normals[i] != Vec3::ZERO
    }
}

/// The camera-frame points of a z-depth map (0 = none).
pub fn unproject(depth: &[f32], width: usize, k: &Intrinsics) -> Vec<Vec3> {
    let (ifx, ify) = (1.0 / k.fx as f32, 1.0 / k.fy as f32);
    let (cx, cy) = (k.cx as f32, k.cy as f32);
    depth
        .par_iter()
        .enumerate()
        .map(|(i, &z)| {
            if !(z > 0.0 && z.is_finite()) {
                return Vec3::ZERO;
            }
            let (x, y) = ((i % width.max(1)) as f32, (i / width.max(1)) as f32);
            Vec3::new((x - cx) * z * ifx, (y - cy) * z * ify, z)
        })
        .collect()
}

/// Normals from the depth map: the cross product of the horizontal and vertical differences
/// of neighbouring points (central where both neighbours exist, else one-sided), turned to
/// face the camera. A pixel without a neighbour along one axis gets no normal.
pub fn depth_normals(points: &[Vec3], width: usize, height: usize) -> Vec<Vec3> {
    let at = |x: usize, y: usize| points[y * width + x];
    let valid = |x: usize, y: usize| points[y * width + x].z > 0.0;
    (0..width * height)
        .into_par_iter()
        .map(|i| {
            let (x, y) = (i % width, i / width);
            let p = points[i];
            if !(p.z > 0.0) {
                return Vec3::ZERO;
            }
            let diff = |a: Option<Vec3>, b: Option<Vec3>| match (a, b) {
                (Some(a), Some(b)) => Some(b - a),
                (None, Some(b)) => Some(b - p),
                (Some(a), None) => Some(p - a),
                (None, None) => None,
            };
            let l = (x > 0 && valid(x - 1, y)).then(|| at(x - 1, y));
            let r = (x + 1 < width && valid(x + 1, y)).then(|| at(x + 1, y));
            let u = (y > 0 && valid(x, y - 1)).then(|| at(x, y - 1));
            let d = (y + 1 < height && valid(x, y + 1)).then(|| at(x, y + 1));
            let (Some(dx), Some(dy)) = (diff(l, r), diff(u, d)) else {
                return Vec3::ZERO;
            };
            let n = dx.cross(dy).normalize_or_zero();
            if n.dot(p) > 0.0 {
                -n
            } else {
                n
            }
        })
        .collect()
}

/// The frame's geometry from its cleaned z-depth map.
pub fn geometry(depth: &[f32], width: usize, height: usize, k: &Intrinsics) -> FrameGeometry {
    let points = unproject(depth, width, k);
    let normals = depth_normals(&points, width, height);
    FrameGeometry {
        width,
        height,
        points,
        normals,
    }
}

/// The pinhole projection of intrinsics `k` over a `width × height` map, in the
/// projection module's pixel convention (pixel `i` covers `[i, i + 1)`).
pub fn projection(k: &Intrinsics, width: usize, height: usize) -> Projection {
    Projection::new(
        Model::Perspective {
            rot: Mat3::IDENTITY,
            a: Mat2::from_diagonal(Vec2::new(k.fx as f32, k.fy as f32)),
            c: Vec2::new(k.cx as f32 + 0.5, k.cy as f32 + 0.5),
        },
        width,
        height,
        false,
    )
}

/// The G-buffer of a frame: each valid pixel holds its own point (index = pixel), depth
/// as the projection measures it (distance from the camera) and radius = the pixel's
/// footprint at its depth.
pub fn gbuffer(g: &FrameGeometry, k: &Intrinsics) -> GBuffer {
    let n = g.width * g.height;
    let valid: Vec<bool> = (0..n).into_par_iter().map(|i| g.is_valid(i)).collect();
    let inv_f = 1.0 / k.fx.max(k.fy) as f32;
    GBuffer {
        width: g.width,
        height: g.height,
        point: (0..n)
            .into_par_iter()
            .map(|i| if valid[i] { i as u32 } else { EMPTY })
            .collect(),
        depth: (0..n)
            .into_par_iter()
            .map(|i| {
                if valid[i] {
                    g.points[i].length()
                } else {
                    f32::INFINITY
                }
            })
            .collect(),
        position: (0..n)
            .into_par_iter()
            .map(|i| if valid[i] { g.points[i] } else { Vec3::ZERO })
            .collect(),
        normal: (0..n)
            .into_par_iter()
            .map(|i| if valid[i] { g.normals[i] } else { Vec3::ZERO })
            .collect(),
        radius: (0..n)
            .into_par_iter()
            .map(|i| if valid[i] { g.points[i].z * inv_f } else { 0.0 })
            .collect(),
        lift_receivers: false,
    }
}

/// A z-depth map at `1/factor` of the resolution: per block the mean of its measured
/// depths (the cleaning already removed blocks that straddle an edge).
pub fn downsample(
    depth: &[f32],
    width: usize,
    height: usize,
    factor: usize,
) -> (Vec<f32>, usize, usize) {
    let f = factor.max(1);
    if f == 1 {
        return (depth.to_vec(), width, height);
    }
    let (w, h) = (width / f, height / f);
    let out = (0..w * h)
        .into_par_iter()
        .map(|i| {
            let (bx, by) = (i % w, i / w);
            let (mut sum, mut n) = (0.0f32, 0u32);
            for y in by * f..by * f + f {
                for x in bx * f..bx * f + f {
                    let d = depth[y * width + x];
                    if d > 0.0 {
                        sum += d;
                        n += 1;
                    }
                }
            }
            // A block must be mostly measured, or its mean would stand for a hole's border.
            if n * 2 > (f * f) as u32 {
                sum / n as f32
            } else {
                0.0
            }
        })
        .collect();
    (out, w, h)
}

/// Per-pixel SSAO of a frame at full resolution (`own`, the frame's full-resolution
/// geometry, intrinsics `k`) from its geometry at `1/factor` of it: each pixel reads its
/// block's value. A pixel whose block has none (a block mostly emptied by the cleaning, or
/// without a normal) takes the value of the neighbouring block whose point lies nearest to
/// its own, when that is within two block widths at the pixel's depth, so the pixels the
/// cleaning kept are not lost for sitting in a sparse block while a depth edge still
/// separates blocks; `None` where no block qualifies.
pub fn frame_ssao(
    low: &FrameGeometry,
    k_low: &Intrinsics,
    p: &SsaoParams,
    own: &FrameGeometry,
    k: &Intrinsics,
    factor: usize,
) -> Vec<Option<f32>> {
    let g = gbuffer(low, k_low);
    let proj = projection(k_low, low.width, low.height);
    let map = ssao::compute(&g, &proj, p);
    let f = factor.max(1);
    let (width, height) = (own.width, own.height);
    let value = |j: usize| (g.point[j] != EMPTY && !map.no_sample[j]).then_some(map.ao[j]);
    let reach = 2.0 * f as f32 / k.fx.max(k.fy) as f32;
    (0..width * height)
        .into_par_iter()
        .map(|i| {
            let (x, y) = ((i % width) / f, (i / width) / f);
            if x >= low.width || y >= low.height {
                return None;
            }
            let j = y * low.width + x;
            if let Some(a) = value(j) {
                return Some(a);
            }
            if f == 1 || !own.is_valid(i) {
                return None;
            }
            let q = own.points[i];
            let limit = (reach * q.z).powi(2);
            let mut best: Option<(f32, f32)> = None;
            for ny in y.saturating_sub(1)..(y + 2).min(low.height) {
                for nx in x.saturating_sub(1)..(x + 2).min(low.width) {
                    let jj = ny * low.width + nx;
                    let Some(a) = value(jj) else { continue };
                    let d2 = g.position[jj].distance_squared(q);
                    if d2 <= limit && best.is_none_or(|b| d2 < b.0) {
                        best = Some((d2, a));
                    }
                }
            }
            best.map(|b| b.1)
        })
        .collect()
}

/// The integration weight `w_d·w_n` of a camera-frame point `p` with unit normal `n`:
/// `w_d = max(1 − max(|p| − d_min, 0)/d_max, 0.1)`, `w_n = max(n·l, 0)` with `l` the unit
/// direction to the camera.
#[inline]
pub fn weight(p: Vec3, n: Vec3, dmin: f32, dmax: f32) -> f32 {
    let r = p.length();
    if !(r > 0.0 && dmax > 0.0) {
        return 0.0;
    }
    let wd = (1.0 - (r - dmin).max(0.0) / dmax).max(0.1);
    let wn = n.dot(-p / r).max(0.0);
    wd * wn
}
