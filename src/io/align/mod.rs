//! Alignment files: the rigid pose (local → world, f64) of every scan. This module owns reading
//! the three supported formats — Stanford scanalyze `.conf`, MeshLab project `.mlp` and a plain
//! JSON object — finding an alignment file next to the scans, matching its entries to the scans
//! given on the command line, checking that every pose is rigid, and writing `.mlp` projects.

use crate::error::{Error, Result};
use glam::{DMat3, DMat4, DQuat, DVec3, DVec4};
use std::collections::HashMap;
use std::io::Write;
use std::path::{Component, Path, PathBuf};

/// Extensions (lowercase, without the dot) recognised as alignment files.
pub const ALIGN_EXTENSIONS: [&str; 4] = ["conf", "mlp", "aln", "json"];

/// Largest accepted `max |RᵀR − I|` of a pose's rotation block before it counts as scaled or
/// sheared; below it the rotation is re-orthonormalised.
pub const RIGID_TOLERANCE: f64 = 1e-3;

/// Largest accepted deviation of a pose's bottom row from `(0, 0, 0, 1)`.
pub const BOTTOM_ROW_TOLERANCE: f64 = 1e-9;

/// The content of one alignment file.
#[derive(Debug, Clone, PartialEq)]
pub struct Alignment {
    /// The file the poses were read from (used in error messages and to resolve relative names).
    pub path: PathBuf,
    /// The entries in file order.
    pub entries: Vec<AlignEntry>,
}

/// One scan's entry in an alignment file.
#[derive(Debug, Clone, PartialEq)]
pub struct AlignEntry {
    /// The scan file name exactly as written in the alignment file.
    pub file: String,
    /// Rigid transform from the scan's local frame to world coordinates.
    pub pose: DMat4,
}

/// Reads an alignment file, choosing the format by extension (`.conf`, `.mlp`, `.aln` or
/// `.json`, case-insensitive). Every pose is checked with [`check_rigid`]; a file without
/// entries is an error.
pub fn read_alignment(path: &Path) -> Result<Alignment> {
    read_alignment_with(path, false)
}

/// [`read_alignment`], accepting poses with scale or shear when `allow_scale` (checked by
/// [`check_pose`] instead of [`check_rigid`]).
pub fn read_alignment_with(path: &Path, allow_scale: bool) -> Result<Alignment> {
    let ext = path
        .extension()
        .map(|e| e.to_string_lossy().to_ascii_lowercase())
        .unwrap_or_default();
    let parse: fn(&Path, &str) -> Result<Vec<AlignEntry>> = match ext.as_str() {
        "conf" => parse_conf,
        "mlp" => parse_mlp,
        "aln" => parse_aln,
        "json" => parse_json,
        _ => {
            return Err(Error::align(
                path,
                "unknown alignment format (expected a .conf, .mlp, .aln or .json file)",
            ))
        }
    };
    let text = std::fs::read_to_string(path).map_err(|e| Error::io(path, e))?;
    let mut entries = parse(path, &text)?;
    if entries.is_empty() {
        return Err(Error::align(path, "the alignment file names no scans"));
    }
    for e in &mut entries {
        e.pose = check_pose(e.pose, path, &e.file, allow_scale)?;
    }
    Ok(Alignment {
        path: path.to_path_buf(),
        entries,
    })
}

/// Checks a pose: [`check_rigid`] unless `allow_scale`, in which case any finite affine map
/// with a positive determinant is accepted, its bottom row made exactly `(0, 0, 0, 1)` (see
/// [`split_scale`]).
pub fn check_pose(m: DMat4, path: &Path, what: &str, allow_scale: bool) -> Result<DMat4> {
    if !allow_scale {
        return check_rigid(m, path, what);
    }
    if !m.is_finite() {
        return Err(Error::align(
            path,
            format!("pose of '{what}' has a non-finite entry"),
        ));
    }
    if (m.row(3) - DVec4::W).abs().max_element() > BOTTOM_ROW_TOLERANCE {
        return Err(Error::align(
            path,
            format!("pose of '{what}' has a projective bottom row"),
        ));
    }
    let det = DMat3::from_mat4(m).determinant();
    if !(det > 1e-12 && det.is_finite()) {
        return Err(Error::align(
            path,
            format!(
                "pose of '{what}' is singular or a reflection (determinant {det:.6e}); \
                 --allow-scale accepts scale and shear only"
            ),
        ));
    }
    // The bottom row was within tolerance of (0, 0, 0, 1): make it exact, as `check_rigid`
    // does, so that no trace of a projective map is carried into the transforms.
    let mut m = m;
    for col in [&mut m.x_axis, &mut m.y_axis, &mut m.z_axis] {
        col.w = 0.0;
    }
    m.w_axis.w = 1.0;
    // The pose is applied as a rotation plus a stretch of the points (`split_scale`): a
    // stretch so extreme that the split fails would put NaN or a non-rotation in the pose.
    let (rigid, stretch) = split_scale(m);
    let dev = orthogonality_error(DMat3::from_mat4(rigid));
    if !(stretch.is_finite() && dev <= 1e-9) {
        return Err(Error::align(
            path,
            format!(
                "pose of '{what}' cannot be split into a rotation and a stretch (its scales \
                 are too far apart or beyond double precision)"
            ),
        ));
    }
    Ok(m)
}

