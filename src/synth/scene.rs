//! Synthetic scenes: lists of analytic primitives with nearest-hit ray casting, and the two
//! built-in scenes ([`Scene::room`], [`Scene::courtyard`]). World frame: metres, z up.

use super::prim::Prim;
use glam::DVec3;

/// Smallest ray parameter [`Scene::intersect`] accepts (metres for a unit direction).
pub const T_EPS: f64 = 1e-9;

/// The nearest surface a ray meets.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Hit {
    /// Ray parameter of the hit (distance when the direction is a unit vector).
    pub t: f64,
    /// Exact unit front normal of the primitive at the hit (see [`Prim`]); not oriented
    /// towards the ray.
    pub normal: DVec3,
    /// Index of the primitive in [`Scene::prims`].
    pub prim: usize,
}

/// An analytic scene: a list of primitives.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Scene {
    /// The primitives, in no particular order.
    pub prims: Vec<Prim>,
}

impl Scene {
    /// Nearest hit of the ray `origin + t·dir` with `t > T_EPS`.
    pub fn intersect(&self, origin: DVec3, dir: DVec3) -> Option<Hit> {
        self.intersect_range(origin, dir, T_EPS, f64::INFINITY)
    }

    /// Nearest hit of the ray `origin + t·dir` with `t ∈ (t_min, t_max)`.
    pub fn intersect_range(
        &self,
        origin: DVec3,
        dir: DVec3,
        t_min: f64,
        t_max: f64,
    ) -> Option<Hit> {
        let mut best: Option<Hit> = None;
        let mut limit = t_max;
        for (i, p) in self.prims.iter().enumerate() {
            if let Some((t, normal)) = p.intersect(origin, dir, t_min, limit) {
                limit = t;
                best = Some(Hit { t, normal, prim: i });
            }
        }
        best
    }

    /// True when `p` lies strictly inside one of the scene's solid primitives.
    pub fn inside_solid(&self, p: DVec3) -> bool {
        self.prims.iter().any(|q| q.contains(p))
    }

    /// Axis-aligned bounds `(min, max)` of all primitives (zero box for an empty scene).
    pub fn bounds(&self) -> (DVec3, DVec3) {
        let mut it = self.prims.iter().map(Prim::bounds);
        let Some(first) = it.next() else {
            return (DVec3::ZERO, DVec3::ZERO);
        };
        it.fold(first, |(lo, hi), (a, b)| (lo.min(a), hi.max(b)))
    }

