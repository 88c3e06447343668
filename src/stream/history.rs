//! The geometry integrated so far, seen from a frame's pose: each occupied voxel's mean
//! position and normal splatted into the frame with a z-buffer, each pixel of a splat
//! taking the point where its ray meets the voxel's plane (so a wall renders flat, not as
//! steps). The paper ray-casts its fused volume for the same purpose: a depth map less noisy
//! than the raw frame, with holes filled by what earlier frames saw.

use super::frame::FrameGeometry;
use super::frames::Intrinsics;
use super::grid::VoxelGrid;
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

/// The frame's geometry for its SSAO with history: each pixel the frame measured moves
/// along its ray onto the plane (mean position, mean normal) of the integrated points
/// around it and takes that normal, so the noise of one frame is replaced by the average of the
/// frames before it; pixels the frame did not measure take the rendered history. A pixel
/// whose voxel is empty, or whose plane lies farther than a voxel along the ray, keeps its
/// own point and normal.
pub fn blend(
    history: &FrameGeometry,
    own: &FrameGeometry,
    grid: &VoxelGrid,
    pose: DMat4,
) -> FrameGeometry {
    let to_cam = pose.inverse();
    let rot = glam::DMat3::from_mat4(to_cam);
    let voxel = grid.voxel as f32;
    let n = own.points.len().min(history.points.len());
    let px: Vec<(Vec3, Vec3)> = (0..n)
        .into_par_iter()
        .map(|i| {
            if !own.is_valid(i) {
                return (history.points[i], history.normals[i]);
            }
            let q = own.points[i];
            let keep = (q, own.normals[i]);
            let pw = pose.transform_point3(q.as_dvec3());
            let Some((mw, nw)) = neighbourhood_plane(grid, pw) else {
                return keep;
            };
            let m = to_cam.transform_point3(mw).as_vec3();
            let nrm = (rot * nw.as_dvec3()).as_vec3();
            let ray = q / q.z;
            let den = nrm.dot(ray);
            if !(den < -1e-3) {
                return keep;
            }
            let z = nrm.dot(m) / den;
            if !((z - q.z).abs() <= voxel) {
                return keep;
            }
            (ray * z, nrm)
        })
        .collect();
    let points: Vec<Vec3> = px.iter().map(|p| p.0).collect();
    let normals = px.iter().map(|p| p.1).collect();
    FrameGeometry {
        width: own.width,
        height: own.height,
        points,
        normals,
    }
}

/// The weighted mean position and unit mean normal of the points in the 2 × 2 × 2 voxels
/// whose centres surround `p`: two voxels across hold a surface's noise on both sides of `p`,
/// so the mean lies on the surface rather than on the side of it one voxel happens to cut.
pub fn neighbourhood_plane(grid: &VoxelGrid, p: glam::DVec3) -> Option<(glam::DVec3, Vec3)> {
    let c = grid.cell_of(p - glam::DVec3::splat(0.5 * grid.voxel));
    let (mut sp, mut sn, mut sw) = (glam::DVec3::ZERO, Vec3::ZERO, 0.0f64);
    for dz in 0..=1 {
        for dy in 0..=1 {
            for dx in 0..=1 {
                let Some(k) = super::grid::morton([c[0] + dx, c[1] + dy, c[2] + dz]) else {
                    continue;
                };
                let Some(cell) = grid.get(k) else {
                    continue;
                };
                let off =
                    glam::DVec3::new(cell.pos[0] as f64, cell.pos[1] as f64, cell.pos[2] as f64);
                sp += grid.corner(k) * cell.w + off;
                sn += Vec3::from(cell.nrm);
                sw += cell.w;
            }
        }
    }
    let n = sn.normalize_or_zero();
    (sw > 0.0 && n != Vec3::ZERO).then(|| (sp / sw, n))
}
