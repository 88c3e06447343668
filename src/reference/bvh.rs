//! A bounding volume hierarchy over one kind of primitive: binned SAH build (parallel near the
//! root), flattened depth-first into 32-byte nodes (left child = next node), primitives
//! reordered into leaf order so a leaf reads one contiguous run of memory.
//!
//! Traversal tests both children's boxes at their parent and descends into the nearer one
//! first; the ray's far end is the current nearest hit (or `t_max`), so finite-range rays
//! never leave the neighbourhood of their origin.

use glam::Vec3;

/// A primitive the hierarchy can hold.
pub(crate) trait Primitive: Copy + Send + Sync {
    /// Axis-aligned bounds `(min, max)`.
    fn bounds(&self) -> (Vec3, Vec3);
    /// Nearest accepted hit with `t ∈ (0, t_hi)`, if any.
    fn hit(&self, ray: &Ray, t_hi: f32) -> Option<f32>;
    /// Whether some point of the primitive lies in the open half-space `n·(x − o) > 0`.
    fn above(&self, o: Vec3, n: Vec3) -> bool;
}

/// A ray with what the primitives need to recognise the query point's own surface.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Ray {
    /// Origin.
    pub o: Vec3,
    /// Unit direction.
    pub d: Vec3,
    /// Component-wise `1/d`.
    pub inv: Vec3,
    /// The query point's radius `rad(p)` (surfels use it for the back-hit rule).
    pub r_self: f32,
}

impl Ray {
    /// A ray from `o` along the unit vector `d`.
    #[inline]
    pub fn new(o: Vec3, d: Vec3, r_self: f32) -> Ray {
        Ray {
            o,
            d,
            inv: d.recip(),
            r_self,
        }
    }
}

/// One flattened node (32 bytes, two per cache line). Interior: `b = INTERIOR | axis`,
/// `a` = index of the right child (the left child is the next node). Leaf: `b` = number of
/// primitives, `a` = first primitive.
#[derive(Debug, Clone, Copy, Default)]
#[repr(C, align(32))]
struct Node {
    min: [f32; 3],
    a: u32,
    max: [f32; 3],
    b: u32,
}

const INTERIOR: u32 = 1 << 31;

impl Node {
    /// Entry distance of the ray into the box, or `f32::INFINITY` when it misses it within
    /// `[0, t_hi]`. NaN from a zero direction component on a slab plane is dropped by
    /// `min`/`max`, which keeps the test conservative.
    #[inline(always)]
    fn enter(&self, ray: &Ray, t_hi: f32) -> f32 {
        let t1x = (self.min[0] - ray.o.x) * ray.inv.x;
        let t2x = (self.max[0] - ray.o.x) * ray.inv.x;
        let t1y = (self.min[1] - ray.o.y) * ray.inv.y;
        let t2y = (self.max[1] - ray.o.y) * ray.inv.y;
        let t1z = (self.min[2] - ray.o.z) * ray.inv.z;
        let t2z = (self.max[2] - ray.o.z) * ray.inv.z;
        let tn = t1x.min(t2x).max(t1y.min(t2y)).max(t1z.min(t2z)).max(0.0);
        let tf = t1x.max(t2x).min(t1y.max(t2y)).min(t1z.max(t2z)).min(t_hi);
        if tn <= tf {
            tn
        } else {
            f32::INFINITY
        }
    }
}

/// The hierarchy and its primitives in leaf order.
#[derive(Debug, Clone)]
pub(crate) struct Bvh<P> {
    nodes: Vec<Node>,
    prims: Vec<P>,
}

/// Deepest node the build creates; the traversal stack holds one entry per level.
const MAX_DEPTH: usize = 64;
/// SAH bins per axis.
const BINS: usize = 16;
/// Leaves never hold more (unless all centroids coincide and the depth limit is hit).
const MAX_LEAF: usize = 8;
/// Cost of a box test relative to a primitive test.
const C_TRAV: f32 = 1.0;
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

