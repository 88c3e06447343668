//! The traversed hierarchy: the binary SAH tree of [`super::bvh`] collapsed into 4-wide nodes
//! (128 bytes: the four children's boxes as structure-of-arrays, tested together with SIMD),
//! and the per-origin context that lets all rays of one query point skip the descent to
//! their common start.
//!
//! Traversal visits hit children nearest first; the ray's far end is the current nearest hit
//! (or `t_max`), so finite-range rays never leave the neighbourhood of their origin.

use super::bvh::{self, Node, Primitive, Ray, INTERIOR};
use glam::{Vec3, Vec4};

/// Four children: boxes by axis and slot, and what each slot holds: an interior node
/// (`count = 0`, `child` = node index), a leaf (`count` primitives from `child`), or nothing
/// (`child = u32::MAX`, box at +∞ so that no ray with a finite far end enters it).
#[derive(Debug, Clone, Copy)]
#[repr(C, align(64))]
struct Node4 {
    lo: [[f32; 4]; 3],
    hi: [[f32; 4]; 3],
    child: [u32; 4],
    count: [u32; 4],
}

const EMPTY: u32 = u32::MAX;

impl Node4 {
    fn empty() -> Node4 {
        Node4 {
            lo: [[f32::INFINITY; 4]; 3],
            hi: [[f32::INFINITY; 4]; 3],
            child: [EMPTY; 4],
            count: [0; 4],
        }
    }

    fn slot_box(&self, k: usize) -> (Vec3, Vec3) {
        (
            Vec3::new(self.lo[0][k], self.lo[1][k], self.lo[2][k]),
            Vec3::new(self.hi[0][k], self.hi[1][k], self.hi[2][k]),
        )
    }
}

/// A ray splatted for four-box tests.
struct Ray4 {
    o: [Vec4; 3],
    inv: [Vec4; 3],
}

impl Ray4 {
    #[inline(always)]
    fn new(ray: &Ray) -> Ray4 {
        Ray4 {
            o: [
                Vec4::splat(ray.o.x),
                Vec4::splat(ray.o.y),
                Vec4::splat(ray.o.z),
            ],
            inv: [
                Vec4::splat(ray.inv.x),
                Vec4::splat(ray.inv.y),
                Vec4::splat(ray.inv.z),
            ],
        }
    }

    /// Entry distances into four boxes and the mask of those entered within `[0, t_hi]`
    /// (`t_hi` finite).
    #[inline(always)]
    fn test(&self, lo: &[[f32; 4]; 3], hi: &[[f32; 4]; 3], t_hi: f32) -> (Vec4, u32) {
        let t1x = (Vec4::from_array(lo[0]) - self.o[0]) * self.inv[0];
        let t2x = (Vec4::from_array(hi[0]) - self.o[0]) * self.inv[0];
        let t1y = (Vec4::from_array(lo[1]) - self.o[1]) * self.inv[1];
        let t2y = (Vec4::from_array(hi[1]) - self.o[1]) * self.inv[1];
        let t1z = (Vec4::from_array(lo[2]) - self.o[2]) * self.inv[2];
        let t2z = (Vec4::from_array(hi[2]) - self.o[2]) * self.inv[2];
        let tn = t1x
            .min(t2x)
            .max(t1y.min(t2y))
            .max(t1z.min(t2z).max(Vec4::ZERO));
        let tf = t1x
            .max(t2x)
            .min(t1y.max(t2y))
            .min(t1z.max(t2z).min(Vec4::splat(t_hi)));
        (tn, tn.cmple(tf).bitmask())
    }
}

/// A 4-wide hierarchy and its primitives in leaf order. Node 0 is the root.
#[derive(Debug, Clone)]
pub(crate) struct Bvh<P> {
    nodes: Vec<Node4>,
    prims: Vec<P>,
}

/// Traversal stack entries (each level pushes at most three; the build is at most
/// `bvh::MAX_DEPTH` = 64 binary levels deep).
const STACK: usize = 3 * 64 + 4;

/// A traversal stack, kept by the caller so that no call zeroes a fresh one.
pub(crate) struct Stack([(u32, f32); STACK]);

impl Default for Stack {
    fn default() -> Self {
        Stack([(0, 0.0); STACK])
    }
}

