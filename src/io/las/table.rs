//! Writing a point table (inputs of other formats) as LAS or LAZ on a quantisation grid.

use super::write::*;
use super::*;

/// Writes a [`PointTable`] (from another input format) as LAS 1.4, or LAZ with `compress`:
/// world coordinates (the table's pose applied) on a grid chosen by [`grid_exponent`] with an
/// offset near the data, RGB when the table has it (format 7, else 6), intensity scaled to 16
/// bits, the `ao` float dimension and each `extra` field as a double dimension (names cut to
/// 32 bytes, made unique). Records with non-finite coordinates (no return) have no place in
/// LAS and are left out. Atomic. Returns warnings: points the grid merges.
pub fn write_table_las(table: &PointTable, out: &Path, compress: bool) -> Result<Vec<String>> {
    let n = table.len();
    check_ao(&table.ao, n, out)?;
    check_compress(compress, out)?;
    let bad_len = |what: &str, len: usize| {
        Error::Param(format!(
            "{}: {len} {what} values for {n} points (internal error)",
            out.display()
        ))
    };
    if let Some(c) = table.rgb.as_ref().filter(|c| c.len() != n) {
        return Err(bad_len("colour", c.len()));
    }
    if let Some(i) = table.intensity.as_ref().filter(|i| i.len() != n) {
        return Err(bad_len("intensity", i.len()));
    }
    if let Some((name, v)) = table.extra.iter().find(|(_, v)| v.len() != n) {
        return Err(bad_len(name, v.len()));
    }
    let world: Vec<[f64; 3]> = (0..n)
        .into_par_iter()
        .map(|k| table.world(k).to_array())
        .collect();
    let keep: Vec<usize> = (0..n)
        .filter(|&k| world[k].iter().all(|c| c.is_finite()))
        .collect();
    let transforms = grid_of(&world, &keep);
    let grid = [transforms.x, transforms.y, transforms.z];
    let mut warnings = Vec::new();
    let merged = merged_points(&world, &keep, &grid);
    if merged > 0 {
        let step = grid.iter().map(|t| t.scale).fold(0.0, f64::max);
        warnings.push(format!(
            "{}: {merged} of {} points fall on the LAS grid position ({step:e} m steps) of a \
             different point and can no longer be told apart",
            out.display(),
            keep.len()
        ));
    }

    let data = extra_descriptors(table);
    let id = if table.rgb.is_some() { 7 } else { 6 };
    let mut format =
        Format::new(id).map_err(|e| write_error(out, format!("point format {id}: {e}")))?;
    format.extra_bytes = (4 + 8 * table.extra.len()) as u16;
    format.is_compressed = compress;
    let mut builder = Builder::from((1, 4));
    builder.point_format = format;
    builder.transforms = transforms;
    builder.generating_software = software();
    builder.system_identifier = "OTHER".into();
    builder.date = None;
    builder.vlrs.push(extra_bytes_vlr(data));
    let header = builder
        .into_header()
        .map_err(|e| write_error(out, format!("cannot build the LAS header: {e}")))?;
    let out_len = format.len() as usize;
    let std_len = STD_LEN[id as usize];
    let fill = |dst: &mut [u8], first: usize| {
        let m = dst.len() / out_len;
        dst.par_chunks_exact_mut(out_len)
            .zip(&keep[first..first + m])
            .for_each(|(o, &k)| {
                o.fill(0);
                for (a, q) in quantise(world[k], &grid).into_iter().enumerate() {
                    o[4 * a..4 * a + 4].copy_from_slice(&q.to_le_bytes());
                }
                if let Some(i) = &table.intensity {
                    let v = i[k].clamp(0.0, 1.0); // NaN stays NaN and casts to 0
                    o[12..14].copy_from_slice(&((v * 65535.0).round() as u16).to_le_bytes());
                }
                o[14] = 0x11; // return 1 of 1
                if let Some(c) = &table.rgb {
                    for ch in 0..3 {
                        let v = c[k][ch] as u16 * 257;
                        o[30 + 2 * ch..32 + 2 * ch].copy_from_slice(&v.to_le_bytes());
                    }
                }
                o[std_len..std_len + 4].copy_from_slice(&table.ao[k].to_le_bytes());
                for (j, (_, values)) in table.extra.iter().enumerate() {
                    let v = values[k];
                    let v = if v.is_finite() { v } else { f64::MIN };
                    let at = std_len + 4 + 8 * j;
                    o[at..at + 8].copy_from_slice(&v.to_le_bytes());
                }
            });
    };
    let waveform = WaveformPatch {
        bits: 0,
        evlr: None,
    };
    write_points(out, header, keep.len(), fill, waveform)?;
    Ok(warnings)
}