    /// A closed room of 8 × 6 × 3 m: x ∈ [-4, 4], y ∈ [-3, 3], floor z = 0, ceiling z = 3
    /// (bounds reach y = 3.4 through the niche). Floor, ceiling and walls face inwards.
    ///
    /// Contents (all standing on the floor):
    /// - a cabinet against the west wall: box x ∈ [-4, -3.4], y ∈ [-1, 0.6], z ∈ [0, 2];
    /// - a crate in the south-east corner: box x ∈ [3.2, 4], y ∈ [-3, -2.2], z ∈ [0, 0.5];
    /// - a free table block x ∈ [0.8, 2], y ∈ [-1.2, -0.4], z ∈ [0, 0.75], with a small box
    ///   x ∈ [1.1, 1.5], y ∈ [-1, -0.6], z ∈ [0.75, 1] on top;
    /// - a floor-to-ceiling column: cylinder at (-1.5, 1.2), radius 0.25;
    /// - a ball of radius 0.3 resting on the floor at (2.5, 1.5);
    /// - an arched niche in the north wall (y = 3): x ∈ [0.4, 1.6], sill at z = 0.8, straight
    ///   sides up to the spring line z = 1.8, semicircular vault of radius 0.6 (crown at 2.4),
    ///   0.4 m deep (back wall at y = 3.4).
    ///
    /// Open floor remains around the room's centre, e.g. at (0, 0) and (-1, -1.5).
    pub fn room() -> Scene {
        let (x0, x1, y0, y1, h) = (-4.0, 4.0, -3.0, 3.0, 3.0);
        let mut s = Scene::default();
        let (ex, ey, ez) = (DVec3::X, DVec3::Y, DVec3::Z);
        // Floor and ceiling.
        s.quad(DVec3::new(0.0, 0.0, 0.0), ex * 8.0, ey * 6.0, ez);
        s.quad(DVec3::new(0.0, 0.0, h), ex * 8.0, ey * 6.0, -ez);
        // West, east and south walls.
        s.quad(DVec3::new(x0, 0.0, h / 2.0), ey * 6.0, ez * h, ex);
        s.quad(DVec3::new(x1, 0.0, h / 2.0), ey * 6.0, ez * h, -ex);
        s.quad(DVec3::new(0.0, y0, h / 2.0), ex * 8.0, ez * h, ey);
        // North wall around the niche opening x ∈ [nx0, nx1], z ∈ [sill, spring + r].
        let (nx0, nx1, sill, spring, depth) = (0.4, 1.6, 0.8, 1.8, 0.4);
        let r = (nx1 - nx0) / 2.0;
        let ncx = (nx0 + nx1) / 2.0;
        s.wall_y(y1, x0, nx0, 0.0, h, -ey);
        s.wall_y(y1, nx1, x1, 0.0, h, -ey);
        s.wall_y(y1, nx0, nx1, 0.0, sill, -ey);
        s.prims.push(Prim::Spandrel {
            center: DVec3::new(ncx, y1, (spring + h) / 2.0),
            u: ex * (nx1 - nx0),
            v: ez * (h - spring),
            hole_center: DVec3::new(ncx, y1, spring),
            hole_radius: r,
        });
        // Niche: back, sides, sill, vault.
        let yc = y1 + depth / 2.0;
        s.wall_y(y1 + depth, nx0, nx1, sill, spring + r, -ey);
        s.quad(
            DVec3::new(nx0, yc, (sill + spring) / 2.0),
            ey * depth,
            ez * (spring - sill),
            ex,
        );
        s.quad(
            DVec3::new(nx1, yc, (sill + spring) / 2.0),
            ey * depth,
            ez * (spring - sill),
            -ex,
        );
        s.quad(DVec3::new(ncx, yc, sill), ex * (nx1 - nx0), ey * depth, ez);
        s.prims.push(Prim::Vault {
            start: DVec3::new(ncx, y1, spring),
            axis: ey * depth,
            radius: r,
        });
        // Furniture.
        s.cuboid([-4.0, -1.0, 0.0], [-3.4, 0.6, 2.0]);
        s.cuboid([3.2, -3.0, 0.0], [4.0, -2.2, 0.5]);
        s.cuboid([0.8, -1.2, 0.0], [2.0, -0.4, 0.75]);
        s.cuboid([1.1, -1.0, 0.75], [1.5, -0.6, 1.0]);
        s.prims.push(Prim::Cylinder {
            base: DVec3::new(-1.5, 1.2, 0.0),
            radius: 0.25,
            height: h,
            caps: true,
        });
        s.prims.push(Prim::Sphere {
            center: DVec3::new(2.5, 1.5, 0.3),
            radius: 0.3,
        });
        s
    }

