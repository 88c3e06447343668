//! Command-line flags (what the user typed) and their check into a [`Config`]. Opens no files.

use clap::{Args, Parser, Subcommand, ValueEnum};
use glam::DVec3;
use mvao::accuracy::{Geometry, RefConfig, SurfaceSpec};
use mvao::config::{ComputeParams, Config};
use mvao::falloff::{parse_tmax, Falloff};
use mvao::io::dataset::{PlaceOptions, PoseOverride};
use mvao::io::output::ColorMode;
use mvao::io::source::Format;
use mvao::synth::{MeshKind, MeshSource, Registration, SceneKind, SynthOptions};
use mvao::Estimator;
use mvao::Occlusion;
use mvao::ProjectionChoice;
use mvao::RefParams;
use mvao::Sampling;
use mvao::SensorModel;
use mvao::{PreviewStyle, Tone, Up};
use std::path::PathBuf;

/// mvao — multi-view ambient occlusion for raw aligned 3D scans.
#[derive(Debug, Parser)]
#[command(name = "mvao", version, about, long_about = None)]
pub struct Cli {
    /// What to do.
    #[command(subcommand)]
    pub command: Command,
}

/// Subcommands.
#[derive(Debug, Subcommand)]
pub enum Command {
    /// Compute per-point multi-view AO for aligned scans and write coloured copies.
    Merge(MergeArgs),
    /// Compute and store the per-scan products (G-buffer, SSAO, border field) in the work
    /// directory, without merging: one job per scan with `--only`.
    Prepare(MergeArgs),
    /// Describe scan files: format, points, attributes, pose, grid, sensor model, bounds,
    /// overlaps.
    Info(InfoArgs),
    /// Ray-traced reference obscurance of every point (the ground truth of `eval`).
    Reference(ReferenceArgs),
    /// Score result files against a reference directory.
    Eval(EvalArgs),
    /// Error against run time over a grid of settings: CSV and SVG plot.
    Sweep(SweepArgs),
    /// Plot a sweep CSV (e.g. after a script added rows).
    Plot(PlotArgs),
    /// Write synthetic scans of an analytic scene (a virtual scanner) with an .mlp alignment.
    Synth(SynthArgs),
    /// Integrate a depth-camera stream (depth frames + trajectory) into an AO voxel grid.
    Stream(super::stream::StreamArgs),
}

