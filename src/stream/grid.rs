//! The sparse voxel grid a stream integrates into: per occupied voxel Σ SSAO·w and Σ w (f64),
//! the w-weighted sums of position (from the voxel's corner) and normal. Voxels are keyed
//! by the Morton code of their integer cell, so the grid has no bounds to guess from the
//! first frames: every cell within ±2²⁰ voxels of the world origin has a key (±10 km at 1 cm).
//! Memory is one table entry per occupied voxel; the checkpoint is the table on disk.

use super::tsdf::Tsdf;
use crate::error::{Error, Result};
use glam::{DVec3, Vec3};
use std::collections::HashMap;
use std::hash::{BuildHasherDefault, Hasher};
use std::io::{Read, Write};
use std::path::Path;

/// Bits per axis of a Morton key.
pub const AXIS_BITS: u32 = 21;
/// Cells run from `-BIAS` to `BIAS - 1` along each axis.
pub const BIAS: i64 = 1 << (AXIS_BITS - 1);

/// Spreads the low 21 bits of `v` to every third bit.
fn part1by2(v: u64) -> u64 {
    let mut x = v & 0x1f_ffff;
    x = (x | (x << 32)) & 0x001f_0000_0000_ffff;
    x = (x | (x << 16)) & 0x001f_0000_ff00_00ff;
    x = (x | (x << 8)) & 0x100f_00f0_0f00_f00f;
    x = (x | (x << 4)) & 0x10c3_0c30_c30c_30c3;
    x = (x | (x << 2)) & 0x1249_2492_4924_9249;
    x
}

/// Gathers every third bit of `v` into the low 21 bits.
fn compact1by2(v: u64) -> u64 {
    let mut x = v & 0x1249_2492_4924_9249;
    x = (x | (x >> 2)) & 0x10c3_0c30_c30c_30c3;
    x = (x | (x >> 4)) & 0x100f_00f0_0f00_f00f;
    x = (x | (x >> 8)) & 0x001f_0000_ff00_00ff;
    x = (x | (x >> 16)) & 0x001f_0000_0000_ffff;
    x = (x | (x >> 32)) & 0x1f_ffff;
    x
}

/// The Morton key of integer cell `c`, `None` outside ±2²⁰ cells.
pub fn morton(c: [i64; 3]) -> Option<u64> {
    if c.iter().any(|&v| !(-BIAS..BIAS).contains(&v)) {
        return None;
    }
    let u = c.map(|v| (v + BIAS) as u64);
    Some(part1by2(u[0]) | (part1by2(u[1]) << 1) | (part1by2(u[2]) << 2))
}

/// The integer cell of Morton key `k`.
pub fn unmorton(k: u64) -> [i64; 3] {
    [0, 1, 2].map(|a| compact1by2(k >> a) as i64 - BIAS)
}

/// Multiplicative hashing of a Morton key: cheap, and deterministic across runs.
#[derive(Default, Clone, Copy)]
pub struct KeyHasher(u64);

impl Hasher for KeyHasher {
    fn finish(&self) -> u64 {
        self.0
    }
    fn write(&mut self, bytes: &[u8]) {
        for &b in bytes {
            self.0 = (self.0.rotate_left(8) ^ b as u64).wrapping_mul(0x9e37_79b9_7f4a_7c15);
        }
    }
    fn write_u64(&mut self, k: u64) {
        let h = (k ^ (k >> 29)).wrapping_mul(0x9e37_79b9_7f4a_7c15);
        self.0 = h ^ (h >> 32);
    }
}

/// Parts of the table (a power of two).
pub const SHARDS: usize = 16;

/// One part of the table.
pub type Table = HashMap<u64, Cell, BuildHasherDefault<KeyHasher>>;

/// The part of the table holding key `k`: high bits of a mix of the key, so that a frame's
/// voxels spread evenly over the parts.
#[inline]
pub fn shard(k: u64) -> usize {
    (k.wrapping_mul(0x9e37_79b9_7f4a_7c15) >> 60) as usize & (SHARDS - 1)
}

/// One occupied voxel's sums.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct Cell {
    /// Σ SSAO·w.
    pub aw: f64,
    /// Σ w.
    pub w: f64,
    /// Σ w·(p − corner), metres.
    pub pos: [f32; 3],
    /// Σ w·n.
    pub nrm: [f32; 3],
}

impl Cell {
    /// Adds the sums of `o`.
    #[inline]
    pub fn accumulate(&mut self, o: &Cell) {
        self.aw += o.aw;
        self.w += o.w;
        for a in 0..3 {
            self.pos[a] += o.pos[a];
            self.nrm[a] += o.nrm[a];
        }
    }
}

/// One output point of the grid.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct VoxelPoint {
    /// Morton key.
    pub key: u64,
    /// Weighted mean position (world).
    pub position: DVec3,
    /// Unit mean normal (zero if the normals cancelled).
    pub normal: Vec3,
    /// Σ SSAO·w / Σ w in \[0, 1\].
    pub ao: f32,
    /// Σ w.
    pub weight: f64,
}