impl<P: Primitive> Bvh<P> {
    /// Builds the hierarchy over `prims` (which it takes and reorders).
    pub fn build(prims: Vec<P>) -> Bvh<P> {
        let (bin, prims) = bvh::build(prims);
        let mut nodes = Vec::with_capacity(bin.len() / 3 + 1);
        if !bin.is_empty() {
            collapse(&bin, 0, &mut nodes);
        }
        Bvh { nodes, prims }
    }

    /// The primitives in leaf order.
    pub fn prims(&self) -> &[P] {
        &self.prims
    }

    /// Number of primitives.
    pub fn len(&self) -> usize {
        self.prims.len()
    }

    /// Bytes held by nodes and primitives.
    pub fn bytes(&self) -> usize {
        self.nodes.len() * std::mem::size_of::<Node4>()
            + self.prims.len() * std::mem::size_of::<P>()
    }

    /// Tests the `count` primitives from `first`; the nearest accepted hit below `best`.
    #[inline(always)]
    fn leaf<const ANY: bool>(&self, first: u32, count: u32, ray: &Ray, mut best: f32) -> f32 {
        let first = first as usize;
        for p in &self.prims[first..first + count as usize] {
            if let Some(t) = p.hit(ray, best) {
                best = t;
                if ANY {
                    break;
                }
            }
        }
        best
    }

    /// Nearest hit distance below `t_hi` (finite; `t_hi` itself when none). With `ANY`,
    /// the first accepted hit found ends the search.
    #[inline]
    pub fn trace<const ANY: bool>(&self, ray: &Ray, t_hi: f32, stack: &mut Stack) -> f32 {
        if self.nodes.is_empty() {
            return t_hi;
        }
        self.trace_node::<ANY>(0, ray, &Ray4::new(ray), t_hi, stack)
    }