/// Splits an affine pose `M = [A | t]` (det A > 0) into a rigid pose `[R | t]` and the
/// symmetric stretch `S` with `A = R·S` (polar decomposition). Applying `S` to a scan's
/// local points (and `S⁻ᵀ` to its normals) and `[R | t]` as its pose places it exactly where
/// `M` did, while the scanner stays at the local origin and every distance is in world units.
pub fn split_scale(m: DMat4) -> (DMat4, DMat3) {
    let a = DMat3::from_mat4(m);
    let r = nearest_rotation(a);
    let s = r.transpose() * a;
    let rigid = DMat4::from_cols(
        r.x_axis.extend(0.0),
        r.y_axis.extend(0.0),
        r.z_axis.extend(0.0),
        m.w_axis.truncate().extend(1.0),
    );
    (rigid, s)
}

/// Reads a plain 4×4 matrix file (a per-scan sidecar `scan.txt` / `scan.mat`, or a
/// `--pose` file): 16 numbers, row-major, separated by white space or commas; `#` starts a
/// comment. The pose is checked with [`check_pose`].
pub fn read_matrix_file(path: &Path, what: &str, allow_scale: bool) -> Result<DMat4> {
    let text = std::fs::read_to_string(path).map_err(|e| Error::io(path, e))?;
    let mut nums: Vec<&str> = Vec::with_capacity(16);
    for line in text.lines() {
        let line = line.split('#').next().unwrap_or("");
        nums.extend(
            line.split(|c: char| c.is_whitespace() || c == ',' || c == ';')
                .filter(|t| !t.is_empty()),
        );
    }
    let m = matrix_from_row_major(&nums, |t| parse_number(t))
        .map_err(|msg| Error::align(path, format!("not a 4×4 matrix of 16 numbers: {msg}")))?;
    check_pose(m, path, what, allow_scale)
}

/// The per-scan matrix sidecar of `scan` (`<stem>.txt` or `<stem>.mat` beside it), if any.
pub fn sidecar_of(scan: &Path) -> Option<PathBuf> {
    ["mat", "txt", "MAT", "TXT"]
        .iter()
        .map(|e| scan.with_extension(e))
        .find(|p| p.is_file())
}

/// An error when `scan` has both a `.mat` and a `.txt` sidecar (which one holds its pose?).
pub fn check_one_sidecar(scan: &Path) -> Result<()> {
    let found: Vec<PathBuf> = ["mat", "MAT", "txt", "TXT"]
        .iter()
        .map(|e| scan.with_extension(e))
        .filter(|p| p.is_file())
        .collect();
    // A case-insensitive file system finds one file under both spellings.
    let distinct = found
        .iter()
        .filter_map(|p| std::fs::canonicalize(p).ok())
        .collect::<std::collections::BTreeSet<_>>();
    if distinct.len() > 1 {
        return Err(Error::Param(format!(
            "{}: several sidecar pose files ({}); keep one or give --pose",
            scan.display(),
            found
                .iter()
                .map(|p| p.display().to_string())
                .collect::<Vec<_>>()
                .join(", ")
        )));
    }
    Ok(())
}