    /// A suite of `rooms` copies of [`Scene::room`] in a row along +x, 9 m apart (walls 1 m
    /// thick between them), each joined to the next by a doorway 1 m wide and 2.1 m high
    /// with a short passage through the wall. Doorways alternate between y ∈ [1.2, 2.2] and
    /// y ∈ [-2.1, -1.1], so no line of sight runs through two of them: like the rooms of a
    /// palace or a castle, each room is seen from its own stations and, through the
    /// doorways, a little from its neighbours'. Room `k` spans x ∈ [9k − 4, 9k + 4].
    pub fn suite(rooms: usize) -> Scene {
        let (x0, x1, h, hd) = (-4.0, 4.0, 3.0, 2.1);
        let door = |k: usize| if k % 2 == 0 { (1.2, 2.2) } else { (-2.1, -1.1) };
        let base = Scene::room();
        let mut s = Scene::default();
        for k in 0..rooms.max(1) {
            let off = DVec3::new(9.0 * k as f64, 0.0, 0.0);
            // Every primitive of the room but its west and east walls, which get doorways.
            for p in &base.prims {
                let end_wall = matches!(p, Prim::Quad { center, .. }
                    if (center.x - x0).abs() < 1e-9 || (center.x - x1).abs() < 1e-9);
                if !end_wall {
                    s.prims.push(p.translated(off));
                }
            }
            let west = (k > 0).then(|| door(k - 1));
            let east = (k + 1 < rooms).then(|| door(k));
            for (x, facing, d) in [(x0, DVec3::X, west), (x1, -DVec3::X, east)] {
                let x = x + off.x;
                match d {
                    None => s.wall_x(x, -3.0, 3.0, 0.0, h, facing),
                    Some((d0, d1)) => {
                        s.wall_x(x, -3.0, d0, 0.0, h, facing);
                        s.wall_x(x, d1, 3.0, 0.0, h, facing);
                        s.wall_x(x, d0, d1, hd, h, facing);
                    }
                }
            }
            // The passage through the 1 m wall to the next room.
            if let Some((d0, d1)) = east {
                let (xa, xb) = (off.x + x1, off.x + x1 + 1.0);
                let (xc, yc) = ((xa + xb) / 2.0, (d0 + d1) / 2.0);
                let (ex, ey, ez) = (DVec3::X, DVec3::Y, DVec3::Z);
                s.quad(DVec3::new(xc, d0, hd / 2.0), ex, ez * hd, ey);
                s.quad(DVec3::new(xc, d1, hd / 2.0), ex, ez * hd, -ey);
                s.quad(DVec3::new(xc, yc, hd), ex, ey * (d1 - d0), -ez);
                s.quad(DVec3::new(xc, yc, 0.0), ex, ey * (d1 - d0), ez);
            }
        }
        s
    }

    /// An open courtyard (no ceiling): ground 30 × 30 m (x, y ∈ [-15, 15], z = 0) with a
    /// 20 × 20 m court (x, y ∈ [-10, 10]) enclosed by buildings (solid boxes):
    /// - west x ∈ [-15, -10], 9 m high; east x ∈ [10, 15], 7 m; south y ∈ [-15, -10], 8 m;
    /// - north: an arcade on the line y = 10 (walls 0.6 m thick): six pillars 0.8 m wide at
    ///   x = -10, -6, …, 10 rising to z = 5, five round arches of radius 1.6 springing at
    ///   z = 3 (crowns at 4.6) with spandrels up to z = 5, a gallery behind (y ∈ [10.6, 13],
    ///   ceiling z = 5), an upper storey y ∈ [10, 13], z ∈ [5, 8], and a back block
    ///   y ∈ [13, 15], 8 m high;
    /// - a fountain at the centre: plinth (cylinder r = 2, z ∈ [0, 0.3]), an open rim
    ///   (tube r = 2, z ∈ [0.3, 0.6]), a column r = 0.25 up to z = 1.8 and a ball r = 0.35
    ///   centred at z = 2.05;
    /// - two benches: boxes x ∈ [-6, -4] and [4, 6], y ∈ [-6, -5.5], 0.45 m high.
    pub fn courtyard() -> Scene {
        let mut s = Scene::default();
        let (ex, ey, ez) = (DVec3::X, DVec3::Y, DVec3::Z);
        s.quad(DVec3::ZERO, ex * 30.0, ey * 30.0, ez);
        s.cuboid([-15.0, -15.0, 0.0], [-10.0, 15.0, 9.0]);
        s.cuboid([10.0, -15.0, 0.0], [15.0, 15.0, 7.0]);
        s.cuboid([-10.0, -15.0, 0.0], [10.0, -10.0, 8.0]);
        // North range: back block, upper storey (its underside is the gallery ceiling).
        let (ya, yb, spring, top, r) = (10.0, 10.6, 3.0, 5.0, 1.6);
        s.cuboid([-10.0, 13.0, 0.0], [10.0, 15.0, 8.0]);
        s.cuboid([-10.0, ya, top], [10.0, 13.0, 8.0]);
        for i in 0..6 {
            let xc = -10.0 + 4.0 * i as f64;
            s.cuboid([xc - 0.4, ya, 0.0], [xc + 0.4, yb, top]);
            if i == 5 {
                break;
            }
            let ac = xc + 2.0;
            for (y, facing) in [(ya, -ey), (yb, ey)] {
                let v = if ex.cross(ez).dot(facing) > 0.0 {
                    ez
                } else {
                    -ez
                };
                s.prims.push(Prim::Spandrel {
                    center: DVec3::new(ac, y, (spring + top) / 2.0),
                    u: ex * (2.0 * r),
                    v: v * (top - spring),
                    hole_center: DVec3::new(ac, y, spring),
                    hole_radius: r,
                });
            }
            s.prims.push(Prim::Vault {
                start: DVec3::new(ac, ya, spring),
                axis: ey * (yb - ya),
                radius: r,
            });
        }
        // Fountain.
        s.prims.push(Prim::Cylinder {
            base: DVec3::ZERO,
            radius: 2.0,
            height: 0.3,
            caps: true,
        });
        s.prims.push(Prim::Cylinder {
            base: DVec3::new(0.0, 0.0, 0.3),
            radius: 2.0,
            height: 0.3,
            caps: false,
        });
        s.prims.push(Prim::Cylinder {
            base: DVec3::new(0.0, 0.0, 0.3),
            radius: 0.25,
            height: 1.5,
            caps: true,
        });
        s.prims.push(Prim::Sphere {
            center: DVec3::new(0.0, 0.0, 2.05),
            radius: 0.35,
        });
        // Benches.
        s.cuboid([-6.0, -6.0, 0.0], [-4.0, -5.5, 0.45]);
        s.cuboid([4.0, -6.0, 0.0], [6.0, -5.5, 0.45]);
        s
    }

