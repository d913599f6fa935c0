//! Counted queries of the 8-wide tree for `kalos bench`: a scalar copy of
//! the AVX2 kernels of `traverse8.rs`, which visits the same nodes and packs
//! in the same order, so that the kernels themselves carry no counters.
//!
//! Each lane's arithmetic is the kernel's, operation for operation (no fused
//! multiply-add; `maxps`'s and `minps`'s NaN rule written out), so the box
//! and triangle tests accept exactly what the kernel's do and the visits
//! are the kernel's; the tests check that the answers are the kernel's, bit
//! for bit.

use glam::Vec3;

use super::super::collapse::leaf_packs;
use super::super::traverse::SlotHit;
use super::super::wide8::{Node8, Pack8, Wide8, LEAF_BIT};
use super::Visits;

/// The far distance's widening of the kernels (pbrt-v4's 1 + 2γ₃).
const FAR_SCALE: f32 = 1.0 + 2.0 * (3.0 * f32::EPSILON * 0.5) / (1.0 - 3.0 * f32::EPSILON * 0.5);

/// `maxps(a, b)`: `a` when `a > b`, else `b` (so `b` when either is NaN).
#[inline(always)]
fn maxps(a: f32, b: f32) -> f32 {
    if a > b {
        a
    } else {
        b
    }
}

/// `minps(a, b)`: `a` when `a < b`, else `b`.
#[inline(always)]
fn minps(a: f32, b: f32) -> f32 {
    if a < b {
        a
    } else {
        b
    }
}

struct Prepared {
    o: Vec3,
    d: Vec3,
    inv: Vec3,
    near: [usize; 3],
    far: [usize; 3],
}

impl Prepared {
    fn new(o: Vec3, d: Vec3) -> Prepared {
        let inv = d.recip();
        let neg = |x: f32| usize::from(x.is_sign_negative());
        let near = [neg(d.x), 2 + neg(d.y), 4 + neg(d.z)];
        Prepared {
            o,
            d,
            inv,
            near,
            far: near.map(|r| r ^ 1),
        }
    }

    /// The kernel's box test: the lanes entered within `[tmin, tmax]`, and
    /// their entry distances.
    fn boxes(&self, node: &Node8, tmin: f32, tmax: f32) -> (u32, [f32; 8]) {
        let mut mask = 0;
        let mut t0s = [0f32; 8];
        for (lane, t0_out) in t0s.iter_mut().enumerate() {
            let (mut t0, mut t1) = (tmin, tmax);
            for axis in 0..3 {
                let n = node.b[self.near[axis]][lane];
                let f = node.b[self.far[axis]][lane];
                t0 = maxps((n - self.o[axis]) * self.inv[axis], t0);
                t1 = minps((f - self.o[axis]) * self.inv[axis], t1);
            }
            if t0 <= t1 * FAR_SCALE {
                mask |= 1 << lane;
            }
            *t0_out = t0;
        }
        (mask, t0s)
    }

    /// The kernel's Möller–Trumbore on one lane of `pack`: `(t, u, v)` when
    /// it hits within `[tmin, tmax)`.
    fn triangle(&self, pack: &Pack8, lane: usize, tmin: f32, tmax: f32) -> Option<(f32, f32, f32)> {
        let row = |rows: &[[f32; 8]; 3]| [rows[0][lane], rows[1][lane], rows[2][lane]];
        let (v0, e1, e2, ng) = (row(&pack.v0), row(&pack.e1), row(&pack.e2), row(&pack.ng));
        let dot = |a: [f32; 3], b: [f32; 3]| a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
        let (o, d) = (self.o, self.d);
        let c = [v0[0] - o.x, v0[1] - o.y, v0[2] - o.z];
        let r = [
            d.y * c[2] - d.z * c[1],
            d.z * c[0] - d.x * c[2],
            d.x * c[1] - d.y * c[0],
        ];
        let det = dot(ng, d.to_array());
        let inv_det = 1.0 / det;
        let u = dot(r, e2) * inv_det;
        let v = dot(r, e1) * inv_det;
        let w = (1.0 - u) - v;
        let t = dot(ng, c) * inv_det;
        // det != 0 is true for NaN, as cmpneq_uq
        let hit = det != 0.0 && u >= 0.0 && v >= 0.0 && w >= 0.0 && t >= tmin && t < tmax;
        hit.then_some((t, u, v))
    }
}

