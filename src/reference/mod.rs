//! Ray-traced reference obscurance: the ground truth every estimator is judged against.
//!
//! `A(p) = (1/π) ∫_Ω ρ(d(p,ω)) max(n·ω, 0) dω` with `ρ(d) = smoothstep(0, t_max, d)`
//! (`x = clamp(d/t_max, 0, 1)`, `x²(3 − 2x)`; `t_max = ∞` allowed: `ρ = 0` on any hit, 1 on a
//! miss), 1 = open. With cosine-weighted directions `A(p) = E[ρ(d)]`, estimated by casting
//! [`RefParams::rays`] rays per point against all scans together.
//!
//! **Geometry.** A [`Scene`] holds oriented disks (surfels: centre, unit normal, radius
//! `rad(p)`) for point clouds and triangles for meshes or native range grids
//! ([`triangulate_grid`]), each kind in its own bounding volume hierarchy (our own: binned
//! SAH build, collapsed into 4-wide 128-byte nodes whose four child boxes are tested together
//! with SIMD, primitives in leaf order). Everything lives in one f32 frame chosen by the
//! caller (usually the first scan's local frame): each scan's pose is composed with the
//! frame's inverse in f64 before its points are rounded to f32, so georeferenced data stays
//! exact. Rays stop at `t_max`; with `t_max = ∞` the first hit found ends a ray.
//!
//! **Sampling.** Per point a Hammersley set of `R` directions with a random shift drawn from
//! `(seed, point index)`, mapped to the cosine-weighted hemisphere: stratified, deterministic
//! for a seed, independent of the thread count and of the other points.
//!
//! **Self-hits.** A query point lies on its own surfel and among neighbouring surfels of the
//! same surface, from its own scan and from others. A ray must not be stopped by the sampled
//! surface it starts from; three rules keep it out (measured against exact mesh ground
//! truth, `docs/reference.md`):
//! 1. the ray starts at `p + n·ε`, `ε = 0.01·rad(p)` (at least 16 f32 ulps of `p`), so the
//!    point's own disk and coplanar neighbours are behind the origin;
//! 2. a surfel hit from its back side (`d·n_q > 0`: the ray leaves through the disk in the
//!    direction the disk faces) closer than `2·(rad(p) + rad(q))` is ignored: on a convex
//!    surface every neighbour's tangent disk overhangs the query point;
//! 3. own patch: any hit closer than `2·rad(p)` on a surface whose normal is within 60° of
//!    the point's (`n_q·n_p > 0.5`) is ignored: neighbours tilted by normal error or noise,
//!    the co-located samples of another scan lifted by a registration residual, a grid
//!    triangle cutting the corner of a crease. A real occluder that close faces across (the
//!    wall of a crease) and is kept. A surface facing back (`n_q·n_p < −0.5`) is ignored only
//!    where it lies in the point's own surface (a neighbour whose estimated normal flipped):
//!    across a groove narrower than `2·rad(p)` the facing wall stands steeply over the
//!    tangent plane and is kept. The same holds at any distance for such a surface lower over
//!    the tangent plane than the scan's own-surface height ([`residual::own_heights`],
//!    [`Scene::set_self_height`]): the separation measured between overlapping scans, which a
//!    grazing ray meets far beyond `2·rad(p)`.
//!
//! Each ray that had a hit discarded by these rules is counted per point
//! ([`Reference::self_hits`], the `self_hits` column of the reference files): a large share
//! shows where the value rests on the rules rather than on the data.
//!
//! **Sizes from the grid.** For scans with a native grid, [`surfel_radii`] gives each disk
//! `0.75 ×` its longest kept grid edge measured in its tangent plane (`0.5 ×` on a boundary,
//! edges steeply off the plane not counted: [`grid_radii`]) instead of `rad(p)`: `rad(p)` spreads the 32 nearest
//! neighbours over a disk, which swells the disks of one-cell-wide structures (a thin
//! column far away, a silhouette) to several times their width and leaves gaps between the
//! stretched cells of a grazing floor. Grid edges within 4° of the line of sight are dropped
//! ([`MIN_VIEW_ANGLE_DEG`]): they join a foreground to its background where the ratio test
//! cannot see the jump (both neighbours of a one-cell-wide foreground are jumps too).
//!
//! What the rules cost: occluders closer than `ε` to the point are missed (a bias of order
//! `ε/t_max` in creases), and so are surfaces met from behind within `2·(rad(p) + rad(q))`
//! and surfaces nearly parallel to the point within `2·rad(p)` (a step lower than two
//! sample spacings).
//!
//! **Self-check.** [`self_check`] examines a sample of points that the data itself shows to
//! be open (nothing of any scan above a plane lifted a little over the tangent plane within
//! `t_max`) and counts those the reference darkens.
//!
//! **Cost.** Rays of one point share their origin, so the descent to it is done once per
//! point: the leaves whose box contains the origin give a short list of primitives that some
//! ray could hit (above the tangent plane, and not a surfel whose every hit would be an
//! ignored back hit), and the subtrees hanging off that path (those within `t_max` and above
//! the tangent plane) a list sorted by distance that each ray scans four boxes at a time,
//! stopping at the first group farther than its nearest hit. Query points are traced in
//! Morton order (each keeps its own index as seed) so that consecutive points reuse the same
//! nodes. No allocation per point or ray; rayon over points.
//!
//! Throughput: `cargo bench --bench reference`; the figures are in `docs/reference.md`.

