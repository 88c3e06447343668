//! `mvao stream`: depth frames from a depth camera integrated as they arrive into a sparse
//! voxel grid of ambient occlusion (Sabbadin et al. 2016, §6). Each frame is cleaned, its
//! normals come from the depth map, its SSAO from the same per-view estimator as `merge`,
//! and every pixel adds `SSAO·w` and `w = w_d·w_n` to the voxel holding its world point.
//! With history, the SSAO is computed on the geometry integrated so far rendered at the
//! frame's pose (filled with the frame's own depth), as the paper does on its fused volume.
//!
//! [`Integrator`] is the computation over frames in memory; [`run`] the job over files.

pub mod clean;
pub mod frame;
pub mod frames;
pub mod grid;
pub mod history;
mod job;
pub mod score;
pub mod synth;
pub mod tsdf;

pub use job::{
    run, settings_hash, DroppedFrame, StreamConfig, StreamReport, VolumeSummary, WeightSummary,
};

use crate::ssao::SsaoParams;
use clean::CleanParams;
use frames::{DepthFrame, Intrinsics};
use glam::{DMat3, DMat4};
use grid::VoxelGrid;
use rayon::prelude::*;
use serde::Serialize;
use std::time::Instant;

/// The settings of an integration.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct StreamParams {
    /// Cleaning of each frame.
    #[serde(skip)]
    pub clean: CleanParams,
    /// Voxel edge (metres).
    pub voxel: f64,
    /// SSAO of each frame.
    pub ssao: SsaoParams,
    /// The SSAO is computed at `1/ssao_scale` of the frame's resolution.
    pub ssao_scale: usize,
    /// SSAO on the integrated geometry rendered at the frame's pose.
    pub history: bool,
}

impl Default for StreamParams {
    fn default() -> Self {
        StreamParams {
            clean: CleanParams::default(),
            voxel: 0.01,
            ssao: SsaoParams {
                estimator: crate::Estimator::Horizon,
                radius: 0.2,
                tmax: 0.4,
                falloff: crate::Falloff::Smoothstep,
                samples: 32,
                directions: 8,
                steps: 8,
                seed: 0,
                blur: true,
                sampling: Default::default(),
            },
            ssao_scale: 4,
            history: false,
        }
    }
}

/// Seconds spent per stage, summed over frames.
#[derive(Debug, Clone, Default, PartialEq, Serialize)]
pub struct StageTimes {
    /// Reading and decoding frames.
    pub read: f64,
    /// Cleaning and normals.
    pub clean_normals: f64,
    /// Rendering the history.
    pub history: f64,
    /// SSAO.
    pub ssao: f64,
    /// Adding to the grid.
    pub integrate: f64,
}

/// What one frame added.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct FrameStats {
    /// Pixels with a depth.
    pub measured: u64,
    /// Pixels left after cleaning.
    pub kept: u64,
    /// Pixels integrated (kept, with a normal, an SSAO value and a positive weight).
    pub integrated: u64,
}

/// A running integration: the grid and what it needs to add frames.
#[derive(Debug, Clone)]
pub struct Integrator {
    /// The voxel grid.
    pub grid: VoxelGrid,
    /// Settings.
    pub params: StreamParams,
    /// Camera intrinsics of every frame.
    pub intrinsics: Intrinsics,
    /// Stage times so far.
    pub times: StageTimes,
    /// Per voxel Σ A and the count of the ground truths added with
    /// [`Integrator::add_frame_truth`] (empty otherwise).
    pub truth: std::collections::HashMap<u64, (f64, u64)>,
    /// The fused geometry history reads (`None` without history, or before the first
    /// frame with a depth).
    pub volume: Option<tsdf::Tsdf>,
}

/// One pixel to add: its index, its voxel's key (`u64::MAX` beyond the keyed range) and
/// its contribution.
type Sample = (usize, u64, grid::Cell);

impl Integrator {
    /// An empty integration.
    pub fn new(params: StreamParams, intrinsics: Intrinsics) -> Integrator {
        Integrator {
            grid: VoxelGrid::new(params.voxel),
            params,
            intrinsics,
            times: StageTimes::default(),
            truth: Default::default(),
            volume: None,
        }
    }

    /// Bytes held by the grid's table and the history volume.
    pub fn bytes(&self) -> usize {
        self.grid.table_bytes() + self.volume.as_ref().map_or(0, tsdf::Tsdf::bytes)
    }

    /// Cleans `frame`, computes its SSAO and adds its pixels to the grid at camera-to-world
    /// `pose`.
    pub fn add_frame(&mut self, frame: &DepthFrame, pose: DMat4) -> FrameStats {
        self.add_frame_truth(frame, pose, None)
    }

    /// [`Integrator::add_frame`], also adding each integrated pixel's ground truth `A`
    /// (per pixel of the frame) to its voxel's truth sums.
    pub fn add_frame_truth(
        &mut self,
        frame: &DepthFrame,
        pose: DMat4,
        truth: Option<&[f32]>,
    ) -> FrameStats {
        let (geo, ao, mut st) = self.frame_ssao(frame, pose);
        let t = Instant::now();
        st.integrated = self.integrate(&geo, &ao, pose, truth);
        self.times.integrate += t.elapsed().as_secs_f64();
        st
    }

