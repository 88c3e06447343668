//! Writing E57 results: the input's scans with `ao` added, new scans, or point tables.

use super::read::*;
use super::*;
use crate::io::output::ExtraFloat;

impl E57Scan {
    /// The Cartesian coordinates and `cartesianInvalidState` written for record `k`: valid
    /// records their coordinates, a direction-only record its stored direction, others zero.
    pub(super) fn output_xyz(&self, k: usize) -> ([f64; 3], u8) {
        let p = self.xyz[k];
        if p.iter().all(|v| v.is_finite()) {
            return (p, 0);
        }
        let proto = &self.descriptor.prototype;
        let col = |n: RecordName| find(proto, &n);
        let val = |i: usize| self.columns[i].value(k, &proto[i].data_type);
        let st = |i: Option<usize>| i.map_or(0, |i| val(i) as i64);
        if let (Some(x), Some(y), Some(z)) = (
            col(RecordName::CartesianX),
            col(RecordName::CartesianY),
            col(RecordName::CartesianZ),
        ) {
            let q = [val(x), val(y), val(z)];
            if st(col(RecordName::CartesianInvalidState)) == 1 && q.iter().all(|v| v.is_finite()) {
                return (q, 1);
            }
            return ([0.0; 3], 2);
        }
        if let (Some(a), Some(e)) = (
            col(RecordName::SphericalAzimuth),
            col(RecordName::SphericalElevation),
        ) {
            if st(col(RecordName::SphericalInvalidState)) == 1 {
                let (se, ce) = val(e).sin_cos();
                let (sa, ca) = val(a).sin_cos();
                let d = [ce * ca, ce * sa, se];
                if d.iter().all(|v| v.is_finite()) {
                    return (d, 1);
                }
            }
        }
        ([0.0; 3], 2)
    }