mod bvh;
mod explain;
mod grid;
mod prim;
pub mod residual;
pub(crate) mod sampling;
mod wide;

pub use explain::{RayAccount, RayStop};
pub use grid::{
    grid_radii, grid_skirts, triangulate_grid, triangulate_grid_creased, triangulate_grid_seen,
    View, BORDER_RADIUS_FACTOR, EDGE_OFF_PLANE, EDGE_RATIO, GRID_RADIUS_FACTOR, MIN_VIEW_ANGLE_DEG,
};

use crate::error::{Error, Result};
pub use crate::falloff::Falloff;
use bvh::Ray;
use glam::{DMat3, DMat4, Vec3};
use prim::{Surfel, Triangle};
use rayon::prelude::*;
use sampling::{Azimuths, Pattern};
use serde::Serialize;
use std::time::Instant;
use wide::{Bvh, Origin, Stack};

/// Origin offset along the normal, relative to `rad(p)`.
pub const ORIGIN_OFFSET: f32 = 0.01;
/// Rays per point of the default parameters.
pub const DEFAULT_RAYS: u32 = 256;
/// Most rays per point accepted (the convergence check casts four times as many).
pub const MAX_RAYS: u32 = 1 << 20;
/// Points in the default convergence sample.
pub const DEFAULT_SAMPLE: usize = 2000;

/// What [`obscurance`] computes.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct RefParams {
    /// Rays per point (1 ..= [`MAX_RAYS`]).
    pub rays: u32,
    /// Falloff distance of ρ in the scene frame's units (> 0; `f32::INFINITY` = plain
    /// cosine-weighted ambient occlusion).
    #[serde(serialize_with = "crate::falloff::serialize_tmax")]
    pub tmax: f32,
    /// Shape of ρ below `t_max`.
    pub falloff: Falloff,
    /// Seed of the per-point direction sets.
    pub seed: u64,
}

impl Default for RefParams {
    /// [`DEFAULT_RAYS`] rays, `t_max = ∞`, seed 0.
    fn default() -> Self {
        RefParams {
            rays: DEFAULT_RAYS,
            tmax: f32::INFINITY,
            falloff: Falloff::Smoothstep,
            seed: 0,
        }
    }
}

impl RefParams {
    /// Refuses rays outside `1..=MAX_RAYS` and a non-positive `t_max`.
    pub(crate) fn check(&self) -> Result<()> {
        if self.rays == 0 || self.rays > MAX_RAYS {
            return Err(Error::Param(format!(
                "reference: rays must be in 1..={MAX_RAYS}, got {}",
                self.rays
            )));
        }
        if !(self.tmax > 0.0) {
            return Err(Error::Param(format!(
                "reference: t_max must be positive, got {}",
                self.tmax
            )));
        }
        Ok(())
    }
}

/// The default falloff `ρ(d) = smoothstep(0, t_max, d)`; 1 for `d ≥ t_max` (a miss).
#[inline]
pub fn rho(d: f32, tmax: f32) -> f32 {
    Falloff::Smoothstep.rho(d, tmax)
}

