//! Rasterizing one scan into its G-buffer: per pixel the nearest point's local position,
//! normal, depth, radius and index. Pixels with no point are empty and never sampled. No AO.

use crate::projection::Projection;
use glam::Vec3;
use rayon::prelude::*;
use std::sync::atomic::{AtomicU64, Ordering};

/// Marks an empty pixel in [`GBuffer::point`] (and a point with no pixel).
pub const EMPTY: u32 = u32::MAX;

/// One scan's G-buffer, row-major `width × height`.
#[derive(Debug, Clone, Default)]
pub struct GBuffer {
    /// Map width.
    pub width: usize,
    /// Map height.
    pub height: usize,
    /// Index (into the scan's valid points) of the nearest point, or [`EMPTY`].
    pub point: Vec<u32>,
    /// Depth of that point (metres); `f32::INFINITY` where empty.
    pub depth: Vec<f32>,
    /// Local position; zero where empty.
    pub position: Vec<Vec3>,
    /// Unit normal; zero where empty.
    pub normal: Vec<Vec3>,
    /// Radius `rad(p)`; zero where empty.
    pub radius: Vec<f32>,
    /// Whether the horizon estimator lifts each receiver by the map's range noise (a scan's
    /// map). A depth stream's frames are not lifted: integrating them over frames already
    /// averages the noise out (`docs/design.md`, "Receiver lift").
    pub lift_receivers: bool,
}

impl GBuffer {
    /// True when pixel `i` holds a point.
    #[inline]
    pub fn is_valid(&self, i: usize) -> bool {
        self.point[i] != EMPTY
    }

    /// Number of non-empty pixels.
    pub fn filled(&self) -> usize {
        self.point.iter().filter(|&&p| p != EMPTY).count()
    }
}

/// The pixel and depth of every point: from the native grid when given, else by projection.
/// Points outside the map (or with no image) get pixel [`EMPTY`].
pub fn point_pixels(
    points: &[Vec3],
    proj: &Projection,
    grid_pixels: Option<&[u32]>,
) -> (Vec<u32>, Vec<f32>) {
    let n = points.len();
    let (mut pixels, mut depths) = (
        crate::par::filled(n, EMPTY),
        crate::par::filled(n, f32::INFINITY),
    );
    // Four points per projection (the same values as one at a time).
    const CHUNK: usize = 4096;
    pixels
        .par_chunks_mut(CHUNK)
        .zip(depths.par_chunks_mut(CHUNK))
        .zip(points.par_chunks(CHUNK))
        .enumerate()
        .for_each(|(ci, ((px, dp), pts))| {
            for (g, four) in pts.chunks(4).enumerate() {
                let mut p = [Vec3::ZERO; 4];
                p[..four.len()].copy_from_slice(four);
                for (l, pr) in proj.project4(p).into_iter().take(four.len()).enumerate() {
                    let Some(pr) = pr.filter(|pr| pr.depth.is_finite()) else {
                        continue;
                    };
                    let k = g * 4 + l;
                    px[k] = match grid_pixels {
                        Some(gp) => gp[ci * CHUNK + k],
                        None => proj
                            .pixel_index(pr.x, pr.y)
                            .map(|v| v as u32)
                            .unwrap_or(EMPTY),
                    };
                    dp[k] = pr.depth;
                }
            }
        });
    (pixels, depths)
}

/// Rasterizes points into a `width × height` G-buffer keeping the nearest point per pixel
/// (ties broken by the lower index, so the result does not depend on thread timing).
pub fn rasterize(
    width: usize,
    height: usize,
    pixels: &[u32],
    depths: &[f32],
    points: &[Vec3],
    normals: &[Vec3],
    radii: &[f32],
) -> GBuffer {
    let n = width * height;
    // Depth ≥ 0 so its f32 bit pattern orders like the value; pack (depth, index) so one
    // atomic min picks the nearest point. Every buffer is filled by a parallel pass (a
    // collect writes straight into the new vector): a serial fill of ~10⁶ pixels kept a core
    // idle while it faulted the pages in.
    let best: Vec<AtomicU64> = (0..n)
        .into_par_iter()
        .map(|_| AtomicU64::new(u64::MAX))
        .collect();
    pixels
        .par_iter()
        .zip(depths.par_iter())
        .enumerate()
        .for_each(|(i, (&px, &d))| {
            if px != EMPTY && (px as usize) < n && d.is_finite() {
                let key = ((d.max(0.0).to_bits() as u64) << 32) | i as u64;
                best[px as usize].fetch_min(key, Ordering::Relaxed);
            }
        });
    GBuffer {
        width,
        height,
        point: per_pixel(&best, EMPTY, |i| i as u32),
        depth: per_pixel(&best, f32::INFINITY, |i| depths[i]),
        position: per_pixel(&best, Vec3::ZERO, |i| points[i]),
        normal: per_pixel(&best, Vec3::ZERO, |i| normals[i]),
        radius: per_pixel(&best, 0.0, |i| radii[i]),
        lift_receivers: true,
    }
}

/// Per pixel, `value` of the nearest point (packed in `best`), or `empty`.
fn per_pixel<T>(best: &[AtomicU64], empty: T, value: impl Fn(usize) -> T + Sync) -> Vec<T>
where
    T: Copy + Send + Sync,
{
    best.par_iter()
        .map(|b| {
            let key = b.load(Ordering::Relaxed);
            if key == u64::MAX {
                empty
            } else {
                value((key & 0xffff_ffff) as usize)
            }
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn nearest_point_wins_and_ties_go_to_lower_index() {
        let pts = vec![Vec3::X, Vec3::Y, Vec3::Z, Vec3::ONE];
        let nrm = vec![Vec3::Z; 4];
        let rad = vec![0.1, 0.2, 0.3, 0.4];
        let pixels = vec![0, 0, 3, 3];
        let depths = vec![2.0, 1.0, 5.0, 5.0];
        let g = rasterize(2, 2, &pixels, &depths, &pts, &nrm, &rad);
        assert_eq!(g.point, vec![1, EMPTY, EMPTY, 2]);
        assert_eq!(g.depth[0], 1.0);
        assert_eq!(g.radius[3], 0.3);
        assert!(g.depth[1].is_infinite());
        assert_eq!(g.filled(), 2);
    }
}
