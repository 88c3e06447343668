//! A dataset: every input file read, its scans flattened into one list, and every scan placed
//! in world coordinates. Poses come, from strongest to weakest, from `--pose SCAN=FILE`, a
//! per-scan matrix sidecar (`scan.txt` / `scan.mat`), the alignment file (given or found beside
//! the scans), and the file's own pose (E57, PTX); the alignment pose of a file is applied on
//! top of the file's own poses.

use super::align::{self, Alignment};
use super::source::{self, InputFile};
use crate::error::{Error, Result};
use crate::scan::Scan;
use glam::{DMat3, DMat4, Vec3};
use std::path::{Path, PathBuf};

/// `--pose SCAN=FILE`: the 4×4 matrix in FILE places SCAN (scan coordinates → world),
/// replacing every other pose of it.
#[derive(Debug, Clone, PartialEq)]
pub struct PoseOverride {
    /// A scan name, a file name, a file stem or a path as given.
    pub target: String,
    /// The matrix file.
    pub file: PathBuf,
}

impl std::str::FromStr for PoseOverride {
    type Err = String;
    fn from_str(s: &str) -> std::result::Result<Self, String> {
        match s.split_once('=') {
            Some((t, f)) if !t.is_empty() && !f.is_empty() => Ok(PoseOverride {
                target: t.to_string(),
                file: PathBuf::from(f),
            }),
            _ => Err(format!("'{s}' is not SCAN=FILE")),
        }
    }
}

/// How the scans are placed.
#[derive(Debug, Clone, Default)]
pub struct PlaceOptions {
    /// Alignment file; `None` looks for exactly one beside the scans.
    pub align: Option<PathBuf>,
    /// Per-scan overrides.
    pub poses: Vec<PoseOverride>,
    /// Accept poses with scale or shear (the stretch is applied to the points).
    pub allow_scale: bool,
}

/// Every input read and placed.
#[derive(Debug)]
pub struct Dataset {
    /// Input files in command-line order (their `scans` moved out into [`Dataset::scans`]).
    pub files: Vec<InputFile>,
    /// All scans, file by file, with world poses (rigid).
    pub scans: Vec<Scan>,
    /// For each scan: (index into `files`, index within its file).
    pub origin: Vec<(usize, usize)>,
    /// For each scan: file coordinates → world (affine when `--allow-scale` let a stretch in).
    pub file_to_world: Vec<DMat4>,
    /// For each scan: where its pose came from, for `info` and the report.
    pub pose_source: Vec<String>,
    /// The alignment file used, if any.
    pub alignment: Option<PathBuf>,
    /// Things the user should know (re-centred coordinates, skipped points, no alignment).
    pub warnings: Vec<String>,
}

/// Poses of every input file resolved before any file is read (alignment file, sidecars,
/// `--pose` by file), so files can be read and placed one at a time.
#[derive(Debug, Clone)]
pub struct Placer {
    paths: Vec<PathBuf>,
    opts: PlaceOptions,
    file_pose: Vec<Option<(DMat4, String)>>,
    alignment: Option<PathBuf>,
}

/// One input file read and placed.
#[derive(Debug)]
pub struct PlacedFile {
    /// The file (its `scans` moved out into [`PlacedFile::scans`]).
    pub file: InputFile,
    /// Its scans with world poses.
    pub scans: Vec<Scan>,
    /// Per scan: file coordinates → world.
    pub file_to_world: Vec<DMat4>,
    /// Per scan: where its pose came from.
    pub pose_source: Vec<String>,
    /// Warnings about this file.
    pub warnings: Vec<String>,
}

