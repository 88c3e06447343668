//! Cosine-weighted ray directions: a Hammersley set of `R` points per query point, shifted by
//! a per-point random offset (Cranley–Patterson rotation) drawn from `(seed, point index)`,
//! mapped to the hemisphere by Malley's method (uniform on the disk, lifted). The set is
//! stratified (one point per 1/R slab in radius², low discrepancy in azimuth) and depends only
//! on the seed, the point's index and `R`. The azimuth shift is applied by turning the
//! point's tangent frame, so the sines and cosines come from one table per run.

use crate::rng::Rng;
use glam::Vec3;
use std::f32::consts::TAU;

/// Radical inverse in base 2 of `i` (van der Corput), in [0, 1).
#[inline]
pub(crate) fn radical_inverse2(i: u32) -> f32 {
    (i.reverse_bits() >> 8) as f32 * (1.0 / (1u32 << 24) as f32)
}

/// The azimuths of a set of `R` rays: `(cos, sin)` of `2π·radical_inverse(j)`, shared by
/// all points (each point turns its tangent frame by its own random angle instead).
#[derive(Debug, Clone)]
pub(crate) struct Azimuths(Vec<[f32; 2]>);

impl Azimuths {
    pub fn new(rays: u32) -> Azimuths {
        Azimuths(
            (0..rays)
                .map(|j| {
                    let (s, c) = (std::f64::consts::TAU * radical_inverse2(j) as f64).sin_cos();
                    [c as f32, s as f32]
                })
                .collect(),
        )
    }
}

/// Per-point sample pattern.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Pattern<'a> {
    shift: f32,
    inv_r: f32,
    t: Vec3,
    b: Vec3,
    n: Vec3,
    az: &'a [[f32; 2]],
}

impl<'a> Pattern<'a> {
    /// The pattern of point `index` with unit normal `n`, for `az.len()` rays.
    #[inline]
    pub fn new(seed: u64, index: u64, n: Vec3, az: &'a Azimuths) -> Pattern<'a> {
        let mut rng = Rng::new(seed, index);
        let shift = rng.next_f32();
        // Shifting every azimuth by 2π·u equals turning the tangent frame by that angle.
        let (s, c) = (TAU * rng.next_f32()).sin_cos();
        let (t0, b0) = n.any_orthonormal_pair();
        Pattern {
            shift,
            inv_r: 1.0 / az.0.len().max(1) as f32,
            t: t0 * c + b0 * s,
            b: b0 * c - t0 * s,
            n,
            az: &az.0,
        }
    }

    /// Direction of ray `j` (unit, `n·d > 0`).
    #[inline]
    pub fn dir(&self, j: u32) -> Vec3 {
        let u1 = fract((j as f32 + 0.5) * self.inv_r + self.shift);
        let r = u1.sqrt();
        let [c, s] = self.az[j as usize];
        let z = (1.0 - u1).max(0.0).sqrt();
        (self.t * (r * c) + self.b * (r * s) + self.n * z).normalize_or(self.n)
    }
}

#[inline]
fn fract(x: f32) -> f32 {
    let f = x - x.floor();
    // x just below an integer can round up to 1.0.
    if f >= 1.0 {
        0.0
    } else {
        f
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn directions_are_cosine_distributed() {
        // E[cos θ] = 2/3 and E[cos² θ] = 1/2 under p(ω) = cos θ / π.
        let n = Vec3::new(0.3, -0.4, 0.866).normalize();
        let (mut m1, mut m2, mut cnt) = (0.0f64, 0.0f64, 0);
        let az = Azimuths::new(64);
        for i in 0..200u64 {
            let p = Pattern::new(9, i, n, &az);
            for j in 0..64 {
                let d = p.dir(j);
                assert!((d.length() - 1.0).abs() < 1e-5);
                let c = d.dot(n) as f64;
                assert!(c >= -1e-6);
                m1 += c;
                m2 += c * c;
                cnt += 1;
            }
        }
        let (m1, m2) = (m1 / cnt as f64, m2 / cnt as f64);
        assert!((m1 - 2.0 / 3.0).abs() < 2e-3, "{m1}");
        assert!((m2 - 0.5).abs() < 2e-3, "{m2}");
    }

    #[test]
    fn radical_inverse_values() {
        assert_eq!(radical_inverse2(0), 0.0);
        assert_eq!(radical_inverse2(1), 0.5);
        assert_eq!(radical_inverse2(2), 0.25);
        assert_eq!(radical_inverse2(3), 0.75);
    }
}
