//! Eight f32 lanes in an AVX register, for the code compiled for AVX2.
//!
//! The contract of this module: an [`F8`] is made and used only inside
//! functions compiled with `#[target_feature(enable = "avx2")]` (or
//! x86-64-v3) that run only where [`super::has_v3`] said the CPU has AVX2.
//! The wrappers are `#[inline(always)]` so that they become the one
//! instruction inside those functions; `#[target_feature]` functions cannot
//! be `#[inline(always)]`, which is why each holds an `unsafe` block whose
//! soundness rests on that contract. Their users are the light tree's
//! importances (`emitter::tree::group`), `path`'s lanes
//! (`transport::lanes::avx`) and the ray core's packets (`accel::packet8`).

use std::arch::x86_64::*;
use std::ops::{Add, BitAnd, BitOr, Div, Mul, Neg, Not, Sub};

/// Eight f32 lanes; a comparison gives a mask (all bits set where true).
/// The register is public to the crate for the few operations that are
/// not lane arithmetic on f32 (integer work, bit casts).
#[derive(Clone, Copy)]
pub(crate) struct F8(pub(crate) __m256);

impl F8 {
    /// `x` in every lane.
    #[inline(always)]
    pub(crate) fn splat(x: f32) -> F8 {
        // SAFETY: AVX, which the module's contract guarantees
        F8(unsafe { _mm256_set1_ps(x) })
    }
    /// The eight values of `a`.
    #[inline(always)]
    pub(crate) fn load(a: &[f32; 8]) -> F8 {
        // SAFETY: `a` is eight readable f32s (no alignment needed); AVX,
        // which the module's contract guarantees
        F8(unsafe { _mm256_loadu_ps(a.as_ptr()) })
    }
    /// The first eight values of `a` (which must hold at least eight).
    #[inline(always)]
    pub(crate) fn load_slice(a: &[f32]) -> F8 {
        let a = &a[..8];
        // SAFETY: `a` is eight readable f32s (no alignment needed); AVX,
        // which the module's contract guarantees
        F8(unsafe { _mm256_loadu_ps(a.as_ptr()) })
    }
    /// The eight lanes, lane 0 first.
    #[inline(always)]
    pub(crate) fn store(self) -> [f32; 8] {
        let mut out = [0.0; 8];
        // SAFETY: `out` is eight writable f32s (no alignment needed); AVX,
        // which the module's contract guarantees
        unsafe { _mm256_storeu_ps(out.as_mut_ptr(), self.0) };
        out
    }
    /// Into the first eight values of `out` (which must hold at least eight).
    #[inline(always)]
    pub(crate) fn store_slice(self, out: &mut [f32]) {
        let out = &mut out[..8];
        // SAFETY: `out` is eight writable f32s (no alignment needed); AVX,
        // which the module's contract guarantees
        unsafe { _mm256_storeu_ps(out.as_mut_ptr(), self.0) }
    }
    /// The IEEE square root.
    #[inline(always)]
    pub(crate) fn sqrt(self) -> F8 {
        // SAFETY: AVX, which the module's contract guarantees
        F8(unsafe { _mm256_sqrt_ps(self.0) })
    }
    /// `|self|`: the sign bit cleared.
    #[inline(always)]
    pub(crate) fn abs(self) -> F8 {
        // SAFETY: AVX, which the module's contract guarantees
        F8(unsafe { _mm256_andnot_ps(_mm256_set1_ps(-0.0), self.0) })
    }
    /// `self` where `self < b`, else `b` (so `b` when either is NaN).
    #[inline(always)]
    pub(crate) fn min(self, b: F8) -> F8 {
        // SAFETY: AVX, which the module's contract guarantees
        F8(unsafe { _mm256_min_ps(self.0, b.0) })
    }
    /// `self` where `self > b`, else `b` (so `b` when either is NaN).
    #[inline(always)]
    pub(crate) fn max(self, b: F8) -> F8 {
        // SAFETY: AVX, which the module's contract guarantees
        F8(unsafe { _mm256_max_ps(self.0, b.0) })
    }
    /// `f32::max(self, 0.0)`: 0 for NaN, as `maxps` gives its second
    /// operand then, and +0 for −0 (where `f32::max` may give either).
    #[inline(always)]
    pub(crate) fn max0(self) -> F8 {
        // SAFETY: AVX, which the module's contract guarantees
        F8(unsafe { _mm256_max_ps(self.0, _mm256_setzero_ps()) })
    }
    /// `!self & b`, by bits.
    #[inline(always)]
    pub(crate) fn andnot(self, b: F8) -> F8 {
        // SAFETY: AVX, which the module's contract guarantees
        F8(unsafe { _mm256_andnot_ps(self.0, b.0) })
    }
    /// `<`, false for NaN.
    #[inline(always)]
    pub(crate) fn lt(self, b: F8) -> F8 {
        // SAFETY: AVX, which the module's contract guarantees
        F8(unsafe { _mm256_cmp_ps::<_CMP_LT_OQ>(self.0, b.0) })
    }
    /// `>`, false for NaN.
    #[inline(always)]
    pub(crate) fn gt(self, b: F8) -> F8 {
        // SAFETY: AVX, which the module's contract guarantees
        F8(unsafe { _mm256_cmp_ps::<_CMP_GT_OQ>(self.0, b.0) })
    }
    /// `<=`, false for NaN.
    #[inline(always)]
    pub(crate) fn le(self, b: F8) -> F8 {
        // SAFETY: AVX, which the module's contract guarantees
        F8(unsafe { _mm256_cmp_ps::<_CMP_LE_OQ>(self.0, b.0) })
    }
    /// `>=`, false for NaN.
    #[inline(always)]
    pub(crate) fn ge(self, b: F8) -> F8 {
        // SAFETY: AVX, which the module's contract guarantees
        F8(unsafe { _mm256_cmp_ps::<_CMP_GE_OQ>(self.0, b.0) })
    }
    /// `==`, false for NaN.
    #[inline(always)]
    pub(crate) fn eq(self, b: F8) -> F8 {
        // SAFETY: AVX, which the module's contract guarantees
        F8(unsafe { _mm256_cmp_ps::<_CMP_EQ_OQ>(self.0, b.0) })
    }
    /// `!=`, true for NaN as in Rust.
    #[inline(always)]
    pub(crate) fn ne(self, b: F8) -> F8 {
        // SAFETY: AVX, which the module's contract guarantees
        F8(unsafe { _mm256_cmp_ps::<_CMP_NEQ_UQ>(self.0, b.0) })
    }
    /// `!(self <= b)`, true for NaN.
    #[inline(always)]
    pub(crate) fn nle(self, b: F8) -> F8 {
        // SAFETY: AVX, which the module's contract guarantees
        F8(unsafe { _mm256_cmp_ps::<_CMP_NLE_UQ>(self.0, b.0) })
    }
    /// `f32::is_finite`.
    #[inline(always)]
    pub(crate) fn finite(self) -> F8 {
        self.abs().lt(F8::splat(f32::INFINITY))
    }
    /// `if self { a } else { b }` for a mask (by each lane's sign bit).
    #[inline(always)]
    pub(crate) fn select(self, a: F8, b: F8) -> F8 {
        // SAFETY: AVX, which the module's contract guarantees
        F8(unsafe { _mm256_blendv_ps(b.0, a.0, self.0) })
    }
    /// The lanes set in a mask, as bits (lane 0 in bit 0).
    #[inline(always)]
    pub(crate) fn bits(self) -> u32 {
        // SAFETY: AVX, which the module's contract guarantees
        (unsafe { _mm256_movemask_ps(self.0) }) as u32
    }
    /// The mask of the lanes in `bits` (lane 0 in bit 0).
    #[inline(always)]
    pub(crate) fn mask(bits: u32) -> F8 {
        // SAFETY: AVX2, which the module's contract guarantees
        unsafe {
            let lane = _mm256_setr_epi32(1, 2, 4, 8, 16, 32, 64, 128);
            let set =
                _mm256_cmpeq_epi32(_mm256_and_si256(_mm256_set1_epi32(bits as i32), lane), lane);
            F8(_mm256_castsi256_ps(set))
        }
    }
}

