//! The AVX2 traversal kernels over the 8-wide BVH of `wide8.rs`: closest
//! hit, with children visited nearest first and skipped once a closer hit is
//! known, and occlusion, which stops at the first hit in range.
//!
//! Every floating-point operation is the one `traverse.rs` does, in the same
//! order, eight lanes instead of four: no fused multiply-add, which would
//! round the slab and triangle tests differently from the 4-wide kernel, so
//! that both kernels accept exactly the same boxes and triangles and a
//! scene renders alike on CPUs with and without AVX2.

use std::arch::x86_64::*;

use glam::Vec3;

use super::collapse::leaf_packs;
use super::traverse::{better, visits, Count, NoCount, SlotHit, Stack, FAR_SCALE};
use super::wide8::{Node8, Pack8, Wide8, LEAF_BIT, STACK};
use super::{lane_vec, Hit, OCCLUDED_TMAX};

/// Takes the hits of leaf pack `p` that [`better`] prefers into `best`
/// and `t_best`: the lanes set in `mask`, at distances `t` with
/// barycentric weights `u` and `v` (as [`Prepared::triangles`] gives them).
#[inline]
#[target_feature(enable = "avx2")]
fn take_hits(
    mask: u32,
    (t, u, v): (__m256, __m256, __m256),
    p: usize,
    ids: &[u32],
    t_best: &mut f32,
    best: &mut Option<SlotHit>,
) {
    if mask == 0 {
        return;
    }
    let (mut ta, mut ua, mut va) = ([0f32; 8], [0f32; 8], [0f32; 8]);
    // SAFETY: eight writable f32s each; no alignment needed
    unsafe {
        _mm256_storeu_ps(ta.as_mut_ptr(), t);
        _mm256_storeu_ps(ua.as_mut_ptr(), u);
        _mm256_storeu_ps(va.as_mut_ptr(), v);
    }
    let mut bits = mask;
    while bits != 0 {
        let i = bits.trailing_zeros() as usize;
        bits &= bits - 1;
        if better(ta[i], 8 * p + i, *t_best, best, ids) {
            *t_best = ta[i];
            *best = Some(SlotHit {
                t: ta[i],
                slot: 8 * p + i,
                b1: ua[i],
                b2: va[i],
            });
        }
    }
}

/// A ray prepared for the kernels (and for the packets of `packet8.rs`,
/// where few of their rays take part in a node).
pub(super) struct Prepared {
    o: [__m256; 3],
    d: [__m256; 3],
    inv: [__m256; 3],
    /// Row of `Node8::b` holding the near plane along each axis (min for a
    /// direction component with its sign bit clear, else max), and the far.
    near: [usize; 3],
    far: [usize; 3],
}

impl Prepared {
    #[inline]
    #[target_feature(enable = "avx2")]
    fn new(o: Vec3, d: Vec3) -> Prepared {
        // 1/±0 is ±∞, whose sign agrees with the choice of planes below; the
        // NaN from 0·∞ (a ray in a slab's plane) is ignored by the box test.
        let inv = d.recip();
        let neg = |x: f32| usize::from(x.is_sign_negative());
        let near = [neg(d.x), 2 + neg(d.y), 4 + neg(d.z)];
        Prepared {
            o: [
                _mm256_set1_ps(o.x),
                _mm256_set1_ps(o.y),
                _mm256_set1_ps(o.z),
            ],
            d: [
                _mm256_set1_ps(d.x),
                _mm256_set1_ps(d.y),
                _mm256_set1_ps(d.z),
            ],
            inv: [
                _mm256_set1_ps(inv.x),
                _mm256_set1_ps(inv.y),
                _mm256_set1_ps(inv.z),
            ],
            near,
            far: near.map(|r| r ^ 1),
        }
    }

    /// Lane `k`'s ray of a packet whose origins, directions and their
    /// reciprocals are `o`, `d` and `inv`, one ray a lane (`inv` computed
    /// as [`Prepared::new`] does: a correctly rounded division either way).
    #[inline]
    #[target_feature(enable = "avx2")]
    pub(super) fn lane(o: &[__m256; 3], d: &[__m256; 3], inv: &[__m256; 3], k: usize) -> Prepared {
        let idx = _mm256_set1_epi32(k as i32);
        let pick = |v: &[__m256; 3]| v.map(|v| _mm256_permutevar8x32_ps(v, idx));
        let signs = d.map(|d| (_mm256_movemask_ps(d) as usize >> k) & 1);
        let near = [signs[0], 2 + signs[1], 4 + signs[2]];
        Prepared {
            o: pick(o),
            d: pick(d),
            inv: pick(inv),
            near,
            far: near.map(|r| r ^ 1),
        }
    }

