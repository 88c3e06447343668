//! Flags of `mvao stream` and the command itself: depth frames + trajectory → AO voxel grid.

use super::bars::Bars;
use clap::Args;
use mvao::falloff::Falloff;
use mvao::io::source::Format;
use mvao::stream::clean::CleanParams;
use mvao::stream::frames::parse_intrinsics;
use mvao::stream::{StreamConfig, StreamParams};
use mvao::Estimator;
use std::path::PathBuf;

/// Flags of `mvao stream`.
#[derive(Debug, Args)]
pub struct StreamArgs {
    /// Depth frames: 16-bit PNG files, or folders of them (taken in name order).
    #[arg(required = true)]
    pub frames: Vec<PathBuf>,
    /// Camera trajectory: Open3D/Redwood `.log`, or TUM (`timestamp tx ty tz qx qy qz qw`,
    /// matched to each frame by the timestamp its file name holds, else by order).
    #[arg(long, short = 't', value_name = "FILE")]
    pub trajectory: PathBuf,
    /// Pinhole intrinsics `"fx fy cx cy"` (pixels), or an Open3D camera JSON file.
    #[arg(long, value_name = "\"FX FY CX CY\"|FILE")]
    pub intrinsics: String,
    /// PNG units per metre (1000 = millimetres); 0 in a PNG is no measurement.
    #[arg(long, default_value_t = 1000.0)]
    pub depth_scale: f64,
    /// Voxel edge in metres.
    #[arg(long, default_value_t = 0.01, conflicts_with = "grid")]
    pub voxel: f64,
    /// Voxels along the longest side of `--bounds` (the paper's 512³ grid) instead of
    /// `--voxel`; points outside the bounds are kept all the same.
    #[arg(long, requires = "bounds")]
    pub grid: Option<u32>,
    /// Scene bounds `X0,Y0,Z0,X1,Y1,Z1` (metres) for `--grid`.
    #[arg(long, value_name = "X0,Y0,Z0,X1,Y1,Z1", allow_hyphen_values = true)]
    pub bounds: Option<String>,
    /// Cleaning: drop a pixel whose 8-neighbours' depth differs by more than this (metres).
    #[arg(long, default_value_t = 0.02)]
    pub edge: f32,
    /// Nearest depth kept (metres).
    #[arg(long, default_value_t = 0.1)]
    pub min_range: f32,
    /// Farthest depth kept (metres); also d_max of the distance weight.
    #[arg(long, default_value_t = 8.0)]
    pub max_range: f32,
    /// SSAO radius r_s (metres).
    #[arg(long, default_value_t = 0.2)]
    pub radius: f32,
    /// Falloff distance t_max (metres) [default: 2 × radius].
    #[arg(long)]
    pub tmax: Option<f32>,
    /// Shape of the falloff below t_max (as for `merge`).
    #[arg(long, default_value = "smoothstep", value_parser = Falloff::parse)]
    pub falloff: Falloff,
    /// Per-frame AO estimator (the one `merge` uses).
    #[arg(long, value_enum, default_value_t = Estimator::Horizon)]
    pub estimator: Estimator,
    /// SSAO samples per pixel (paper estimator).
    #[arg(long, default_value_t = 32, value_parser = clap::value_parser!(u32).range(1..=4096))]
    pub samples: u32,
    /// Horizon estimator: directions per pixel.
    #[arg(long, default_value_t = 8, value_parser = clap::value_parser!(u32).range(1..=256))]
    pub directions: u32,
    /// Horizon estimator: steps per direction.
    #[arg(long, default_value_t = 8, value_parser = clap::value_parser!(u32).range(1..=1024))]
    pub steps: u32,
    /// Compute each frame's SSAO at 1/N of its resolution (means of N × N pixel blocks).
    #[arg(long, default_value_t = 4, value_parser = clap::value_parser!(u32).range(1..=8))]
    pub ssao_scale: u32,
    /// SSAO on a depth map ray-cast at each frame's pose from a signed-distance volume of the
    /// frames so far instead of on the frame's own cleaned depth: less noise at full or half
    /// resolution, no gain at the default quarter (without it, the result does not depend on
    /// the frame order).
    #[arg(long)]
    pub history: bool,
    /// Skip the 5×5 blur of each frame's SSAO.
    #[arg(long)]
    pub no_blur: bool,
    /// Seed of the SSAO sample patterns.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Output directory.
    #[arg(short, long, default_value = "mvao-stream")]
    pub output: PathBuf,
    /// Output format of the voxel points.
    #[arg(long, value_enum, default_value_t = Format::Ply)]
    pub format: Format,
    /// Gamma of the grey colours and preview.
    #[arg(long, default_value_t = 1.0)]
    pub gamma: f32,
    /// No preview picture.
    #[arg(long)]
    pub no_preview: bool,
    /// Frames between checkpoints of the grid (0 = none); a rerun resumes from one.
    #[arg(long, default_value_t = 25)]
    pub checkpoint_every: usize,
    /// TUM trajectories: largest gap (seconds) between a frame's timestamp and its pose's.
    #[arg(long, default_value_t = 0.02)]
    pub max_dt: f64,
    /// No progress bar or summary.
    #[arg(short, long)]
    pub quiet: bool,
}