/// Collects primitives in one frame; [`SceneBuilder::build`] makes the [`Scene`].
#[derive(Debug, Clone)]
pub struct SceneBuilder {
    frame: DMat4,
    frame_inv: DMat4,
    surfels: Vec<Surfel>,
    tris: Vec<Triangle>,
    skipped: usize,
}

/// Surfels and triangles of all scans in one f32 frame, with their hierarchies.
#[derive(Debug, Clone)]
pub struct Scene {
    frame: DMat4,
    self_height: f32,
    surfels: Bvh<Surfel>,
    tris: Bvh<Triangle>,
    skipped: usize,
}

/// `frame⁻¹ · pose` in f64 and its normal matrix, or an error naming `name`.
fn relative(frame_inv: DMat4, pose: DMat4, name: &str) -> Result<(DMat4, DMat3)> {
    if !frame_inv.is_finite() {
        return Err(Error::scan(
            name,
            "reference scene frame is not a finite invertible transform",
        ));
    }
    if !pose.is_finite() {
        return Err(Error::scan(name, "pose is not finite"));
    }
    let rel = frame_inv * pose;
    let m = DMat3::from_mat4(rel);
    let det = m.determinant();
    if !(det.abs() > 1e-12) || !det.is_finite() {
        return Err(Error::scan(name, "pose is singular"));
    }
    Ok((rel, m.inverse().transpose()))
}

impl SceneBuilder {
    /// An empty scene whose f32 frame is `frame`'s local frame (`frame` maps it to world).
    /// A frame that is not finite and invertible makes every `add_*` call an error.
    pub fn new(frame: DMat4) -> SceneBuilder {
        let frame_inv = if frame.is_finite() && frame.determinant().abs() > 1e-12 {
            frame.inverse()
        } else {
            DMat4::from_cols_array(&[f64::NAN; 16])
        };
        SceneBuilder {
            frame,
            frame_inv,
            surfels: Vec::new(),
            tris: Vec::new(),
            skipped: 0,
        }
    }

    /// Adds one disk per point of scan `name` (local coordinates, `pose`: local → world).
    /// Points with non-finite coordinates, a zero or non-finite normal, or a radius that is
    /// not positive and finite are skipped and counted ([`Scene::skipped`]). Returns the
    /// number added; errors when the slices differ in length or the pose is unusable.
    pub fn add_surfels(
        &mut self,
        name: &str,
        pose: DMat4,
        points: &[Vec3],
        normals: &[Vec3],
        radii: &[f32],
    ) -> Result<usize> {
        if normals.len() != points.len() || radii.len() != points.len() {
            return Err(Error::scan(
                name,
                format!(
                    "reference scene: {} points, {} normals, {} radii",
                    points.len(),
                    normals.len(),
                    radii.len()
                ),
            ));
        }
        let (rel, nm) = relative(self.frame_inv, pose, name)?;
        let before = self.surfels.len();
        self.surfels.reserve(points.len());
        for ((p, n), &r) in points.iter().zip(normals).zip(radii) {
            let c = rel.transform_point3(p.as_dvec3()).as_vec3();
            let n = (nm * n.as_dvec3()).normalize_or_zero().as_vec3();
            if !(c.is_finite() && n != Vec3::ZERO && n.is_finite() && r > 0.0 && r.is_finite()) {
                self.skipped += 1;
                continue;
            }
            self.surfels.push(Surfel { c, r2: r * r, n, r });
        }
        Ok(self.surfels.len() - before)
    }