impl<P: Primitive> Bvh<P> {
    /// Builds the hierarchy over `prims` (which it takes and reorders).
    pub fn build(prims: Vec<P>) -> Bvh<P> {
        if prims.is_empty() {
            return Bvh {
                nodes: Vec::new(),
                prims,
            };
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
        Bvh { nodes, prims }
    }

    /// Number of primitives.
    pub fn len(&self) -> usize {
        self.prims.len()
    }

    /// Bytes held by nodes and primitives.
    pub fn bytes(&self) -> usize {
        self.nodes.len() * std::mem::size_of::<Node>() + self.prims.len() * std::mem::size_of::<P>()
    }

    /// Nearest hit distance below `t_hi` (`t_hi` itself when none). With `ANY`, the first
    /// accepted hit found ends the search (its distance is returned, not necessarily the
    /// nearest).
    #[inline]
    pub fn trace<const ANY: bool>(&self, ray: &Ray, t_hi: f32) -> f32 {
        match self.nodes.first() {
            Some(root) if root.enter(ray, t_hi) < f32::INFINITY => {
                self.trace_from::<ANY>(0, ray, t_hi)
            }
            _ => t_hi,
        }
    }

    /// Gathers what every ray from `o` into the half-space `n·x > n·o` shares (see
    /// [`Origin`]): walks the nodes whose box contains `o` once, keeps the primitives of such
    /// leaves that reach into the half-space, and the other children (sorted by distance
    /// from `o`) that reach into it closer than `t_max`.
    pub fn origin(&self, o: Vec3, n: Vec3, t_max: f32, ctx: &mut Origin) {
        ctx.near_len = 0;
        ctx.front_len = 0;
        ctx.whole = false;
        if self.nodes.is_empty() {
            return;
        }
        let nodes = &self.nodes[..];
        let mut stack = [0u32; MAX_DEPTH];
        let mut sp = 0usize;
        let mut cur = 0usize;
        if !nodes[0].contains(o) {
            if !ctx.push_front(nodes[0].reach(o, n), 0, t_max) {
                ctx.whole = true;
            }
            return;
        }
        loop {
            let node = &nodes[cur];
            if node.b & INTERIOR != 0 {
                let mut next = None;
                for c in [cur + 1, node.a as usize] {
                    if nodes[c].contains(o) {
                        if let Some(first) = next.replace(c) {
                            stack[sp] = first as u32;
                            sp += 1;
                        }
                    } else if !ctx.push_front(nodes[c].reach(o, n), c, t_max) {
                        ctx.whole = true;
                        return;
                    }
                }
                if let Some(c) = next {
                    cur = c;
                    continue;
                }
            } else {
                let first = node.a as usize;
                for (k, p) in self.prims[first..first + node.b as usize]
                    .iter()
                    .enumerate()
                {
                    if p.above(o, n) {
                        if ctx.near_len == NEAR_CAP {
                            ctx.whole = true;
                            return;
                        }
                        ctx.near[ctx.near_len] = (first + k) as u32;
                        ctx.near_len += 1;
                    }
                }
            }
            if sp == 0 {
                break;
            }
            sp -= 1;
            cur = stack[sp] as usize;
        }
        let f = &mut ctx.front[..ctx.front_len];
        f.sort_unstable_by(|a, b| a.1.total_cmp(&b.1));
    }

    /// [`Bvh::trace`] for a ray starting at the origin of `ctx` (built by [`Bvh::origin`]
    /// with a half-space containing the ray).
    #[inline]
    pub fn trace_origin<const ANY: bool>(&self, ctx: &Origin, ray: &Ray, t_hi: f32) -> f32 {
        if ctx.whole {
            return self.trace::<ANY>(ray, t_hi);
        }
        let mut best = t_hi;
        for &i in &ctx.near[..ctx.near_len] {
            if let Some(t) = self.prims[i as usize].hit(ray, best) {
                best = t;
                if ANY {
                    return best;
                }
            }
        }
        for &(node, dist) in &ctx.front[..ctx.front_len] {
            if dist >= best {
                break;
            }
            if self.nodes[node as usize].enter(ray, best) < f32::INFINITY {
                let t = self.trace_from::<ANY>(node as usize, ray, best);
                if t < best {
                    best = t;
                    if ANY {
                        return best;
                    }
                }
            }
        }
        best
    }

    /// Traversal below node `start`, whose box the ray is known to enter before `t_hi`.
    #[inline]
    fn trace_from<const ANY: bool>(&self, start: usize, ray: &Ray, t_hi: f32) -> f32 {
        let mut best = t_hi;
        let nodes = &self.nodes[..];
        let mut stack = [(0u32, 0.0f32); MAX_DEPTH];
        let mut sp = 0usize;
        let mut cur = start;
        loop {
            let node = &nodes[cur];
            if node.b & INTERIOR != 0 {
                let (l, r) = (cur + 1, node.a as usize);
                let tl = nodes[l].enter(ray, best);
                let tr = nodes[r].enter(ray, best);
                match (tl < f32::INFINITY, tr < f32::INFINITY) {
                    (true, true) => {
                        let (near, far, tfar) = if tl <= tr { (l, r, tr) } else { (r, l, tl) };
                        // The stack cannot overflow: each level pushes at most one entry and
                        // the build stops at MAX_DEPTH levels.
                        stack[sp] = (far as u32, tfar);
                        sp += 1;
                        cur = near;
                        continue;
                    }
                    (true, false) => {
                        cur = l;
                        continue;
                    }
                    (false, true) => {
                        cur = r;
                        continue;
                    }
                    (false, false) => {}
                }
            } else {
                let first = node.a as usize;
                for p in &self.prims[first..first + node.b as usize] {
                    if let Some(t) = p.hit(ray, best) {
                        best = t;
                        if ANY {
                            return best;
                        }
                    }
                }
            }
            // Pop the next node still nearer than the best hit.
            loop {
                if sp == 0 {
                    return best;
                }
                sp -= 1;
                let (n, t) = stack[sp];
                if t < best {
                    cur = n as usize;
                    break;
                }
            }
        }
    }
}

/// Primitives kept per origin before falling back to whole-tree traversal.
const NEAR_CAP: usize = 64;
/// Subtrees kept per origin before falling back.
const FRONT_CAP: usize = 192;

/// What all rays from one origin share, computed once per query point: the primitives of
/// the leaves whose box contains the origin (every ray starts inside those boxes) that reach
/// above the origin's tangent plane, and the other subtrees hanging off the path to them,
/// sorted by their distance from the origin so a ray stops as soon as the next one is
/// farther than its nearest hit. Subtrees entirely below the tangent plane or beyond
/// `t_max` are dropped once for all rays. Fixed capacity, no allocation; a point whose
/// neighbourhood does not fit is traced from the root.
#[derive(Clone)]
pub(crate) struct Origin {
    near: [u32; NEAR_CAP],
    near_len: usize,
    front: [(u32, f32); FRONT_CAP],
    front_len: usize,
    whole: bool,
}

impl Default for Origin {
    fn default() -> Self {
        Origin {
            near: [0; NEAR_CAP],
            near_len: 0,
            front: [(0, 0.0); FRONT_CAP],
            front_len: 0,
            whole: true,
        }
    }
}

impl Origin {
    /// Adds a subtree at distance `reach` (`None`: unreachable); false when full.
    fn push_front(&mut self, reach: Option<f32>, node: usize, t_max: f32) -> bool {
        match reach {
            Some(d) if d < t_max => {
                if self.front_len == FRONT_CAP {
                    return false;
                }
                self.front[self.front_len] = (node as u32, d);
                self.front_len += 1;
                true
            }
            _ => true,
        }
    }
}

impl Node {
    fn contains(&self, p: Vec3) -> bool {
        (0..3).all(|k| self.min[k] <= p[k] && p[k] <= self.max[k])
    }

