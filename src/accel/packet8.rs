//! Packets of up to eight rays walked together through the 8-wide BVH of
//! `wide8.rs`, for rays that start close together and point alike (the
//! camera rays of neighbouring pixels). The rays are in the lanes: one AVX2
//! register holds a quantity of all eight rays, and each child box of a
//! node, and each triangle of a leaf, is tested against the eight rays at
//! once (the form of Embree's stream and packet kernels; Wald et al.'s
//! packets, 2001), rather than each ray against eight boxes or triangles
//! in turn as the single-ray kernel of `traverse8.rs` does.
//!
//! The packet shares one walk over the 8-wide BVH of `wide8.rs`: one stack,
//! one order of visits (each child by the least entry distance of the rays
//! that enter it), and for every ray the set of nodes it takes part in. A
//! child's rays are those that take part in its parent and enter its box.
//!
//! The answers are the single-ray kernel's (`traverse8.rs`), bit for bit:
//! each lane does that kernel's operations on its ray in the same order
//! (the slab test of `Prepared::boxes_v` with the ray's own near and far
//! planes, and the Möller–Trumbore test of `Prepared::triangles`; Rust
//! never contracts them into fused multiply-adds), and a lane keeps the
//! least (distance, triangle) of the triangles it meets, as
//! `traverse::better` does, which does not depend on the order of visits.
//! (This rests on the box test being conservative, as `FAR_SCALE` makes
//! it: a box is never rejected while it holds a triangle the ray meets no
//! farther than the best so far. Were a rounding to break that, the two
//! kernels could differ on that ray; the tests compare them on the rays of
//! recorded scenes.) A ray takes part in a popped node while its own
//! `traverse::visits` holds for the least entry distance of the node's
//! rays, which is never above its own.
//!
//! Rays in the lanes pay for every lane, whether its ray takes part or not,
//! and the single-ray form for every child slot and triangle slot. Where a
//! packet's rays diverge (deep in a large scene's tree, a node or leaf
//! sees few of them), a node with more valid children than taking-part
//! rays, or a pack with more triangles than those rays, is tested ray by
//! ray with the single-ray kernel's own tests (`Prepared::lane`), the
//! same operations either way.
//!
//! Rays need not share an octant: each lane picks its near plane along an
//! axis by its direction's sign bit, as the single-ray kernel does. Where
//! they do share one (camera rays of neighbouring pixels, but at the
//! image's middle row and column), the choice is one for all lanes and the
//! selection costs nothing, and a node's children are first tested against
//! the packet's bounds (the least and greatest origin and `1/d` of its rays
//! along each axis: an interval slab test, Embree's for coherent streams),
//! which drops, for all eight children at once, those no ray can enter;
//! only the others are tested ray by ray in the lanes. The interval test
//! is conservative (see `Frustum::keep`), so it drops nothing the rays'
//! own tests would keep, and is left out for packets with a zero direction
//! component, whose products the slab test may meet as NaN.

use std::arch::x86_64::*;
use std::mem::MaybeUninit;

use super::collapse::leaf_packs;
use super::traverse::FAR_SCALE;
use super::traverse8::{moller_trumbore, Prepared};
use super::wide8::{Node8, Pack8, Wide8, LEAF_BIT, STACK};
use super::Hit;
use crate::geometry::Ray;

/// Rays in a packet (one per lane).
pub(super) const PACKET: usize = 8;

/// The closest hit of each of `rays` (1 to [`PACKET`] of them) into `out`
/// (as long), each the one `traverse8::closest` finds, bit for bit.
#[inline]
pub(super) fn closest(w: &Wide8, rays: &[Ray], out: &mut [Option<Hit>]) {
    let _ = w.avx2;
    assert!(!rays.is_empty() && rays.len() <= PACKET && out.len() == rays.len());
    // SAFETY: a Wide8 holds an Avx2 token, made only where AVX2 was detected
    unsafe { closest_avx2(w, rays, out) }
}

/// [`closest`] with AVX2. The lanes are made here and the walk inlined, so
/// that they stay in this frame (a walk called with a reference to them
/// copied them into its own).
#[target_feature(enable = "avx2")]
fn closest_avx2(w: &Wide8, rays: &[Ray], out: &mut [Option<Hit>]) {
    let p = Lanes::new(rays);
    if p.octant.is_some() {
        walk::<false>(w, &p, out);
    } else {
        walk::<true>(w, &p, out);
    }
}