/// The sparse grid.
#[derive(Debug, Clone)]
pub struct VoxelGrid {
    /// Edge of a voxel (metres).
    pub voxel: f64,
    /// The table, split by key into [`SHARDS`] parts that frames update in parallel.
    cells: Vec<Table>,
    /// Samples whose cell has no key (beyond ±2²⁰ voxels).
    pub out_of_range: u64,
}

impl VoxelGrid {
    /// An empty grid of voxels of edge `voxel` metres.
    pub fn new(voxel: f64) -> VoxelGrid {
        VoxelGrid {
            voxel,
            cells: (0..SHARDS).map(|_| Table::default()).collect(),
            out_of_range: 0,
        }
    }

    /// The integer cell holding world point `p`.
    pub fn cell_of(&self, p: DVec3) -> [i64; 3] {
        let c = (p / self.voxel).floor();
        // `as` saturates, so a far or non-finite point falls outside the keyed range.
        [c.x as i64, c.y as i64, c.z as i64]
    }

    /// The key of the voxel holding `p`, `None` beyond the keyed range.
    pub fn key_of(&self, p: DVec3) -> Option<u64> {
        if !p.is_finite() {
            return None;
        }
        morton(self.cell_of(p))
    }

    /// World position of the corner (smallest coordinates) of the voxel of key `k`.
    pub fn corner(&self, k: u64) -> DVec3 {
        let c = unmorton(k);
        DVec3::new(c[0] as f64, c[1] as f64, c[2] as f64) * self.voxel
    }

    /// Adds one sample: world point `p`, world unit normal `n`, SSAO `ao`, weight `w > 0`.
    pub fn add(&mut self, p: DVec3, n: Vec3, ao: f32, w: f32) {
        let Some(k) = self.key_of(p) else {
            self.out_of_range += 1;
            return;
        };
        let off = (p - self.corner(k)).as_vec3() * w;
        let nw = n * w;
        let c = self.cells[shard(k)].entry(k).or_default();
        c.aw += ao as f64 * w as f64;
        c.w += w as f64;
        for a in 0..3 {
            c.pos[a] += off[a];
            c.nrm[a] += nw[a];
        }
    }

    /// One sample's contribution to the voxel of key `k`: world point `p`, world unit normal
    /// `n`, SSAO `ao`, weight `w`.
    pub fn contribution(&self, k: u64, p: DVec3, n: Vec3, ao: f32, w: f32) -> Cell {
        let off = (p - self.corner(k)).as_vec3() * w;
        let nw = n * w;
        Cell {
            aw: ao as f64 * w as f64,
            w: w as f64,
            pos: off.to_array(),
            nrm: nw.to_array(),
        }
    }

    /// Adds summed contributions `c` to the voxel of key `k`.
    pub fn add_cell(&mut self, k: u64, c: &Cell) {
        self.cells[shard(k)].entry(k).or_default().accumulate(c);
    }

    /// The parts of the table, for updates in parallel (key `k` belongs in part [`shard`]`(k)`).
    pub fn shards_mut(&mut self) -> &mut [Table] {
        &mut self.cells
    }

    /// Number of occupied voxels.
    pub fn len(&self) -> usize {
        self.cells.iter().map(HashMap::len).sum()
    }

    /// True when no voxel is occupied.
    pub fn is_empty(&self) -> bool {
        self.cells.iter().all(HashMap::is_empty)
    }

    /// The sums of the voxel of key `k`.
    pub fn get(&self, k: u64) -> Option<&Cell> {
        self.cells[shard(k)].get(&k)
    }

    /// Bytes the table holds (its entries and control bytes at its present capacity).
    pub fn table_bytes(&self) -> usize {
        let entry = std::mem::size_of::<(u64, Cell)>() + 1;
        let slots: usize = self.cells.iter().map(HashMap::capacity).sum();
        slots * entry + SHARDS * std::mem::size_of::<Table>() + std::mem::size_of::<Self>()
    }

    /// Every occupied voxel with positive weight as a point, in key order.
    pub fn points(&self) -> Vec<VoxelPoint> {
        let mut keys: Vec<u64> = self.iter().map(|(k, _)| k).collect();
        keys.sort_unstable();
        keys.into_iter()
            .filter_map(|k| {
                let c = self.get(k)?;
                self.point_of(k, c)
            })
            .collect()
    }

    /// The point of voxel `k` with sums `c`, `None` when its weight is not positive.
    pub fn point_of(&self, k: u64, c: &Cell) -> Option<VoxelPoint> {
        if !(c.w > 0.0) {
            return None;
        }
        let inv = 1.0 / c.w;
        let off = DVec3::new(c.pos[0] as f64, c.pos[1] as f64, c.pos[2] as f64) * inv;
        // The mean of points inside a voxel stays inside it; clamping guards against rounding.
        let off = off.clamp(DVec3::ZERO, DVec3::splat(self.voxel));
        Some(VoxelPoint {
            key: k,
            position: self.corner(k) + off,
            normal: Vec3::from(c.nrm).normalize_or_zero(),
            ao: ((c.aw * inv) as f32).clamp(0.0, 1.0),
            weight: c.w,
        })
    }

