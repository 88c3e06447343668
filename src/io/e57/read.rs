//! Reading E57: every scan of the file with its pose, grid indices and every attribute,
//! one scan at a time in parallel.

use super::*;

/// Decoded values of one prototype record. Integers keep their stored value (a scaled
/// integer its unscaled one) in the smallest type that holds the declared range.
#[derive(Debug, Clone)]
pub(super) enum Column {
    F32(Vec<f32>),
    F64(Vec<f64>),
    U8(Vec<u8>),
    U16(Vec<u16>),
    I32(Vec<i32>),
    I64(Vec<i64>),
}

impl Column {
    pub(super) fn for_type(dt: &RecordDataType, cap: usize) -> Column {
        match *dt {
            RecordDataType::Single { .. } => Column::F32(Vec::with_capacity(cap)),
            RecordDataType::Double { .. } => Column::F64(Vec::with_capacity(cap)),
            RecordDataType::Integer { min, max }
            | RecordDataType::ScaledInteger { min, max, .. } => {
                if min >= 0 && max <= u8::MAX as i64 {
                    Column::U8(Vec::with_capacity(cap))
                } else if min >= 0 && max <= u16::MAX as i64 {
                    Column::U16(Vec::with_capacity(cap))
                } else if min >= i32::MIN as i64 && max <= i32::MAX as i64 {
                    Column::I32(Vec::with_capacity(cap))
                } else {
                    Column::I64(Vec::with_capacity(cap))
                }
            }
        }
    }

    /// Appends a decoded value; `Err` when it does not fit the declared type or range (the
    /// crate's decoder can return values past `max` from corrupt bit streams).
    pub(super) fn push(
        &mut self,
        v: &RecordValue,
        dt: &RecordDataType,
    ) -> std::result::Result<(), String> {
        let int = match (v, dt) {
            (RecordValue::Integer(i), RecordDataType::Integer { min, max })
            | (RecordValue::ScaledInteger(i), RecordDataType::ScaledInteger { min, max, .. }) => {
                if i < min || i > max {
                    return Err(format!("value {i} outside its declared range {min}..{max}"));
                }
                Some(*i)
            }
            _ => None,
        };
        match (self, v, int) {
            (Column::F32(c), RecordValue::Single(x), _) => c.push(*x),
            (Column::F64(c), RecordValue::Double(x), _) => c.push(*x),
            (Column::U8(c), _, Some(i)) => c.push(i as u8),
            (Column::U16(c), _, Some(i)) => c.push(i as u16),
            (Column::I32(c), _, Some(i)) => c.push(i as i32),
            (Column::I64(c), _, Some(i)) => c.push(i),
            _ => return Err("value of another type than declared".into()),
        }
        Ok(())
    }

    pub(super) fn len(&self) -> usize {
        match self {
            Column::F32(c) => c.len(),
            Column::F64(c) => c.len(),
            Column::U8(c) => c.len(),
            Column::U16(c) => c.len(),
            Column::I32(c) => c.len(),
            Column::I64(c) => c.len(),
        }
    }

    /// The stored value without scaling.
    #[inline]
    pub(super) fn raw(&self, k: usize) -> f64 {
        match self {
            Column::F32(c) => c[k] as f64,
            Column::F64(c) => c[k],
            Column::U8(c) => c[k] as f64,
            Column::U16(c) => c[k] as f64,
            Column::I32(c) => c[k] as f64,
            Column::I64(c) => c[k] as f64,
        }
    }

    #[inline]
    pub(super) fn int(&self, k: usize) -> i64 {
        match self {
            Column::F32(c) => c[k] as i64,
            Column::F64(c) => c[k] as i64,
            Column::U8(c) => c[k] as i64,
            Column::U16(c) => c[k] as i64,
            Column::I32(c) => c[k] as i64,
            Column::I64(c) => c[k],
        }
    }

