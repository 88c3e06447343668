//! Neighbours from the native grid agree with the k-d tree on real gridded scans, within the
//! tolerance the docs state: median radius difference under 5 %, median normal angle under 5°.

mod common;

use common::*;
use mvao::io::ply::scan::read_scan;
use mvao::testing::scan::normals;
use mvao::testing::sensor::{self, ProjectionChoice};

fn compare(path: &std::path::Path) -> (f32, f32) {
    let (scan, _) = read_scan(path).unwrap();
    let setup = sensor::setup(&scan, ProjectionChoice::Auto).unwrap();
    let toward = |p| setup.projection.toward_sensor(p);
    let (nt, rt) = normals::estimate(&scan.points, true, toward);
    let (ng, rg) = normals::estimate_grid(&scan.points, scan.grid.as_ref().unwrap(), true, toward);
    medians(&rt, &rg, &nt.unwrap(), &ng.unwrap())
}

/// Median relative difference of radii `ra` and `rb` and median angle (degrees) between
/// normals `na` and `nb`.
fn medians(ra: &[f32], rb: &[f32], na: &[glam::Vec3], nb: &[glam::Vec3]) -> (f32, f32) {
    let mut dr: Vec<f32> = ra
        .iter()
        .zip(rb)
        .map(|(a, b)| (a - b).abs() / a.max(1e-9))
        .collect();
    let mut da: Vec<f32> = na
        .iter()
        .zip(nb)
        .map(|(a, b)| a.dot(*b).clamp(-1.0, 1.0).acos().to_degrees())
        .collect();
    dr.sort_by(f32::total_cmp);
    da.sort_by(f32::total_cmp);
    (dr[dr.len() / 2], da[da.len() / 2])
}

#[test]
fn grid_neighbours_match_the_kd_tree() {
    for p in plys("stanford-bunny")
        .iter()
        .take(3)
        .chain(plys("3dtk-uos-3scans").iter())
    {
        let (dr, da) = compare(p);
        eprintln!("{}: radius {dr:.4}, normal {da:.2}°", p.display());
        assert!(dr < 0.05, "{}: median radius difference {dr}", p.display());
        assert!(da < 5.0, "{}: median normal angle {da}°", p.display());
    }
}

/// The cell grid's neighbours are the k-d tree's: identical radii on every point, identical
/// normals except where distances tie among a point's 17 nearest (the two searches may then
/// order or choose the tied points differently).
#[test]
fn cell_grid_neighbours_are_the_kd_trees() {
    use kiddo::{ImmutableKdTree, SquaredEuclidean};
    for p in plys("stanford-bunny")
        .iter()
        .take(2)
        .chain(plys("3dtk-uos-3scans").iter().take(1))
    {
        let (scan, _) = read_scan(p).unwrap();
        let pts = &scan.points;
        assert!(pts.len() >= normals::VOXEL_MIN_POINTS, "{}", p.display());
        assert!(mvao::testing::scan::knn::VoxelGrid::new(pts, normals::K_RADIUS).is_some());
        let toward = |q: glam::Vec3| (-q).normalize_or_zero();
        let (nv, rv) = normals::estimate(pts, true, toward);
        let (nt, rt) = normals::estimate_kdtree(pts, true, toward);
        let (nv, nt) = (nv.unwrap(), nt.unwrap());
        let same_radii = rv.iter().zip(&rt).all(|(a, b)| a.to_bits() == b.to_bits());
        assert!(same_radii, "{}: radii differ", p.display());
        let coords: Vec<[f32; 3]> = pts.iter().map(|q| q.to_array()).collect();
        let tree: ImmutableKdTree<f32, 3> = ImmutableKdTree::new_from_slice(&coords);
        let k17 = std::num::NonZeroUsize::new(17).unwrap();
        let mut differ = 0;
        for i in (0..pts.len()).filter(|&i| nv[i] != nt[i]) {
            let nb = tree.nearest_n::<SquaredEuclidean>(&coords[i], k17);
            let tied = nb.windows(2).any(|w| w[0].distance == w[1].distance);
            assert!(
                tied,
                "{}: point {i}'s normal differs without a tie",
                p.display()
            );
            differ += 1;
        }
        eprintln!(
            "{}: {} points, {differ} normals differ at ties",
            p.display(),
            pts.len()
        );
    }
}

