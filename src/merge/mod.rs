//! Merging views (eq. 6–12): for every point of scan i and every scan j (i included), find the
//! point scan j stored at the projection of `M_j⁻¹ M_i p_i` (and its N×N neighbours), keep it
//! when it is the same surface seen from the right side (eq. 7), and average the views' SSAO
//! with weights `w_d·w_n·w_b`. Relative transforms are composed in f64 once per pair and
//! applied to the f32 local points. Reads no files, rasterizes nothing.

pub mod border;
pub mod weights;

use crate::gbuffer::{GBuffer, EMPTY};
use crate::projection::Projection;
use glam::{Affine3A, DMat4, Vec3, Vec3A};
use rayon::prelude::*;
use serde::Serialize;
use weights::{corresponds, w_border, w_distance, w_normal};

/// What the merge needs of one view (scan j).
#[derive(Debug, Clone, Copy)]
pub struct View<'a> {
    /// Scan j's projection.
    pub proj: &'a Projection,
    /// Scan j's G-buffer.
    pub gbuf: &'a GBuffer,
    /// Scan j's per-pixel SSAO (after blur).
    pub ao: &'a [f32],
    /// Scan j's per-pixel distance (pixels) to the nearest depth discontinuity.
    pub border: &'a [f32],
    /// Scan j's local → world pose.
    pub pose: DMat4,
}

/// Merge parameters (after defaults).
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct MergeParams {
    /// Neighbourhood side N (odd): N×N pixels around each projection.
    pub neighbors: u32,
    /// `d_min` of eq. 10 (metres).
    pub dmin: f32,
    /// `d_max` of eq. 10 (metres).
    pub dmax: f32,
    /// `t_p` of eq. 12 (pixels).
    pub border_px: f32,
}

/// Counters of one scan's merge; add up with `+=`.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize)]
pub struct MergeStats {
    /// Points whose weights summed to zero (they keep their own SSAO).
    pub zero_weight: u64,
    /// (point, view) pairs evaluated.
    pub point_views: u64,
    /// Samples accepted by eq. 7.
    pub samples_kept: u64,
}

impl std::ops::AddAssign for MergeStats {
    fn add_assign(&mut self, o: Self) {
        self.zero_weight += o.zero_weight;
        self.point_views += o.point_views;
        self.samples_kept += o.samples_kept;
    }
}

/// MVAO of scan i's points. `own` is each point's SSAO in its own scan (the fallback when all
/// weights are zero); `views[i]` must be scan i itself. Views listed in `skip` are not visited
/// (pairs known not to overlap).
pub fn merge_scan(
    i: usize,
    points: &[Vec3],
    radii: &[f32],
    own: &[f32],
    views: &[View<'_>],
    skip: &[bool],
    prm: &MergeParams,
) -> (Vec<f32>, MergeStats) {
    let half = (prm.neighbors.max(1) / 2) as i64;
    let pose_i = views[i].pose;
    let pairs: Vec<(usize, Affine3A, glam::Vec4)> = views
        .iter()
        .enumerate()
        .filter(|(j, _)| !skip.get(*j).copied().unwrap_or(false))
        .map(|(j, v)| {
            // Scan i local → scan j local, composed in f64, rounded to f32 once per pair.
            let relm = v.pose.inverse() * pose_i;
            let rel = Affine3A::from_mat4(relm.as_mat4());
            let b = (relm * views[i].proj.sensor_homogeneous().as_dvec4()).as_vec4();
            (j, rel, b)
        })
        .collect();
    const CHUNK: usize = 8192;
    let mut out = vec![0.0f32; points.len()];
    let stats = out
        .par_chunks_mut(CHUNK)
        .enumerate()
        .map(|(ci, res)| {
            let base = ci * CHUNK;
            let n = res.len();
            let mut num = vec![0.0f32; n];
            let mut den = vec![0.0f32; n];
            let mut st = MergeStats::default();
            for &(j, rel, b) in &pairs {
                let v = &views[j];
                let g = v.gbuf;
                for k in 0..n {
                    let pi = base + k;
                    let q: Vec3 = rel.transform_point3a(Vec3A::from(points[pi])).into();
                    let Some(pr) = v.proj.project(q) else {
                        continue;
                    };
                    st.point_views += 1;
                    let (cx, cy) = (pr.x.floor() as i64, pr.y.floor() as i64);
                    let rad_i = radii[pi];
                    for dy in -half..=half {
                        for dx in -half..=half {
                            let Some(idx) = v.proj.pixel_at(cx + dx, cy + dy) else {
                                continue;
                            };
                            if g.point[idx] == EMPTY {
                                continue;
                            }
                            let p_ij = g.position[idx];
                            let n_ij = g.normal[idx];
                            let rad_ij = g.radius[idx];
                            if !corresponds(q, p_ij, n_ij, rad_i, rad_ij, b) {
                                continue;
                            }
                            let w = w_distance(g.depth[idx], prm.dmin, prm.dmax)
                                * w_normal(n_ij, v.proj.toward_sensor(p_ij))
                                * w_border(v.border[idx], prm.border_px, rad_i, rad_ij);
                            st.samples_kept += 1;
                            num[k] += v.ao[idx] * w;
                            den[k] += w;
                        }
                    }
                }
            }
            for k in 0..n {
                res[k] = if den[k] > 0.0 && num[k].is_finite() {
                    (num[k] / den[k]).clamp(0.0, 1.0)
                } else {
                    st.zero_weight += 1;
                    own[base + k]
                };
            }
            st
        })
        .reduce(MergeStats::default, |mut a, b| {
            a += b;
            a
        });
    (out, stats)
}