/// Flags of `mvao merge`.
#[derive(Debug, Args)]
pub struct MergeArgs {
    /// Input scans: PLY, LAS/LAZ, E57 (any number of scans per file), PTX.
    #[arg(required = true)]
    pub scans: Vec<PathBuf>,
    /// How the scans are placed.
    #[command(flatten)]
    pub place: PlaceArgs,
    /// Output directory.
    #[arg(short, long, default_value = "mvao-out")]
    pub output: PathBuf,
    /// Output format [default: the input's; PTX → ply].
    #[arg(long, value_enum)]
    pub format: Option<Format>,
    /// SSAO sampling-sphere radius r_s in metres [default: sqrt(point spacing × robust
    /// scene diagonal), within diagonal/100 and diagonal/10].
    #[arg(long)]
    pub radius: Option<f32>,
    /// Obscurance falloff distance t_max in metres, or `inf` for plain ambient occlusion
    /// (what pymeshlab computes) [default: 2 × radius].
    #[arg(long, value_parser = tmax_flag)]
    pub tmax: Option<f32>,
    /// Shape of the falloff ρ below t_max: smoothstep, linear, none, or exp:METRES (decay
    /// length). `--tmax inf --falloff none` is plain ambient occlusion.
    #[arg(long, default_value = "smoothstep", value_parser = Falloff::parse)]
    pub falloff: Falloff,
    /// SSAO samples per pixel.
    #[arg(long, default_value_t = 32, value_parser = clap::value_parser!(u32).range(1..=4096))]
    pub samples: u32,
    /// Horizon estimator: azimuthal directions per pixel.
    #[arg(long, default_value_t = 8, value_parser = clap::value_parser!(u32).range(1..=256))]
    pub directions: u32,
    /// Horizon estimator: steps marched per direction.
    #[arg(long, default_value_t = 8, value_parser = clap::value_parser!(u32).range(1..=1024))]
    pub steps: u32,
    /// Merge neighbourhood N (N×N pixels per view): 1, 3, 5, 7 or 9.
    #[arg(long, default_value_t = 1, value_parser = parse_neighbors)]
    pub neighbors: u32,
    /// d_min of the distance weight, metres [default: smallest depth over all scans].
    #[arg(long)]
    pub dmin: Option<f32>,
    /// d_max of the distance weight, metres [default: largest depth over all scans].
    #[arg(long)]
    pub dmax: Option<f32>,
    /// Border-weight threshold t_p in pixels.
    #[arg(long, default_value_t = 64.0)]
    pub border_px: f32,
    /// Spacing weight κ: a view whose point spacing at the match exceeds κ·t_max counts less
    /// (a sharp near view outweighs coarse far ones); 0 = the paper's weights only.
    #[arg(long, default_value_t = ComputeParams::default().spacing_weight)]
    pub spacing_weight: f32,
    /// Gamma of the grey colours and previews (grey = ao^(1/gamma)); the `ao` scalar stays linear.
    #[arg(long, default_value_t = 1.0)]
    pub gamma: f32,
    /// Seed of the SSAO sample patterns (same seed, same output).
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Sensor model per scan.
    #[arg(long, value_enum, default_value_t = ProjectionChoice::Auto)]
    pub projection: ProjectionChoice,
    /// Per-view AO estimator.
    #[arg(long, value_enum, default_value_t = Estimator::Horizon)]
    pub estimator: Estimator,
    /// Horizon march density: every pixel (`uniform`), or once per 2×2 or 4×4 block on flat,
    /// continuous surfaces small against t_max (`adaptive`; at `--tmax inf` up to 16×16, by
    /// the distance to the nearest occluder).
    #[arg(long, value_enum, default_value_t = Sampling::Adaptive)]
    pub sampling: Sampling,
    /// Write each scan's single-view SSAO instead of the multi-view merge.
    #[arg(long)]
    pub ssao_only: bool,
    /// How views combine: `average` their finished AO per point, march each point's rays
    /// through the geometry of the views that overlap it (`union`, `--union-views`), or
    /// `auto`: the union for the points of all-round stations at `--tmax inf`, the average
    /// elsewhere.
    #[arg(long, value_enum, default_value_t = Occlusion::Auto)]
    pub occlusion: Occlusion,
    /// Rays per point of the union and the bent normals [default: 8 for the union `auto`
    /// runs at `--tmax inf`, else 32].
    #[arg(long, value_parser = clap::value_parser!(u32).range(2..=4096))]
    pub rays: Option<u32>,
    /// Depth behind an observed surface taken as solid by `--occlusion union`, metres
    /// [default: radius / 10].
    #[arg(long)]
    pub thickness: Option<f32>,
    /// Radius in pixels of the edge-aware smoothing of `--occlusion union`'s values (and bent
    /// normals) over each scan's own map, pooling neighbours' rays on the same surface (0:
    /// off).
    #[arg(long, default_value_t = mvao::UNION_FILTER,
          value_parser = clap::value_parser!(u32).range(0..=16))]
    pub union_filter: u32,
    /// Most views each point's union rays are marched through: its own, then those that
    /// observed the point, finest pixel first (0: every view whose map holds the point).
    #[arg(long, default_value_t = mvao::UNION_VIEWS)]
    pub union_views: u32,
    /// Also write each point's bent normal, the cosine-weighted mean unoccluded direction (by
    /// the union's `--rays` rays), as `bnx bny bnz`: in the file's frame in a PLY written
    /// back, in world coordinates in a result written across formats.
    #[arg(long)]
    pub bent_normals: bool,
    /// What happens to input colours.
    #[arg(long, value_enum, default_value_t = ColorMode::Modulate)]
    pub color: ColorMode,
    /// Skip the 5×5 Gaussian blur of the SSAO maps.
    #[arg(long)]
    pub no_blur: bool,
    /// No PNG preview per scan.
    #[arg(long)]
    pub no_preview: bool,
    /// World axis at the top of the previews: x, y, z, -x, -y or -z (the Stanford scans: y).
    #[arg(long, value_enum, default_value_t = Up::Z, allow_hyphen_values = true)]
    pub up: Up,
    /// Grey levels of the previews: `stretch` spans the 1st–99th percentile of each picture
    /// from black to white; `linear` is grey = AO. The `ao` values and colours are not
    /// affected.
    #[arg(long, value_enum, default_value_t = Tone::Stretch)]
    pub preview_tone: Tone,
    /// Overwrite existing outputs.
    #[arg(long)]
    pub force: bool,
    /// No progress bars or summary.
    #[arg(short, long)]
    pub quiet: bool,
    /// Score the result and the single-view SSAO against this reference directory
    /// (`mvao reference` on the same scans with the same t_max); metrics go to report.json.
    #[arg(long, value_name = "DIR")]
    pub reference: Option<PathBuf>,
    /// Work directory of the per-scan products (EXR maps, manifest) [default: OUTDIR/work].
    /// A rerun reuses every product whose inputs and parameters are unchanged.
    #[arg(long, value_name = "DIR")]
    pub work: Option<PathBuf>,
    /// Memory budget, e.g. 2G, 500M [default: half the machine's memory]. Maps of other
    /// scans are cached within it and loaded again when evicted.
    #[arg(long, value_name = "SIZE", value_parser = parse_size)]
    pub max_memory: Option<u64>,
    /// Only this scan (by name; repeatable): merge it against the prepared products of the
    /// scans it overlaps. With `prepare`: prepare only it.
    #[arg(long, value_name = "SCAN")]
    pub only: Vec<String>,
    /// Print the plan (pairs kept and skipped, memory, work) and stop.
    #[arg(long)]
    pub dry_run: bool,
}

