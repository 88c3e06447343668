//! The `mvao stream` job over files: frames, intrinsics and trajectory in; the voxel points
//! (PLY, LAS/LAZ or E57), `report.json` and a preview out. A checkpoint of the grid is
//! written every few frames so that a killed run resumes where it stopped.

use super::frames::{self, Intrinsics};
use super::grid::{self, CheckpointHead};
use super::{history, FrameStats, Integrator, StageTimes, StreamParams};
use crate::error::{Error, Result};
use crate::io::output::grey;
use crate::io::raw::PointTable;
use crate::io::source::Format;
use crate::preview::{Orientation, Picture, Tone};
use crate::progress::Observer;
use glam::DMat4;
use serde::Serialize;
use std::path::{Path, PathBuf};
use std::time::Instant;

/// Everything `mvao stream` needs, checked.
#[derive(Debug, Clone)]
pub struct StreamConfig {
    /// Depth frames (PNG files or folders of them).
    pub inputs: Vec<PathBuf>,
    /// Trajectory file (`.log` or TUM).
    pub trajectory: PathBuf,
    /// Camera intrinsics.
    pub intrinsics: Intrinsics,
    /// PNG units per metre (1000 = millimetres).
    pub depth_scale: f64,
    /// Integration settings.
    pub params: StreamParams,
    /// Output directory.
    pub out_dir: PathBuf,
    /// Output format of the voxel points.
    pub format: Format,
    /// Gamma of the grey colours.
    pub gamma: f32,
    /// Write a preview picture.
    pub preview: bool,
    /// Frames between checkpoints (0 = none).
    pub checkpoint_every: usize,
    /// Largest gap (seconds) between a frame's name and a TUM timestamp.
    pub max_dt: f64,
}

/// A frame left out, and why.
#[derive(Debug, Clone, Serialize)]
pub struct DroppedFrame {
    /// The frame file.
    pub frame: PathBuf,
    /// Why.
    pub reason: String,
}

/// `report.json` of a stream.
#[derive(Debug, Clone, Serialize)]
pub struct StreamReport {
    /// Frames given.
    pub frames: usize,
    /// Frames integrated in this run (fewer than given after a resume).
    pub frames_this_run: usize,
    /// Frame at which the run resumed from a checkpoint, if it did.
    pub resumed_at: Option<usize>,
    /// Frames left out.
    pub dropped: Vec<DroppedFrame>,
    /// Occupied voxels with a positive weight (= output points).
    pub voxels: usize,
    /// Pixels integrated over all frames of this run.
    pub pixels_integrated: u64,
    /// Samples whose voxel lies beyond the keyed range.
    pub out_of_range: u64,
    /// Total weight, and the smallest, median and largest voxel weight.
    pub weights: WeightSummary,
    /// Bytes of the voxel table (and the history volume) per occupied voxel.
    pub bytes_per_voxel: f64,
    /// The history volume, when the run has one.
    pub history_volume: Option<VolumeSummary>,
    /// Settings.
    pub params: StreamParams,
    /// Seconds per stage (this run).
    pub times: StageTimes,
    /// Seconds writing the outputs.
    pub write_s: f64,
    /// Wall time of the run (seconds).
    pub wall_s: f64,
    /// Frames integrated per second of wall time (this run).
    pub frames_per_s: f64,
    /// The output file.
    pub output: PathBuf,
}

/// The history's distance volume in `report.json`.
#[derive(Debug, Clone, Serialize)]
pub struct VolumeSummary {
    /// Voxel edge (metres).
    pub voxel: f64,
    /// Truncation distance (metres).
    pub truncation: f64,
    /// Allocated blocks of 4 × 4 × 4 voxels.
    pub blocks: usize,
    /// Voxels observed at least once.
    pub observed_voxels: usize,
    /// Bytes held.
    pub bytes: usize,
}

/// Voxel weights.
#[derive(Debug, Clone, Default, Serialize)]
pub struct WeightSummary {
    /// Σ over voxels.
    pub total: f64,
    /// Smallest.
    pub min: f64,
    /// Median.
    pub median: f64,
    /// Largest.
    pub max: f64,
}

