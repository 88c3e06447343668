//! Per tile of a view's map, which pixels hold a point and the range of stored depths: a
//! sample in front of the nearest is in front of every stored surface of the tile, and one
//! behind the deepest by more than the solid depth is deep inside whatever the view saw
//! there. That is all most of a ray's samples need to know (a view that sees the point's
//! surface from behind holds every sample near it deep inside), and this small record
//! answers it without reading the pixel itself: a ray's samples fall scattered over the
//! maps, and a tile's 16 bytes stand for 64 pixels' records.

use glam::Vec4;
use rayon::prelude::*;

/// Side of a tile in pixels (its pixels fit the 64 bits of [`Tile::valid`]).
const SIDE: usize = 8;

/// One tile.
#[derive(Debug, Clone, Copy)]
#[repr(C, align(16))]
struct Tile {
    /// Bit `8·row + column` set where the pixel holds a point.
    valid: u64,
    /// Smallest and largest stored depth of the tile (`−∞` and `+∞` where one is not a
    /// number: nothing is known of a sample there).
    near: f32,
    far: f32,
}

/// A tile holding nothing.
const EMPTY: Tile = Tile {
    valid: 0,
    near: f32::INFINITY,
    far: f32::NEG_INFINITY,
};

impl Tile {
    /// The union of two tiles' contents (the valid bits only say whether any is set).
    fn with(self, o: &Tile) -> Tile {
        Tile {
            valid: self.valid | o.valid,
            near: self.near.min(o.near),
            far: self.far.max(o.far),
        }
    }
}

/// What a view's tiles say about a sample at one pixel.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(super) enum Seen {
    /// The pixel holds no point.
    Empty,
    /// The sample is nearer than every stored point of the pixel's tile.
    Front,
    /// The sample is deeper than every stored point of the tile by more than the depth
    /// asked.
    Deep,
    /// Read the pixel.
    Unknown,
}

/// The tiles of one view, and blocks of `SIDE × SIDE` tiles summing them up.
#[derive(Debug, Clone, Default)]
pub(super) struct FrontTiles {
    width: usize,
    height: usize,
    across: usize,
    tiles: Vec<Tile>,
    blocks_across: usize,
    blocks: Vec<Tile>,
}

/// What the stored points of a rectangle of pixels span.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(super) struct Span {
    /// Whether any pixel of it (or of the tiles it touches) holds a point.
    pub any: bool,
    /// Smallest and largest stored depth (`±∞` as in the tiles).
    pub near: f32,
    pub far: f32,
}

impl FrontTiles {
    /// The tiles of a map of `width` holding `near` (position and radius, radius `−∞` where
    /// empty), stored depths measured by `depth`.
    pub(super) fn new(width: usize, near: &[Vec4], depth: impl Fn(Vec4) -> f32 + Sync) -> Self {
        let height = near.len().checked_div(width).unwrap_or(0);
        let across = width.div_ceil(SIDE);
        let mut tiles = vec![EMPTY; across * height.div_ceil(SIDE)];
        if across == 0 {
            return FrontTiles::default();
        }
        tiles
            .par_chunks_mut(across)
            .enumerate()
            .for_each(|(ty, row)| {
                for y in ty * SIDE..((ty + 1) * SIDE).min(height) {
                    for (x, q) in near[y * width..(y + 1) * width].iter().enumerate() {
                        if q.w == f32::NEG_INFINITY {
                            continue;
                        }
                        let t = &mut row[x / SIDE];
                        t.valid |= 1u64 << ((y % SIDE) * SIDE + x % SIDE);
                        let d = depth(*q);
                        if d.is_nan() {
                            (t.near, t.far) = (f32::NEG_INFINITY, f32::INFINITY);
                        } else {
                            (t.near, t.far) = (t.near.min(d), t.far.max(d));
                        }
                    }
                }
            });
        let blocks_across = across.div_ceil(SIDE);
        let down = tiles.len() / across;
        let mut blocks = vec![EMPTY; blocks_across * down.div_ceil(SIDE)];
        for (i, t) in tiles.iter().enumerate() {
            let (tx, ty) = (i % across, i / across);
            let b = &mut blocks[(ty / SIDE) * blocks_across + tx / SIDE];
            *b = b.with(t);
        }
        FrontTiles {
            width,
            height,
            across,
            tiles,
            blocks_across,
            blocks,
        }
    }