/// `--max-memory`: bytes with an optional K, M, G or T suffix (powers of 1024).
pub fn parse_size(s: &str) -> Result<u64, String> {
    let t = s.trim();
    let (num, mult) = match t.char_indices().last() {
        Some((i, c)) if c.is_ascii_alphabetic() => {
            let m: u64 = match c.to_ascii_uppercase() {
                'K' => 1 << 10,
                'M' => 1 << 20,
                'G' => 1 << 30,
                'T' => 1 << 40,
                'B' => 1,
                _ => return Err(format!("'{s}': unknown size suffix (use K, M, G or T)")),
            };
            (&t[..i], m)
        }
        _ => (t, 1),
    };
    match num.trim().parse::<f64>() {
        Ok(v) if v > 0.0 && v.is_finite() => Ok((v * mult as f64) as u64),
        _ => Err(format!("'{s}' is not a size such as 2G or 512M")),
    }
}

/// Flags of `mvao reference`.
#[derive(Debug, Args)]
pub struct ReferenceArgs {
    /// Input scans (as for `merge`).
    #[arg(required = true)]
    pub scans: Vec<PathBuf>,
    /// How the scans are placed.
    #[command(flatten)]
    pub place: PlaceArgs,
    /// Output directory (`<scan>.ref.ply` per scan and `reference.json`).
    #[arg(short, long)]
    pub output: PathBuf,
    /// Rays per point.
    #[arg(long, default_value_t = 256, value_parser = clap::value_parser!(u32).range(1..=1_000_000))]
    pub rays: u32,
    /// Falloff distance t_max of ρ in metres; `inf` = plain ambient occlusion. Use the same
    /// value as the runs it will score.
    #[arg(long)]
    pub tmax: String,
    /// Shape of the falloff below t_max (as for `merge`); use the runs' own.
    #[arg(long, default_value = "smoothstep", value_parser = Falloff::parse)]
    pub falloff: Falloff,
    /// What the rays hit.
    #[arg(long, value_enum, default_value_t = Geometry::Surfels)]
    pub geometry: Geometry,
    /// Cast at this true surface instead (a triangle mesh, PLY or OBJ, in the scans' world
    /// frame: a reconstruction or a model of the site). Each point is moved to the nearest
    /// point of the surface and takes that face's normal; points farther than
    /// --surface-tolerance are written with on_surface 0 and not scored.
    #[arg(long, value_name = "MESH", conflicts_with = "geometry")]
    pub surface: Option<PathBuf>,
    /// Largest distance (metres) from a point to --surface for it to be scored [default: 4 ×
    /// the point's radius rad(p)].
    #[arg(long, value_name = "METRES", requires = "surface")]
    pub surface_tolerance: Option<f32>,
    /// Points per scan in the convergence check (R against 4R rays).
    #[arg(long, default_value_t = 2000)]
    pub sample: usize,
    /// Seed of the ray directions.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Sensor model (orients estimated normals).
    #[arg(long, value_enum, default_value_t = ProjectionChoice::Auto)]
    pub projection: ProjectionChoice,
    /// Overwrite existing outputs.
    #[arg(long)]
    pub force: bool,
    /// No progress bar.
    #[arg(short, long)]
    pub quiet: bool,
}

