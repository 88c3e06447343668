//! The fused geometry history reads: a sparse truncated signed-distance volume (Curless and
//! Levoy's running average, as KinectFusion and the paper's §6 use it). Each frame adds, per
//! voxel near its surface, the distance along the ray from the voxel to the measured depth,
//! truncated to `±μ`; the zero crossing of the average lies on the mean of the frames'
//! surfaces, so ray-casting it at a frame's pose gives a depth map whose noise the frames
//! before have averaged out along the rays (where the occupied voxels of the AO grid only
//! keep a noisy shell a few voxels thick).
//!
//! Voxels live in 4 × 4 × 4 blocks keyed by the Morton code of the block, allocated where a
//! frame's rays pass within `μ` of their depth; an arena keeps blocks in the order they
//! were first seen (sorted by key within a frame), so the volume does not depend on thread
//! timing.

use super::frames::Intrinsics;
use super::grid::{morton, KeyHasher};
use glam::{DMat3, DMat4, DVec3, Vec3};
use rayon::prelude::*;
use std::collections::HashMap;
use std::hash::BuildHasherDefault;

/// Voxels along a block's edge.
const EDGE: usize = 4;
/// Voxels in a block.
const CELLS: usize = EDGE * EDGE * EDGE;
/// The truncation distance in voxels: two voxels on each side of a surface hold a value
/// for the zero crossing (2, 3 and 4 measured alike on noisy synthetic streams; fewer
/// voxels per surface keep the volume small).
pub const TRUNCATION_VOXELS: f64 = 2.0;
/// The distance's fixed-point unit: `μ` is `D_ONE`.
const D_ONE: f32 = 32767.0;

/// One block: per voxel the running mean of the truncated distance (fixed point, `±μ` =
/// `±D_ONE`) and its weight (frames that saw it, up to 255; 0 = unknown). Three bytes a voxel.
#[derive(Debug, Clone)]
pub struct Block {
    /// Truncated signed distance, per voxel, x fastest.
    pub d: [i16; CELLS],
    /// Observations per voxel.
    pub w: [u8; CELLS],
}

impl Default for Block {
    fn default() -> Self {
        Block {
            d: [0; CELLS],
            w: [0; CELLS],
        }
    }
}

/// The volume.
#[derive(Debug, Clone)]
pub struct Tsdf {
    /// Voxel edge (metres).
    pub voxel: f64,
    /// Truncation distance `μ` (metres).
    pub mu: f64,
    index: HashMap<u64, u32, BuildHasherDefault<KeyHasher>>,
    /// Block keys in arena order.
    pub keys: Vec<u64>,
    /// The blocks, in arena order.
    pub blocks: Vec<Box<Block>>,
}

/// What one frame's depth integration needs besides the depth.
pub struct DepthView<'a> {
    /// Z-depth per pixel (0 = none), row-major.
    pub depth: &'a [f32],
    /// Width in pixels.
    pub width: usize,
    /// Height in pixels.
    pub height: usize,
    /// Intrinsics at this resolution.
    pub k: Intrinsics,
    /// Camera-to-world pose.
    pub pose: DMat4,
}

/// Floor of `v / d` for integers.
#[inline]
fn div_floor(v: i64, d: i64) -> i64 {
    v.div_euclid(d)
}

impl Tsdf {
    /// An empty volume of voxels of edge `voxel` metres, truncated at
    /// [`TRUNCATION_VOXELS`] voxels.
    pub fn new(voxel: f64) -> Tsdf {
        Tsdf {
            voxel,
            mu: TRUNCATION_VOXELS * voxel,
            index: HashMap::default(),
            keys: Vec::new(),
            blocks: Vec::new(),
        }
    }

    /// Voxels with at least one observation.
    pub fn observed(&self) -> usize {
        self.blocks
            .iter()
            .map(|b| b.w.iter().filter(|&&w| w > 0).count())
            .sum()
    }

    /// Bytes held by blocks, arena and index.
    pub fn bytes(&self) -> usize {
        // Per block its allocation with the allocator's header; the arena's pointers and
        // keys; the index's entries and control bytes.
        self.blocks.len() * (std::mem::size_of::<Block>() + 16)
            + (self.blocks.capacity() + self.keys.capacity()) * 8
            + self.index.capacity() * 13
    }