/// Looks for alignment files (`.conf`, `.mlp`, `.aln`, `.json`, case-insensitive; hidden files
/// skipped) in the directories holding `scans`. Exactly one candidate → `Some(it)`; none →
/// `None`; several → [`Error::Param`] listing them and asking for `--align`.
pub fn find_alignment_beside(scans: &[PathBuf]) -> Result<Option<PathBuf>> {
    let mut dirs: Vec<PathBuf> = Vec::new();
    for scan in scans {
        let dir = match scan.parent() {
            Some(d) if !d.as_os_str().is_empty() => d.to_path_buf(),
            _ => PathBuf::from("."),
        };
        if !dirs.contains(&dir) {
            dirs.push(dir);
        }
    }
    let mut found: Vec<PathBuf> = Vec::new();
    for dir in &dirs {
        let rd = std::fs::read_dir(dir).map_err(|e| Error::io(dir, e))?;
        let mut here = Vec::new();
        for item in rd {
            let item = item.map_err(|e| Error::io(dir, e))?;
            let name = item.file_name();
            let name = name.to_string_lossy();
            // Hidden files and mvao's own report are never alignments.
            if name.starts_with('.') || name == "report.json" {
                continue;
            }
            let p = item.path();
            let ext = p
                .extension()
                .map(|e| e.to_string_lossy().to_ascii_lowercase())
                .unwrap_or_default();
            if ALIGN_EXTENSIONS.contains(&ext.as_str()) && p.is_file() {
                here.push(p);
            }
        }
        here.sort();
        found.extend(here);
    }
    match found.len() {
        0 => Ok(None),
        1 => Ok(found.pop()),
        _ => {
            let list: Vec<String> = found.iter().map(|p| p.display().to_string()).collect();
            Err(Error::Param(format!(
                "several alignment files beside the scans ({}); choose one with --align",
                list.join(", ")
            )))
        }
    }
}

/// Returns one pose per scan, in scan order: [`match_scans`], with a scan the alignment does
/// not name an error. Entries that match none of `scans` are fine (a subset of a site).
pub fn poses_for_scans(al: &Alignment, scans: &[PathBuf]) -> Result<Vec<DMat4>> {
    let found = match_scans(al, scans)?;
    let mut poses = Vec::with_capacity(scans.len());
    for (scan, m) in scans.iter().zip(found) {
        let Some(m) = m else {
            return Err(Error::align(
                &al.path,
                format!(
                    "scan '{}' is not in the alignment file; add it, or give its pose with \
                     --pose",
                    scan.display()
                ),
            ));
        };
        poses.push(m);
    }
    Ok(poses)
}

/// The pose of each scan in the alignment, `None` for a scan it does not name. A scan matches
/// the entry with the same file name; when file names are ambiguous (two entries or two scans
/// share one), the entry's name is resolved relative to the alignment file's directory and
/// compared with the scan's path. Entries that match no scan are fine: running on part of a
/// site is normal. Errors: an entry that appears twice, or two scans matching one entry.
pub fn match_scans(al: &Alignment, scans: &[PathBuf]) -> Result<Vec<Option<DMat4>>> {
    let err = |msg: String| Error::align(&al.path, msg);

    // Duplicate entries (same name after normalising separators and "./").
    let mut seen: HashMap<String, usize> = HashMap::new();
    for (i, e) in al.entries.iter().enumerate() {
        if seen.insert(normalise_name(&e.file), i).is_some() {
            return Err(err(format!(
                "'{}' is named more than once in the alignment file",
                e.file
            )));
        }
    }

    let entry_base: Vec<String> = al.entries.iter().map(|e| base_name(&e.file)).collect();
    let scan_base: Vec<String> = scans
        .iter()
        .map(|s| {
            s.file_name()
                .map(|n| n.to_string_lossy().into_owned())
                .unwrap_or_default()
        })
        .collect();
    // How often each base name occurs, and its first entry: one pass each, so that matching
    // stays linear in the number of scans and entries.
    fn tally(names: &[String]) -> HashMap<&str, usize> {
        let mut m: HashMap<&str, usize> = HashMap::new();
        for n in names {
            *m.entry(n.as_str()).or_default() += 1;
        }
        m
    }
    let (entry_count, scan_count) = (tally(&entry_base), tally(&scan_base));
    let mut first_entry: HashMap<&str, usize> = HashMap::new();
    for (i, b) in entry_base.iter().enumerate() {
        first_entry.entry(b.as_str()).or_insert(i);
    }
    let dir = al.path.parent().unwrap_or(Path::new(""));
    // Path keys of the entries, computed once and only if some name is ambiguous.
    let mut entry_keys: Option<Vec<PathBuf>> = None;

    let mut owner: Vec<Option<usize>> = vec![None; al.entries.len()];
    let mut poses = Vec::with_capacity(scans.len());
    for (si, scan) in scans.iter().enumerate() {
        let base = scan_base[si].as_str();
        let ambiguous = entry_count.get(base).is_some_and(|&c| c > 1)
            || scan_count.get(base).is_some_and(|&c| c > 1);
        let hit = if ambiguous {
            let key = path_key(scan);
            entry_keys
                .get_or_insert_with(|| {
                    al.entries
                        .iter()
                        .map(|e| path_key(&dir.join(native_name(&e.file))))
                        .collect()
                })
                .iter()
                .position(|k| *k == key)
        } else {
            first_entry.get(base).copied()
        };
        let Some(ei) = hit else {
            poses.push(None);
            continue;
        };
        if let Some(other) = owner[ei] {
            return Err(err(format!(
                "scans '{}' and '{}' both match the entry '{}'",
                scans[other].display(),
                scan.display(),
                al.entries[ei].file
            )));
        }
        owner[ei] = Some(si);
        poses.push(Some(al.entries[ei].pose));
    }
    Ok(poses)
}