/// The packet's rays, one per lane; lanes past the packet's rays repeat
/// its first ray, and take no part.
struct Lanes {
    o: [__m256; 3],
    d: [__m256; 3],
    /// `1/d`, as `Prepared::new` computes it (a correctly rounded division
    /// either way).
    inv: [__m256; 3],
    tmin: __m256,
    tmax: __m256,
    /// The rays in the packet (bit k for lane k).
    rays: u32,
    /// When all eight lanes' directions have the same sign bit along each
    /// axis: bit `axis` set where that sign is negative.
    octant: Option<u32>,
    /// The packet's bounds, where it has an octant and bounds that hold.
    frustum: Option<Frustum>,
}

/// Bounds of a common-octant packet's rays, for the interval test
/// ([`Frustum::keep`]) that drops the children of a node no ray can enter
/// before the rays' own tests. Each field holds its value in every lane.
struct Frustum {
    /// Per axis, the origin coordinate that gives the least `n − o` on the
    /// near plane: the greatest where the directions are positive, the
    /// least where they are negative.
    o_near: [__m256; 3],
    /// Per axis, the origin coordinate that gives the greatest `f − o` on
    /// the far plane (the other extreme).
    o_far: [__m256; 3],
    /// Per axis, the least and the greatest `1/d` of the rays.
    inv_lo: [__m256; 3],
    inv_hi: [__m256; 3],
    /// The least `tmin` of the rays.
    tmin: __m256,
}

impl Frustum {
    /// The bounds of `p`'s rays, or none where an interval could not bound
    /// their tests: a zero, infinite or NaN reciprocal (a zero direction
    /// component, whose products may be NaN, which the slab test skips), an
    /// origin that is not finite, or a NaN `tmin` or `tmax`.
    #[inline]
    #[target_feature(enable = "avx2")]
    fn new(
        o: &[__m256; 3],
        inv: &[__m256; 3],
        tmin: __m256,
        tmax: __m256,
        octant: u32,
    ) -> Option<Frustum> {
        let abs = |x| _mm256_andnot_ps(_mm256_set1_ps(-0.0), x);
        let inf = _mm256_set1_ps(f32::INFINITY);
        let mut ok = _mm256_and_ps(
            _mm256_cmp_ps::<_CMP_ORD_Q>(tmin, tmin),
            _mm256_cmp_ps::<_CMP_ORD_Q>(tmax, tmax),
        );
        for axis in 0..3 {
            let (a, b) = (abs(inv[axis]), abs(o[axis]));
            ok = _mm256_and_ps(ok, _mm256_cmp_ps::<_CMP_GT_OQ>(a, _mm256_setzero_ps()));
            ok = _mm256_and_ps(ok, _mm256_cmp_ps::<_CMP_LT_OQ>(a, inf));
            ok = _mm256_and_ps(ok, _mm256_cmp_ps::<_CMP_LT_OQ>(b, inf));
        }
        if _mm256_movemask_ps(ok) != 0xff {
            return None;
        }
        let (o_lo, o_hi) = (o.map(|x| least_v(x)), o.map(|x| most_v(x)));
        let o_near = std::array::from_fn(|a| {
            if octant & (1 << a) != 0 {
                o_lo[a]
            } else {
                o_hi[a]
            }
        });
        let o_far = std::array::from_fn(|a| {
            if octant & (1 << a) != 0 {
                o_hi[a]
            } else {
                o_lo[a]
            }
        });
        Some(Frustum {
            o_near,
            o_far,
            inv_lo: inv.map(|x| least_v(x)),
            inv_hi: inv.map(|x| most_v(x)),
            tmin: least_v(tmin),
        })
    }

