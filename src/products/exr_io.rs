//! One view's per-pixel maps as a single multi-channel OpenEXR image, so a person can open a
//! product in any EXR viewer: `P.X P.Y P.Z` (local position), `N.X N.Y N.Z` (normal),
//! `radius`, `depth`, `ssao`, `border` (f32), `index` (u32 point index, [`EMPTY`] where the
//! pixel is empty) and `no_sample` (half, 0 or 1). Lossless compression only, so every sample
//! comes back with its exact bits (infinite depths of empty pixels included).

use crate::error::{Error, Result};
use crate::gbuffer::{GBuffer, EMPTY};
use exr::prelude::*;
use glam::Vec3;
use std::io::Cursor;
use std::path::Path;

/// How the maps are compressed. Both are lossless; `None` is the default because it reads and
/// writes fastest on local disks (see the report in [`crate::products`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum MapCompression {
    /// Uncompressed scan lines: largest files, least CPU.
    #[default]
    None,
    /// ZIP over blocks of 16 scan lines: smaller files (empty regions shrink to almost
    /// nothing), more CPU.
    Zip,
}

/// Channel names, as written.
pub mod channel {
    /// Local position x, y, z.
    pub const POSITION: [&str; 3] = ["P.X", "P.Y", "P.Z"];
    /// Normal x, y, z.
    pub const NORMAL: [&str; 3] = ["N.X", "N.Y", "N.Z"];
    /// Radius `rad(p)`.
    pub const RADIUS: &str = "radius";
    /// Depth (infinite where empty).
    pub const DEPTH: &str = "depth";
    /// Blurred SSAO.
    pub const SSAO: &str = "ssao";
    /// Distance to the nearest depth discontinuity (pixels).
    pub const BORDER: &str = "border";
    /// Point index (u32).
    pub const INDEX: &str = "index";
    /// 1 where a valid pixel had no valid SSAO sample.
    pub const NO_SAMPLE: &str = "no_sample";
}

/// The maps of one view as decoded from an EXR product.
#[derive(Debug, Clone, Default)]
pub struct Maps {
    /// The G-buffer.
    pub gbuf: GBuffer,
    /// Per-pixel SSAO.
    pub ao: Vec<f32>,
    /// Per-pixel no-sample flags; `None` when they were not asked for.
    pub no_sample: Option<Vec<bool>>,
    /// Per-pixel border distance.
    pub border: Vec<f32>,
}

/// Encodes a view's maps as EXR bytes. All slices must hold `gbuf.width × gbuf.height`
/// values (checked by the caller).
pub fn encode_maps(
    gbuf: &GBuffer,
    ao: &[f32],
    no_sample: &[bool],
    border: &[f32],
    compression: MapCompression,
) -> std::result::Result<Vec<u8>, String> {
    let (w, h) = (gbuf.width, gbuf.height);
    if w == 0 || h == 0 {
        return Err(format!("a {w}x{h} map cannot be stored"));
    }
    let comp = |v: &[Vec3], k: usize| -> Vec<f32> { v.iter().map(|p| p[k]).collect() };
    let f32ch = |name: &str, v: Vec<f32>| AnyChannel::new(name, FlatSamples::F32(v));
    let mut list: Vec<AnyChannel<FlatSamples>> = Vec::with_capacity(12);
    for k in 0..3 {
        list.push(f32ch(channel::POSITION[k], comp(&gbuf.position, k)));
        list.push(f32ch(channel::NORMAL[k], comp(&gbuf.normal, k)));
    }
    list.push(f32ch(channel::RADIUS, gbuf.radius.clone()));
    list.push(f32ch(channel::DEPTH, gbuf.depth.clone()));
    list.push(f32ch(channel::SSAO, ao.to_vec()));
    list.push(f32ch(channel::BORDER, border.to_vec()));
    list.push(AnyChannel::new(
        channel::INDEX,
        FlatSamples::U32(gbuf.point.clone()),
    ));
    list.push(AnyChannel::new(
        channel::NO_SAMPLE,
        FlatSamples::F16(
            no_sample
                .iter()
                .map(|&b| if b { f16::ONE } else { f16::ZERO })
                .collect(),
        ),
    ));
    let encoding = Encoding {
        compression: match compression {
            MapCompression::None => Compression::Uncompressed,
            MapCompression::Zip => Compression::ZIP16,
        },
        blocks: Blocks::ScanLines,
        line_order: LineOrder::Increasing,
    };
    let attrs = LayerAttributes {
        software_name: Some(Text::from(concat!("mvao ", env!("CARGO_PKG_VERSION")))),
        comments: Some(Text::from(
            "mvao per-view maps: local position P, normal N, radius, depth (inf = empty), \
             ssao, border (px), index (u32, 4294967295 = empty), no_sample",
        )),
        ..Default::default()
    };
    let layer = Layer::new(
        (w, h),
        attrs,
        encoding,
        AnyChannels::sort(SmallVec::from_vec(list)),
    );
    let image = Image::from_layer(layer);
    // Raw maps are ~50 bytes per pixel; reserve that so the buffer grows once.
    let mut buf = Vec::with_capacity(w * h * 50 + 4096);
    image
        .write()
        .to_buffered(Cursor::new(&mut buf))
        .map_err(|e| format!("cannot encode the maps as EXR: {e}"))?;
    Ok(buf)
}