    /// Every occupied voxel's key and sums, in no particular order.
    pub fn iter(&self) -> impl Iterator<Item = (u64, &Cell)> + '_ {
        self.cells
            .iter()
            .flat_map(|t| t.iter().map(|(k, c)| (*k, c)))
    }
}

const MAGIC: &[u8; 8] = b"MVAOGRD2";
/// Checkpoints of the first layout: the grid without a history volume.
const MAGIC_V1: &[u8; 8] = b"MVAOGRD1";

/// What a checkpoint holds besides the grid: how far the stream got and for which settings.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct CheckpointHead {
    /// Frames integrated (the next frame to read).
    pub frames_done: u64,
    /// Hash of the settings and inputs; a checkpoint of other settings is not resumed.
    pub settings: u64,
}

/// Writes the grid, the history volume if any, and `head` to `path` (a temporary file, then
/// renamed over it).
pub fn write_checkpoint(
    path: &Path,
    grid: &VoxelGrid,
    volume: Option<&Tsdf>,
    head: CheckpointHead,
) -> Result<()> {
    crate::io::atomic::write_atomic(path, |out| {
        let mut w = std::io::BufWriter::new(out);
        w.write_all(MAGIC)?;
        for v in [
            head.frames_done,
            head.settings,
            grid.voxel.to_bits(),
            grid.out_of_range,
            grid.len() as u64,
        ] {
            w.write_all(&v.to_le_bytes())?;
        }
        let mut keys: Vec<u64> = grid.iter().map(|(k, _)| k).collect();
        keys.sort_unstable();
        for k in keys {
            let c = grid.get(k).copied().unwrap_or_default();
            w.write_all(&k.to_le_bytes())?;
            w.write_all(&c.aw.to_le_bytes())?;
            w.write_all(&c.w.to_le_bytes())?;
            for v in c.pos.iter().chain(&c.nrm) {
                w.write_all(&v.to_le_bytes())?;
            }
        }
        match volume {
            Some(v) => {
                w.write_all(&[1])?;
                v.write_to(&mut w)?;
            }
            None => w.write_all(&[0])?,
        }
        w.flush()
    })
}

/// What [`read_checkpoint`] returns: the grid, the history volume (if the run had one) and
/// the head.
pub type Checkpoint = (VoxelGrid, Option<Tsdf>, CheckpointHead);

/// Reads a checkpoint written by [`write_checkpoint`] (or by the first layout, which has no
/// history volume).
pub fn read_checkpoint(path: &Path) -> Result<Checkpoint> {
    let bytes = std::fs::read(path).map_err(|e| Error::io(path, e))?;
    let bad = || Error::format(path, "not an mvao stream checkpoint, or truncated");
    let mut r: &[u8] = &bytes;
    let mut magic = [0u8; 8];
    r.read_exact(&mut magic).map_err(|_| bad())?;
    let v1 = &magic == MAGIC_V1;
    if &magic != MAGIC && !v1 {
        return Err(bad());
    }
    let mut u64s = [0u64; 5];
    for v in &mut u64s {
        let mut b = [0u8; 8];
        r.read_exact(&mut b).map_err(|_| bad())?;
        *v = u64::from_le_bytes(b);
    }
    let [frames_done, settings, voxel, out_of_range, n] = u64s;
    const ENTRY: usize = 8 * 3 + 4 * 6;
    let grid_bytes = n.saturating_mul(ENTRY as u64);
    let rest = (r.len() as u64).checked_sub(grid_bytes).ok_or_else(bad)?;
    if v1 && rest != 0 {
        return Err(bad());
    }
    let (entries, mut tail) = r.split_at(grid_bytes as usize);
    let mut grid = VoxelGrid::new(f64::from_bits(voxel));
    grid.out_of_range = out_of_range;
    for e in entries.chunks_exact(ENTRY) {
        let u = |i: usize| {
            let mut b = [0u8; 8];
            b.copy_from_slice(&e[i..i + 8]);
            u64::from_le_bytes(b)
        };
        let f = |i: usize| {
            let mut b = [0u8; 4];
            b.copy_from_slice(&e[24 + 4 * i..28 + 4 * i]);
            f32::from_le_bytes(b)
        };
        let c = Cell {
            aw: f64::from_bits(u(8)),
            w: f64::from_bits(u(16)),
            pos: [f(0), f(1), f(2)],
            nrm: [f(3), f(4), f(5)],
        };
        grid.cells[shard(u(0))].insert(u(0), c);
    }
    let volume = if v1 {
        None
    } else {
        let mut flag = [0u8; 1];
        tail.read_exact(&mut flag).map_err(|_| bad())?;
        match flag[0] {
            0 => None,
            1 => Some(Tsdf::read_from(&mut tail).ok_or_else(bad)?),
            _ => return Err(bad()),
        }
    };
    if !tail.is_empty() {
        return Err(bad());
    }
    Ok((
        grid,
        volume,
        CheckpointHead {
            frames_done,
            settings,
        },
    ))
}