    /// The lanes of `node` whose box the ray enters within `[tmin, tmax]`,
    /// and the distance at which it enters each.
    #[inline]
    #[target_feature(enable = "avx2")]
    fn boxes(&self, node: &Node8, tmin: __m256, tmax: __m256) -> (u32, __m256) {
        let (hit, t0) = self.boxes_v(node, tmin, tmax);
        (_mm256_movemask_ps(hit) as u32, t0)
    }

    /// [`Prepared::boxes`] with the lanes as a vector mask (all ones where
    /// the ray enters the box).
    #[inline]
    #[target_feature(enable = "avx2")]
    pub(super) fn boxes_v(&self, node: &Node8, tmin: __m256, tmax: __m256) -> (__m256, __m256) {
        // maxps/minps return their second operand when either is NaN: the
        // running bound goes second so that NaN lanes leave it unchanged
        let mut t0 = tmin;
        let mut t1 = tmax;
        for axis in 0..3 {
            // SAFETY: each row is eight f32s, 32-byte aligned (Node8's repr)
            let (n, f) = unsafe {
                (
                    _mm256_load_ps(node.b[self.near[axis]].as_ptr()),
                    _mm256_load_ps(node.b[self.far[axis]].as_ptr()),
                )
            };
            t0 = _mm256_max_ps(
                _mm256_mul_ps(_mm256_sub_ps(n, self.o[axis]), self.inv[axis]),
                t0,
            );
            t1 = _mm256_min_ps(
                _mm256_mul_ps(_mm256_sub_ps(f, self.o[axis]), self.inv[axis]),
                t1,
            );
        }
        let far = _mm256_mul_ps(t1, _mm256_set1_ps(FAR_SCALE));
        (_mm256_cmp_ps::<_CMP_LE_OQ>(t0, far), t0)
    }

    /// `traverse.rs`'s Möller–Trumbore on the eight triangles of `pack`,
    /// the same operations in the same order: the lanes hit within
    /// `[tmin, tmax)`, or `[tmin, tmax]` when `UPTO`, with their distances
    /// and barycentric weights of the second and third vertex. The closest
    /// hit asks for `[tmin, t_best]`, so that a triangle at the same
    /// distance as the best so far can win the tie ([`better`]).
    #[inline]
    #[target_feature(enable = "avx2")]
    pub(super) fn triangles<const UPTO: bool>(
        &self,
        pack: &Pack8,
        tmin: __m256,
        tmax: __m256,
    ) -> (u32, __m256, __m256, __m256) {
        // SAFETY: each row is eight f32s, 32-byte aligned (Pack8's repr)
        let ld = |rows: &[[f32; 8]; 3]| unsafe {
            [
                _mm256_load_ps(rows[0].as_ptr()),
                _mm256_load_ps(rows[1].as_ptr()),
                _mm256_load_ps(rows[2].as_ptr()),
            ]
        };
        let (v0, e1, e2, ng) = (ld(&pack.v0), ld(&pack.e1), ld(&pack.e2), ld(&pack.ng));
        let (hit, t, u, v) =
            moller_trumbore::<UPTO>(&self.o, &self.d, [v0, e1, e2, ng], tmin, tmax);
        (_mm256_movemask_ps(hit) as u32, t, u, v)
    }
}