    /// Adds the triangles `tris` (indices into `vertices`, local coordinates of scan `name`).
    /// A triangle's front is the side that `fronts` (one direction per vertex: towards the
    /// sensor that sampled it, or its normal) points to when given, else the side from which
    /// its winding is counter-clockwise: the own-patch rule treats a surface facing the query
    /// point differently from one facing its way. Triangles with a non-finite vertex or zero
    /// area are skipped and counted. Returns the number added; errors on an index past the
    /// vertices, a count of `fronts` that is not the vertex count, or an unusable pose.
    pub fn add_triangles(
        &mut self,
        name: &str,
        pose: DMat4,
        vertices: &[Vec3],
        fronts: Option<&[Vec3]>,
        tris: &[[u32; 3]],
    ) -> Result<usize> {
        if let Some((k, t)) = tris
            .iter()
            .enumerate()
            .find(|(_, t)| t.iter().any(|&i| i as usize >= vertices.len()))
        {
            return Err(Error::scan(
                name,
                format!(
                    "reference scene: triangle {k} refers to vertex {} of {}",
                    t.iter().max().copied().unwrap_or(0),
                    vertices.len()
                ),
            ));
        }
        if let Some(n) = fronts.filter(|n| n.len() != vertices.len()) {
            return Err(Error::scan(
                name,
                format!(
                    "reference scene: {} front directions for {} vertices",
                    n.len(),
                    vertices.len()
                ),
            ));
        }
        let (rel, _) = relative(self.frame_inv, pose, name)?;
        let v: Vec<Vec3> = vertices
            .iter()
            .map(|p| rel.transform_point3(p.as_dvec3()).as_vec3())
            .collect();
        let before = self.tris.len();
        self.tris.reserve(tris.len());
        for t in tris {
            let [a, b, c] = t.map(|i| v[i as usize]);
            // Decided in local coordinates, where the fronts are given (the pose is rigid).
            let back = fronts.is_some_and(|n| {
                let [la, lb, lc] = t.map(|i| vertices[i as usize]);
                let sum: Vec3 = t.iter().map(|&i| n[i as usize]).sum();
                (lb - la).cross(lc - la).dot(sum) < 0.0
            });
            let (e1, e2) = if back { (c - a, b - a) } else { (b - a, c - a) };
            if !(a.is_finite() && b.is_finite() && c.is_finite()) || e1.cross(e2) == Vec3::ZERO {
                self.skipped += 1;
                continue;
            }
            self.tris.push(Triangle { v0: a, e1, e2 });
        }
        Ok(self.tris.len() - before)
    }

    /// Builds the hierarchies.
    pub fn build(self) -> Scene {
        let (surfels, tris) = rayon::join(|| Bvh::build(self.surfels), || Bvh::build(self.tris));
        Scene {
            frame: self.frame,
            self_height: 0.0,
            surfels,
            tris,
            skipped: self.skipped,
        }
    }
}

impl Scene {
    /// A builder for a scene in `frame`'s local frame (see [`SceneBuilder::new`]).
    pub fn builder(frame: DMat4) -> SceneBuilder {
        SceneBuilder::new(frame)
    }

    /// Sets the own-surface height of the query points traced next (see
    /// [`residual::own_heights`]): a surface within 60° of a point's normal lower than this
    /// over its tangent plane is the point's own, however far along the ray (0: only the
    /// `2·rad(p)` rule). Negative or non-finite values count as 0.
    pub fn set_self_height(&mut self, h: f32) {
        self.self_height = if h.is_finite() { h.max(0.0) } else { 0.0 };
    }

    /// The own-surface height in use.
    pub fn self_height(&self) -> f32 {
        self.self_height
    }

    /// The scene frame → world transform.
    pub fn frame(&self) -> DMat4 {
        self.frame
    }

    /// Number of surfels.
    pub fn surfel_count(&self) -> usize {
        self.surfels.len()
    }

    /// Number of triangles.
    pub fn triangle_count(&self) -> usize {
        self.tris.len()
    }

    /// Primitives left out for invalid data.
    pub fn skipped(&self) -> usize {
        self.skipped
    }

    /// Memory held by the hierarchies and primitives (bytes).
    pub fn bytes(&self) -> usize {
        self.surfels.bytes() + self.tris.bytes()
    }

    /// Query points and normals of a scan (`pose`: local → world) in the scene frame,
    /// composed in f64. Normals are renormalised (zero stays zero).
    pub fn to_frame(
        &self,
        pose: DMat4,
        points: &[Vec3],
        normals: &[Vec3],
    ) -> Result<(Vec<Vec3>, Vec<Vec3>)> {
        let frame_inv = SceneBuilder::new(self.frame).frame_inv;
        let (rel, nm) = relative(frame_inv, pose, "query points")?;
        let p = points
            .iter()
            .map(|p| rel.transform_point3(p.as_dvec3()).as_vec3())
            .collect();
        let n = normals
            .iter()
            .map(|n| (nm * n.as_dvec3()).normalize_or_zero().as_vec3())
            .collect();
        Ok((p, n))
    }

