//! One view's per-point arrays (radius, pixel, depth and, for a native grid, the grid pixel)
//! as a raw little-endian file: a 48-byte header, then each array in turn.
//!
//! Header: magic `MVAOPTS\0` (8 bytes), format version (u32), flags (u32; bit 0 = grid
//! pixels present), point count (u64), payload length in bytes (u64), xxh3-128 of the payload
//! (u128). A short, long or altered file is an error, never a wrong value.

use crate::error::{Error, Result};
use std::path::Path;
use xxhash_rust::xxh3::xxh3_128;

/// File magic.
pub const MAGIC: [u8; 8] = *b"MVAOPTS\0";
/// Layout version of the points file.
pub const VERSION: u32 = 1;
/// Header length in bytes.
pub const HEADER_LEN: usize = 48;
const FLAG_GRID: u32 = 1;

/// The per-point arrays of one view.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Points {
    /// Radius of each point.
    pub radii: Vec<f32>,
    /// Pixel of each point ([`crate::gbuffer::EMPTY`] if none).
    pub pixel: Vec<u32>,
    /// Depth of each point.
    pub depth: Vec<f32>,
    /// Native-grid pixel of each point, when the native grid is the map.
    pub grid_pixels: Option<Vec<u32>>,
}

/// Appends each value's 4 little-endian bytes (a loop the compiler turns into a copy).
fn put<T: Copy>(out: &mut Vec<u8>, v: &[T], le: impl Fn(T) -> [u8; 4]) {
    let start = out.len();
    out.resize(start + 4 * v.len(), 0);
    for (dst, &x) in out[start..].chunks_exact_mut(4).zip(v) {
        dst.copy_from_slice(&le(x));
    }
}

/// Encodes the arrays; all must have `radii.len()` entries (checked by the caller).
pub fn encode(radii: &[f32], pixel: &[u32], depth: &[f32], grid_pixels: Option<&[u32]>) -> Vec<u8> {
    let n = radii.len();
    let arrays = 3 + usize::from(grid_pixels.is_some());
    let payload = 4 * n * arrays;
    let mut out = Vec::with_capacity(HEADER_LEN + payload);
    out.resize(HEADER_LEN, 0);
    put(&mut out, radii, f32::to_le_bytes);
    put(&mut out, pixel, u32::to_le_bytes);
    put(&mut out, depth, f32::to_le_bytes);
    if let Some(g) = grid_pixels {
        put(&mut out, g, u32::to_le_bytes);
    }
    let hash = xxh3_128(&out[HEADER_LEN..]);
    let flags = if grid_pixels.is_some() { FLAG_GRID } else { 0 };
    let h = &mut out[..HEADER_LEN];
    h[0..8].copy_from_slice(&MAGIC);
    h[8..12].copy_from_slice(&VERSION.to_le_bytes());
    h[12..16].copy_from_slice(&flags.to_le_bytes());
    h[16..24].copy_from_slice(&(n as u64).to_le_bytes());
    h[24..32].copy_from_slice(&(payload as u64).to_le_bytes());
    h[32..48].copy_from_slice(&hash.to_le_bytes());
    out
}

/// Decodes a points file; `path` names it in errors.
pub fn decode(bytes: &[u8], path: &Path) -> Result<Points> {
    let bad = |msg: String| Error::format(path, msg);
    if bytes.len() < HEADER_LEN {
        return Err(bad(format!(
            "points file truncated: {} bytes, the header alone is {HEADER_LEN}",
            bytes.len()
        )));
    }
    let (head, body) = bytes.split_at(HEADER_LEN);
    let u32_at = |o: usize| u32::from_le_bytes([head[o], head[o + 1], head[o + 2], head[o + 3]]);
    let u64_at = |o: usize| {
        let mut b = [0u8; 8];
        b.copy_from_slice(&head[o..o + 8]);
        u64::from_le_bytes(b)
    };
    if head[0..8] != MAGIC {
        return Err(bad("not an mvao points file (bad magic)".into()));
    }
    let version = u32_at(8);
    if version != VERSION {
        return Err(bad(format!(
            "points file version {version}, this mvao reads {VERSION}"
        )));
    }
    let flags = u32_at(12);
    if flags & !FLAG_GRID != 0 {
        return Err(bad(format!("unknown flags {flags:#x} in the points file")));
    }
    let n = u64_at(16);
    let payload = u64_at(24);
    let arrays = 3 + u64::from(flags & FLAG_GRID);
    let want = n.checked_mul(4 * arrays);
    if want != Some(payload) || payload != body.len() as u64 {
        return Err(bad(format!(
            "points file of {n} points should carry {} payload bytes; header says {payload}, \
             file has {} (truncated or corrupt)",
            want.map_or("too many".to_string(), |w| w.to_string()),
            body.len()
        )));
    }
    let mut hash = [0u8; 16];
    hash.copy_from_slice(&head[32..48]);
    if xxh3_128(body) != u128::from_le_bytes(hash) {
        return Err(bad("points file checksum mismatch (corrupt)".into()));
    }
    let n = n as usize;
    let mut chunks = body.chunks_exact(4 * n.max(1));
    let mut next_u32 = || -> Vec<u32> {
        if n == 0 {
            return Vec::new();
        }
        chunks
            .next()
            .map(|c| {
                c.chunks_exact(4)
                    .map(|b| u32::from_le_bytes([b[0], b[1], b[2], b[3]]))
                    .collect()
            })
            .unwrap_or_default()
    };
    let as_f32 = |v: Vec<u32>| -> Vec<f32> { v.into_iter().map(f32::from_bits).collect() };
    let radii = as_f32(next_u32());
    let pixel = next_u32();
    let depth = as_f32(next_u32());
    let grid_pixels = (flags & FLAG_GRID != 0).then(&mut next_u32);
    Ok(Points {
        radii,
        pixel,
        depth,
        grid_pixels,
    })
}