impl ReferenceArgs {
    /// Checks the values and turns them into a [`RefConfig`].
    pub fn into_config(self) -> Result<RefConfig, String> {
        let tmax = parse_tmax(&self.tmax, "tmax")?;
        Ok(RefConfig {
            scans: self.scans,
            place: self.place.options(),
            out_dir: self.output,
            params: RefParams {
                rays: self.rays,
                tmax,
                falloff: self.falloff,
                seed: self.seed,
            },
            geometry: self.geometry,
            surface: self.surface.map(|path| SurfaceSpec {
                path,
                tolerance: self.surface_tolerance,
            }),
            sample: self.sample,
            projection: self.projection,
            force: self.force,
        })
    }
}

/// `--tmax` of `merge`, `prepare` and `sweep`: a positive number of metres or `inf`.
fn tmax_flag(s: &str) -> Result<f32, String> {
    parse_tmax(s, "tmax")
}

/// Flags of `mvao eval`.
#[derive(Debug, Args)]
pub struct EvalArgs {
    /// Result files: PLY with a per-vertex `ao`, named `<scan>.<anything>.ply`.
    #[arg(required = true)]
    pub results: Vec<PathBuf>,
    /// Reference directory.
    #[arg(long, value_name = "DIR")]
    pub reference: PathBuf,
    /// Append a row to this sweep CSV.
    #[arg(long, value_name = "FILE")]
    pub csv: Option<PathBuf>,
    /// `dataset` column of the CSV row.
    #[arg(long, default_value = "")]
    pub dataset: String,
    /// `method` (and `estimator`) column of the CSV row, e.g. pymeshlab.
    #[arg(long, default_value = "external")]
    pub method: String,
    /// `directions` column (the method's budget, e.g. rays per point).
    #[arg(long, default_value_t = 0)]
    pub directions: u32,
    /// `wall_s` column: the method's run time in seconds.
    #[arg(long, default_value_t = 0.0)]
    pub wall_s: f64,
    /// `tmax` column (inf for plain ambient occlusion).
    #[arg(long, default_value = "inf")]
    pub tmax: String,
    /// Print JSON instead of one line per scan.
    #[arg(long)]
    pub json: bool,
}

/// Flags of `mvao sweep`.
#[derive(Debug, Args)]
pub struct SweepArgs {
    /// Input scans (as for `merge`).
    #[arg(required = true)]
    pub scans: Vec<PathBuf>,
    /// How the scans are placed.
    #[command(flatten)]
    pub place: PlaceArgs,
    /// Reference directory (`mvao reference` with the same t_max).
    #[arg(long, value_name = "DIR")]
    pub reference: PathBuf,
    /// Output directory (`sweep.csv`, `sweep.svg`).
    #[arg(short, long)]
    pub output: PathBuf,
    /// Name of the dataset in the CSV and plot title.
    #[arg(long, default_value = "dataset")]
    pub dataset: String,
    /// SSAO radius in metres [default: as `merge`'s].
    #[arg(long)]
    pub radius: Option<f32>,
    /// t_max in metres or `inf` [default: 2 × radius]; must match the reference's.
    #[arg(long, value_parser = tmax_flag)]
    pub tmax: Option<f32>,
    /// Falloff below t_max (as for `merge`); must match the reference's.
    #[arg(long, default_value = "smoothstep", value_parser = Falloff::parse)]
    pub falloff: Falloff,
    /// Seed.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Horizon march density of every setting of the sweep (`uniform` or `adaptive`, as for
    /// `merge`).
    #[arg(long, value_enum, default_value_t = Sampling::Adaptive)]
    pub sampling: Sampling,
    /// Also run the union occlusion (`merge --occlusion union`) with every horizon setting, at
    /// each of these rays per point (comma-separated).
    #[arg(long, value_name = "K,...", value_delimiter = ',',
          value_parser = clap::value_parser!(u32).range(2..=4096))]
    pub union_rays: Vec<u32>,
    /// Fewer settings (paper 16/32, horizon 4×4/8×8; N = 1, 3): a quick look.
    #[arg(long)]
    pub quick: bool,
    /// Overwrite existing outputs.
    #[arg(long)]
    pub force: bool,
}

