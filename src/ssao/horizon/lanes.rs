//! The SIMD half of the march: a pixel's directions set up and marched four at a time, one
//! per lane, with the same arithmetic as the one-direction references in the tests.

use super::*;
use crate::projection::{atan2_4, sqrt4};
use glam::{BVec4A, Vec4};

impl<'a> Ctx<'a> {
    /// Sets up the group's directions, one per lane (`grp.n` of them), with the arithmetic of
    /// [`Slice::new`], [`unit`] and [`exit`] done on all lanes at once (the divisions and
    /// square roots of four directions in one instruction each). Every lane gets the same bits
    /// as [`Ctx::setup_one`] (a test checks it): the same operations in the same order, and
    /// selects where the scalar code branches.
    #[inline(always)]
    pub(super) fn setup_lanes(
        &self,
        f: &Frame,
        dirs: &mut Dirs,
        grp: &mut Group,
        terms: &mut [Term; LANES],
    ) {
        let n = grp.n;
        let (mut sn, mut cs, mut jit, mut bs) =
            ([0.0f32; LANES], [0.0; LANES], [0.0; LANES], [0.0; LANES]);
        let mut us = [Vec3A::ZERO; LANES];
        for l in 0..n {
            let ((s, co), j) = dirs.next(self.rot);
            (sn[l], cs[l], jit[l]) = (s, co, j);
            us[l] = f.e1 * co + f.e2 * s;
            bs[l] = f.na.dot(us[l]);
        }
        let lanes = BVec4A::new(n > 0, n > 1, n > 2, n > 3);
        let a = f.a;
        let (av, b) = (Vec4::splat(a), Vec4::from_array(bs));
        // Slice::new on four lanes (a is the pixel's, so its branch is the same for all).
        let r = sqrt4(Vec4::splat(a * a) + b * b);
        let ok = lanes & r.cmpgt(Vec4::splat(1e-6)) & r.is_finite_mask();
        let inv_r = Vec4::ONE / r;
        let (ca, sb) = (av * inv_r, b * inv_r);
        let (lo, lo_s, lo_c, hi, hi_s, hi_c, g_lo, g_hi);
        if a > 0.0 {
            (lo, lo_s, lo_c) = (Vec4::ZERO, Vec4::ZERO, Vec4::ONE);
            hi = atan2_4(b, Vec4::splat(a)) + Vec4::splat(FRAC_PI_2);
            (hi_s, hi_c) = (ca, -sb);
            g_lo = Vec4::splat(-0.25 * a);
            g_hi = Vec4::splat(0.25 * a) + Vec4::splat(0.5) * b * hi;
        } else {
            let gn = Vec4::select(
                b.cmpeq(Vec4::ZERO),
                Vec4::splat(PI),
                atan2_4(b, Vec4::splat(a)),
            );
            lo = Vec4::select(
                gn.cmplt(Vec4::splat(FRAC_PI_2)),
                gn + Vec4::splat(1.5 * PI),
                gn - Vec4::splat(FRAC_PI_2),
            );
            (lo_s, lo_c) = (-ca, sb);
            (hi, hi_s, hi_c) = (Vec4::splat(PI), Vec4::ZERO, Vec4::splat(-1.0));
            let g = |s: Vec4, c: Vec4, gamma: Vec4| {
                Vec4::splat(-0.25 * a) * (c * c - s * s) + Vec4::splat(0.5) * b * (gamma - s * c)
            };
            (g_lo, g_hi) = (g(lo_s, lo_c, lo), g(hi_s, hi_c, hi));
        }
        let ok = ok & hi.cmpgt(lo);
        let open = (g_hi - g_lo).max(Vec4::ZERO);
        // The march: unit screen direction, its length to the t_max ellipse and the map's
        // edges, from where it leaves the pixel.
        let march = f.d.map(|(d1, d2)| {
            let (co, s) = (Vec4::from_array(cs), Vec4::from_array(sn));
            let x = co * d1.0 + s * d2.0;
            let y = co * d1.1 + s * d2.1;
            let len = sqrt4(x * x + y * y);
            let dir_ok = len.cmpgt(Vec4::ZERO) & len.is_finite_mask();
            let (dx, dy) = (x / len, y / len);
            let (idx, idy) = (Vec4::ONE / dx, Vec4::ONE / dy);
            let ellipse =
                Vec4::ONE / sqrt4(dx * dx * Vec4::splat(f.irx2) + dy * dy * Vec4::splat(f.iry2));
            // Pixels per radian of arc along each direction (spherical maps only).
            let ppr = len * Vec4::splat(f.arc.map_or(0.0, |a| a.0));
            let reach = if let Some((_, angle)) = f.arc {
                ppr * Vec4::splat(angle)
            } else {
                let mut reach = min_lanes(ellipse, exit_lanes(f.o.1, idy, self.hf));
                reach = min_lanes(reach, Vec4::splat(self.wf + self.hf));
                if !self.wrap {
                    reach = min_lanes(reach, exit_lanes(f.o.0, idx, self.wf));
                }
                reach
            };
            let t0 = min_lanes(exit_lanes(f.fo.0, idx, 1.0), exit_lanes(f.fo.1, idy, 1.0));
            let span = reach - t0;
            let go = (dir_ok & span.cmpgt(Vec4::ZERO)).bitmask();
            let [dx, dy, t0, span, ppr] = [dx, dy, t0, span, ppr].map(|v| v.to_array());
            (dx, dy, t0, span, ppr, go)
        });
        let okb = ok.bitmask();
        let (b, inv_r, lo, lo_s, lo_c, hi, hi_s, hi_c, g_lo, g_hi, open) = (
            b.to_array(),
            inv_r.to_array(),
            lo.to_array(),
            lo_s.to_array(),
            lo_c.to_array(),
            hi.to_array(),
            hi_s.to_array(),
            hi_c.to_array(),
            g_lo.to_array(),
            g_hi.to_array(),
            open.to_array(),
        );
        for l in 0..n {
            if okb & (1 << l) == 0 {
                continue;
            }
            terms[l] = Term::Open(open[l]);
            let Some((dx, dy, t0, span, ppr, go)) = &march else {
                continue;
            };
            if go & (1 << l) == 0 {
                continue;
            }
            let slice = Slice {
                a,
                b: b[l],
                inv_r: inv_r[l],
                lo: lo[l],
                lo_sc: (lo_s[l], lo_c[l]),
                hi: hi[l],
                hi_sc: (hi_s[l], hi_c[l]),
                g_lo: g_lo[l],
                g_hi: g_hi[l],
            };
            self.start(
                f,
                grp,
                l,
                slice,
                us[l],
                (dx[l], dy[l]),
                (t0[l], span[l]),
                ppr[l],
                jit[l],
            );
            terms[l] = Term::March(open[l], l);
        }
    }