/// Möller–Trumbore in eight lanes: the rays `o + t d` against the
/// triangles of corner `v0`, edges `e1`, `e2` and normal `ng = e1 × e2`,
/// lane by lane; either may be the same in every lane (one ray against a
/// pack's eight triangles here, one triangle against a packet's eight rays
/// in `packet8.rs`), so that both kernels do the same operations in the
/// same order. The lanes that hit within `[tmin, tmax)`, or `[tmin, tmax]`
/// when `UPTO`, as a vector mask, with the distances and the barycentric
/// weights of the second and third vertex.
#[inline(always)]
pub(super) fn moller_trumbore<const UPTO: bool>(
    o: &[__m256; 3],
    d: &[__m256; 3],
    [v0, e1, e2, ng]: [[__m256; 3]; 4],
    tmin: __m256,
    tmax: __m256,
) -> (__m256, __m256, __m256, __m256) {
    // SAFETY: register operations only; inlined into the AVX2 kernels
    unsafe {
        let (add, sub, mul) = (
            |a, b| _mm256_add_ps(a, b),
            |a, b| _mm256_sub_ps(a, b),
            |a, b| _mm256_mul_ps(a, b),
        );
        let dot = |a: &[__m256; 3], b: &[__m256; 3]| {
            add(add(mul(a[0], b[0]), mul(a[1], b[1])), mul(a[2], b[2]))
        };
        let c = [sub(v0[0], o[0]), sub(v0[1], o[1]), sub(v0[2], o[2])];
        let r = [
            sub(mul(d[1], c[2]), mul(d[2], c[1])),
            sub(mul(d[2], c[0]), mul(d[0], c[2])),
            sub(mul(d[0], c[1]), mul(d[1], c[0])),
        ];
        let det = dot(&ng, d);
        let one = _mm256_set1_ps(1.0);
        let inv_det = _mm256_div_ps(one, det);
        let u = mul(dot(&r, &e2), inv_det);
        let v = mul(dot(&r, &e1), inv_det);
        let w = sub(sub(one, u), v);
        let t = mul(dot(&ng, &c), inv_det);
        let zero = _mm256_setzero_ps();
        // The comparisons of SSE's cmpneqps, cmpgeps and cmpltps
        let and = |a, b| _mm256_and_ps(a, b);
        let hit = and(
            and(
                and(
                    _mm256_cmp_ps::<_CMP_NEQ_UQ>(det, zero),
                    _mm256_cmp_ps::<_CMP_GE_OS>(u, zero),
                ),
                and(
                    _mm256_cmp_ps::<_CMP_GE_OS>(v, zero),
                    _mm256_cmp_ps::<_CMP_GE_OS>(w, zero),
                ),
            ),
            and(
                _mm256_cmp_ps::<_CMP_GE_OS>(t, tmin),
                if UPTO {
                    _mm256_cmp_ps::<_CMP_LE_OS>(t, tmax)
                } else {
                    _mm256_cmp_ps::<_CMP_LT_OS>(t, tmax)
                },
            ),
        );
        (hit, t, u, v)
    }
}

/// The closest hit along `o + t d` in `[tmin, tmax)`.
#[inline]
pub(super) fn closest(
    w: &Wide8,
    o: Vec3,
    d: Vec3,
    tmin: f32,
    tmax: f32,
    count: &mut impl Count,
) -> Option<SlotHit> {
    let _ = w.avx2;
    // SAFETY: a Wide8 holds an Avx2 token, made only where AVX2 was detected
    unsafe { closest_avx2(w, o, d, tmin, tmax, count) }
}

/// True when anything meets `o + t d` within `[tmin, tmax)`.
#[inline]
pub(super) fn any(
    w: &Wide8,
    o: Vec3,
    d: Vec3,
    tmin: f32,
    tmax: f32,
    count: &mut impl Count,
) -> bool {
    let _ = w.avx2;
    // SAFETY: as in `closest`
    unsafe { any_avx2(w, o, d, tmin, tmax, count) }
}

/// [`closest`] of the rays of the lanes of `mask` (bit i for lane i),
/// one after another, lane i's ray starting at `o[·][i]` with direction
/// `d[·][i]` over `[0, ∞)`; each answer goes to `out[i]` as a [`Hit`]
/// (lanes outside `mask` are left as they were). One call for up to eight
/// rays, whose origins and directions are read from the lanes' arrays
/// component by component: called ray by ray through
/// [`crate::accel::Accel::intersect`], each ray's fields were stored one
/// by one and read back two at a time, and its answer likewise, which the
/// CPU cannot forward from store to load.
#[target_feature(enable = "avx2")]
pub(super) fn closest_lanes(
    w: &Wide8,
    o: &[[f32; 8]; 3],
    d: &[[f32; 8]; 3],
    mask: u32,
    out: &mut [Option<Hit>; 8],
) {
    let mut bits = mask & 0xff;
    while bits != 0 {
        let i = bits.trailing_zeros() as usize;
        bits &= bits - 1;
        let (oi, di) = (lane_vec(o, i), lane_vec(d, i));
        // SAFETY: this function is compiled for AVX2
        let h = unsafe { closest_in(w, oi, di, 0.0, f32::INFINITY, &mut NoCount) };
        out[i] = h.map(|h| h.hit(&w.ids));
    }
}

