//! A stream's accuracy against the ground truth of a synthetic stream: the voxel grid's
//! error beside the error of the SSAO each frame computes on its own depth, the yardstick
//! the grid must beat.

use super::synth::SynthStream;
use super::{Integrator, StreamParams};

/// The errors of one integration of a synthetic stream (mean |AO − A|).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct StreamScore {
    /// Over the scored voxels, each voxel's A the mean of its pixels' truths.
    pub voxel: f64,
    /// The same weighted by each voxel's number of integrated pixels (the population the
    /// single-frame error averages over).
    pub voxel_per_pixel: f64,
    /// The mean over frames of the error of the SSAO each frame computes on its own
    /// cleaned depth (no history), over its pixels with a value and a truth.
    pub single: f64,
    /// Voxels scored.
    pub voxels: usize,
    /// Bytes of the grid's table and the history volume per occupied voxel.
    pub bytes_per_voxel: f64,
}

/// Integrates the frames of `s` in `order` with `p` and scores the grid.
pub fn score(s: &SynthStream, p: StreamParams, order: &[usize]) -> StreamScore {
    let mut it = Integrator::new(p, s.intrinsics);
    let mut alone = Integrator::new(
        StreamParams {
            history: false,
            ..p
        },
        s.intrinsics,
    );
    let mut frame_e = Vec::new();
    for &i in order {
        let pose = s.poses[i];
        let (geo, ao, _) = alone.frame_ssao(&s.frames[i], pose);
        let (mut sad, mut n) = (0.0f64, 0usize);
        for (k, a) in ao.iter().enumerate() {
            let t = s.truth[i][k];
            if let (Some(a), true, true) = (a, t.is_finite(), geo.is_valid(k)) {
                sad += (a - t).abs() as f64;
                n += 1;
            }
        }
        if n > 0 {
            frame_e.push(sad / n as f64);
        }
        it.add_frame_truth(&s.frames[i], pose, Some(&s.truth[i]));
    }
    let (mut sad, mut n, mut wsad, mut wn) = (0.0f64, 0usize, 0.0f64, 0u64);
    for vp in it.grid.points() {
        if let Some(&(sum, count)) = it.truth.get(&vp.key) {
            if count > 0 {
                let e = (vp.ao as f64 - sum / count as f64).abs();
                sad += e;
                n += 1;
                wsad += e * count as f64;
                wn += count;
            }
        }
    }
    StreamScore {
        voxel: sad / n.max(1) as f64,
        voxel_per_pixel: wsad / wn.max(1) as f64,
        single: frame_e.iter().sum::<f64>() / frame_e.len().max(1) as f64,
        voxels: n,
        bytes_per_voxel: it.bytes() as f64 / it.grid.len().max(1) as f64,
    }
}