    /// Lane `l`'s march along unit screen direction `dir` from `t0`, over `span` pixels (on
    /// a spherical map along the great circle, `ppr` pixels to the radian).
    #[allow(clippy::too_many_arguments)]
    #[inline(always)]
    pub(super) fn start(
        &self,
        f: &Frame,
        grp: &mut Group,
        l: usize,
        slice: Slice,
        u: Vec3A,
        (dx, dy): (f32, f32),
        (t0, span): (f32, f32),
        ppr: f32,
        jitter: f32,
    ) {
        let count = (span as u32).clamp(1, f.steps);
        let step = span / count as f32;
        // In-plane coordinates as linear forms of v = s − p: along the tangent line
        // (a u − b V)/R as measured; across it the height n·v above the tangent plane
        // scaled to the plane (÷ R), so that a point of the tangent plane stays on it:
        // x = v·(a² u − ab V + b n)/R², y = v·(a n − ab u + b² V)/R².
        let (sa, sb) = (slice.a, slice.b);
        let ir2 = slice.inv_r * slice.inv_r;
        let fx = (u * (sa * sa) - f.va * (sa * sb) + f.na * sb) * ir2;
        let fy = (f.na * sa - u * (sa * sb) + f.va * (sb * sb)) * ir2;
        // March in 48.16 fixed point: floor = arithmetic shift, no float → int per sample.
        let t1 = t0 + jitter * step;
        let (ox, oy) = f.o;
        grp.hz[l] = Horizon::new(slice, fx, fy);
        if f.arc.is_some() {
            let (phi, dphi) = (t1 / ppr, step / ppr);
            let ((s1, c1), (sd, cd)) = (phi.sin_cos(), dphi.sin_cos());
            grp.arc[l] = Arc {
                d: -f.va,
                u,
                cs: (c1, s1),
                rot: (cd, sd),
            };
        } else {
            grp.q[l] = (fixed(ox + dx * t1), fixed(oy + dy * t1));
            grp.step[l] = (fixed(dx * step), fixed(dy * step));
        }
        grp.count[l] = count;
    }

    /// The map index of the next sample of lane `l` (advancing it), `None` once the line has
    /// left the map (it leaves once: y is monotone, x wraps or is clipped).
    #[inline(always)]
    pub(super) fn next_index(&self, grp: &mut Group, l: usize) -> Option<usize> {
        if grp.arc_on {
            return self.next_index_arc(&mut grp.arc[l]);
        }
        let (qx, qy) = grp.q[l];
        let (mut ix, iy) = (qx >> 16, qy >> 16);
        grp.q[l] = (qx + grp.step[l].0, qy + grp.step[l].1);
        if iy as u64 >= self.h as u64 {
            return None;
        }
        if ix as u64 >= self.w as u64 {
            if !self.wrap {
                return None;
            }
            ix = ix.rem_euclid(self.w as i64);
        }
        let i = iy as usize * self.w as usize + ix as usize;
        (i < self.pts.len()).then_some(i)
    }