    /// The integer voxel cell holding world point `p`.
    #[inline]
    fn cell(&self, p: DVec3) -> [i64; 3] {
        let c = (p / self.voxel).floor();
        [c.x as i64, c.y as i64, c.z as i64]
    }

    /// The block key of voxel cell `c`.
    #[inline]
    fn block_key(c: [i64; 3]) -> Option<u64> {
        morton(c.map(|v| div_floor(v, EDGE as i64)))
    }

    /// The blocks within `μ` of the frame's measured surface, sorted by key.
    fn touched_blocks(&self, v: &DepthView) -> Vec<u64> {
        let (fx, fy, cx, cy) = (v.k.fx, v.k.fy, v.k.cx, v.k.cy);
        let block = self.voxel * EDGE as f64;
        let mu = self.mu;
        let rot = DMat3::from_mat4(v.pose);
        let origin = v.pose.w_axis.truncate();
        // Pixels at most half a block apart at the frame's farthest depth, so no block the
        // surface crosses is missed; a block is usually many pixels wide.
        let far = v.depth.par_iter().copied().reduce(|| 0.0, f32::max) as f64;
        let across = block * fx.min(fy) / far.max(1e-6);
        let stride = ((0.5 * across) as usize).clamp(1, 4);
        let mut keys: Vec<u64> = (0..v.height.div_ceil(stride))
            .into_par_iter()
            .flat_map_iter(|row| {
                let y = row * stride;
                let mut out = Vec::new();
                let mut last = u64::MAX;
                for x in (0..v.width).step_by(stride) {
                    let d = v.depth[y * v.width + x] as f64;
                    if !(d > 0.0) {
                        continue;
                    }
                    let dir = rot * DVec3::new((x as f64 - cx) / fx, (y as f64 - cy) / fy, 1.0);
                    let len = dir.length();
                    // Along the ray from `μ` before to `μ` behind the surface, a step
                    // under half a block, so no block the band crosses is skipped.
                    let (t0, t1) = ((d - mu / len).max(0.0), d + mu / len);
                    let steps = (((t1 - t0) * len / (0.5 * block)).ceil() as usize).max(1);
                    for s in 0..=steps {
                        let t = t0 + (t1 - t0) * s as f64 / steps as f64;
                        let p = origin + dir * t;
                        if let Some(k) = Tsdf::block_key(self.cell(p)) {
                            if k != last {
                                out.push(k);
                                last = k;
                            }
                        }
                    }
                }
                out
            })
            .collect();
        keys.par_sort_unstable();
        keys.dedup();
        keys
    }