/// Runs a stream: reads every frame in order, integrates it, writes the outputs.
pub fn run(cfg: &StreamConfig, obs: &dyn Observer) -> Result<StreamReport> {
    let start = Instant::now();
    let files = frames::list_frames(&cfg.inputs)?;
    if files.is_empty() {
        return Err(Error::Param("no depth frame given".into()));
    }
    for f in &files {
        if !f.is_file() {
            return Err(Error::io(
                f,
                std::io::Error::new(std::io::ErrorKind::NotFound, "depth frame not found"),
            ));
        }
    }
    let traj = frames::read_trajectory(&cfg.trajectory)?;
    let poses = frames::match_poses(&files, &traj, &cfg.trajectory, cfg.max_dt)?;
    std::fs::create_dir_all(&cfg.out_dir).map_err(|e| Error::io(&cfg.out_dir, e))?;
    let ck_path = cfg.out_dir.join("stream.checkpoint");
    let settings = settings_hash(cfg, &files);
    let mut integ = Integrator::new(cfg.params, cfg.intrinsics);
    let mut first = 0usize;
    if ck_path.is_file() {
        let (g, volume, head) = grid::read_checkpoint(&ck_path)?;
        // A checkpoint of an earlier layout has no history volume to continue from.
        let complete = volume.is_some() || !cfg.params.history || head.frames_done == 0;
        if head.settings == settings && (head.frames_done as usize) <= files.len() && complete {
            integ.grid = g;
            integ.volume = volume;
            first = head.frames_done as usize;
            obs.info(&format!("resuming from frame {first} of {}", files.len()));
        }
    }
    let resumed_at = (first > 0).then_some(first);
    let mut dropped = Vec::new();
    let mut size: Option<(usize, usize)> = None;
    let mut pixels = 0u64;
    obs.stage("frames", (files.len() - first) as u64);
    for (i, (f, pose)) in files.iter().zip(&poses).enumerate().skip(first) {
        let t = Instant::now();
        let frame = frames::read_depth_png(f, cfg.depth_scale)?;
        integ.times.read += t.elapsed().as_secs_f64();
        let dims = (frame.width, frame.height);
        if *size.get_or_insert(dims) != dims {
            return Err(Error::format(
                f,
                format!(
                    "{}×{} pixels, the stream's first frame has {}×{}",
                    dims.0,
                    dims.1,
                    size.map_or(0, |s| s.0),
                    size.map_or(0, |s| s.1)
                ),
            ));
        }
        let st: FrameStats = integ.add_frame(&frame, *pose);
        pixels += st.integrated;
        if st.integrated == 0 {
            let reason = if st.measured == 0 {
                "no measured pixel"
            } else if st.kept == 0 {
                "every pixel removed by the cleaning"
            } else {
                "no pixel with a normal, an SSAO value and a positive weight"
            };
            dropped.push(DroppedFrame {
                frame: f.clone(),
                reason: reason.into(),
            });
        }
        obs.advance(1);
        let done = i + 1;
        if cfg.checkpoint_every > 0 && done % cfg.checkpoint_every == 0 && done < files.len() {
            let head = CheckpointHead {
                frames_done: done as u64,
                settings,
            };
            grid::write_checkpoint(&ck_path, &integ.grid, integ.volume.as_ref(), head)?;
        }
    }
    obs.done("frames", start.elapsed().as_secs_f64());
    let frames_this_run = files.len() - first;
    let t = Instant::now();
    let output = cfg
        .out_dir
        .join(format!("stream.{}", extension(cfg.format)));
    let points = write_points(cfg, &integ, &output)?;
    if cfg.preview {
        let mid = poses.len() / 2;
        let dims = size.unwrap_or((640, 480));
        write_preview(
            &cfg.out_dir.join("stream.png"),
            &integ,
            poses[mid],
            dims,
            cfg.gamma,
        )?;
    }
    let write_s = t.elapsed().as_secs_f64();
    let wall_s = start.elapsed().as_secs_f64();
    let report = StreamReport {
        frames: files.len(),
        frames_this_run,
        resumed_at,
        dropped,
        voxels: points,
        pixels_integrated: pixels,
        out_of_range: integ.grid.out_of_range,
        weights: weights(&integ),
        bytes_per_voxel: integ.bytes() as f64 / integ.grid.len().max(1) as f64,
        history_volume: integ.volume.as_ref().map(|v| VolumeSummary {
            voxel: v.voxel,
            truncation: v.mu,
            blocks: v.blocks.len(),
            observed_voxels: v.observed(),
            bytes: v.bytes(),
        }),
        params: cfg.params,
        times: integ.times.clone(),
        write_s,
        wall_s,
        frames_per_s: frames_this_run as f64 / wall_s.max(1e-9),
        output,
    };
    let json =
        serde_json::to_string_pretty(&report).map_err(|e| Error::Param(format!("report: {e}")))?;
    let rp = cfg.out_dir.join("report.json");
    crate::io::atomic::write_atomic(&rp, |w| std::io::Write::write_all(w, json.as_bytes()))?;
    if ck_path.is_file() {
        std::fs::remove_file(&ck_path).map_err(|e| Error::io(&ck_path, e))?;
    }
    Ok(report)
}