    /// Everything [`write_e57`] writes for this scan.
    pub(super) fn result_cloud<'a>(
        &'a self,
        ao: &[f32],
        extra: &[ExtraFloat],
        gamma: f32,
        color: ColorMode,
        extensions: &[Extension],
    ) -> CloudOut<'a> {
        let n = self.len();
        let proto = &self.descriptor.prototype;
        let coords: Vec<([f64; 3], u8)> =
            (0..n).into_par_iter().map(|k| self.output_xyz(k)).collect();
        let any_invalid = coords.iter().any(|c| c.1 != 0);
        let mut records: Vec<(Record, Cow<'a, Column>)> = Vec::with_capacity(proto.len() + 6);
        for (axis, rec) in [
            Record::CARTESIAN_X_F64,
            Record::CARTESIAN_Y_F64,
            Record::CARTESIAN_Z_F64,
        ]
        .into_iter()
        .enumerate()
        {
            let c = coords.par_iter().map(|c| c.0[axis]).collect();
            records.push((rec, Cow::Owned(Column::F64(c))));
        }
        if any_invalid || find(proto, &RecordName::CartesianInvalidState).is_some() {
            let c = coords.par_iter().map(|c| c.1).collect();
            records.push((Record::CARTESIAN_INVALID_STATE, Cow::Owned(Column::U8(c))));
        }
        drop(coords);
        let replace_colour = color != ColorMode::Keep || self.rgb.is_none();
        let declared = |ns: &str| extensions.iter().any(|e| e.namespace == ns);
        for (r, c) in proto.iter().zip(&self.columns) {
            let drop_it = match &r.name {
                RecordName::CartesianX
                | RecordName::CartesianY
                | RecordName::CartesianZ
                | RecordName::CartesianInvalidState => true,
                RecordName::ColorRed
                | RecordName::ColorGreen
                | RecordName::ColorBlue
                | RecordName::IsColorInvalid => replace_colour,
                RecordName::Unknown { namespace, name } => {
                    let ours = name == AO_ATTRIBUTE || extra.iter().any(|e| e.name == name);
                    (namespace == MVAO_NAMESPACE && ours) || !declared(namespace)
                }
                _ => false,
            };
            if !drop_it {
                records.push((r.clone(), Cow::Borrowed(c)));
            }
        }
        if replace_colour {
            let valid: Option<Vec<bool>> = self
                .rgb
                .as_ref()
                .map(|_| (0..n).map(|k| self.colour_valid(k)).collect());
            let rgb = result_colours(self.rgb.as_deref(), valid.as_deref(), ao, gamma, color);
            for (ch, rec) in [
                Record::COLOR_RED_U8,
                Record::COLOR_GREEN_U8,
                Record::COLOR_BLUE_U8,
            ]
            .into_iter()
            .enumerate()
            {
                let c = rgb.par_iter().map(|p| p[ch]).collect();
                records.push((rec, Cow::Owned(Column::U8(c))));
            }
        }
        records.push((ao_record(), Cow::Owned(Column::F32(ao.to_vec()))));
        for e in extra {
            let (lo, hi) = e.range;
            let record = Record {
                name: RecordName::Unknown {
                    namespace: MVAO_NAMESPACE.into(),
                    name: e.name.into(),
                },
                data_type: RecordDataType::Single {
                    min: Some(lo as f32),
                    max: Some(hi as f32),
                },
            };
            records.push((record, Cow::Owned(Column::F32(e.values.to_vec()))));
        }

        let d = &self.descriptor;
        let intensity_limits = find(proto, &RecordName::Intensity).and_then(|i| {
            let l = d.intensity_limits.as_ref()?;
            let dt = &proto[i].data_type;
            Some(IntensityLimits {
                intensity_min: l.intensity_min.as_ref().map(|v| unit_limit(v, dt)),
                intensity_max: l.intensity_max.as_ref().map(|v| unit_limit(v, dt)),
            })
        });
        let color_limits = if replace_colour {
            None
        } else {
            d.color_limits.as_ref().and_then(|l| {
                let dt = |n: RecordName| find(proto, &n).map(|i| &proto[i].data_type);
                let (r, g, b) = (
                    dt(RecordName::ColorRed)?,
                    dt(RecordName::ColorGreen)?,
                    dt(RecordName::ColorBlue)?,
                );
                let f = |v: &Option<RecordValue>, dt| v.as_ref().map(|v| unit_limit(v, dt));
                Some(ColorLimits {
                    red_min: f(&l.red_min, r),
                    red_max: f(&l.red_max, r),
                    green_min: f(&l.green_min, g),
                    green_max: f(&l.green_max, g),
                    blue_min: f(&l.blue_min, b),
                    blue_max: f(&l.blue_max, b),
                })
            })
        };
        let mut original_guids = d.original_guids.clone().unwrap_or_default();
        let seed = d.guid.clone().unwrap_or_else(|| self.name.clone());
        if let Some(g) = &d.guid {
            original_guids.push(g.clone());
        }
        CloudOut {
            guid: derived_guid(&format!("mvao result of {seed}")),
            name: d.name.clone(),
            meta: Some(d),
            transform: d.transform.clone(),
            original_guids: (!original_guids.is_empty()).then_some(original_guids),
            intensity_limits,
            color_limits,
            index_bounds: d.index_bounds.clone(),
            records,
            len: n,
        }
    }
}

/// A stored limit in the record's unit, as a double (a scaled-integer limit written back
/// without its scale would change meaning).
pub(super) fn unit_limit(v: &RecordValue, dt: &RecordDataType) -> RecordValue {
    match (v, dt) {
        (RecordValue::ScaledInteger(i), RecordDataType::ScaledInteger { scale, offset, .. }) => {
            RecordValue::Double(*i as f64 * scale + offset)
        }
        (RecordValue::ScaledInteger(i), _) => RecordValue::Double(*i as f64),
        _ => v.clone(),
    }
}

pub(super) fn is_mvao_ao(n: &RecordName) -> bool {
    matches!(n, RecordName::Unknown { namespace, name } if namespace == MVAO_NAMESPACE && name == AO_ATTRIBUTE)
}

