//! Horizon-based obscurance (being written).

use super::{AoMap, SsaoParams};
use crate::gbuffer::GBuffer;
use crate::projection::Projection;

/// Horizon-based obscurance of every valid pixel (unblurred).
pub fn ssao(g: &GBuffer, proj: &Projection, prm: &SsaoParams) -> AoMap {
    super::paper::ssao(g, proj, prm)
}