    /// Distance from `o` to the box, or `None` when the box lies entirely in `n·(x − o) ≤ 0`.
    fn reach(&self, o: Vec3, n: Vec3) -> Option<f32> {
        let (lo, hi) = (Vec3::from(self.min), Vec3::from(self.max));
        let support = Vec3::select(n.cmpge(Vec3::ZERO), hi, lo);
        if !(n.dot(support - o) > 0.0) {
            return None;
        }
        Some((lo - o).max(o - hi).max(Vec3::ZERO).length())
    }
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

#[cfg(test)]
mod tests {
    use super::*;

    /// Unit-size axis-aligned "points": hit when the ray passes within 0.5 of the centre
    /// in its box.
    #[derive(Clone, Copy)]
    struct Cube(Vec3);
    impl Primitive for Cube {
        fn bounds(&self) -> (Vec3, Vec3) {
            (self.0 - 0.5, self.0 + 0.5)
        }
        fn hit(&self, ray: &Ray, t_hi: f32) -> Option<f32> {
            let n = node_box(self.0 - 0.5, self.0 + 0.5);
            let t = n.enter(ray, t_hi);
            (t < t_hi && t > 0.0).then_some(t)
        }
        fn above(&self, o: Vec3, n: Vec3) -> bool {
            node_box(self.0 - 0.5, self.0 + 0.5).reach(o, n).is_some()
        }
    }