    /// The value in its unit (a scaled integer scaled), as the crate's reader gives it.
    #[inline]
    pub(super) fn value(&self, k: usize, dt: &RecordDataType) -> f64 {
        match dt {
            RecordDataType::ScaledInteger { scale, offset, .. } => {
                self.int(k) as f64 * scale + offset
            }
            _ => self.raw(k),
        }
    }

    /// The value as the crate's writer takes it for a record of type `dt` (the column was
    /// made for that type).
    #[inline]
    pub(super) fn record_value(&self, k: usize, dt: &RecordDataType) -> RecordValue {
        match (self, dt) {
            (Column::F32(c), _) => RecordValue::Single(c[k]),
            (Column::F64(c), _) => RecordValue::Double(c[k]),
            (_, RecordDataType::ScaledInteger { .. }) => RecordValue::ScaledInteger(self.int(k)),
            _ => RecordValue::Integer(self.int(k)),
        }
    }

    pub(super) fn min_max_int(&self) -> Option<(i64, i64)> {
        let n = self.len();
        (n > 0).then(|| {
            (0..n)
                .into_par_iter()
                .map(|k| (self.int(k), self.int(k)))
                .reduce(|| (i64::MAX, i64::MIN), |a, b| (a.0.min(b.0), a.1.max(b.1)))
        })
    }
}

/// Bits per value of a record type, as the format packs it.
pub(super) fn bit_size(dt: &RecordDataType) -> u64 {
    match *dt {
        RecordDataType::Single { .. } => 32,
        RecordDataType::Double { .. } => 64,
        RecordDataType::Integer { min, max } | RecordDataType::ScaledInteger { min, max, .. } => {
            let range = max as i128 - min as i128;
            if range > 0 {
                range.ilog2() as u64 + 1
            } else {
                0
            }
        }
    }
}

impl E57Input {
    /// Reads every point cloud of an E57 file (see the module documentation).
    ///
    /// Errors: the file cannot be opened or is not E57, a scan's data is truncated or corrupt
    /// (the message names the scan), a scan has no coordinates, a pose is not a rotation plus
    /// translation, or the file holds several scans of which none has a pose.
    ///
    /// There is no reader over a stream: the scans are decoded in parallel, each from its own
    /// handle on the file.
    pub fn from_path(path: &Path) -> Result<E57Input> {
        let file = File::open(path).map_err(|e| Error::io(path, e))?;
        let file_len = file.metadata().map_err(|e| Error::io(path, e))?.len();
        let reader = E57Reader::new(BufReader::new(file))
            .map_err(|e| Error::format(path, format!("not a readable E57 file: {e}")))?;
        let clouds = reader.pointclouds();
        let guid = reader.guid().to_string();
        let coordinate_metadata = reader.coordinate_metadata().map(str::to_string);
        let extensions = reader.extensions();
        drop(reader);
        if clouds.is_empty() {
            return Err(Error::format(path, "E57 file holds no data3D point cloud"));
        }
        let stem = path
            .file_stem()
            .map(|s| s.to_string_lossy().into_owned())
            .unwrap_or_else(|| "scan".into());
        let names = scan_names(&clouds, &stem);
        // One reader per scan, so several scans decode in parallel.
        let results: Vec<Result<E57Scan>> = clouds
            .par_iter()
            .zip(names)
            .map(|(pc, name)| read_cloud(path, file_len, pc, name))
            .collect();
        let scans = results.into_iter().collect::<Result<Vec<_>>>()?;
        if scans.len() > 1 && !scans.iter().any(|s| s.has_pose) {
            return Err(Error::format(
                path,
                format!(
                    "{} scans and none has a pose; the scans cannot be placed",
                    scans.len()
                ),
            ));
        }
        Ok(E57Input {
            path: path.to_path_buf(),
            guid,
            coordinate_metadata,
            extensions,
            scans,
        })
    }
}