/// Checks that `m` is a rigid transform and returns it with an exactly orthonormal rotation.
///
/// The bottom row must be `(0, 0, 0, 1)` within [`BOTTOM_ROW_TOLERANCE`] and every entry finite.
/// With `R` the upper 3×3 block: `det R < 0` is rejected as a reflection;
/// `max |RᵀR − I| > `[`RIGID_TOLERANCE`] is rejected as scale or shear; otherwise `R` is replaced
/// by its nearest rotation (Newton polar iteration) and the translation is kept. `path` and
/// `what` (the scan's name) only go into error messages.
pub fn check_rigid(m: DMat4, path: &Path, what: &str) -> Result<DMat4> {
    if !m.is_finite() {
        return Err(Error::align(
            path,
            format!("pose of '{what}' has a non-finite entry"),
        ));
    }
    let bottom = m.row(3);
    if (bottom - DVec4::W).abs().max_element() > BOTTOM_ROW_TOLERANCE {
        return Err(Error::align(
            path,
            format!("pose of '{what}' has a projective bottom row"),
        ));
    }
    let r = DMat3::from_mat4(m);
    let det = r.determinant();
    if det < 0.0 {
        return Err(Error::align(
            path,
            format!("pose of '{what}' is a reflection (determinant {det:.6})"),
        ));
    }
    let dev = orthogonality_error(r);
    if !(dev <= RIGID_TOLERANCE && det > 0.0) {
        return Err(Error::align(
            path,
            format!(
                "pose of '{what}' has scale or shear (max |R^T R - I| = {dev:.3e}, \
                 more than {RIGID_TOLERANCE:e} allowed)"
            ),
        ));
    }
    let r = nearest_rotation(r);
    Ok(DMat4::from_cols(
        r.x_axis.extend(0.0),
        r.y_axis.extend(0.0),
        r.z_axis.extend(0.0),
        m.w_axis.truncate().extend(1.0),
    ))
}

/// Writes `entries` as a MeshLab project (`.mlp`) atomically: one `MLMesh` per entry with the
/// entry's file as `filename`, its base name as `label`, and the pose as a row-major
/// `MLMatrix44` printed with round-trip precision.
pub fn write_mlp(path: &Path, entries: &[AlignEntry]) -> Result<()> {
    crate::io::atomic::write_atomic(path, |w| {
        writeln!(w, "<!DOCTYPE MeshLabDocument>")?;
        writeln!(w, "<MeshLabProject>")?;
        writeln!(w, " <MeshGroup>")?;
        for e in entries {
            let file = quick_xml::escape::escape(e.file.as_str());
            let label = base_name(&e.file);
            let label = quick_xml::escape::escape(label.as_str());
            writeln!(w, "  <MLMesh label=\"{label}\" filename=\"{file}\">")?;
            writeln!(w, "   <MLMatrix44>")?;
            for i in 0..4 {
                let row = e.pose.row(i);
                writeln!(w, "{:?} {:?} {:?} {:?} ", row.x, row.y, row.z, row.w)?;
            }
            writeln!(w, "</MLMatrix44>")?;
            writeln!(w, "  </MLMesh>")?;
        }
        writeln!(w, " </MeshGroup>")?;
        writeln!(w, " <RasterGroup/>")?;
        writeln!(w, "</MeshLabProject>")?;
        Ok(())
    })
}

