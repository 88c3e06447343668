//! Writing a LAS or LAZ result beside its input: the input's records, header and VLRs kept,
//! the `ao` value added as an extra-bytes dimension.

use super::read::is_extra_bytes_vlr;
use super::*;
use crate::io::output::ExtraFloat;

/// What happens to RGB in a record.
#[derive(Clone, Copy)]
pub(super) enum Paint {
    /// The input had no colour: grey.
    Grey,
    /// The input's colour stays.
    Keep,
    /// Grey replaces the colour.
    Replace,
    /// Colour × grey.
    Modulate,
}

/// Storage type of a float dimension.
#[derive(Clone, Copy, PartialEq)]
pub(super) enum FloatType {
    F32,
    F64,
}

/// Writes `input`'s points with every original field unchanged, plus the AO (one finite value
/// per point) as an `ao` float extra-bytes dimension, each of `extra` as a float dimension of
/// its name, and RGB by `color` (grey `ao^(1/gamma)` scaled to 16 bits; formats without colour
/// gain it). An existing float dimension of one of those names is overwritten. The header keeps scale, offset, VLRs, EVLRs and system identifier; the
/// generating software becomes `mvao <version>`. `compress` writes LAZ. Atomic.
pub fn write_las(
    input: &LasInput,
    ao: &[f32],
    extra: &[ExtraFloat],
    gamma: f32,
    color: ColorMode,
    out: &Path,
    compress: bool,
) -> Result<()> {
    check_ao(ao, input.len(), out)?;
    for e in extra {
        check_ao(e.values, input.len(), out)?;
    }
    check_compress(compress, out)?;
    let out_id = match input.format_id {
        0 => 2,
        1 => 3,
        4 => 5,
        6 => 7,
        9 => 10,
        id => id,
    };
    let std_len = |id: u8| {
        STD_LEN
            .get(id as usize)
            .copied()
            .ok_or_else(|| write_error(out, format!("unknown point format {id}")))
    };
    let in_std = std_len(input.format_id)?;
    let out_std = std_len(out_id)?;
    let in_extra = input.record_len - in_std;
    let paint = match (input.format.has_color, color) {
        (false, _) => Paint::Grey,
        (true, ColorMode::Keep) => Paint::Keep,
        (true, ColorMode::Replace) => Paint::Replace,
        (true, ColorMode::Modulate) => Paint::Modulate,
    };
    // RGB goes where the output format has it; formats without colour get it inserted there.
    let rgb_at = rgb_offset(out_id)
        .ok_or_else(|| write_error(out, format!("point format {out_id} has no colour")))?;
    let (insert_at, insert_len) = if out_id != input.format_id {
        (rgb_at, out_std - in_std)
    } else {
        (input.record_len, 0)
    };
    let mut vlrs = input.builder.vlrs.clone();
    let mut evlrs = input.builder.evlrs.clone();
    let mut dims = vec![ExtraFloat {
        name: AO_NAME,
        description: AO_DESCRIPTION,
        range: (0.0, 1.0),
        values: ao,
    }];
    dims.extend_from_slice(extra);
    let (slots, out_extra) = float_layout(
        input, &dims, in_extra, insert_len, out_std, &mut vlrs, &mut evlrs,
    )?;
    let mut format =
        Format::new(out_id).map_err(|e| write_error(out, format!("point format {out_id}: {e}")))?;
    format.extra_bytes = out_extra as u16;
    format.is_compressed = compress;

    let mut builder = input.builder.clone();
    builder.vlrs = vlrs;
    builder.evlrs = evlrs;
    builder.point_format = format;
    builder.generating_software = software();
    builder.system_identifier = las_ascii(&builder.system_identifier, 32);
    for v in builder.vlrs.iter_mut().chain(builder.evlrs.iter_mut()) {
        v.user_id = las_ascii(&v.user_id, 16);
        v.description = las_ascii(&v.description, 32);
    }
    let header = output_header(input, builder, format, out)?;
    let waveform = WaveformPatch {
        bits: if format.has_waveform {
            input.global_encoding & WAVEFORM_BITS
        } else {
            0
        },
        evlr: input.waveform_evlr.filter(|_| format.has_waveform),
    };

    let out_len = format.len() as usize;
    let in_len = input.record_len;
    let fill = |dst: &mut [u8], first: usize| {
        let n = dst.len() / out_len;
        let src = &input.records[first * in_len..(first + n) * in_len];
        dst.par_chunks_exact_mut(out_len)
            .zip(src.par_chunks_exact(in_len))
            .enumerate()
            .for_each(|(k, (o, i))| {
                let a = ao[first + k];
                o[..insert_at].copy_from_slice(&i[..insert_at]);
                o[insert_at..insert_at + insert_len].fill(0);
                o[insert_at + insert_len..insert_len + in_len].copy_from_slice(&i[insert_at..]);
                let g = grey(a, gamma) as u16;
                for c in 0..3 {
                    let at = rgb_at + 2 * c;
                    let old = u16::from_le_bytes([o[at], o[at + 1]]);
                    let new = match paint {
                        Paint::Keep => old,
                        Paint::Grey | Paint::Replace => g * 257,
                        Paint::Modulate => ((old as u32 * g as u32 + 127) / 255) as u16,
                    };
                    o[at..at + 2].copy_from_slice(&new.to_le_bytes());
                }
                for (&(at, ty), d) in slots.iter().zip(&dims) {
                    let v = d.values[first + k];
                    match ty {
                        FloatType::F32 => o[at..at + 4].copy_from_slice(&v.to_le_bytes()),
                        FloatType::F64 => o[at..at + 8].copy_from_slice(&(v as f64).to_le_bytes()),
                    }
                }
            });
    };
    write_points(out, header, input.len(), fill, waveform)
}

