//! Triangles from a native range grid.
//!
//! **Rule.** Every 2×2 block of occupied cells is a quad; a grid edge between 4-neighbours is
//! *kept* when its length is at most [`EDGE_RATIO`] times the shorter of the two collinear
//! edges next to it (same row or column, one cell before and one after). On a smooth surface
//! consecutive edges have nearly the same length, even at grazing incidence where they are
//! long; across a depth discontinuity the jump edge is many times longer than the edges on
//! both of its sides (foreground and background), so it is dropped. An edge with no collinear
//! neighbour is compared with the perpendicular edges at its two ends instead (same factor),
//! and kept when there is none. A quad is split along its shorter diagonal into two triangles,
//! each made only when both of its grid edges are kept (the diagonal is then at most their
//! sum); a block with one empty cell gives the one triangle of the other three. The rule is
//! scale-free and needs no sensor model. Columns do not wrap around (a 360° scan keeps a
//! one-column seam open).

use crate::error::{Error, Result};
use crate::scan::Grid;
use glam::Vec3;
use rayon::prelude::*;

/// Longest kept edge relative to its collinear neighbours.
pub const EDGE_RATIO: f32 = 3.0;
/// Smallest angle (degrees) between a kept grid edge and the line of sight: an edge closer
/// to the line of sight joins a foreground to a background (a depth jump the ratio test
/// misses when the foreground is one or two cells wide, as a thin column far away) or lies
/// on a surface seen so edge-on that its cells are not neighbours on it.
pub const MIN_VIEW_ANGLE_DEG: f32 = 4.0;
/// Surfel radius from the kept grid edges, relative to the longest of them: a disk of
/// `0.75·max(edge)` covers its share of a grid of cells of up to that size (the half
/// diagonal of a square cell is `0.707·edge`) without reaching past a depth jump.
pub const GRID_RADIUS_FACTOR: f32 = 0.75;

/// Largest `|ê·n|` of a grid edge `ê` counted in a surfel's radius (its normal `n`): an edge
/// more than 17.5° off the tangent plane leads to another surface, across a crease or a depth
/// jump the line-of-sight test lets through at coarse angular steps.
pub const EDGE_OFF_PLANE: f32 = 0.3;
/// Surfel radius relative to the longest counted edge for a point with fewer than four
/// counted edges (on a boundary: a silhouette, a convex edge, a hole): a disk of
/// [`GRID_RADIUS_FACTOR`] there overhangs the surface's true edge and stops the rays of
/// whatever lies beside it, which at `t_max = ∞` darkens every point that sees the
/// boundary; a smaller one on every point leaves gaps between the cells of closed walls.
pub const BORDER_RADIUS_FACTOR: f32 = 0.5;

/// Largest angle (degrees) between the normals of a kept edge's ends in a triangulation with
/// normals ([`triangulate_grid_creased`]): the own-patch rule's 60°, beyond which a surface
/// is another.
pub const CREASE_DEG: f32 = 60.0;

/// Smallest cosine of the incidence counted in a pixel's footprint on its surface.
pub const MIN_INCIDENCE_COS: f32 = 0.05;

/// Where a scan's sensor looks from, for the line-of-sight test of [`MIN_VIEW_ANGLE_DEG`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum View {
    /// A centre of projection at the scan's local origin (laser scanners, cameras).
    Origin,
    /// Parallel rays along this direction (orthographic sweeps).
    Parallel(Vec3),
}

/// Largest grid (in cells) accepted relative to the number of points: a cell index table of
/// `max(16·n, 2²⁴)` entries.
fn max_cells(n: usize) -> u64 {
    (16 * n as u64).max(1 << 24)
}

/// A scan's points indexed by grid cell, with the edge rule of the module.
struct Cells<'a> {
    points: &'a [Vec3],
    at: Vec<u32>,
    rows: usize,
    cols: usize,
    cos_view: f32,
    view: View,
    /// Normals per point for the crease rule of [`Cells::keep`]; empty: no rule.
    normals: &'a [Vec3],
    cos_crease: f32,
}

