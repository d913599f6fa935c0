//! The traversal kernels over the wide BVH of `wide.rs`: closest hit, with
//! children visited nearest first and skipped once a closer hit is known, and
//! occlusion, which stops at the first hit in range.

use std::mem::MaybeUninit;

use glam::Vec3;

use super::collapse::leaf_packs;
use super::wide::{Node, Pack, Wide, LEAF_BIT, STACK};
use crate::simd::F4;

/// Rounding in the slab test can put an exact box's far distance just
/// before a triangle on its face; the far distance is widened by 1 + 2γ₃
/// (pbrt-v4, §6.8.2) so that the box test never rejects a hit the triangle
/// test would accept.
pub(super) const FAR_SCALE: f32 =
    1.0 + 2.0 * (3.0 * f32::EPSILON * 0.5) / (1.0 - 3.0 * f32::EPSILON * 0.5);

/// True when a hit at `t` on pack slot `slot` replaces `best`, the closest
/// so far (at `t_best`, the range's end while there is none): when it is
/// nearer, or as near and on a triangle of lower scene index. The closest
/// hit is then the least (distance, triangle) over every triangle the ray
/// meets, whatever the order in which the nodes are visited, so that the
/// 4-wide and 8-wide kernels and the packets of `packet8.rs` (which all
/// visit in different orders) answer alike on a shared edge or coincident
/// triangles.
#[inline(always)]
pub(super) fn better(
    t: f32,
    slot: usize,
    t_best: f32,
    best: &Option<SlotHit>,
    ids: &[u32],
) -> bool {
    t < t_best
        || best
            .as_ref()
            .is_some_and(|b| t == t_best && ids[slot] < ids[b.slot])
}

/// True when a node the ray enters at `entry` may still hold a hit that
/// [`better`] takes over one at `t_best`: the box test's own bound,
/// `entry ≤ t_best · FAR_SCALE` (a triangle at `t_best` on the near face
/// of a box must still be visited, for the tie rule).
#[inline(always)]
pub(super) fn visits(entry: f32, t_best: f32) -> bool {
    entry <= t_best * FAR_SCALE
}

/// A ray prepared for the kernels.
struct Prepared {
    o: [F4; 3],
    d: [F4; 3],
    inv: [F4; 3],
    /// Row of `Node::b` holding the near plane along each axis (min for a
    /// direction component with its sign bit clear, else max), and the far.
    near: [usize; 3],
    far: [usize; 3],
}

impl Prepared {
    #[inline(always)]
    fn new(o: Vec3, d: Vec3) -> Prepared {
        // 1/±0 is ±∞, whose sign agrees with the choice of planes below; the
        // NaN from 0·∞ (a ray in a slab's plane) is ignored by the box test.
        let inv = d.recip();
        let neg = |x: f32| usize::from(x.is_sign_negative());
        let near = [neg(d.x), 2 + neg(d.y), 4 + neg(d.z)];
        Prepared {
            o: [F4::splat(o.x), F4::splat(o.y), F4::splat(o.z)],
            d: [F4::splat(d.x), F4::splat(d.y), F4::splat(d.z)],
            inv: [F4::splat(inv.x), F4::splat(inv.y), F4::splat(inv.z)],
            near,
            far: near.map(|r| r ^ 1),
        }
    }

    /// The lanes of `node` whose box the ray enters within `[tmin, tmax]`,
    /// and the distance at which it enters each.
    #[inline(always)]
    fn boxes(&self, node: &Node, tmin: F4, tmax: F4) -> (u32, F4) {
        // maxps/minps return their second operand when either is NaN: the
        // running bound goes second so that NaN lanes leave it unchanged
        let mut t0 = tmin;
        let mut t1 = tmax;
        for axis in 0..3 {
            let n = F4::load(&node.b[self.near[axis]]);
            let f = F4::load(&node.b[self.far[axis]]);
            t0 = n.sub(self.o[axis]).mul(self.inv[axis]).max(t0);
            t1 = f.sub(self.o[axis]).mul(self.inv[axis]).min(t1);
        }
        let hit = t0.le(t1.mul(F4::splat(FAR_SCALE)));
        (hit.bits(), t0)
    }