/// `max |RᵀR − I|` over the nine entries.
fn orthogonality_error(r: DMat3) -> f64 {
    let d = r.transpose() * r - DMat3::IDENTITY;
    d.x_axis
        .abs()
        .max(d.y_axis.abs())
        .max(d.z_axis.abs())
        .max_element()
}

/// Nearest rotation to `r` (positive determinant): the polar factor by the scaled Newton
/// iteration `R ← ½(γR + (γR)⁻ᵀ)`, which converges quadratically.
fn nearest_rotation(mut r: DMat3) -> DMat3 {
    for _ in 0..100 {
        // Scaled by |det|^(-1/3) (Higham), the iteration converges in a few steps whatever
        // the scale of a pose `--allow-scale` let in; unscaled it only halves a large scale
        // per step. Near a rotation the factor is 1.
        let det = r.determinant();
        let g = if det.is_finite() && det > 0.0 {
            det.cbrt().recip()
        } else {
            1.0
        };
        let gr = r * g;
        let next = (gr + gr.inverse().transpose()) * 0.5;
        let change = (next - r)
            .to_cols_array()
            .iter()
            .fold(0.0f64, |a, v| a.max(v.abs()));
        r = next;
        if change < 1e-16 {
            break;
        }
    }
    r
}

/// Parses a Stanford scanalyze `.conf` file.
fn parse_conf(path: &Path, text: &str) -> Result<Vec<AlignEntry>> {
    let mut out = Vec::new();
    for (i, line) in text.lines().enumerate() {
        let lineno = i + 1;
        let line = line.trim();
        if line.is_empty() || line.starts_with('#') {
            continue;
        }
        let tok: Vec<&str> = line.split_whitespace().collect();
        if tok[0] != "bmesh" {
            continue; // "camera" and other keywords carry nothing we need
        }
        let bad = |msg: String| Error::align(path, format!("line {lineno}: {msg}"));
        if tok.len() != 9 {
            return Err(bad(format!(
                "a bmesh line needs a file name and 7 numbers (tx ty tz qx qy qz qw), \
                 found {} fields after 'bmesh'",
                tok.len() - 1
            )));
        }
        let mut v = [0.0f64; 7];
        for (slot, t) in v.iter_mut().zip(&tok[2..]) {
            *slot = parse_number(t).map_err(bad)?;
        }
        let t = DVec3::new(v[0], v[1], v[2]);
        let q = DQuat::from_xyzw(v[3], v[4], v[5], v[6]);
        let n = q.length();
        if !n.is_finite() || n < 1e-6 {
            return Err(bad(format!(
                "the quaternion of '{}' has norm {n:e}, not a rotation",
                tok[1]
            )));
        }
        // scanalyze convention: world = R(q)ᵀ · p + t, i.e. rotate by the conjugate quaternion.
        let r = DMat3::from_quat(q / n).transpose();
        let pose = DMat4::from_cols(
            r.x_axis.extend(0.0),
            r.y_axis.extend(0.0),
            r.z_axis.extend(0.0),
            t.extend(1.0),
        );
        out.push(AlignEntry {
            file: tok[1].to_string(),
            pose,
        });
    }
    Ok(out)
}