/// The `mvao:ao` record: single float in [0, 1].
pub(super) fn ao_record() -> Record {
    Record {
        name: RecordName::Unknown {
            namespace: MVAO_NAMESPACE.into(),
            name: AO_ATTRIBUTE.into(),
        },
        data_type: RecordDataType::UNIT_F32,
    }
}

/// Output colours of a result, as the PLY writer makes them: without input colours (or
/// with [`ColorMode::Replace`]) the grey `ao^(1/γ)`; [`ColorMode::Modulate`] multiplies the
/// input colour by it; [`ColorMode::Keep`] keeps the input colour. Records whose colour is
/// flagged invalid (`valid[k] == false`) get the grey.
pub fn result_colours(
    input: Option<&[[u8; 3]]>,
    valid: Option<&[bool]>,
    ao: &[f32],
    gamma: f32,
    color: ColorMode,
) -> Vec<[u8; 3]> {
    ao.par_iter()
        .enumerate()
        .map(|(k, &a)| {
            let g = grey(a, gamma);
            let own = input
                .and_then(|c| c.get(k))
                .filter(|_| valid.is_none_or(|v| v.get(k).copied().unwrap_or(true)));
            match (own, color) {
                (Some(c), ColorMode::Keep) => *c,
                (Some(c), ColorMode::Modulate) => {
                    c.map(|v| (v as f32 * g as f32 / 255.0).round().clamp(0.0, 255.0) as u8)
                }
                _ => [g; 3],
            }
        })
        .collect()
}

/// Checks that `ao` has one finite value per record of scan `name`.
pub(super) fn check_ao(path: &Path, name: &str, ao: &[f32], n: usize) -> Result<()> {
    if ao.len() != n {
        return Err(Error::Param(format!(
            "{}: scan {name}: {} AO values for {n} records (internal error)",
            path.display(),
            ao.len()
        )));
    }
    if ao.iter().any(|a| !a.is_finite()) {
        return Err(Error::Param(format!(
            "{}: scan {name}: refusing to write a non-finite ao value (internal error)",
            path.display()
        )));
    }
    Ok(())
}

/// A GUID in the usual `{8-4-4-4-12}` form, derived from `seed` so outputs are reproducible.
pub(super) fn derived_guid(seed: &str) -> String {
    let h = xxhash_rust::xxh3::xxh3_128(seed.as_bytes());
    let x = format!("{h:032X}");
    format!(
        "{{{}-{}-{}-{}-{}}}",
        &x[0..8],
        &x[8..12],
        &x[12..16],
        &x[16..20],
        &x[20..32]
    )
}

/// An E57 name (namespace or attribute) the format accepts.
pub(super) fn valid_xml_name(s: &str) -> bool {
    !s.is_empty()
        && !s.to_ascii_lowercase().starts_with("xml")
        && s.chars()
            .all(|c| c.is_ascii_alphanumeric() || c == '_' || c == '-')
}

/// `name` as an attribute name the format accepts, not yet in `used` (which it joins).
pub(super) fn attribute_name(name: &str, used: &mut Vec<String>) -> String {
    let mut s: String = name
        .chars()
        .map(|c| {
            if c.is_ascii_alphanumeric() || c == '_' || c == '-' {
                c
            } else {
                '_'
            }
        })
        .collect();
    if !valid_xml_name(&s) || s.starts_with(|c: char| c.is_ascii_digit() || c == '-') {
        s = format!("x_{s}");
    }
    let base = s.clone();
    let mut j = 1;
    while used.contains(&s) {
        s = format!("{base}_{j}");
        j += 1;
    }
    used.push(s.clone());
    s
}

/// A rigid pose as an E57 transform (unit quaternion with w ≥ 0, translation).
pub(super) fn transform_of(pose: DMat4) -> Transform {
    let q = DQuat::from_mat3(&DMat3::from_mat4(pose)).normalize();
    let q = if q.w < 0.0 { -q } else { q };
    let t = pose.w_axis;
    Transform {
        rotation: Quaternion {
            w: q.w,
            x: q.x,
            y: q.y,
            z: q.z,
        },
        translation: Translation {
            x: t.x,
            y: t.y,
            z: t.z,
        },
    }
}