/// Unique, file-name-safe scan names.
pub(super) fn scan_names(clouds: &[PointCloud], stem: &str) -> Vec<String> {
    let mut used = std::collections::HashSet::new();
    clouds
        .iter()
        .enumerate()
        .map(|(k, pc)| {
            let stored = pc.name.as_deref().map(file_safe).unwrap_or_default();
            let base = if !stored.is_empty() {
                stored
            } else if clouds.len() == 1 {
                stem.to_string()
            } else {
                format!("{stem}_{k}")
            };
            let mut name = base.clone();
            let mut j = 1;
            while !used.insert(name.clone()) {
                name = format!("{base}_{j}");
                j += 1;
            }
            name
        })
        .collect()
}

/// `s` trimmed, with characters that are not allowed in file names replaced by `_`.
pub(super) fn file_safe(s: &str) -> String {
    let t: String = s
        .trim()
        .chars()
        .map(|c| {
            if c.is_control() || "/\\:*?\"<>|".contains(c) {
                '_'
            } else {
                c
            }
        })
        .collect();
    if t.chars().all(|c| c == '.') {
        String::new()
    } else {
        t
    }
}

/// The stored pose as a matrix: unit quaternion and translation, checked.
pub(super) fn pose_matrix(t: &Transform) -> std::result::Result<DMat4, String> {
    let q = DQuat::from_xyzw(t.rotation.x, t.rotation.y, t.rotation.z, t.rotation.w);
    let len = q.length();
    if !len.is_finite() || (len - 1.0).abs() > QUATERNION_TOLERANCE {
        return Err(format!(
            "pose rotation quaternion (w {}, x {}, y {}, z {}) has length {len}, not 1",
            t.rotation.w, t.rotation.x, t.rotation.y, t.rotation.z
        ));
    }
    let tr = DVec3::new(t.translation.x, t.translation.y, t.translation.z);
    if !tr.is_finite() {
        return Err("pose translation is not finite".into());
    }
    Ok(DMat4::from_rotation_translation(q / len, tr))
}

/// Index of the prototype record called `name`.
pub(super) fn find(proto: &[Record], name: &RecordName) -> Option<usize> {
    proto.iter().position(|r| &r.name == name)
}

/// Index of the extension record whose attribute name is `name`, in any namespace.
pub(super) fn find_unknown(proto: &[Record], attr: &str) -> Option<usize> {
    proto
        .iter()
        .position(|r| matches!(&r.name, RecordName::Unknown { name, .. } if name == attr))
}

/// The value range a record's values are normalised by: the stored limits, else the
/// declared type range. `None` when neither bounds the values.
pub(super) fn value_range(
    lo: Option<&RecordValue>,
    hi: Option<&RecordValue>,
    dt: &RecordDataType,
) -> Option<(f64, f64)> {
    let lim = |v: &RecordValue| match (v, dt) {
        (RecordValue::ScaledInteger(i), RecordDataType::ScaledInteger { scale, offset, .. }) => {
            *i as f64 * scale + offset
        }
        (RecordValue::ScaledInteger(i), _) | (RecordValue::Integer(i), _) => *i as f64,
        (RecordValue::Single(x), _) => *x as f64,
        (RecordValue::Double(x), _) => *x,
    };
    let ordered = |a: f64, b: f64| (a.is_finite() && b.is_finite() && b > a).then_some((a, b));
    if let (Some(a), Some(b)) = (lo, hi) {
        if let Some(r) = ordered(lim(a), lim(b)) {
            return Some(r);
        }
    }
    match *dt {
        RecordDataType::Single {
            min: Some(a),
            max: Some(b),
        } => ordered(a as f64, b as f64),
        RecordDataType::Double {
            min: Some(a),
            max: Some(b),
        } => ordered(a, b),
        RecordDataType::Integer { min, max } => ordered(min as f64, max as f64),
        RecordDataType::ScaledInteger {
            min,
            max,
            scale,
            offset,
        } => {
            let (a, b) = (min as f64 * scale + offset, max as f64 * scale + offset);
            ordered(a.min(b), a.max(b))
        }
        _ => None,
    }
}

