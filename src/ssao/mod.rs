//! Screen-space ambient occlusion of one view: per-pixel AO from the G-buffer, then a blur,
//! then per-point values and flags. Sees one scan, never its pose or other scans.

pub mod blur;
pub mod farfield;
pub mod horizon;
pub mod multires;
pub mod paper;

pub(crate) use crate::rng;

pub use crate::falloff::Falloff;
use crate::gbuffer::GBuffer;
use crate::projection::Projection;
use serde::Serialize;

/// Which per-view estimator computes the AO map.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, clap::ValueEnum, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Estimator {
    /// Eq. 3–5 of the paper (relative shading; an open floor reads below 1).
    #[default]
    Paper,
    /// Horizon-based obscurance: converges to the range map's own ray-traced `A(p)` as
    /// directions × steps grow.
    Horizon,
}

/// How densely the horizon march evaluates a map.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, clap::ValueEnum, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Sampling {
    /// Every pixel.
    Uniform,
    /// Once per 2×2 or 4×4 block on flat, continuous surfaces small against `t_max`, every
    /// pixel at creases, edges and concave regions ([`multires`]).
    #[default]
    Adaptive,
}

impl Sampling {
    /// Left out of the products' parameters and reports, so that products made with every
    /// pixel before `adaptive` became the default keep their parameters (and stay fresh).
    pub fn is_uniform(&self) -> bool {
        *self == Sampling::Uniform
    }
}

/// Parameters of one SSAO evaluation.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct SsaoParams {
    /// Estimator.
    pub estimator: Estimator,
    /// Sampling-sphere radius `r_s` (metres).
    pub radius: f32,
    /// Falloff distance `t_max` of ρ (metres; `f32::INFINITY` = plain ambient occlusion).
    #[serde(serialize_with = "crate::falloff::serialize_tmax")]
    pub tmax: f32,
    /// Shape of ρ below `t_max` (left out of the JSON when it is the default, so products
    /// and reports of the default keep their parameters).
    #[serde(skip_serializing_if = "Falloff::is_default")]
    pub falloff: Falloff,
    /// Samples per pixel `|S|` (paper estimator).
    pub samples: u32,
    /// Azimuthal directions per pixel (horizon estimator).
    pub directions: u32,
    /// Steps marched per direction (horizon estimator).
    pub steps: u32,
    /// Seed of the per-pixel sample patterns.
    pub seed: u64,
    /// Apply the 5×5 Gaussian blur.
    pub blur: bool,
    /// Evaluation density of the horizon march (left out of the JSON when uniform, so
    /// products made before `adaptive` became the default keep their parameters).
    #[serde(skip_serializing_if = "Sampling::is_uniform")]
    pub sampling: Sampling,
}

/// An AO map of one view.
#[derive(Debug, Clone, Default)]
pub struct AoMap {
    /// Per-pixel AO in \[0, 1\] (1 where empty).
    pub ao: Vec<f32>,
    /// Per-pixel flag: a valid pixel none of whose samples was valid (AO left at 1).
    pub no_sample: Vec<bool>,
    /// Valid pixels evaluated at each level of `--sampling adaptive` (`None` when uniform).
    pub levels: Option<multires::Levels>,
}

/// The default falloff `ρ(d) = smoothstep(0, t_max, d)`: `x = clamp(d/t_max, 0, 1)`,
/// `x²(3 − 2x)`; 1 from `t_max` on (a non-positive `t_max` lets everything through).
#[inline]
pub fn rho(d: f32, tmax: f32) -> f32 {
    Falloff::Smoothstep.rho(d, tmax)
}

/// Eq. 5: `w = 1 − max(n·(p_i − p)/‖p_i − p‖, 0)` for a sample at offset `v = p_i − p` of
/// length `len > 0`.
#[inline]
pub fn visibility_weight(n: glam::Vec3, v: glam::Vec3, len: f32) -> f32 {
    1.0 - (n.dot(v) / len).max(0.0)
}