/// One point cloud to write.
pub(super) struct CloudOut<'a> {
    guid: String,
    name: Option<String>,
    /// Descriptor whose description and sensor metadata are copied.
    meta: Option<&'a PointCloud>,
    transform: Option<Transform>,
    original_guids: Option<Vec<String>>,
    intensity_limits: Option<IntensityLimits>,
    color_limits: Option<ColorLimits>,
    /// Stored index bounds, widened to the data.
    index_bounds: Option<IndexBounds>,
    records: Vec<(Record, Cow<'a, Column>)>,
    len: usize,
}

/// Writes `clouds` as one E57 file, atomically.
pub(super) fn write_clouds(
    out: &Path,
    file_guid: &str,
    coordinate_metadata: Option<String>,
    extensions: &[Extension],
    clouds: &[CloudOut],
) -> Result<()> {
    let other = |name: &str, e: ::e57::Error| std::io::Error::other(format!("scan {name}: {e}"));
    write_atomic_seekable(out, |file| {
        let mut w = E57Writer::new(file, file_guid).map_err(std::io::Error::other)?;
        for e in extensions {
            w.register_extension(e.clone())
                .map_err(std::io::Error::other)?;
        }
        w.set_coordinate_metadata(coordinate_metadata);
        for c in clouds {
            let label = c.name.clone().unwrap_or_else(|| c.guid.clone());
            let proto: Vec<Record> = c.records.iter().map(|(r, _)| r.clone()).collect();
            let mut pw = w
                .add_pointcloud(&c.guid, proto)
                .map_err(|e| other(&label, e))?;
            pw.set_name(c.name.clone());
            pw.set_transform(c.transform.clone());
            pw.set_original_guids(c.original_guids.clone());
            if let Some(m) = c.meta {
                pw.set_description(m.description.clone());
                pw.set_sensor_vendor(m.sensor_vendor.clone());
                pw.set_sensor_model(m.sensor_model.clone());
                pw.set_sensor_serial(m.sensor_serial.clone());
                pw.set_sensor_hw_version(m.sensor_hw_version.clone());
                pw.set_sensor_sw_version(m.sensor_sw_version.clone());
                pw.set_sensor_fw_version(m.sensor_fw_version.clone());
                pw.set_temperature(m.temperature);
                pw.set_humidity(m.humidity);
                pw.set_atmospheric_pressure(m.atmospheric_pressure);
                pw.set_acquisition_start(m.acquisition_start.clone());
                pw.set_acquisition_end(m.acquisition_end.clone());
            }
            if c.intensity_limits.is_some() {
                pw.set_intensity_limits(c.intensity_limits.clone());
            }
            if c.color_limits.is_some() {
                pw.set_color_limits(c.color_limits.clone());
            }
            for k in 0..c.len {
                // The crate takes one vector per record.
                let values = c
                    .records
                    .iter()
                    .map(|(r, col)| col.record_value(k, &r.data_type))
                    .collect();
                pw.add_point(values).map_err(|e| other(&label, e))?;
            }
            if let Some(b) = &c.index_bounds {
                // After the last point, as the crate requires; never narrower than the data.
                let data = |n: RecordName| {
                    c.records
                        .iter()
                        .find(|(r, _)| r.name == n)
                        .and_then(|(_, col)| col.min_max_int())
                };
                let widen = |lo: Option<i64>, hi: Option<i64>, d: Option<(i64, i64)>| match d {
                    Some((a, b)) => (
                        Some(lo.map_or(a, |l| l.min(a))),
                        Some(hi.map_or(b, |h| h.max(b))),
                    ),
                    None => (lo, hi),
                };
                let (row_min, row_max) = widen(b.row_min, b.row_max, data(RecordName::RowIndex));
                let (column_min, column_max) =
                    widen(b.column_min, b.column_max, data(RecordName::ColumnIndex));
                let (return_min, return_max) =
                    widen(b.return_min, b.return_max, data(RecordName::ReturnIndex));
                pw.set_index_bounds(Some(IndexBounds {
                    row_min,
                    row_max,
                    column_min,
                    column_max,
                    return_min,
                    return_max,
                }));
            }
            pw.finalize().map_err(|e| other(&label, e))?;
        }
        w.finalize().map_err(std::io::Error::other)?;
        Ok(())
    })
}