    /// The children of `node` (bit i for child i) that some ray of the
    /// packet may enter within its `[tmin, t_best]`, `t_best` at most
    /// `t_hi` in every lane: the rays' slab test done on intervals. The
    /// entry distance of a ray along an axis, `(n − o)·(1/d)`, is at least
    /// the least of `(n − o_near)·(1/d)` over the extreme reciprocals
    /// (`x·y` is bilinear, so its extremes over a box are at corners, and
    /// correctly rounded subtraction and multiplication are monotone); its
    /// exit distance at most the greatest of `(f − o_far)·(1/d)`. A child
    /// whose least entry is beyond its greatest exit (times `FAR_SCALE`) is
    /// entered by no ray; with no NaN among the rays' values (as
    /// [`Frustum::new`] requires) its lanes' own tests reject it too.
    #[inline]
    #[target_feature(enable = "avx2")]
    fn keep(&self, node: &Node8, octant: u32, t_hi: __m256) -> u32 {
        let mut t0 = self.tmin;
        let mut t1 = t_hi;
        for axis in 0..3 {
            let s = ((octant >> axis) & 1) as usize;
            // SAFETY: each row is eight f32s, 32-byte aligned (Node8's repr)
            let (n, f) = unsafe {
                (
                    _mm256_load_ps(node.b[2 * axis + s].as_ptr()),
                    _mm256_load_ps(node.b[2 * axis + 1 - s].as_ptr()),
                )
            };
            let x = _mm256_sub_ps(n, self.o_near[axis]);
            let (a, b) = (
                _mm256_mul_ps(x, self.inv_lo[axis]),
                _mm256_mul_ps(x, self.inv_hi[axis]),
            );
            t0 = _mm256_max_ps(_mm256_min_ps(a, b), t0);
            let x = _mm256_sub_ps(f, self.o_far[axis]);
            let (a, b) = (
                _mm256_mul_ps(x, self.inv_lo[axis]),
                _mm256_mul_ps(x, self.inv_hi[axis]),
            );
            t1 = _mm256_min_ps(_mm256_max_ps(a, b), t1);
        }
        let far = _mm256_mul_ps(t1, _mm256_set1_ps(FAR_SCALE));
        // Kept unless surely beyond (a NaN from an unused slot keeps it)
        _mm256_movemask_ps(_mm256_cmp_ps::<_CMP_NGT_UQ>(t0, far)) as u32
    }
}

impl Lanes {
    #[inline]
    #[target_feature(enable = "avx2")]
    fn new(rays: &[Ray]) -> Lanes {
        let n = rays.len();
        // A ray is eight f32s: each is one row, and the transpose of the
        // eight rows gives each of the ray's values in the lanes
        let rows: [__m256; PACKET] = std::array::from_fn(|k| {
            let r = &rays[if k < n { k } else { 0 }];
            // SAFETY: a Ray is eight f32s (checked at compile time below);
            // no alignment needed
            unsafe { _mm256_loadu_ps((r as *const Ray).cast()) }
        });
        let t = crate::simd::transpose8(rows);
        let o = [t[O], t[O + 1], t[O + 2]];
        let d = [t[D], t[D + 1], t[D + 2]];
        let one = _mm256_set1_ps(1.0);
        let inv = d.map(|d| _mm256_div_ps(one, d));
        // The sign bits of each axis's eight directions
        let signs = d.map(|d| _mm256_movemask_ps(d) as u32);
        let octant = signs
            .iter()
            .all(|&s| s == 0 || s == 0xff)
            .then(|| (0..3).map(|a| u32::from(signs[a] != 0) << a).sum());
        let (tmin, tmax) = (t[TMIN], t[TMAX]);
        let frustum = octant.and_then(|oct| Frustum::new(&o, &inv, tmin, tmax, oct));
        Lanes {
            o,
            d,
            inv,
            tmin,
            tmax,
            rays: (1 << n) - 1,
            octant,
            frustum,
        }
    }

    /// Lane `k`'s `tmin` in every lane.
    #[inline]
    #[target_feature(enable = "avx2")]
    fn tmin_of(&self, k: usize) -> __m256 {
        _mm256_permutevar8x32_ps(self.tmin, _mm256_set1_epi32(k as i32))
    }

