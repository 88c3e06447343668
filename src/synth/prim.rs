//! Analytic primitives of the synthetic scenes and their exact ray intersection (f64).
//!
//! Every primitive returns the nearest ray parameter `t` in an open interval and the exact
//! unit geometric normal at the hit. Surfaces are two-sided: a ray hits a quad from either
//! side and a solid from outside or inside; the normal is the primitive's *front* normal
//! (documented per variant) whatever side the ray came from, so callers orient it themselves.

use glam::DVec3;

/// One analytic primitive. World frame, metres, z up.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Prim {
    /// Planar parallelogram `center + s·u + q·v`, `s, q ∈ [-½, ½]` (`u`, `v` are full edge
    /// vectors). Front normal `normalize(u × v)`.
    Quad {
        /// Centre of the parallelogram.
        center: DVec3,
        /// First edge vector.
        u: DVec3,
        /// Second edge vector.
        v: DVec3,
    },
    /// A [`Prim::Quad`] with the points closer than `hole_radius` to `hole_center` removed:
    /// the wall around an arch (a spandrel) when the hole's centre lies on an edge.
    Spandrel {
        /// Centre of the parallelogram.
        center: DVec3,
        /// First edge vector.
        u: DVec3,
        /// Second edge vector.
        v: DVec3,
        /// Centre of the circular hole (in the quad's plane).
        hole_center: DVec3,
        /// Radius of the hole.
        hole_radius: f64,
    },
    /// Solid axis-aligned box (all six faces); normals point outwards.
    Box {
        /// Minimum corner.
        min: DVec3,
        /// Maximum corner.
        max: DVec3,
    },
    /// Vertical cylinder standing on `base` (centre of its bottom circle); normals point
    /// outwards (radially, `-z` on the bottom cap, `+z` on the top cap).
    Cylinder {
        /// Centre of the bottom circle.
        base: DVec3,
        /// Radius.
        radius: f64,
        /// Height along +z.
        height: f64,
        /// True for a solid with both caps, false for an open tube (seen from both sides).
        caps: bool,
    },
    /// Solid sphere; normals point outwards.
    Sphere {
        /// Centre.
        center: DVec3,
        /// Radius.
        radius: f64,
    },
    /// Half-cylinder vault (the intrados of an arch or a niche): the points at distance
    /// `radius` from the horizontal segment `start → start + axis` that lie at or above the
    /// segment's height. Open surface; the front normal points towards the axis (the side
    /// under the vault).
    Vault {
        /// Axis point at the spring line, at one end.
        start: DVec3,
        /// Horizontal axis vector; its length is the depth of the vault.
        axis: DVec3,
        /// Radius of the arch.
        radius: f64,
    },
}

impl Prim {
    /// The same primitive moved by `off`.
    pub fn translated(&self, off: DVec3) -> Prim {
        let mut p = *self;
        match &mut p {
            Prim::Quad { center, .. } => *center += off,
            Prim::Spandrel {
                center,
                hole_center,
                ..
            } => {
                *center += off;
                *hole_center += off;
            }
            Prim::Box { min, max } => {
                *min += off;
                *max += off;
            }
            Prim::Cylinder { base, .. } => *base += off,
            Prim::Sphere { center, .. } => *center += off,
            Prim::Vault { start, .. } => *start += off,
        }
        p
    }

    /// A [`Prim::Quad`] with edge vectors `u`, `v` whose front normal points along `facing`
    /// (the sign of `v` is flipped when needed).
    pub fn quad_facing(center: DVec3, u: DVec3, v: DVec3, facing: DVec3) -> Prim {
        let v = if u.cross(v).dot(facing) < 0.0 { -v } else { v };
        Prim::Quad { center, u, v }
    }