/// Parses a MeshLab project (`.mlp`).
fn parse_mlp(path: &Path, text: &str) -> Result<Vec<AlignEntry>> {
    use quick_xml::events::{BytesStart, Event};

    let line_of = |pos: u64| {
        let pos = usize::try_from(pos).unwrap_or(usize::MAX).min(text.len());
        text.as_bytes()[..pos]
            .iter()
            .filter(|&&b| b == b'\n')
            .count()
            + 1
    };
    let name_of = |e: &BytesStart, reader_pos: u64| -> Result<String> {
        let mut filename = None;
        let mut label = None;
        for a in e.attributes() {
            let a = a.map_err(|err| {
                Error::align(path, format!("line {}: {err}", line_of(reader_pos)))
            })?;
            let v = a.unescape_value().map_err(|err| {
                Error::align(path, format!("line {}: {err}", line_of(reader_pos)))
            })?;
            match a.key.as_ref() {
                b"filename" => filename = Some(v.into_owned()),
                b"label" => label = Some(v.into_owned()),
                _ => {}
            }
        }
        filename
            .filter(|s| !s.trim().is_empty())
            .or(label.filter(|s| !s.trim().is_empty()))
            .ok_or_else(|| {
                Error::align(
                    path,
                    format!(
                        "line {}: an MLMesh has neither a filename nor a label",
                        line_of(reader_pos)
                    ),
                )
            })
    };

    let mut reader = quick_xml::Reader::from_str(text);
    let mut out = Vec::new();
    // (file name, byte position of the MLMesh, matrix text if one was seen). The line number is
    // only counted for an error message: counting it for every mesh is quadratic in the size
    // of the file.
    let mut mesh: Option<(String, u64, Option<String>)> = None;
    let mut matrix: Option<String> = None;
    loop {
        let pos = reader.buffer_position();
        let ev = reader.read_event().map_err(|e| {
            Error::align(
                path,
                format!("line {}: {e}", line_of(reader.error_position())),
            )
        })?;
        match ev {
            Event::Start(e) if e.local_name().as_ref() == b"MLMesh" => {
                mesh = Some((name_of(&e, pos)?, pos, None));
            }
            Event::Empty(e) if e.local_name().as_ref() == b"MLMesh" => {
                let name = name_of(&e, pos)?;
                return Err(Error::align(
                    path,
                    format!("line {}: mesh '{name}' has no MLMatrix44", line_of(pos)),
                ));
            }
            Event::Start(e) if e.local_name().as_ref() == b"MLMatrix44" && mesh.is_some() => {
                matrix = Some(String::new());
            }
            Event::Text(t) => {
                if let Some(m) = matrix.as_mut() {
                    let s = t
                        .unescape()
                        .map_err(|e| Error::align(path, format!("line {}: {e}", line_of(pos))))?;
                    m.push_str(&s);
                    m.push(' ');
                }
            }
            Event::End(e) if e.local_name().as_ref() == b"MLMatrix44" => {
                if let (Some(m), Some(cur)) = (matrix.take(), mesh.as_mut()) {
                    cur.2 = Some(m);
                }
            }
            Event::End(e) if e.local_name().as_ref() == b"MLMesh" => {
                if let Some((file, mesh_pos, m)) = mesh.take() {
                    let Some(m) = m else {
                        return Err(Error::align(
                            path,
                            format!(
                                "line {}: mesh '{file}' has no MLMatrix44",
                                line_of(mesh_pos)
                            ),
                        ));
                    };
                    let nums: Vec<&str> = m.split_whitespace().collect();
                    let pose =
                        matrix_from_row_major(&nums, |t| parse_number(t)).map_err(|msg| {
                            Error::align(
                                path,
                                format!("line {}: matrix of '{file}': {msg}", line_of(mesh_pos)),
                            )
                        })?;
                    out.push(AlignEntry { file, pose });
                }
            }
            Event::Eof => break,
            _ => {}
        }
    }
    Ok(out)
}

/// Parses a MeshLab alignment (`.aln`): the number of meshes, then per mesh its file name, a
/// `#` comment line and the 4×4 row-major matrix; a final `0` ends the list.
fn parse_aln(path: &Path, text: &str) -> Result<Vec<AlignEntry>> {
    let mut lines = text
        .lines()
        .enumerate()
        .map(|(i, l)| (i + 1, l.trim()))
        .filter(|(_, l)| !l.is_empty());
    let Some((n0, first)) = lines.next() else {
        return Ok(Vec::new());
    };
    let count: usize = first.parse().map_err(|_| {
        Error::align(
            path,
            format!("line {n0}: expected the number of meshes, found '{first}'"),
        )
    })?;
    let mut out = Vec::with_capacity(count.min(1 << 16));
    for k in 0..count {
        let Some((ln, file)) = lines.next() else {
            return Err(Error::align(
                path,
                format!("the file declares {count} meshes but ends after {k}"),
            ));
        };
        let mut nums: Vec<&str> = Vec::with_capacity(16);
        let mut last = ln;
        while nums.len() < 16 {
            let Some((l, line)) = lines.next() else {
                return Err(Error::align(
                    path,
                    format!("line {last}: the matrix of '{file}' is cut short"),
                ));
            };
            last = l;
            if line.starts_with('#') {
                continue;
            }
            nums.extend(line.split_whitespace());
        }
        let pose = matrix_from_row_major(&nums, |t| parse_number(t))
            .map_err(|msg| Error::align(path, format!("line {last}: matrix of '{file}': {msg}")))?;
        out.push(AlignEntry {
            file: file.to_string(),
            pose,
        });
    }
    Ok(out)
}