/// Values of column `c` (record type `dt`) mapped to [0, 1] by `range`; without a range,
/// values already in [0, 1] are kept and others scaled by their own minimum and maximum.
pub(super) fn normalised(c: &Column, dt: &RecordDataType, range: Option<(f64, f64)>) -> Vec<f32> {
    let n = c.len();
    let (lo, hi) = range.unwrap_or_else(|| {
        let (a, b) = (0..n)
            .into_par_iter()
            .map(|k| c.value(k, dt))
            .filter(|v| v.is_finite())
            .fold(
                || (f64::INFINITY, f64::NEG_INFINITY),
                |m, v| (m.0.min(v), m.1.max(v)),
            )
            .reduce(
                || (f64::INFINITY, f64::NEG_INFINITY),
                |a, b| (a.0.min(b.0), a.1.max(b.1)),
            );
        if a >= 0.0 && b <= 1.0 || !(b > a) {
            (0.0, 1.0)
        } else {
            (a, b)
        }
    });
    let inv = 1.0 / (hi - lo);
    (0..n)
        .into_par_iter()
        .map(|k| {
            let v = (c.value(k, dt) - lo) * inv;
            if v.is_finite() {
                v.clamp(0.0, 1.0) as f32
            } else {
                0.0
            }
        })
        .collect()
}

/// Decodes one point cloud and derives coordinates, grid, normals, intensity and colour.
pub(super) fn read_cloud(
    path: &Path,
    file_len: u64,
    pc: &PointCloud,
    name: String,
) -> Result<E57Scan> {
    let fail = |msg: String| Error::format(path, format!("scan {name}: {msg}"));
    let proto = &pc.prototype;
    let bits: u64 = proto.iter().map(|r| bit_size(&r.data_type)).sum();
    if bits == 0 {
        // The crate would generate constant records without end.
        return Err(fail(
            "every attribute is constant (0 bits per record); not a point cloud".into(),
        ));
    }
    let (has_pose, pose) = match &pc.transform {
        Some(t) => (true, pose_matrix(t).map_err(&fail)?),
        None => (false, DMat4::IDENTITY),
    };
    let ix = |n: RecordName| find(proto, &n);
    let cart = (
        ix(RecordName::CartesianX),
        ix(RecordName::CartesianY),
        ix(RecordName::CartesianZ),
    );
    let sph = (
        ix(RecordName::SphericalRange),
        ix(RecordName::SphericalAzimuth),
        ix(RecordName::SphericalElevation),
    );
    let cart = match cart {
        (Some(a), Some(b), Some(c)) => Some([a, b, c]),
        _ => None,
    };
    let sph = match sph {
        (Some(a), Some(b), Some(c)) => Some([a, b, c]),
        _ => None,
    };
    if cart.is_none() && sph.is_none() {
        return Err(fail(
            "has neither Cartesian (cartesianX/Y/Z) nor spherical coordinates".into(),
        ));
    }
    // A scaled integer with a zero or non-finite scale holds no value (the standard asks for
    // a non-zero scale).
    for &k in cart.iter().chain(sph.iter()).flatten() {
        if let RecordDataType::ScaledInteger { scale, offset, .. } = proto[k].data_type {
            if !(scale != 0.0 && scale.is_finite() && offset.is_finite()) {
                return Err(fail(format!(
                    "{} is a scaled integer with scale {scale} and offset {offset}",
                    record_label(&proto[k].name)
                )));
            }
        }
    }

    let cols = decode(path, file_len, pc, bits, &fail)?;
    let n = cols.first().map_or(0, Column::len);
    if n as u64 != pc.records {
        return Err(fail(format!(
            "{} records declared, {n} decoded (truncated or corrupt)",
            pc.records
        )));
    }

    let xyz = positions(proto, &cols, cart, sph);
    let invalid = xyz.par_iter().filter(|p| !p[0].is_finite()).count();

    let grid = grid_of(pc, &cols);

    let (normals, intensity, rgb) = attributes(pc, &cols);

    Ok(E57Scan {
        name,
        descriptor: pc.clone(),
        pose,
        has_pose,
        xyz,
        grid,
        normals,
        intensity,
        rgb,
        invalid,
        columns: cols,
    })
}