    /// Nearest intersection of the ray `o + t·d` with `t ∈ (t_min, t_max)`: `(t, unit front
    /// normal)`. `t` is in units of `|d|`; `d` need not be unit but must be non-zero.
    pub fn intersect(&self, o: DVec3, d: DVec3, t_min: f64, t_max: f64) -> Option<(f64, DVec3)> {
        match *self {
            Prim::Quad { center, u, v } => quad_hit(o, d, center, u, v, t_min, t_max),
            Prim::Spandrel {
                center,
                u,
                v,
                hole_center,
                hole_radius,
            } => quad_hit(o, d, center, u, v, t_min, t_max).filter(|&(t, _)| {
                (o + d * t).distance_squared(hole_center) >= hole_radius * hole_radius
            }),
            Prim::Box { min, max } => box_hit(o, d, min, max, t_min, t_max),
            Prim::Cylinder {
                base,
                radius,
                height,
                caps,
            } => {
                let mut best = cyl_side(o, d, base, DVec3::Z, height, radius, false, t_min, t_max);
                if caps && d.z != 0.0 {
                    for (z, nz) in [(base.z, -1.0), (base.z + height, 1.0)] {
                        let t = (z - o.z) / d.z;
                        let lim = best.map_or(t_max, |b| b.0);
                        if t > t_min && t < lim {
                            let p = o + d * t;
                            let (dx, dy) = (p.x - base.x, p.y - base.y);
                            if dx * dx + dy * dy <= radius * radius {
                                best = Some((t, DVec3::new(0.0, 0.0, nz)));
                            }
                        }
                    }
                }
                best
            }
            Prim::Sphere { center, radius } => sphere_hit(o, d, center, radius, t_min, t_max),
            Prim::Vault {
                start,
                axis,
                radius,
            } => {
                let len = axis.length();
                if !(len.is_finite() && len > 0.0) {
                    return None;
                }
                cyl_side(o, d, start, axis / len, len, radius, true, t_min, t_max)
                    .map(|(t, n)| (t, -n))
            }
        }
    }

    /// True when `p` lies strictly inside a solid primitive (box, capped cylinder, sphere);
    /// always false for surfaces.
    pub fn contains(&self, p: DVec3) -> bool {
        match *self {
            Prim::Box { min, max } => p.cmpgt(min).all() && p.cmplt(max).all(),
            Prim::Cylinder {
                base,
                radius,
                height,
                caps: true,
            } => {
                let (dx, dy) = (p.x - base.x, p.y - base.y);
                dx * dx + dy * dy < radius * radius && p.z > base.z && p.z < base.z + height
            }
            Prim::Sphere { center, radius } => p.distance_squared(center) < radius * radius,
            _ => false,
        }
    }

    /// Axis-aligned bounds `(min, max)` enclosing the primitive (conservative for vaults).
    pub fn bounds(&self) -> (DVec3, DVec3) {
        match *self {
            Prim::Quad { center, u, v } | Prim::Spandrel { center, u, v, .. } => {
                let h = (u.abs() + v.abs()) * 0.5;
                (center - h, center + h)
            }
            Prim::Box { min, max } => (min, max),
            Prim::Cylinder {
                base,
                radius,
                height,
                ..
            } => (
                base - DVec3::new(radius, radius, 0.0),
                base + DVec3::new(radius, radius, height),
            ),
            Prim::Sphere { center, radius } => (center - radius, center + radius),
            Prim::Vault {
                start,
                axis,
                radius,
            } => {
                // Horizontal axis: the arch spans ±radius across it and radius upwards.
                let end = start + axis;
                let across = axis.cross(DVec3::Z).normalize_or_zero().abs() * radius;
                let lo = start.min(end) - across;
                (lo, start.max(end) + across + DVec3::new(0.0, 0.0, radius))
            }
        }
    }
}