/// [`any`] of the segments of the lanes of `mask`, from `a[·][i]` to
/// `b[·][i]` as [`crate::accel::Accel::occluded`] tests them; returns the
/// lanes whose segment is blocked. One call for up to eight shadow rays,
/// as [`closest_lanes`] is for closest hits.
#[target_feature(enable = "avx2")]
pub(super) fn occluded_lanes(w: &Wide8, a: &[[f32; 8]; 3], b: &[[f32; 8]; 3], mask: u32) -> u32 {
    let mut blocked = 0;
    let mut bits = mask & 0xff;
    while bits != 0 {
        let i = bits.trailing_zeros() as usize;
        bits &= bits - 1;
        let (ai, bi) = (lane_vec(a, i), lane_vec(b, i));
        blocked |= u32::from(any_avx2(w, ai, bi - ai, 0.0, OCCLUDED_TMAX, &mut NoCount)) << i;
    }
    blocked
}

#[target_feature(enable = "avx2")]
fn closest_avx2<C: Count>(
    w: &Wide8,
    o: Vec3,
    d: Vec3,
    tmin: f32,
    tmax: f32,
    count: &mut C,
) -> Option<SlotHit> {
    // SAFETY: this function is compiled for AVX2
    unsafe { closest_in(w, o, d, tmin, tmax, count) }
}