impl<'a> Cells<'a> {
    fn new(points: &'a [Vec3], grid: &Grid, view: View) -> Result<Cells<'a>> {
        let n = points.len();
        if grid.row.len() != n || grid.col.len() != n {
            return Err(Error::Param(format!(
                "range grid has {} rows and {} columns for {n} points",
                grid.row.len(),
                grid.col.len()
            )));
        }
        let (rows, cols) = (grid.rows as usize, grid.cols as usize);
        let cells = rows as u64 * cols as u64;
        if cells > max_cells(n) {
            return Err(Error::Param(format!(
                "range grid of {rows} × {cols} cells is too sparse for {n} points"
            )));
        }
        let mut at = vec![u32::MAX; cells as usize];
        for (i, p) in points.iter().enumerate() {
            let (r, c) = (grid.row[i] as usize, grid.col[i] as usize);
            if r < rows && c < cols && p.is_finite() {
                at[r * cols + c] = i as u32;
            }
        }
        Ok(Cells {
            points,
            at,
            rows,
            cols,
            cos_view: MIN_VIEW_ANGLE_DEG.to_radians().cos(),
            view,
            normals: &[],
            cos_crease: CREASE_DEG.to_radians().cos(),
        })
    }

    /// [`Cells::new`] with the crease rule of `normals` (one per point; else none).
    fn with_normals(
        points: &'a [Vec3],
        grid: &Grid,
        view: View,
        normals: &'a [Vec3],
    ) -> Result<Cells<'a>> {
        let mut g = Cells::new(points, grid, view)?;
        if normals.len() == points.len() {
            g.normals = normals;
        }
        Ok(g)
    }

    fn idx(&self, r: isize, c: isize) -> u32 {
        if r < 0 || c < 0 || r as usize >= self.rows || c as usize >= self.cols {
            return u32::MAX;
        }
        self.at[r as usize * self.cols + c as usize]
    }

    fn get(&self, r: isize, c: isize) -> Option<Vec3> {
        let i = self.idx(r, c);
        (i != u32::MAX).then(|| self.points[i as usize])
    }

    /// Length of the edge from (r, c) to (r + dr, c + dc), if both cells are occupied.
    fn len(&self, r: isize, c: isize, dr: isize, dc: isize) -> Option<f32> {
        Some(self.get(r, c)?.distance(self.get(r + dr, c + dc)?))
    }

    /// The lateral distance at `p` between its ray and the ray of the point at `q`: the
    /// sensor's angular step times the range (its metric step for parallel rays).
    fn pitch(&self, p: Vec3, q: Vec3) -> f32 {
        match self.view {
            View::Origin => {
                let (a, b) = (p.normalize_or_zero(), q.normalize_or_zero());
                p.length() * (a - b).length()
            }
            View::Parallel(d) => {
                let (d, e) = (d.normalize_or_zero(), q - p);
                (e - d * e.dot(d)).length()
            }
        }
    }

    /// Half the diagonal of a square as large as the footprint of the pixel of the point at
    /// `(r, c)` on its surface (normal `n`): the footprint's area is the row and column
    /// pitches at its range over the cosine of its incidence (held above
    /// [`MIN_INCIDENCE_COS`]); either pitch stands for both when the other has no neighbour.
    /// `None` without any neighbour.
    fn footprint(&self, r: isize, c: isize, n: Vec3) -> Option<f32> {
        let p = self.get(r, c)?;
        let axis = |dr: isize, dc: isize| {
            [(dr, dc), (-dr, -dc)]
                .into_iter()
                .filter_map(|(a, b)| self.get(r + a, c + b))
                .map(|q| self.pitch(p, q))
                .reduce(f32::min)
        };
        let (a, b) = match (axis(1, 0), axis(0, 1)) {
            (Some(a), Some(b)) => (a, b),
            (Some(a), None) | (None, Some(a)) => (a, a),
            (None, None) => return None,
        };
        let los = match self.view {
            View::Origin => p.normalize_or_zero(),
            View::Parallel(d) => d.normalize_or_zero(),
        };
        let cos = n.dot(los).abs().max(MIN_INCIDENCE_COS);
        let r = (0.5 * a * b / cos).sqrt();
        (r > 0.0 && r.is_finite()).then_some(r)
    }