/// Flags of `mvao plot`.
#[derive(Debug, Args)]
pub struct PlotArgs {
    /// A sweep CSV (rows added by scripts included).
    pub csv: PathBuf,
    /// Output SVG [default: the CSV's name with .svg].
    #[arg(short, long)]
    pub output: Option<PathBuf>,
    /// Title.
    #[arg(long, default_value = "e_A against wall time")]
    pub title: String,
}

/// How scans are placed in world coordinates (shared by `merge`, `info`, `reference`).
#[derive(Debug, Args, Clone)]
pub struct PlaceArgs {
    /// Alignment: Stanford .conf, MeshLab .mlp or .aln, or JSON {"file": [16 numbers
    /// row-major]}. Default: the one such file beside the scans, if exactly one exists.
    /// A scan with a sidecar matrix (scan.txt or scan.mat, 16 numbers row-major beside it)
    /// takes that instead.
    #[arg(long)]
    pub align: Option<PathBuf>,
    /// Place one scan by a 4×4 matrix file (scan → world), overriding every other pose of it.
    /// SCAN is a scan name, file name or stem. Repeatable.
    #[arg(long = "pose", value_name = "SCAN=FILE")]
    pub poses: Vec<PoseOverride>,
    /// Accept poses with scale or shear (applied to the points; the scanner stays put).
    #[arg(long)]
    pub allow_scale: bool,
}

impl PlaceArgs {
    /// The library's placement options.
    pub fn options(&self) -> PlaceOptions {
        PlaceOptions {
            align: self.align.clone(),
            poses: self.poses.clone(),
            allow_scale: self.allow_scale,
        }
    }
}

/// Flags of `mvao info`.
#[derive(Debug, Args)]
pub struct InfoArgs {
    /// Scan files.
    #[arg(required = true)]
    pub scans: Vec<PathBuf>,
    /// How the scans are placed.
    #[command(flatten)]
    pub place: PlaceArgs,
    /// Sensor model `merge` would use (auto fits the grid or the points).
    #[arg(long, value_enum, default_value_t = ProjectionChoice::Auto)]
    pub projection: ProjectionChoice,
    /// Print JSON instead of text.
    #[arg(long)]
    pub json: bool,
}

fn parse_neighbors(s: &str) -> Result<u32, String> {
    match s.parse::<u32>() {
        Ok(n @ (1 | 3 | 5 | 7 | 9)) => Ok(n),
        _ => Err(format!("'{s}' is not one of 1, 3, 5, 7, 9")),
    }
}

/// Sensor models of `mvao synth`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum ModelArg {
    /// Terrestrial laser scanner.
    Equirect,
    /// Camera.
    Perspective,
    /// Linear sweep.
    Ortho,
}

impl From<ModelArg> for SensorModel {
    fn from(m: ModelArg) -> Self {
        match m {
            ModelArg::Equirect => SensorModel::Equirect,
            ModelArg::Perspective => SensorModel::Perspective,
            ModelArg::Ortho => SensorModel::Ortho,
        }
    }
}

/// Stations to a room of `mvao synth --scene suite`.
pub const STATIONS_PER_ROOM: usize = 4;

