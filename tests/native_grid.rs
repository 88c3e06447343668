//! Native grids with bad entries: a few bad references are dropped and the rest of the grid
//! kept, a grid mostly bad or of inconsistent size is dropped, and every such case is a
//! warning naming the file that reaches `mvao info` and `mvao merge`.

mod common;

use common::*;
use mvao::io::dataset::{Dataset, PlaceOptions};
use mvao::testing::gbuffer;
use mvao::testing::projection::SensorModel;
use mvao::testing::scan::{Scan, NO_CELL};
use mvao::testing::sensor::{self, ProjectionChoice};
use std::fmt::Write as _;
use std::path::{Path, PathBuf};

/// Grid side of the test scans.
const N: usize = 30;

/// A height field seen from above (a bump and a trench): vertex `k` lies at row `k / N`,
/// column `k % N`, which an orthographic model fits exactly.
fn field() -> Vec<[f64; 3]> {
    let s = 0.02;
    (0..N * N)
        .map(|k| {
            let (x, y) = ((k / N) as f64 * s, (k % N) as f64 * s);
            let mut z = 0.05 * (-((x - 0.3).powi(2) + (y - 0.3).powi(2)) / 0.005).exp();
            if 0.1 < x && x < 0.15 {
                z -= 0.03;
            }
            [x, y, z]
        })
        .collect()
}

/// An ASCII PLY of `field()` with the extra header lines `head`, per-vertex extra values
/// `extra(k)` (after x y z) and the body lines `tail` after the vertices.
fn write_ply(
    dir: &Path,
    name: &str,
    head: &str,
    extra: impl Fn(usize) -> String,
    tail: &str,
) -> PathBuf {
    let pts = field();
    // obj_info lines first, then the vertex element, then the rest of `head`.
    let (obj, rest): (Vec<&str>, Vec<&str>) = head
        .lines()
        .partition(|l| l.starts_with("obj_info") || l.starts_with("comment"));
    let mut s = String::from("ply\nformat ascii 1.0\n");
    for l in obj {
        let _ = writeln!(s, "{l}");
    }
    let _ = writeln!(s, "element vertex {}", pts.len());
    s += "property float x\nproperty float y\nproperty float z\n";
    for l in rest {
        let _ = writeln!(s, "{l}");
    }
    s += "end_header\n";
    for (k, p) in pts.iter().enumerate() {
        let _ = writeln!(s, "{} {} {} {}", p[0], p[1], p[2], extra(k));
    }
    s += tail;
    let path = dir.join(name);
    std::fs::write(&path, s).unwrap();
    path
}

/// A Stanford range grid of `N × N` cells whose entry `e` lists `entry(e)` (`None` = empty).
fn range_grid_ply(
    dir: &Path,
    name: &str,
    dims: (usize, usize),
    entry: impl Fn(usize) -> Option<i64>,
) -> PathBuf {
    let head = format!(
        "obj_info num_cols {}\nobj_info num_rows {}\nelement range_grid {}\n\
         property list uchar int vertex_indices\n",
        dims.0,
        dims.1,
        N * N
    );
    let mut tail = String::new();
    for e in 0..N * N {
        match entry(e) {
            Some(v) => {
                let _ = writeln!(tail, "1 {v}");
            }
            None => tail += "0\n",
        }
    }
    write_ply(dir, name, &head, |_| String::new(), &tail)
}

/// A PLY with per-vertex `row`/`col` indices `cell(k)`.
fn row_col_ply(dir: &Path, name: &str, cell: impl Fn(usize) -> (i64, i64)) -> PathBuf {
    write_ply(
        dir,
        name,
        "property int row\nproperty int col\n",
        |k| {
            let (r, c) = cell(k);
            format!("{r} {c}")
        },
        "",
    )
}

/// The file's one scan as the dataset places it, with the dataset's warnings.
fn open(path: &Path) -> (Scan, Vec<String>) {
    let ds = Dataset::open(&[path.to_path_buf()], &PlaceOptions::default(), &|| {}).unwrap();
    let warnings = ds.warnings.clone();
    (ds.scans.into_iter().next().unwrap(), warnings)
}

/// The one warning containing `needle`; it must name the file.
fn warning<'a>(warnings: &'a [String], path: &Path, needle: &str) -> &'a str {
    let hits: Vec<&String> = warnings.iter().filter(|w| w.contains(needle)).collect();
    assert_eq!(hits.len(), 1, "'{needle}' in {warnings:?}");
    assert!(hits[0].contains(&path.display().to_string()), "{}", hits[0]);
    hits[0]
}

#[test]
fn valid_range_grid_is_used_without_warning() {
    let dir = tempfile::tempdir().unwrap();
    let p = range_grid_ply(dir.path(), "valid.ply", (N, N), |e| Some(e as i64));
    let (scan, warnings) = open(&p);
    assert!(warnings.is_empty(), "{warnings:?}");
    let g = scan.grid.as_ref().unwrap();
    assert_eq!((g.rows, g.cols, g.uncelled()), (N as u32, N as u32, 0));
    assert_eq!(g.occupied_cells(), N * N);
    let setup = sensor::setup(&scan, ProjectionChoice::Auto).unwrap();
    assert_eq!(setup.projection.sensor_model(), SensorModel::Ortho);
    assert!(setup.grid_pixels.is_some(), "{}", setup.reason);
}