    /// Is the edge from `a` to `b` within [`MIN_VIEW_ANGLE_DEG`] of the line of sight?
    fn edge_on(&self, a: Vec3, b: Vec3) -> bool {
        let e = (b - a).normalize_or_zero();
        let v = match self.view {
            View::Origin => ((a + b) * 0.5).normalize_or_zero(),
            View::Parallel(d) => d.normalize_or_zero(),
        };
        e.dot(v).abs() > self.cos_view
    }

    /// With normals, do the ends of the edge (r, c) → (r + dr, c + dc) face more than
    /// [`CREASE_DEG`] apart?
    fn crease(&self, r: isize, c: isize, dr: isize, dc: isize) -> bool {
        let normal = |i: u32| unit(self.normals, i as usize);
        let (na, nb) = (normal(self.idx(r, c)), normal(self.idx(r + dr, c + dc)));
        na != Vec3::ZERO && nb != Vec3::ZERO && na.dot(nb) < self.cos_crease
    }

    /// [`Cells::keep`] of the edge from `(r, c)` to its neighbour at `(r + dr, c + dc)` in
    /// any of the four directions (the edge read from its upper-left end).
    fn keep_at(&self, r: isize, c: isize, dr: isize, dc: isize) -> bool {
        let (sr, sc) = upper_left(r, c, dr, dc);
        self.keep(sr, sc, dr.abs(), dc.abs())
    }

    /// [`Cells::joins`] like [`Cells::keep_at`].
    fn joins_at(&self, r: isize, c: isize, dr: isize, dc: isize) -> bool {
        let (sr, sc) = upper_left(r, c, dr, dc);
        self.joins(sr, sc, dr.abs(), dc.abs())
    }

    /// Is the edge (r, c) → (r + dr, c + dc) kept?
    fn keep(&self, r: isize, c: isize, dr: isize, dc: isize) -> bool {
        self.joins(r, c, dr, dc) && !self.crease(r, c, dr, dc)
    }

    /// Is the edge (r, c) → (r + dr, c + dc) kept but for the crease rule: both cells
    /// occupied, not along the line of sight, no longer than [`EDGE_RATIO`] times its
    /// neighbours?
    fn joins(&self, r: isize, c: isize, dr: isize, dc: isize) -> bool {
        let (Some(a), Some(b)) = (self.get(r, c), self.get(r + dr, c + dc)) else {
            return false;
        };
        if self.edge_on(a, b) {
            return false;
        }
        let l = a.distance(b);
        let mut reference = f32::INFINITY;
        for x in [
            self.len(r - dr, c - dc, dr, dc),
            self.len(r + dr, c + dc, dr, dc),
        ]
        .into_iter()
        .flatten()
        {
            reference = reference.min(x);
        }
        if reference == f32::INFINITY {
            let (pr, pc) = (dc, dr); // perpendicular step
            for (rr, cc) in [(r, c), (r + dr, c + dc)] {
                for x in [self.len(rr, cc, pr, pc), self.len(rr - pr, cc - pc, pr, pc)]
                    .into_iter()
                    .flatten()
                {
                    reference = reference.min(x);
                }
            }
        }
        reference == f32::INFINITY || l <= EDGE_RATIO * reference
    }
}

/// The unit normal of point `i` (zero when there is none or it is zero).
fn unit(normals: &[Vec3], i: usize) -> Vec3 {
    normals
        .get(i)
        .copied()
        .unwrap_or(Vec3::ZERO)
        .normalize_or_zero()
}

/// The upper-left end of the edge from `(r, c)` to `(r + dr, c + dc)`.
fn upper_left(r: isize, c: isize, dr: isize, dc: isize) -> (isize, isize) {
    if dr + dc < 0 {
        (r + dr, c + dc)
    } else {
        (r, c)
    }
}