    #[test]
    fn nearest_hit_matches_brute_force() {
        let mut s = 12345u64;
        let mut rnd = || {
            s = crate::ssao::rng::splitmix64(s);
            (s >> 40) as f32 / (1u64 << 24) as f32
        };
        let cubes: Vec<Cube> = (0..5000)
            .map(|_| Cube(Vec3::new(rnd(), rnd(), rnd()) * 100.0))
            .collect();
        let bvh = Bvh::build(cubes.clone());
        assert_eq!(bvh.len(), 5000);
        for _ in 0..500 {
            let o = Vec3::new(rnd(), rnd(), rnd()) * 100.0;
            let d = (Vec3::new(rnd(), rnd(), rnd()) - 0.5).normalize();
            let ray = Ray::new(o, d, 0.0);
            for tmax in [5.0f32, f32::INFINITY] {
                let brute = cubes
                    .iter()
                    .filter_map(|c| c.hit(&ray, tmax))
                    .fold(tmax, f32::min);
                assert_eq!(bvh.trace::<false>(&ray, tmax), brute);
                let any = bvh.trace::<true>(&ray, tmax);
                assert_eq!(any < tmax, brute < tmax);
            }
        }
        // Rays sharing an origin, traced through the origin's context, against brute force.
        let mut ctx = Origin::default();
        for _ in 0..200 {
            // Origins inside the cloud (inside some boxes) and a random half-space.
            let o =
                cubes[(rnd() * 4999.0) as usize].0 + (Vec3::new(rnd(), rnd(), rnd()) - 0.5) * 0.8;
            let n = (Vec3::new(rnd(), rnd(), rnd()) - 0.5).normalize();
            for tmax in [3.0f32, f32::INFINITY] {
                bvh.origin(o, n, tmax, &mut ctx);
                assert!(!ctx.whole);
                for _ in 0..20 {
                    let mut d = (Vec3::new(rnd(), rnd(), rnd()) - 0.5).normalize();
                    if d.dot(n) <= 0.0 {
                        d = -d;
                    }
                    let ray = Ray::new(o, d, 0.0);
                    let brute = cubes
                        .iter()
                        .filter_map(|c| c.hit(&ray, tmax))
                        .fold(tmax, f32::min);
                    assert_eq!(bvh.trace_origin::<false>(&ctx, &ray, tmax), brute);
                    let any = bvh.trace_origin::<true>(&ctx, &ray, tmax);
                    assert_eq!(any < tmax, brute < tmax);
                }
            }
        }
    }

    #[test]
    fn coincident_primitives_build_bounded_tree() {
        let cubes = vec![Cube(Vec3::ONE); 10_000];
        let bvh = Bvh::build(cubes);
        let ray = Ray::new(Vec3::new(1.0, 1.0, -5.0), Vec3::Z, 0.0);
        assert_eq!(bvh.trace::<false>(&ray, f32::INFINITY), 5.5);
    }
}
