//! A dataset: every input file read, its scans flattened into one list, and every scan placed
//! in world coordinates. Poses come, from strongest to weakest, from `--pose SCAN=FILE`, a
//! per-scan matrix sidecar (`scan.txt` / `scan.mat`), the alignment file (given or found beside
//! the scans), and the file's own pose (E57, PTX); the alignment pose of a file is applied on
//! top of the file's own poses.

use super::align;
use super::source::{self, Container, InputFile};
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
    /// Per input file: what placing it found worth telling, handed out with the file.
    notes: Vec<Vec<String>>,
    mode: Mode,
}

/// How placement problems are met.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Mode {
    /// A run: a problem that leaves a scan without the pose it needs is an error.
    Run,
    /// `mvao info`: every placement problem is a warning and the scans it concerns are taken
    /// as they are, so that every readable file is described.
    Describe,
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
    ///
    /// An alignment found beside the scans places the scans it names; naming more scans than
    /// were given is normal (part of a site). A scan it does not name is taken as it is, with
    /// a warning, unless the alignment places other scans given with it: then it is an error
    /// that names `--pose` and `--align` as the fix. A found alignment that cannot be read or
    /// matched is an error only when some scan needs a pose from it. An alignment given with
    /// `--align` is the user's statement of where the scans are, so every problem with it is
    /// an error. Before reporting an alignment problem about a scan, the scan file itself is
    /// read: its own problem is reported first.
    pub fn new(paths: &[PathBuf], opts: &PlaceOptions) -> Result<Placer> {
        Placer::build(paths, opts, Mode::Run)
    }

    /// [`Placer::new`] for describing files (`mvao info`): a placement problem becomes a
    /// warning on the files it concerns, which are then taken as they are, and a file that
    /// does not exist is left for [`Placer::open`] to report.
    pub fn describing(paths: &[PathBuf], opts: &PlaceOptions) -> Result<Placer> {
        Placer::build(paths, opts, Mode::Describe)
    }

    fn build(paths: &[PathBuf], opts: &PlaceOptions, mode: Mode) -> Result<Placer> {
        if paths.is_empty() {
            return Err(Error::Param("no scan given".into()));
        }
        if mode == Mode::Run {
            // A missing input is named before any alignment lookup in its directory.
            for p in paths {
                std::fs::metadata(p).map_err(|e| Error::io(p, e))?;
            }
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
        let n = paths.len();
        let mut placer = Placer {
            paths: paths.to_vec(),
            opts: opts.clone(),
            file_pose: vec![None; n],
            alignment: None,
            notes: vec![Vec::new(); n],
            mode,
        };
        let by_file = |p: &Path| opts.poses.iter().any(|o| names_file(&o.target, p));
        let mut sidecar: Vec<Option<PathBuf>> = vec![None; n];
        let mut needs_align = Vec::new();
        for (i, p) in paths.iter().enumerate() {
            if by_file(p) {
                continue;
            }
            match align::check_one_sidecar(p) {
                Ok(()) => match align::sidecar_of(p) {
                    Some(sc) => sidecar[i] = Some(sc),
                    None => needs_align.push(i),
                },
                Err(e) => placer.excuse(i, e)?,
            }
        }
        placer.place_by_alignment(&needs_align)?;
        for (i, s) in sidecar.iter().enumerate() {
            if let Some(sc) = s {
                let what = paths[i].display().to_string();
                match align::read_matrix_file(sc, &what, opts.allow_scale) {
                    Ok(m) => placer.file_pose[i] = Some((m, format!("sidecar {}", sc.display()))),
                    Err(e) => placer.excuse(i, e)?,
                }
            }
        }
        Ok(placer)
    }

    /// Places the files `needs` (no sidecar, no `--pose`) by the alignment file given or found
    /// beside them (see [`Placer::new`]).
    fn place_by_alignment(&mut self, needs: &[usize]) -> Result<()> {
        let explicit = self.opts.align.is_some();
        if needs.is_empty() && !explicit {
            return Ok(());
        }
        let list: Vec<PathBuf> = needs.iter().map(|&i| self.paths[i].clone()).collect();
        // A found alignment's problem stops the run only when a scan needs a pose from it.
        let blocks = explicit || self.need_pose(needs);
        let path = match &self.opts.align {
            Some(a) => a.clone(),
            None => match align::find_alignment_beside(&list) {
                Ok(Some(a)) => a,
                Ok(None) => return Ok(()),
                Err(e) => return self.alignment_problem(needs, e, blocks),
            },
        };
        let found = align::read_alignment_with(&path, self.opts.allow_scale)
            .and_then(|al| align::match_scans(&al, &list));
        let found = match found {
            Ok(f) => f,
            Err(e) => return self.alignment_problem(needs, e, blocks),
        };
        let src = format!("alignment {}", path.display());
        let unnamed: Vec<usize> = needs
            .iter()
            .zip(&found)
            .filter(|(_, m)| m.is_none())
            .map(|(&i, _)| i)
            .collect();
        let named = needs.len() - unnamed.len();
        for (&i, m) in needs.iter().zip(found) {
            self.file_pose[i] = m.map(|m| (m, src.clone()));
        }
        if named > 0 || explicit {
            self.alignment = Some(path.clone());
        }
        for &i in &unnamed {
            let scan = self.paths[i].display().to_string();
            let stem = self.paths[i]
                .file_stem()
                .map_or_else(|| scan.clone(), |s| s.to_string_lossy().into_owned());
            let e = if explicit {
                Error::align(
                    &path,
                    format!(
                        "scan '{scan}' is not in the alignment file; add it, or give its pose \
                         with --pose {stem}=FILE"
                    ),
                )
            } else if named > 0 {
                Error::Param(format!(
                    "{scan}: not named in the alignment file {} found beside it, which places \
                     {named} of the other scans given; give its pose with --pose {stem}=FILE, \
                     or choose an alignment that names it with --align",
                    path.display()
                ))
            } else {
                self.notes[i].push(format!(
                    "{scan}: not named in the alignment file {} found beside it; taken as it \
                     is (give its pose with --pose {stem}=FILE or --align)",
                    path.display()
                ));
                continue;
            };
            if self.mode == Mode::Run {
                return Err(self.own_problem_first(&[i], e));
            }
            self.notes[i].push(format!("{e}; described as it is"));
        }
        Ok(())
    }

    /// True when some of the files `needs` must get a pose from an alignment: files that
    /// carry no placement of their own (E57 and PTX poses, LAS world coordinates), given
    /// with other files. One file alone is shaded in its own frame.
    fn need_pose(&self, needs: &[usize]) -> bool {
        self.paths.len() > 1
            && needs.iter().any(|&i| {
                !source::Format::of_path(&self.paths[i])
                    .is_ok_and(|f| f.multi_scan() || f.world_coordinates())
            })
    }

    /// An alignment file that cannot be used for the files `needs`: an error when it
    /// `blocks` a run (after any problem of the files themselves), else a note on the first
    /// of them.
    fn alignment_problem(&mut self, needs: &[usize], e: Error, blocks: bool) -> Result<()> {
        if blocks && self.mode == Mode::Run {
            let e = match e {
                Error::Align { path, msg } if self.opts.align.is_none() => Error::Align {
                    path,
                    msg: format!(
                        "{msg} (alignment file found beside the scans: fix it, choose another \
                         with --align, or give the poses with --pose)"
                    ),
                },
                e => e,
            };
            return Err(self.own_problem_first(needs, e));
        }
        let why = match self.mode {
            Mode::Run => "not used: no scan given needs a pose from it",
            Mode::Describe => "not used: the scans are described as they are",
        };
        if let Some(&i) = needs.first() {
            self.notes[i].push(format!("{e} ({why})"));
        }
        Ok(())
    }

    /// A pose problem of file `i` (its sidecars): an error in a run, after any problem of the
    /// file itself; a note when describing.
    fn excuse(&mut self, i: usize, e: Error) -> Result<()> {
        match self.mode {
            Mode::Run => Err(self.own_problem_first(&[i], e)),
            Mode::Describe => {
                self.notes[i].push(format!("{e}; described as it is"));
                Ok(())
            }
        }
    }

    /// The first problem of the files `concerned` themselves (unreadable, holding no scan),
    /// else `e`: a broken file is reported as such rather than as an alignment mismatch.
    fn own_problem_first(&self, concerned: &[usize], e: Error) -> Error {
        concerned
            .iter()
            .find_map(|&i| read_scans(&self.paths[i]).err())
            .unwrap_or(e)
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
        let mut f = read_scans(p)?;
        let file_pose = &self.file_pose;
        let mut scans = Vec::new();
        let mut file_to_world = Vec::new();
        let mut pose_source = Vec::new();
        let mut warnings = self.notes[fi].clone();
        warnings.append(&mut f.warnings);
        let own: Vec<Scan> = std::mem::take(&mut f.scans);
        let single = own.len() == 1;
        for (k, mut s) in own.into_iter().enumerate() {
            warnings.append(&mut s.warnings);
            let offset = f.file_to_local[k];
            let given: Option<(DMat4, String)> = match override_for(opts, &s.name, &f.path, single)
            {
                Some(o) => match align::read_matrix_file(&o.file, &s.name, opts.allow_scale) {
                    Ok(m) => Some((m, format!("--pose {}", o.file.display()))),
                    Err(e) if self.mode == Mode::Describe => {
                        warnings.push(format!("{e}; described as it is"));
                        None
                    }
                    Err(e) => return Err(e),
                },
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
            if let Container::Ply(ply) = &f.container {
                let bad = ply.faces_out_of_range();
                if bad > 0 {
                    let (faces, refer) = if bad == 1 {
                        ("face", "refers")
                    } else {
                        ("faces", "refer")
                    };
                    warnings.push(format!(
                        "{}: {bad} {faces} {refer} to vertices the file does not have; dropped \
                         from the output",
                        f.path.display()
                    ));
                }
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
        let mut ds = Dataset::empty(&placer);
        for fi in 0..placer.len() {
            ds.add(placer.open(fi)?);
            progress();
        }
        placer.check_pose_targets(ds.scans.iter().map(|s| s.name.as_str()))?;
        ds.warn_unplaced();
        Ok(ds)
    }

    /// For `mvao info`, which never refuses to describe a file: placement problems are
    /// warnings (see [`Placer::describing`]), and a file that cannot be read is left out of
    /// the dataset and returned with its error, in input order.
    pub fn describe(paths: &[PathBuf], opts: &PlaceOptions) -> Result<(Dataset, Vec<Error>)> {
        let placer = Placer::describing(paths, opts)?;
        let mut ds = Dataset::empty(&placer);
        let mut unreadable = Vec::new();
        for fi in 0..placer.len() {
            match placer.open(fi) {
                Ok(pf) => ds.add(pf),
                Err(e) => unreadable.push(e),
            }
        }
        if let Err(e) = placer.check_pose_targets(ds.scans.iter().map(|s| s.name.as_str())) {
            ds.warnings.push(e.to_string());
        }
        ds.warn_unplaced();
        Ok((ds, unreadable))
    }

    fn empty(placer: &Placer) -> Dataset {
        Dataset {
            files: Vec::with_capacity(placer.len()),
            scans: Vec::new(),
            origin: Vec::new(),
            file_to_world: Vec::new(),
            pose_source: Vec::new(),
            alignment: placer.alignment().map(Path::to_path_buf),
            warnings: Vec::new(),
        }
    }

    fn add(&mut self, pf: PlacedFile) {
        let fi = self.files.len();
        self.origin.extend((0..pf.scans.len()).map(|k| (fi, k)));
        self.scans.extend(pf.scans);
        self.file_to_world.extend(pf.file_to_world);
        self.pose_source.extend(pf.pose_source);
        self.warnings.extend(pf.warnings);
        self.files.push(pf.file);
    }

    /// One warning when some of several scans have no pose at all.
    fn warn_unplaced(&mut self) {
        let identity = self
            .pose_source
            .iter()
            .filter(|p| *p == "none (identity)")
            .count();
        if self.scans.len() > 1 && identity > 0 {
            self.warnings.push(format!(
                "{identity} of {} scans have no pose (no alignment file given or found beside \
                 them that names them, no sidecar, no pose in the file): taken as already aligned",
                self.scans.len()
            ));
        }
    }
}

/// Reads a scan file that must hold at least one scan.
fn read_scans(path: &Path) -> Result<InputFile> {
    let f = source::read_input(path)?;
    if f.scans.is_empty() {
        return Err(Error::format(path, "holds no scan"));
    }
    Ok(f)
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