    /// What the stored points of pixels `x0..=x1`, `y0..=y1` span (clipped to the map), read
    /// from the tiles, or from the blocks when the rectangle is wider than a few tiles: more
    /// than the rectangle holds, never less.
    pub(super) fn span(&self, x0: i64, y0: i64, x1: i64, y1: i64) -> Span {
        let (w, h) = (self.width as i64, self.height as i64);
        let (x0, y0, x1, y1) = (x0.max(0), y0.max(0), x1.min(w - 1), y1.min(h - 1));
        let mut acc = EMPTY;
        if x0 <= x1 && y0 <= y1 {
            let side = SIDE as i64;
            let (tx0, ty0, tx1, ty1) = (x0 / side, y0 / side, x1 / side, y1 / side);
            let (level, across, step) = if (tx1 - tx0).max(ty1 - ty0) < 4 {
                (&self.tiles, self.across, 1)
            } else {
                (&self.blocks, self.blocks_across, side)
            };
            for ty in ty0 / step..=ty1 / step {
                let row = ty as usize * across;
                for tx in tx0 / step..=tx1 / step {
                    acc = acc.with(&level[row + tx as usize]);
                }
            }
        }
        Span {
            any: acc.valid != 0,
            near: acc.near,
            far: acc.far,
        }
    }

    /// What is known of a sample at depth `d` in pixel `idx` (row `y`) without reading it;
    /// `solid` is the depth behind a surface that [`Seen::Deep`] must exceed.
    #[inline]
    pub(super) fn seen(&self, idx: usize, y: usize, d: f32, solid: impl FnOnce() -> f32) -> Seen {
        let x = idx - y * self.width;
        let Some(t) = self.tiles.get((y / SIDE) * self.across + x / SIDE) else {
            return Seen::Unknown;
        };
        if t.valid & (1u64 << ((y % SIDE) * SIDE + x % SIDE)) == 0 {
            Seen::Empty
        } else if d < t.near {
            Seen::Front
        } else if d - t.far > solid() {
            Seen::Deep
        } else {
            Seen::Unknown
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_sample_is_in_front_only_of_a_tile_whose_every_point_is_deeper() {
        // 10 × 9 map: depths 5 except one point at 2 in the first tile, an empty pixel, and
        // a NaN in the last tile.
        let (w, h) = (10usize, 9usize);
        let mut near = vec![Vec4::new(0.0, 0.0, 5.0, 0.1); w * h];
        near[3 * w + 4] = Vec4::new(0.0, 0.0, 2.0, 0.1);
        near[w + 1].w = f32::NEG_INFINITY;
        near[8 * w + 9] = Vec4::new(0.0, 0.0, f32::NAN, 0.1);
        let f = FrontTiles::new(w, &near, |q| q.z);
        let solid = || 0.5;
        assert_eq!(f.seen(w + 1, 1, 1.0, solid), Seen::Empty);
        assert_eq!(f.seen(0, 0, 1.9, solid), Seen::Front);
        assert_eq!(
            f.seen(0, 0, 2.0, solid),
            Seen::Unknown,
            "the nearest decides"
        );
        assert_eq!(
            f.seen(0, 0, 5.5, solid),
            Seen::Unknown,
            "the deepest decides"
        );
        assert_eq!(f.seen(0, 0, 5.6, solid), Seen::Deep);
        for d in [1.0, 5.2, 9.0] {
            let nan = f.seen(8 * w + 8, 8, d, solid);
            assert_eq!(nan, Seen::Unknown, "NaN: nothing is known");
        }
        assert_eq!(
            f.seen(9, 0, 4.9, solid),
            Seen::Front,
            "second tile holds only depth 5"
        );
        assert_eq!(f.seen(9, 0, 5.0, solid), Seen::Unknown);
    }
}