/// Decodes EXR bytes written by [`encode_maps`]. `path` names the product in errors;
/// `points` is the scan's point count (every non-empty `index` must be below it) when known.
pub fn decode_maps(
    bytes: &[u8],
    path: &Path,
    points: Option<u64>,
    with_no_sample: bool,
) -> Result<Maps> {
    let bad = |msg: String| Error::format(path, msg);
    let image = read()
        .no_deep_data()
        .largest_resolution_level()
        .all_channels()
        .first_valid_layer()
        .all_attributes()
        .from_buffered(Cursor::new(bytes))
        .map_err(|e| bad(format!("not a readable EXR map: {e}")))?;
    let layer = image.layer_data;
    let (w, h) = (layer.size.width(), layer.size.height());
    let n = w
        .checked_mul(h)
        .ok_or_else(|| bad(format!("map size {w}x{h} overflows")))?;
    let mut chans = layer.channel_data.list;
    let mut take = |name: &str| -> Result<FlatSamples> {
        let i = chans
            .iter()
            .position(|c| c.name.eq(name))
            .ok_or_else(|| bad(format!("channel '{name}' is missing")))?;
        let s = chans.swap_remove(i).sample_data;
        if s.len() != n {
            return Err(bad(format!(
                "channel '{name}' has {} samples for a {w}x{h} map",
                s.len()
            )));
        }
        Ok(s)
    };
    let mut f32s = |name: &str| -> Result<Vec<f32>> {
        match take(name)? {
            FlatSamples::F32(v) => Ok(v),
            _ => Err(bad(format!("channel '{name}' is not 32-bit float"))),
        }
    };
    let vec3 = |x: Vec<f32>, y: Vec<f32>, z: Vec<f32>| -> Vec<Vec3> {
        x.iter()
            .zip(&y)
            .zip(&z)
            .map(|((&x, &y), &z)| Vec3::new(x, y, z))
            .collect()
    };
    let [px, py, pz] = channel::POSITION;
    let position = vec3(f32s(px)?, f32s(py)?, f32s(pz)?);
    let [nx, ny, nz] = channel::NORMAL;
    let normal = vec3(f32s(nx)?, f32s(ny)?, f32s(nz)?);
    let radius = f32s(channel::RADIUS)?;
    let depth = f32s(channel::DEPTH)?;
    let ao = f32s(channel::SSAO)?;
    let border = f32s(channel::BORDER)?;
    let point = match take(channel::INDEX)? {
        FlatSamples::U32(v) => v,
        _ => return Err(bad(format!("channel '{}' is not u32", channel::INDEX))),
    };
    if let Some(count) = points {
        if let Some(&bad_i) = point.iter().find(|&&p| p != EMPTY && p as u64 >= count) {
            return Err(bad(format!(
                "point index {bad_i} in the map, but the scan has {count} points"
            )));
        }
    }
    let no_sample = if with_no_sample {
        let v = match take(channel::NO_SAMPLE)? {
            FlatSamples::F16(v) => v,
            _ => {
                return Err(bad(format!(
                    "channel '{}' is not 16-bit float",
                    channel::NO_SAMPLE
                )))
            }
        };
        let mut flags = Vec::with_capacity(n);
        for s in v {
            flags.push(match s.to_bits() {
                0 => false,
                b if b == f16::ONE.to_bits() => true,
                _ => {
                    return Err(bad(format!(
                        "channel '{}' holds {s}, not 0 or 1",
                        channel::NO_SAMPLE
                    )))
                }
            });
        }
        Some(flags)
    } else {
        None
    };
    Ok(Maps {
        gbuf: GBuffer {
            width: w,
            height: h,
            point,
            depth,
            position,
            normal,
            radius,
        },
        ao,
        no_sample,
        border,
    })
}
