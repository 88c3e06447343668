//! Views held in memory: nothing is written, nothing evicted.

use super::{Summary, ViewStore};
use crate::error::{Error, Result};
use crate::merge::MergeParams;
use crate::products::manifest::InputRecord;
use crate::products::points::Points;
use crate::products::MergeMaps;
use crate::view::PreparedView;
use glam::DMat4;
use std::collections::HashMap;
use std::sync::Arc;

/// Every view in memory, with its maps packed for the merge once asked for.
#[derive(Default)]
pub struct MemoryStore {
    views: Vec<Option<(Summary, PreparedView)>>,
    maps: HashMap<usize, Arc<MergeMaps>>,
}

impl MemoryStore {
    /// A store for `n` scans.
    pub fn new(n: usize) -> MemoryStore {
        MemoryStore {
            views: vec![None; n],
            maps: HashMap::new(),
        }
    }

    /// The views, by scan index (`None` for a scan never prepared).
    pub fn into_views(self) -> Vec<Option<PreparedView>> {
        self.views.into_iter().map(|v| v.map(|v| v.1)).collect()
    }

    fn view(&self, i: usize) -> Result<&(Summary, PreparedView)> {
        self.views
            .get(i)
            .and_then(Option::as_ref)
            .ok_or_else(|| Error::Param(format!("view {i} asked for before it was prepared")))
    }
}

impl ViewStore for MemoryStore {
    fn is_current(&mut self, i: usize) -> bool {
        self.views.get(i).is_some_and(Option::is_some)
    }

    fn put(
        &mut self,
        i: usize,
        _record: Option<&InputRecord>,
        sum: Summary,
        view: PreparedView,
    ) -> Result<()> {
        if i >= self.views.len() {
            self.views.resize(i + 1, None);
        }
        self.maps.remove(&i);
        self.views[i] = Some((sum, view));
        Ok(())
    }

    fn finish_prepare(&mut self) -> Result<()> {
        Ok(())
    }

    fn summary(&mut self, i: usize) -> Result<Summary> {
        Ok(self.view(i)?.0.clone())
    }

    fn points(&mut self, i: usize, _next: Option<usize>) -> Result<Points> {
        let v = &self.view(i)?.1;
        Ok(Points {
            radii: v.radii.clone(),
            pixel: v.pixel.clone(),
            depth: v.depth.clone(),
            grid_pixels: v.sensor.grid_pixels.clone(),
        })
    }

    fn maps(&mut self, j: usize, pose: DMat4, prm: &MergeParams) -> Result<Arc<MergeMaps>> {
        if let Some(m) = self.maps.get(&j) {
            return Ok(m.clone());
        }
        let mut m = MergeMaps::from_view(self.view(j)?.1.clone());
        m.place(pose, prm);
        let m = Arc::new(m);
        self.maps.insert(j, m.clone());
        Ok(m)
    }
}