/// Where `write_las` puts each of `dims` in the output record, in which type, and how many
/// extra bytes the output record has: an existing float dimension of the name is reused, else
/// one is described (in the extra-bytes VLR) after the input's `in_extra` extra bytes.
/// `insert_len` is the colour inserted before the extra bytes, `out_std` the output format's
/// standard record length.
fn float_layout(
    input: &LasInput,
    dims: &[ExtraFloat],
    in_extra: usize,
    insert_len: usize,
    out_std: usize,
    vlrs: &mut Vec<Vlr>,
    evlrs: &mut [Vlr],
) -> Result<(Vec<(usize, FloatType)>, usize)> {
    let mut slots = Vec::with_capacity(dims.len());
    let mut data = Vec::new();
    let mut added = 0;
    for dim in dims {
        let existing = input.extra.iter().find(|d| d.name == dim.name);
        match existing {
            Some(d) if d.data_type == 9 && d.scale.is_none() && d.value_offset.is_none() => {
                slots.push((d.offset + insert_len, FloatType::F32));
            }
            Some(d) if d.data_type == 10 && d.scale.is_none() && d.value_offset.is_none() => {
                slots.push((d.offset + insert_len, FloatType::F64));
            }
            Some(d) => {
                return Err(Error::format(
                    &input.path,
                    format!(
                        "has an extra dimension '{}' of data type {} (scaled or not a float): \
                         rename it before writing a new '{}'",
                        dim.name, d.data_type, dim.name
                    ),
                ))
            }
            None => {
                if added == 0 {
                    // Undocumented extra bytes keep their place: describe them so the new
                    // dimensions land after.
                    let documented: usize = input.extra.iter().map(|d| d.size).sum();
                    let mut gap = in_extra - documented;
                    let mut k = 0;
                    while gap > 0 {
                        let n = gap.min(255);
                        let name = format!("undocumented_{k}");
                        data.extend(descriptor(&name, 0, n as u8, "", None));
                        gap -= n;
                        k += 1;
                    }
                }
                data.extend(descriptor(dim.name, 9, 0, dim.description, Some(dim.range)));
                slots.push((out_std + in_extra + added, FloatType::F32));
                added += 4;
            }
        }
    }
    if !data.is_empty() {
        let found = vlrs
            .iter_mut()
            .chain(evlrs.iter_mut())
            .find(|v| is_extra_bytes_vlr(v));
        match found {
            Some(v) => v.data.extend(data),
            None => vlrs.push(extra_bytes_vlr(data)),
        }
    }
    Ok((slots, in_extra + added))
}