    /// Traversal below node `start`, whose box the ray is known to enter before `t_hi`.
    #[inline]
    fn trace_node<const ANY: bool>(
        &self,
        start: u32,
        ray: &Ray,
        r4: &Ray4,
        t_hi: f32,
        stack: &mut Stack,
    ) -> f32 {
        let mut best = t_hi;
        let nodes = &self.nodes[..];
        let stack = &mut stack.0;
        let mut sp = 0usize;
        let mut cur = start as usize;
        loop {
            let node = &nodes[cur];
            let (tn, mut mask) = r4.test(&node.lo, &node.hi, best);
            let tn = tn.to_array();
            let mut cand = [(0.0f32, 0u32); 4];
            let mut nc = 0;
            while mask != 0 {
                let k = mask.trailing_zeros() as usize;
                mask &= mask - 1;
                if node.count[k] > 0 {
                    if tn[k] < best {
                        let t = self.leaf::<ANY>(node.child[k], node.count[k], ray, best);
                        if t < best {
                            best = t;
                            if ANY {
                                return best;
                            }
                        }
                    }
                } else {
                    cand[nc] = (tn[k], node.child[k]);
                    nc += 1;
                }
            }
            if nc > 0 {
                // Nearest first: sort (at most four), push the others farthest first.
                let c = &mut cand[..nc];
                for i in 1..nc {
                    let mut j = i;
                    while j > 0 && c[j - 1].0 > c[j].0 {
                        c.swap(j - 1, j);
                        j -= 1;
                    }
                }
                for &(t, n) in c[1..].iter().rev() {
                    stack[sp] = (n, t);
                    sp += 1;
                }
                if c[0].0 < best {
                    cur = c[0].1 as usize;
                    continue;
                }
            }
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

    /// Gathers what every ray from `o` into the half-space `n·(x − o) > 0` shares (see
    /// [`Origin`]) for a query point of radius `r_self`. `t_max` finite.
    pub fn origin(&self, o: Vec3, n: Vec3, r_self: f32, t_max: f32, ctx: &mut Origin) {
        ctx.near_len = 0;
        ctx.front_len = 0;
        ctx.whole = false;
        if self.nodes.is_empty() {
            return;
        }
        let mut walk = [0u32; STACK];
        let mut sp = 1usize;
        let mut nf = 0usize;
        while sp > 0 {
            sp -= 1;
            let node = &self.nodes[walk[sp] as usize];
            for k in 0..4 {
                if node.child[k] == EMPTY {
                    continue;
                }
                let (lo, hi) = node.slot_box(k);
                let Some(d) = reach(lo, hi, o, n) else {
                    continue;
                };
                if d == 0.0 {
                    // Every ray starts inside this box: open it. The primitives of such leaves
                    // are culled once for all rays (most are the point's own surface).
                    if node.count[k] > 0 {
                        let first = node.child[k] as usize;
                        for i in first..first + node.count[k] as usize {
                            if self.prims[i].can_hit(o, n, r_self) {
                                if ctx.near_len == NEAR_CAP {
                                    ctx.whole = true;
                                    return;
                                }
                                ctx.near[ctx.near_len] = i as u32;
                                ctx.near_len += 1;
                            }
                        }
                    } else {
                        if sp == STACK {
                            ctx.whole = true;
                            return;
                        }
                        walk[sp] = node.child[k];
                        sp += 1;
                    }
                } else if d < t_max {
                    if nf == FRONT_CAP {
                        ctx.whole = true;
                        return;
                    }
                    ctx.scratch[nf] = Front {
                        dist: d,
                        lo,
                        hi,
                        child: node.child[k],
                        count: node.count[k],
                    };
                    nf += 1;
                }
            }
        }
        let f = &mut ctx.scratch[..nf];
        f.sort_unstable_by(|a, b| a.dist.total_cmp(&b.dist));
        let padded = nf.div_ceil(4) * 4;
        for i in 0..padded {
            let e = if i < nf { ctx.scratch[i] } else { Front::NONE };
            let (g, k) = (i / 4, i % 4);
            for a in 0..3 {
                ctx.lo[g][a][k] = e.lo[a];
                ctx.hi[g][a][k] = e.hi[a];
            }
            ctx.child[i] = e.child;
            ctx.count[i] = e.count;
            ctx.dist[i] = e.dist;
        }
        ctx.front_len = nf;
    }

    /// Bounds of every primitive (an inverted box when empty).
    pub fn bounds(&self) -> (Vec3, Vec3) {
        let (mut lo, mut hi) = (Vec3::INFINITY, Vec3::NEG_INFINITY);
        if let Some(root) = self.nodes.first() {
            for k in 0..4 {
                if root.child[k] != EMPTY {
                    let (a, b) = root.slot_box(k);
                    lo = lo.min(a);
                    hi = hi.max(b);
                }
            }
        }
        (lo, hi)
    }

    /// True when [`Bvh::origin`] found nothing any ray from `o` could meet within `t_max`
    /// (no primitive nor box reaching above the plane through `o` normal to `n`).
    pub fn nothing_above(&self, o: Vec3, n: Vec3, t_max: f32, ctx: &mut Origin) -> bool {
        self.origin(o, n, 0.0, t_max, ctx);
        !ctx.whole && ctx.near_len == 0 && ctx.front_len == 0
    }

    /// [`Bvh::trace`] for a ray starting at the origin of `ctx` (built by [`Bvh::origin`]
    /// with a half-space containing the ray and a `t_max` at least `t_hi`).
    #[inline]
    pub fn trace_origin<const ANY: bool>(
        &self,
        ctx: &Origin,
        ray: &Ray,
        t_hi: f32,
        stack: &mut Stack,
    ) -> f32 {
        if ctx.whole {
            return self.trace::<ANY>(ray, t_hi, stack);
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
        if ctx.front_len == 0 {
            return best;
        }
        let r4 = Ray4::new(ray);
        for g in 0..ctx.front_len.div_ceil(4) {
            if ctx.dist[4 * g] >= best {
                break;
            }
            let (tn, mut mask) = r4.test(&ctx.lo[g], &ctx.hi[g], best);
            let tn = tn.to_array();
            while mask != 0 {
                let k = mask.trailing_zeros() as usize;
                mask &= mask - 1;
                if tn[k] >= best {
                    continue;
                }
                let i = 4 * g + k;
                let t = if ctx.count[i] > 0 {
                    self.leaf::<ANY>(ctx.child[i], ctx.count[i], ray, best)
                } else {
                    self.trace_node::<ANY>(ctx.child[i], ray, &r4, best, stack)
                };
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
}

/// Collapses the binary subtree at `at` (an interior node, or the root leaf) into 4-wide
/// nodes appended to `out`; returns its index.
fn collapse(bin: &[Node], at: usize, out: &mut Vec<Node4>) -> u32 {
    let me = out.len();
    out.push(Node4::empty());
    let is_leaf = |b: usize| bin[b].b & INTERIOR == 0;
    let mut slots = [0usize; 4];
    let mut ns;
    if is_leaf(at) {
        slots[0] = at;
        ns = 1;
    } else {
        slots[0] = at + 1;
        slots[1] = bin[at].a as usize;
        ns = 2;
        // Open the largest interior child until four slots are filled.
        while ns < 4 {
            let area = |b: usize| {
                let e = Vec3::from(bin[b].max) - Vec3::from(bin[b].min);
                e.x * e.y + e.y * e.z + e.z * e.x
            };
            let Some(k) = (0..ns)
                .filter(|&k| !is_leaf(slots[k]))
                .max_by(|&a, &b| area(slots[a]).total_cmp(&area(slots[b])))
            else {
                break;
            };
            let b = slots[k];
            slots[k] = b + 1;
            slots[ns] = bin[b].a as usize;
            ns += 1;
        }
    }
    let mut node = Node4::empty();
    for (k, &b) in slots[..ns].iter().enumerate() {
        for a in 0..3 {
            node.lo[a][k] = bin[b].min[a];
            node.hi[a][k] = bin[b].max[a];
        }
        if is_leaf(b) {
            node.child[k] = bin[b].a;
            node.count[k] = bin[b].b;
        } else {
            node.child[k] = collapse(bin, b, out);
        }
    }
    out[me] = node;
    me as u32
}

/// Distance from `o` to the box `lo..hi`, or `None` when the box lies entirely in
/// `n·(x − o) ≤ 0`.
fn reach(lo: Vec3, hi: Vec3, o: Vec3, n: Vec3) -> Option<f32> {
    let support = Vec3::select(n.cmpge(Vec3::ZERO), hi, lo);
    if !(n.dot(support - o) > 0.0) {
        return None;
    }
    Some((lo - o).max(o - hi).max(Vec3::ZERO).length())
}

/// Primitives kept per origin before falling back to whole-tree traversal.
const NEAR_CAP: usize = 64;
/// Subtrees kept per origin before falling back (a multiple of 4).
const FRONT_CAP: usize = 128;

#[derive(Debug, Clone, Copy)]
struct Front {
    dist: f32,
    lo: Vec3,
    hi: Vec3,
    child: u32,
    count: u32,
}

impl Front {
    const NONE: Front = Front {
        dist: f32::INFINITY,
        lo: Vec3::INFINITY,
        hi: Vec3::INFINITY,
        child: EMPTY,
        count: 0,
    };
}

/// What all rays from one origin share, computed once per query point: the primitives of
/// the leaves whose box contains the origin (every ray starts inside them) that some ray
/// could hit ([`Primitive::can_hit`]), and the other subtrees hanging off the paths to them,
/// sorted
/// by distance from the origin (boxes in groups of four for SIMD tests) so a ray stops as
/// soon as the next group is farther than its nearest hit. Subtrees entirely below the
/// tangent plane or beyond `t_max` are dropped once for all rays. Fixed capacity, no
/// allocation; a point whose neighbourhood does not fit is traced from the root.
#[derive(Clone)]
pub(crate) struct Origin {
    near: [u32; NEAR_CAP],
    near_len: usize,
    lo: [[[f32; 4]; 3]; FRONT_CAP / 4],
    hi: [[[f32; 4]; 3]; FRONT_CAP / 4],
    child: [u32; FRONT_CAP],
    count: [u32; FRONT_CAP],
    dist: [f32; FRONT_CAP],
    front_len: usize,
    scratch: [Front; FRONT_CAP],
    whole: bool,
}

impl Default for Origin {
    fn default() -> Self {
        Origin {
            near: [0; NEAR_CAP],
            near_len: 0,
            lo: [[[f32::INFINITY; 4]; 3]; FRONT_CAP / 4],
            hi: [[[f32::INFINITY; 4]; 3]; FRONT_CAP / 4],
            child: [EMPTY; FRONT_CAP],
            count: [0; FRONT_CAP],
            dist: [f32::INFINITY; FRONT_CAP],
            front_len: 0,
            scratch: [Front::NONE; FRONT_CAP],
            whole: true,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Unit cubes: hit where the ray enters the cube (not from inside).
    #[derive(Clone, Copy)]
    struct Cube(Vec3);
    impl Primitive for Cube {
        fn bounds(&self) -> (Vec3, Vec3) {
            (self.0 - 0.5, self.0 + 0.5)
        }
        fn hit(&self, ray: &Ray, t_hi: f32) -> Option<f32> {
            let lo = (self.0 - 0.5 - ray.o) * ray.inv;
            let hi = (self.0 + 0.5 - ray.o) * ray.inv;
            let tn = lo.min(hi).max_element();
            let tf = lo.max(hi).min_element();
            (tn <= tf && tn > 0.0 && tn < t_hi).then_some(tn)
        }
        fn can_hit(&self, o: Vec3, n: Vec3, _r_self: f32) -> bool {
            reach(self.0 - 0.5, self.0 + 0.5, o, n).is_some()
        }
    }

    fn rng(seed: u64) -> impl FnMut() -> f32 {
        let mut s = seed;
        move || {
            s = crate::rng::splitmix64(s);
            (s >> 40) as f32 / (1u64 << 24) as f32
        }
    }

    #[test]
    fn nearest_hit_matches_brute_force() {
        let mut st = Stack::default();
        let mut rnd = rng(12345);
        let cubes: Vec<Cube> = (0..5000)
            .map(|_| Cube(Vec3::new(rnd(), rnd(), rnd()) * 100.0))
            .collect();
        let bvh = Bvh::build(cubes.clone());
        assert_eq!(bvh.len(), 5000);
        let brute = |ray: &Ray, tmax: f32| {
            cubes
                .iter()
                .filter_map(|c| c.hit(ray, tmax))
                .fold(tmax, f32::min)
        };
        for _ in 0..500 {
            let o = Vec3::new(rnd(), rnd(), rnd()) * 100.0;
            let d = (Vec3::new(rnd(), rnd(), rnd()) - 0.5).normalize();
            let ray = Ray::new(o, d, 0.0);
            for tmax in [5.0f32, f32::MAX] {
                let want = brute(&ray, tmax);
                assert_eq!(bvh.trace::<false>(&ray, tmax, &mut st), want);
                assert_eq!(bvh.trace::<true>(&ray, tmax, &mut st) < tmax, want < tmax);
            }
        }
        // Rays sharing an origin, traced through the origin's context.
        let mut ctx = Origin::default();
        for _ in 0..200 {
            let o =
                cubes[(rnd() * 4999.0) as usize].0 + (Vec3::new(rnd(), rnd(), rnd()) - 0.5) * 0.8;
            let n = (Vec3::new(rnd(), rnd(), rnd()) - 0.5).normalize();
            for tmax in [3.0f32, 30.0, f32::MAX] {
                bvh.origin(o, n, 0.3, tmax, &mut ctx);
                for _ in 0..20 {
                    let mut d = (Vec3::new(rnd(), rnd(), rnd()) - 0.5).normalize();
                    if d.dot(n) <= 0.0 {
                        d = -d;
                    }
                    let ray = Ray::new(o, d, 0.0);
                    let want = brute(&ray, tmax);
                    assert_eq!(bvh.trace_origin::<false>(&ctx, &ray, tmax, &mut st), want);
                    assert_eq!(
                        bvh.trace_origin::<true>(&ctx, &ray, tmax, &mut st) < tmax,
                        want < tmax
                    );
                }
            }
        }
    }

    #[test]
    fn axis_aligned_rays_and_small_trees() {
        let mut st = Stack::default();
        // Zero direction components with the origin on slab planes.
        let cubes: Vec<Cube> = (0..40)
            .map(|i| Cube(Vec3::new(i as f32, 0.0, 0.0)))
            .collect();
        let bvh = Bvh::build(cubes.clone());
        let ray = Ray::new(Vec3::new(-3.0, 0.0, 0.0), Vec3::X, 0.0);
        assert_eq!(bvh.trace::<false>(&ray, f32::MAX, &mut st), 2.5);
        for o in [
            Vec3::new(-3.0, 0.5, 0.5),
            Vec3::new(4.5, 0.5, -2.0),
            Vec3::new(7.0, -0.5, 3.0),
        ] {
            for d in [Vec3::X, Vec3::Y, Vec3::Z, Vec3::NEG_Z, Vec3::NEG_Y] {
                let ray = Ray::new(o, d, 0.0);
                let want = cubes
                    .iter()
                    .filter_map(|c| c.hit(&ray, 1e9))
                    .fold(1e9, f32::min);
                assert_eq!(bvh.trace::<false>(&ray, 1e9, &mut st), want);
            }
        }
        for n in [1usize, 2, 3, 5] {
            let bvh = Bvh::build(
                (0..n)
                    .map(|i| Cube(Vec3::new(0.0, 0.0, 3.0 * i as f32)))
                    .collect(),
            );
            let ray = Ray::new(Vec3::new(0.0, 0.0, -5.0), Vec3::Z, 0.0);
            assert_eq!(bvh.trace::<false>(&ray, f32::MAX, &mut st), 4.5);
            let mut ctx = Origin::default();
            bvh.origin(ray.o, Vec3::Z, 0.0, f32::MAX, &mut ctx);
            assert_eq!(
                bvh.trace_origin::<false>(&ctx, &ray, f32::MAX, &mut st),
                4.5
            );
        }
        let empty: Bvh<Cube> = Bvh::build(Vec::new());
        assert_eq!(
            empty.trace::<false>(&Ray::new(Vec3::ZERO, Vec3::Z, 0.0), 7.0, &mut st),
            7.0
        );
    }

    #[test]
    fn origin_lists_with_surfel_culling_match_whole_tree_traversal() {
        use crate::reference::prim::Surfel;
        // A noisy plane of overlapping disks (two interleaved "scans" of different radii)
        // and a bump: the cases where neighbours are culled per origin.
        let mut rnd = rng(99);
        let mut s = Vec::new();
        for i in 0..80 {
            for j in 0..80 {
                let (x, y) = (i as f32 * 0.01, j as f32 * 0.01);
                let bump = 0.05 * (-((x - 0.4).powi(2) + (y - 0.4).powi(2)) / 0.01).exp();
                let z = bump + (rnd() - 0.5) * 0.004;
                let r = if (i + j) % 2 == 0 { 0.011 } else { 0.02 };
                let n = (Vec3::new(0.0, 0.0, 1.0) + (Vec3::new(rnd(), rnd(), 0.0) - 0.5) * 0.1)
                    .normalize();
                s.push(Surfel {
                    c: Vec3::new(x, y, z),
                    r2: r * r,
                    n,
                    r,
                });
            }
        }
        let bvh = Bvh::build(s.clone());
        let mut ctx = Origin::default();
        let mut st = Stack::default();
        let mut hits = 0;
        for q in s.iter().step_by(37) {
            let o = q.c + q.n * (0.01 * q.r);
            for tmax in [0.1f32, f32::MAX] {
                bvh.origin(o, q.n, q.r, tmax, &mut ctx);
                for _ in 0..16 {
                    let mut d = (Vec3::new(rnd(), rnd(), rnd()) - 0.5).normalize();
                    if d.dot(q.n) <= 0.0 {
                        d = -d;
                    }
                    let ray = Ray::new(o, d, q.r);
                    let want = bvh.trace::<false>(&ray, tmax, &mut st);
                    hits += (want < tmax) as usize;
                    assert_eq!(bvh.trace_origin::<false>(&ctx, &ray, tmax, &mut st), want);
                    let any = bvh.trace_origin::<true>(&ctx, &ray, tmax, &mut st);
                    assert_eq!(any < tmax, want < tmax);
                }
            }
        }
        assert!(hits > 100, "{hits}");
    }

    #[test]
    fn coincident_primitives_build_bounded_tree() {
        let mut st = Stack::default();
        let bvh = Bvh::build(vec![Cube(Vec3::ONE); 10_000]);
        let ray = Ray::new(Vec3::new(1.0, 1.0, -5.0), Vec3::Z, 0.0);
        assert_eq!(bvh.trace::<false>(&ray, f32::MAX, &mut st), 5.5);
    }
}