/// Ray–parallelogram intersection.
#[allow(clippy::too_many_arguments)]
fn quad_hit(
    o: DVec3,
    d: DVec3,
    c: DVec3,
    u: DVec3,
    v: DVec3,
    t_min: f64,
    t_max: f64,
) -> Option<(f64, DVec3)> {
    let n = u.cross(v);
    let denom = n.dot(d);
    if denom == 0.0 || !denom.is_finite() {
        return None;
    }
    let t = n.dot(c - o) / denom;
    if !(t > t_min && t < t_max) {
        return None;
    }
    let r = o + d * t - c;
    let (uu, uv, vv) = (u.dot(u), u.dot(v), v.dot(v));
    let det = uu * vv - uv * uv;
    if !(det.is_finite() && det > 0.0) {
        return None;
    }
    let (ru, rv) = (r.dot(u), r.dot(v));
    let s = (ru * vv - rv * uv) / det;
    let q = (rv * uu - ru * uv) / det;
    if s.abs() <= 0.5 && q.abs() <= 0.5 {
        Some((t, n.normalize()))
    } else {
        None
    }
}

/// Slab test; from outside the entry face, from inside the exit face, normals outwards.
fn box_hit(
    o: DVec3,
    d: DVec3,
    min: DVec3,
    max: DVec3,
    t_min: f64,
    t_max: f64,
) -> Option<(f64, DVec3)> {
    let (mut t0, mut t1) = (f64::NEG_INFINITY, f64::INFINITY);
    let (mut ax0, mut ax1) = (0usize, 0usize);
    for i in 0..3 {
        if d[i] == 0.0 {
            if o[i] < min[i] || o[i] > max[i] {
                return None;
            }
            continue;
        }
        let (a, b) = ((min[i] - o[i]) / d[i], (max[i] - o[i]) / d[i]);
        let (near, far) = if a < b { (a, b) } else { (b, a) };
        if near > t0 {
            t0 = near;
            ax0 = i;
        }
        if far < t1 {
            t1 = far;
            ax1 = i;
        }
    }
    if t0.is_nan() || t1.is_nan() || t0 > t1 {
        return None;
    }
    let face = |axis: usize, sign: f64| {
        let mut n = DVec3::ZERO;
        n[axis] = sign;
        n
    };
    if t0 > t_min && t0 < t_max {
        Some((t0, face(ax0, -d[ax0].signum())))
    } else if t0 <= t_min && t1 > t_min && t1 < t_max {
        Some((t1, face(ax1, d[ax1].signum())))
    } else {
        None
    }
}

/// Side of a finite cylinder around the segment `a0 → a0 + len·w` (`w` unit); with `upper`
/// only the half at or above `a0.z`. Normal points away from the axis.
#[allow(clippy::too_many_arguments)]
fn cyl_side(
    o: DVec3,
    d: DVec3,
    a0: DVec3,
    w: DVec3,
    len: f64,
    r: f64,
    upper: bool,
    t_min: f64,
    t_max: f64,
) -> Option<(f64, DVec3)> {
    let oc = o - a0;
    let op = oc - w * oc.dot(w);
    let dp = d - w * d.dot(w);
    let a = dp.dot(dp);
    if !(a.is_finite() && a > 0.0) {
        return None;
    }
    let b = op.dot(dp);
    let c = op.dot(op) - r * r;
    let disc = b * b - a * c;
    if disc.is_nan() || disc < 0.0 {
        return None;
    }
    let sq = disc.sqrt();
    // Numerically stable roots of a·t² + 2b·t + c.
    let q = -(b + b.signum() * sq);
    let (r0, r1) = if q != 0.0 { (q / a, c / q) } else { (0.0, 0.0) };
    let (ta, tb) = if r0 < r1 { (r0, r1) } else { (r1, r0) };
    for t in [ta, tb] {
        if !(t > t_min && t < t_max) {
            continue;
        }
        let p = oc + d * t;
        let s = p.dot(w);
        if s < 0.0 || s > len || (upper && p.z < 0.0) {
            continue;
        }
        let radial = p - w * s;
        return Some((t, radial / r));
    }
    None
}