/// The output header: the input's, in the input's LAS version when that can hold the output,
/// else in LAS 1.4.
fn output_header(
    input: &LasInput,
    mut builder: Builder,
    format: Format,
    out: &Path,
) -> Result<Header> {
    let v = builder.version;
    // Legacy records hold return numbers up to 7, but before LAS 1.4 the header counts
    // points by return for 1–5 only.
    let high_returns = !input.format.is_extended
        && input
            .records
            .par_chunks_exact(input.record_len.max(1))
            .any(|r| r.len() > 14 && r[14] & 7 > 5);
    let large = v.supports::<::las::feature::LargeFiles>();
    let fits = v.supports_point_format(format)
        && (builder.evlrs.is_empty() || v.supports::<::las::feature::Evlrs>())
        && (input.len() as u64 <= u32::MAX as u64 || large)
        && (!high_returns || large);
    let header = if fits {
        builder.clone().into_header().ok()
    } else {
        None
    };
    match header {
        Some(h) => Ok(h),
        None => {
            if v == Version::new(1, 0) && builder.vlr_padding.ends_with(&[0xCC, 0xDD]) {
                // The point-data start signature belongs to LAS 1.0 only.
                let n = builder.vlr_padding.len();
                builder.vlr_padding.truncate(n - 2);
            }
            builder.version = Version::new(1, 4);
            builder
                .into_header()
                .map_err(|e| write_error(out, format!("cannot build the LAS header: {e}")))
        }
    }
}

/// Where the RGB of a point format starts.
pub(super) fn rgb_offset(id: u8) -> Option<usize> {
    match id {
        2 => Some(20),
        3 | 5 => Some(28),
        7 | 8 | 10 => Some(30),
        _ => None,
    }
}

pub(super) fn software() -> String {
    format!("mvao {}", env!("CARGO_PKG_VERSION"))
}

/// `s` as the las crate can write it: ASCII, at most `max` bytes.
pub(super) fn las_ascii(s: &str, max: usize) -> String {
    s.chars()
        .map(|c| if c.is_ascii() { c } else { '?' })
        .take(max)
        .collect()
}

/// One extra-bytes descriptor; `min_max` is stored as doubles, as for float types.
pub(super) fn descriptor(
    name: &str,
    data_type: u8,
    options: u8,
    description: &str,
    min_max: Option<(f64, f64)>,
) -> [u8; DESCRIPTOR_LEN] {
    let mut d = [0u8; DESCRIPTOR_LEN];
    d[2] = data_type;
    d[3] = options;
    let n = truncate_utf8(name, 32);
    d[4..4 + n.len()].copy_from_slice(n.as_bytes());
    if let Some((lo, hi)) = min_max {
        d[3] |= 0b110;
        d[64..72].copy_from_slice(&lo.to_le_bytes());
        d[88..96].copy_from_slice(&hi.to_le_bytes());
    }
    let s = truncate_utf8(description, 32);
    d[160..160 + s.len()].copy_from_slice(s.as_bytes());
    d
}

pub(super) fn extra_bytes_vlr(data: Vec<u8>) -> Vlr {
    Vlr {
        user_id: LASF_SPEC.into(),
        record_id: EXTRA_BYTES_RECORD,
        description: "extra bytes".into(),
        data,
    }
}

/// The longest prefix of `s` of at most `max` bytes ending on a character boundary.
pub(super) fn truncate_utf8(s: &str, max: usize) -> &str {
    let mut end = s.len().min(max);
    while !s.is_char_boundary(end) {
        end -= 1;
    }
    &s[..end]
}

pub(super) fn check_ao(ao: &[f32], n: usize, out: &Path) -> Result<()> {
    if ao.len() != n {
        return Err(Error::Param(format!(
            "{}: {} ao values for {n} points (internal error)",
            out.display(),
            ao.len()
        )));
    }
    if ao.iter().any(|a| !a.is_finite()) {
        return Err(Error::Param(format!(
            "{}: refusing to write a non-finite ao value (internal error)",
            out.display()
        )));
    }
    Ok(())
}

#[cfg(feature = "laz")]
pub(super) fn check_compress(_compress: bool, _out: &Path) -> Result<()> {
    Ok(())
}

#[cfg(not(feature = "laz"))]
pub(super) fn check_compress(compress: bool, out: &Path) -> Result<()> {
    if compress {
        Err(Error::Param(format!("{}: {NO_LAZ}", out.display())))
    } else {
        Ok(())
    }
}

pub(super) fn write_error(out: &Path, msg: String) -> Error {
    Error::io(out, std::io::Error::other(msg))
}

/// The header fields the las crate does not write: waveform bits and packet position.
pub(super) struct WaveformPatch {
    /// Global-encoding waveform bits to set.
    pub(super) bits: u16,
    /// Index among the output EVLRs of the internal waveform packets.
    pub(super) evlr: Option<usize>,
}

/// A file writer that, once poisoned, swallows everything: the las writer closes itself when
/// dropped and panics if that fails, so after an error the drop must succeed silently.
pub(super) struct Sink {
    inner: BufWriter<File>,
    dead: Arc<AtomicBool>,
}

impl Sink {
    fn check<T>(&self, r: std::io::Result<T>) -> std::io::Result<T> {
        if r.is_err() {
            self.dead.store(true, Ordering::Relaxed);
        }
        r
    }
}