    /// [`Ctx::next_index`] on a spherical map: the pixel of the arc's next direction, `None`
    /// once it leaves the map (past the top or bottom row of a partial panorama).
    #[inline(always)]
    pub(super) fn next_index_arc(&self, a: &mut Arc) -> Option<usize> {
        let (c, s) = a.cs;
        let w = a.d * c + a.u * s;
        a.cs = (c * a.rot.0 - s * a.rot.1, s * a.rot.0 + c * a.rot.1);
        let pr = self.proj.project(glam::Vec3::from(w))?;
        let i = self.pixel_at(pr.x, pr.y)?;
        (i < self.pts.len()).then_some(i)
    }

    /// Marches the group's half-planes in lock step, one SIMD lane each: the sample tests run
    /// on all lanes at once and only a lane whose sample raises its horizon takes the scalar
    /// [`Horizon::raise`]. Every lane sees the same samples, in the same order, with the same
    /// arithmetic as [`Ctx::march_one`]. Returns whether any sample landed on a neighbouring
    /// valid pixel.
    pub(super) fn march_lanes(&self, grp: &mut Group, c: usize, pa: Vec3A, na: Vec3A) -> bool {
        let lanes = |f: &dyn Fn(&Horizon) -> f32| {
            Vec4::new(f(&grp.hz[0]), f(&grp.hz[1]), f(&grp.hz[2]), f(&grp.hz[3]))
        };
        let (fxx, fxy, fxz) = (lanes(&|h| h.fx.x), lanes(&|h| h.fx.y), lanes(&|h| h.fx.z));
        let (fyx, fyy, fyz) = (lanes(&|h| h.fy.x), lanes(&|h| h.fy.y), lanes(&|h| h.fy.z));
        let (pax, pay, paz) = (Vec4::splat(pa.x), Vec4::splat(pa.y), Vec4::splat(pa.z));
        let (nax, nay, naz) = (Vec4::splat(na.x), Vec4::splat(na.y), Vec4::splat(na.z));
        let tmax2 = Vec4::splat(self.tmax2);
        let plen = Vec4::splat(pa.length());
        let mut cos_h = [0.0f32; LANES];
        for (ch, h) in cos_h.iter_mut().zip(&grp.hz) {
            *ch = h.sc.1;
        }
        // The previous sample's in-plane coordinates (NaN before the first).
        let (mut prev_x, mut prev_y) = (Vec4::NAN, Vec4::NAN);
        // The previous sample's offset, and whether it was inside the t_max sphere.
        let (mut pvx, mut pvy, mut pvz) = (Vec4::ZERO, Vec4::ZERO, Vec4::ZERO);
        let mut prev_in = BVec4A::FALSE;
        let mut live = [false; LANES];
        for (l, lv) in live.iter_mut().enumerate().take(grp.n) {
            *lv = grp.count[l] > 0;
        }
        let steps = grp.count.iter().copied().max().unwrap_or(0);
        let mut any = false;
        // The samples of a block of steps are all loaded before any is tested, lanes apart
        // (x, y, z) so that a step's lanes load as three vectors. A lane with no sample has
        // x = NaN, which makes every test below fail whatever y and z hold.
        const BLOCK: u32 = 8;
        let mut k0 = 0;
        while k0 < steps {
            let kn = (steps - k0).min(BLOCK);
            let mut qx = [[f32::NAN; LANES]; BLOCK as usize];
            let mut qy = [[0.0f32; LANES]; BLOCK as usize];
            let mut qz = [[0.0f32; LANES]; BLOCK as usize];
            for l in 0..grp.n {
                if !live[l] {
                    continue;
                }
                // The lane's samples left in this block; it is done once they run out.
                let todo = grp.count[l].saturating_sub(k0).min(kn);
                live[l] = k0 + kn < grp.count[l];
                for k in 0..todo as usize {
                    let Some(i) = self.next_index(grp, l) else {
                        live[l] = false;
                        break;
                    };
                    let s = self.pts[i];
                    if i != c && !s.x.is_nan() {
                        any = true;
                        (qx[k][l], qy[k][l], qz[k][l]) = (s.x, s.y, s.z);
                    }
                }
            }
            for k in 0..kn as usize {
                let vx = Vec4::from_array(qx[k]) - pax;
                let vy = Vec4::from_array(qy[k]) - pay;
                let vz = Vec4::from_array(qz[k]) - paz;
                let l2 = (vx * vx + vy * vy) + vz * vz;
                // Lanes without a sample are NaN and fail every test.
                let inside = l2.cmplt(tmax2);
                let height = (nax * vx + nay * vy) + naz * vz;
                let height = Vec4::select((height * height).cmpgt(l2 * 1e-10), height, Vec4::ZERO);
                let x = (vx * fxx + vy * fxy) + vz * fxz;
                let y = (vx * fyx + vy * fyy) + vz * fyz;
                let raise = inside & height.cmpgt(Vec4::ZERO) & x.cmpgt(Vec4::ZERO);
                let mut bits = raise.bitmask();
                if bits != 0 {
                    let ch = Vec4::from_array(cos_h);
                    bits &= above_horizon_lanes(x, y, ch).bitmask();
                    if grp.arc_on && bits != 0 {
                        let (sx, sy, sz) = (vx + pax, vy + pay, vz + paz);
                        let dq = (pax * sx + pay * sy) + paz * sz;
                        let len = sqrt4((sx * sx + sy * sy) + sz * sz);
                        let joins = (dq + ch * (len * plen)).cmpge(Vec4::ZERO);
                        bits &= joins.bitmask();
                    }
                    let (xs, ys) = (x.to_array(), y.to_array());
                    let (pxs, pys) = (prev_x.to_array(), prev_y.to_array());
                    while bits != 0 {
                        let l = bits.trailing_zeros() as usize;
                        bits &= bits - 1;
                        grp.hz[l].raise(xs[l], ys[l], pxs[l], pys[l], &self.rho);
                        cos_h[l] = grp.hz[l].sc.1;
                    }
                }
                prev_x = Vec4::select(inside, x, prev_x);
                prev_y = Vec4::select(inside, y, prev_y);
                if self.clip {
                    let valid = !l2.is_nan_mask();
                    let mut exits = (valid & !inside & prev_in).bitmask();
                    if exits != 0 {
                        let (xs, ys, zs) = (vx.to_array(), vy.to_array(), vz.to_array());
                        let (px, py, pz) = (pvx.to_array(), pvy.to_array(), pvz.to_array());
                        let (mut pxs, mut pys) = (prev_x.to_array(), prev_y.to_array());
                        while exits != 0 {
                            let l = exits.trailing_zeros() as usize;
                            exits &= exits - 1;
                            let v = Vec3A::new(xs[l], ys[l], zs[l]);
                            let pv = Vec3A::new(px[l], py[l], pz[l]);
                            let hz = &mut grp.hz[l];
                            let prev = (pxs[l], pys[l]);
                            if let Some(xy) =
                                self.offer_exit(hz, (pa, na), (pv, v), prev, grp.arc_on)
                            {
                                (pxs[l], pys[l]) = xy;
                                cos_h[l] = hz.sc.1;
                            }
                        }
                        (prev_x, prev_y) = (Vec4::from_array(pxs), Vec4::from_array(pys));
                    }
                    prev_in = (valid & inside) | (!valid & prev_in);
                    (pvx, pvy, pvz) = (
                        Vec4::select(valid, vx, pvx),
                        Vec4::select(valid, vy, pvy),
                        Vec4::select(valid, vz, pvz),
                    );
                }
            }
            k0 += kn;
        }
        any
    }
}