impl Placer {
    /// Resolves the alignment file, sidecars and file-level `--pose` flags of `paths`.
    pub fn new(paths: &[PathBuf], opts: &PlaceOptions) -> Result<Placer> {
        if paths.is_empty() {
            return Err(Error::Param("no scan given".into()));
        }
        // A missing input is named before any alignment lookup in its directory.
        for p in paths {
            std::fs::metadata(p).map_err(|e| Error::io(p, e))?;
        }
        for (i, o) in opts.poses.iter().enumerate() {
            if let Some(d) = opts.poses[..i].iter().find(|d| d.target == o.target) {
                return Err(Error::Param(format!(
                    "--pose {} is given twice ({} and {})",
                    o.target,
                    d.file.display(),
                    o.file.display()
                )));
            }
        }
        let by_file = |p: &Path| opts.poses.iter().any(|o| names_file(&o.target, p));
        for p in paths.iter().filter(|p| !by_file(p)) {
            align::check_one_sidecar(p)?;
        }
        let sidecar: Vec<Option<PathBuf>> = paths
            .iter()
            .map(|p| (!by_file(p)).then(|| align::sidecar_of(p)).flatten())
            .collect();
        let needs_align: Vec<usize> = (0..paths.len())
            .filter(|&i| sidecar[i].is_none() && !by_file(&paths[i]))
            .collect();
        let align_path = match &opts.align {
            Some(a) => Some(a.clone()),
            None if !needs_align.is_empty() => {
                let list: Vec<PathBuf> = needs_align.iter().map(|&i| paths[i].clone()).collect();
                align::find_alignment_beside(&list)?
            }
            None => None,
        };
        let mut file_pose: Vec<Option<(DMat4, String)>> = vec![None; paths.len()];
        if let Some(a) = &align_path {
            let al: Alignment = align::read_alignment_with(a, opts.allow_scale)?;
            let list: Vec<PathBuf> = needs_align.iter().map(|&i| paths[i].clone()).collect();
            let placed: Vec<PathBuf> = (0..paths.len())
                .filter(|i| !needs_align.contains(i))
                .map(|i| paths[i].clone())
                .collect();
            let poses = align::poses_for_scans_beside(&al, &list, &placed)?;
            for (&i, m) in needs_align.iter().zip(poses) {
                file_pose[i] = Some((m, format!("alignment {}", a.display())));
            }
        }
        for (i, s) in sidecar.iter().enumerate() {
            if let Some(sc) = s {
                let what = paths[i].display().to_string();
                let m = align::read_matrix_file(sc, &what, opts.allow_scale)?;
                file_pose[i] = Some((m, format!("sidecar {}", sc.display())));
            }
        }
        Ok(Placer {
            paths: paths.to_vec(),
            opts: opts.clone(),
            file_pose,
            alignment: align_path,
        })
    }

    /// An error for a `--pose` that names none of the input files and none of `scans` (the
    /// names of every scan they hold).
    pub fn check_pose_targets<'a>(
        &self,
        scans: impl Iterator<Item = &'a str> + Clone,
    ) -> Result<()> {
        for o in &self.opts.poses {
            let hit = self.paths.iter().any(|p| names_file(&o.target, p))
                || scans.clone().any(|n| n == o.target);
            if !hit {
                return Err(Error::Param(format!(
                    "--pose {}={}: no input file or scan is named '{}'",
                    o.target,
                    o.file.display(),
                    o.target
                )));
            }
        }
        Ok(())
    }

    /// Number of input files.
    pub fn len(&self) -> usize {
        self.paths.len()
    }

    /// True when there is no input file.
    pub fn is_empty(&self) -> bool {
        self.paths.is_empty()
    }

    /// The input files.
    pub fn paths(&self) -> &[PathBuf] {
        &self.paths
    }

    /// The alignment file used, if any.
    pub fn alignment(&self) -> Option<&Path> {
        self.alignment.as_deref()
    }

    /// Reads input file `fi` and places its scans.
    pub fn open(&self, fi: usize) -> Result<PlacedFile> {
        let opts = &self.opts;
        let p = &self.paths[fi];
        let mut f = source::read_input(p)?;
        if f.scans.is_empty() {
            return Err(Error::format(p, "holds no scan"));
        }
        let file_pose = &self.file_pose;
        let mut scans = Vec::new();
        let mut file_to_world = Vec::new();
        let mut pose_source = Vec::new();
        let mut warnings = std::mem::take(&mut f.warnings);
        let own: Vec<Scan> = std::mem::take(&mut f.scans);
        let single = own.len() == 1;
        for (k, mut s) in own.into_iter().enumerate() {
            warnings.append(&mut s.warnings);
            let offset = f.file_to_local[k];
            let given: Option<(DMat4, String)> = match override_for(opts, &s.name, &f.path, single)
            {
                Some(o) => Some((
                    align::read_matrix_file(&o.file, &s.name, opts.allow_scale)?,
                    format!("--pose {}", o.file.display()),
                )),
                None => file_pose[fi].clone(),
            };
            if f.format.world_coordinates() {
                // LAS/LAZ hold world coordinates: a pose says where the scanner stood.
                let m = match given {
                    Some((m, src)) => {
                        let (rigid, _) = align::split_scale(m);
                        let to_local = rigid.inverse() * s.pose;
                        let rot = glam::DMat3::from_mat4(to_local);
                        for p in &mut s.points {
                            *p = to_local.transform_point3(p.as_dvec3()).as_vec3();
                        }
                        if let Some(ns) = s.normals.as_mut() {
                            for n in ns {
                                *n = (rot * n.as_dvec3()).as_vec3();
                            }
                        }
                        s.pose = rigid;
                        pose_source
                            .push(format!("{src} (scanner pose; file coordinates are world)"));
                        DMat4::IDENTITY
                    }
                    None => {
                        let at = if offset == glam::DVec3::ZERO {
                            "the coordinate origin".to_string()
                        } else {
                            format!(
                                "the centre of its bounds ({:.3}, {:.3}, {:.3})",
                                offset.x, offset.y, offset.z
                            )
                        };
                        warnings.push(format!(
                            "{}: {} files carry no scanner position; the scanner is assumed at \
                             {at}. Give its pose (scanner → world) with --pose {}=FILE, a \
                             sidecar {} or an alignment file",
                            f.path.display(),
                            f.format,
                            s.name,
                            f.path.with_extension("txt").display()
                        ));
                        pose_source.push("none (no scanner position)".into());
                        DMat4::IDENTITY
                    }
                };
                if s.skipped_nonfinite > 0 {
                    warnings.push(format!(
                        "{}: {} points with non-finite coordinates skipped",
                        f.path.display(),
                        s.skipped_nonfinite
                    ));
                }
                file_to_world.push(m);
                scans.push(s);
                continue;
            }
            let (m, src) = match given {
                Some((a, src)) if override_for(opts, &s.name, &f.path, single).is_some() => {
                    (a * DMat4::from_translation(offset), src)
                }
                Some((a, src)) => (a * s.pose, src),
                None => (
                    s.pose,
                    if f.format.multi_scan() {
                        format!("{} pose", f.format)
                    } else {
                        "none (identity)".to_string()
                    },
                ),
            };
            let off = offset;
            if off.length() > 0.0 && !f.format.multi_scan() {
                warnings.push(format!(
                    "{}: coordinates beyond {} m; re-centred on ({:.3}, {:.3}, {:.3}) (kept in f64) and the scanner is assumed at that centre (no scanner position in the file)",
                    f.path.display(),
                    source::RECENTRE_ABOVE,
                    off.x,
                    off.y,
                    off.z
                ));
            }
            if s.skipped_nonfinite > 0 && !f.format.multi_scan() {
                warnings.push(format!(
                    "{}: {} vertices with non-finite coordinates skipped (not written)",
                    f.path.display(),
                    s.skipped_nonfinite
                ));
            }
            let (rigid, stretch) = align::split_scale(m);
            if (stretch - DMat3::IDENTITY).abs_diff_eq(DMat3::ZERO, 1e-12) {
                s.pose = rigid;
            } else {
                apply_stretch(&mut s, stretch);
                s.pose = rigid;
            }
            file_to_world.push(m * DMat4::from_translation(-offset));
            pose_source.push(src);
            scans.push(s);
        }
        Ok(PlacedFile {
            file: f,
            scans,
            file_to_world,
            pose_source,
            warnings,
        })
    }
}

