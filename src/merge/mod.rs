//! Merging views (eq. 6–12): for every point of scan i and every scan j (i included), find the
//! point scan j stored at the projection of `M_j⁻¹ M_i p_i` (and its N×N neighbours), keep it
//! when it is the same surface seen from the right side (eq. 7), and average the views' SSAO
//! with weights `w_d·w_n·w_b·w_s`. Relative transforms are composed in f64 once per pair and
//! applied to the f32 local points. Reads no files, rasterizes nothing.

pub mod border;
pub mod cull;
pub mod union;
pub mod visible;
pub mod weights;

use crate::gbuffer::{GBuffer, EMPTY};
use crate::projection::{floor_i64, Projection};
use cull::{PointCells, ViewCells};
use glam::{Affine3A, DMat4, Vec3, Vec3A, Vec4};
use rayon::prelude::*;
use serde::Serialize;
use weights::{faces, w_border, w_distance, w_normal, w_spacing, within};

/// What the merge needs of one view (scan j).
#[derive(Debug, Clone, Copy)]
pub struct View<'a> {
    /// Scan j's projection.
    pub proj: &'a Projection,
    /// Scan j's per-pixel data, laid out for the merge.
    pub maps: &'a ViewMaps,
    /// Scan j's local → world pose.
    pub pose: DMat4,
    /// Scan j's cells for leaving out points it cannot match (`None`: every point is tried).
    pub cells: Option<&'a ViewCells>,
}

/// One view's per-pixel data in the order the merge reads it: the distance test of eq. 7
/// reads one 16-byte record (position, radius), a match one more (normal, `w_d·w_n`, SSAO,
/// border distance), instead of seven separate maps. `w_d·w_n` depends only on the pixel, so
/// it is computed once per view.
#[derive(Debug, Clone, Default)]
pub struct ViewMaps {
    /// Map width.
    pub width: usize,
    /// Local position and radius; radius −∞ where the pixel is empty.
    near: Vec<Vec4>,
    /// Normal, `w_d·w_n`, SSAO and border distance.
    rest: Vec<[f32; 6]>,
    /// Ranges of the stored points per tile, for leaving out hidden cells.
    tiles: visible::RangeTiles,
}

impl ViewMaps {
    /// Packs a view's G-buffer, SSAO (after blur) and border distances (pixels) for `prm`.
    pub fn new(
        proj: &Projection,
        g: &GBuffer,
        ao: &[f32],
        border: &[f32],
        prm: &MergeParams,
    ) -> ViewMaps {
        let n = g.point.len();
        let use_wd = proj.sensor_model() != crate::projection::SensorModel::Ortho;
        let (near, rest): (Vec<Vec4>, Vec<[f32; 6]>) = (0..n)
            .into_par_iter()
            .map(|i| {
                if g.point[i] == EMPTY {
                    return (Vec4::new(0.0, 0.0, 0.0, f32::NEG_INFINITY), [0.0; 6]);
                }
                let (p, nrm) = (g.position[i], g.normal[i]);
                let wd = if use_wd {
                    w_distance(g.depth[i], prm.dmin, prm.dmax)
                } else {
                    1.0
                };
                let wdn = wd * w_normal(nrm, proj.toward_sensor(p));
                let a = ao.get(i).copied().unwrap_or(0.0);
                let b = border.get(i).copied().unwrap_or(0.0);
                (p.extend(g.radius[i]), [nrm.x, nrm.y, nrm.z, wdn, a, b])
            })
            .unzip();
        let tiles = visible::RangeTiles::new(proj, g.width, &near);
        ViewMaps {
            width: g.width,
            near,
            rest,
            tiles,
        }
    }

    /// Heap bytes held.
    pub fn heap_bytes(&self) -> u64 {
        (self.near.capacity() * 16 + self.rest.capacity() * 24) as u64 + self.tiles.heap_bytes()
    }
}