/// [`above_horizon`] on four lanes, with the same arithmetic.
#[inline]
pub(super) fn above_horizon_lanes(x: Vec4, y: Vec4, cos_h: Vec4) -> BVec4A {
    let (y2, k) = (y * y, cos_h * cos_h * (x * x + y * y));
    let facing = y.cmpgt(Vec4::ZERO) & y2.cmpgt(k);
    let beyond = y.cmpge(Vec4::ZERO) | y2.cmplt(k);
    let up = cos_h.cmpge(Vec4::ZERO);
    (up & facing) | (!up & beyond)
}

/// `f32::min` on four lanes: the non-NaN operand when one is NaN.
#[inline(always)]
pub(super) fn min_lanes(a: Vec4, b: Vec4) -> Vec4 {
    // minps returns its second operand when either is NaN.
    Vec4::select(b.is_nan_mask(), a, a.min(b))
}

/// [`exit`] on four lanes of `inv`.
#[inline(always)]
pub(super) fn exit_lanes(o: f32, inv: Vec4, size: f32) -> Vec4 {
    let pos = (Vec4::splat(size) - Vec4::splat(o)) * inv;
    let neg = Vec4::splat(-o) * inv;
    Vec4::select(
        inv.cmpgt(Vec4::ZERO),
        pos,
        Vec4::select(inv.cmplt(Vec4::ZERO), neg, Vec4::INFINITY),
    )
}

/// `x` in 48.16 fixed point (saturating).
#[inline]
pub(super) fn fixed(x: f32) -> i64 {
    (x * 65536.0) as i64
}