    /// Distance to the nearest accepted hit of the ray `origin + t·dir` (`dir` unit) with
    /// `t < t_max`, applying the back-side rule for a query point of radius `self_radius`.
    pub fn nearest_hit(
        &self,
        origin: Vec3,
        dir: Vec3,
        self_radius: f32,
        t_max: f32,
    ) -> Option<f32> {
        // The traversal needs a finite far end (empty child slots sit at +∞).
        let far = t_max.min(f32::MAX);
        let ray = Ray::new(origin, dir, self_radius);
        let mut stack = Stack::default();
        let t = self.surfels.trace::<false>(&ray, far, &mut stack);
        let t = self.tris.trace::<false>(&ray, t, &mut stack);
        (t < far).then_some(t)
    }

    /// Obscurance of one point (index `index` seeds its directions) and the number of its
    /// rays that met their own surface (hits discarded by the self-hit rules); `ctx` is
    /// scratch.
    fn point(
        &self,
        p: Vec3,
        n: Vec3,
        r: f32,
        run: &Run,
        index: u64,
        ctx: &mut Contexts,
    ) -> (f32, u32) {
        let (prm, az) = (&run.prm, &run.az);
        let n = n.normalize_or_zero();
        if n == Vec3::ZERO || !p.is_finite() {
            return (1.0, 0);
        }
        let r = if r > 0.0 && r.is_finite() { r } else { 0.0 };
        let eps = (ORIGIN_OFFSET * r).max(16.0 * f32::EPSILON * p.abs().max_element());
        let o = p + n * eps;
        let pat = Pattern::new(prm.seed, index, n, az);
        // The traversal needs a finite far end (empty child slots sit at +∞).
        let far = prm.tmax.min(f32::MAX);
        self.surfels.origin(o, n, r, far, &mut ctx.surfels);
        self.tris.origin(o, n, r, far, &mut ctx.tris);
        let (cs, ct, st) = (&ctx.surfels, &ctx.tris, &mut ctx.stack);
        let mut sum = 0.0f32;
        let mut own = 0u32;
        if prm.falloff.blocks_fully(prm.tmax) {
            for j in 0..prm.rays {
                let ray = Ray::of_point(o, pat.dir(j), r, n, self.self_height);
                if self.surfels.trace_origin::<true>(cs, &ray, far, st) == far
                    && self.tris.trace_origin::<true>(ct, &ray, far, st) == far
                {
                    sum += 1.0;
                }
                own += (ray.discarded.get() > 0) as u32;
            }
        } else {
            for j in 0..prm.rays {
                let ray = Ray::of_point(o, pat.dir(j), r, n, self.self_height);
                let t = self.surfels.trace_origin::<false>(cs, &ray, far, st);
                let t = self.tris.trace_origin::<false>(ct, &ray, t, st);
                sum += prm.falloff.rho(t, prm.tmax);
                own += (ray.discarded.get() > 0) as u32;
            }
        }
        ((sum / prm.rays as f32).clamp(0.0, 1.0), own)
    }
}

/// Height of the plane the self-check lifts above an open point, relative to `t_max` (or to
/// the scene's extent when `t_max = ∞`); at least `2·rad(p)`.
pub const OPEN_LIFT: f32 = 0.05;
/// An open point reading below this is counted as darkened by the self-check.
pub const OPEN_MIN_A: f32 = 0.9;

/// The self-check of a reference run: points that the data itself shows to be open must
/// read open.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct SelfCheck {
    /// Points examined (evenly spread over the input order).
    pub sample: usize,
    /// Of those, points with nothing of any scan above the plane lifted
    /// `max(OPEN_LIFT·t_max, 2·rad(p))` over their tangent plane within `t_max`: open by the
    /// data alone, so `A` should be near 1.
    pub open: usize,
    /// Open points whose reference reads below [`OPEN_MIN_A`].
    pub darkened: usize,
    /// Smallest reference value among the open points (1 when there is none).
    pub min_open_a: f32,
    /// Mean over the sample of the share of a point's rays that met its own surface.
    pub mean_self_hit_share: f32,
}

