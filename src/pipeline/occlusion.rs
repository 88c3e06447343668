//! The occlusion stage: a view's AO map from its geometry ([`ViewGeometry`] → [`AoMap`]) by
//! the chosen estimator, then the blur. It runs between the per-view geometry and the store,
//! once per prepared view; occlusion that reads other views' geometry belongs here.

use crate::error::Result;
use crate::scan::Scan;
use crate::sensor::ProjectionChoice;
use crate::ssao::{self, AoMap, SsaoParams};
use crate::view::{view_geometry, PreparedView, ViewGeometry};
use std::time::Instant;

/// The AO map of view `g` with parameters `prm`.
pub fn occlude(g: &ViewGeometry, prm: &SsaoParams) -> AoMap {
    ssao::compute(&g.gbuf, &g.sensor.projection, prm)
}

/// One scan through the per-view stages and the occlusion stage: what the prepare stage
/// stores for it.
pub fn prepare_view(
    scan: &Scan,
    choice: ProjectionChoice,
    prm: &SsaoParams,
) -> Result<PreparedView> {
    let g = view_geometry(scan, choice)?;
    let t = Instant::now();
    let ao = occlude(&g, prm);
    Ok(g.with_occlusion(ao, t.elapsed().as_secs_f64()))
}
