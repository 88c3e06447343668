//! Cleaning of one depth frame before anything uses it (the paper's §6 filter): a pixel is
//! dropped when one of its 8 neighbours' depth differs from its own by more than a
//! threshold, or when it lies outside the sensor's range. Aggressive at depth edges on
//! purpose: a later frame that sees the surface more squarely measures it again.

use rayon::prelude::*;

/// The cleaning settings.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CleanParams {
    /// Largest depth difference to an 8-neighbour that keeps a pixel (metres).
    pub edge: f32,
    /// Nearest depth kept (metres).
    pub min_range: f32,
    /// Farthest depth kept (metres).
    pub max_range: f32,
}

impl Default for CleanParams {
    fn default() -> Self {
        CleanParams {
            edge: 0.02,
            min_range: 0.1,
            max_range: 8.0,
        }
    }
}

/// Cleans a `width × height` z-depth map (0 = no measurement): the kept depths, 0 where a
/// pixel was dropped or empty. Neighbours without a measurement do not count; the
/// comparison is always against the input, so the result does not depend on the order
/// in which pixels are visited.
pub fn clean(depth: &[f32], width: usize, height: usize, p: &CleanParams) -> Vec<f32> {
    let mut out = vec![0.0f32; depth.len()];
    if depth.len() != width * height {
        return out;
    }
    out.par_chunks_mut(width.max(1))
        .enumerate()
        .for_each(|(y, row)| {
            for (x, o) in row.iter_mut().enumerate() {
                let d = depth[y * width + x];
                if !(d >= p.min_range && d <= p.max_range) {
                    continue;
                }
                let mut keep = true;
                'nb: for ny in y.saturating_sub(1)..(y + 2).min(height) {
                    for nx in x.saturating_sub(1)..(x + 2).min(width) {
                        let q = depth[ny * width + nx];
                        if q > 0.0 && (q - d).abs() > p.edge {
                            keep = false;
                            break 'nb;
                        }
                    }
                }
                if keep {
                    *o = d;
                }
            }
        });
    out
}
