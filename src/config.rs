//! The configuration of a run: what `mvao merge` and `mvao prepare` were asked to do (validated
//! by the command line) and the parameters of the computation every stage reads. Depends on
//! nothing but the small parameter types of the modules it configures.

use crate::falloff::Falloff;
use crate::io::dataset::PlaceOptions;
use crate::io::output::ColorMode;
use crate::io::source::Format;
use crate::sensor::ProjectionChoice;
use crate::ssao::Estimator;
use std::path::PathBuf;

/// Everything `mvao merge` needs, validated (see the CLI for meanings and units).
#[derive(Debug, Clone)]
pub struct Config {
    /// Input scans.
    pub scans: Vec<PathBuf>,
    /// How the scans are placed (alignment file, `--pose`, `--allow-scale`).
    pub place: PlaceOptions,
    /// Output format; `None` follows each input.
    pub format: Option<Format>,
    /// Output directory.
    pub out_dir: PathBuf,
    /// The computation's parameters.
    pub compute: ComputeParams,
    /// Gamma of grey colours and previews.
    pub gamma: f32,
    /// What happens to input colours.
    pub color: ColorMode,
    /// No progress bars.
    pub quiet: bool,
    /// Write a PNG preview per scan.
    pub preview: bool,
    /// How previews are drawn (up axis, tone).
    pub preview_style: crate::preview::PreviewStyle,
    /// Overwrite existing outputs.
    pub force: bool,
    /// Reference directory to score the result against.
    pub reference: Option<PathBuf>,
    /// Work directory for per-scan products; `None` = `OUTDIR/work`.
    pub work_dir: Option<PathBuf>,
    /// Memory budget in bytes; `None` = half the machine's memory.
    pub max_memory: Option<u64>,
    /// Only these scans (by name): prepare them, or merge them against their partners.
    pub only: Vec<String>,
    /// Print the plan and stop.
    pub dry_run: bool,
    /// Stop after preparing the products (`mvao prepare`).
    pub prepare_only: bool,
}

/// Parameters of the in-memory computation (no files).
#[derive(Debug, Clone)]
pub struct ComputeParams {
    /// SSAO radius; `None` = scene diagonal / 50.
    pub radius: Option<f32>,
    /// t_max (`f32::INFINITY` = plain ambient occlusion); `None` = 2·radius.
    pub tmax: Option<f32>,
    /// Shape of ρ below t_max.
    pub falloff: Falloff,
    /// Samples per pixel (paper estimator).
    pub samples: u32,
    /// Directions per pixel (horizon estimator).
    pub directions: u32,
    /// Steps per direction (horizon estimator).
    pub steps: u32,
    /// Merge neighbourhood N.
    pub neighbors: u32,
    /// d_min override.
    pub dmin: Option<f32>,
    /// d_max override.
    pub dmax: Option<f32>,
    /// t_p.
    pub border_px: f32,
    /// κ of the spacing weight (0 = off).
    pub spacing_weight: f32,
    /// Seed.
    pub seed: u64,
    /// Sensor model choice.
    pub projection: ProjectionChoice,
    /// Estimator.
    pub estimator: Estimator,
    /// Blur SSAO maps.
    pub blur: bool,
    /// Evaluation density of the horizon march.
    pub sampling: crate::ssao::Sampling,
    /// Skip the merge (MVAO = own SSAO).
    pub ssao_only: bool,
    /// How the merge combines the views.
    pub occlusion: crate::merge::union::Occlusion,
    /// Rays per point of the union occlusion and the bent normals; `None` = by the mode
    /// ([`crate::merge::union::AUTO_RAYS`] for the union `auto` runs, else
    /// [`crate::merge::union::UNION_RAYS`]).
    pub rays: Option<u32>,
    /// Thickness behind observed surfaces (union); `None` = a tenth of the SSAO radius.
    pub thickness: Option<f32>,
    /// Radius in pixels of the union's edge-aware smoothing over each scan's map (0: none).
    pub union_filter: u32,
    /// Most views a point's union rays are marched through (0: every view holding it).
    pub union_views: u32,
    /// Compute each point's bent normal.
    pub bent_normals: bool,
}

impl Default for ComputeParams {
    fn default() -> Self {
        ComputeParams {
            radius: None,
            tmax: None,
            falloff: Falloff::Smoothstep,
            samples: 32,
            directions: 8,
            steps: 8,
            neighbors: 1,
            dmin: None,
            dmax: None,
            border_px: 64.0,
            spacing_weight: crate::merge::weights::SPACING_WEIGHT,
            seed: 0,
            projection: ProjectionChoice::Auto,
            estimator: Estimator::Horizon,
            blur: true,
            sampling: crate::ssao::Sampling::Adaptive,
            ssao_only: false,
            occlusion: crate::merge::union::Occlusion::Auto,
            rays: None,
            thickness: None,
            union_filter: crate::merge::union::FILTER_RADIUS,
            union_views: crate::merge::union::MAX_VIEWS,
            bent_normals: false,
        }
    }
}