    /// The frame's cleaned geometry (full resolution) and the SSAO each of its pixels would
    /// add (`None` where it has none), without adding them.
    pub fn frame_ssao(
        &mut self,
        frame: &DepthFrame,
        pose: DMat4,
    ) -> (frame::FrameGeometry, Vec<Option<f32>>, FrameStats) {
        let p = self.params;
        let k = self.intrinsics;
        let (w, h) = (frame.width, frame.height);
        let mut t = Instant::now();
        let lap = |t: &mut Instant| {
            let s = t.elapsed().as_secs_f64();
            *t = Instant::now();
            s
        };
        let cleaned = clean::clean(&frame.depth, w, h, &p.clean);
        let geo = frame::geometry(&cleaned, w, h, &k);
        let f = p.ssao_scale.max(1);
        let k_low = k.scaled_down(f);
        let (low_depth, lw, lh) = frame::downsample(&cleaned, w, h, f);
        let own_low = if f == 1 {
            geo.clone()
        } else {
            frame::geometry(&low_depth, lw, lh, &k_low)
        };
        self.times.clean_normals += lap(&mut t);
        if p.history && self.volume.is_none() {
            self.volume = history_voxel(&cleaned, &k_low, p.voxel).map(tsdf::Tsdf::new);
        }
        let low = match self.volume.as_mut().filter(|_| p.history) {
            Some(vol) => {
                vol.integrate(&tsdf::DepthView {
                    depth: &cleaned,
                    width: w,
                    height: h,
                    k,
                    pose,
                });
                let range = (p.clean.min_range, p.clean.max_range);
                history::cast(vol, &own_low, pose, &k_low, range)
            }
            None => own_low,
        };
        self.times.history += lap(&mut t);
        let ao = frame::frame_ssao(&low, &k_low, &p.ssao, &geo, &k, f);
        self.times.ssao += lap(&mut t);
        let st = FrameStats {
            measured: frame.depth.iter().filter(|&&d| d > 0.0).count() as u64,
            kept: cleaned.iter().filter(|&&d| d > 0.0).count() as u64,
            integrated: 0,
        };
        (geo, ao, st)
    }

    /// Adds every valid pixel of `geo` with an SSAO value to the grid; returns how many.
    fn integrate(
        &mut self,
        geo: &frame::FrameGeometry,
        ao: &[Option<f32>],
        pose: DMat4,
        truth: Option<&[f32]>,
    ) -> u64 {
        let rot = DMat3::from_mat4(pose);
        let (dmin, dmax) = (self.params.clean.min_range, self.params.clean.max_range);
        // Per pixel in parallel, then added in pixel order so the sums do not depend on
        // thread timing.
        let grid = &self.grid;
        let samples: Vec<Option<Sample>> = (0..geo.points.len())
            .into_par_iter()
            .map(|i| {
                let a = ao.get(i).copied().flatten()?;
                if !geo.is_valid(i) {
                    return None;
                }
                let (pl, nl) = (geo.points[i], geo.normals[i]);
                let wt = frame::weight(pl, nl, dmin, dmax);
                if !(wt > 0.0) {
                    return None;
                }
                let pw = pose.transform_point3(pl.as_dvec3());
                let nw = (rot * nl.as_dvec3()).as_vec3().normalize_or_zero();
                let Some(k) = grid.key_of(pw) else {
                    return Some((i, u64::MAX, grid::Cell::default()));
                };
                Some((i, k, grid.contribution(k, pw, nw, a, wt)))
            })
            .collect();
        let mut n = 0;
        for &(i, k, _) in samples.iter().flatten() {
            n += 1;
            if k == u64::MAX {
                self.grid.out_of_range += 1;
                continue;
            }
            let Some(t) = truth else {
                continue;
            };
            let a = t.get(i).copied().unwrap_or(f32::NAN);
            if a.is_finite() {
                let e = self.truth.entry(k).or_insert((0.0, 0));
                e.0 += a as f64;
                e.1 += 1;
            }
        }
        // Each part of the table takes its pixels in pixel order, so the sums do not depend
        // on thread timing. Neighbouring pixels of a row mostly share a voxel: their sums are
        // added up first and reach the table once per run.
        self.grid
            .shards_mut()
            .par_iter_mut()
            .enumerate()
            .for_each(|(si, table)| {
                let mut run: Option<(u64, grid::Cell)> = None;
                let mine = samples
                    .iter()
                    .flatten()
                    .filter(|s| s.1 != u64::MAX && grid::shard(s.1) == si);
                for (_, k, c) in mine {
                    match &mut run {
                        Some((rk, acc)) if rk == k => acc.accumulate(c),
                        _ => {
                            if let Some((rk, acc)) = run.take() {
                                table.entry(rk).or_default().accumulate(&acc);
                            }
                            run = Some((*k, *c));
                        }
                    }
                }
                if let Some((rk, acc)) = run {
                    table.entry(rk).or_default().accumulate(&acc);
                }
            });
        n
    }
}

/// The history volume's voxel: the SSAO map's pixel footprint at the median depth of the
/// first frame with a depth (`None` before one), or the grid's voxel when that is larger.
/// Finer voxels add no detail to a depth map cast at the SSAO's resolution, only the noise
/// of fewer frames per voxel (a noisy synthetic room stream at ¼ resolution: e_A
/// 0.0098–0.0105 at the grid's 6 mm, 0.0082–0.0093 at the footprint, 32–36 mm).
fn history_voxel(depth: &[f32], k_low: &Intrinsics, grid_voxel: f64) -> Option<f64> {
    let mut d: Vec<f32> = depth.iter().copied().filter(|&z| z > 0.0).collect();
    if d.is_empty() {
        return None;
    }
    let mid = d.len() / 2;
    let (_, m, _) = d.select_nth_unstable_by(mid, f32::total_cmp);
    let f = k_low.fx.max(k_low.fy);
    Some(if f > 0.0 {
        (*m as f64 / f).max(grid_voxel)
    } else {
        grid_voxel
    })
}

#[cfg(test)]
mod tests;