/// `traverse8::closest`, counting the nodes and packs it tests.
pub(in super::super) fn closest8_counted(
    w: &Wide8,
    o: Vec3,
    d: Vec3,
    tmin: f32,
    tmax: f32,
    visits: &mut Visits,
) -> Option<SlotHit> {
    let ray = Prepared::new(o, d);
    let mut best: Option<SlotHit> = None;
    let mut t_best = tmax;
    let mut stack: Vec<(u32, f32)> = Vec::new();
    let mut r = w.root;
    loop {
        if r & LEAF_BIT == 0 {
            let node = &w.nodes[r as usize];
            visits.nodes += 1;
            let (mask, t0a) = ray.boxes(node, tmin, t_best);
            if mask != 0 {
                if mask & (mask - 1) == 0 {
                    r = node.child[mask.trailing_zeros() as usize];
                    continue;
                }
                let rest = mask & (mask - 1);
                if rest & (rest - 1) == 0 {
                    let (a, b) = (
                        mask.trailing_zeros() as usize,
                        rest.trailing_zeros() as usize,
                    );
                    let (near, far) = if t0a[b] <= t0a[a] { (b, a) } else { (a, b) };
                    stack.push((node.child[far], t0a[far]));
                    r = node.child[near];
                    continue;
                }
                // Insertion keeping the new entries sorted farthest first
                let base = stack.len();
                let mut bits = mask;
                while bits != 0 {
                    let i = bits.trailing_zeros() as usize;
                    bits &= bits - 1;
                    let mut j = stack.len();
                    while j > base && stack[j - 1].1 < t0a[i] {
                        j -= 1;
                    }
                    stack.insert(j, (node.child[i], t0a[i]));
                }
                r = stack.pop().map_or(r, |e| e.0);
                continue;
            }
        } else {
            for p in leaf_packs(r) {
                visits.packs += 1;
                let pack = &w.packs[p];
                // The kernel tests the whole pack against the bound on entry
                let bound = t_best;
                for lane in 0..8 {
                    if let Some((t, u, v)) = ray.triangle(pack, lane, tmin, bound) {
                        if t < t_best {
                            t_best = t;
                            best = Some(SlotHit {
                                t,
                                slot: 8 * p + lane,
                                b1: u,
                                b2: v,
                            });
                        }
                    }
                }
            }
        }
        loop {
            let Some((cr, cd)) = stack.pop() else {
                return best;
            };
            if cd < t_best {
                r = cr;
                break;
            }
        }
    }
}

/// `traverse8::any`, counting the nodes and packs it tests.
pub(in super::super) fn any8_counted(
    w: &Wide8,
    o: Vec3,
    d: Vec3,
    tmin: f32,
    tmax: f32,
    visits: &mut Visits,
) -> bool {
    let ray = Prepared::new(o, d);
    let mut stack: Vec<u32> = Vec::new();
    let mut r = w.root;
    loop {
        if r & LEAF_BIT == 0 {
            let node = &w.nodes[r as usize];
            visits.nodes += 1;
            let (mut mask, _) = ray.boxes(node, tmin, tmax);
            if mask != 0 {
                r = node.child[mask.trailing_zeros() as usize];
                mask &= mask - 1;
                while mask != 0 {
                    stack.push(node.child[mask.trailing_zeros() as usize]);
                    mask &= mask - 1;
                }
                continue;
            }
        } else {
            for p in leaf_packs(r) {
                visits.packs += 1;
                if (0..8).any(|lane| ray.triangle(&w.packs[p], lane, tmin, tmax).is_some()) {
                    return true;
                }
            }
        }
        match stack.pop() {
            Some(c) => r = c,
            None => return false,
        }
    }
}