/// The share of a map's filled pixels beside a one-pixel hole (an empty pixel whose left and
/// right, or upper and lower, neighbours are filled) and the share of points that share their
/// pixel with another.
fn holes_and_sharing(
    points: &[glam::Vec3],
    proj: &mvao::testing::projection::Projection,
) -> (f64, f64) {
    use mvao::testing::gbuffer::{point_pixels, EMPTY};
    let (px, _) = point_pixels(points, proj, None);
    let (w, h) = (proj.width, proj.height);
    let mut filled = vec![false; w * h];
    let mut shared = 0usize;
    for &p in px.iter().filter(|&&p| p != EMPTY) {
        shared += usize::from(filled[p as usize]);
        filled[p as usize] = true;
    }
    let at = |x: usize, y: usize| filled[y * w + x];
    let mut holes = 0usize;
    for y in 1..h.saturating_sub(1) {
        for x in 1..w.saturating_sub(1) {
            if !at(x, y) && ((at(x - 1, y) && at(x + 1, y)) || (at(x, y - 1) && at(x, y + 1))) {
                holes += 1;
            }
        }
    }
    let n = filled.iter().filter(|&&f| f).count().max(1) as f64;
    (holes as f64 / n, shared as f64 / points.len().max(1) as f64)
}

/// Median relative radius difference and median normal angle (degrees) between the normals
/// and radii `scan_normals` gives a scan and its exact k nearest neighbours'.
fn against_exact(scan: &mvao::Scan, setup: &sensor::SensorSetup) -> (f32, f32, String) {
    let (n, r, note) = mvao::testing::view::scan_normals(scan, setup);
    let toward = |q| setup.projection.toward_sensor(q);
    let (nt, rt) = normals::estimate(&scan.points, true, toward);
    let (dr, da) = medians(&rt, &r, &nt.unwrap(), &n);
    (dr, da, note)
}

/// Scanner stations stored without their grid (and without normals): the map built from the
/// loose points is a little coarser than the scanner's grid, so surfaces have no holes, and
/// neighbours come from a grid over the sensor's image, as close to the exact ones as a native
/// grid's are.
#[test]
fn loose_scanner_points_get_a_map_without_holes_and_image_neighbours() {
    use mvao::synth::{scan_scene, station_layout, SceneKind};
    use mvao::testing::projection::SensorModel;
    let kind = SceneKind::Suite { rooms: 2 };
    for (model, w, h) in [
        (SensorModel::Equirect, 720, 360),
        (SensorModel::Perspective, 320, 240),
    ] {
        let st = station_layout(kind, model, 4, w, h)[1];
        let mut scan = scan_scene(&kind.scene(), &st, 0.002, 0, "s");
        scan.normals = None;
        let native = sensor::setup(&scan, ProjectionChoice::Auto).unwrap();
        let (ndr, nda, nnote) = against_exact(&scan, &native);
        eprintln!("native: radius {ndr:.4}, normal {nda:.2}°, {nnote}");
        scan.grid = None;
        scan.normals = None;
        scan.sensor_hint = None;
        let setup = sensor::setup(&scan, ProjectionChoice::Auto).unwrap();
        assert_eq!(setup.projection.sensor_model(), model, "{}", setup.reason);
        let (mw, mh) = (setup.projection.width, setup.projection.height);
        let (holes, shared) = holes_and_sharing(&scan.points, &setup.projection);
        let (dr, da, note) = against_exact(&scan, &setup);
        eprintln!(
            "{model:?} {w}x{h}: map {mw}x{mh}, holes {holes:.4}, shared {shared:.4}, radius {dr:.4}, normal {da:.2}°, {note}"
        );
        if model == SensorModel::Equirect {
            let scale = w as f64 / mw as f64;
            assert!((1.0..1.07).contains(&scale), "map {mw} wide for a {w} grid");
        }
        assert!(
            holes < 0.002,
            "{model:?}: {holes} of the pixels are one-pixel holes"
        );
        assert!(
            shared < 0.1,
            "{model:?}: {shared} of the points share a pixel"
        );
        assert!(note.contains("sensor's image"), "{model:?}: {note}");
        assert!(
            dr < 0.05 && da < 5.0,
            "{model:?}: radius {dr}, normal {da}°"
        );
    }
}

/// Real scans stored without their grid (the bunny's Cyberware scans, a 3DTK station):
/// whichever neighbour path their map allows agrees with the exact neighbours.
#[test]
fn loose_real_scans_keep_exact_neighbours() {
    let mut files: Vec<_> = plys("stanford-bunny").into_iter().take(2).collect();
    files.extend(plys("3dtk-uos-3scans").into_iter().take(1));
    for p in &files {
        let (mut scan, _) = read_scan(p).unwrap();
        scan.grid = None;
        scan.normals = None;
        let setup = sensor::setup(&scan, ProjectionChoice::Auto).unwrap();
        let (dr, da, note) = against_exact(&scan, &setup);
        eprintln!("{}: radius {dr:.4}, normal {da:.2}°, {note}", p.display());
        assert!(
            dr < 0.05 && da < 5.0,
            "{}: radius {dr}, normal {da}°",
            p.display()
        );
    }
}