/// The map an estimator returns when it cannot march `g` with `proj`: every pixel open; valid
/// pixels flagged when the projection's size differs from the G-buffer's (or the map is too
/// large to index with `i32`); `None` when the inputs can be marched.
pub(crate) fn unmarchable(g: &GBuffer, proj: &Projection) -> Option<AoMap> {
    let n = g.width * g.height;
    let consistent = [
        g.point.len(),
        g.position.len(),
        g.normal.len(),
        g.depth.len(),
    ]
    .iter()
    .all(|&l| l == n);
    let fits = proj.width == g.width && proj.height == g.height && n <= i32::MAX as usize;
    if g.width != 0 && consistent && fits {
        return None;
    }
    let ao = crate::par::filled(n, 1.0f32);
    let mut no_sample = crate::par::filled(n, false);
    if g.width != 0 && consistent {
        for (i, f) in no_sample.iter_mut().enumerate() {
            *f = g.is_valid(i);
        }
    }
    Some(AoMap {
        ao,
        no_sample,
        levels: None,
    })
}

/// Whether [`compute`] gives the far-field sweeps' plain ambient occlusion for `p`.
pub fn uses_far_field(p: &SsaoParams) -> bool {
    p.estimator == Estimator::Horizon && farfield::applies(p)
}

/// Bytes the occlusion stage holds beside a view of `pixels` pixels while it computes the
/// view's map (estimated): the far-field sweeps' line families; the march holds no more than a
/// few maps of the view's size, which the view's own estimate covers.
pub fn working_bytes(pixels: u64, p: &SsaoParams) -> u64 {
    if uses_far_field(p) {
        farfield::BYTES_PER_PIXEL_AND_FAMILY * farfield::families(p) as u64 * pixels
    } else {
        0
    }
}

/// Computes the AO map of a view with the chosen estimator, then blurs it.
pub fn compute(g: &GBuffer, proj: &Projection, p: &SsaoParams) -> AoMap {
    let adaptive = p.sampling == Sampling::Adaptive;
    let mut map = match p.estimator {
        Estimator::Paper => paper::ssao(g, proj, p),
        _ if uses_far_field(p) && adaptive => multires::far_field(g, proj, p),
        _ if uses_far_field(p) => farfield::ssao(g, proj, p),
        Estimator::Horizon if adaptive => multires::ssao(g, proj, p),
        Estimator::Horizon => horizon::ssao(g, proj, p),
    };
    if adaptive && map.levels.is_none() {
        // The paper's estimator and the far-field sweeps evaluate every pixel.
        let valid = (0..g.width * g.height).filter(|&c| g.is_valid(c)).count();
        map.levels = Some(multires::Levels::full(valid as u64));
    }
    if p.blur {
        map.ao = blur::gaussian5(&map.ao, g, proj.wrap_x);
    }
    map
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::Vec3;

    #[test]
    fn rho_matches_hand_values() {
        assert_eq!(rho(0.0, 0.4), 0.0);
        assert_eq!(rho(0.4, 0.4), 1.0);
        assert_eq!(rho(1.0, 0.4), 1.0);
        // d = 0.1, t = 0.4: x = 0.25, x²(3−2x) = 0.0625·2.5 = 0.15625
        assert!((rho(0.1, 0.4) - 0.15625).abs() < 1e-7);
        // midpoint is exactly 0.5
        assert!((rho(0.2, 0.4) - 0.5).abs() < 1e-7);
        assert_eq!(rho(0.5, 0.0), 1.0);
    }

    #[test]
    fn eq5_weight_matches_hand_values() {
        let n = Vec3::Z;
        // sample straight above: fully occluding direction → w = 0
        assert_eq!(visibility_weight(n, Vec3::new(0.0, 0.0, 2.0), 2.0), 0.0);
        // tangent sample → w = 1
        assert_eq!(visibility_weight(n, Vec3::new(1.0, 0.0, 0.0), 1.0), 1.0);
        // 45° above the tangent plane: 1 − cos45°
        let v = Vec3::new(1.0, 0.0, 1.0);
        let w = visibility_weight(n, v, v.length());
        assert!((w - (1.0 - std::f32::consts::FRAC_1_SQRT_2)).abs() < 1e-6);
        // below the plane → w = 1
        assert_eq!(
            visibility_weight(n, Vec3::new(1.0, 0.0, -1.0), 2f32.sqrt()),
            1.0
        );
    }
}