/// The body of [`closest_avx2`], inlined into it and into
/// [`closest_lanes`], whose loop then keeps each answer in registers
/// (a call returns it through memory, written field by field and read
/// back two fields at a time, which the CPU cannot forward from store to
/// load).
///
/// # Safety
/// Only to be inlined into a function compiled for AVX2.
#[inline(always)]
unsafe fn closest_in<C: Count>(
    w: &Wide8,
    o: Vec3,
    d: Vec3,
    tmin: f32,
    tmax: f32,
    count: &mut C,
) -> Option<SlotHit> {
    // SAFETY: AVX2 intrinsics and AVX2 functions, in a caller compiled for
    // AVX2 (this function's contract), and one unaligned store of eight
    // f32 into `t0a`, which holds eight
    unsafe {
        let ray = Prepared::new(o, d);
        let vmin = _mm256_set1_ps(tmin);
        let mut best: Option<SlotHit> = None;
        let mut t_best = tmax;
        let mut stack = Stack::<STACK>::new();
        let mut r = w.root;
        loop {
            if r & LEAF_BIT == 0 {
                // Test the eight children; descend into the nearest, push the others
                let node = &w.nodes[r as usize];
                count.node();
                let (mask, t0) = ray.boxes(node, vmin, _mm256_set1_ps(t_best));
                if mask != 0 {
                    if mask & (mask - 1) == 0 {
                        r = node.child[mask.trailing_zeros() as usize];
                        continue;
                    }
                    let mut t0a = [0f32; 8];
                    // `t0a` is eight writable f32s; no alignment needed
                    _mm256_storeu_ps(t0a.as_mut_ptr(), t0);
                    let rest = mask & (mask - 1);
                    if rest & (rest - 1) == 0 {
                        // Two children need no sort: descend into the nearer
                        // (the second on a tie, as the insertion below would)
                        let (a, b) = (
                            mask.trailing_zeros() as usize,
                            rest.trailing_zeros() as usize,
                        );
                        let (near, far) = if t0a[b] <= t0a[a] { (b, a) } else { (a, b) };
                        stack.set(stack.len, node.child[far], t0a[far]);
                        stack.len += 1;
                        r = node.child[near];
                        continue;
                    }
                    if rest.count_ones() <= 3 {
                        // Three or four children: a sorting network, whose
                        // compare-exchanges need no branches (the insertion
                        // below branches on each comparison, on distances the
                        // predictor cannot guess). A key is the
                        // entry distance's bits, which order as the distances
                        // do when these are not negative (they are at least
                        // `tmin`; a negative `tmin` could change the order of
                        // visits, not the closest distance), above 7 − lane,
                        // so that equal distances are popped last lane first,
                        // as the insertion would; a missing fourth is u64::MAX
                        // and sorts last.
                        let key = |m: u32| {
                            let i = m.trailing_zeros() as usize;
                            (u64::from(t0a[i].to_bits()) << 32) | (7 - i) as u64
                        };
                        let (m1, m2) = (rest, rest & (rest - 1));
                        let m3 = m2 & (m2 - 1);
                        // (lane 7 stands in for a missing fourth, to read in bounds)
                        let k3 = key(m3 | 0x80);
                        let mut k = [
                            key(mask),
                            key(m1),
                            key(m2),
                            if m3 != 0 { k3 } else { u64::MAX },
                        ];
                        for (a, b) in [(0, 1), (2, 3), (0, 2), (1, 3), (1, 2)] {
                            let (lo, hi) = (k[a].min(k[b]), k[a].max(k[b]));
                            (k[a], k[b]) = (lo, hi);
                        }
                        // Push the farthest first, as stack entries (the key's
                        // distance above the child); without a fourth, the
                        // third slot written is past the new top, unused
                        let child = |k: u64| node.child[(k & 7) as usize ^ 7];
                        let entry = |k: u64| (k & !0xffff_ffff) | u64::from(child(k));
                        let (e1, e2, e3) = (entry(k[1]), entry(k[2]), entry(k[3]));
                        let four = m3 != 0;
                        stack.set3(
                            stack.len,
                            [if four { e3 } else { e2 }, if four { e2 } else { e1 }, e1],
                        );
                        stack.len += 2 + usize::from(four);
                        r = child(k[0]);
                        continue;
                    }
                    let base = stack.len;
                    let mut bits = mask;
                    while bits != 0 {
                        let i = bits.trailing_zeros() as usize;
                        bits &= bits - 1;
                        // Insertion keeps stack[base..] sorted farthest first
                        let mut j = stack.len;
                        while j > base {
                            let (rj, dj) = stack.get(j - 1);
                            if dj >= t0a[i] {
                                break;
                            }
                            stack.set(j, rj, dj);
                            j -= 1;
                        }
                        stack.set(j, node.child[i], t0a[i]);
                        stack.len += 1;
                    }
                    // The nearest was pushed last: pop it and descend
                    r = stack.get(stack.len - 1).0;
                    stack.len -= 1;
                    continue;
                }
            } else {
                // Test the leaf's triangles, eight at a time
                for p in leaf_packs(r) {
                    count.pack();
                    let (mask, t, u, v) =
                        ray.triangles::<true>(&w.packs[p], vmin, _mm256_set1_ps(t_best));
                    take_hits(mask, (t, u, v), p, &w.ids, &mut t_best, &mut best);
                }
            }
            // Pop the nearest entry that may still hold a closer hit
            loop {
                if stack.len == 0 {
                    return best;
                }
                let (cr, cd) = stack.get(stack.len - 1);
                stack.len -= 1;
                if visits(cd, t_best) {
                    r = cr;
                    break;
                }
            }
        }
    }
}

#[inline]
#[target_feature(enable = "avx2")]
fn any_avx2<C: Count>(w: &Wide8, o: Vec3, d: Vec3, tmin: f32, tmax: f32, count: &mut C) -> bool {
    let ray = Prepared::new(o, d);
    let (vmin, vmax) = (_mm256_set1_ps(tmin), _mm256_set1_ps(tmax));
    let mut stack = Stack::<STACK>::new();
    let mut r = w.root;
    loop {
        if r & LEAF_BIT == 0 {
            // Any order will do: descend into the first child hit, push the rest
            let node = &w.nodes[r as usize];
            count.node();
            let (mut mask, _) = ray.boxes(node, vmin, vmax);
            if mask != 0 {
                r = node.child[mask.trailing_zeros() as usize];
                mask &= mask - 1;
                while mask != 0 {
                    stack.set(stack.len, node.child[mask.trailing_zeros() as usize], 0.0);
                    stack.len += 1;
                    mask &= mask - 1;
                }
                continue;
            }
        } else {
            for p in leaf_packs(r) {
                count.pack();
                if ray.triangles::<false>(&w.packs[p], vmin, vmax).0 != 0 {
                    return true;
                }
            }
        }
        if stack.len == 0 {
            return false;
        }
        r = stack.get(stack.len - 1).0;
        stack.len -= 1;
    }
}
