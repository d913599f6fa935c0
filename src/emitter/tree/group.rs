//! The importances of a light-tree node's two children and four
//! grandchildren, evaluated together: the walk down the tree evaluates
//! [`Bounds::importance`] for the two children of every node it passes,
//! and this does two levels' worth at once, in the eight lanes of an AVX
//! register where the CPU has AVX (two SSE registers elsewhere).
//!
//! Every operation is the scalar one, lane by lane and in the same order
//! (IEEE `sqrt` and division are exact in all three forms, and nothing is
//! fused), and the scalar code's branches become selects between values
//! computed in every lane, so the importances are the scalar ones bit for
//! bit: the tree samples the same lights with the same probabilities
//! whichever form runs.

use glam::Vec3;

use super::Bounds;
#[cfg(target_arch = "x86_64")]
use crate::simd::F8;
use crate::simd::{F4, M4};

/// Eight nodes' bounds by field, the fields [`Bounds::importance`] reads.
/// For a node with children a and b, lanes: a, b, a's two children, b's
/// two children, then a and b again (a child that is a leaf, or whose
/// share is fixed, repeats a and b in its lanes, which nothing reads).
#[derive(Clone, Copy, Debug)]
#[repr(C, align(32))]
pub(super) struct Group {
    centre: [[f32; 8]; 3],
    r: [f32; 8],
    r2: [f32; 8],
    axis: [[f32; 8]; 3],
    cos_o: [f32; 8],
    sin_o: [f32; 8],
    phi: [f32; 8],
}

/// One lane's view of a [`Group`]: which bounds it holds.
type Lanes8<'a> = [&'a Bounds; 8];

impl Group {
    /// The group of children `a` and `b` and, where given, their children.
    pub(super) fn new(
        a: &Bounds,
        b: &Bounds,
        below_a: Option<[&Bounds; 2]>,
        below_b: Option<[&Bounds; 2]>,
    ) -> Self {
        let [a1, a2] = below_a.unwrap_or([a, b]);
        let [b1, b2] = below_b.unwrap_or([a, b]);
        let lanes: Lanes8 = [a, b, a1, a2, b1, b2, a, b];
        let f = |g: fn(&Bounds) -> f32| lanes.map(g);
        Group {
            centre: [f(|x| x.centre.x), f(|x| x.centre.y), f(|x| x.centre.z)],
            r: f(|x| x.r),
            r2: f(|x| x.r2),
            axis: [f(|x| x.axis.x), f(|x| x.axis.y), f(|x| x.axis.z)],
            cos_o: f(|x| x.cos_o),
            sin_o: f(|x| x.sin_o),
            phi: f(|x| x.phi),
        }
    }

    /// [`Bounds::importance`] of the eight lanes at p with normal n.
    #[inline]
    pub(super) fn importance(&self, p: Vec3, n: Vec3) -> [f32; 8] {
        #[cfg(target_arch = "x86_64")]
        if crate::simd::has_v3() {
            // SAFETY: the CPU has AVX (has_v3 checks AVX2, which implies it)
            return unsafe { self.importance_avx(p, n) };
        }
        self.importance_sse(p, n)
    }

    /// [`Group::importance`] in two SSE registers (or plain arrays off
    /// x86_64).
    #[inline(always)]
    pub(super) fn importance_sse(&self, p: Vec3, n: Vec3) -> [f32; 8] {
        let mut out = [0.0; 8];
        self.eval::<F4>(0, p, n, &mut out[..4]);
        self.eval::<F4>(4, p, n, &mut out[4..]);
        out
    }

    /// [`Group::importance`] in one AVX register.
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx")]
    fn importance_avx(&self, p: Vec3, n: Vec3) -> [f32; 8] {
        let mut out = [0.0; 8];
        self.eval::<F8>(0, p, n, &mut out);
        out
    }