/// The extensions a result file declares: the input's valid ones and `mvao`.
pub(super) fn output_extensions(input: &[Extension]) -> Vec<Extension> {
    let mut ext: Vec<Extension> = Vec::with_capacity(input.len() + 1);
    for e in input {
        if e.namespace != MVAO_NAMESPACE
            && valid_xml_name(&e.namespace)
            && !ext.iter().any(|x| x.namespace == e.namespace)
        {
            ext.push(e.clone());
        }
    }
    ext.push(Extension::new(MVAO_NAMESPACE, MVAO_NAMESPACE_URI));
    ext
}

/// Writes the result of `input`: every scan with its AO (`ao[k]` has one value per record of
/// scan `k`, finite) and the float columns `extra[k]` (none when `extra` is empty) as `mvao:`
/// attributes of their names, grey colours `ao^(1/gamma)` treated by `color`, to `out`,
/// atomically. See the module documentation for what is kept.
pub fn write_e57(
    input: &E57Input,
    ao: &[Vec<f32>],
    extra: &[Vec<ExtraFloat>],
    gamma: f32,
    color: ColorMode,
    out: &Path,
) -> Result<()> {
    if ao.len() != input.scans.len() {
        return Err(Error::Param(format!(
            "{}: {} AO arrays for {} scans (internal error)",
            out.display(),
            ao.len(),
            input.scans.len()
        )));
    }
    if !extra.is_empty() && extra.len() != ao.len() {
        return Err(Error::Param(format!(
            "{}: further columns for {} of {} scans (internal error)",
            out.display(),
            extra.len(),
            ao.len()
        )));
    }
    let none = Vec::new();
    let extra_of = |k: usize| extra.get(k).unwrap_or(&none);
    for (k, (s, a)) in input.scans.iter().zip(ao).enumerate() {
        check_ao(out, &s.name, a, s.len())?;
        for e in extra_of(k) {
            check_ao(out, &s.name, e.values, s.len())?;
        }
    }
    let extensions = output_extensions(&input.extensions);
    let clouds: Vec<CloudOut> = input
        .scans
        .iter()
        .zip(ao)
        .enumerate()
        .map(|(k, (s, a))| s.result_cloud(a, extra_of(k), gamma, color, &extensions))
        .collect();
    write_clouds(
        out,
        &derived_guid(&format!("mvao result of {}", input.guid)),
        input.coordinate_metadata.clone(),
        &extensions,
        &clouds,
    )
}

