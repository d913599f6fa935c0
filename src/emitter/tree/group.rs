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
        if crate::transport::dispatch::has_v3() {
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
        self.eval::<L4>(0, p, n, &mut out[..4]);
        self.eval::<L4>(4, p, n, &mut out[4..]);
        out
    }

    /// [`Group::importance`] in one AVX register.
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx")]
    fn importance_avx(&self, p: Vec3, n: Vec3) -> [f32; 8] {
        let mut out = [0.0; 8];
        self.eval::<L8>(0, p, n, &mut out);
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

#[cfg(target_arch = "x86_64")]
mod lanes {
    //! SSE2 (which every x86_64 has) and AVX. Every `unsafe` block calls an
    //! intrinsic on register values, or loads or stores as many f32s as the
    //! slice just taken holds. The AVX methods run only inlined into
    //! [`super::Group::importance_avx`], which is compiled for AVX and
    //! called where the CPU has it.
    use std::arch::x86_64::*;

    use super::Lanes;

    /// Four f32 lanes.
    #[derive(Clone, Copy)]
    pub(super) struct L4(__m128);

    /// Eight f32 lanes.
    #[derive(Clone, Copy)]
    pub(super) struct L8(__m256);

    macro_rules! lanes {
        ($t:ident, $n:literal, $v:ty, $set1:ident, $loadu:ident, $storeu:ident, $add:ident, $sub:ident,
         $mul:ident, $div:ident, $sqrt:ident, $min:ident, $max:ident, $andnot:ident, $and:ident, $or:ident,
         |$x:ident, $y:ident| $le:expr, $ge:expr) => {
            impl Lanes for $t {
                type Mask = $v;
                #[inline(always)]
                fn splat(x: f32) -> Self {
                    $t(unsafe { $set1(x) })
                }
                #[inline(always)]
                fn load(a: &[f32]) -> Self {
                    let a = &a[..$n];
                    $t(unsafe { $loadu(a.as_ptr()) })
                }
                #[inline(always)]
                fn store(self, out: &mut [f32]) {
                    let out = &mut out[..$n];
                    unsafe { $storeu(out.as_mut_ptr(), self.0) }
                }
                #[inline(always)]
                fn add(self, b: Self) -> Self {
                    $t(unsafe { $add(self.0, b.0) })
                }
                #[inline(always)]
                fn sub(self, b: Self) -> Self {
                    $t(unsafe { $sub(self.0, b.0) })
                }
                #[inline(always)]
                fn mul(self, b: Self) -> Self {
                    $t(unsafe { $mul(self.0, b.0) })
                }
                #[inline(always)]
                fn div(self, b: Self) -> Self {
                    $t(unsafe { $div(self.0, b.0) })
                }
                #[inline(always)]
                fn sqrt(self) -> Self {
                    $t(unsafe { $sqrt(self.0) })
                }
                #[inline(always)]
                fn min(self, b: Self) -> Self {
                    $t(unsafe { $min(self.0, b.0) })
                }
                #[inline(always)]
                fn max(self, b: Self) -> Self {
                    $t(unsafe { $max(self.0, b.0) })
                }
                #[inline(always)]
                fn abs(self) -> Self {
                    $t(unsafe { $andnot($set1(-0.0), self.0) })
                }
                #[inline(always)]
                fn le(self, b: Self) -> $v {
                    let ($x, $y) = (self.0, b.0);
                    unsafe { $le }
                }
                #[inline(always)]
                fn ge(self, b: Self) -> $v {
                    let ($x, $y) = (self.0, b.0);
                    unsafe { $ge }
                }
                #[inline(always)]
                fn select(m: $v, a: Self, b: Self) -> Self {
                    $t(unsafe { $or($and(m, a.0), $andnot(m, b.0)) })
                }
            }
        };
    }

    lanes!(
        L4,
        4,
        __m128,
        _mm_set1_ps,
        _mm_loadu_ps,
        _mm_storeu_ps,
        _mm_add_ps,
        _mm_sub_ps,
        _mm_mul_ps,
        _mm_div_ps,
        _mm_sqrt_ps,
        _mm_min_ps,
        _mm_max_ps,
        _mm_andnot_ps,
        _mm_and_ps,
        _mm_or_ps,
        |x, y| _mm_cmple_ps(x, y),
        _mm_cmpge_ps(x, y)
    );
    lanes!(
        L8,
        8,
        __m256,
        _mm256_set1_ps,
        _mm256_loadu_ps,
        _mm256_storeu_ps,
        _mm256_add_ps,
        _mm256_sub_ps,
        _mm256_mul_ps,
        _mm256_div_ps,
        _mm256_sqrt_ps,
        _mm256_min_ps,
        _mm256_max_ps,
        _mm256_andnot_ps,
        _mm256_and_ps,
        _mm256_or_ps,
        |x, y| _mm256_cmp_ps::<_CMP_LE_OS>(x, y),
        _mm256_cmp_ps::<_CMP_GE_OS>(x, y)
    );
}

#[cfg(not(target_arch = "x86_64"))]
mod lanes {
    //! Plain arrays, with SSE's semantics for min, max and comparisons.

    use super::Lanes;

    /// Four f32 lanes.
    #[derive(Clone, Copy)]
    pub(super) struct L4([f32; 4]);

    #[inline(always)]
    fn map(a: L4, b: L4, f: impl Fn(f32, f32) -> f32) -> L4 {
        L4(std::array::from_fn(|i| f(a.0[i], b.0[i])))
    }

    impl Lanes for L4 {
        type Mask = [bool; 4];
        fn splat(x: f32) -> Self {
            L4([x; 4])
        }
        fn load(a: &[f32]) -> Self {
            L4(std::array::from_fn(|i| a[i]))
        }
        fn store(self, out: &mut [f32]) {
            out[..4].copy_from_slice(&self.0);
        }
        fn add(self, b: Self) -> Self {
            map(self, b, |x, y| x + y)
        }
        fn sub(self, b: Self) -> Self {
            map(self, b, |x, y| x - y)
        }
        fn mul(self, b: Self) -> Self {
            map(self, b, |x, y| x * y)
        }
        fn div(self, b: Self) -> Self {
            map(self, b, |x, y| x / y)
        }
        fn sqrt(self) -> Self {
            L4(self.0.map(f32::sqrt))
        }
        fn min(self, b: Self) -> Self {
            map(self, b, |x, y| if x < y { x } else { y })
        }
        fn max(self, b: Self) -> Self {
            map(self, b, |x, y| if x > y { x } else { y })
        }
        fn abs(self) -> Self {
            L4(self.0.map(f32::abs))
        }
        fn le(self, b: Self) -> [bool; 4] {
            std::array::from_fn(|i| self.0[i] <= b.0[i])
        }
        fn ge(self, b: Self) -> [bool; 4] {
            std::array::from_fn(|i| self.0[i] >= b.0[i])
        }
        fn select(m: [bool; 4], a: Self, b: Self) -> Self {
            L4(std::array::from_fn(|i| if m[i] { a.0[i] } else { b.0[i] }))
        }
    }
}

use lanes::L4;
#[cfg(target_arch = "x86_64")]
use lanes::L8;