impl Dataset {
    /// Reads every file in `paths` and places its scans. `progress` is called once per file.
    pub fn open(paths: &[PathBuf], opts: &PlaceOptions, progress: &dyn Fn()) -> Result<Dataset> {
        let placer = Placer::new(paths, opts)?;
        let mut files = Vec::with_capacity(paths.len());
        let mut scans = Vec::new();
        let mut origin = Vec::new();
        let mut file_to_world = Vec::new();
        let mut pose_source = Vec::new();
        let mut warnings = Vec::new();
        for fi in 0..placer.len() {
            let pf = placer.open(fi)?;
            for k in 0..pf.scans.len() {
                origin.push((fi, k));
            }
            scans.extend(pf.scans);
            file_to_world.extend(pf.file_to_world);
            pose_source.extend(pf.pose_source);
            warnings.extend(pf.warnings);
            files.push(pf.file);
            progress();
        }
        placer.check_pose_targets(scans.iter().map(|s| s.name.as_str()))?;
        let identity = pose_source
            .iter()
            .filter(|p| *p == "none (identity)")
            .count();
        if scans.len() > 1 && identity > 0 {
            warnings.push(format!(
                "{identity} of {} scans have no pose (no alignment file given or found beside \
                 them, no sidecar, no pose in the file): taken as already aligned",
                scans.len()
            ));
        }
        Ok(Dataset {
            files,
            scans,
            origin,
            file_to_world,
            pose_source,
            alignment: placer.alignment().map(Path::to_path_buf),
            warnings,
        })
    }
}

/// The last `--pose` naming the scan `name` of `path` (by scan name, or by the file when it
/// holds one scan).
fn override_for<'a>(
    opts: &'a PlaceOptions,
    name: &str,
    path: &Path,
    single: bool,
) -> Option<&'a PoseOverride> {
    opts.poses
        .iter()
        .rev()
        .find(|o| o.target == name || (single && names_file(&o.target, path)))
}

/// True when `target` names `path`: its file name, its stem, or the path as written.
fn names_file(target: &str, path: &Path) -> bool {
    path.file_name()
        .is_some_and(|n| n.to_string_lossy() == target)
        || path
            .file_stem()
            .is_some_and(|n| n.to_string_lossy() == target)
        || path.display().to_string() == target
}

/// Applies a symmetric stretch to a scan's local points (in f64) and its normals (by the
/// inverse transpose), so that a rigid pose places it where the affine one did.
fn apply_stretch(s: &mut Scan, m: DMat3) {
    for p in &mut s.points {
        *p = (m * p.as_dvec3()).as_vec3();
    }
    if let Some(ns) = s.normals.as_mut() {
        let nt = m.inverse().transpose();
        for n in ns {
            if *n != Vec3::ZERO {
                *n = (nt * n.as_dvec3()).normalize_or_zero().as_vec3();
            }
        }
    }
}