#[test]
fn range_grid_with_one_bad_index_keeps_its_other_cells() {
    let dir = tempfile::tempdir().unwrap();
    let bad = 417;
    let p = range_grid_ply(dir.path(), "one_oob.ply", (N, N), |e| {
        Some(if e == bad { 999_999 } else { e as i64 })
    });
    let (scan, warnings) = open(&p);
    warning(&warnings, &p, "1 of the 900 range_grid references dropped");
    warning(&warnings, &p, "1 of 900 points have no cell");
    let g = scan.grid.as_ref().unwrap();
    assert_eq!((g.rows, g.cols), (N as u32, N as u32));
    assert_eq!((g.row[bad], g.col[bad]), (NO_CELL, NO_CELL));
    assert_eq!(g.uncelled(), 1);
    // The sensor model stays the grid's, and the point that lost its cell is placed by it
    // where the cell was.
    let setup = sensor::setup(&scan, ProjectionChoice::Auto).unwrap();
    assert_eq!(setup.projection.sensor_model(), SensorModel::Ortho);
    let px = setup.grid_pixels.as_ref().expect("native grid kept");
    let valid = range_grid_ply(dir.path(), "valid.ply", (N, N), |e| Some(e as i64));
    let (vscan, _) = open(&valid);
    let vsetup = sensor::setup(&vscan, ProjectionChoice::Auto).unwrap();
    assert_eq!(px, vsetup.grid_pixels.as_ref().unwrap());
}

#[test]
fn range_grid_with_negative_index_keeps_its_other_cells() {
    let dir = tempfile::tempdir().unwrap();
    let p = range_grid_ply(dir.path(), "neg.ply", (N, N), |e| {
        Some(if e == 5 { -1 } else { e as i64 })
    });
    let (scan, warnings) = open(&p);
    warning(&warnings, &p, "1 of the 900 range_grid references dropped");
    assert_eq!(scan.grid.as_ref().unwrap().uncelled(), 1);
}

#[test]
fn range_grid_mostly_invalid_is_dropped_with_a_warning() {
    let dir = tempfile::tempdir().unwrap();
    // Every fifth entry names no vertex: 20 % bad.
    let p = range_grid_ply(dir.path(), "oob.ply", (N, N), |e| {
        Some(if e % 5 == 0 {
            5000 + e as i64
        } else {
            e as i64
        })
    });
    let (scan, warnings) = open(&p);
    let w = warning(&warnings, &p, "range_grid references are invalid");
    assert!(w.contains("180 of the 900"), "{w}");
    assert!(w.contains("sensor model fitted to the points"), "{w}");
    assert!(scan.grid.is_none());
    let setup = sensor::setup(&scan, ProjectionChoice::Auto).unwrap();
    assert!(setup.grid_pixels.is_none());

    // Every entry naming the same vertex.
    let p = range_grid_ply(dir.path(), "same.ply", (N, N), |_| Some(0));
    let (scan, warnings) = open(&p);
    let w = warning(&warnings, &p, "range_grid references are invalid");
    assert!(w.contains("899 repeating a vertex"), "{w}");
    assert!(scan.grid.is_none());
}

#[test]
fn range_grid_of_inconsistent_size_is_dropped_with_a_warning() {
    let dir = tempfile::tempdir().unwrap();
    for (name, dims) in [("dims.ply", (7, 13)), ("zero.ply", (0, 0))] {
        let p = range_grid_ply(dir.path(), name, dims, |e| Some(e as i64));
        let (scan, warnings) = open(&p);
        let w = warning(&warnings, &p, "range_grid element has 900 entries");
        assert!(
            w.contains(&format!("num_cols {} × num_rows {}", dims.0, dims.1)),
            "{w}"
        );
        assert!(w.contains("sensor model fitted to the points"), "{w}");
        assert!(scan.grid.is_none());
    }
    // No size at all.
    let head = format!(
        "element range_grid {}\nproperty list uchar int vertex_indices\n",
        N * N
    );
    let tail: String = (0..N * N).map(|e| format!("1 {e}\n")).collect();
    let p = write_ply(dir.path(), "nosize.ply", &head, |_| String::new(), &tail);
    let (scan, warnings) = open(&p);
    warning(
        &warnings,
        &p,
        "obj_info gives no usable num_cols and num_rows",
    );
    assert!(scan.grid.is_none());
}

#[test]
fn row_col_grid_with_every_point_in_one_cell_is_dropped() {
    let dir = tempfile::tempdir().unwrap();
    let p = row_col_ply(dir.path(), "dup.ply", |_| (0, 0));
    let (scan, warnings) = open(&p);
    let w = warning(&warnings, &p, "already holding another point");
    assert!(w.contains("899 of 900 points"), "{w}");
    assert!(w.contains("sensor model fitted to the points"), "{w}");
    assert!(scan.grid.is_none());
    let setup = sensor::setup(&scan, ProjectionChoice::Auto).unwrap();
    assert!(setup.grid_pixels.is_none());
    assert!(setup.projection.width * setup.projection.height > 1);
}

