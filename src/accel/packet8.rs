//! Packets of up to eight rays walked together through the 8-wide BVH of
//! `wide8.rs` (the AVX2 kernels of `traverse8.rs`, for rays that start
//! close together and point alike, such as the camera rays of neighbouring
//! pixels).
//!
//! The packet shares one walk: one stack, one order of visits, one fetch of
//! each node, and the sorting of a node's children once for all its rays.
//! Each ray still tests each node it takes part in with the single-ray box
//! test (`Prepared::boxes_v`: eight boxes against one ray, in its own
//! direction's octant), so that rays of a packet need not share an octant,
//! and each leaf's triangles with the single-ray triangle test. A child is
//! visited by the rays that enter its box, nearest first by the least entry
//! distance among them (Wald et al.'s packets, 2001, over Embree's BVH8
//! layout, with the rays in the outer loop instead of SIMD lanes).
//!
//! The answers are the single-ray kernel's, bit for bit: every operation a
//! ray sees is that kernel's, and the closest hit is the least (distance,
//! triangle) of every triangle the ray meets (`traverse::better`), which
//! does not depend on the order of visits. (This rests on the box test
//! being conservative, as `FAR_SCALE` makes it: a box is never rejected
//! while it holds a triangle the ray meets no farther than the best so
//! far. Were a rounding to break that, the two kernels could differ on
//! that ray; the tests compare them on the rays of recorded scenes.)

use std::arch::x86_64::*;
use std::mem::MaybeUninit;

use super::collapse::leaf_packs;
use super::traverse::visits;
use super::traverse::SlotHit;
use super::traverse8::{take_hits, Prepared};
use super::wide8::{Wide8, LEAF_BIT, STACK};
use super::Hit;
use crate::geometry::Ray;

/// Rays in a packet.
pub(super) const PACKET: usize = 8;

/// The closest hit of each of `rays` (1 to [`PACKET`] of them) into `out`
/// (as long).
#[inline]
pub(super) fn closest(w: &Wide8, rays: &[Ray], out: &mut [Option<Hit>]) {
    let _ = w.avx2;
    assert!(!rays.is_empty() && rays.len() <= PACKET && out.len() == rays.len());
    // SAFETY: a Wide8 holds an Avx2 token, made only where AVX2 was detected
    unsafe { closest_avx2(w, rays, out) }
}

/// The packet's stack: child references, the least entry distance of the
/// rays that enter each, and the set of those rays (bit k for ray k). Left
/// uninitialised, as `traverse.rs`'s `Stack`.
struct PacketStack {
    node: MaybeUninit<[u32; STACK]>,
    dist: MaybeUninit<[f32; STACK]>,
    rays: MaybeUninit<[u8; STACK]>,
    len: usize,
}

impl PacketStack {
    #[inline(always)]
    fn new() -> PacketStack {
        PacketStack {
            node: MaybeUninit::uninit(),
            dist: MaybeUninit::uninit(),
            rays: MaybeUninit::uninit(),
            len: 0,
        }
    }

    #[inline(always)]
    fn set(&mut self, i: usize, node: u32, dist: f32, rays: u8) {
        // The tree's depth was checked against the stack when it was built
        assert!(i < STACK);
        // SAFETY: i < STACK
        unsafe {
            self.node.as_mut_ptr().cast::<u32>().add(i).write(node);
            self.dist.as_mut_ptr().cast::<f32>().add(i).write(dist);
            self.rays.as_mut_ptr().cast::<u8>().add(i).write(rays);
        }
    }

    #[inline(always)]
    fn get(&self, i: usize) -> (u32, f32, u8) {
        debug_assert!(i < self.len);
        // SAFETY: entries below `len` were written, and len <= STACK
        unsafe {
            (
                self.node.as_ptr().cast::<u32>().add(i).read(),
                self.dist.as_ptr().cast::<f32>().add(i).read(),
                self.rays.as_ptr().cast::<u8>().add(i).read(),
            )
        }
    }
}