/// Share of the open points the self-check lets read below [`OPEN_MIN_A`]: the open test
/// looks only above a lifted plane, so a point beside a kerb lower than the lift may
/// rightly read a little darker.
pub const OPEN_DARKENED_MAX: f64 = 0.01;

impl SelfCheck {
    /// True when at most [`OPEN_DARKENED_MAX`] of the open points read darkened.
    pub fn passed(&self) -> bool {
        self.darkened as f64 <= OPEN_DARKENED_MAX * self.open as f64
    }
}

/// Checks a computed reference `r` (values and per-point self-hit counts) on `sample` points
/// spread evenly over the input: a point is *open* when the scene has nothing above the
/// plane `max(OPEN_LIFT·t_max, 2·rad(p))` over its tangent plane within `t_max` (t_max = ∞:
/// within the scene), in which case nearly every ray must escape; a darkened open point
/// means the reference stops rays on something the data does not hold above it.
pub fn self_check(
    scene: &Scene,
    points: &[Vec3],
    normals: &[Vec3],
    radii: &[f32],
    r: &Reference,
    prm: &RefParams,
    sample: usize,
) -> SelfCheck {
    let (a, self_hits) = (&r.a, &r.self_hits);
    let n = points
        .len()
        .min(normals.len())
        .min(radii.len())
        .min(a.len());
    let m = sample.min(n);
    let ((l1, h1), (l2, h2)) = (scene.surfels.bounds(), scene.tris.bounds());
    let extent = (h1.max(h2) - l1.min(l2)).max_element().max(0.0);
    let reach = if prm.tmax.is_finite() {
        prm.tmax
    } else {
        extent.max(f32::MIN_POSITIVE) * 2.0
    };
    let found: Vec<(bool, f32, f32)> = (0..m)
        .into_par_iter()
        .map_init(Contexts::default, |ctx, k| {
            let i = (k as u128 * n as u128 / m as u128) as usize;
            let nn = normals[i].normalize_or_zero();
            let share = self_hits.get(i).copied().unwrap_or(0) as f32 / prm.rays as f32;
            if nn == Vec3::ZERO || !points[i].is_finite() {
                return (false, 1.0, share);
            }
            let lift = (OPEN_LIFT * reach.min(extent)).max(2.0 * radii[i].max(0.0));
            let o = points[i] + nn * lift;
            let open = scene.surfels.nothing_above(o, nn, reach, &mut ctx.surfels)
                && scene.tris.nothing_above(o, nn, reach, &mut ctx.tris);
            (open, a[i], share)
        })
        .collect();
    let open: Vec<f32> = found.iter().filter(|f| f.0).map(|f| f.1).collect();
    SelfCheck {
        sample: m,
        open: open.len(),
        darkened: open.iter().filter(|&&v| v < OPEN_MIN_A).count(),
        min_open_a: open.iter().copied().fold(1.0, f32::min),
        mean_self_hit_share: if m > 0 {
            found.iter().map(|f| f.2).sum::<f32>() / m as f32
        } else {
            0.0
        },
    }
}

/// How scan `s` is seen, for the grid rules ([`View`]).
pub fn scan_view(s: &crate::scan::Scan) -> View {
    match s.sensor_hint {
        Some(crate::projection::SensorModel::Ortho) => View::Parallel(Vec3::Z),
        _ => View::Origin,
    }
}

/// Surfel radii of scan `s` (local unit `normals`) for the reference: [`grid_radii`] on its
/// native grid, else `rad` (that is `rad(p)`) unchanged.
pub fn surfel_radii(s: &crate::scan::Scan, normals: &[Vec3], rad: &[f32]) -> Result<Vec<f32>> {
    match &s.grid {
        Some(g) => grid_radii(&s.points, g, scan_view(s), normals, rad),
        None => Ok(rad.to_vec()),
    }
}

/// Per-thread scratch of [`Scene::point`].
#[derive(Default)]
struct Contexts {
    surfels: Origin,
    tris: Origin,
    stack: Stack,
}

/// Parameters of one run with the azimuth table of its ray count.
struct Run {
    prm: RefParams,
    az: Azimuths,
}