/// Ray–sphere intersection (nearer root first, the far one from inside).
fn sphere_hit(
    o: DVec3,
    d: DVec3,
    c: DVec3,
    r: f64,
    t_min: f64,
    t_max: f64,
) -> Option<(f64, DVec3)> {
    let oc = o - c;
    let a = d.dot(d);
    let b = oc.dot(d);
    let cc = oc.dot(oc) - r * r;
    let disc = b * b - a * cc;
    if !(a > 0.0 && disc >= 0.0) {
        return None;
    }
    let sq = disc.sqrt();
    let q = -(b + b.signum() * sq);
    let (r0, r1) = if q != 0.0 {
        (q / a, cc / q)
    } else {
        (0.0, 0.0)
    };
    let (ta, tb) = if r0 < r1 { (r0, r1) } else { (r1, r0) };
    [ta, tb]
        .into_iter()
        .find(|&t| t > t_min && t < t_max)
        .map(|t| (t, (oc + d * t) / r))
}

#[cfg(test)]
mod tests {
    use super::*;

    const INF: f64 = f64::INFINITY;

    fn close(a: DVec3, b: DVec3) -> bool {
        (a - b).length() < 1e-12
    }

    #[test]
    fn quad_hit_inside_edges_and_miss() {
        // 2 × 1 quad in the plane z = 1, centred at (1, 0, 1), front normal +z.
        let q = Prim::Quad {
            center: DVec3::new(1.0, 0.0, 1.0),
            u: DVec3::new(2.0, 0.0, 0.0),
            v: DVec3::new(0.0, 1.0, 0.0),
        };
        let (t, n) = q
            .intersect(DVec3::new(1.5, 0.2, 3.0), DVec3::NEG_Z, 0.0, INF)
            .unwrap();
        assert!((t - 2.0).abs() < 1e-12 && close(n, DVec3::Z));
        // From below: same front normal, t = 1.
        let (t, n) = q
            .intersect(DVec3::new(0.1, -0.4, 0.0), DVec3::Z, 0.0, INF)
            .unwrap();
        assert!((t - 1.0).abs() < 1e-12 && close(n, DVec3::Z));
        // Oblique: from origin towards (1, 0, 1)·k hits at t = √2 with a unit direction.
        let d = DVec3::new(1.0, 0.0, 1.0).normalize();
        let (t, _) = q.intersect(DVec3::ZERO, d, 0.0, INF).unwrap();
        assert!((t - 2f64.sqrt()).abs() < 1e-12);
        // Just outside the long edge (x = 2.01) and beyond t_max.
        assert!(q
            .intersect(DVec3::new(2.01, 0.0, 3.0), DVec3::NEG_Z, 0.0, INF)
            .is_none());
        assert!(q
            .intersect(DVec3::new(1.0, 0.0, 3.0), DVec3::NEG_Z, 0.0, 1.9)
            .is_none());
        // Parallel ray.
        assert!(q
            .intersect(DVec3::new(1.0, 0.0, 1.0), DVec3::X, 0.0, INF)
            .is_none());
        // quad_facing flips v to honour the requested normal.
        let f = Prim::quad_facing(DVec3::ZERO, DVec3::X, DVec3::Y, DVec3::NEG_Z);
        let (_, n) = f.intersect(DVec3::Z, DVec3::NEG_Z, 0.0, INF).unwrap();
        assert!(close(n, DVec3::NEG_Z));
    }

