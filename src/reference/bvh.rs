//! The binary bounding volume hierarchy build: binned SAH (parallel near the root), flattened
//! depth-first (left child = next node), primitives reordered into leaf order so a leaf reads
//! one contiguous run of memory. [`super::wide`] collapses it into the 4-wide tree that is
//! traversed.

use glam::Vec3;

/// A primitive the hierarchy can hold.
pub(crate) trait Primitive: Copy + Send + Sync {
    /// Axis-aligned bounds `(min, max)`.
    fn bounds(&self) -> (Vec3, Vec3);
    /// Nearest accepted hit with `t ∈ (0, t_hi)`, if any.
    fn hit(&self, ray: &Ray, t_hi: f32) -> Option<f32>;
    /// False when no ray from `o` into the half-space `n·(x − o) > 0` can get an accepted
    /// hit on the primitive (for a query point of radius `r_self`); true when unsure.
    fn can_hit(&self, o: Vec3, n: Vec3, r_self: f32) -> bool;
}

/// A ray with what the primitives need to recognise the query point's own surface.
#[derive(Debug, Clone)]
pub(crate) struct Ray {
    /// Origin.
    pub o: Vec3,
    /// Unit direction.
    pub d: Vec3,
    /// Component-wise `1/d`.
    pub inv: Vec3,
    /// The query point's radius `rad(p)` (surfels use it for the back-hit rule).
    pub r_self: f32,
    /// The query point's unit normal for the own-patch rule (zero: no such rule).
    pub n_self: Vec3,
    /// Height above the query point's tangent plane below which a surface parallel to it is
    /// its own (the registration residual between scans; 0: none).
    pub h_self: f32,
    /// Rise of the ray per unit length over the tangent plane (`d·n_self`).
    pub rise: f32,
    /// Hits the rules discarded as the query point's own surface.
    pub discarded: std::cell::Cell<u32>,
}

impl Ray {
    /// A ray from `o` along the unit vector `d`.
    #[inline]
    pub fn new(o: Vec3, d: Vec3, r_self: f32) -> Ray {
        // A zero component would give 0·∞ = NaN in the slab test for an origin on a slab
        // plane; a tiny one gives a huge finite slope instead.
        let safe = Vec3::select(
            d.abs().cmplt(Vec3::splat(1e-30)),
            Vec3::splat(1e-30).copysign(d),
            d,
        );
        Ray {
            o,
            d,
            inv: safe.recip(),
            r_self,
            n_self: Vec3::ZERO,
            h_self: 0.0,
            rise: 0.0,
            discarded: std::cell::Cell::new(0),
        }
    }

    /// A ray of a query point with normal `n` (unit) and own-surface height `h_self`: the
    /// own-patch rule applies.
    #[inline]
    pub fn of_point(o: Vec3, d: Vec3, r_self: f32, n: Vec3, h_self: f32) -> Ray {
        Ray {
            n_self: n,
            h_self,
            rise: d.dot(n),
            ..Ray::new(o, d, r_self)
        }
    }

    /// Notes one discarded hit.
    #[inline]
    pub fn discard(&self) {
        self.discarded.set(self.discarded.get() + 1);
    }
}

/// One flattened node (32 bytes, two per cache line). Interior: `b = INTERIOR | axis`,
/// `a` = index of the right child (the left child is the next node). Leaf: `b` = number of
/// primitives, `a` = first primitive.
#[derive(Debug, Clone, Copy, Default)]
#[repr(C, align(32))]
pub(crate) struct Node {
    pub min: [f32; 3],
    pub a: u32,
    pub max: [f32; 3],
    pub b: u32,
}

pub(crate) const INTERIOR: u32 = 1 << 31;

/// Deepest node the build creates; the traversal stack holds one entry per level.
const MAX_DEPTH: usize = 64;
/// SAH bins per axis.
const BINS: usize = 16;
/// Leaves never hold more (unless all centroids coincide and the depth limit is hit).
const MAX_LEAF: usize = 16;
/// Cost of a box test relative to a primitive test.
const C_TRAV: f32 = 3.0;
/// Subtrees at least this large are built in parallel.
const PAR_MIN: usize = 32 * 1024;

