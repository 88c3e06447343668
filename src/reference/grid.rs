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

/// Largest grid (in cells) accepted relative to the number of points: a cell index table of
/// `max(16·n, 2²⁴)` entries.
fn max_cells(n: usize) -> u64 {
    (16 * n as u64).max(1 << 24)
}

/// Triangles (indices into `points`) over a scan's native grid; see the module rule.
/// `grid.row`/`grid.col` give each point's cell; points outside the grid are left out.
pub fn triangulate_grid(points: &[Vec3], grid: &Grid) -> Result<Vec<[u32; 3]>> {
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
    let get = |r: isize, c: isize| -> Option<Vec3> {
        if r < 0 || c < 0 || r as usize >= rows || c as usize >= cols {
            return None;
        }
        let i = at[r as usize * cols + c as usize];
        (i != u32::MAX).then(|| points[i as usize])
    };
    // Length of the edge from (r, c) to (r + dr, c + dc), if both cells are occupied.
    let len = |r: isize, c: isize, dr: isize, dc: isize| -> Option<f32> {
        Some(get(r, c)?.distance(get(r + dr, c + dc)?))
    };
    // Is the edge (r, c) → (r + dr, c + dc) kept?
    let keep = |r: isize, c: isize, dr: isize, dc: isize| -> bool {
        let Some(l) = len(r, c, dr, dc) else {
            return false;
        };
        let mut reference = f32::INFINITY;
        for x in [len(r - dr, c - dc, dr, dc), len(r + dr, c + dc, dr, dc)]
            .into_iter()
            .flatten()
        {
            reference = reference.min(x);
        }
        if reference == f32::INFINITY {
            let (pr, pc) = (dc, dr); // perpendicular step
            for (rr, cc) in [(r, c), (r + dr, c + dc)] {
                for x in [len(rr, cc, pr, pc), len(rr - pr, cc - pc, pr, pc)]
                    .into_iter()
                    .flatten()
                {
                    reference = reference.min(x);
                }
            }
        }
        reference == f32::INFINITY || l <= EDGE_RATIO * reference
    };
    let idx = |r: usize, c: usize| at[r * cols + c];
    let per_row: Vec<Vec<[u32; 3]>> = (0..rows.saturating_sub(1))
        .into_par_iter()
        .map(|r| {
            let mut out = Vec::new();
            let ri = r as isize;
            for c in 0..cols.saturating_sub(1) {
                let ci = c as isize;
                let (a, b, cc, d) = (idx(r, c), idx(r, c + 1), idx(r + 1, c), idx(r + 1, c + 1));
                let present = [a, b, cc, d].map(|i| i != u32::MAX);
                if present.iter().filter(|&&p| p).count() < 3 {
                    continue;
                }
                let ab = keep(ri, ci, 0, 1);
                let cd = keep(ri + 1, ci, 0, 1);
                let ac = keep(ri, ci, 1, 0);
                let bd = keep(ri, ci + 1, 1, 0);
                let diag_ad = match (
                    get(ri, ci),
                    get(ri + 1, ci + 1),
                    get(ri, ci + 1),
                    get(ri + 1, ci),
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
        let (p, g) = grid_of(5, 6, |r, c| Some(Vec3::new(c as f32, r as f32, 0.0)));
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
            Some(Vec3::new(0.1 * (c as f32).powf(1.2), r as f32 * 0.01, 0.0))
        });
        assert_eq!(triangulate_grid(&p, &g).unwrap().len(), 2 * 5 * 9);
    }

    #[test]
    fn holes_and_bad_grids() {
        let (p, g) = grid_of(3, 3, |r, c| {
            (!(r == 1 && c == 1)).then(|| Vec3::new(c as f32, r as f32, 0.0))
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