/// The values of every record of `pc`, one column per prototype attribute. The capacity is
/// bounded by what the file can hold (`bits` per record), not by the stored count.
fn decode(
    path: &Path,
    file_len: u64,
    pc: &PointCloud,
    bits: u64,
    fail: &dyn Fn(String) -> Error,
) -> Result<Vec<Column>> {
    let proto = &pc.prototype;
    let cap = pc.records.min(file_len.saturating_mul(8) / bits + 1) as usize;
    let mut cols: Vec<Column> = proto
        .iter()
        .map(|r| Column::for_type(&r.data_type, cap))
        .collect();
    let file = File::open(path).map_err(|e| Error::io(path, e))?;
    let mut reader = E57Reader::new(BufReader::new(file))
        .map_err(|e| Error::format(path, format!("not a readable E57 file: {e}")))?;
    let iter = reader
        .pointcloud_raw(pc)
        .map_err(|e| fail(format!("cannot start reading points: {e}")))?;
    for (k, values) in iter.enumerate() {
        let values = values.map_err(|e| {
            fail(format!(
                "record {k} of {}: {e} (truncated or corrupt)",
                pc.records
            ))
        })?;
        if values.len() != cols.len() {
            return Err(fail(format!(
                "record {k} has {} values, the prototype {}",
                values.len(),
                cols.len()
            )));
        }
        for ((c, r), v) in cols.iter_mut().zip(proto).zip(&values) {
            c.push(v, &r.data_type)
                .map_err(|m| fail(format!("record {k}: {}: {m}", record_label(&r.name))))?;
        }
    }
    Ok(cols)
}

/// Cartesian coordinates of every record: the Cartesian ones when valid, else the spherical
/// ones converted, else NaN.
fn positions(
    proto: &[Record],
    cols: &[Column],
    cart: Option<[usize; 3]>,
    sph: Option<[usize; 3]>,
) -> Vec<[f64; 3]> {
    let n = cols.first().map_or(0, Column::len);
    let dt = |i: usize| &proto[i].data_type;
    let state = |i: Option<usize>, k: usize| i.map_or(0, |i| cols[i].value(k, dt(i)) as i64);
    let cart_state = find(proto, &RecordName::CartesianInvalidState);
    let sph_state = find(proto, &RecordName::SphericalInvalidState);
    (0..n)
        .into_par_iter()
        .map(|k| {
            if let Some(c) = cart {
                if state(cart_state, k) == 0 {
                    let p = c.map(|i| cols[i].value(k, dt(i)));
                    if p.iter().all(|v| v.is_finite()) {
                        return p;
                    }
                }
            }
            if let Some([r, a, e]) = sph {
                if state(sph_state, k) == 0 {
                    let (r, a, e) = (
                        cols[r].value(k, dt(r)),
                        cols[a].value(k, dt(a)),
                        cols[e].value(k, dt(e)),
                    );
                    let (se, ce) = e.sin_cos();
                    let (sa, ca) = a.sin_cos();
                    let p = [r * ce * ca, r * ce * sa, r * se];
                    if p.iter().all(|v| v.is_finite()) {
                        return p;
                    }
                }
            }
            [f64::NAN; 3]
        })
        .collect()
}

/// The scan grid from the row and column indices, when there are both and they are in range.
fn grid_of(pc: &PointCloud, cols: &[Column]) -> Option<RawGrid> {
    let n = cols.first().map_or(0, Column::len);
    let ix = |n: RecordName| find(&pc.prototype, &n);
    match (ix(RecordName::RowIndex), ix(RecordName::ColumnIndex)) {
        (Some(ri), Some(ci)) if n > 0 => {
            let (r0, r1) = cols[ri].min_max_int().unwrap_or((0, 0));
            let (c0, c1) = cols[ci].min_max_int().unwrap_or((0, 0));
            if r0 < 0 || c0 < 0 || r1 >= MAX_GRID_INDEX || c1 >= MAX_GRID_INDEX {
                None
            } else {
                // The stored bounds may declare a larger grid than the records reach.
                let bound = |b: Option<i64>, data: i64| match b {
                    Some(b) if (0..MAX_GRID_INDEX).contains(&b) => b.max(data),
                    _ => data,
                };
                let ib = pc.index_bounds.as_ref();
                let rows = bound(ib.and_then(|b| b.row_max), r1) + 1;
                let ncols = bound(ib.and_then(|b| b.column_max), c1) + 1;
                Some(RawGrid {
                    rows: rows as u32,
                    cols: ncols as u32,
                    row: (0..n)
                        .into_par_iter()
                        .map(|k| cols[ri].int(k) as u32)
                        .collect(),
                    col: (0..n)
                        .into_par_iter()
                        .map(|k| cols[ci].int(k) as u32)
                        .collect(),
                })
            }
        }
        _ => None,
    }
}

