//! Command-line flags (what the user typed) and their check into a [`Config`]. Opens no files.

use crate::io::dataset::{PlaceOptions, PoseOverride};
use crate::io::output::ColorMode;
use crate::io::source::Format;
use crate::pipeline::{ComputeParams, Config};
use crate::projection::SensorModel;
use crate::sensor::ProjectionChoice;
use crate::ssao::Estimator;
use crate::synth::{SceneKind, SynthOptions};
use clap::{Args, Parser, Subcommand, ValueEnum};
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
    /// Describe scan files: format, points, attributes, pose, grid, sensor model, bounds,
    /// overlaps.
    Info(InfoArgs),
    /// Write synthetic scans of an analytic scene (a virtual scanner) with an .mlp alignment.
    Synth(SynthArgs),
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
    /// SSAO sampling-sphere radius r_s in metres [default: robust scene diagonal / 50].
    #[arg(long)]
    pub radius: Option<f32>,
    /// Obscurance falloff distance t_max in metres [default: 2 × radius].
    #[arg(long)]
    pub tmax: Option<f32>,
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
    #[arg(long, value_enum, default_value_t = Estimator::Paper)]
    pub estimator: Estimator,
    /// Write each scan's single-view SSAO instead of the multi-view merge.
    #[arg(long)]
    pub ssao_only: bool,
    /// What happens to input colours.
    #[arg(long, value_enum, default_value_t = ColorMode::Modulate)]
    pub color: ColorMode,
    /// Skip the 5×5 Gaussian blur of the SSAO maps.
    #[arg(long)]
    pub no_blur: bool,
    /// No PNG preview per scan.
    #[arg(long)]
    pub no_preview: bool,
    /// Overwrite existing outputs.
    #[arg(long)]
    pub force: bool,
    /// No progress bars or summary.
    #[arg(short, long)]
    pub quiet: bool,
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

/// Scenes of `mvao synth`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum SceneArg {
    /// A closed room with furniture, a column and a niche.
    Room,
    /// An open courtyard with an arcade and a fountain.
    Courtyard,
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

/// Flags of `mvao synth`.
#[derive(Debug, Args)]
pub struct SynthArgs {
    /// Scene.
    #[arg(long, value_enum, default_value_t = SceneArg::Room)]
    pub scene: SceneArg,
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
    /// Gaussian range noise sigma, metres.
    #[arg(long, default_value_t = 0.0)]
    pub noise: f64,
    /// Seed of the noise.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Output directory.
    #[arg(short, long)]
    pub output: PathBuf,
}

impl SynthArgs {
    /// The virtual scanner's options.
    pub fn into_options(self) -> SynthOptions {
        SynthOptions {
            scene: match self.scene {
                SceneArg::Room => SceneKind::Room,
                SceneArg::Courtyard => SceneKind::Courtyard,
            },
            stations: self.stations as usize,
            model: self.projection.into(),
            width: self.width,
            height: self.height,
            noise: self.noise,
            seed: self.seed,
            out_dir: self.output,
        }
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
        pos("tmax", self.tmax)?;
        pos("dmax", self.dmax)?;
        if let Some(d) = self.dmin {
            if !(d >= 0.0 && d.is_finite()) {
                return Err(format!("--dmin must be ≥ 0 metres, got {d}"));
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
        Ok(Config {
            scans: self.scans,
            place: self.place.options(),
            format: self.format,
            out_dir: self.output,
            compute: ComputeParams {
                radius: self.radius,
                tmax: self.tmax,
                samples: self.samples,
                directions: self.directions,
                steps: self.steps,
                neighbors: self.neighbors,
                dmin: self.dmin,
                dmax: self.dmax,
                border_px: self.border_px,
                seed: self.seed,
                projection: self.projection,
                estimator: self.estimator,
                blur: !self.no_blur,
                ssao_only: self.ssao_only,
            },
            gamma: self.gamma,
            color: self.color,
            quiet: self.quiet,
            preview: !self.no_preview,
            force: self.force,
        })
    }
}