/// Triangles (indices into `points`) over a scan's native grid seen from the local origin;
/// see the module rule and [`triangulate_grid_seen`].
pub fn triangulate_grid(points: &[Vec3], grid: &Grid) -> Result<Vec<[u32; 3]>> {
    triangulate_grid_seen(points, grid, View::Origin)
}

/// Triangles (indices into `points`) over a scan's native grid; see the module rule. An
/// edge within [`MIN_VIEW_ANGLE_DEG`] of the line of sight of `view` is never kept.
/// `grid.row`/`grid.col` give each point's cell; points outside the grid are left out.
pub fn triangulate_grid_seen(points: &[Vec3], grid: &Grid, view: View) -> Result<Vec<[u32; 3]>> {
    triangulate_grid_creased(points, grid, view, &[])
}

/// [`triangulate_grid_seen`] with unit `normals` per point (empty: none): an edge whose ends
/// face more than [`CREASE_DEG`] apart crosses a crease and is not kept, so no triangle cuts
/// the corner (where two surfaces meet, a triangle from one to the other stands in front of
/// both and stops the rays of the points beside the corner early); [`grid_skirts`] closes
/// the corner instead.
pub fn triangulate_grid_creased(
    points: &[Vec3],
    grid: &Grid,
    view: View,
    normals: &[Vec3],
) -> Result<Vec<[u32; 3]>> {
    let g = Cells::with_normals(points, grid, view, normals)?;
    let per_row: Vec<Vec<[u32; 3]>> = (0..g.rows.saturating_sub(1))
        .into_par_iter()
        .map(|r| {
            let mut out = Vec::new();
            let ri = r as isize;
            for c in 0..g.cols.saturating_sub(1) {
                let ci = c as isize;
                let (a, b, cc, d) = (
                    g.idx(ri, ci),
                    g.idx(ri, ci + 1),
                    g.idx(ri + 1, ci),
                    g.idx(ri + 1, ci + 1),
                );
                let present = [a, b, cc, d].map(|i| i != u32::MAX);
                if present.iter().filter(|&&p| p).count() < 3 {
                    continue;
                }
                let ab = g.keep(ri, ci, 0, 1);
                let cd = g.keep(ri + 1, ci, 0, 1);
                let ac = g.keep(ri, ci, 1, 0);
                let bd = g.keep(ri, ci + 1, 1, 0);
                let diag_ad = match (
                    g.get(ri, ci),
                    g.get(ri + 1, ci + 1),
                    g.get(ri, ci + 1),
                    g.get(ri + 1, ci),
                ) {
                    (Some(pa), Some(pd), Some(pb), Some(pc)) => {
                        pa.distance_squared(pd) <= pb.distance_squared(pc)
                    }
                    // Three cells: the diagonal is the one whose ends are both present.
                    (Some(_), Some(_), _, _) => true,
                    _ => false,
                };
                if diag_ad {
                    if ab && bd {
                        out.push([a, b, d]);
                    }
                    if ac && cd {
                        out.push([a, d, cc]);
                    }
                } else {
                    if ab && ac {
                        out.push([a, b, cc]);
                    }
                    if bd && cd {
                        out.push([b, d, cc]);
                    }
                }
            }
            out
        })
        .collect();
    Ok(per_row.concat())
}