impl Write for Sink {
    fn write(&mut self, buf: &[u8]) -> std::io::Result<usize> {
        if self.dead.load(Ordering::Relaxed) {
            return Ok(buf.len());
        }
        let r = self.inner.write(buf);
        self.check(r)
    }

    fn flush(&mut self) -> std::io::Result<()> {
        if self.dead.load(Ordering::Relaxed) {
            return Ok(());
        }
        let r = self.inner.flush();
        self.check(r)
    }
}

impl Seek for Sink {
    fn seek(&mut self, pos: SeekFrom) -> std::io::Result<u64> {
        if self.dead.load(Ordering::Relaxed) {
            return Ok(0);
        }
        let r = self.inner.seek(pos);
        self.check(r)
    }
}

/// Writes `n` records produced by `fill(batch, first_index)` under `header` to `out`
/// atomically, then completes the header fields the las crate leaves out.
pub(super) fn write_points<F>(
    out: &Path,
    header: Header,
    n: usize,
    fill: F,
    waveform: WaveformPatch,
) -> Result<()>
where
    F: Fn(&mut [u8], usize),
{
    let werr = |e: ::las::Error| match e {
        ::las::Error::Io(io) => Error::io(out, io),
        other => write_error(out, format!("cannot write LAS: {other}")),
    };
    let evlr_lens: Vec<u64> = header
        .evlrs()
        .iter()
        .map(|v| EVLR_HEADER_LEN + v.data.len() as u64)
        .collect();
    let version = header.version();
    let extended = header.point_format().is_extended;
    write_atomic_file(out, |file| {
        let dead = Arc::new(AtomicBool::new(false));
        let sink = Sink {
            inner: BufWriter::with_capacity(1 << 20, file),
            dead: dead.clone(),
        };
        let mut batch = PointDataBuilder::new()
            .with_format(*header.point_format())
            .with_transforms(*header.transforms())
            .build();
        let mut writer = Writer::new(sink, header).map_err(werr)?;
        // A panic in the encoder becomes an error; the poisoned sink then lets the writer's
        // closing on drop succeed.
        let written = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| {
            let mut first = 0;
            while first < n {
                let m = BATCH.min(n - first);
                fill(batch.resize_for(m), first);
                writer.write_points(&batch)?;
                first += m;
            }
            writer.close()
        }));
        let written = written.unwrap_or_else(|_| {
            Err(::las::Error::Io(std::io::Error::other(
                "the LAS/LAZ encoder failed on these points",
            )))
        });
        if let Err(e) = written {
            dead.store(true, Ordering::Relaxed);
            // The writer closes itself on drop and panics if that fails again (as it does
            // for a header it cannot write): it is left undropped instead.
            std::mem::forget(writer);
            return Err(werr(e));
        }
        let sink = writer.into_inner().map_err(werr)?;
        let mut file = sink
            .inner
            .into_inner()
            .map_err(|e| Error::io(out, e.into_error()))?;
        patch_header(&mut file, version, extended, &waveform, &evlr_lens)
            .map_err(|e| Error::io(out, e))?;
        Ok(file)
    })
}

/// Sets what the las crate does not: the waveform bits and packet offset, and zero legacy
/// point counts for formats 6–10 (LAS 1.4 asks for them).
pub(super) fn patch_header(
    file: &mut File,
    version: Version,
    extended: bool,
    waveform: &WaveformPatch,
    evlr_lens: &[u64],
) -> std::io::Result<()> {
    let mut b2 = [0u8; 2];
    file.seek(SeekFrom::Start(6))?;
    file.read_exact(&mut b2)?;
    let ge = (u16::from_le_bytes(b2) & !WAVEFORM_BITS) | waveform.bits;
    file.seek(SeekFrom::Start(6))?;
    file.write_all(&ge.to_le_bytes())?;
    if version >= Version::new(1, 4) {
        if let Some(i) = waveform.evlr.filter(|_| waveform.bits & 2 != 0) {
            let mut b8 = [0u8; 8];
            file.seek(SeekFrom::Start(235))?;
            file.read_exact(&mut b8)?;
            let start = u64::from_le_bytes(b8) + evlr_lens[..i].iter().sum::<u64>();
            file.seek(SeekFrom::Start(227))?;
            file.write_all(&start.to_le_bytes())?;
        }
        if extended {
            file.seek(SeekFrom::Start(107))?;
            file.write_all(&[0u8; 24])?;
        }
    }
    Ok(())
}
