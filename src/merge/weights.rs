//! The view weights of eq. 9–12, `w = w_d · w_n · w_b`, times the spacing weight `w_s` that lets
//! sharp views outweigh coarse ones, and the correspondence test of eq. 7.

use glam::{Vec3, Vec4};

/// Default κ of [`w_spacing`]: a view counts half where its point spacing is a tenth of
/// `t_max`. Chosen on five multi-station scenes and checked on three others
/// (`docs/accuracy.md`).
pub const SPACING_WEIGHT: f32 = 0.1;

/// Eq. 10: `w_d = max(1 − max(depth − d_min, 0)/d_max, 0.1)`. A non-positive `d_max` disables
/// the distance falloff (weight 1).
#[inline]
pub fn w_distance(depth: f32, dmin: f32, dmax: f32) -> f32 {
    if !(dmax > 0.0) {
        return 1.0;
    }
    (1.0 - (depth - dmin).max(0.0) / dmax).max(0.1)
}

/// Eq. 11: `w_n = max(n·l, 0)` with `l` the unit direction from the point to the sensor.
#[inline]
pub fn w_normal(n: Vec3, l: Vec3) -> f32 {
    n.dot(l).max(0.0)
}

/// Eq. 12: `w_b = min(d_b / (t_p·α), 1)`, `α = rad(p_i)/rad(p_ij)`. Radii are floored at a
/// positive minimum upstream; a non-finite or zero denominator gives weight 1 when `d_b > 0`.
#[inline]
pub fn w_border(db: f32, tp: f32, rad_i: f32, rad_ij: f32) -> f32 {
    let alpha = if rad_ij > 0.0 { rad_i / rad_ij } else { 1.0 };
    let den = tp * alpha;
    if !(den > 0.0) || !den.is_finite() {
        return if db > 0.0 { 1.0 } else { 0.0 };
    }
    (db / den).min(1.0)
}

/// The spacing weight `w_s = 1 / (1 + (rad_ij / s)²)` of a view whose point spacing at the match
/// is `rad_ij`, with `s = κ·t_max` (`docs/design.md`): a view that samples the `t_max`
/// neighbourhood with fewer than about `1/κ` points across counts less, views finer than `s`
/// count alike. A non-positive or non-finite `s` (off, or `t_max = ∞`) gives weight 1.
#[inline]
pub fn w_spacing(rad_ij: f32, s: f32) -> f32 {
    if !(s > 0.0 && s.is_finite()) {
        return 1.0;
    }
    let q = rad_ij / s;
    // q² overflowing to ∞ gives 0, never NaN (radii are finite and positive upstream).
    1.0 / (1.0 + q * q)
}

/// Eq. 7: `p_ij` corresponds to `q` (scan i's point in scan j's frame) when
/// `‖q − p_ij‖ < 2·max(rad_i, rad_ij)` and `p_ij` faces scanner i: `(b − p_ij)·n_ij > 0`, with
/// `b` scanner i in scan j's frame as a homogeneous point (`w = 0`: a sensor at infinity in
/// direction `b.xyz`).
#[inline]
pub fn corresponds(q: Vec3, p_ij: Vec3, n_ij: Vec3, rad_i: f32, rad_ij: f32, b: Vec4) -> bool {
    within(q, p_ij, rad_i, rad_ij) && faces(p_ij, n_ij, b)
}

/// The distance half of eq. 7: `‖q − p_ij‖ < 2·max(rad_i, rad_ij)`.
#[inline]
pub fn within(q: Vec3, p_ij: Vec3, rad_i: f32, rad_ij: f32) -> bool {
    let t = rad_i.max(rad_ij);
    !(q.distance_squared(p_ij) >= 4.0 * t * t)
}