    /// [`Bounds::importance`] of lanes `at`.. (as many as `L` holds) into `out`.
    #[inline(always)]
    fn eval<L: Lanes>(&self, at: usize, p: Vec3, n: Vec3, out: &mut [f32]) {
        let ld = |a: &[f32; 8]| L::load(&a[at..]);
        let (zero, one) = (L::splat(0.0), L::splat(1.0));
        let to_p = [
            L::splat(p.x).sub(ld(&self.centre[0])),
            L::splat(p.y).sub(ld(&self.centre[1])),
            L::splat(p.z).sub(ld(&self.centre[2])),
        ];
        let dist2 = dot(to_p, to_p);
        let (r2, phi) = (ld(&self.r2), ld(&self.phi));
        let inside = dist2.le(r2);
        let inside_value = phi.div(r2.max(L::splat(f32::MIN_POSITIVE)));
        let inv_d = one.div(dist2.sqrt());
        let wi = to_p.map(|c| c.mul(inv_d));
        let sin_b = ld(&self.r).mul(inv_d);
        let cos_b = one.sub(sin_b.mul(sin_b)).max(zero).sqrt();
        let axis = self.axis.each_ref().map(ld);
        // clamp(−1, 1), NaN passing through as in f32::clamp
        let cos_w = one.min(L::splat(-1.0).max(dot(axis, wi)));
        let sin_w = one.sub(cos_w.mul(cos_w)).max(zero).sqrt();
        let (cos_o, sin_o) = (ld(&self.cos_o), ld(&self.sin_o));
        let (cos_x, sin_x) = angle_minus(cos_w, sin_w, cos_o, sin_o);
        let (cos_t, _) = angle_minus(cos_x, sin_x, cos_b, sin_b);
        let mut imp = phi.mul(cos_t).mul(inv_d.mul(inv_d));
        if n != Vec3::ZERO {
            let n = [L::splat(n.x), L::splat(n.y), L::splat(n.z)];
            let cos_i = dot(n, wi).abs().min(one);
            let sin_i = one.sub(cos_i.mul(cos_i)).max(zero).sqrt();
            let (cos_ti, _) = angle_minus(cos_i, sin_i, cos_b, sin_b);
            imp = imp.mul(cos_ti.max(zero));
        }
        let imp = L::select(cos_t.le(zero), zero, imp);
        L::select(inside, inside_value, imp).store(out);
    }
}

/// glam's `Vec3::dot`, lane by lane: (x·x' + y·y') + z·z'.
#[inline(always)]
fn dot<L: Lanes>(a: [L; 3], b: [L; 3]) -> L {
    a[0].mul(b[0]).add(a[1].mul(b[1])).add(a[2].mul(b[2]))
}

/// The scalar `angle_minus`, lane by lane.
#[inline(always)]
fn angle_minus<L: Lanes>(cos_a: L, sin_a: L, cos_b: L, sin_b: L) -> (L, L) {
    let done = cos_a.ge(cos_b);
    let c = cos_a.mul(cos_b).add(sin_a.mul(sin_b));
    let s = sin_a.mul(cos_b).sub(cos_a.mul(sin_b));
    (
        L::select(done, L::splat(1.0), c),
        L::select(done, L::splat(0.0), s),
    )
}

/// f32 lanes with the operations [`Group::eval`] uses. `min` and `max`
/// follow SSE: `min(a, b)` is `a` where `a < b`, else `b` (so `b` when
/// either is NaN), and `max` likewise with `>`.
trait Lanes: Copy {
    /// A lane mask from a comparison.
    type Mask: Copy;
    fn splat(x: f32) -> Self;
    /// The first lanes of `a` (which must hold at least as many).
    fn load(a: &[f32]) -> Self;
    /// Into the first lanes of `out` (which must hold at least as many).
    fn store(self, out: &mut [f32]);
    fn add(self, b: Self) -> Self;
    fn sub(self, b: Self) -> Self;
    fn mul(self, b: Self) -> Self;
    fn div(self, b: Self) -> Self;
    fn sqrt(self) -> Self;
    fn min(self, b: Self) -> Self;
    fn max(self, b: Self) -> Self;
    fn abs(self) -> Self;
    fn le(self, b: Self) -> Self::Mask;
    fn ge(self, b: Self) -> Self::Mask;
    /// `a` in the lanes where `m` is set, `b` elsewhere.
    fn select(m: Self::Mask, a: Self, b: Self) -> Self;
}