    #[test]
    fn spandrel_hole_is_empty() {
        // 2 × 1 wall in y = 0 spanning x ∈ [-1, 1], z ∈ [0, 1], hole of radius 0.8 at origin.
        let s = Prim::Spandrel {
            center: DVec3::new(0.0, 0.0, 0.5),
            u: DVec3::new(2.0, 0.0, 0.0),
            v: DVec3::new(0.0, 0.0, 1.0),
            hole_center: DVec3::ZERO,
            hole_radius: 0.8,
        };
        assert!(s
            .intersect(DVec3::new(0.0, -1.0, 0.5), DVec3::Y, 0.0, INF)
            .is_none());
        let (t, n) = s
            .intersect(DVec3::new(0.0, -1.0, 0.9), DVec3::Y, 0.0, INF)
            .unwrap();
        assert!((t - 1.0).abs() < 1e-12 && close(n, DVec3::NEG_Y));
        assert!(s
            .intersect(DVec3::new(0.9, -1.0, 0.1), DVec3::Y, 0.0, INF)
            .is_some());
    }

    #[test]
    fn box_from_outside_and_inside() {
        let b = Prim::Box {
            min: DVec3::new(-1.0, -2.0, 0.0),
            max: DVec3::new(1.0, 2.0, 3.0),
        };
        // From outside along +x: enters the x = -1 face at t = 4, normal -x.
        let (t, n) = b
            .intersect(DVec3::new(-5.0, 0.0, 1.0), DVec3::X, 0.0, INF)
            .unwrap();
        assert!((t - 4.0).abs() < 1e-12 && close(n, DVec3::NEG_X));
        // From above: top face at t = 2, normal +z.
        let (t, n) = b
            .intersect(DVec3::new(0.5, 1.0, 5.0), DVec3::NEG_Z, 0.0, INF)
            .unwrap();
        assert!((t - 2.0).abs() < 1e-12 && close(n, DVec3::Z));
        // Diagonal from outside along (1, 1, 0): y = -2 is crossed at t = 1, x = -1 at t = 2,
        // so the entry is the x = -1 face at t = 2.
        let (t, n) = b
            .intersect(
                DVec3::new(-3.0, -3.0, 1.0),
                DVec3::new(1.0, 1.0, 0.0),
                0.0,
                INF,
            )
            .unwrap();
        assert!((t - 2.0).abs() < 1e-12 && close(n, DVec3::NEG_X));
        // From inside: exit through y = 2 at t = 1.5, outward normal +y.
        let (t, n) = b
            .intersect(DVec3::new(0.0, 0.5, 1.0), DVec3::Y, 0.0, INF)
            .unwrap();
        assert!((t - 1.5).abs() < 1e-12 && close(n, DVec3::Y));
        // Miss, and a ray pointing away.
        assert!(b
            .intersect(DVec3::new(-5.0, 3.0, 1.0), DVec3::X, 0.0, INF)
            .is_none());
        assert!(b
            .intersect(DVec3::new(-5.0, 0.0, 1.0), DVec3::NEG_X, 0.0, INF)
            .is_none());
        assert!(b.contains(DVec3::new(0.0, 0.0, 1.0)));
        assert!(!b.contains(DVec3::new(0.0, 0.0, 3.5)));
    }