/// Build-time record of one primitive.
#[derive(Clone, Copy)]
struct Item {
    min: Vec3,
    max: Vec3,
    c: Vec3,
    idx: u32,
}

/// Builds the binary hierarchy over `prims`: its nodes (empty for no primitive) and the
/// primitives in leaf order.
pub(crate) fn build<P: Primitive>(prims: Vec<P>) -> (Vec<Node>, Vec<P>) {
    if prims.is_empty() {
        return (Vec::new(), prims);
    }
    let mut items: Vec<Item> = prims
        .iter()
        .enumerate()
        .map(|(i, p)| {
            let (min, max) = p.bounds();
            Item {
                min,
                max,
                c: (min + max) * 0.5,
                idx: i as u32,
            }
        })
        .collect();
    let nodes = build_par(&mut items, 0, 0);
    let prims = items.iter().map(|it| prims[it.idx as usize]).collect();
    (nodes, prims)
}

/// Bounds of a slice of items: (box min, box max, centroid min, centroid max).
fn bounds_of(items: &[Item]) -> (Vec3, Vec3, Vec3, Vec3) {
    let mut b = (
        Vec3::splat(f32::INFINITY),
        Vec3::splat(f32::NEG_INFINITY),
        Vec3::splat(f32::INFINITY),
        Vec3::splat(f32::NEG_INFINITY),
    );
    for it in items {
        b.0 = b.0.min(it.min);
        b.1 = b.1.max(it.max);
        b.2 = b.2.min(it.c);
        b.3 = b.3.max(it.c);
    }
    b
}

fn half_area(min: Vec3, max: Vec3) -> f32 {
    let e = (max - min).max(Vec3::ZERO);
    e.x * e.y + e.y * e.z + e.z * e.x
}

/// Where to split `items` (already bounded by `bmin..bmax` with centroid box `cmin..cmax`):
/// the binned-SAH split position (number of items going left, after partitioning), or
/// `None` to make a leaf.
fn split(
    items: &mut [Item],
    bmin: Vec3,
    bmax: Vec3,
    cmin: Vec3,
    cmax: Vec3,
    depth: usize,
) -> Option<usize> {
    let n = items.len();
    if n <= 2 || depth + 1 >= MAX_DEPTH {
        return None;
    }
    let ext = cmax - cmin;
    let mut best = (f32::INFINITY, 0usize, 0usize); // cost, axis, bins going left
    for axis in 0..3 {
        if !(ext[axis] > 0.0) {
            continue;
        }
        let scale = BINS as f32 / ext[axis];
        let mut cnt = [0u32; BINS];
        let mut bmn = [Vec3::splat(f32::INFINITY); BINS];
        let mut bmx = [Vec3::splat(f32::NEG_INFINITY); BINS];
        for it in items.iter() {
            let k = (((it.c[axis] - cmin[axis]) * scale) as usize).min(BINS - 1);
            cnt[k] += 1;
            bmn[k] = bmn[k].min(it.min);
            bmx[k] = bmx[k].max(it.max);
        }
        // Sweep from the right: area × count of every right part.
        let mut right = [0.0f32; BINS];
        let (mut mn, mut mx, mut c) = (
            Vec3::splat(f32::INFINITY),
            Vec3::splat(f32::NEG_INFINITY),
            0u32,
        );
        for k in (1..BINS).rev() {
            mn = mn.min(bmn[k]);
            mx = mx.max(bmx[k]);
            c += cnt[k];
            right[k] = if c > 0 {
                half_area(mn, mx) * c as f32
            } else {
                0.0
            };
        }
        let (mut mn, mut mx, mut c) = (
            Vec3::splat(f32::INFINITY),
            Vec3::splat(f32::NEG_INFINITY),
            0u32,
        );
        for k in 0..BINS - 1 {
            mn = mn.min(bmn[k]);
            mx = mx.max(bmx[k]);
            c += cnt[k];
            if c == 0 || c as usize == n {
                continue;
            }
            let cost = half_area(mn, mx) * c as f32 + right[k + 1];
            if cost < best.0 {
                best = (cost, axis, k + 1);
            }
        }
    }
    let parent = half_area(bmin, bmax).max(f32::MIN_POSITIVE);
    let leaf_cost = n as f32;
    if best.0.is_finite() {
        let split_cost = C_TRAV + best.0 / parent;
        if split_cost >= leaf_cost && n <= MAX_LEAF {
            return None;
        }
        let (axis, bins) = (best.1, best.2);
        let scale = BINS as f32 / ext[axis];
        let lo = cmin[axis];
        let mid = partition(items, |it| {
            (((it.c[axis] - lo) * scale) as usize).min(BINS - 1) < bins
        });
        if mid > 0 && mid < n {
            return Some(mid);
        }
    }
    if n <= MAX_LEAF {
        return None;
    }
    // All centroids in one bin (or coincident): split at the median along the widest axis.
    let axis = ext.max_position();
    let mid = n / 2;
    items.select_nth_unstable_by(mid, |a, b| a.c[axis].total_cmp(&b.c[axis]));
    Some(mid)
}