macro_rules! binop {
    ($tr:ident, $f:ident, $op:ident) => {
        impl $tr for F8 {
            type Output = F8;
            #[inline(always)]
            fn $f(self, b: F8) -> F8 {
                // SAFETY: AVX, which the module's contract guarantees
                F8(unsafe { $op(self.0, b.0) })
            }
        }
    };
}
binop!(Add, add, _mm256_add_ps);
binop!(Sub, sub, _mm256_sub_ps);
binop!(Mul, mul, _mm256_mul_ps);
binop!(Div, div, _mm256_div_ps);
binop!(BitAnd, bitand, _mm256_and_ps);
binop!(BitOr, bitor, _mm256_or_ps);

impl Neg for F8 {
    type Output = F8;
    /// The sign bit flipped.
    #[inline(always)]
    fn neg(self) -> F8 {
        // SAFETY: AVX, which the module's contract guarantees
        F8(unsafe { _mm256_xor_ps(self.0, _mm256_set1_ps(-0.0)) })
    }
}

impl Not for F8 {
    type Output = F8;
    /// Every bit flipped (a mask's complement).
    #[inline(always)]
    fn not(self) -> F8 {
        // SAFETY: AVX, which the module's contract guarantees
        F8(unsafe { _mm256_xor_ps(self.0, _mm256_castsi256_ps(_mm256_set1_epi32(-1))) })
    }
}