/// Columns of a generated scan: coordinates, intensity, colour, grid.
pub(super) fn simple_records(
    out: &Path,
    name: &str,
    xyz: &[[f64; 3]],
    spherical: bool,
    intensity: Option<&[f32]>,
    rgb: Option<&[[u8; 3]]>,
    grid: Option<&RawGrid>,
) -> Result<Vec<(Record, Cow<'static, Column>)>> {
    let n = xyz.len();
    let bad = |what: &str, len: usize| {
        Error::Param(format!(
            "{}: scan {name}: {len} {what} for {n} points",
            out.display()
        ))
    };
    let mut rec: Vec<(Record, Cow<'static, Column>)> = Vec::with_capacity(9);
    let valid = |p: &[f64; 3]| p.iter().all(|v| v.is_finite());
    let any_invalid = xyz.par_iter().any(|p| !valid(p));
    if spherical {
        let rae: Vec<[f64; 3]> = xyz
            .par_iter()
            .map(|p| {
                let r = (p[0] * p[0] + p[1] * p[1] + p[2] * p[2]).sqrt();
                if valid(p) && r > 0.0 {
                    [r, p[1].atan2(p[0]), (p[2] / r).clamp(-1.0, 1.0).asin()]
                } else {
                    [0.0; 3]
                }
            })
            .collect();
        for (i, r) in [
            Record::SPHERICAL_RANGE_F64,
            Record::SPHERICAL_AZIMUTH_F64,
            Record::SPHERICAL_ELEVATION_F64,
        ]
        .into_iter()
        .enumerate()
        {
            let c = rae.iter().map(|v| v[i]).collect();
            rec.push((r, Cow::Owned(Column::F64(c))));
        }
        let zero = |p: &[f64; 3]| p.iter().all(|v| *v == 0.0);
        if any_invalid || xyz.iter().any(zero) {
            let c = xyz
                .iter()
                .map(|p| if valid(p) && !zero(p) { 0 } else { 2 })
                .collect();
            rec.push((Record::SPHERICAL_INVALID_STATE, Cow::Owned(Column::U8(c))));
        }
    } else {
        for (i, r) in [
            Record::CARTESIAN_X_F64,
            Record::CARTESIAN_Y_F64,
            Record::CARTESIAN_Z_F64,
        ]
        .into_iter()
        .enumerate()
        {
            let c = xyz
                .par_iter()
                .map(|p| if valid(p) { p[i] } else { 0.0 })
                .collect();
            rec.push((r, Cow::Owned(Column::F64(c))));
        }
        if any_invalid {
            let c = xyz.iter().map(|p| if valid(p) { 0 } else { 2 }).collect();
            rec.push((Record::CARTESIAN_INVALID_STATE, Cow::Owned(Column::U8(c))));
        }
    }
    if let Some(i) = intensity {
        if i.len() != n {
            return Err(bad("intensities", i.len()));
        }
        let c = i
            .iter()
            .map(|v| {
                if v.is_finite() {
                    v.clamp(0.0, 1.0)
                } else {
                    0.0
                }
            })
            .collect();
        rec.push((Record::INTENSITY_UNIT_F32, Cow::Owned(Column::F32(c))));
    }
    if let Some(rgb) = rgb {
        if rgb.len() != n {
            return Err(bad("colours", rgb.len()));
        }
        for (ch, r) in [
            Record::COLOR_RED_U8,
            Record::COLOR_GREEN_U8,
            Record::COLOR_BLUE_U8,
        ]
        .into_iter()
        .enumerate()
        {
            let c = rgb.iter().map(|p| p[ch]).collect();
            rec.push((r, Cow::Owned(Column::U8(c))));
        }
    }
    if let Some(g) = grid {
        if g.row.len() != n || g.col.len() != n {
            return Err(bad("grid cells", g.row.len().min(g.col.len())));
        }
        if g.row.iter().any(|&r| r >= g.rows) || g.col.iter().any(|&c| c >= g.cols) {
            return Err(Error::Param(format!(
                "{}: scan {name}: a grid cell lies outside the {} × {} grid",
                out.display(),
                g.rows,
                g.cols
            )));
        }
        for (name, idx, len) in [
            (RecordName::RowIndex, &g.row, g.rows),
            (RecordName::ColumnIndex, &g.col, g.cols),
        ] {
            let max = len.saturating_sub(1) as i64;
            let dt = RecordDataType::Integer { min: 0, max };
            let col = if max <= u16::MAX as i64 {
                Column::U16(idx.iter().map(|&v| v as u16).collect())
            } else {
                Column::I64(idx.iter().map(|&v| v as i64).collect())
            };
            rec.push((
                Record {
                    name,
                    data_type: dt,
                },
                Cow::Owned(col),
            ));
        }
    }
    Ok(rec)
}

/// Writes `scans` as one E57 file (synthetic stations with known poses and grids; the
/// virtual scanner), atomically. Scans get GUIDs derived from their name and position.
pub fn write_e57_scans(scans: &[E57ScanOut], out: &Path) -> Result<()> {
    let mut clouds = Vec::with_capacity(scans.len());
    for (k, s) in scans.iter().enumerate() {
        let transform = match s.pose {
            Some(p) => Some(transform_of(check_rigid(p, out, &s.name)?)),
            None => None,
        };
        let records = simple_records(
            out,
            &s.name,
            &s.xyz,
            s.spherical,
            s.intensity.as_deref(),
            s.rgb.as_deref(),
            s.grid.as_ref(),
        )?;
        clouds.push(CloudOut {
            guid: derived_guid(&format!("mvao scan {k} {}", s.name)),
            name: Some(s.name.clone()),
            meta: None,
            transform,
            original_guids: None,
            intensity_limits: None,
            color_limits: None,
            index_bounds: None,
            records,
            len: s.xyz.len(),
        });
    }
    let seed: String = scans
        .iter()
        .map(|s| s.name.as_str())
        .collect::<Vec<_>>()
        .join("/");
    write_clouds(
        out,
        &derived_guid(&format!("mvao scans {seed}")),
        None,
        &[Extension::new(MVAO_NAMESPACE, MVAO_NAMESPACE_URI)],
        &clouds,
    )
}

/// Writes `tables` (results of other formats) as one E57 file, one scan per table with its
/// pose (must be rigid), Cartesian f64 coordinates (non-finite ones flagged invalid),
/// intensity, colours (the table's, else the AO grey), grid, `mvao:ao`, and every extra field
/// as an `mvao:` double attribute (name reduced to letters, digits, `_` and `-`; non-finite
/// values written as 0). Atomic.
pub fn write_table_e57(tables: &[PointTable], out: &Path) -> Result<()> {
    let mut clouds = Vec::with_capacity(tables.len());
    for (k, t) in tables.iter().enumerate() {
        check_ao(out, &t.name, &t.ao, t.len())?;
        let pose = check_rigid(t.pose, out, &t.name)?;
        let grey_rgb;
        let rgb = match &t.rgb {
            Some(c) => c.as_slice(),
            None => {
                grey_rgb = result_colours(None, None, &t.ao, 1.0, ColorMode::Replace);
                &grey_rgb
            }
        };
        let mut records = simple_records(
            out,
            &t.name,
            &t.xyz,
            false,
            t.intensity.as_deref(),
            Some(rgb),
            t.grid.as_ref(),
        )?;
        records.push((ao_record(), Cow::Owned(Column::F32(t.ao.clone()))));
        let mut used = vec![AO_ATTRIBUTE.to_string()];
        for (name, v) in &t.extra {
            if v.len() != t.len() {
                return Err(Error::Param(format!(
                    "{}: scan {}: field {name} has {} values for {} points",
                    out.display(),
                    t.name,
                    v.len(),
                    t.len()
                )));
            }
            let c = v
                .iter()
                .map(|x| if x.is_finite() { *x } else { 0.0 })
                .collect();
            records.push((
                Record {
                    name: RecordName::Unknown {
                        namespace: MVAO_NAMESPACE.into(),
                        name: attribute_name(name, &mut used),
                    },
                    data_type: RecordDataType::F64,
                },
                Cow::Owned(Column::F64(c)),
            ));
        }
        clouds.push(CloudOut {
            guid: derived_guid(&format!("mvao table {k} {}", t.name)),
            name: Some(t.name.clone()),
            meta: None,
            transform: Some(transform_of(pose)),
            original_guids: None,
            intensity_limits: None,
            color_limits: None,
            index_bounds: None,
            records,
            len: t.len(),
        });
    }
    let seed: String = tables
        .iter()
        .map(|s| s.name.as_str())
        .collect::<Vec<_>>()
        .join("/");
    write_clouds(
        out,
        &derived_guid(&format!("mvao tables {seed}")),
        None,
        &[Extension::new(MVAO_NAMESPACE, MVAO_NAMESPACE_URI)],
        &clouds,
    )
}