/// Normals, intensity (0–1) and colour of every record, where the scan has them.
#[allow(clippy::type_complexity)]
fn attributes(
    pc: &PointCloud,
    cols: &[Column],
) -> (Option<Vec<Vec3>>, Option<Vec<f32>>, Option<Vec<[u8; 3]>>) {
    let proto = &pc.prototype;
    let n = cols.first().map_or(0, Column::len);
    let ix = |n: RecordName| find(proto, &n);
    let dt = |i: usize| &proto[i].data_type;
    let normals = match (
        find_unknown(proto, "normalX"),
        find_unknown(proto, "normalY"),
        find_unknown(proto, "normalZ"),
    ) {
        (Some(a), Some(b), Some(c)) => Some(
            (0..n)
                .into_par_iter()
                .map(|k| {
                    let v = Vec3::new(
                        cols[a].value(k, dt(a)) as f32,
                        cols[b].value(k, dt(b)) as f32,
                        cols[c].value(k, dt(c)) as f32,
                    );
                    // An unusable normal becomes zero and is re-estimated downstream.
                    v.try_normalize().unwrap_or(Vec3::ZERO)
                })
                .collect(),
        ),
        _ => None,
    };

    let intensity = ix(RecordName::Intensity).map(|i| {
        let lim = pc.intensity_limits.as_ref();
        let range = value_range(
            lim.and_then(|l| l.intensity_min.as_ref()),
            lim.and_then(|l| l.intensity_max.as_ref()),
            dt(i),
        );
        let mut v = normalised(&cols[i], dt(i), range);
        if let Some(f) = ix(RecordName::IsIntensityInvalid) {
            v.par_iter_mut()
                .enumerate()
                .for_each(|(k, x)| *x = if cols[f].int(k) != 0 { 0.0 } else { *x });
        }
        v
    });

    let rgb = match (
        ix(RecordName::ColorRed),
        ix(RecordName::ColorGreen),
        ix(RecordName::ColorBlue),
    ) {
        (Some(r), Some(g), Some(b)) => {
            let lim = pc.color_limits.as_ref();
            let ch = |i: usize, lo: Option<&RecordValue>, hi: Option<&RecordValue>| {
                normalised(&cols[i], dt(i), value_range(lo, hi, dt(i)))
            };
            let rr = ch(
                r,
                lim.and_then(|l| l.red_min.as_ref()),
                lim.and_then(|l| l.red_max.as_ref()),
            );
            let gg = ch(
                g,
                lim.and_then(|l| l.green_min.as_ref()),
                lim.and_then(|l| l.green_max.as_ref()),
            );
            let bb = ch(
                b,
                lim.and_then(|l| l.blue_min.as_ref()),
                lim.and_then(|l| l.blue_max.as_ref()),
            );
            let bad = ix(RecordName::IsColorInvalid);
            let to8 = |v: f32| (v * 255.0).round() as u8;
            Some(
                (0..n)
                    .into_par_iter()
                    .map(|k| {
                        if bad.is_some_and(|f| cols[f].int(k) != 0) {
                            [0; 3]
                        } else {
                            [to8(rr[k]), to8(gg[k]), to8(bb[k])]
                        }
                    })
                    .collect(),
            )
        }
        _ => None,
    };

    (normals, intensity, rgb)
}