fn extension(f: Format) -> &'static str {
    match f {
        Format::Ply | Format::Ptx => "ply",
        Format::Las => "las",
        Format::Laz => "laz",
        Format::E57 => "e57",
    }
}

/// A hash of what decides the result: the settings and the frame list, so a checkpoint
/// of another run is not resumed.
pub fn settings_hash(cfg: &StreamConfig, files: &[PathBuf]) -> u64 {
    let text = format!(
        "{:?}|{:?}|{}|{:?}|{:?}",
        cfg.params, cfg.intrinsics, cfg.depth_scale, files, cfg.trajectory
    );
    xxhash_rust::xxh3::xxh3_64(text.as_bytes())
}

fn weights(integ: &Integrator) -> WeightSummary {
    let mut w: Vec<f64> = integ
        .grid
        .iter()
        .map(|(_, c)| c.w)
        .filter(|w| *w > 0.0)
        .collect();
    if w.is_empty() {
        return WeightSummary::default();
    }
    w.sort_unstable_by(f64::total_cmp);
    WeightSummary {
        total: w.iter().sum(),
        min: w[0],
        median: w[w.len() / 2],
        max: w[w.len() - 1],
    }
}

/// Writes one point per voxel: mean position, grey colour from the AO, `ao`, the mean
/// normal and the weight as extra fields. Returns the number of points.
fn write_points(cfg: &StreamConfig, integ: &Integrator, path: &Path) -> Result<usize> {
    let pts = integ.grid.points();
    let col = |f: fn(&grid::VoxelPoint) -> f64| pts.iter().map(f).collect::<Vec<f64>>();
    let table = PointTable {
        name: "stream".into(),
        xyz: pts.iter().map(|p| p.position.to_array()).collect(),
        pose: DMat4::IDENTITY,
        rgb: Some(pts.iter().map(|p| [grey(p.ao, cfg.gamma); 3]).collect()),
        intensity: None,
        ao: pts.iter().map(|p| p.ao).collect(),
        grid: None,
        extra: vec![
            ("nx".into(), col(|p| p.normal.x as f64)),
            ("ny".into(), col(|p| p.normal.y as f64)),
            ("nz".into(), col(|p| p.normal.z as f64)),
            ("weight".into(), col(|p| p.weight)),
        ],
    };
    match cfg.format {
        Format::Ply | Format::Ptx => {
            crate::io::results::write_table_ply(&table, "mvao stream: one point per voxel", path)?;
        }
        Format::Las | Format::Laz => {
            crate::io::las::write_table_las(&table, path, cfg.format == Format::Laz)?;
        }
        Format::E57 => crate::io::e57::write_table_e57(&[table], path)?,
    }
    Ok(pts.len())
}

/// The AO grid rendered from `pose` at the frames' size, as a grey picture.
fn write_preview(
    path: &Path,
    integ: &Integrator,
    pose: DMat4,
    (w, h): (usize, usize),
    gamma: f32,
) -> Result<()> {
    let (geo, ao) = history::render(&integ.grid, pose, &integ.intrinsics, w, h, 0.0);
    let pic = Picture {
        width: w,
        height: h,
        values: (0..w * h)
            .map(|i| {
                if geo.points[i].z > 0.0 {
                    ao[i]
                } else {
                    f32::NAN
                }
            })
            .collect(),
    };
    let (pw, ph, buf) = pic.cropped().fitted().despeckled().grey_alpha(
        Tone::Stretch,
        gamma,
        Orientation::default(),
    );
    crate::preview::write_png(path, pw, ph, &buf)
}