    /// Möller–Trumbore on the four triangles of `pack` in the form of
    /// madmann91's `bvh`: the lanes hit within `[tmin, tmax)`, or
    /// `[tmin, tmax]` when `UPTO`, with their distances and barycentric
    /// weights of the second and third vertex. The closest hit asks for
    /// `[tmin, t_best]`, so that a triangle at the same distance as the best
    /// so far can win the tie ([`better`]).
    #[inline(always)]
    fn triangles<const UPTO: bool>(&self, pack: &Pack, tmin: F4, tmax: F4) -> (u32, F4, F4, F4) {
        let ld =
            |rows: &[[f32; 4]; 3]| [F4::load(&rows[0]), F4::load(&rows[1]), F4::load(&rows[2])];
        let (v0, e1, e2, ng) = (ld(&pack.v0), ld(&pack.e1), ld(&pack.e2), ld(&pack.ng));
        let dot = |a: &[F4; 3], b: &[F4; 3]| a[0].mul(b[0]).add(a[1].mul(b[1])).add(a[2].mul(b[2]));
        let c = [
            v0[0].sub(self.o[0]),
            v0[1].sub(self.o[1]),
            v0[2].sub(self.o[2]),
        ];
        let d = &self.d;
        let r = [
            d[1].mul(c[2]).sub(d[2].mul(c[1])),
            d[2].mul(c[0]).sub(d[0].mul(c[2])),
            d[0].mul(c[1]).sub(d[1].mul(c[0])),
        ];
        let det = dot(&ng, d);
        let inv_det = F4::splat(1.0).div(det);
        let u = dot(&r, &e2).mul(inv_det);
        let v = dot(&r, &e1).mul(inv_det);
        let w = F4::splat(1.0).sub(u).sub(v);
        let t = dot(&ng, &c).mul(inv_det);
        let zero = F4::splat(0.0);
        // A degenerate triangle (or an unused slot) has ng = 0, so det = 0
        let hit = det
            .ne(zero)
            .and(u.ge(zero))
            .and(v.ge(zero))
            .and(w.ge(zero))
            .and(t.ge(tmin))
            .and(if UPTO { t.le(tmax) } else { t.lt(tmax) });
        (hit.bits(), t, u, v)
    }
}

/// A closest hit: distance, pack slot (`4 · pack + lane`), barycentric
/// weights of the second and third vertex.
pub(super) struct SlotHit {
    pub t: f32,
    pub slot: usize,
    pub b1: f32,
    pub b2: f32,
}

impl SlotHit {
    /// The hit, its slot mapped to its triangle by the tree's `ids`.
    #[inline(always)]
    pub fn hit(self, ids: &[u32]) -> super::Hit {
        super::Hit {
            t: self.t,
            tri: ids[self.slot],
            b1: self.b1,
            b2: self.b2,
        }
    }
}

/// A fixed stack of child references, each with the distance at which the
/// ray enters it (in the high half, as f32 bits), and its length. Left
/// uninitialised, and built in place: a struct literal with the array
/// uninitialised next to an initialised field was cleared whole by a
/// memset on every query. `N` is the width's [`STACK`] (`wide8.rs` has its
/// own).
pub(super) struct Stack<const N: usize> {
    entries: MaybeUninit<[u64; N]>,
    pub len: usize,
}

impl<const N: usize> Stack<N> {
    #[inline(always)]
    pub fn new() -> Stack<N> {
        let mut s = MaybeUninit::<Stack<N>>::uninit();
        // SAFETY: `len` is written through a raw pointer before the value
        // is read, and `entries` may stay uninitialised
        unsafe {
            (&raw mut (*s.as_mut_ptr()).len).write(0);
            s.assume_init()
        }
    }

    #[inline(always)]
    fn ptr(&mut self) -> *mut u64 {
        self.entries.as_mut_ptr().cast()
    }

    /// Entry `i`, which must be below `len`.
    #[inline(always)]
    pub fn get(&mut self, i: usize) -> (u32, f32) {
        debug_assert!(i < self.len);
        // SAFETY: entries below `len` were written, and len <= N
        let e = unsafe { self.ptr().add(i).read() };
        (e as u32, f32::from_bits((e >> 32) as u32))
    }

    /// Writes entry `i`, which must be at most `len`.
    #[inline(always)]
    pub fn set(&mut self, i: usize, r: u32, dist: f32) {
        // The tree's depth was checked against the stack when it was built
        assert!(i < N);
        // SAFETY: i < N
        unsafe {
            self.ptr()
                .add(i)
                .write(u64::from(r) | (u64::from(dist.to_bits()) << 32))
        };
    }