/// Surfel radii of a gridded scan for the reference: [`GRID_RADIUS_FACTOR`] times the longest
/// kept edge (the rule of [`triangulate_grid_seen`]) to the point's four grid neighbours,
/// each edge measured in the point's tangent plane (`normals[i]`; a zero normal takes the
/// whole edge); `fallback[i]` (usually `rad(p)`) for a point with no kept edge. Unlike
/// `rad(p)`, which spreads the 32 nearest neighbours over a disk, this neither swells on
/// one-cell-wide structures (a thin column far away, an edge) nor leaves gaps between the
/// stretched cells of a grazing floor. Measuring in the tangent plane keeps the disk of a
/// column's foot, whose grid neighbour below is a long cell of a grazing floor, from
/// reaching metres across the floor it stands on.
pub fn grid_radii(
    points: &[Vec3],
    grid: &Grid,
    view: View,
    normals: &[Vec3],
    fallback: &[f32],
) -> Result<Vec<f32>> {
    let g = Cells::new(points, grid, view)?;
    Ok((0..points.len())
        .into_par_iter()
        .map(|i| {
            let (r, c) = (grid.row[i] as isize, grid.col[i] as isize);
            let n = unit(normals, i);
            let mut longest = 0.0f32;
            let mut kept = 0;
            // Edges the triangulation keeps (towards a neighbour on this surface or across a
            // crease), as against a depth jump, an empty cell or the map's edge.
            let mut joined = 0;
            let mut any = 0.0f32;
            for (dr, dc) in [(0, 1), (1, 0), (0, -1), (-1, 0)] {
                if g.idx(r, c) == i as u32 && g.keep_at(r, c, dr, dc) {
                    joined += 1;
                    if let (Some(a), Some(b)) = (g.get(r, c), g.get(r + dr, c + dc)) {
                        let e = b - a;
                        any = any.max((e - n * e.dot(n)).length());
                        let along = e.dot(n);
                        if along.abs() <= EDGE_OFF_PLANE * e.length() {
                            longest = longest.max((e - n * along).length());
                            kept += 1;
                        }
                    }
                }
            }
            let f = fallback.get(i).copied().unwrap_or(0.0);
            // On a silhouette or beside a hole the disk may not reach past the corners of its
            // own pixel's footprint: beyond them lies what the neighbouring pixel saw instead.
            // Across a crease the other surface closes the gap, and a smaller disk would open
            // one into the corner.
            let held = |x: f32| match (joined < 4).then(|| g.footprint(r, c, n)).flatten() {
                Some(cell) => x.min(cell),
                None => x,
            };
            // Where no edge lies in the tangent plane (a normal estimated from noisy points
            // can be tens of degrees off), rad(p) would swell a thin structure's disk to
            // several times its width: it is held to the boundary size of the kept edges.
            let f = if any > 0.0 {
                f.min(BORDER_RADIUS_FACTOR * any)
            } else {
                f
            };
            if longest > 0.0 && longest.is_finite() {
                let f = if kept == 4 {
                    GRID_RADIUS_FACTOR
                } else {
                    BORDER_RADIUS_FACTOR
                };
                held(f * longest)
            } else {
                held(f)
            }
        })
        .collect())
}