/// In-place partition; returns the number of items for which `left` holds.
fn partition(items: &mut [Item], left: impl Fn(&Item) -> bool) -> usize {
    let mut i = 0;
    let mut j = items.len();
    while i < j {
        if left(&items[i]) {
            i += 1;
        } else {
            j -= 1;
            items.swap(i, j);
        }
    }
    i
}

fn node_box(min: Vec3, max: Vec3) -> Node {
    Node {
        min: min.to_array(),
        max: max.to_array(),
        ..Default::default()
    }
}

/// Builds the subtree of `items` (whose first item is primitive number `first` in the final
/// order) and returns its nodes in depth-first order with indices relative to the subtree.
fn build_par(items: &mut [Item], first: usize, depth: usize) -> Vec<Node> {
    if items.len() < PAR_MIN {
        let mut out = Vec::with_capacity(2 * items.len() / 3 + 1);
        build_seq(items, first, depth, &mut out);
        return out;
    }
    let (bmin, bmax, cmin, cmax) = bounds_of(items);
    let mut node = node_box(bmin, bmax);
    let Some(mid) = split(items, bmin, bmax, cmin, cmax, depth) else {
        node.a = first as u32;
        node.b = items.len() as u32;
        return vec![node];
    };
    let (li, ri) = items.split_at_mut(mid);
    let (left, right) = rayon::join(
        || build_par(li, first, depth + 1),
        || build_par(ri, first + mid, depth + 1),
    );
    let base_r = 1 + left.len();
    node.a = base_r as u32;
    node.b = INTERIOR | axis_of(bmin, bmax);
    let mut out = Vec::with_capacity(1 + left.len() + right.len());
    out.push(node);
    out.extend(left.into_iter().map(|n| shift(n, 1)));
    out.extend(right.into_iter().map(|n| shift(n, base_r as u32)));
    out
}

/// Re-bases a node's child index by `off` (leaves keep their primitive index).
fn shift(mut n: Node, off: u32) -> Node {
    if n.b & INTERIOR != 0 {
        n.a += off;
    }
    n
}

fn axis_of(min: Vec3, max: Vec3) -> u32 {
    (max - min).max_position() as u32
}

fn build_seq(items: &mut [Item], first: usize, depth: usize, out: &mut Vec<Node>) {
    let (bmin, bmax, cmin, cmax) = bounds_of(items);
    let me = out.len();
    out.push(node_box(bmin, bmax));
    match split(items, bmin, bmax, cmin, cmax, depth) {
        None => {
            out[me].a = first as u32;
            out[me].b = items.len() as u32;
        }
        Some(mid) => {
            let (li, ri) = items.split_at_mut(mid);
            build_seq(li, first, depth + 1, out);
            out[me].a = out.len() as u32;
            out[me].b = INTERIOR | axis_of(bmin, bmax);
            build_seq(ri, first + mid, depth + 1, out);
        }
    }
}
