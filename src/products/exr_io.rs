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

/// How the maps are compressed. Both are lossless; `None` is the default because on a local
/// disk the CPU, not the bytes, bounds reading and writing the maps.
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

/// The `software` attribute.
const SOFTWARE: &str = concat!("mvao ", env!("CARGO_PKG_VERSION"));

/// The `comments` attribute.
const COMMENTS: &str = concat!(
    "mvao per-view maps: local position P, normal N, radius, depth (inf = empty), ",
    "ssao, border (px), index (u32, 4294967295 = empty), no_sample"
);

/// Encodes a view's maps as EXR bytes. All slices must hold `gbuf.width × gbuf.height`
/// values (an error otherwise).
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
    let n = w * h;
    let lens = [
        gbuf.position.len(),
        gbuf.normal.len(),
        gbuf.radius.len(),
        gbuf.depth.len(),
        gbuf.point.len(),
        ao.len(),
        no_sample.len(),
        border.len(),
    ];
    if lens.iter().any(|&l| l != n) {
        return Err(format!("map arrays of {lens:?} values for a {w}x{h} map"));
    }
    match compression {
        MapCompression::None => encode_uncompressed(gbuf, ao, no_sample, border),
        MapCompression::Zip => encode_with_crate(gbuf, ao, no_sample, border, compression),
    }
}

/// Uncompressed scan lines written straight from the maps into one buffer of the file's
/// exact size: the same bytes as the `exr` crate's encoder (a test checks it) without its
/// per-channel copies, each of which faults in fresh pages for a whole map.
fn encode_uncompressed(
    gbuf: &GBuffer,
    ao: &[f32],
    no_sample: &[bool],
    border: &[f32],
) -> std::result::Result<Vec<u8>, String> {
    let (w, h) = (gbuf.width, gbuf.height);
    let too_large = || format!("a {w}x{h} map is too large for an EXR file");
    let (wi, hi) = (
        i32::try_from(w).map_err(|_| too_large())?,
        i32::try_from(h).map_err(|_| too_large())?,
    );
    // Channels in the file's (byte-wise sorted) order, with their pixel type: 0 u32, 1 half,
    // 2 f32.
    const CHANNELS: [(&str, i32); 12] = [
        ("N.X", 2),
        ("N.Y", 2),
        ("N.Z", 2),
        ("P.X", 2),
        ("P.Y", 2),
        ("P.Z", 2),
        (channel::BORDER, 2),
        (channel::DEPTH, 2),
        (channel::INDEX, 0),
        (channel::NO_SAMPLE, 1),
        (channel::RADIUS, 2),
        (channel::SSAO, 2),
    ];
    let line_bytes = w
        .checked_mul(11 * 4 + 2)
        .filter(|&b| b <= i32::MAX as usize)
        .ok_or_else(too_large)?;
    let mut head = Vec::with_capacity(1024);
    head.extend_from_slice(&[0x76, 0x2f, 0x31, 0x01, 2, 0, 0, 0]);
    let attr = |head: &mut Vec<u8>, name: &str, kind: &str, value: &[u8]| {
        head.extend_from_slice(name.as_bytes());
        head.push(0);
        head.extend_from_slice(kind.as_bytes());
        head.push(0);
        head.extend_from_slice(&(value.len() as i32).to_le_bytes());
        head.extend_from_slice(value);
    };
    let mut chlist = Vec::new();
    for (name, kind) in CHANNELS {
        chlist.extend_from_slice(name.as_bytes());
        chlist.push(0);
        chlist.extend_from_slice(&kind.to_le_bytes());
        chlist.extend_from_slice(&[1, 0, 0, 0]); // pLinear (as the crate writes it), reserved
        chlist.extend_from_slice(&1i32.to_le_bytes()); // x sampling
        chlist.extend_from_slice(&1i32.to_le_bytes()); // y sampling
    }
    chlist.push(0);
    let mut window = Vec::new();
    for v in [0, 0, wi - 1, hi - 1] {
        window.extend_from_slice(&v.to_le_bytes());
    }
    // In the order the `exr` crate writes them (`chunkCount` and `type` are optional in a
    // single-part file; it writes them anyway).
    attr(&mut head, "chunkCount", "int", &hi.to_le_bytes());
    attr(&mut head, "channels", "chlist", &chlist);
    attr(&mut head, "compression", "compression", &[0]);
    attr(&mut head, "lineOrder", "lineOrder", &[0]);
    attr(&mut head, "displayWindow", "box2i", &window);
    attr(&mut head, "pixelAspectRatio", "float", &1f32.to_le_bytes());
    attr(&mut head, "screenWindowCenter", "v2f", &[0; 8]);
    attr(&mut head, "screenWindowWidth", "float", &1f32.to_le_bytes());
    attr(&mut head, "dataWindow", "box2i", &window);
    attr(&mut head, "type", "string", b"scanlineimage");
    attr(&mut head, "comments", "string", COMMENTS.as_bytes());
    attr(&mut head, "software", "string", SOFTWARE.as_bytes());
    head.push(0);
    let chunk = 8 + line_bytes;
    let first = head.len() + 8 * h;
    let total = h
        .checked_mul(chunk)
        .and_then(|b| b.checked_add(first))
        .ok_or_else(too_large)?;
    let mut out = Vec::with_capacity(total);
    out.extend_from_slice(&head);
    for y in 0..h {
        out.extend_from_slice(&((first + y * chunk) as u64).to_le_bytes());
    }
    let one = f16::ONE.to_bits();
    for y in 0..h {
        let r = y * w..(y + 1) * w;
        out.extend_from_slice(&(y as i32).to_le_bytes());
        out.extend_from_slice(&(line_bytes as i32).to_le_bytes());
        for k in 0..3 {
            put(
                &mut out,
                gbuf.normal[r.clone()].iter().map(|v| v[k].to_bits()),
            );
        }
        for k in 0..3 {
            put(
                &mut out,
                gbuf.position[r.clone()].iter().map(|v| v[k].to_bits()),
            );
        }
        for v in [&border[r.clone()], &gbuf.depth[r.clone()]] {
            put(&mut out, v.iter().map(|x| x.to_bits()));
        }
        put(&mut out, gbuf.point[r.clone()].iter().copied());
        let at = out.len();
        out.resize(at + 2 * w, 0);
        for (d, &b) in out[at..].chunks_exact_mut(2).zip(&no_sample[r.clone()]) {
            d.copy_from_slice(&(if b { one } else { 0 }).to_le_bytes());
        }
        for v in [&gbuf.radius[r.clone()], &ao[r.clone()]] {
            put(&mut out, v.iter().map(|x| x.to_bits()));
        }
    }
    debug_assert_eq!(out.len(), total);
    Ok(out)
}