    /// Adds a frame's depth: each voxel of the blocks near its surface that projects onto a
    /// measured pixel and lies no more than `1.5 μ` behind it takes the truncated distance.
    pub fn integrate(&mut self, v: &DepthView) {
        let touched = self.touched_blocks(v);
        let mut mark = vec![false; self.blocks.len()];
        for &k in &touched {
            if let Some(&i) = self.index.get(&k) {
                mark[i as usize] = true;
            } else {
                self.index.insert(k, self.blocks.len() as u32);
                self.keys.push(k);
                self.blocks.push(Box::default());
                mark.push(true);
            }
        }
        let to_cam = v.pose.inverse();
        let (voxel, mu) = (self.voxel, self.mu as f32);
        let (fx, fy, cx, cy) = (v.k.fx as f32, v.k.fy as f32, v.k.cx as f32, v.k.cy as f32);
        let ax = (to_cam.transform_vector3(DVec3::X) * voxel).as_vec3();
        let ay = (to_cam.transform_vector3(DVec3::Y) * voxel).as_vec3();
        let az = (to_cam.transform_vector3(DVec3::Z) * voxel).as_vec3();
        let keys = &self.keys;
        self.blocks
            .par_iter_mut()
            .enumerate()
            .filter(|(i, _)| mark[*i])
            .for_each(|(i, b)| {
                let bc = super::grid::unmorton(keys[i]);
                let corner =
                    DVec3::new(bc[0] as f64, bc[1] as f64, bc[2] as f64) * (EDGE as f64 * voxel);
                // The first voxel's centre in the camera frame, in f64 (world coordinates
                // may be large); the offsets within a block are small and stay f32.
                let q0 = to_cam
                    .transform_point3(corner + DVec3::splat(0.5 * voxel))
                    .as_vec3();
                for c in 0..CELLS {
                    let (x, y, z) = (c % EDGE, (c / EDGE) % EDGE, c / (EDGE * EDGE));
                    let q = q0 + ax * x as f32 + ay * y as f32 + az * z as f32;
                    if !(q.z > 0.0) {
                        continue;
                    }
                    let (u, vv) = ((fx * q.x / q.z + cx).round(), (fy * q.y / q.z + cy).round());
                    if !(u >= 0.0 && vv >= 0.0 && u < v.width as f32 && vv < v.height as f32) {
                        continue;
                    }
                    let d = v.depth[vv as usize * v.width + u as usize];
                    if !(d > 0.0) {
                        continue;
                    }
                    let sdf = (d - q.z) * (q.length() / q.z);
                    // Half a `μ` of slack behind the surface: the distance is measured to the
                    // depth of the pixel the voxel's centre falls in, up to half a pixel
                    // away, which on a tilted surface seen through coarse pixels reads a
                    // voxel just inside the band as beyond it and leaves a hole at the
                    // crossing.
                    if sdf < -1.5 * mu {
                        continue;
                    }
                    let f = (sdf / mu).clamp(-1.0, 1.0) * D_ONE;
                    // Past 255 frames the mean turns into a running average over about as
                    // many; the steps stay far above the fixed point's unit.
                    let w = b.w[c].min(u8::MAX - 1) as f32;
                    let d = (b.d[c] as f32 * w + f) / (w + 1.0);
                    b.d[c] = d.round().clamp(-D_ONE, D_ONE) as i16;
                    b.w[c] = b.w[c].saturating_add(1);
                }
            });
    }

    /// The distance (over `μ`) of voxel cell `c`, `None` where unobserved.
    #[inline]
    fn at(&self, c: [i64; 3], cache: &mut (u64, u32)) -> Option<f32> {
        let k = Tsdf::block_key(c)?;
        if cache.0 != k {
            *cache = (k, self.index.get(&k).copied().unwrap_or(u32::MAX));
        }
        let bi = cache.1;
        if bi == u32::MAX {
            return None;
        }
        let e = EDGE as i64;
        let l = c.map(|v| v.rem_euclid(e) as usize);
        let j = l[0] + EDGE * (l[1] + EDGE * l[2]);
        let b = &self.blocks[bi as usize];
        (b.w[j] > 0).then(|| b.d[j] as f32 / D_ONE)
    }

    /// The trilinear distance (over `μ`) at world point `p`, `None` unless all eight voxel
    /// centres around it are observed (a partial set would let the band's sparse fringes,
    /// at depth edges, pass for surfaces).
    fn sample(&self, p: DVec3, cache: &mut (u64, u32)) -> Option<f32> {
        let g = p / self.voxel - DVec3::splat(0.5);
        let b = g.floor();
        let f = (g - b).as_vec3();
        let c0 = [b.x as i64, b.y as i64, b.z as i64];
        let mut s = 0.0f32;
        for dz in 0..2 {
            for dy in 0..2 {
                for dx in 0..2 {
                    let v = self.at([c0[0] + dx, c0[1] + dy, c0[2] + dz], cache)?;
                    let wx = if dx == 1 { f.x } else { 1.0 - f.x };
                    let wy = if dy == 1 { f.y } else { 1.0 - f.y };
                    let wz = if dz == 1 { f.z } else { 1.0 - f.z };
                    s += v * wx * wy * wz;
                }
            }
        }
        Some(s)
    }