/// `scan` turned by `turn` in its own frame and stripped of grid, normals and declared sensor,
/// with the automatic map and that map's one-pixel holes and shared pixels.
fn loose_map(
    mut scan: mvao::Scan,
    turn: glam::Quat,
) -> (mvao::Scan, sensor::SensorSetup, f64, f64) {
    for p in &mut scan.points {
        *p = turn * *p;
    }
    scan.grid = None;
    scan.normals = None;
    scan.sensor_hint = None;
    let setup = sensor::setup(&scan, ProjectionChoice::Auto).unwrap();
    let (holes, shared) = holes_and_sharing(&scan.points, &setup.projection);
    (scan, setup, holes, shared)
}

/// A linear scanner stored without grid: its frame's origin is not where its rays meet, so
/// the map is orthographic, and it steps its sweep 3× its line, at 30° to the frame's axes:
/// the map follows both steps and the direction (about one pixel per point, no holes).
#[test]
fn loose_linear_scans_get_an_orthographic_map_with_their_own_steps() {
    use glam::{DVec2, DVec3, Quat};
    use mvao::synth::{scan_scene, SceneKind, Station};
    use mvao::testing::projection::SensorModel;
    let st = Station::ortho(
        DVec3::new(0.0, 0.0, 2.9),
        0.0,
        DVec2::new(3.0, 2.0),
        300,
        67,
    );
    let scan = scan_scene(&SceneKind::Room.scene(), &st, 0.0, 0, "s");
    let turn = Quat::from_rotation_z(30f32.to_radians());
    let (scan, setup, holes, shared) = loose_map(scan, turn);
    let proj = &setup.projection;
    let fill = scan.len() as f64 / (proj.width * proj.height) as f64;
    eprintln!(
        "{}x{} px, {fill:.3} points per pixel, holes {holes:.4}, shared {shared:.4}: {}",
        proj.width, proj.height, setup.reason
    );
    assert_eq!(proj.sensor_model(), SensorModel::Ortho, "{}", setup.reason);
    assert!(holes < 0.002, "{holes} of the pixels are one-pixel holes");
    assert!(shared < 0.1, "{shared} of the points share a pixel");
    // A map along the frame's axes would leave half its pixels outside the turned rectangle.
    assert!(fill > 0.85, "{fill} points per pixel");
}

/// The bunny's scans stored without grid: a Cyberware scanner sweeps linearly, so the map is
/// orthographic along −z, with the row step 1.45 × the column step the points show.
#[test]
fn loose_cyberware_scans_get_an_orthographic_map() {
    use mvao::testing::projection::SensorModel;
    for p in plys("stanford-bunny").into_iter().take(3) {
        let (mut scan, _) = read_scan(&p).unwrap();
        scan.grid = None;
        scan.normals = None;
        let setup = sensor::setup(&scan, ProjectionChoice::Auto).unwrap();
        let (holes, shared) = holes_and_sharing(&scan.points, &setup.projection);
        eprintln!(
            "{}: holes {holes:.4}, shared {shared:.4}, {}",
            p.display(),
            setup.reason
        );
        assert_eq!(
            setup.projection.sensor_model(),
            SensorModel::Ortho,
            "{}",
            setup.reason
        );
        assert!(
            shared < 0.2 && holes < 0.05,
            "{}: holes {holes}, shared {shared}",
            p.display()
        );
    }
}

/// A station written with its pole along local y (as 3DTK writes them) and without grid: the
/// map takes the pole its even sampling shows, so it is as clean as with the pole along z.
#[test]
fn loose_stations_find_their_pole() {
    use glam::Quat;
    use mvao::synth::{scan_scene, station_layout, SceneKind};
    use mvao::testing::projection::SensorModel;
    let kind = SceneKind::Suite { rooms: 2 };
    let st = station_layout(kind, SensorModel::Equirect, 4, 720, 360)[1];
    let scan = scan_scene(&kind.scene(), &st, 0.002, 0, "s");
    let z_to_y = Quat::from_rotation_x(-90f32.to_radians());
    let (_, setup, holes, shared) = loose_map(scan, z_to_y);
    let proj = &setup.projection;
    eprintln!(
        "{}x{} px, holes {holes:.4}, shared {shared:.4}: {}",
        proj.width, proj.height, setup.reason
    );
    assert_eq!(proj.sensor_model(), SensorModel::Equirect);
    let scale = 720.0 / proj.width as f64;
    assert!((1.0..1.07).contains(&scale), "map {} wide", proj.width);
    assert!(holes < 0.002, "{holes} of the pixels are one-pixel holes");
    assert!(shared < 0.1, "{shared} of the points share a pixel");
}