/// Appends 32-bit words as little-endian bytes.
#[inline]
fn put(out: &mut Vec<u8>, words: impl ExactSizeIterator<Item = u32>) {
    let at = out.len();
    out.resize(at + 4 * words.len(), 0);
    for (d, v) in out[at..].chunks_exact_mut(4).zip(words) {
        d.copy_from_slice(&v.to_le_bytes());
    }
}

/// The `exr` crate's encoder (used for compressed maps).
fn encode_with_crate(
    gbuf: &GBuffer,
    ao: &[f32],
    no_sample: &[bool],
    border: &[f32],
    compression: MapCompression,
) -> std::result::Result<Vec<u8>, String> {
    let (w, h) = (gbuf.width, gbuf.height);
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
        software_name: Some(Text::from(SOFTWARE)),
        comments: Some(Text::from(COMMENTS)),
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
            lift_receivers: true,
        },
        ao,
        no_sample,
        border,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A small G-buffer with every kind of value: empty pixels (infinite depth), negative
    /// zeros, subnormals, NaN payloads and the largest index.
    fn maps(w: usize, h: usize) -> (GBuffer, Vec<f32>, Vec<bool>, Vec<f32>) {
        let n = w * h;
        let f = |i: usize, k: u32| f32::from_bits((i as u32).wrapping_mul(2_654_435_761) ^ k);
        let mut g = GBuffer {
            width: w,
            height: h,
            point: (0..n as u32)
                .map(|i| if i % 7 == 3 { EMPTY } else { i * 3 })
                .collect(),
            depth: (0..n)
                .map(|i| if i % 7 == 3 { f32::INFINITY } else { f(i, 1) })
                .collect(),
            position: (0..n).map(|i| Vec3::new(f(i, 2), f(i, 3), -0.0)).collect(),
            normal: (0..n).map(|i| Vec3::new(f(i, 4), 1e-40, f(i, 5))).collect(),
            radius: (0..n).map(|i| f(i, 6)).collect(),
            lift_receivers: true,
        };
        g.point[0] = u32::MAX - 1;
        let ao = (0..n).map(|i| f(i, 7)).collect();
        let ns = (0..n).map(|i| i % 3 == 0).collect();
        let border = (0..n).map(|i| f(i, 8)).collect();
        (g, ao, ns, border)
    }

    #[test]
    fn direct_encoding_equals_the_exr_crates_and_reads_back() {
        for (w, h) in [(1, 1), (5, 3), (64, 17)] {
            let (g, ao, ns, border) = maps(w, h);
            let direct = encode_maps(&g, &ao, &ns, &border, MapCompression::None).expect("direct");
            let krate =
                encode_with_crate(&g, &ao, &ns, &border, MapCompression::None).expect("crate");
            assert_eq!(direct.len(), krate.len(), "{w}x{h}");
            assert!(direct == krate, "{w}x{h}: bytes differ");
            let back = decode_maps(&direct, Path::new("t.exr"), None, true).expect("decode");
            let bits = |v: &[f32]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
            let bits3 = |v: &[Vec3]| {
                v.iter()
                    .flat_map(|p| p.to_array().map(f32::to_bits))
                    .collect::<Vec<_>>()
            };
            assert_eq!((back.gbuf.width, back.gbuf.height), (w, h));
            assert_eq!(back.gbuf.point, g.point);
            assert_eq!(bits(&back.gbuf.depth), bits(&g.depth));
            assert_eq!(bits3(&back.gbuf.position), bits3(&g.position));
            assert_eq!(bits3(&back.gbuf.normal), bits3(&g.normal));
            assert_eq!(bits(&back.gbuf.radius), bits(&g.radius));
            assert_eq!(bits(&back.ao), bits(&ao));
            assert_eq!(bits(&back.border), bits(&border));
            assert_eq!(back.no_sample, Some(ns));
        }
    }

    #[test]
    fn arrays_of_the_wrong_size_are_refused() {
        let (g, ao, ns, border) = maps(4, 4);
        let e = encode_maps(&g, &ao[..15], &ns, &border, MapCompression::None).unwrap_err();
        assert!(e.contains("4x4"), "{e}");
        let mut g0 = g.clone();
        g0.width = 0;
        assert!(encode_maps(&g0, &ao, &ns, &border, MapCompression::None).is_err());
    }
}