/// Merge parameters (after defaults). `d_min`/`d_max` apply to views with a sensor position
/// (equirect, perspective); an orthographic view gets `w_d = 1`.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct MergeParams {
    /// Neighbourhood side N (odd): N×N pixels around each projection.
    pub neighbors: u32,
    /// `d_min` of eq. 10 (metres).
    pub dmin: f32,
    /// `d_max` of eq. 10 (metres).
    pub dmax: f32,
    /// `t_p` of eq. 12 (pixels).
    pub border_px: f32,
    /// `s = κ·t_max` of the spacing weight (metres; 0 = off).
    pub spacing: f32,
    /// A point matched by views whose maps cover every direction around their sensors takes
    /// the largest of those views' values instead of the weighted average (set for plain
    /// ambient occlusion by the far-field sweeps; `docs/design.md`, "Lower bounds at ∞").
    pub largest_all_round: bool,
}

#[cfg(test)]
impl MergeParams {
    /// Unit tests' merge of single pixels: no distance or spacing weight, border falloff over
    /// `border_px` pixels.
    pub(crate) fn single_pixel(border_px: f32) -> MergeParams {
        MergeParams {
            neighbors: 1,
            dmin: 0.0,
            dmax: 0.0,
            border_px,
            spacing: 0.0,
            largest_all_round: false,
        }
    }
}

/// Counters of one scan's merge; add up with `+=`.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize)]
pub struct MergeStats {
    /// Points whose weights summed to zero (they keep their own SSAO).
    pub zero_weight: u64,
    /// (point, view) pairs evaluated.
    pub point_views: u64,
    /// (point, view) pairs left out because no stored point of the view is near enough
    /// ([`cull`]).
    pub culled: u64,
    /// Samples accepted by eq. 7.
    pub samples_kept: u64,
    /// Points given the largest all-round view's value ([`MergeParams::largest_all_round`]).
    pub largest: u64,
    /// Points shaded by the union occlusion instead.
    pub united: u64,
}

impl std::ops::AddAssign for MergeStats {
    fn add_assign(&mut self, o: Self) {
        self.zero_weight += o.zero_weight;
        self.point_views += o.point_views;
        self.culled += o.culled;
        self.samples_kept += o.samples_kept;
        self.largest += o.largest;
        self.united += o.united;
    }
}

/// Per-point running sums of the merge of one scan (eq. 8): Σ SSAO·w and Σ w over the views
/// added so far. Views may be added one at a time (loaded on demand) in any grouping; adding
/// them in the same order gives bit-identical sums.
///
/// With [`MergeParams::largest_all_round`] a point that an all-round view matched holds
/// instead the largest such view's value in `num` and [`BOUND`] in `den`; the sums of other
/// views are then dropped, whichever came first.
#[derive(Debug, Clone)]
pub struct Accum {
    num: Vec<f32>,
    den: Vec<f32>,
    stats: MergeStats,
}

/// `den` of a point whose `num` is the largest lower bound (a value no weight sum takes).
const BOUND: f32 = -1.0;

impl Accum {
    /// Empty sums for `n` points.
    pub fn new(n: usize) -> Accum {
        Accum {
            num: crate::par::filled(n, 0.0),
            den: crate::par::filled(n, 0.0),
            stats: MergeStats::default(),
        }
    }

    /// The merged AO: Σ SSAO·w / Σ w (or the largest lower bound), or the point's own SSAO
    /// (counted) where Σ w = 0.
    pub fn finish(self, own: &[f32]) -> (Vec<f32>, MergeStats) {
        let mut st = self.stats;
        let weighed = |n: f32, d: f32| (d > 0.0 || d == BOUND) && n.is_finite();
        let out = self
            .num
            .par_iter()
            .zip(&self.den)
            .zip(own)
            .map(|((&n, &d), &o)| {
                if !weighed(n, d) {
                    o
                } else if d == BOUND {
                    n.clamp(0.0, 1.0)
                } else {
                    (n / d).clamp(0.0, 1.0)
                }
            })
            .collect();
        let (zero, largest) = self
            .num
            .par_iter()
            .zip(&self.den)
            .map(|(&n, &d)| match (weighed(n, d), d == BOUND) {
                (false, _) => (1u64, 0u64),
                (true, bound) => (0, bound as u64),
            })
            .reduce(|| (0, 0), |a, b| (a.0 + b.0, a.1 + b.1));
        st.zero_weight += zero;
        st.largest += largest;
        (out, st)
    }
}