#[cfg(test)]
mod tests {
    use super::F8;

    /// Values that tell the IEEE corners apart: signed zeros, infinities,
    /// NaN, subnormals.
    const X: [f32; 8] = [1.5, -0.0, f32::INFINITY, f32::NAN, 1e-40, -3.25, 0.0, 7.0];
    const Y: [f32; 8] = [2.0, 0.0, -f32::INFINITY, 1.0, f32::NAN, -3.25, -0.0, 0.5];

    /// Bit for bit, but any NaN for a NaN: Rust leaves a NaN's sign and
    /// payload unspecified (and Miri picks them at random).
    fn same(got: [f32; 8], want: [f32; 8]) {
        let bits = |v: [f32; 8]| {
            v.map(|x| {
                if x.is_nan() {
                    f32::NAN.to_bits()
                } else {
                    x.to_bits()
                }
            })
        };
        assert_eq!(bits(got), bits(want), "{got:?} against {want:?}");
    }

    fn mask(m: F8, want: [bool; 8]) {
        let bits = (0..8).fold(0, |b, i| b | (u32::from(want[i]) << i));
        assert_eq!(m.bits(), bits, "{want:?}");
        // a mask is all bits or none
        for (v, w) in m.store().iter().zip(want) {
            assert_eq!(v.to_bits(), if w { u32::MAX } else { 0 });
        }
    }

    /// The checks of [`lanes_are_the_scalar_operations`], compiled for
    /// AVX2 as [`F8`]'s contract asks.
    #[target_feature(enable = "avx2")]
    fn check() {
        let (a, b) = (F8::load(&X), F8::load_slice(&Y));
        let f = |op: fn(f32, f32) -> f32| std::array::from_fn(|k| op(X[k], Y[k]));
        let g = |op: fn(f32, f32) -> bool| std::array::from_fn(|k| op(X[k], Y[k]));
        same((a + b).store(), f(|p, q| p + q));
        same((a - b).store(), f(|p, q| p - q));
        same((a * b).store(), f(|p, q| p * q));
        same((a / b).store(), f(|p, q| p / q));
        same((-a).store(), X.map(|p| -p));
        same(a.min(b).store(), f(|p, q| if p < q { p } else { q }));
        same(a.max(b).store(), f(|p, q| if p > q { p } else { q }));
        same(a.max0().store(), X.map(|p| if p > 0.0 { p } else { 0.0 }));
        same(a.sqrt().store(), X.map(f32::sqrt));
        same(a.abs().store(), X.map(f32::abs));
        mask(a.lt(b), g(|p, q| p < q));
        mask(a.gt(b), g(|p, q| p > q));
        mask(a.le(b), g(|p, q| p <= q));
        mask(a.ge(b), g(|p, q| p >= q));
        mask(a.eq(b), g(|p, q| p == q));
        mask(a.ne(b), g(|p, q| p != q));
        mask(a.nle(b), g(|p, q| !p.le(&q)));
        mask(a.finite(), X.map(f32::is_finite));
        mask(!a.lt(b), g(|p, q| !p.lt(&q)));
        mask(a.lt(b) & a.ne(b), g(|p, q| p < q && p != q));
        mask(a.lt(b) | a.eq(b), g(|p, q| p <= q));
        mask(a.lt(b).andnot(a.ne(b)), g(|p, q| !p.lt(&q) && p != q));
        mask(
            F8::mask(0b1010_0110),
            std::array::from_fn(|k| 0b1010_0110 & (1 << k) != 0),
        );
        same(
            a.lt(b).select(a, b).store(),
            f(|p, q| if p < q { p } else { q }),
        );
        same(F8::splat(-2.5).store(), [-2.5; 8]);
        let mut out = [9.0; 10];
        a.store_slice(&mut out[1..]);
        same(out[1..9].try_into().unwrap(), X);
        assert_eq!([out[0], out[9]], [9.0, 9.0]);
    }

    /// Every operation is the scalar one lane by lane, bit for bit (with
    /// SSE's rule for min and max), and masks are all bits or none.
    #[test]
    fn lanes_are_the_scalar_operations() {
        if !super::super::has_v3() {
            eprintln!("no AVX2: F8 is not used here");
            return;
        }
        // SAFETY: the CPU has AVX2 (has_v3 just said so)
        unsafe { check() }
    }
}
