//! The own-surface height of each scan: how far the other scans' samples of the same surface
//! lie above or below its points, measured along their normals.
//!
//! Overlapping scans of one surface never coincide: a registration residual and the range
//! noise put each scan's samples a fraction of a millimetre to centimetres above or below
//! the others'. A grazing ray from a point meets such a parallel sheet at `h / sin φ`, far
//! beyond the `2·rad(p)` of the own-patch rule, and on a surface covered by several scans it
//! nearly always does somewhere. The reference takes a surface within 60° of the point's
//! normal and lower than the scan's own-surface height over the tangent plane as the point's
//! own, whatever the distance along the ray.

use crate::scan::knn::VoxelGrid;
use glam::Vec3;
use rayon::prelude::*;

/// Points of each scan examined.
pub const RESIDUAL_SAMPLE: usize = 4000;
/// Quantile of the heights of the other scan over a scan's points taken as their separation.
pub const RESIDUAL_QUANTILE: f64 = 0.9;
/// Fewest overlapping samples for a pair of scans to count.
pub const MIN_OVERLAP: usize = 50;
/// Least cosine between a point's normal and the nearest other-scan sample's normal for the
/// two to be samples of the same surface.
const SAME_SURFACE_COS: f32 = 0.8;
/// Largest distance across the normal, relative to the larger of the two radii, from a
/// point to the nearest other-scan sample for the two to overlap.
const LATERAL: f32 = 2.0;

/// One scan's query geometry in the scene frame.
#[derive(Debug, Clone, Copy)]
pub struct ScanGeometry<'a> {
    /// Points.
    pub points: &'a [Vec3],
    /// Unit normals (zero: unknown).
    pub normals: &'a [Vec3],
    /// Radii `rad(p)` or the grid radii.
    pub radii: &'a [f32],
}

fn consistent(s: &ScanGeometry) -> bool {
    s.normals.len() == s.points.len() && s.radii.len() == s.points.len()
}

/// Finite points of a scan and their indices, with the neighbour grid over them.
struct Indexed {
    grid: Option<VoxelGrid>,
    index: Vec<u32>,
}

fn indexed(s: &ScanGeometry) -> Indexed {
    let index: Vec<u32> = (0..s.points.len() as u32)
        .filter(|&i| s.points[i as usize].is_finite())
        .collect();
    let pts: Vec<Vec3> = index.iter().map(|&i| s.points[i as usize]).collect();
    Indexed {
        grid: VoxelGrid::new(&pts, 1),
        index,
    }
}

/// Per scan, the own-surface height: the largest over the other scans that overlap it of
/// the [`RESIDUAL_QUANTILE`] of `|(q − p)·n_p|`, `q` the nearest sample of the other scan to
/// a point `p` of this one, over pairs that sample the same surface. 0 for a scan that no
/// other overlaps. Deterministic.
pub fn own_heights(scans: &[ScanGeometry]) -> Vec<f32> {
    let idx: Vec<Indexed> = scans.par_iter().map(indexed).collect();
    (0..scans.len())
        .map(|i| {
            let s = &scans[i];
            let n = s.points.len();
            if !consistent(s) {
                return 0.0;
            }
            let m = RESIDUAL_SAMPLE.min(n);
            let mut h = 0.0f32;
            for (j, other) in idx.iter().enumerate() {
                let Some(grid) = other.grid.as_ref().filter(|_| j != i) else {
                    continue;
                };
                let o = &scans[j];
                if !consistent(o) {
                    continue;
                }
                let mut heights: Vec<f32> = (0..m)
                    .into_par_iter()
                    .map_init(Vec::new, |out, k| {
                        let a = (k as u128 * n as u128 / m.max(1) as u128) as usize;
                        let (p, np) = (s.points[a], s.normals[a].normalize_or_zero());
                        if !p.is_finite() || np == Vec3::ZERO || !grid.nearest(p, 1, out) {
                            return None;
                        }
                        let b = other.index[(*out.first()? & 0xffff_ffff) as usize] as usize;
                        let d = o.points[b] - p;
                        let up = d.dot(np);
                        let reach = LATERAL * s.radii[a].max(o.radii[b]);
                        let same =
                            o.normals[b].normalize_or_zero().dot(np).abs() > SAME_SURFACE_COS;
                        (same && (d - np * up).length() <= reach && up.is_finite())
                            .then_some(up.abs())
                    })
                    .flatten()
                    .collect();
                if heights.len() < MIN_OVERLAP {
                    continue;
                }
                heights.sort_by(f32::total_cmp);
                let q = ((heights.len() - 1) as f64 * RESIDUAL_QUANTILE).round() as usize;
                h = h.max(heights[q.min(heights.len() - 1)]);
            }
            h
        })
        .collect()
}