    #[test]
    fn cylinder_side_caps_and_open() {
        let c = Prim::Cylinder {
            base: DVec3::new(1.0, 1.0, 0.0),
            radius: 0.5,
            height: 2.0,
            caps: true,
        };
        // Horizontal ray along +x at y = 1.3: side at x = 1 - √(0.25 - 0.09) = 0.6.
        let (t, n) = c
            .intersect(DVec3::new(-2.0, 1.3, 1.0), DVec3::X, 0.0, INF)
            .unwrap();
        assert!((t - 2.6).abs() < 1e-12);
        assert!(close(n, DVec3::new(-0.8, 0.6, 0.0)));
        // From above: top cap at z = 2.
        let (t, n) = c
            .intersect(DVec3::new(1.2, 1.0, 5.0), DVec3::NEG_Z, 0.0, INF)
            .unwrap();
        assert!((t - 3.0).abs() < 1e-12 && close(n, DVec3::Z));
        // Above the top: miss on the side.
        assert!(c
            .intersect(DVec3::new(-2.0, 1.0, 2.5), DVec3::X, 0.0, INF)
            .is_none());
        // From inside a solid cylinder, going down: bottom cap, outward normal -z.
        let (t, n) = c
            .intersect(DVec3::new(1.0, 1.0, 1.0), DVec3::NEG_Z, 0.0, INF)
            .unwrap();
        assert!((t - 1.0).abs() < 1e-12 && close(n, DVec3::NEG_Z));
        // Open tube seen from inside: far wall at x = 1.5, radial normal +x.
        let open = Prim::Cylinder {
            base: DVec3::new(1.0, 1.0, 0.0),
            radius: 0.5,
            height: 2.0,
            caps: false,
        };
        let (t, n) = open
            .intersect(DVec3::new(1.0, 1.0, 1.0), DVec3::X, 0.0, INF)
            .unwrap();
        assert!((t - 0.5).abs() < 1e-12 && close(n, DVec3::X));
        assert!(open
            .intersect(DVec3::new(1.2, 1.0, 5.0), DVec3::NEG_Z, 0.0, INF)
            .is_none());
        assert!(c.contains(DVec3::new(1.1, 1.1, 0.5)) && !open.contains(DVec3::new(1.1, 1.1, 0.5)));
    }

    #[test]
    fn sphere_outside_and_inside() {
        let s = Prim::Sphere {
            center: DVec3::new(0.0, 0.0, 2.0),
            radius: 1.0,
        };
        let (t, n) = s.intersect(DVec3::ZERO, DVec3::Z, 0.0, INF).unwrap();
        assert!((t - 1.0).abs() < 1e-12 && close(n, DVec3::NEG_Z));
        let (t, n) = s
            .intersect(DVec3::new(0.0, 0.0, 2.0), DVec3::X, 0.0, INF)
            .unwrap();
        assert!((t - 1.0).abs() < 1e-12 && close(n, DVec3::X));
        // Grazing-ish: offset 0.6 → chord half-length 0.8; from x = -3, t = 3 - 0.8 = 2.2.
        let (t, n) = s
            .intersect(DVec3::new(-3.0, 0.6, 2.0), DVec3::X, 0.0, INF)
            .unwrap();
        assert!((t - 2.2).abs() < 1e-12 && close(n, DVec3::new(-0.8, 0.6, 0.0)));
        assert!(s
            .intersect(DVec3::new(-3.0, 1.1, 2.0), DVec3::X, 0.0, INF)
            .is_none());
    }

    #[test]
    fn vault_only_upper_half() {
        // Arch of radius 1 around the segment (0,0,2) → (0,1,2).
        let v = Prim::Vault {
            start: DVec3::new(0.0, 0.0, 2.0),
            axis: DVec3::new(0.0, 1.0, 0.0),
            radius: 1.0,
        };
        // Straight up from below the axis: crown at z = 3, normal towards the axis (-z).
        let (t, n) = v
            .intersect(DVec3::new(0.0, 0.5, 0.0), DVec3::Z, 0.0, INF)
            .unwrap();
        assert!((t - 3.0).abs() < 1e-12 && close(n, DVec3::NEG_Z));
        // Horizontal ray below the spring line misses (lower half is open).
        assert!(v
            .intersect(DVec3::new(-5.0, 0.5, 1.9), DVec3::X, 0.0, INF)
            .is_none());
        // Horizontal ray at z = 2.6 from outside: x = -0.8 at t = 4.2, normal (0.8, 0, -0.6).
        let (t, n) = v
            .intersect(DVec3::new(-5.0, 0.5, 2.6), DVec3::X, 0.0, INF)
            .unwrap();
        assert!((t - 4.2).abs() < 1e-12 && close(n, DVec3::new(0.8, 0.0, -0.6)));
        // Outside the depth of the vault.
        assert!(v
            .intersect(DVec3::new(0.0, 1.5, 0.0), DVec3::Z, 0.0, INF)
            .is_none());
    }
}
