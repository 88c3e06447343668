//! Eq. 3–5 of Sabbadin et al. 2016: `a = (1/|S|) Σ ρ(‖p_i − p‖)·(1 − max(n·(p_i−p)/‖p_i−p‖, 0))`
//! over samples uniform in the screen-space disk that a sphere of radius `r_s` projects to at
//! the pixel's depth. Kept exactly as published (an open floor reads E\[ρ\] < 1; see the spec).
//!
//! Decisions the paper leaves open: a sample landing on an empty pixel, on the centre pixel
//! itself, or on a point at distance 0 carries no information about the neighbourhood and is
//! skipped (not counted); a pixel with no valid sample keeps `a = 1` and is flagged.

use super::{visibility_weight, AoMap, SsaoParams};
use crate::gbuffer::GBuffer;
use crate::projection::{angular_radius, Model, Projection};
use crate::rng::Rng;
use rayon::prelude::*;

/// cos and sin of the golden angle π(3 − √5).
const GOLD_COS: f32 = -0.737_368_9;
const GOLD_SIN: f32 = 0.675_490_3;

/// Computes the unblurred paper SSAO of every valid pixel.
pub fn ssao(g: &GBuffer, proj: &Projection, prm: &SsaoParams) -> AoMap {
    let n = g.width * g.height;
    let mut ao = vec![1.0f32; n];
    let mut flag = vec![false; n];
    if g.width == 0 {
        return AoMap {
            ao,
            no_sample: flag,
            levels: None,
        };
    }
    let tau = std::f32::consts::TAU;
    let is_equirect = matches!(proj.model, Model::Equirect { .. });
    ao.par_chunks_mut(g.width)
        .zip(flag.par_chunks_mut(g.width))
        .enumerate()
        .for_each(|(y, (arow, frow))| {
            for x in 0..g.width {
                let c = y * g.width + x;
                if !g.is_valid(c) {
                    continue;
                }
                let p = g.position[c];
                let nrm = g.normal[c];
                let (rx, ry) =
                    proj.disk_radius(prm.radius, g.depth[c], x as f32 + 0.5, y as f32 + 0.5);
                let mut rng = Rng::new(prm.seed, c as u64);
                let (mut sum, mut cnt) = (0.0f32, 0u32);
                // Where the disk crosses an equirect map's pole the pixel ellipse would lose its
                // samples off the map; there the disk is taken on the sphere, around the
                // pixel's view direction, and each sample projected (elsewhere the ellipse,
                // widened by 1/cos(elevation), is the disk on the sphere).
                let yc = y as f32 + 0.5;
                let crosses_pole = yc < ry || yc + ry > g.height as f32;
                let sphere = if is_equirect && crosses_pole {
                    proj.ray(x as f32 + 0.5, y as f32 + 0.5).map(|(_, d)| {
                        let d = d.normalize_or_zero();
                        let (e1, e2) = d.any_orthonormal_pair();
                        let t = angular_radius(prm.radius, g.depth[c]).tan();
                        (d, e1 * t, e2 * t)
                    })
                } else {
                    None
                };
                // Stratified uniform disk samples: sample k has r² uniform in [k/S, (k+1)/S)
                // and the angles step by the golden angle from a random start, so every
                // sample is uniform in the disk and the set covers it evenly.
                let u = rng.next_f32();
                let (mut s, mut co) = (tau * rng.next_f32()).sin_cos();
                let inv = 1.0 / prm.samples.max(1) as f32;
                for k in 0..prm.samples {
                    let r = ((k as f32 + u) * inv).sqrt();
                    let (sx, sy) = match sphere {
                        None => (x as f32 + 0.5 + rx * r * co, y as f32 + 0.5 + ry * r * s),
                        Some((d, a, b)) => match proj.project(d + a * (r * co) + b * (r * s)) {
                            Some(pr) => (pr.x, pr.y),
                            None => (f32::NAN, f32::NAN),
                        },
                    };
                    (s, co) = (s * GOLD_COS + co * GOLD_SIN, co * GOLD_COS - s * GOLD_SIN);
                    let Some(i) = proj.pixel_index(sx, sy) else {
                        continue;
                    };
                    if i == c || !g.is_valid(i) {
                        continue;
                    }
                    let v = g.position[i] - p;
                    let len = v.length();
                    if !(len > 0.0) {
                        continue;
                    }
                    sum += prm.falloff.rho(len, prm.tmax) * visibility_weight(nrm, v, len);
                    cnt += 1;
                }
                if cnt > 0 {
                    arow[x] = (sum / cnt as f32).clamp(0.0, 1.0);
                } else {
                    frow[x] = true;
                }
            }
        });
    AoMap {
        ao,
        no_sample: flag,
        levels: None,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::gbuffer::rasterize;
    use crate::projection::Model;
    use crate::ssao::Estimator;
    use glam::Vec3;

    /// A plane z = 0 seen by an orthographic sensor from above, 1 mm pixels.
    fn floor(n: usize) -> (GBuffer, Projection) {
        let step = 0.001f32;
        let proj = Projection {
            model: Model::Ortho {
                a: Vec3::new(1.0 / step, 0.0, 0.0),
                a0: 0.0,
                b: Vec3::new(0.0, 1.0 / step, 0.0),
                b0: 0.0,
                toward: Vec3::Z,
                depth0: 1.0,
            },
            width: n,
            height: n,
            wrap_x: false,
            warp_x: None,
            warp_y: None,
        };
        let pts: Vec<Vec3> = (0..n * n)
            .map(|i| {
                Vec3::new(
                    ((i % n) as f32 + 0.5) * step,
                    ((i / n) as f32 + 0.5) * step,
                    0.0,
                )
            })
            .collect();
        let px: Vec<u32> = (0..(n * n) as u32).collect();
        let d = vec![1.0; n * n];
        let g = rasterize(
            n,
            n,
            &px,
            &d,
            &pts,
            &vec![Vec3::Z; n * n],
            &vec![0.001; n * n],
        );
        (g, proj)
    }

    fn params(radius: f32, tmax: f32, samples: u32) -> SsaoParams {
        SsaoParams {
            estimator: Estimator::Paper,
            radius,
            tmax,
            falloff: Default::default(),
            samples,
            directions: 8,
            steps: 8,
            seed: 1,
            blur: false,
            sampling: Default::default(),
        }
    }

    #[test]
    fn open_floor_reads_expected_rho_bias() {
        // Spec: uniform disk samples in the tangent plane with t_max = 2·r_s give
        // E[ρ] = ∫₀¹ ρ(u r_s)·2u du = 3/8 − 1/10 = 0.275.
        let (g, proj) = floor(201);
        let m = ssao(&g, &proj, &params(0.03, 0.06, 256));
        let c = 100 * 201 + 100;
        assert!((m.ao[c] - 0.275).abs() < 0.02, "{}", m.ao[c]);
        assert!(!m.no_sample[c]);
    }

    #[test]
    fn sub_pixel_disk_has_no_valid_sample() {
        let (g, proj) = floor(21);
        let m = ssao(&g, &proj, &params(0.0001, 0.0002, 32));
        assert!(m.no_sample[10 * 21 + 10]);
        assert_eq!(m.ao[10 * 21 + 10], 1.0);
    }

    #[test]
    fn deterministic_for_a_seed() {
        let (g, proj) = floor(41);
        let a = ssao(&g, &proj, &params(0.005, 0.01, 32));
        let b = ssao(&g, &proj, &params(0.005, 0.01, 32));
        assert_eq!(a.ao, b.ao);
        let mut p = params(0.005, 0.01, 32);
        p.seed = 2;
        assert_ne!(a.ao, ssao(&g, &proj, &p).ao);
    }

    #[test]
    fn hand_computed_single_sample() {
        // Two pixels: centre p = 0 with n = +z, neighbour at (0.1, 0, 0.1): ρ(0.1414; t=0.4)
        // times (1 − cos45°). Disk radius covers only the neighbour (and the skipped centre).
        let proj = Projection {
            model: Model::Ortho {
                a: Vec3::new(10.0, 0.0, 0.0),
                a0: 0.0,
                b: Vec3::new(0.0, 10.0, 0.0),
                b0: 0.0,
                toward: Vec3::Z,
                depth0: 1.0,
            },
            width: 2,
            height: 1,
            wrap_x: false,
            warp_x: None,
            warp_y: None,
        };
        let pts = vec![Vec3::new(0.05, 0.05, 0.0), Vec3::new(0.15, 0.05, 0.1)];
        let g = rasterize(
            2,
            1,
            &[0, 1],
            &[1.0, 0.9],
            &pts,
            &[Vec3::Z, Vec3::Z],
            &[0.1, 0.1],
        );
        let m = ssao(&g, &proj, &params(0.2, 0.4, 64));
        let d = 0.1f32 * 2f32.sqrt();
        let x = d / 0.4;
        let expect = x * x * (3.0 - 2.0 * x) * (1.0 - std::f32::consts::FRAC_1_SQRT_2);
        assert!((m.ao[0] - expect).abs() < 1e-5, "{} vs {expect}", m.ao[0]);
    }
}