/// The scan being merged: its points (local frame), radii, pixel of each point in its own
/// map, pose and projection.
#[derive(Debug, Clone, Copy)]
pub struct Target<'a> {
    /// Index of the scan among the views (its own view is read at `own_pixel`).
    pub index: usize,
    /// Local points.
    pub points: &'a [Vec3],
    /// rad(p) per point.
    pub radii: &'a [f32],
    /// Pixel of each point in its own map ([`EMPTY`] if outside).
    pub own_pixel: &'a [u32],
    /// Local → world.
    pub pose: DMat4,
    /// Its sensor model (the scanner position `b` of eq. 7).
    pub proj: &'a Projection,
    /// Its points' cells (`None`: every point is tried against every view).
    pub cells: Option<&'a PointCells>,
}

/// Adds view `j` to the sums of `t` (eq. 6–12 for one view), in parallel over points.
pub fn accumulate(
    acc: &mut Accum,
    t: &Target<'_>,
    j: usize,
    v: &View<'_>,
    prm: &MergeParams,
    progress: &(dyn Fn(u64) + Sync),
) {
    let half = (prm.neighbors.max(1) / 2) as i64;
    let relm = v.pose.inverse() * t.pose;
    let rel = Affine3A::from_mat4(relm.as_mat4());
    let b = (relm * t.proj.sensor_homogeneous().as_dvec4()).as_vec4();
    let bound = prm.largest_all_round && v.proj.all_round();
    const CHUNK: usize = 8192;
    let m = v.maps;
    // Cells of the target that may hold a partner in this view (all, for its own view): near
    // a point the view stored, and not hidden behind what it stored there.
    let keep = match t.cells {
        Some(pc) if j != t.index && pc.len() == t.points.len() => {
            let mut keep = v
                .cells
                .and_then(|vc| vc.relevant(pc))
                .unwrap_or_else(|| vec![true; pc.cell_count()]);
            visible::cull_hidden(&mut keep, pc, v.pose, v.proj, &m.tiles, half);
            Some((pc, keep))
        }
        _ => None,
    };
    // Eq. 7–12 for target point `k` of a chunk at `q` (view j's frame), whose image is in
    // pixel `(cx, cy)` of view j.
    let visit = |k: usize,
                 pi: usize,
                 q: Vec3,
                 (cx, cy): (i64, i64),
                 num: &mut [f32],
                 den: &mut [f32],
                 st: &mut MergeStats| {
        st.point_views += 1;
        if den[k] == BOUND && !bound {
            return;
        }
        let rad_i = t.radii[pi];
        let (mut bn, mut bd) = (0.0f32, 0.0f32);
        for dy in -half..=half {
            for dx in -half..=half {
                let Some(idx) = v.proj.pixel_at(cx + dx, cy + dy) else {
                    continue;
                };
                let (Some(near), Some(rest)) = (m.near.get(idx), m.rest.get(idx)) else {
                    continue;
                };
                let (p_ij, rad_ij) = (near.truncate(), near.w);
                if rad_ij == f32::NEG_INFINITY || !within(q, p_ij, rad_i, rad_ij) {
                    continue;
                }
                let n_ij = Vec3::new(rest[0], rest[1], rest[2]);
                if !faces(p_ij, n_ij, b) {
                    continue;
                }
                let w = rest[3]
                    * w_border(rest[5], prm.border_px, rad_i, rad_ij)
                    * w_spacing(rad_ij, prm.spacing);
                st.samples_kept += 1;
                if bound {
                    bn += rest[4] * w;
                    bd += w;
                } else {
                    num[k] += rest[4] * w;
                    den[k] += w;
                }
            }
        }
        // Weights of zero (a pixel at the map's border) leave the point to the other views.
        if bound && bd > 0.0 {
            let a = bn / bd;
            num[k] = if den[k] == BOUND { num[k].max(a) } else { a };
            den[k] = BOUND;
        }
    };
    let st = acc
        .num
        .par_chunks_mut(CHUNK)
        .zip(acc.den.par_chunks_mut(CHUNK))
        .enumerate()
        .map(|(ci, (num, den))| {
            let base = ci * CHUNK;
            let mut st = MergeStats::default();
            // Points of other scans are projected four at a time (the same pixels as one at
            // a time); `held` are those waiting for a full group.
            let mut held = [(0usize, Vec3::ZERO); 4];
            let mut n_held = 0;
            let project =
                |held: &[(usize, Vec3)], num: &mut [f32], den: &mut [f32], st: &mut MergeStats| {
                    let mut four = [Vec3::ZERO; 4];
                    for (f, h) in four.iter_mut().zip(held) {
                        *f = h.1;
                    }
                    let pr = v.proj.project4(four);
                    for (&(k, q), pr) in held.iter().zip(pr) {
                        if let Some(pr) = pr {
                            let px = (floor_i64(pr.x), floor_i64(pr.y));
                            visit(k, base + k, q, px, num, den, st);
                        }
                    }
                };
            for k in 0..num.len() {
                let pi = base + k;
                if let Some((pc, keep)) = &keep {
                    if !keep[pc.cell_of(pi)] {
                        st.culled += 1;
                        continue;
                    }
                }
                if j == t.index {
                    let px = t.own_pixel[pi];
                    if px == EMPTY {
                        continue;
                    }
                    let w = m.width.max(1);
                    let at = ((px as usize % w) as i64, (px as usize / w) as i64);
                    visit(k, pi, t.points[pi], at, num, den, &mut st);
                } else {
                    let q: Vec3 = rel.transform_point3a(Vec3A::from(t.points[pi])).into();
                    held[n_held] = (k, q);
                    n_held += 1;
                    if n_held == 4 {
                        project(&held, num, den, &mut st);
                        n_held = 0;
                    }
                }
            }
            project(&held[..n_held], num, den, &mut st);
            progress(num.len() as u64);
            st
        })
        .reduce(MergeStats::default, |mut a, b| {
            a += b;
            a
        });
    acc.stats += st;
}