/// Radii of the disks that close a grid triangulation's silhouettes and creases: a point on
/// a boundary of [`triangulate_grid_creased`] with the same `normals` (one of its four grid
/// edges not kept) gets a disk on its surface of half its pixel's pitch (the triangles stop
/// at the last sample, the surface goes on for half a pixel on average), and at a concave
/// crease as far as the other surface's sample lies along its surface (up to one pitch), so
/// that it reaches into the corner; 0 elsewhere.
pub fn grid_skirts(points: &[Vec3], grid: &Grid, view: View, normals: &[Vec3]) -> Result<Vec<f32>> {
    let g = Cells::with_normals(points, grid, view, normals)?;
    Ok((0..points.len())
        .into_par_iter()
        .map(|i| {
            let (r, c) = (grid.row[i] as isize, grid.col[i] as isize);
            if g.idx(r, c) != i as u32 {
                return 0.0;
            }
            let n = unit(normals, i);
            let p = points[i];
            // Half the pitch on a silhouette (the footprint's half-diagonal is
            // sqrt(area / 2), half its pitch sqrt(area) / 2); across a crease, as far as the
            // other surface's sample lies along this one (to the corner, not past it).
            let mut skirt = 0.0f32;
            // The footprint, found once on the first edge that is not kept.
            let mut half = None;
            for (dr, dc) in [(0, 1), (1, 0), (0, -1), (-1, 0)] {
                if g.keep_at(r, c, dr, dc) {
                    continue;
                }
                let h = *half
                    .get_or_insert_with(|| g.footprint(r, c, n).map_or(0.0, |h| h / 2f32.sqrt()));
                let reach = match g.get(r + dr, c + dc) {
                    // A concave crease: the other surface's sample stands in front of this
                    // one's plane, and a disk reaching into the corner ends in that surface.
                    // The corner lies within the next pixel: at most a whole pitch (a longer
                    // reach is an edge the ratio test let across a jump).
                    Some(q) if g.joins_at(r, c, dr, dc) && (q - p).dot(n) > 0.0 => {
                        let e = q - p;
                        (e - n * e.dot(n)).length().clamp(h, 2.0 * h)
                    }
                    _ => h,
                };
                skirt = skirt.max(reach);
            }
            skirt
        })
        .collect())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn grid_of(rows: u32, cols: u32, f: impl Fn(u32, u32) -> Option<Vec3>) -> (Vec<Vec3>, Grid) {
        let (mut pts, mut row, mut col) = (Vec::new(), Vec::new(), Vec::new());
        for r in 0..rows {
            for c in 0..cols {
                if let Some(p) = f(r, c) {
                    pts.push(p);
                    row.push(r);
                    col.push(c);
                }
            }
        }
        (
            pts,
            Grid {
                rows,
                cols,
                row,
                col,
            },
        )
    }

    #[test]
    fn flat_grid_gives_two_triangles_per_quad() {
        let (p, g) = grid_of(5, 6, |r, c| Some(Vec3::new(c as f32, r as f32, -1.0)));
        let t = triangulate_grid(&p, &g).unwrap();
        assert_eq!(t.len(), 2 * 4 * 5);
        // Total area = 4 × 5.
        let area: f32 = t
            .iter()
            .map(|t| {
                let [a, b, c] = t.map(|i| p[i as usize]);
                (b - a).cross(c - a).length() / 2.0
            })
            .sum();
        assert!((area - 20.0).abs() < 1e-4);
    }

    #[test]
    fn depth_step_is_not_bridged_but_grazing_stretch_is_kept() {
        // Columns 0..5 at depth 1, columns 5..10 at depth 3: no triangle across.
        let (p, g) = grid_of(6, 10, |r, c| {
            let z = if c < 5 { 1.0 } else { 3.0 };
            Some(Vec3::new(c as f32 * 0.01, r as f32 * 0.01, z))
        });
        let t = triangulate_grid(&p, &g).unwrap();
        assert_eq!(t.len(), 2 * 5 * (4 + 4));
        assert!(t.iter().all(|t| {
            let zs = t.map(|i| p[i as usize].z);
            zs.iter().all(|&z| z == zs[0])
        }));
        // A plane seen at grazing incidence: column spacing 10× the row spacing, smoothly
        // growing; every quad kept.
        let (p, g) = grid_of(6, 10, |r, c| {
            Some(Vec3::new(0.1 * (c as f32).powf(1.2), r as f32 * 0.01, -1.0))
        });
        assert_eq!(triangulate_grid(&p, &g).unwrap().len(), 2 * 5 * 9);
    }

    #[test]
    fn thin_foreground_is_cut_from_its_background_and_sized_by_its_own_cells() {
        // A one-column post at depth 2 before a wall at depth 5: the ratio test alone keeps
        // the jump edges (both neighbours of a jump are jumps), the line of sight drops them.
        let (p, g) = grid_of(8, 9, |r, c| {
            let (x, y) = (c as f32 * 0.01 - 0.04, r as f32 * 0.01);
            Some(if c == 4 {
                Vec3::new(2.0 * x, 2.0 * y, 2.0)
            } else {
                Vec3::new(5.0 * x, 5.0 * y, 5.0)
            })
        });
        let t = triangulate_grid(&p, &g).unwrap();
        assert!(t.iter().all(|t| {
            let zs = t.map(|i| p[i as usize].z);
            zs.iter().all(|&z| z == zs[0])
        }));
        let rad = vec![1.0f32; p.len()];
        let r = grid_radii(&p, &g, View::Origin, &[], &rad).unwrap();
        for (i, q) in p.iter().enumerate() {
            // Post cells are 0.02 apart (rows only: a boundary), wall cells 0.05; wall cells
            // beside the post or on the grid's edge are on a boundary too.
            let (row, col) = (g.row[i], g.col[i]);
            let inside = row > 0 && row < 7 && col > 0 && col < 8 && col != 3 && col != 5;
            let want = if q.z == 2.0 {
                BORDER_RADIUS_FACTOR * 0.02
            } else if inside {
                GRID_RADIUS_FACTOR * 0.05
            } else {
                BORDER_RADIUS_FACTOR * 0.05
            };
            assert!((r[i] - want).abs() < 1e-4, "{i} {q} {}", r[i]);
        }
    }

    #[test]
    fn edges_off_the_tangent_plane_do_not_size_the_disk() {
        // A wall tilted 45° to the line of sight; its last row is stepped 0.04 off its plane
        // (a crease): the edge down to it passes the line-of-sight and ratio tests but lies
        // steeply off the tangent plane, so the point above it is sized as a boundary point.
        let n = Vec3::new(1.0, 0.0, -1.0).normalize();
        let (p, g) = grid_of(3, 3, |r, c| {
            let x = c as f32 * 0.02 - 0.02;
            let wall = Vec3::new(x, r as f32 * 0.02, 2.0 + x);
            Some(if r < 2 { wall } else { wall + n * 0.04 })
        });
        let normals = vec![n; p.len()];
        let rad = vec![1.0f32; p.len()];
        let r = grid_radii(&p, &g, View::Origin, &normals, &rad).unwrap();
        let mid = (0..p.len())
            .find(|&i| g.row[i] == 1 && g.col[i] == 1)
            .unwrap();
        let want = BORDER_RADIUS_FACTOR * 0.02 * 2f32.sqrt();
        assert!((r[mid] - want).abs() < 1e-4, "{} {want}", r[mid]);
        // Without normals every kept edge counts: an inside point.
        let r = grid_radii(&p, &g, View::Origin, &[], &rad).unwrap();
        assert!(r[mid] > want * 1.2, "{}", r[mid]);
    }

    /// A floor seen at grazing incidence whose far row ends at the sky or at a wall.
    fn grazing_floor(wall: bool) -> (Vec<Vec3>, Grid, Vec<Vec3>) {
        let (p, g) = grid_of(14, 11, |r, c| {
            // Rows 0..4 look 6°..9° down (the wall, or sky), rows 4.. 10°..19° (the floor).
            let (el, az) = ((6.0 + r as f32).to_radians(), (c as f32 - 5.0).to_radians());
            let d = Vec3::new(az.sin() * el.cos(), -el.sin(), -az.cos() * el.cos());
            if r >= 4 {
                Some(d / el.sin())
            } else {
                wall.then(|| d * (5.95 / -d.z))
            }
        });
        let floor = |q: &Vec3| (q.y + 1.0).abs() < 1e-4;
        let normals = p
            .iter()
            .map(|q| if floor(q) { Vec3::Y } else { Vec3::Z })
            .collect();
        (p, g, normals)
    }

    /// The point at `(r, c)` of a grid.
    fn cell(p: &[Vec3], g: &Grid, r: u32, c: u32) -> usize {
        (0..p.len())
            .find(|&i| g.row[i] == r && g.col[i] == c)
            .unwrap()
    }

    /// The area of the footprint on the floor of [`grazing_floor`]'s far-row pixel at `q`
    /// (1° steps, 10° down).
    fn far_footprint(q: Vec3) -> f32 {
        let pitch = q.length() * 1f32.to_radians();
        pitch * pitch / 10f32.to_radians().sin()
    }

    #[test]
    fn boundary_disks_stay_within_their_pixel_but_creases_keep_theirs() {
        let (p, g, normals) = grazing_floor(false);
        let rad = vec![9.0f32; p.len()];
        let radii = grid_radii(&p, &g, View::Origin, &normals, &rad).unwrap();
        // The far row's cells are 0.1 m wide and 0.53 m deep: half their depth would reach
        // 0.26 m past the floor's last sample into the sky; their square of equal area has a
        // half-diagonal of 0.17 m.
        let far = cell(&p, &g, 4, 5);
        let depth = p[far].distance(p[cell(&p, &g, 5, 5)]);
        let square = (0.5 * far_footprint(p[far])).sqrt();
        assert!(
            square < 0.7 * BORDER_RADIUS_FACTOR * depth,
            "{square} {depth}"
        );
        assert!(
            (radii[far] - square).abs() < 0.02 * square,
            "{} {square}",
            radii[far]
        );
        // Inside the floor the covering disk is unchanged.
        let inside = cell(&p, &g, 8, 5);
        let longest = p[inside].distance(p[cell(&p, &g, 7, 5)]);
        assert!((radii[inside] - GRID_RADIUS_FACTOR * longest).abs() < 1e-4);
        // Where a wall stands 0.28 m behind the far row the floor runs on to it: joined on
        // every side, the disk is not held to its pixel.
        let (p, g, normals) = grazing_floor(true);
        let radii = grid_radii(&p, &g, View::Origin, &normals, &rad).unwrap();
        let far = cell(&p, &g, 4, 5);
        let want = GRID_RADIUS_FACTOR * p[far].distance(p[cell(&p, &g, 5, 5)]);
        assert!(want > 2.0 * square);
        assert!((radii[far] - want).abs() < 1e-4, "{} {want}", radii[far]);
    }

    #[test]
    fn skirts_close_silhouettes_and_concave_creases() {
        let (p, g, normals) = grazing_floor(false);
        let skirt = grid_skirts(&p, &g, View::Origin, &normals).unwrap();
        // The far row ends at the sky: half its pixel's pitch on the floor, the square root
        // of the footprint's area over two.
        let far = cell(&p, &g, 4, 5);
        let half = 0.5 * far_footprint(p[far]).sqrt();
        assert!(
            (skirt[far] - half).abs() < 0.02 * half,
            "{} {half}",
            skirt[far]
        );
        assert_eq!(skirt[cell(&p, &g, 8, 5)], 0.0);
        // A wall 0.28 m behind the far row: without normals it joins the floor (no skirt);
        // with them the edge crosses a concave crease, is cut from the triangulation, and
        // the floor's disk reaches to the wall's foot.
        let (p, g, normals) = grazing_floor(true);
        let far = cell(&p, &g, 4, 5);
        assert_eq!(grid_skirts(&p, &g, View::Origin, &[]).unwrap()[far], 0.0);
        let skirt = grid_skirts(&p, &g, View::Origin, &normals).unwrap();
        let foot = p[cell(&p, &g, 3, 5)] - p[far];
        let reach = (foot - Vec3::Y * foot.y).length();
        // The foot is 0.28 m away, past one pitch (0.24 m): held to the pitch.
        assert!(reach > 2.0 * half, "{reach} {half}");
        assert!(
            (skirt[far] - 2.0 * half).abs() < 0.04 * half,
            "{} {half}",
            skirt[far]
        );
        let tris = triangulate_grid_creased(&p, &g, View::Origin, &normals).unwrap();
        let wall = |i: u32| p[i as usize].y > -1.0 + 1e-4;
        assert!(tris
            .iter()
            .all(|t| t.iter().all(|&i| wall(i)) || !t.iter().any(|&i| wall(i))));
        assert!(triangulate_grid(&p, &g).unwrap().len() > tris.len());
    }

    #[test]
    fn holes_and_bad_grids() {
        let (p, g) = grid_of(3, 3, |r, c| {
            (!(r == 1 && c == 1)).then(|| Vec3::new(c as f32, r as f32, -1.0))
        });
        // Every block has 3 cells: one triangle each.
        assert_eq!(triangulate_grid(&p, &g).unwrap().len(), 4);
        let bad = Grid {
            rows: 3,
            cols: 3,
            row: vec![0],
            col: vec![0],
        };
        assert!(triangulate_grid(&p, &bad).is_err());
        let huge = Grid {
            rows: u32::MAX,
            cols: u32::MAX,
            row: vec![0; p.len()],
            col: vec![0; p.len()],
        };
        assert!(triangulate_grid(&p, &huge).is_err());
    }
}