/// Flags of `mvao synth`.
#[derive(Debug, Args)]
pub struct SynthArgs {
    /// Scene: room, courtyard, suite (analytic); colonnade, vault, relief, porch (built-in
    /// meshes); or a PLY/OBJ triangle mesh file (world coordinates, metres, z up).
    #[arg(long, default_value = "room", value_name = "NAME|FILE")]
    pub scene: String,
    /// Number of scanner stations.
    #[arg(long, default_value_t = 3, value_parser = clap::value_parser!(u32).range(1..=1000))]
    pub stations: u32,
    /// Sensor model of every station.
    #[arg(long, value_enum, default_value_t = ModelArg::Equirect)]
    pub projection: ModelArg,
    /// Map width in pixels [default: equirect 1440, perspective/ortho 1024].
    #[arg(long, default_value_t = 0, hide_default_value = true)]
    pub width: usize,
    /// Map height in pixels [default: equirect 720, perspective/ortho 768].
    #[arg(long, default_value_t = 0, hide_default_value = true)]
    pub height: usize,
    /// Gaussian range noise sigma, metres. With --frames, a scale of the structured-light
    /// camera's depth-dependent noise instead (0 or unset = 1, the camera as modelled).
    #[arg(long, default_value_t = 0.0)]
    pub noise: f64,
    /// Seed of the noise.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Output directory.
    #[arg(short, long)]
    pub output: PathBuf,
    /// Also write the reference obscurance against the exact analytic geometry into
    /// OUTPUT/reference-analytic/ with this many rays per point (needs --reference-tmax).
    #[arg(long, value_name = "RAYS")]
    pub reference_rays: Option<u32>,
    /// t_max (metres, or inf) of the analytic reference.
    #[arg(long, value_name = "T", default_value = "inf")]
    pub reference_tmax: String,
    /// Falloff of the analytic reference below its t_max (as for `merge`).
    #[arg(long, default_value = "smoothstep", value_parser = Falloff::parse)]
    pub reference_falloff: Falloff,
    // Mesh scenes.
    /// Mesh scenes: a station position `X,Y,Z` (repeat for more; used in turn).
    #[arg(long = "at", value_name = "X,Y,Z", value_parser = parse_xyz, allow_hyphen_values = true)]
    pub at: Vec<DVec3>,
    /// Mesh scenes: where perspective stations look (`X,Y,Z`).
    #[arg(long, value_name = "X,Y,Z", value_parser = parse_xyz, allow_hyphen_values = true)]
    pub look_at: Option<DVec3>,
    /// Mesh scenes: registration error put into each station's pose, `METRES,DEGREES` (a
    /// random rigid shift and rotation of exactly that size per station).
    #[arg(long, value_name = "M,DEG", default_value = "0,0")]
    pub registration_error: String,
    /// Leave the exact normals out of the scans.
    #[arg(long)]
    pub no_normals: bool,
    /// Leave each point's row and column out of the scans (as many exports do).
    #[arg(long)]
    pub no_grid: bool,
    /// Write a depth-camera stream of this many frames instead of scans (the room, or a mesh
    /// scene: the camera orbits the --look-at point through the first --at position, else the
    /// built-in scene's first station): structured-light noise, 16-bit PNG frames,
    /// trajectory.log, intrinsics.txt and, with --reference-rays, the ground truth per pixel in
    /// truth/.
    #[arg(long, default_value_t = 0)]
    pub frames: u32,
}

/// `X,Y,Z` as a finite point.
fn parse_xyz(s: &str) -> Result<DVec3, String> {
    let v: Vec<f64> = s
        .split(',')
        .map(|t| t.trim().parse::<f64>())
        .collect::<Result<_, _>>()
        .map_err(|_| format!("'{s}' is not X,Y,Z"))?;
    match v[..] {
        [x, y, z] if x.is_finite() && y.is_finite() && z.is_finite() => Ok(DVec3::new(x, y, z)),
        _ => Err(format!("'{s}' is not X,Y,Z")),
    }
}