/// The quantisation grid of table output: per axis an offset on a whole metre near the data and
/// the step of [`grid_exponent`], coarser where the extent would overflow 32-bit integers.
fn grid_of(world: &[[f64; 3]], keep: &[usize]) -> Vector<Transform> {
    let mut lo = [f64::INFINITY; 3];
    let mut hi = [f64::NEG_INFINITY; 3];
    for &k in keep {
        for a in 0..3 {
            lo[a] = lo[a].min(world[k][a]);
            hi[a] = hi[a].max(world[k][a]);
        }
    }
    let extent = (0..3).map(|a| hi[a] - lo[a]).fold(0.0, f64::max);
    let exp = grid_exponent(extent);
    let axis = |a: usize| {
        if keep.is_empty() {
            return Transform {
                scale: 1e-4,
                offset: 0.0,
            };
        }
        let offset = ((lo[a] + hi[a]) * 0.5).round();
        let half = (hi[a] - offset).max(offset - lo[a]);
        // Coarser where the extent would overflow the 32-bit integers.
        let mut e = exp;
        while half / pow10(e) > 2.0e9 && e < 300 {
            e += 1;
        }
        Transform {
            scale: pow10(e),
            offset,
        }
    };
    Vector {
        x: axis(0),
        y: axis(1),
        z: axis(2),
    }
}

/// The extra-bytes descriptors of table output: `ao`, then each extra field as f64 with a
/// unique name.
fn extra_descriptors(table: &PointTable) -> Vec<u8> {
    let mut names: Vec<String> = vec![AO_NAME.to_string()];
    let mut data = descriptor(AO_NAME, 9, 0, AO_DESCRIPTION, Some((0.0, 1.0))).to_vec();
    for (k, (name, values)) in table.extra.iter().enumerate() {
        let base = if name.is_empty() {
            format!("extra_{k}")
        } else {
            name.clone()
        };
        let mut unique = truncate_utf8(&base, 32).to_string();
        let mut i = 2;
        while names.contains(&unique) {
            let suffix = format!("_{i}");
            unique = format!("{}{suffix}", truncate_utf8(&base, 32 - suffix.len()));
            i += 1;
        }
        // No NaN reaches the file: non-finite values become the declared no-data value.
        let has_nodata = values.iter().any(|v| !v.is_finite());
        let mut d = descriptor(&unique, 10, 0, "", None);
        if has_nodata {
            d[3] |= 1;
            d[40..48].copy_from_slice(&f64::MIN.to_le_bytes());
        }
        data.extend(d);
        names.push(unique);
    }
    data
}

/// The coarsest grid step of table output, 0.1 mm (10^-4 m): scans of scenes a metre or more
/// across are stored at it.
pub(super) const GRID_EXP_COARSEST: i32 = -4;

/// The finest grid step, 1 nm: an offset on a whole metre leaves every coordinate within
/// ±2 m of it, still inside the 32-bit integers at this step.
pub(super) const GRID_EXP_FINEST: i32 = -9;

/// Grid steps across the data's largest extent below which the step is made finer.
pub(super) const GRID_MIN_STEPS: f64 = 1e4;

/// The power of ten of the LAS grid step for data of `extent` (metres, largest over the
/// axes): the point spacing is unknown, so the step is at most 1/10⁴ of the extent (the
/// relative precision of any scanner), 0.1 mm at the most, 1 nm at the least. A 10 cm object
/// gets 10 µm; a room or a city 0.1 mm.
pub fn grid_exponent(extent: f64) -> i32 {
    let mut e = GRID_EXP_COARSEST;
    while e > GRID_EXP_FINEST && extent < GRID_MIN_STEPS * pow10(e) {
        e -= 1;
    }
    e
}

/// `10^e`, correctly rounded (`1e-4` exactly as the literal).
pub(super) fn pow10(e: i32) -> f64 {
    // 10^k is exact for the exponents used; one division rounds correctly.
    if e < 0 {
        1.0 / 10f64.powi(-e)
    } else {
        10f64.powi(e)
    }
}

/// A world position as the 32-bit integers of `grid` (saturating; the grid is chosen so that
/// every kept point fits).
pub(super) fn quantise(w: [f64; 3], grid: &[Transform; 3]) -> [i32; 3] {
    [0, 1, 2].map(|a| ((w[a] - grid[a].offset) / grid[a].scale).round() as i32)
}

/// How many of the points `keep` of `world` the grid puts on the position of a different
/// point (distinct points of a group sharing a position count all but one).
pub(super) fn merged_points(world: &[[f64; 3]], keep: &[usize], grid: &[Transform; 3]) -> usize {
    // A u32 index keeps the sort at 16 bytes a point; no table of one scan comes near 2^32.
    let Ok(mut q) = keep
        .par_iter()
        .map(|&k| u32::try_from(k).map(|i| (quantise(world[k], grid), i)))
        .collect::<std::result::Result<Vec<_>, _>>()
    else {
        return 0;
    };
    q.par_sort_unstable();
    let mut merged = 0;
    for g in q.chunk_by(|a, b| a.0 == b.0).filter(|g| g.len() > 1) {
        let mut pts: Vec<[u64; 3]> = g
            .iter()
            .map(|&(_, i)| world[i as usize].map(|c| (c + 0.0).to_bits()))
            .collect();
        pts.sort_unstable();
        pts.dedup();
        merged += pts.len() - 1;
    }
    merged
}