impl StreamArgs {
    /// Checks the values and turns them into a [`StreamConfig`].
    pub fn into_config(self) -> Result<StreamConfig, String> {
        let positive = |name: &str, v: f64| {
            if v > 0.0 && v.is_finite() {
                Ok(())
            } else {
                Err(format!("--{name} must be positive, got {v}"))
            }
        };
        positive("depth-scale", self.depth_scale)?;
        positive("edge", self.edge as f64)?;
        positive("max-range", self.max_range as f64)?;
        positive("radius", self.radius as f64)?;
        if !(self.min_range >= 0.0 && self.min_range < self.max_range) {
            return Err(format!(
                "--min-range {} must be ≥ 0 and below --max-range {}",
                self.min_range, self.max_range
            ));
        }
        let voxel = match (self.grid, &self.bounds) {
            (Some(n), Some(b)) => grid_voxel(n, b)?,
            _ => self.voxel,
        };
        positive("voxel", voxel)?;
        let tmax = self.tmax.unwrap_or(2.0 * self.radius);
        positive("tmax", tmax as f64)?;
        let intrinsics = parse_intrinsics(&self.intrinsics).map_err(|e| e.to_string())?;
        let mut params = StreamParams {
            clean: CleanParams {
                edge: self.edge,
                min_range: self.min_range,
                max_range: self.max_range,
            },
            voxel,
            ssao_scale: self.ssao_scale as usize,
            history: self.history,
            ..StreamParams::default()
        };
        params.ssao.estimator = self.estimator;
        params.ssao.radius = self.radius;
        params.ssao.tmax = tmax;
        params.ssao.falloff = self.falloff;
        params.ssao.samples = self.samples;
        params.ssao.directions = self.directions;
        params.ssao.steps = self.steps;
        params.ssao.seed = self.seed;
        params.ssao.blur = !self.no_blur;
        Ok(StreamConfig {
            inputs: self.frames,
            trajectory: self.trajectory,
            intrinsics,
            depth_scale: self.depth_scale,
            params,
            out_dir: self.output,
            format: self.format,
            gamma: self.gamma,
            preview: !self.no_preview,
            checkpoint_every: self.checkpoint_every,
            max_dt: self.max_dt,
        })
    }
}

