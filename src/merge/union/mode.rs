//! Which points the union shades: the choice of `--occlusion`.

use serde::Serialize;

/// How the merge combines the views.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, clap::ValueEnum, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Occlusion {
    /// The union for the points of all-round stations at `t_max = ∞` (where every view's
    /// depth map takes the space behind its surfaces as solid out to infinity), the average
    /// elsewhere.
    #[default]
    Auto,
    /// The views' finished AO averaged at each point (eq. 6–12).
    Average,
    /// Each point's rays marched through every overlapping view's geometry.
    Union,
}

/// Rays per point of the union that [`Occlusion::Auto`] runs, unless asked otherwise.
pub const AUTO_RAYS: u32 = 8;
/// Rays per point of [`Occlusion::Union`] and of the bent normals, unless asked otherwise.
pub const UNION_RAYS: u32 = 32;

impl Occlusion {
    /// Whether the union shades the points of a scan whose own view is `all_round` (a
    /// full-circle station), given whether the views' own maps are plain ambient occlusion
    /// by the far-field sweeps (`plain`).
    pub fn unites(self, plain: bool, all_round: bool) -> bool {
        match self {
            Occlusion::Auto => plain && all_round,
            Occlusion::Average => false,
            Occlusion::Union => true,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::Occlusion;

    #[test]
    fn auto_unites_only_all_round_stations_at_infinity() {
        for plain in [false, true] {
            for round in [false, true] {
                assert!(Occlusion::Union.unites(plain, round));
                assert!(!Occlusion::Average.unites(plain, round));
                assert_eq!(Occlusion::Auto.unites(plain, round), plain && round);
            }
        }
    }
}