impl Lanes for F4 {
    type Mask = M4;
    #[inline(always)]
    fn splat(x: f32) -> Self {
        F4::splat(x)
    }
    #[inline(always)]
    fn load(a: &[f32]) -> Self {
        F4::load_slice(a)
    }
    #[inline(always)]
    fn store(self, out: &mut [f32]) {
        self.store_slice(out)
    }
    #[inline(always)]
    fn add(self, b: Self) -> Self {
        F4::add(self, b)
    }
    #[inline(always)]
    fn sub(self, b: Self) -> Self {
        F4::sub(self, b)
    }
    #[inline(always)]
    fn mul(self, b: Self) -> Self {
        F4::mul(self, b)
    }
    #[inline(always)]
    fn div(self, b: Self) -> Self {
        F4::div(self, b)
    }
    #[inline(always)]
    fn sqrt(self) -> Self {
        F4::sqrt(self)
    }
    #[inline(always)]
    fn min(self, b: Self) -> Self {
        F4::min(self, b)
    }
    #[inline(always)]
    fn max(self, b: Self) -> Self {
        F4::max(self, b)
    }
    #[inline(always)]
    fn abs(self) -> Self {
        F4::abs(self)
    }
    #[inline(always)]
    fn le(self, b: Self) -> M4 {
        F4::le(self, b)
    }
    #[inline(always)]
    fn ge(self, b: Self) -> M4 {
        F4::ge(self, b)
    }
    #[inline(always)]
    fn select(m: M4, a: Self, b: Self) -> Self {
        F4::select(m, a, b)
    }
}

/// Only inlined into [`Group::importance_avx`], which is compiled for AVX
/// and called where the CPU has it, as [`F8`]'s contract asks.
#[cfg(target_arch = "x86_64")]
impl Lanes for F8 {
    type Mask = F8;
    #[inline(always)]
    fn splat(x: f32) -> Self {
        F8::splat(x)
    }
    #[inline(always)]
    fn load(a: &[f32]) -> Self {
        F8::load_slice(a)
    }
    #[inline(always)]
    fn store(self, out: &mut [f32]) {
        self.store_slice(out)
    }
    #[inline(always)]
    fn add(self, b: Self) -> Self {
        self + b
    }
    #[inline(always)]
    fn sub(self, b: Self) -> Self {
        self - b
    }
    #[inline(always)]
    fn mul(self, b: Self) -> Self {
        self * b
    }
    #[inline(always)]
    fn div(self, b: Self) -> Self {
        self / b
    }
    #[inline(always)]
    fn sqrt(self) -> Self {
        F8::sqrt(self)
    }
    #[inline(always)]
    fn min(self, b: Self) -> Self {
        F8::min(self, b)
    }
    #[inline(always)]
    fn max(self, b: Self) -> Self {
        F8::max(self, b)
    }
    #[inline(always)]
    fn abs(self) -> Self {
        F8::abs(self)
    }
    #[inline(always)]
    fn le(self, b: Self) -> F8 {
        F8::le(self, b)
    }
    #[inline(always)]
    fn ge(self, b: Self) -> F8 {
        F8::ge(self, b)
    }
    /// By bits, (m ∧ a) ∨ (¬m ∧ b), as [`F4::select`].
    #[inline(always)]
    fn select(m: F8, a: Self, b: Self) -> Self {
        (m & a) | m.andnot(b)
    }
}