    /// Writes three entries, packed as [`Stack::set`] packs them, from
    /// entry `i` up (`i` at most `len`), with one bounds check.
    #[inline(always)]
    pub fn set3(&mut self, i: usize, e: [u64; 3]) {
        // The tree's depth was checked against the stack when it was built
        assert!(i + 3 <= N);
        // SAFETY: i + 3 <= N
        unsafe { self.ptr().add(i).cast::<[u64; 3]>().write_unaligned(e) };
    }
}

/// What a kernel tells as it walks: the wide nodes and triangle packs it
/// tests. The queries pass [`NoCount`], whose empty methods vanish when the
/// kernel is inlined; `kalos bench` passes [`super::Visits`].
pub(super) trait Count {
    /// One wide node's boxes were tested (all at once).
    fn node(&mut self);
    /// One pack of triangles was tested (all at once).
    fn pack(&mut self);
}

/// Counts nothing.
pub(super) struct NoCount;

impl Count for NoCount {
    #[inline(always)]
    fn node(&mut self) {}
    #[inline(always)]
    fn pack(&mut self) {}
}

impl Count for super::Visits {
    #[inline(always)]
    fn node(&mut self) {
        self.nodes += 1;
    }
    #[inline(always)]
    fn pack(&mut self) {
        self.packs += 1;
    }
}

/// The closest hit along `o + t d` in `[tmin, tmax)`.
#[inline(always)]
pub(super) fn closest(
    w: &Wide,
    o: Vec3,
    d: Vec3,
    tmin: f32,
    tmax: f32,
    count: &mut impl Count,
) -> Option<SlotHit> {
    let ray = Prepared::new(o, d);
    let vmin = F4::splat(tmin);
    let mut best: Option<SlotHit> = None;
    let mut t_best = tmax;
    let mut stack = Stack::<STACK>::new();
    let mut r = w.root;
    loop {
        if r & LEAF_BIT == 0 {
            // Test the four children; descend into the nearest, push the others
            let node = &w.nodes[r as usize];
            count.node();
            let (mask, t0) = ray.boxes(node, vmin, F4::splat(t_best));
            if mask != 0 {
                if mask & (mask - 1) == 0 {
                    r = node.child[mask.trailing_zeros() as usize];
                    continue;
                }
                let t0 = t0.to_array();
                let base = stack.len;
                let mut bits = mask;
                while bits != 0 {
                    let i = bits.trailing_zeros() as usize;
                    bits &= bits - 1;
                    // Insertion keeps stack[base..] sorted farthest first
                    let mut j = stack.len;
                    while j > base {
                        let (rj, dj) = stack.get(j - 1);
                        if dj >= t0[i] {
                            break;
                        }
                        stack.set(j, rj, dj);
                        j -= 1;
                    }
                    stack.set(j, node.child[i], t0[i]);
                    stack.len += 1;
                }
                // The nearest was pushed last: pop it and descend
                r = stack.get(stack.len - 1).0;
                stack.len -= 1;
                continue;
            }
        } else {
            // Test the leaf's triangles, four at a time
            for p in leaf_packs(r) {
                count.pack();
                let (mask, t, u, v) = ray.triangles::<true>(&w.packs[p], vmin, F4::splat(t_best));
                if mask != 0 {
                    let (t, u, v) = (t.to_array(), u.to_array(), v.to_array());
                    let mut bits = mask;
                    while bits != 0 {
                        let i = bits.trailing_zeros() as usize;
                        bits &= bits - 1;
                        if better(t[i], 4 * p + i, t_best, &best, &w.ids) {
                            t_best = t[i];
                            best = Some(SlotHit {
                                t: t[i],
                                slot: 4 * p + i,
                                b1: u[i],
                                b2: v[i],
                            });
                        }
                    }
                }
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

/// True when anything meets `o + t d` within `[tmin, tmax)`.
#[inline(always)]
pub(super) fn any(
    w: &Wide,
    o: Vec3,
    d: Vec3,
    tmin: f32,
    tmax: f32,
    count: &mut impl Count,
) -> bool {
    let ray = Prepared::new(o, d);
    let (vmin, vmax) = (F4::splat(tmin), F4::splat(tmax));
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
