//! The geometry integrated so far, seen from a frame's pose. For the SSAO with history, the
//! fused distance volume ray-cast at the frame's pose, as the paper does: a depth map less
//! noisy than the raw frame, with holes filled by what earlier frames saw. For the preview,
//! the AO grid's occupied voxels splatted with a z-buffer, each pixel of a splat taking the
//! point where its ray meets the voxel's plane (so a wall renders flat, not as steps).

use super::frame::FrameGeometry;
use super::frames::Intrinsics;
use super::grid::VoxelGrid;
use super::tsdf::Tsdf;
use glam::{DMat4, Vec3};
use rayon::prelude::*;

/// Renders the grid's occupied voxels into a `width × height` frame of intrinsics `k` seen
/// from camera-to-world `pose`. Pixels no voxel covers are empty. Deterministic: a pixel
/// keeps the nearest splat, ties going to the lower key, whatever the table's order.
pub fn render(
    grid: &VoxelGrid,
    pose: DMat4,
    k: &Intrinsics,
    width: usize,
    height: usize,
    min_range: f32,
) -> (FrameGeometry, Vec<f32>) {
    let n = width * height;
    let mut best: Vec<(f32, u64)> = vec![(f32::INFINITY, u64::MAX); n];
    let mut geo = FrameGeometry {
        width,
        height,
        points: vec![Vec3::ZERO; n],
        normals: vec![Vec3::ZERO; n],
    };
    let mut ao = vec![1.0f32; n];
    let to_cam = pose.inverse();
    let rot = glam::DMat3::from_mat4(to_cam);
    let (fx, fy, cx, cy) = (k.fx as f32, k.fy as f32, k.cx as f32, k.cy as f32);
    let voxel = grid.voxel as f32;
    for (key, cell) in grid.iter() {
        let Some(vp) = grid.point_of(key, cell) else {
            continue;
        };
        let q = to_cam.transform_point3(vp.position).as_vec3();
        let nrm = (rot * vp.normal.as_dvec3()).as_vec3();
        if !(q.z > min_range) || nrm.dot(q) >= 0.0 {
            continue;
        }
        let (u, v) = (fx * q.x / q.z + cx, fy * q.y / q.z + cy);
        let s = (0.5 * voxel * fx.max(fy) / q.z).round();
        let (x0, x1) = (
            (u - s).round().max(0.0),
            (u + s).round().min(width as f32 - 1.0),
        );
        let (y0, y1) = (
            (v - s).round().max(0.0),
            (v + s).round().min(height as f32 - 1.0),
        );
        if !(x0 <= x1 && y0 <= y1) {
            continue;
        }
        let plane = nrm.dot(q);
        for y in y0 as usize..=y1 as usize {
            for x in x0 as usize..=x1 as usize {
                let ray = Vec3::new((x as f32 - cx) / fx, (y as f32 - cy) / fy, 1.0);
                let den = nrm.dot(ray);
                let mut z = if den < -1e-3 { plane / den } else { q.z };
                if !((z - q.z).abs() <= voxel) {
                    z = q.z;
                }
                let i = y * width + x;
                if (z, key) < best[i] {
                    best[i] = (z, key);
                    geo.points[i] = ray * z;
                    geo.normals[i] = nrm;
                    ao[i] = vp.ao;
                }
            }
        }
    }
    (geo, ao)
}

/// The frame's geometry for its SSAO with history: the fused volume ray-cast at the frame's
/// pose, `width × height` pixels of intrinsics `k`. A pixel the frame measured (`own`) looks
/// for the surface within `2μ` of its own depth and keeps its own point where the volume has
/// none there; a pixel it did not measure searches the whole range. Normals come from the
/// cast depth map as from a frame's own (over a pixel's neighbours, not the volume's
/// gradient over a voxel's, which is noisier where voxels are smaller than pixels).
pub fn cast(
    volume: &Tsdf,
    own: &FrameGeometry,
    pose: DMat4,
    k: &Intrinsics,
    range: (f32, f32),
) -> FrameGeometry {
    let (w, h) = (own.width, own.height);
    let (fx, fy, cx, cy) = (k.fx as f32, k.fy as f32, k.cx as f32, k.cy as f32);
    let mu = volume.mu;
    let points: Vec<Vec3> = (0..w * h)
        .into_par_iter()
        .map(|i| {
            let (x, y) = ((i % w) as f32, (i / w) as f32);
            let dir = Vec3::new((x - cx) / fx, (y - cy) / fy, 1.0);
            let measured = own.points[i].z > 0.0;
            let (t0, t1) = if measured {
                let (d, l) = (own.points[i].z as f64, dir.length() as f64);
                ((d - 2.0 * mu / l).max(range.0 as f64), d + 2.0 * mu / l)
            } else {
                (range.0 as f64, range.1 as f64)
            };
            match volume.cast(&pose, dir, t0, t1) {
                Some(t) => dir * t as f32,
                None => own.points[i],
            }
        })
        .collect();
    let normals = super::frame::depth_normals(&points, w, h);
    FrameGeometry {
        width: w,
        height: h,
        points,
        normals,
    }
}