    fn quad(&mut self, center: DVec3, u: DVec3, v: DVec3, facing: DVec3) {
        self.prims.push(Prim::quad_facing(center, u, v, facing));
    }

    /// Vertical rectangle in the plane `y`, spanning `[xa, xb] × [za, zb]`.
    fn wall_y(&mut self, y: f64, xa: f64, xb: f64, za: f64, zb: f64, facing: DVec3) {
        let c = DVec3::new((xa + xb) / 2.0, y, (za + zb) / 2.0);
        self.quad(c, DVec3::X * (xb - xa), DVec3::Z * (zb - za), facing);
    }

    /// Vertical rectangle in the plane `x`, spanning `[ya, yb] × [za, zb]`.
    fn wall_x(&mut self, x: f64, ya: f64, yb: f64, za: f64, zb: f64, facing: DVec3) {
        let c = DVec3::new(x, (ya + yb) / 2.0, (za + zb) / 2.0);
        self.quad(c, DVec3::Y * (yb - ya), DVec3::Z * (zb - za), facing);
    }

    fn cuboid(&mut self, min: [f64; 3], max: [f64; 3]) {
        self.prims.push(Prim::Box {
            min: DVec3::from_array(min),
            max: DVec3::from_array(max),
        });
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn bounds_of_builtin_scenes() {
        let (lo, hi) = Scene::room().bounds();
        assert!(lo.abs_diff_eq(DVec3::new(-4.0, -3.0, 0.0), 1e-12), "{lo}");
        assert!(hi.abs_diff_eq(DVec3::new(4.0, 3.4, 3.0), 1e-12), "{hi}");
        let (lo, hi) = Scene::courtyard().bounds();
        assert!(lo.abs_diff_eq(DVec3::new(-15.0, -15.0, 0.0), 1e-12), "{lo}");
        assert!(hi.abs_diff_eq(DVec3::new(15.0, 15.0, 9.0), 1e-12), "{hi}");
        assert_eq!(Scene::default().bounds(), (DVec3::ZERO, DVec3::ZERO));
    }

    #[test]
    fn room_nearest_hits() {
        let s = Scene::room();
        let c = DVec3::new(0.0, 0.0, 1.5);
        // Straight down to the floor, up to the ceiling; west to the wall.
        let h = s.intersect(c, DVec3::NEG_Z).unwrap();
        assert!((h.t - 1.5).abs() < 1e-12 && h.normal.abs_diff_eq(DVec3::Z, 1e-12));
        let h = s.intersect(c, DVec3::Z).unwrap();
        assert!((h.t - 1.5).abs() < 1e-12 && h.normal.abs_diff_eq(DVec3::NEG_Z, 1e-12));
        let h = s
            .intersect(DVec3::new(0.0, -2.0, 1.5), DVec3::NEG_X)
            .unwrap();
        assert!((h.t - 4.0).abs() < 1e-12 && h.normal.abs_diff_eq(DVec3::X, 1e-12));
        // The cabinet stands in front of the west wall (its face at x = -3.4).
        let h = s.intersect(c, DVec3::NEG_X).unwrap();
        assert!((h.t - 3.4).abs() < 1e-12 && h.normal.abs_diff_eq(DVec3::X, 1e-12));
        // Through the niche opening to its back wall at y = 3.4.
        let h = s.intersect(DVec3::new(1.0, 0.0, 1.5), DVec3::Y).unwrap();
        assert!((h.t - 3.4).abs() < 1e-12 && h.normal.abs_diff_eq(DVec3::NEG_Y, 1e-12));
        // Into the vault: from (1, 3.2, 1.0) straight up to the crown at z = 2.4.
        let h = s.intersect(DVec3::new(1.0, 3.2, 1.0), DVec3::Z).unwrap();
        assert!((h.t - 1.4).abs() < 1e-12);
        assert!(matches!(s.prims[h.prim], Prim::Vault { .. }));
        // Above the arch the north wall is solid (spandrel).
        let h = s.intersect(DVec3::new(1.0, 0.0, 2.7), DVec3::Y).unwrap();
        assert!((h.t - 3.0).abs() < 1e-12);
        // The column blocks the view towards it.
        let h = s.intersect(DVec3::new(-1.5, 0.0, 1.5), DVec3::Y).unwrap();
        assert!((h.t - 0.95).abs() < 1e-12 && h.normal.abs_diff_eq(DVec3::NEG_Y, 1e-12));
        assert!(s.inside_solid(DVec3::new(-1.5, 1.2, 1.0)));
        assert!(!s.inside_solid(c));
    }

    #[test]
    fn courtyard_sky_is_open_and_arches_pass() {
        let s = Scene::courtyard();
        assert!(s.intersect(DVec3::new(5.0, 0.0, 1.5), DVec3::Z).is_none());
        // Through the middle arch (arch centres at x = -8, -4, 0, 4, 8) to the back wall of
        // the gallery at y = 13.
        let h = s.intersect(DVec3::new(0.0, 5.0, 2.0), DVec3::Y).unwrap();
        assert!((h.t - 8.0).abs() < 1e-12 && h.normal.abs_diff_eq(DVec3::NEG_Y, 1e-12));
        // Beside a pillar (x = -2) at that height: the pillar face at y = 10.
        let h = s.intersect(DVec3::new(-2.0, 5.0, 2.0), DVec3::Y).unwrap();
        assert!((h.t - 5.0).abs() < 1e-12);
        // Above the arch crown (z = 4.8): spandrel at y = 10.
        let h = s.intersect(DVec3::new(0.0, 5.0, 4.8), DVec3::Y).unwrap();
        assert!((h.t - 5.0).abs() < 1e-12 && h.normal.abs_diff_eq(DVec3::NEG_Y, 1e-12));
        // Fountain rim from outside at z = 0.45.
        let h = s
            .intersect(DVec3::new(5.0, 0.0, 0.45), DVec3::NEG_X)
            .unwrap();
        assert!((h.t - 3.0).abs() < 1e-12);
    }
}