impl Run {
    fn new(prm: &RefParams) -> Run {
        Run {
            prm: *prm,
            az: Azimuths::new(prm.rays),
        }
    }
}

fn check_inputs(points: &[Vec3], normals: &[Vec3], radii: &[f32]) -> Result<()> {
    if normals.len() != points.len() || radii.len() != points.len() {
        return Err(Error::Param(format!(
            "reference: {} query points, {} normals, {} radii",
            points.len(),
            normals.len(),
            radii.len()
        )));
    }
    Ok(())
}

/// Points per parallel work item (and per progress report).
const CHUNK: usize = 256;

/// Reference obscurance `A` of every query point (scene frame: see [`Scene::to_frame`]),
/// with `rad(p)` in `radii` for the self-hit rules. Values in [0, 1], never NaN; a point with a
/// non-finite position or zero normal gets 1. Point `i`'s directions depend only on
/// `(prm.seed, i)`. `progress(k)` is called as `k` more points are done.
pub fn obscurance(
    scene: &Scene,
    points: &[Vec3],
    normals: &[Vec3],
    radii: &[f32],
    prm: &RefParams,
    progress: &(dyn Fn(u64) + Sync),
) -> Result<Vec<f32>> {
    Ok(obscurance_counted(scene, points, normals, radii, prm, progress)?.0)
}

/// [`obscurance`] with, per point, the number of rays that met the point's own surface (a
/// hit discarded by the self-hit rules): where that share is large the reference rests on
/// the rules rather than on the data.
pub fn obscurance_counted(
    scene: &Scene,
    points: &[Vec3],
    normals: &[Vec3],
    radii: &[f32],
    prm: &RefParams,
    progress: &(dyn Fn(u64) + Sync),
) -> Result<(Vec<f32>, Vec<u32>)> {
    prm.check()?;
    check_inputs(points, normals, radii)?;
    // Points are traced in Morton order so consecutive work touches the same part of the
    // hierarchy (the input order may be anything); each keeps its own index as its seed.
    let order = spatial_order(points);
    let run = Run::new(prm);
    let vals: Vec<(f32, u32)> = order
        .par_chunks(CHUNK)
        .flat_map_iter(|chunk| {
            let mut ctx = Contexts::default();
            let v: Vec<(f32, u32)> = chunk
                .iter()
                .map(|&i| {
                    let i = i as usize;
                    scene.point(points[i], normals[i], radii[i], &run, i as u64, &mut ctx)
                })
                .collect();
            progress(chunk.len() as u64);
            v
        })
        .collect();
    let mut out = vec![1.0f32; points.len()];
    let mut own = vec![0u32; points.len()];
    for (&i, (v, k)) in order.iter().zip(vals) {
        out[i as usize] = v;
        own[i as usize] = k;
    }
    Ok((out, own))
}

/// Indices of `points` sorted along a Morton curve over their bounding box (non-finite points
/// first).
fn spatial_order(points: &[Vec3]) -> Vec<u32> {
    let (mut lo, mut hi) = (Vec3::splat(f32::INFINITY), Vec3::splat(f32::NEG_INFINITY));
    for p in points.iter().filter(|p| p.is_finite()) {
        lo = lo.min(*p);
        hi = hi.max(*p);
    }
    let scale = ((1u32 << 21) - 1) as f32 / (hi - lo).max_element().max(f32::MIN_POSITIVE);
    let mut keyed: Vec<(u64, u32)> = points
        .par_iter()
        .enumerate()
        .map(|(i, p)| {
            let code = if p.is_finite() {
                let q =
                    ((*p - lo) * scale).clamp(Vec3::ZERO, Vec3::splat(((1u32 << 21) - 1) as f32));
                spread3(q.x as u64) | spread3(q.y as u64) << 1 | spread3(q.z as u64) << 2
            } else {
                0
            };
            (code, i as u32)
        })
        .collect();
    keyed.par_sort_unstable();
    keyed.into_iter().map(|(_, i)| i).collect()
}

/// Spreads the low 21 bits of `x` to every third bit.
fn spread3(mut x: u64) -> u64 {
    x &= 0x1f_ffff;
    x = (x | x << 32) & 0x1f_0000_0000_ffff;
    x = (x | x << 16) & 0x1f_0000_ff00_00ff;
    x = (x | x << 8) & 0x100f_00f0_0f00_f00f;
    x = (x | x << 4) & 0x10c3_0c30_c30c_30c3;
    x = (x | x << 2) & 0x1249_2492_4924_9249;
    x
}