/// The voxel edge of `n` voxels along the longest side of bounds `b`.
fn grid_voxel(n: u32, b: &str) -> Result<f64, String> {
    let v: Vec<f64> = b
        .split(',')
        .map(|t| t.trim().parse::<f64>())
        .collect::<Result<_, _>>()
        .map_err(|_| format!("--bounds must be X0,Y0,Z0,X1,Y1,Z1, got '{b}'"))?;
    let [x0, y0, z0, x1, y1, z1] = v[..] else {
        return Err(format!("--bounds must be X0,Y0,Z0,X1,Y1,Z1, got '{b}'"));
    };
    let side = (x1 - x0).max(y1 - y0).max(z1 - z0);
    if !(side > 0.0 && side.is_finite() && n > 0) {
        return Err(format!("--bounds '{b}' has no extent, or --grid is 0"));
    }
    Ok(side / n as f64)
}

/// Runs `mvao stream`.
pub fn run(args: StreamArgs) -> anyhow::Result<()> {
    let quiet = args.quiet;
    let cfg = args.into_config().map_err(anyhow::Error::msg)?;
    let rep = mvao::stream::run(&cfg, &Bars::new(quiet))?;
    if !quiet {
        eprintln!(
            "{} frames ({} dropped), {} voxels in {:.2} s ({:.1} frames/s); {}",
            rep.frames_this_run,
            rep.dropped.len(),
            rep.voxels,
            rep.wall_s,
            rep.frames_per_s,
            rep.output.display()
        );
    }
    Ok(())
}

/// `mvao synth --frames N`: a synthetic depth stream of the room or of a mesh scene with its
/// ground truth.
pub fn synth(args: super::cli::SynthArgs) -> anyhow::Result<()> {
    use mvao::stream::synth::{
        orbit_trajectory, room_trajectory, synth_stream, write_stream, StreamSynthOptions,
    };
    use mvao::synth::{Mesh, MeshScene, MeshSource};
    let truth_tmax = mvao::falloff::parse_tmax(&args.reference_tmax, "reference-tmax")
        .map_err(anyhow::Error::msg)?;
    let o = StreamSynthOptions {
        frames: args.frames as usize,
        width: if args.width > 0 { args.width } else { 640 },
        height: if args.height > 0 { args.height } else { 480 },
        noise: if args.noise > 0.0 { args.noise } else { 1.0 },
        seed: args.seed,
        truth_rays: args.reference_rays.unwrap_or(0),
        truth_tmax,
        truth_falloff: args.reference_falloff,
        ..StreamSynthOptions::default()
    };
    let out = args.output.clone();
    let name = args.scene.clone();
    let opts = args.into_options().map_err(anyhow::Error::msg)?;
    let s = match &opts.mesh {
        None if name.eq_ignore_ascii_case("room") => {
            synth_stream(&mvao::synth::Scene::room(), &room_trajectory(o.frames), &o)
        }
        None => anyhow::bail!(
            "--frames: depth streams are made of the room or a mesh scene (colonnade, vault, \
             relief, porch or a PLY/OBJ file), got --scene {name}"
        ),
        Some(src) => {
            let (mesh, builtin) = match src {
                MeshSource::File(p) => (Mesh::read(p)?, None),
                MeshSource::Builtin(k) => (k.mesh(), Some(k.stations())),
            };
            let (lo, hi) = mesh.bounds();
            let (centre, half) = ((lo + hi) / 2.0, ((hi - lo) / 2.0).length().max(1e-6));
            let target = opts
                .look_at
                .or(builtin.as_ref().map(|b| b.1))
                .unwrap_or(centre);
            let start = opts
                .at
                .first()
                .copied()
                .or(builtin.as_ref().and_then(|b| b.0.first().copied()))
                .unwrap_or(centre + glam::DVec3::new(1.2 * half, 0.0, 0.5 * half));
            let scene = MeshScene::new(&mesh);
            synth_stream(&scene, &orbit_trajectory(target, start, o.frames), &o)
        }
    };
    write_stream(&s, &out)?;
    eprintln!(
        "{} depth frames of {}×{} of {name} written to {}",
        o.frames,
        o.width,
        o.height,
        out.display()
    );
    Ok(())
}