/// Merges scan `i` (its local `points`, `radii`, own SSAO `own` and own pixels) against every
/// view not marked in `skip`: eq. 8 with the weights of eq. 9–12. Views are visited in index
/// order, so the result equals adding them one by one with [`accumulate`]. `cells` (scan i's
/// [`PointCells`]) lets views that carry [`ViewCells`] skip points they cannot match.
#[allow(clippy::too_many_arguments)]
pub fn merge_scan(
    i: usize,
    points: &[Vec3],
    radii: &[f32],
    own: &[f32],
    own_pixel: &[u32],
    cells: Option<&PointCells>,
    views: &[View<'_>],
    skip: &[bool],
    prm: &MergeParams,
    progress: &(dyn Fn(u64) + Sync),
) -> (Vec<f32>, MergeStats) {
    let t = Target {
        index: i,
        points,
        radii,
        own_pixel,
        pose: views[i].pose,
        proj: views[i].proj,
        cells,
    };
    let mut acc = Accum::new(points.len());
    for (j, v) in views.iter().enumerate() {
        if !skip.get(j).copied().unwrap_or(false) {
            accumulate(&mut acc, &t, j, v, prm, &|_| {});
        }
    }
    let r = acc.finish(own);
    progress(points.len() as u64);
    r
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::gbuffer::rasterize;
    use crate::projection::{Model, Projection};
    use glam::{DMat4, DVec3};

    /// A view of `maps` without cells (every point tried).
    fn view<'a>(proj: &'a Projection, maps: &'a ViewMaps, pose: DMat4) -> View<'a> {
        View {
            proj,
            maps,
            pose,
            cells: None,
        }
    }

    /// An orthographic view of a 3×3 pixel patch (10 cm pixels) of the plane z = 0, sensor above.
    fn patch() -> (Projection, Vec<Vec3>) {
        let proj = Projection::new(
            Model::Ortho {
                a: Vec3::new(10.0, 0.0, 0.0),
                a0: 1.5,
                b: Vec3::new(0.0, 10.0, 0.0),
                b0: 1.5,
                toward: Vec3::Z,
                depth0: 2.0,
            },
            3,
            3,
            false,
        );
        let pts = (0..9)
            .map(|i| {
                Vec3::new(
                    ((i % 3) as f32 - 1.0) * 0.1,
                    ((i / 3) as f32 - 1.0) * 0.1,
                    0.0,
                )
            })
            .collect();
        (proj, pts)
    }

    #[test]
    fn eq8_weighted_average_of_two_views() {
        let (proj, pts) = patch();
        let px: Vec<u32> = (0..9).collect();
        let n = vec![Vec3::Z; 9];
        let rad = vec![0.05f32; 9];
        let depth = vec![2.0f32; 9];
        let g = rasterize(3, 3, &px, &depth, &pts, &n, &rad);
        // View 0 sees AO 0.2, view 1 (same surface, shifted frame) sees AO 0.8.
        let ao0 = vec![0.2f32; 9];
        let ao1 = vec![0.8f32; 9];
        // Border distances: view 0 far from borders (w_b = 1), view 1 at 16 px (w_b = 0.25).
        let b0 = vec![1000.0f32; 9];
        let b1 = vec![16.0f32; 9];
        // Scan 1's frame is scan 0's shifted by 5 m in x: its local points are the same
        // numbers, its pose moves them back onto scan 0's surface.
        let pose0 = DMat4::from_translation(DVec3::new(5.0, 0.0, 0.0));
        let pose1 = DMat4::from_translation(DVec3::new(5.0, 0.0, 0.0));
        let prm = MergeParams {
            neighbors: 1,
            dmin: 0.0,
            dmax: 4.0,
            border_px: 64.0,
            spacing: 0.0,
            largest_all_round: false,
        };
        let maps1 = ViewMaps::new(&proj, &g, &ao0, &b0, &prm);
        let maps2 = ViewMaps::new(&proj, &g, &ao1, &b1, &prm);
        let views = [view(&proj, &maps1, pose0), view(&proj, &maps2, pose1)];
        let own = vec![0.2f32; 9];
        let (ao, st) = merge_scan(
            0,
            &pts,
            &rad,
            &own,
            &px,
            None,
            &views,
            &[false, false],
            &prm,
            &|_| {},
        );
        // w_d = 1 − 2/4 = 0.5 for both, w_n = 1, w_b = 1 and 0.25:
        // MVAO = (0.2·0.5 + 0.8·0.125) / (0.5 + 0.125) = 0.32
        for a in &ao {
            assert!((a - 0.32).abs() < 1e-6, "{a}");
        }
        assert_eq!(st.zero_weight, 0);
        assert_eq!(st.point_views, 18);
        assert_eq!(st.samples_kept, 18);
    }

    #[test]
    fn a_sharp_view_outweighs_a_coarse_one() {
        let (proj, pts) = patch();
        let px: Vec<u32> = (0..9).collect();
        let n = vec![Vec3::Z; 9];
        // The same surface seen by a sharp view (spacing 0.05 m, AO 0.2) and a coarse one
        // (spacing 0.2 m, AO 0.8).
        let sharp = rasterize(3, 3, &px, &[2.0; 9], &pts, &n, &[0.05; 9]);
        let coarse = rasterize(3, 3, &px, &[2.0; 9], &pts, &n, &[0.2; 9]);
        let b = vec![1000.0f32; 9];
        let merged = |spacing: f32| {
            let prm = MergeParams {
                neighbors: 1,
                dmin: 0.0,
                dmax: 0.0,
                border_px: 64.0,
                spacing,
                largest_all_round: false,
            };
            let m0 = ViewMaps::new(&proj, &sharp, &[0.2; 9], &b, &prm);
            let m1 = ViewMaps::new(&proj, &coarse, &[0.8; 9], &b, &prm);
            let views = [
                view(&proj, &m0, DMat4::IDENTITY),
                view(&proj, &m1, DMat4::IDENTITY),
            ];
            merge_scan(
                0,
                &pts,
                &[0.05; 9],
                &[0.2; 9],
                &px,
                None,
                &views,
                &[false, false],
                &prm,
                &|_| {},
            )
            .0
        };
        // Off: the plain mean. s = 0.1 m: w_s = 1/(1 + 0.25) = 0.8 and 1/(1 + 4) = 0.2, so
        // (0.2·0.8 + 0.8·0.2) / 1.0 = 0.32.
        for (spacing, want) in [(0.0, 0.5), (0.1, 0.32)] {
            for a in merged(spacing) {
                assert!((a - want).abs() < 1e-6, "s = {spacing}: {a}");
            }
        }
    }

    #[test]
    fn zero_weight_falls_back_to_own_ssao_and_is_counted() {
        let (proj, pts) = patch();
        let px: Vec<u32> = (0..9).collect();
        // Normals facing away from the sensor: w_n = 0 and eq. 7's visibility test fails.
        let n = vec![Vec3::NEG_Z; 9];
        let g = rasterize(3, 3, &px, &[2.0; 9], &pts, &n, &[0.05; 9]);
        let ao = vec![0.3f32; 9];
        let b = vec![100.0f32; 9];
        let prm = MergeParams {
            neighbors: 3,
            dmin: 0.0,
            dmax: 4.0,
            border_px: 64.0,
            spacing: 0.0,
            largest_all_round: false,
        };
        let maps1 = ViewMaps::new(&proj, &g, &ao, &b, &prm);
        let v = [view(&proj, &maps1, DMat4::IDENTITY)];
        let own = vec![0.7f32; 9];
        let (out, st) = merge_scan(
            0,
            &pts,
            &[0.05; 9],
            &own,
            &px,
            None,
            &v,
            &[false],
            &prm,
            &|_| {},
        );
        assert!(out.iter().all(|&a| a == 0.7));
        assert_eq!(st.zero_weight, 9);
    }

    #[test]
    fn neighbourhood_and_distance_test() {
        let (proj, pts) = patch();
        let px: Vec<u32> = (0..9).collect();
        let g = rasterize(3, 3, &px, &[2.0; 9], &pts, &[Vec3::Z; 9], &[0.06; 9]);
        let ao: Vec<f32> = (0..9).map(|i| i as f32 / 10.0).collect();
        let b = vec![1000.0f32; 9];
        let prm = MergeParams {
            neighbors: 3,
            dmin: 0.0,
            dmax: 0.0,
            border_px: 64.0,
            spacing: 0.0,
            largest_all_round: false,
        };
        let maps1 = ViewMaps::new(&proj, &g, &ao, &b, &prm);
        let v = [view(&proj, &maps1, DMat4::IDENTITY)];
        // Centre point: with t = 0.06, neighbours at 0.1 m (edge) pass 2t = 0.12, diagonal
        // ones at 0.1414 do not → average of pixels 1,3,4,5,7 = (0.1+0.3+0.4+0.5+0.7)/5 = 0.4.
        let (out, _) = merge_scan(
            0,
            &pts[4..5],
            &[0.06],
            &[0.0],
            &[4],
            None,
            &v,
            &[false],
            &prm,
            &|_| {},
        );
        assert!((out[0] - 0.4).abs() < 1e-6, "{}", out[0]);
    }
}