/// The visibility half of eq. 7: `p_ij` (normal `n_ij`) faces `b`, a homogeneous point.
#[inline]
pub fn faces(p_ij: Vec3, n_ij: Vec3, b: Vec4) -> bool {
    let to_b = if b.w != 0.0 {
        b.truncate() / b.w - p_ij
    } else {
        b.truncate()
    };
    // A relative margin: a surface seen exactly edge-on must not flip with rounding.
    to_b.dot(n_ij) > 1e-5 * to_b.length()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn eq10_hand_values() {
        // depth 3, d_min 1, d_max 10: 1 − 2/10 = 0.8
        assert!((w_distance(3.0, 1.0, 10.0) - 0.8).abs() < 1e-7);
        // nearer than d_min: 1
        assert_eq!(w_distance(0.5, 1.0, 10.0), 1.0);
        // far: floor 0.1
        assert_eq!(w_distance(50.0, 1.0, 10.0), 0.1);
        assert_eq!(w_distance(5.0, 0.0, 0.0), 1.0);
    }

    #[test]
    fn eq11_hand_values() {
        assert_eq!(w_normal(Vec3::Z, Vec3::Z), 1.0);
        assert_eq!(w_normal(Vec3::Z, Vec3::NEG_Z), 0.0);
        let l = Vec3::new(0.0, 0.6, 0.8);
        assert!((w_normal(Vec3::Z, l) - 0.8).abs() < 1e-7);
    }

    #[test]
    fn eq12_hand_values() {
        // d_b = 32 px, t_p = 64, α = 1 → 0.5
        assert_eq!(w_border(32.0, 64.0, 0.01, 0.01), 0.5);
        // α = 2 (p_i coarser) → 32/128
        assert_eq!(w_border(32.0, 64.0, 0.02, 0.01), 0.25);
        assert_eq!(w_border(200.0, 64.0, 0.01, 0.01), 1.0);
        assert_eq!(w_border(f32::INFINITY, 64.0, 0.01, 0.01), 1.0);
        assert_eq!(w_border(0.0, 64.0, 0.01, 0.01), 0.0);
        // zero radii (duplicates upstream are floored; here raw zeros): α taken as 1
        assert_eq!(w_border(5.0, 64.0, 0.0, 0.0), 5.0 / 64.0);
    }

    #[test]
    fn spacing_weight_hand_values() {
        // rad = s: 1/2; rad = s/10: 1/1.01; rad = 3s: 1/10
        assert_eq!(w_spacing(0.04, 0.04), 0.5);
        assert!((w_spacing(0.004, 0.04) - 1.0 / 1.01).abs() < 1e-6);
        assert!((w_spacing(0.12, 0.04) - 0.1).abs() < 1e-6);
        // off, or t_max = ∞
        assert_eq!(w_spacing(0.5, 0.0), 1.0);
        assert_eq!(w_spacing(0.5, f32::INFINITY), 1.0);
        assert_eq!(w_spacing(0.5, f32::NAN), 1.0);
        // a huge radius weighs nothing, and is not NaN
        assert_eq!(w_spacing(f32::MAX, 1e-6), 0.0);
    }

    #[test]
    fn eq7_hand_values() {
        let b = Vec4::new(0.0, 0.0, 10.0, 1.0);
        let q = Vec3::ZERO;
        // within 2t (t = 0.1): distance 0.15
        assert!(corresponds(
            q,
            Vec3::new(0.15, 0.0, 0.0),
            Vec3::Z,
            0.1,
            0.05,
            b
        ));
        // beyond 2t
        assert!(!corresponds(
            q,
            Vec3::new(0.25, 0.0, 0.0),
            Vec3::Z,
            0.1,
            0.05,
            b
        ));
        // facing away from scanner i
        assert!(!corresponds(
            q,
            Vec3::new(0.1, 0.0, 0.0),
            Vec3::NEG_Z,
            0.1,
            0.1,
            b
        ));
        // sensor at infinity along +z
        let inf = Vec4::new(0.0, 0.0, 1.0, 0.0);
        assert!(corresponds(
            q,
            Vec3::new(0.1, 0.0, 0.0),
            Vec3::Z,
            0.1,
            0.1,
            inf
        ));
    }
}
