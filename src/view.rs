//! The per-view stage functions: one scan's sensor model, normals and radii, G-buffer and
//! border field (its [`ViewGeometry`]), and how the merge reads a [`PreparedView`]. Each sees
//! one scan; the occlusion stage (`pipeline::occlusion`) adds the AO map, and which scans run
//! and where their products live is the pipeline's business.

use crate::error::Result;
use crate::gbuffer::{self, GBuffer, EMPTY};
use crate::merge::cull::ViewCells;
use crate::merge::{MergeParams, View, ViewMaps};
use crate::projection::Projection;
use crate::scan::NO_CELL;
use crate::scan::{normals, Scan};
use crate::sensor::{self, ProjectionChoice, SensorSetup};
use crate::ssao::AoMap;
use glam::Vec3;
use rayon::prelude::*;
use std::time::Instant;

/// One scan's geometry as its own sensor saw it: what the occlusion stage reads.
#[derive(Debug, Clone)]
pub struct ViewGeometry {
    /// Sensor model and map.
    pub sensor: SensorSetup,
    /// The G-buffer.
    pub gbuf: GBuffer,
    /// Distance (pixels) to the nearest depth discontinuity.
    pub border: Vec<f32>,
    /// Radius of each point.
    pub radii: Vec<f32>,
    /// Pixel of each point ([`EMPTY`] if outside the map).
    pub pixel: Vec<u32>,
    /// Depth of each point.
    pub depth: Vec<f32>,
    /// Normals: "input", "estimated", "input, N re-estimated".
    pub normals_note: String,
    /// Wall time of each stage so far (seconds): sensor, normals, gbuffer, border.
    pub times: Vec<(&'static str, f64)>,
}

impl ViewGeometry {
    /// The view with its AO map, computed in `secs` seconds.
    pub fn with_occlusion(self, ssao: AoMap, secs: f64) -> PreparedView {
        let mut times = self.times;
        times.push(("ssao", secs));
        PreparedView {
            sensor: self.sensor,
            gbuf: self.gbuf,
            ssao,
            border: self.border,
            radii: self.radii,
            pixel: self.pixel,
            depth: self.depth,
            normals_note: self.normals_note,
            times,
        }
    }
}

/// One scan after the per-view stages and the occlusion stage.
#[derive(Debug, Clone)]
pub struct PreparedView {
    /// Sensor model and map.
    pub sensor: SensorSetup,
    /// The G-buffer.
    pub gbuf: GBuffer,
    /// SSAO map (blurred).
    pub ssao: AoMap,
    /// Distance (pixels) to the nearest depth discontinuity.
    pub border: Vec<f32>,
    /// Radius of each point.
    pub radii: Vec<f32>,
    /// Pixel of each point ([`EMPTY`] if outside the map).
    pub pixel: Vec<u32>,
    /// Depth of each point.
    pub depth: Vec<f32>,
    /// Normals: "input", "estimated", "input, N re-estimated".
    pub normals_note: String,
    /// Wall time of each per-view stage (seconds): sensor, normals, gbuffer, border, ssao.
    pub times: Vec<(&'static str, f64)>,
}

impl PreparedView {
    /// Each point's SSAO (its pixel's value; 1 for a point outside the map) and whether it
    /// had no valid sample.
    pub fn point_ssao(&self) -> (Vec<f32>, u64) {
        point_values(&self.pixel, &self.ssao.ao, &self.ssao.no_sample)
    }
}

/// Each point's value in a map (`ao` at its pixel; 1 for a point outside the map) and how
/// many points had no valid sample (outside the map, or `no_sample` at their pixel).
pub fn point_values(pixel: &[u32], ao: &[f32], no_sample: &[bool]) -> (Vec<f32>, u64) {
    let mut none = 0u64;
    let v = pixel
        .iter()
        .map(|&px| {
            if px == EMPTY {
                none += 1;
                1.0
            } else {
                none += u64::from(no_sample[px as usize]);
                ao[px as usize]
            }
        })
        .collect();
    (v, none)
}

/// Runs the per-view stages on one scan: its geometry, ready for the occlusion stage.
pub fn view_geometry(scan: &Scan, choice: ProjectionChoice) -> Result<ViewGeometry> {
    let mut times = Vec::with_capacity(5);
    let mut t = Instant::now();
    let mut lap = |name: &'static str, t: &mut Instant| {
        times.push((name, t.elapsed().as_secs_f64()));
        *t = Instant::now();
    };
    let sensor = sensor::setup(scan, choice)?;
    lap("sensor", &mut t);
    let (normals, radii, note) = scan_normals(scan, &sensor);
    let proj: Projection = sensor.projection.clone();
    lap("normals", &mut t);
    let (pixel, depth) = gbuffer::point_pixels(&scan.points, &proj, sensor.grid_pixels.as_deref());
    let gbuf = gbuffer::rasterize(
        proj.width,
        proj.height,
        &pixel,
        &depth,
        &scan.points,
        &normals,
        &radii,
    );
    lap("gbuffer", &mut t);
    let border =
        crate::merge::border::border_distance(&gbuf.depth, gbuf.width, gbuf.height, proj.wrap_x);
    lap("border", &mut t);
    Ok(ViewGeometry {
        sensor,
        gbuf,
        border,
        radii,
        pixel,
        depth,
        normals_note: note,
        times,
    })
}

/// Each point's unit normal (the input's, facing the sensor, or estimated where missing) and
/// radius `rad(p)`, with a note on where the normals came from. Neighbours come from the
/// native grid when the sensor model uses it, else from windows of a grid over the sensor's
/// image ([`sensor_grid`]) where its cells hold at most a point each, else from exact
/// nearest-neighbour queries.
pub fn scan_normals(scan: &Scan, sensor: &SensorSetup) -> (Vec<Vec3>, Vec<f32>, String) {
    let proj: &Projection = &sensor.projection;
    let invalid_normals = scan
        .normals
        .as_ref()
        .map(|n| n.par_iter().filter(|v| *v == &Vec3::ZERO).count());
    let need = invalid_normals.is_none_or(|k| k > 0);
    let toward = |p| proj.toward_sensor(p);
    // A point without a cell has no grid neighbours: then the k-d tree serves every point.
    let grid = scan
        .grid
        .as_ref()
        .filter(|g| sensor.grid_pixels.is_some() && g.uncelled() == 0);
    let (source, (est, radii)) = match grid {
        Some(g) => (
            ", neighbours from the native grid",
            normals::estimate_grid(&scan.points, g, need, toward),
        ),
        None => {
            let cells = sensor_grid(&scan.points, proj);
            match normals::estimate_pixels(&scan.points, &cells, need, toward) {
                Some(e) => (", neighbours from the sensor's image", e),
                None => ("", normals::estimate(&scan.points, need, toward)),
            }
        }
    };
    let (normals, note) = match (&scan.normals, est) {
        (Some(given), Some(est)) => {
            let n: Vec<Vec3> = given
                .par_iter()
                .zip(&est)
                .zip(&scan.points)
                .map(|((g, e), p)| {
                    if *g == Vec3::ZERO {
                        *e
                    } else {
                        face(*g, proj.toward_sensor(*p))
                    }
                })
                .collect();
            (
                n,
                format!("input, {} re-estimated", invalid_normals.unwrap_or(0)),
            )
        }
        (Some(given), None) => (
            given
                .par_iter()
                .zip(&scan.points)
                .map(|(g, p)| face(*g, proj.toward_sensor(*p)))
                .collect(),
            "input".to_string(),
        ),
        (None, Some(est)) => (est, format!("estimated (PCA, k = 16{source})")),
        (None, None) => (vec![Vec3::Z; scan.len()], "none".into()),
    };
    (normals, radii, note)
}

/// Cells per map pixel along each side of [`sensor_grid`]: a map built from loose points is a
/// little coarser than their spacing (see `sensor::MAP_STEP_MARGIN`), so a grid of the map's
/// own pixels would put two points in some cells; 1.25 times finer, evenly spaced points each
/// get their own.
const SENSOR_GRID_SCALE: f32 = 1.25;

/// The cell of each point in a grid over `proj`'s image, [`SENSOR_GRID_SCALE`] times finer
/// than its map ([`crate::scan::NO_CELL`] outside it): the neighbourhood structure a scanner's
/// native grid would have given, for scans stored without one.
fn sensor_grid(points: &[Vec3], proj: &Projection) -> crate::scan::Grid {
    let f = SENSOR_GRID_SCALE;
    let cols = (proj.width as f32 * f).ceil().max(1.0) as u32;
    let rows = (proj.height as f32 * f).ceil() as u32;
    let (row, col): (Vec<u32>, Vec<u32>) = points
        .par_iter()
        .map(|&p| {
            let Some(pr) = proj.project(p).filter(|pr| pr.depth.is_finite()) else {
                return (NO_CELL, NO_CELL);
            };
            let (x, y) = ((pr.x * f).floor(), (pr.y * f).floor());
            if !(x.is_finite() && y >= 0.0 && y < rows as f32) {
                return (NO_CELL, NO_CELL);
            }
            let x = if proj.wrap_x {
                (x as i64).rem_euclid(i64::from(cols))
            } else {
                x as i64
            };
            if (0..i64::from(cols)).contains(&x) {
                (y as u32, x as u32)
            } else {
                (NO_CELL, NO_CELL)
            }
        })
        .unzip();
    crate::scan::Grid {
        rows,
        cols,
        row,
        col,
    }
}

/// Flips `n` to face the sensor direction `t`.
fn face(n: Vec3, t: Vec3) -> Vec3 {
    if n.dot(t) < 0.0 {
        -n
    } else {
        n
    }
}

/// What the merge reads of each prepared view (with its scan's pose and, when given, its
/// cells).
pub fn merge_views<'a>(
    views: &'a [PreparedView],
    maps: &'a [ViewMaps],
    scans: &[Scan],
    cells: Option<&'a [ViewCells]>,
) -> Vec<View<'a>> {
    views
        .iter()
        .zip(maps)
        .zip(scans)
        .enumerate()
        .map(|(j, ((v, m), s))| View {
            proj: &v.sensor.projection,
            maps: m,
            pose: s.pose,
            cells: cells.and_then(|c| c.get(j)),
        })
        .collect()
}

/// Each view's maps packed for the merge with parameters `prm`.
pub fn view_maps(views: &[PreparedView], prm: &MergeParams) -> Vec<ViewMaps> {
    views
        .iter()
        .map(|v| ViewMaps::new(&v.sensor.projection, &v.gbuf, &v.ssao.ao, &v.border, prm))
        .collect()
}

/// Each view's cells, for leaving out points a view cannot match.
pub fn view_cells(views: &[PreparedView], scans: &[Scan]) -> Vec<ViewCells> {
    views
        .par_iter()
        .zip(scans)
        .map(|(v, s)| ViewCells::new(&v.gbuf, s.pose))
        .collect()
}

/// Smallest and largest finite depth (∞, 0 when there is none).
pub fn depth_range(depth: &[f32]) -> (f32, f32) {
    depth
        .iter()
        .filter(|d| d.is_finite())
        .fold((f32::INFINITY, 0.0f32), |(lo, hi), &d| {
            (lo.min(d), hi.max(d))
        })
}