impl SynthArgs {
    /// Checks the values and turns them into the virtual scanner's options.
    pub fn into_options(self) -> Result<SynthOptions, String> {
        let reference = match self.reference_rays {
            Some(r) => Some(RefParams {
                rays: r.max(1),
                tmax: parse_tmax(&self.reference_tmax, "reference-tmax")?,
                falloff: self.reference_falloff,
                seed: 0,
            }),
            None => None,
        };
        let (scene, mesh) = match self.scene.to_ascii_lowercase().as_str() {
            "room" => (SceneKind::Room, None),
            "courtyard" => (SceneKind::Courtyard, None),
            "suite" => (
                SceneKind::Suite {
                    rooms: (self.stations as usize).div_ceil(STATIONS_PER_ROOM),
                },
                None,
            ),
            name => match MeshKind::from_name(name) {
                Some(k) => (SceneKind::Room, Some(MeshSource::Builtin(k))),
                None => (
                    SceneKind::Room,
                    Some(MeshSource::File(PathBuf::from(&self.scene))),
                ),
            },
        };
        let reg: Vec<f64> = self
            .registration_error
            .split(',')
            .map(|t| t.trim().parse::<f64>())
            .collect::<Result<_, _>>()
            .map_err(|_| {
                format!(
                    "--registration-error must be METRES,DEGREES, got '{}'",
                    self.registration_error
                )
            })?;
        let [translation, angle_deg] = reg[..] else {
            return Err(format!(
                "--registration-error must be METRES,DEGREES, got '{}'",
                self.registration_error
            ));
        };
        Ok(SynthOptions {
            scene,
            mesh,
            at: self.at,
            look_at: self.look_at,
            registration: Registration {
                translation,
                angle_deg,
            },
            normals: !self.no_normals,
            grid: !self.no_grid,
            stations: self.stations as usize,
            model: self.projection.into(),
            width: self.width,
            height: self.height,
            noise: self.noise,
            seed: self.seed,
            out_dir: self.output,
            reference,
        })
    }
}

impl MergeArgs {
    /// Checks the values and turns them into a [`Config`].
    pub fn into_config(self) -> Result<Config, String> {
        let pos = |name: &str, v: Option<f32>| -> Result<(), String> {
            match v {
                Some(x) if !(x > 0.0 && x.is_finite()) => Err(format!(
                    "--{name} must be a positive number of metres, got {x}"
                )),
                _ => Ok(()),
            }
        };
        pos("radius", self.radius)?;
        pos("dmax", self.dmax)?;
        if let Some(d) = self.dmin {
            if !(d >= 0.0 && d.is_finite()) {
                return Err(format!("--dmin must be ≥ 0 metres, got {d}"));
            }
        }
        if let (Some(a), Some(b)) = (self.dmin, self.dmax) {
            if a >= b {
                return Err(format!("--dmin {a} must be below --dmax {b}"));
            }
        }
        if let Some(t) = self.thickness {
            if !(t > 0.0 && t.is_finite()) {
                return Err(format!("--thickness must be positive metres, got {t}"));
            }
        }
        if !(self.gamma > 0.0 && self.gamma.is_finite()) {
            return Err(format!("--gamma must be positive, got {}", self.gamma));
        }
        if !(self.border_px > 0.0 && self.border_px.is_finite()) {
            return Err(format!(
                "--border-px must be positive, got {}",
                self.border_px
            ));
        }
        if !(self.spacing_weight >= 0.0 && self.spacing_weight.is_finite()) {
            return Err(format!(
                "--spacing-weight must be 0 or positive, got {}",
                self.spacing_weight
            ));
        }
        Ok(Config {
            scans: self.scans,
            place: self.place.options(),
            format: self.format,
            out_dir: self.output,
            compute: ComputeParams {
                radius: self.radius,
                tmax: self.tmax,
                falloff: self.falloff,
                samples: self.samples,
                directions: self.directions,
                steps: self.steps,
                neighbors: self.neighbors,
                dmin: self.dmin,
                dmax: self.dmax,
                border_px: self.border_px,
                spacing_weight: self.spacing_weight,
                seed: self.seed,
                projection: self.projection,
                estimator: self.estimator,
                blur: !self.no_blur,
                sampling: self.sampling,
                ssao_only: self.ssao_only,
                occlusion: self.occlusion,
                rays: self.rays,
                thickness: self.thickness,
                union_filter: self.union_filter,
                union_views: self.union_views,
                bent_normals: self.bent_normals,
            },
            gamma: self.gamma,
            color: self.color,
            quiet: self.quiet,
            preview: !self.no_preview,
            preview_style: PreviewStyle {
                up: self.up,
                tone: self.preview_tone,
            },
            force: self.force,
            reference: self.reference,
            work_dir: self.work,
            max_memory: self.max_memory,
            only: self.only,
            dry_run: self.dry_run,
            prepare_only: false,
        })
    }
}