    /// The lanes whose ray enters box `i` of `node` within
    /// `[tmin, t_best]`, as a vector mask, and the distance at which each
    /// enters: `Prepared::boxes_v`'s operations, in its order, on each
    /// lane's ray. With `MIXED` each lane takes its near plane by its own
    /// direction's sign bit; without, the planes of `self.octant`.
    #[inline]
    #[target_feature(enable = "avx2")]
    fn enters<const MIXED: bool>(
        &self,
        node: &Node8,
        i: usize,
        t_best: __m256,
    ) -> (__m256, __m256) {
        // maxps/minps return their second operand when either is NaN: the
        // running bound goes second so that NaN lanes leave it unchanged
        let mut t0 = self.tmin;
        let mut t1 = t_best;
        let octant = self.octant.unwrap_or(0);
        for axis in 0..3 {
            let lo = _mm256_set1_ps(node.b[2 * axis][i]);
            let hi = _mm256_set1_ps(node.b[2 * axis + 1][i]);
            let (n, f) = if MIXED {
                (
                    _mm256_blendv_ps(lo, hi, self.d[axis]),
                    _mm256_blendv_ps(hi, lo, self.d[axis]),
                )
            } else if octant & (1 << axis) != 0 {
                (hi, lo)
            } else {
                (lo, hi)
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
}

/// The packet's stack: child references, the least entry distance of the
/// rays that enter each, and the set of those rays (bit k for ray k). Left
/// uninitialised, as `traverse.rs`'s `Stack`. (`len` goes first: after
/// the bytes of `rays`, LLVM merged its zero with them into a memset of
/// the whole array.)
#[repr(C)]
struct PacketStack {
    len: usize,
    node: MaybeUninit<[u32; STACK]>,
    dist: MaybeUninit<[f32; STACK]>,
    rays: MaybeUninit<[u8; STACK]>,
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

/// The lanes set in `bits` (bit k for lane k) as a vector mask.
#[inline]
#[target_feature(enable = "avx2")]
fn lane_mask(bits: u32) -> __m256 {
    crate::simd::F8::mask(bits).0
}

// Where a Ray's values sit among its eight f32s (glam's Vec3 is three f32s,
// `repr(C)`)
const _: () = assert!(std::mem::size_of::<Ray>() == 8 * 4);
const O: usize = std::mem::offset_of!(Ray, o) / 4;
const D: usize = std::mem::offset_of!(Ray, d) / 4;
const TMIN: usize = std::mem::offset_of!(Ray, tmin) / 4;
const TMAX: usize = std::mem::offset_of!(Ray, tmax) / 4;

/// The least of the eight lanes of `x`, in every lane (with no NaN among
/// them).
#[inline]
#[target_feature(enable = "avx2")]
fn least_v(x: __m256) -> __m256 {
    let m = _mm256_min_ps(x, _mm256_permute2f128_ps::<1>(x, x));
    let m = _mm256_min_ps(m, _mm256_shuffle_ps::<0b0100_1110>(m, m));
    _mm256_min_ps(m, _mm256_shuffle_ps::<0b1011_0001>(m, m))
}

/// The greatest of the eight lanes of `x`, in every lane (with no NaN
/// among them).
#[inline]
#[target_feature(enable = "avx2")]
fn most_v(x: __m256) -> __m256 {
    let m = _mm256_max_ps(x, _mm256_permute2f128_ps::<1>(x, x));
    let m = _mm256_max_ps(m, _mm256_shuffle_ps::<0b0100_1110>(m, m));
    _mm256_max_ps(m, _mm256_shuffle_ps::<0b1011_0001>(m, m))
}

/// The least of the eight lanes of `x`.
#[inline]
#[target_feature(enable = "avx2")]
fn least(x: __m256) -> f32 {
    let m = _mm_min_ps(_mm256_castps256_ps128(x), _mm256_extractf128_ps::<1>(x));
    let m = _mm_min_ps(m, _mm_movehl_ps(m, m));
    let m = _mm_min_ss(m, _mm_shuffle_ps::<0b01>(m, m));
    _mm_cvtss_f32(m)
}

/// The best hit of each lane so far: distance, barycentric weights and
/// scene triangle (−1 for none; scene triangle indices are below 2³¹,
/// as the build checks).
struct Best {
    t: __m256,
    u: __m256,
    v: __m256,
    tri: __m256i,
}

impl Best {
    /// The best hit's t, u, v and triangle slot of each lane, as arrays.
    /// Called only from this file's AVX2 functions, into which it is
    /// inlined (a `#[target_feature]` function cannot be `inline(always)`,
    /// and as a plain `inline` one LLVM kept it out of line).
    #[inline(always)]
    fn lanes(&self) -> ([f32; 8], [f32; 8], [f32; 8], [i32; 8]) {
        let (mut t, mut u, mut v, mut tri) = ([0f32; 8], [0f32; 8], [0f32; 8], [0i32; 8]);
        // SAFETY: eight writable f32s or i32s each, no alignment needed;
        // AVX is there, since only AVX2 functions call this one
        unsafe {
            _mm256_storeu_ps(t.as_mut_ptr(), self.t);
            _mm256_storeu_ps(u.as_mut_ptr(), self.u);
            _mm256_storeu_ps(v.as_mut_ptr(), self.v);
            _mm256_storeu_si256(tri.as_mut_ptr().cast(), self.tri);
        }
        (t, u, v, tri)
    }

    /// Tests triangle `j` of `pack`, scene triangle `id`, against the
    /// lanes in `active`, and takes its hits where `traverse::better`
    /// would: `Prepared::triangles::<true>`'s operations, in its order,
    /// with the triangle's values in every lane.
    #[inline]
    #[target_feature(enable = "avx2")]
    fn triangle(&mut self, p: &Lanes, pack: &Pack8, j: usize, id: u32, active: __m256) {
        let ld = |rows: &[[f32; 8]; 3]| {
            [
                _mm256_set1_ps(rows[0][j]),
                _mm256_set1_ps(rows[1][j]),
                _mm256_set1_ps(rows[2][j]),
            ]
        };
        let (v0, e1, e2, ng) = (ld(&pack.v0), ld(&pack.e1), ld(&pack.e2), ld(&pack.ng));
        let (hit, t, u, v) = moller_trumbore::<true>(&p.o, &p.d, [v0, e1, e2, ng], p.tmin, self.t);
        let and = |a, b| _mm256_and_ps(a, b);
        // `better`: nearer, or as near and of lower scene index than a
        // best there is (a lane without one holds −1, below every index)
        let nearer = _mm256_cmp_ps::<_CMP_LT_OS>(t, self.t);
        let lower = _mm256_castsi256_ps(_mm256_cmpgt_epi32(self.tri, _mm256_set1_epi32(id as i32)));
        let tie = and(_mm256_cmp_ps::<_CMP_EQ_OQ>(t, self.t), lower);
        let take = and(and(hit, active), _mm256_or_ps(nearer, tie));
        if _mm256_testz_ps(take, take) == 0 {
            self.t = _mm256_blendv_ps(self.t, t, take);
            self.u = _mm256_blendv_ps(self.u, u, take);
            self.v = _mm256_blendv_ps(self.v, v, take);
            self.tri = _mm256_castps_si256(_mm256_blendv_ps(
                _mm256_castsi256_ps(self.tri),
                _mm256_castsi256_ps(_mm256_set1_epi32(id as i32)),
                take,
            ));
        }
    }
}

impl Best {
    /// Tests each ray of `active` against the eight triangles of `pack`
    /// (scene triangles `ids`, `u32::MAX` for none) at once, with
    /// `Prepared::triangles::<true>` as the single-ray kernel does, and
    /// takes the hits `traverse::better` would, in the order of the slots.
    #[inline]
    #[target_feature(enable = "avx2")]
    fn rays_against(&mut self, p: &Lanes, pack: &Pack8, ids: &[u32], active: u32) {
        let (mut t, mut u, mut v, mut tri) = self.lanes();
        let mut bits = active;
        while bits != 0 {
            let k = bits.trailing_zeros() as usize;
            bits &= bits - 1;
            let ray = Prepared::lane(&p.o, &p.d, &p.inv, k);
            let (mut mask, th, uh, vh) =
                ray.triangles::<true>(pack, p.tmin_of(k), _mm256_set1_ps(t[k]));
            if mask == 0 {
                continue;
            }
            let (mut ta, mut ua, mut va) = ([0f32; 8], [0f32; 8], [0f32; 8]);
            // SAFETY: eight writable f32s each; no alignment needed
            unsafe {
                _mm256_storeu_ps(ta.as_mut_ptr(), th);
                _mm256_storeu_ps(ua.as_mut_ptr(), uh);
                _mm256_storeu_ps(va.as_mut_ptr(), vh);
            }
            while mask != 0 {
                let i = mask.trailing_zeros() as usize;
                mask &= mask - 1;
                // `better`, with −1 for no best
                let id = ids[i] as i32;
                if ta[i] < t[k] || (ta[i] == t[k] && tri[k] > id) {
                    (t[k], u[k], v[k], tri[k]) = (ta[i], ua[i], va[i], id);
                }
            }
        }
        // SAFETY: eight readable f32s or i32s each; no alignment needed
        unsafe {
            self.t = _mm256_loadu_ps(t.as_ptr());
            self.u = _mm256_loadu_ps(u.as_ptr());
            self.v = _mm256_loadu_ps(v.as_ptr());
            self.tri = _mm256_loadu_si256(tri.as_ptr().cast());
        }
    }
}

/// The walk of [`closest_avx2`], with `MIXED` where the rays do not share
/// an octant.
#[inline]
#[target_feature(enable = "avx2")]
fn walk<const MIXED: bool>(w: &Wide8, p: &Lanes, out: &mut [Option<Hit>]) {
    let mut best = Best {
        t: p.tmax,
        u: _mm256_setzero_ps(),
        v: _mm256_setzero_ps(),
        tri: _mm256_set1_epi32(-1),
    };
    let mut stack = PacketStack::new();
    let mut r = w.root;
    let mut active = p.rays;
    loop {
        if r & LEAF_BIT == 0 {
            let node = &w.nodes[r as usize];
            let (hit_children, near, who) = children_hit::<MIXED>(p, node, &best, active);
            if hit_children != 0 {
                if hit_children & (hit_children - 1) == 0 {
                    let i = hit_children.trailing_zeros() as usize;
                    r = node.child[i];
                    active = u32::from(who[i]);
                    continue;
                }
                (r, active) = push_children(&mut stack, node, hit_children, &near, &who);
                continue;
            }
        } else {
            // Each triangle of the leaf against the active rays in the
            // lanes, or, where the rays are fewer than the triangles, each
            // ray against a pack's triangles at once (inline here: as a
            // function of its own LLVM kept it out of line, `best` in memory)
            let av = lane_mask(active);
            for pk in leaf_packs(r) {
                let pack = &w.packs[pk];
                let ids = &w.ids[8 * pk..8 * pk + 8];
                // SAFETY: eight readable u32s; no alignment needed
                let unused = unsafe {
                    let c = _mm256_loadu_si256(ids.as_ptr().cast());
                    _mm256_movemask_ps(_mm256_castsi256_ps(_mm256_cmpeq_epi32(
                        c,
                        _mm256_set1_epi32(-1),
                    ))) as u32
                };
                let valid = !unused & 0xff;
                if active.count_ones() < valid.count_ones() {
                    best.rays_against(p, pack, ids, active);
                } else {
                    let mut bits = valid;
                    while bits != 0 {
                        let j = bits.trailing_zeros() as usize;
                        bits &= bits - 1;
                        best.triangle(p, pack, j, ids[j], av);
                    }
                }
            }
        }
        match pop(&mut stack, &best) {
            Some(next) => (r, active) = next,
            None => {
                best.write(out);
                return;
            }
        }
    }
}

/// The children of `node` that the active rays enter: one bit per child,
/// each one's distance (the least of its rays') and its rays.
#[inline]
#[target_feature(enable = "avx2")]
fn children_hit<const MIXED: bool>(
    p: &Lanes,
    node: &Node8,
    best: &Best,
    active: u32,
) -> (u32, [f32; 8], [u8; 8]) {
    let inf = _mm256_set1_ps(f32::INFINITY);
    // SAFETY: eight readable u32s; no alignment needed
    let unused = unsafe {
        let c = _mm256_loadu_si256(node.child.as_ptr().cast());
        _mm256_movemask_ps(_mm256_castsi256_ps(_mm256_cmpeq_epi32(
            c,
            _mm256_set1_epi32(-1),
        ))) as u32
    };
    let (mut near, mut who) = ([0f32; 8], [0u8; 8]);
    let mut hit_children = 0u32;
    let mut valid = !unused & 0xff;
    if !MIXED {
        if let (Some(f), Some(oct)) = (&p.frustum, p.octant) {
            // Drop the children no ray can enter
            valid &= f.keep(node, oct, most_v(best.t));
        }
    }
    if active.count_ones() < valid.count_ones() {
        // Fewer rays than children: each ray against the eight
        // boxes at once, as the single-ray kernel tests them
        let mut tb = [0f32; 8];
        // SAFETY: eight writable f32s; no alignment needed
        unsafe { _mm256_storeu_ps(tb.as_mut_ptr(), best.t) };
        let mut nv = inf;
        let mut wv = _mm256_setzero_si256();
        let mut bits = active;
        while bits != 0 {
            let k = bits.trailing_zeros() as usize;
            bits &= bits - 1;
            let ray = Prepared::lane(&p.o, &p.d, &p.inv, k);
            let (hit, t0) = ray.boxes_v(node, p.tmin_of(k), _mm256_set1_ps(tb[k]));
            nv = _mm256_min_ps(_mm256_blendv_ps(inf, t0, hit), nv);
            wv = _mm256_or_si256(
                wv,
                _mm256_and_si256(_mm256_castps_si256(hit), _mm256_set1_epi32(1 << k)),
            );
        }
        let mut wa = [0u32; 8];
        // SAFETY: eight writable f32s and u32s; no alignment needed
        unsafe {
            _mm256_storeu_ps(near.as_mut_ptr(), nv);
            _mm256_storeu_si256(wa.as_mut_ptr().cast(), wv);
        }
        who = wa.map(|m| m as u8);
        hit_children = !_mm256_movemask_ps(_mm256_castsi256_ps(_mm256_cmpeq_epi32(
            wv,
            _mm256_setzero_si256(),
        ))) as u32
            & 0xff;
    } else {
        // Each valid child against the active rays in the lanes
        let av = lane_mask(active);
        let mut bits = valid;
        while bits != 0 {
            let i = bits.trailing_zeros() as usize;
            bits &= bits - 1;
            let (hit, t0) = p.enters::<MIXED>(node, i, best.t);
            let hit = _mm256_and_ps(hit, av);
            let m = _mm256_movemask_ps(hit) as u32;
            if m != 0 {
                near[i] = least(_mm256_blendv_ps(inf, t0, hit));
                who[i] = m as u8;
                hit_children |= 1 << i;
            }
        }
    }
    (hit_children, near, who)
}

/// Pushes the children `hit_children` of `node` sorted farthest first, and
/// takes the nearest back off: the node to descend into, with its rays.
#[inline]
#[target_feature(enable = "avx2")]
fn push_children(
    stack: &mut PacketStack,
    node: &Node8,
    hit_children: u32,
    near: &[f32; 8],
    who: &[u8; 8],
) -> (u32, u32) {
    let base = stack.len;
    let mut bits = hit_children;
    while bits != 0 {
        let i = bits.trailing_zeros() as usize;
        bits &= bits - 1;
        let mut j = stack.len;
        while j > base {
            let (rj, dj, mj) = stack.get(j - 1);
            if dj >= near[i] {
                break;
            }
            stack.set(j, rj, dj, mj);
            j -= 1;
        }
        stack.set(j, node.child[i], near[i], who[i]);
        stack.len += 1;
    }
    // The nearest was pushed last: pop it
    let (cr, _, cm) = stack.get(stack.len - 1);
    stack.len -= 1;
    (cr, u32::from(cm))
}

/// Pops the nearest entry that may still hold a closer hit for one of its
/// rays (`traverse::visits` in the lanes): the node, with those rays; none
/// when the stack runs out.
#[inline]
#[target_feature(enable = "avx2")]
fn pop(stack: &mut PacketStack, best: &Best) -> Option<(u32, u32)> {
    let far_scale = _mm256_set1_ps(FAR_SCALE);
    while stack.len != 0 {
        let (cr, cd, cm) = stack.get(stack.len - 1);
        stack.len -= 1;
        let still =
            _mm256_cmp_ps::<_CMP_LE_OQ>(_mm256_set1_ps(cd), _mm256_mul_ps(best.t, far_scale));
        let m = u32::from(cm) & _mm256_movemask_ps(still) as u32;
        if m != 0 {
            return Some((cr, m));
        }
    }
    None
}

impl Best {
    /// The hits found, one per ray.
    #[inline]
    #[target_feature(enable = "avx2")]
    fn write(&self, out: &mut [Option<Hit>]) {
        let (t, u, v, tri) = self.lanes();
        for (k, o) in out.iter_mut().enumerate() {
            *o = (tri[k] >= 0).then(|| Hit {
                t: t[k],
                tri: tri[k] as u32,
                b1: u[k],
                b2: v[k],
            });
        }
    }
}