#[test]
fn row_col_grid_with_a_few_duplicates_keeps_the_nearest_per_cell() {
    let dir = tempfile::tempdir().unwrap();
    // Nine points (1 %) claim the cell of the point before them.
    let dup = |k: usize| k % 100 == 51;
    let p = row_col_ply(dir.path(), "fewdup.ply", |k| {
        let k = if dup(k) { k - 1 } else { k };
        ((k / N) as i64, (k % N) as i64)
    });
    let (scan, warnings) = open(&p);
    warning(
        &warnings,
        &p,
        "9 of 900 points fall in a native grid cell already holding",
    );
    let g = scan.grid.as_ref().unwrap();
    assert_eq!(g.occupied_cells(), N * N - 9);
    let setup = sensor::setup(&scan, ProjectionChoice::Auto).unwrap();
    let gp = setup.grid_pixels.as_ref().expect("native grid kept");
    // Both points of a shared cell land in its pixel; the G-buffer holds the nearer one.
    let proj = &setup.projection;
    let (pixel, depth) = gbuffer::point_pixels(&scan.points, proj, Some(gp));
    let ones = vec![1.0f32; scan.len()];
    let normals = vec![glam::Vec3::Z; scan.len()];
    let gb = gbuffer::rasterize(
        proj.width,
        proj.height,
        &pixel,
        &depth,
        &scan.points,
        &normals,
        &ones,
    );
    for k in (0..scan.len()).filter(|&k| dup(k)) {
        assert_eq!(pixel[k], pixel[k - 1]);
        let held = gb.point[pixel[k] as usize] as usize;
        // Ties go to the lower index.
        let nearer = if depth[k] < depth[k - 1] { k } else { k - 1 };
        assert_eq!(held, nearer);
    }
    assert_eq!(gb.filled(), N * N - 9);
}

#[test]
fn row_col_grid_with_a_few_invalid_indices_keeps_its_other_cells() {
    let dir = tempfile::tempdir().unwrap();
    let p = row_col_ply(dir.path(), "neg.ply", |k| match k {
        3 => (-5, 3),
        7 => (0, 1 << 30),
        _ => ((k / N) as i64, (k % N) as i64),
    });
    let (scan, warnings) = open(&p);
    warning(
        &warnings,
        &p,
        "2 vertices have row/col values that are not grid indices",
    );
    warning(&warnings, &p, "2 of 900 points have no cell");
    let g = scan.grid.as_ref().unwrap();
    assert_eq!((g.rows, g.cols, g.uncelled()), (N as u32, N as u32, 2));
    let setup = sensor::setup(&scan, ProjectionChoice::Auto).unwrap();
    assert!(setup.grid_pixels.is_some(), "{}", setup.reason);
}

#[test]
fn info_prints_grid_warnings_and_never_fills_beyond_the_grid() {
    let dir = tempfile::tempdir().unwrap();
    let p = range_grid_ply(dir.path(), "one_oob.ply", (N, N), |e| {
        Some(if e == 10 { 999_999 } else { e as i64 })
    });
    let text = mvao_ok(&["info", p.to_str().unwrap()]);
    let want = format!(
        "warning: {}: 1 of the 900 range_grid references dropped",
        p.display()
    );
    assert!(text.contains(&want), "{text}");
    assert!(text.contains("grid:       30 rows × 30 columns"), "{text}");
    assert!(text.contains("ortho"), "{text}");

    let p = row_col_ply(dir.path(), "fewdup.ply", |k| {
        let k = if k % 100 == 51 { k - 1 } else { k };
        ((k / N) as i64, (k % N) as i64)
    });
    let r = mvao(&["info", "--json", p.to_str().unwrap()]);
    assert!(r.status.success());
    let v: serde_json::Value = serde_json::from_slice(&r.stdout).unwrap();
    let filled = v["scans"][0]["grid_filled"].as_f64().unwrap();
    assert!((filled - 891.0 / 900.0).abs() < 1e-9, "{filled}");
    assert!(v["warnings"].as_array().unwrap().iter().any(|w| w
        .as_str()
        .unwrap()
        .contains("already holding another point")));
}

#[test]
fn merge_of_a_sparse_grid_sizes_memory_for_the_resampled_map() {
    let dir = tempfile::tempdir().unwrap();
    // Cells 10⁵ apart: a grid of about 3·10⁶ × 3·10⁶ cells, resampled from the points.
    let p = row_col_ply(dir.path(), "huge.ply", |k| {
        ((k / N) as i64 * 100_000, (k % N) as i64 * 100_000)
    });
    let out = dir.path().join("out");
    let text = mvao_ok(&[
        "merge",
        "--max-memory",
        "1G",
        "-o",
        out.to_str().unwrap(),
        p.to_str().unwrap(),
    ]);
    assert!(!text.contains("--max-memory"), "{text}");
}