/// How far the reference is from convergence, and how fast it ran.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Convergence {
    /// Points in the sample (evenly spread over the point order).
    pub sample: usize,
    /// Rays per point of the run (`R`).
    pub rays: u32,
    /// Mean over the sample of `|A_R − A_4R|`.
    pub mean_abs_diff_4r: f32,
    /// Largest `|A_R − A_4R|` in the sample.
    pub max_abs_diff_4r: f32,
    /// Rays cast by the timed run.
    pub rays_cast: u64,
    /// Wall time of the timed run (seconds).
    pub seconds: f64,
    /// `rays_cast / seconds` (0 when too fast to time).
    pub rays_per_second: f64,
}

/// Compares `A_R` with `A_4R` on `sample` points spread evenly over the input order (each
/// with its own index as seed, so `A_R` equals the full run's value). The timing fields
/// describe the sample's two runs.
pub fn convergence(
    scene: &Scene,
    points: &[Vec3],
    normals: &[Vec3],
    radii: &[f32],
    prm: &RefParams,
    sample: usize,
) -> Result<Convergence> {
    prm.check()?;
    check_inputs(points, normals, radii)?;
    let n = points.len();
    let m = sample.min(n);
    let idx: Vec<usize> = (0..m)
        .map(|k| (k as u128 * n as u128 / m as u128) as usize)
        .collect();
    let p4 = RefParams {
        rays: prm.rays.saturating_mul(4),
        ..*prm
    };
    let (r1, r4) = (Run::new(prm), Run::new(&p4));
    let start = Instant::now();
    let diffs: Vec<f32> = idx
        .par_iter()
        .map_init(Contexts::default, |ctx, &i| {
            let a = scene
                .point(points[i], normals[i], radii[i], &r1, i as u64, ctx)
                .0;
            let b = scene
                .point(points[i], normals[i], radii[i], &r4, i as u64, ctx)
                .0;
            (a - b).abs()
        })
        .collect();
    let seconds = start.elapsed().as_secs_f64();
    let rays_cast = m as u64 * (prm.rays as u64 + p4.rays as u64);
    let mean = if m > 0 {
        (diffs.iter().map(|&d| d as f64).sum::<f64>() / m as f64) as f32
    } else {
        0.0
    };
    Ok(Convergence {
        sample: m,
        rays: prm.rays,
        mean_abs_diff_4r: mean,
        max_abs_diff_4r: diffs.iter().copied().fold(0.0, f32::max),
        rays_cast,
        seconds,
        rays_per_second: per_second(rays_cast, seconds),
    })
}

fn per_second(count: u64, seconds: f64) -> f64 {
    if seconds > 0.0 {
        count as f64 / seconds
    } else {
        0.0
    }
}

/// The reference of a point set with its convergence report.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Reference {
    /// `A` per query point.
    pub a: Vec<f32>,
    /// Per query point, the rays that met the point's own surface (discarded hits).
    pub self_hits: Vec<u32>,
    /// `|A_R − A_4R|` on a sample; timing fields from the main run.
    pub convergence: Convergence,
}

/// [`obscurance`] over all points, timed, then [`convergence`] on `sample` points; the
/// report's rays/s are those of the main run.
pub fn reference(
    scene: &Scene,
    points: &[Vec3],
    normals: &[Vec3],
    radii: &[f32],
    prm: &RefParams,
    sample: usize,
    progress: &(dyn Fn(u64) + Sync),
) -> Result<Reference> {
    let start = Instant::now();
    let (a, self_hits) = obscurance_counted(scene, points, normals, radii, prm, progress)?;
    let seconds = start.elapsed().as_secs_f64();
    let rays_cast = points.len() as u64 * prm.rays as u64;
    let conv = convergence(scene, points, normals, radii, prm, sample)?;
    Ok(Reference {
        a,
        self_hits,
        convergence: Convergence {
            rays_cast,
            seconds,
            rays_per_second: per_second(rays_cast, seconds),
            ..conv
        },
    })
}