#[target_feature(enable = "avx2")]
fn closest_avx2(w: &Wide8, rays: &[Ray], out: &mut [Option<Hit>]) {
    let n = rays.len();
    // Lanes past the packet's rays repeat its first ray, and take no part
    let ray = |k: usize| &rays[if k < n { k } else { 0 }];
    let prep: [Prepared; PACKET] = std::array::from_fn(|k| Prepared::new(ray(k).o, ray(k).d));
    let vmin: [__m256; PACKET] = std::array::from_fn(|k| _mm256_set1_ps(ray(k).tmin));
    let mut t_best: [f32; PACKET] = std::array::from_fn(|k| ray(k).tmax);
    let mut best: [Option<SlotHit>; PACKET] = Default::default();
    let inf = _mm256_set1_ps(f32::INFINITY);
    let mut stack = PacketStack::new();
    let mut r = w.root;
    let mut active: u32 = (1 << n) - 1;
    loop {
        if r & LEAF_BIT == 0 {
            // Each active ray tests the eight children; a child's rays are
            // those that enter it, its distance the least of theirs
            let node = &w.nodes[r as usize];
            let mut near = inf;
            let mut who = _mm256_setzero_si256();
            let mut bits = active;
            while bits != 0 {
                let k = bits.trailing_zeros() as usize;
                bits &= bits - 1;
                let (hit, t0) = prep[k].boxes_v(node, vmin[k], _mm256_set1_ps(t_best[k]));
                near = _mm256_min_ps(_mm256_blendv_ps(inf, t0, hit), near);
                who = _mm256_or_si256(
                    who,
                    _mm256_and_si256(_mm256_castps_si256(hit), _mm256_set1_epi32(1 << k)),
                );
            }
            let mask = _mm256_movemask_ps(_mm256_cmp_ps::<_CMP_LT_OQ>(near, inf)) as u32;
            if mask != 0 {
                let (mut na, mut wa) = ([0f32; 8], [0u32; 8]);
                // SAFETY: eight writable f32s and u32s; no alignment needed
                unsafe {
                    _mm256_storeu_ps(na.as_mut_ptr(), near);
                    _mm256_storeu_si256(wa.as_mut_ptr().cast(), who);
                }
                if mask & (mask - 1) == 0 {
                    let i = mask.trailing_zeros() as usize;
                    r = node.child[i];
                    active = wa[i];
                    continue;
                }
                // Push the children sorted farthest first; descend into the
                // nearest
                let base = stack.len;
                let mut bits = mask;
                while bits != 0 {
                    let i = bits.trailing_zeros() as usize;
                    bits &= bits - 1;
                    let mut j = stack.len;
                    while j > base {
                        let (rj, dj, mj) = stack.get(j - 1);
                        if dj >= na[i] {
                            break;
                        }
                        stack.set(j, rj, dj, mj);
                        j -= 1;
                    }
                    stack.set(j, node.child[i], na[i], wa[i] as u8);
                    stack.len += 1;
                }
                stack.len -= 1;
                let (cr, _, cm) = stack.get(stack.len);
                r = cr;
                active = u32::from(cm);
                continue;
            }
        } else {
            // Each active ray tests the leaf's triangles, eight at a time
            for p in leaf_packs(r) {
                let pack = &w.packs[p];
                let mut bits = active;
                while bits != 0 {
                    let k = bits.trailing_zeros() as usize;
                    bits &= bits - 1;
                    let (mask, t, u, v) =
                        prep[k].triangles::<true>(pack, vmin[k], _mm256_set1_ps(t_best[k]));
                    take_hits(mask, (t, u, v), p, &w.ids, &mut t_best[k], &mut best[k]);
                }
            }
        }
        // Pop the nearest entry that may still hold a closer hit for one of
        // its rays, with those rays
        loop {
            if stack.len == 0 {
                for (o, b) in out.iter_mut().zip(&best) {
                    *o = b.as_ref().map(|h| Hit {
                        t: h.t,
                        tri: w.ids[h.slot],
                        b1: h.b1,
                        b2: h.b2,
                    });
                }
                return;
            }
            let (cr, cd, cm) = stack.get(stack.len - 1);
            stack.len -= 1;
            let mut m = u32::from(cm);
            let mut bits = m;
            while bits != 0 {
                let k = bits.trailing_zeros() as usize;
                bits &= bits - 1;
                if !visits(cd, t_best[k]) {
                    m &= !(1 << k);
                }
            }
            if m != 0 {
                r = cr;
                active = m;
                break;
            }
        }
    }
}