    /// Casts the ray of camera direction `dir` (z = 1, so `t` is z-depth) from camera-to-world
    /// `pose` between z-depths `t0` and `t1`: the first crossing from in front of a surface
    /// to behind it, as a z-depth.
    pub fn cast(&self, pose: &DMat4, dir: Vec3, t0: f64, t1: f64) -> Option<f64> {
        let o = pose.w_axis.truncate();
        let dw = DMat3::from_mat4(*pose) * dir.as_dvec3();
        let len = dw.length();
        if !(len > 0.0 && t1 > t0) {
            return None;
        }
        let mut cache = (u64::MAX, 0u32);
        let (min_step, unknown_step) = (0.5 * self.voxel / len, 0.5 * self.mu / len);
        let mut t = t0;
        let mut prev: Option<(f64, f32)> = None;
        // The last unknown sample, and whether the march already went back to it: a step
        // through unknown space can land past the thin front of a surface (a sample needs
        // all eight voxels around it observed), so a first sample behind a surface is
        // checked again at the fine step before it counts as a back face.
        let (mut unknown_at, mut fine) = (None::<f64>, false);
        while t <= t1 {
            let f = self.sample(o + dw * t, &mut cache);
            match (prev, f) {
                (Some((tp, fp)), Some(fc)) if fp > 0.0 && fc <= 0.0 => {
                    return Some(tp + (t - tp) * (fp / (fp - fc)) as f64);
                }
                (None, Some(fc)) if fc < 0.0 && t > t0 => match unknown_at {
                    Some(tu) if !fine => {
                        fine = true;
                        t = tu + min_step;
                        continue;
                    }
                    _ => return None,
                },
                _ => {}
            }
            let step = match f {
                Some(fc) if fc > 0.0 => (0.8 * fc as f64 * self.mu / len).max(min_step),
                Some(_) => min_step,
                None if fine => min_step,
                None => unknown_step,
            };
            if f.is_none() {
                unknown_at = Some(t);
            } else {
                fine = false;
            }
            prev = f.map(|fc| (t, fc));
            t += step;
        }
        None
    }

    /// Writes the volume (a checkpoint's tail): voxel, `μ`, block count, then per block its
    /// key, distances and weights, little-endian.
    pub fn write_to(&self, w: &mut impl std::io::Write) -> std::io::Result<()> {
        for v in [
            self.voxel.to_bits(),
            self.mu.to_bits(),
            self.blocks.len() as u64,
        ] {
            w.write_all(&v.to_le_bytes())?;
        }
        for (k, b) in self.keys.iter().zip(&self.blocks) {
            w.write_all(&k.to_le_bytes())?;
            let mut buf = Vec::with_capacity(CELLS * 3);
            buf.extend(b.d.iter().flat_map(|v| v.to_le_bytes()));
            buf.extend_from_slice(&b.w);
            w.write_all(&buf)?;
        }
        Ok(())
    }

    /// Reads what [`Tsdf::write_to`] wrote from the front of `r`; `None` if it is not that.
    pub fn read_from(r: &mut &[u8]) -> Option<Tsdf> {
        let u64_at = |r: &mut &[u8]| -> Option<u64> {
            let (h, t) = r.split_first_chunk::<8>()?;
            *r = t;
            Some(u64::from_le_bytes(*h))
        };
        let voxel = f64::from_bits(u64_at(r)?);
        let mu = f64::from_bits(u64_at(r)?);
        let n = u64_at(r)? as usize;
        if !(voxel > 0.0 && mu > 0.0 && voxel.is_finite() && mu.is_finite()) {
            return None;
        }
        let block_bytes = 8 + CELLS * 3;
        if r.len() < n.checked_mul(block_bytes)? {
            return None;
        }
        let (mut keys, mut blocks) = (Vec::with_capacity(n), Vec::with_capacity(n));
        for _ in 0..n {
            keys.push(u64_at(r)?);
            let mut b = Block::default();
            let (d, t) = r.split_at(CELLS * 2);
            let (wt, t) = t.split_at(CELLS);
            for (i, c) in d.chunks_exact(2).enumerate() {
                b.d[i] = i16::from_le_bytes([c[0], c[1]]);
            }
            b.w.copy_from_slice(wt);
            *r = t;
            blocks.push(Box::new(b));
        }
        let index: HashMap<u64, u32, BuildHasherDefault<KeyHasher>> = keys
            .iter()
            .enumerate()
            .map(|(i, &k)| (k, i as u32))
            .collect();
        (index.len() == keys.len()).then_some(Tsdf {
            voxel,
            mu,
            index,
            keys,
            blocks,
        })
    }
}