/// Parses a JSON object `{ "file": [16 numbers, row-major], ... }`, keeping file order and
/// duplicate keys (so they can be reported).
fn parse_json(path: &Path, text: &str) -> Result<Vec<AlignEntry>> {
    let obj: JsonEntries = serde_json::from_str(text).map_err(|e| {
        Error::align(
            path,
            format!("expected a JSON object of 16-number row-major matrices: {e}"),
        )
    })?;
    let mut out = Vec::with_capacity(obj.0.len());
    for (file, value) in obj.0 {
        let bad = |msg: String| Error::align(path, format!("matrix of '{file}': {msg}"));
        let serde_json::Value::Array(items) = value else {
            return Err(bad("expected an array of 16 numbers".into()));
        };
        let pose = matrix_from_row_major(&items, |v| {
            v.as_f64()
                .filter(|x| x.is_finite())
                .ok_or_else(|| format!("{v} is not a finite number"))
        })
        .map_err(bad)?;
        out.push(AlignEntry { file, pose });
    }
    Ok(out)
}

/// A JSON object read as an ordered list of (key, value) pairs.
struct JsonEntries(Vec<(String, serde_json::Value)>);

impl<'de> serde::Deserialize<'de> for JsonEntries {
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> std::result::Result<Self, D::Error> {
        struct V;
        impl<'de> serde::de::Visitor<'de> for V {
            type Value = JsonEntries;
            fn expecting(&self, f: &mut std::fmt::Formatter) -> std::fmt::Result {
                f.write_str("an object mapping scan file names to 16 numbers")
            }
            fn visit_map<A: serde::de::MapAccess<'de>>(
                self,
                mut map: A,
            ) -> std::result::Result<JsonEntries, A::Error> {
                let mut v = Vec::new();
                while let Some(kv) = map.next_entry::<String, serde_json::Value>()? {
                    v.push(kv);
                }
                Ok(JsonEntries(v))
            }
        }
        d.deserialize_map(V)
    }
}

/// Builds a matrix from 16 row-major items, converting each with `num`.
fn matrix_from_row_major<T>(
    items: &[T],
    num: impl Fn(&T) -> std::result::Result<f64, String>,
) -> std::result::Result<DMat4, String> {
    // Something that is not a number is named first: prose has the wrong count too.
    for it in items.iter().take(17) {
        num(it)?;
    }
    if items.len() != 16 {
        return Err(format!("expected 16 numbers, found {}", items.len()));
    }
    let mut a = [0.0f64; 16];
    for (slot, it) in a.iter_mut().zip(items) {
        *slot = num(it)?;
    }
    // `from_cols_array` reads column-major; transposing reinterprets the array as rows.
    Ok(DMat4::from_cols_array(&a).transpose())
}

/// Parses one finite number.
fn parse_number(t: &str) -> std::result::Result<f64, String> {
    match t.parse::<f64>() {
        Ok(v) if v.is_finite() => Ok(v),
        _ => Err(format!("'{t}' is not a finite number")),
    }
}

/// The last path component of a name as written in an alignment file (`/` or `\` separated).
fn base_name(file: &str) -> String {
    file.rsplit(['/', '\\']).next().unwrap_or(file).to_string()
}

/// A name with `\` turned into `/` and `./` components removed, for duplicate detection.
fn normalise_name(file: &str) -> String {
    file.replace('\\', "/")
        .split('/')
        .filter(|c| !c.is_empty() && *c != ".")
        .collect::<Vec<_>>()
        .join("/")
}

/// A name from an alignment file as a native relative path.
fn native_name(file: &str) -> PathBuf {
    file.split(['/', '\\']).collect()
}

/// A comparable form of a path: canonical if it exists, else absolute and lexically normalised.
fn path_key(p: &Path) -> PathBuf {
    if let Ok(c) = std::fs::canonicalize(p) {
        return c;
    }
    let abs = std::path::absolute(p).unwrap_or_else(|_| p.to_path_buf());
    let mut out = PathBuf::new();
    for c in abs.components() {
        match c {
            Component::CurDir => {}
            Component::ParentDir => {
                out.pop();
            }
            other => out.push(other.as_os_str()),
        }
    }
    out
}

#[cfg(test)]
mod tests;
