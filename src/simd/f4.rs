//! Four f32 lanes: SSE2 on x86_64 (always present there), plain arrays
//! elsewhere. Both give the same results lane for lane, including with NaN:
//! `max(a, b)` and `min(a, b)` return `b` when either is NaN, as SSE's
//! `maxps`/`minps` do. The ray core's box test relies on that to ignore the
//! NaN that `0 · ∞` gives for a ray lying in a slab's plane.

#[cfg(target_arch = "x86_64")]
mod imp {
    //! SSE2 is part of the x86_64 baseline, so every CPU that runs this
    //! code has the instructions these wrappers call.
    use std::arch::x86_64::*;

    /// Four f32 lanes.
    #[derive(Clone, Copy)]
    pub struct F4(__m128);

    /// A lane mask from a comparison of [`F4`]s (all bits set where true).
    #[derive(Clone, Copy)]
    pub struct M4(__m128);

    impl F4 {
        /// `x` in every lane.
        #[inline(always)]
        pub fn splat(x: f32) -> F4 {
            // SAFETY: SSE2, which every x86_64 CPU has
            F4(unsafe { _mm_set1_ps(x) })
        }
        /// The four values of `a`.
        #[inline(always)]
        pub fn load(a: &[f32; 4]) -> F4 {
            // SAFETY: `a` is four readable f32s; the load needs no alignment.
            F4(unsafe { _mm_loadu_ps(a.as_ptr()) })
        }
        /// The first four values of `a` (which must hold at least four).
        #[inline(always)]
        pub fn load_slice(a: &[f32]) -> F4 {
            let a = &a[..4];
            // SAFETY: `a` is four readable f32s; the load needs no alignment.
            F4(unsafe { _mm_loadu_ps(a.as_ptr()) })
        }
        /// The four lanes, lane 0 first.
        #[inline(always)]
        pub fn to_array(self) -> [f32; 4] {
            let mut out = [0.0; 4];
            // SAFETY: `out` is four writable f32s; the store needs no alignment.
            unsafe { _mm_storeu_ps(out.as_mut_ptr(), self.0) };
            out
        }
        /// Into the first four values of `out` (which must hold at least four).
        #[inline(always)]
        pub fn store_slice(self, out: &mut [f32]) {
            let out = &mut out[..4];
            // SAFETY: `out` is four writable f32s; the store needs no alignment.
            unsafe { _mm_storeu_ps(out.as_mut_ptr(), self.0) }
        }
        /// `self + b`.
        #[inline(always)]
        pub fn add(self, b: F4) -> F4 {
            // SAFETY: SSE2, which every x86_64 CPU has
            F4(unsafe { _mm_add_ps(self.0, b.0) })
        }
        /// `self − b`.
        #[inline(always)]
        pub fn sub(self, b: F4) -> F4 {
            // SAFETY: SSE2, which every x86_64 CPU has
            F4(unsafe { _mm_sub_ps(self.0, b.0) })
        }
        /// `self · b`.
        #[inline(always)]
        pub fn mul(self, b: F4) -> F4 {
            // SAFETY: SSE2, which every x86_64 CPU has
            F4(unsafe { _mm_mul_ps(self.0, b.0) })
        }
        /// `self / b`.
        #[inline(always)]
        pub fn div(self, b: F4) -> F4 {
            // SAFETY: SSE2, which every x86_64 CPU has
            F4(unsafe { _mm_div_ps(self.0, b.0) })
        }
        /// The IEEE square root.
        #[inline(always)]
        pub fn sqrt(self) -> F4 {
            // SAFETY: SSE2, which every x86_64 CPU has
            F4(unsafe { _mm_sqrt_ps(self.0) })
        }
        /// `|self|`: the sign bit cleared.
        #[inline(always)]
        pub fn abs(self) -> F4 {
            // SAFETY: SSE2, which every x86_64 CPU has
            F4(unsafe { _mm_andnot_ps(_mm_set1_ps(-0.0), self.0) })
        }
        /// `self` where `self < b`, else `b` (so `b` when either is NaN).
        #[inline(always)]
        pub fn min(self, b: F4) -> F4 {
            // SAFETY: SSE2, which every x86_64 CPU has
            F4(unsafe { _mm_min_ps(self.0, b.0) })
        }
        /// `self` where `self > b`, else `b` (so `b` when either is NaN).
        #[inline(always)]
        pub fn max(self, b: F4) -> F4 {
            // SAFETY: SSE2, which every x86_64 CPU has
            F4(unsafe { _mm_max_ps(self.0, b.0) })
        }
        /// `self <= b`.
        #[inline(always)]
        pub fn le(self, b: F4) -> M4 {
            // SAFETY: SSE2, which every x86_64 CPU has
            M4(unsafe { _mm_cmple_ps(self.0, b.0) })
        }
        /// `self < b`.
        #[inline(always)]
        pub fn lt(self, b: F4) -> M4 {
            // SAFETY: SSE2, which every x86_64 CPU has
            M4(unsafe { _mm_cmplt_ps(self.0, b.0) })
        }
        /// `self >= b`.
        #[inline(always)]
        pub fn ge(self, b: F4) -> M4 {
            // SAFETY: SSE2, which every x86_64 CPU has
            M4(unsafe { _mm_cmpge_ps(self.0, b.0) })
        }
        /// `self != b` (true for NaN, as in Rust).
        #[inline(always)]
        pub fn ne(self, b: F4) -> M4 {
            // SAFETY: SSE2, which every x86_64 CPU has
            M4(unsafe { _mm_cmpneq_ps(self.0, b.0) })
        }
        /// `a` in the lanes where `m` is set, `b` elsewhere (by bits:
        /// (m ∧ a) ∨ (¬m ∧ b)).
        #[inline(always)]
        pub fn select(m: M4, a: F4, b: F4) -> F4 {
            // SAFETY: SSE2, which every x86_64 CPU has
            F4(unsafe { _mm_or_ps(_mm_and_ps(m.0, a.0), _mm_andnot_ps(m.0, b.0)) })
        }
    }

    impl M4 {
        /// The lanes set in both.
        #[inline(always)]
        pub fn and(self, b: M4) -> M4 {
            // SAFETY: SSE2, which every x86_64 CPU has
            M4(unsafe { _mm_and_ps(self.0, b.0) })
        }
        /// One bit per lane, lane 0 in bit 0.
        #[inline(always)]
        pub fn bits(self) -> u32 {
            // SAFETY: SSE2, which every x86_64 CPU has
            (unsafe { _mm_movemask_ps(self.0) }) as u32
        }
    }
}

#[cfg(not(target_arch = "x86_64"))]
mod imp {
    /// Four f32 lanes.
    #[derive(Clone, Copy)]
    pub struct F4([f32; 4]);

    /// A lane mask from a comparison of [`F4`]s.
    #[derive(Clone, Copy)]
    pub struct M4([bool; 4]);

    #[inline(always)]
    fn map(a: F4, b: F4, f: impl Fn(f32, f32) -> f32) -> F4 {
        F4(std::array::from_fn(|i| f(a.0[i], b.0[i])))
    }

    #[inline(always)]
    fn cmp(a: F4, b: F4, f: impl Fn(f32, f32) -> bool) -> M4 {
        M4(std::array::from_fn(|i| f(a.0[i], b.0[i])))
    }

    impl F4 {
        /// `x` in every lane.
        #[inline(always)]
        pub fn splat(x: f32) -> F4 {
            F4([x; 4])
        }
        /// The four values of `a`.
        #[inline(always)]
        pub fn load(a: &[f32; 4]) -> F4 {
            F4(*a)
        }
        /// The first four values of `a` (which must hold at least four).
        #[inline(always)]
        pub fn load_slice(a: &[f32]) -> F4 {
            F4(std::array::from_fn(|i| a[i]))
        }
        /// The four lanes, lane 0 first.
        #[inline(always)]
        pub fn to_array(self) -> [f32; 4] {
            self.0
        }
        /// Into the first four values of `out` (which must hold at least four).
        #[inline(always)]
        pub fn store_slice(self, out: &mut [f32]) {
            out[..4].copy_from_slice(&self.0);
        }
        /// `self + b`.
        #[inline(always)]
        pub fn add(self, b: F4) -> F4 {
            map(self, b, |x, y| x + y)
        }
        /// `self − b`.
        #[inline(always)]
        pub fn sub(self, b: F4) -> F4 {
            map(self, b, |x, y| x - y)
        }
        /// `self · b`.
        #[inline(always)]
        pub fn mul(self, b: F4) -> F4 {
            map(self, b, |x, y| x * y)
        }
        /// `self / b`.
        #[inline(always)]
        pub fn div(self, b: F4) -> F4 {
            map(self, b, |x, y| x / y)
        }
        /// The IEEE square root.
        #[inline(always)]
        pub fn sqrt(self) -> F4 {
            F4(self.0.map(f32::sqrt))
        }
        /// `|self|`: the sign bit cleared.
        #[inline(always)]
        pub fn abs(self) -> F4 {
            F4(self.0.map(f32::abs))
        }
        /// `self` where `self < b`, else `b` (so `b` when either is NaN).
        #[inline(always)]
        pub fn min(self, b: F4) -> F4 {
            map(self, b, |x, y| if x < y { x } else { y })
        }
        /// `self` where `self > b`, else `b` (so `b` when either is NaN).
        #[inline(always)]
        pub fn max(self, b: F4) -> F4 {
            map(self, b, |x, y| if x > y { x } else { y })
        }
        /// `self <= b`.
        #[inline(always)]
        pub fn le(self, b: F4) -> M4 {
            cmp(self, b, |x, y| x <= y)
        }
        /// `self < b`.
        #[inline(always)]
        pub fn lt(self, b: F4) -> M4 {
            cmp(self, b, |x, y| x < y)
        }
        /// `self >= b`.
        #[inline(always)]
        pub fn ge(self, b: F4) -> M4 {
            cmp(self, b, |x, y| x >= y)
        }
        /// `self != b` (true for NaN, as in Rust).
        #[inline(always)]
        pub fn ne(self, b: F4) -> M4 {
            cmp(self, b, |x, y| x != y)
        }
        /// `a` in the lanes where `m` is set, `b` elsewhere.
        #[inline(always)]
        pub fn select(m: M4, a: F4, b: F4) -> F4 {
            F4(std::array::from_fn(
                |i| if m.0[i] { a.0[i] } else { b.0[i] },
            ))
        }
    }

    impl M4 {
        /// The lanes set in both.
        #[inline(always)]
        pub fn and(self, b: M4) -> M4 {
            M4(std::array::from_fn(|i| self.0[i] && b.0[i]))
        }
        /// One bit per lane, lane 0 in bit 0.
        #[inline(always)]
        pub fn bits(self) -> u32 {
            (0..4).fold(0, |m, i| m | (u32::from(self.0[i]) << i))
        }
    }
}

pub(crate) use imp::{F4, M4};

#[cfg(test)]
mod tests {
    use super::{F4, M4};

    /// Values that tell the IEEE corners apart: signed zeros, infinities,
    /// NaN, subnormals.
    const X: [f32; 8] = [1.5, -0.0, f32::INFINITY, f32::NAN, 1e-40, -3.25, 0.0, 7.0];
    const Y: [f32; 8] = [2.0, 0.0, -f32::INFINITY, 1.0, f32::NAN, -3.25, -0.0, 0.5];

    fn lanes(i: usize) -> (F4, F4, [f32; 4], [f32; 4]) {
        let x: [f32; 4] = X[i..i + 4].try_into().unwrap();
        let y: [f32; 4] = Y[i..i + 4].try_into().unwrap();
        (F4::load(&x), F4::load_slice(&Y[i..]), x, y)
    }

    /// Bit for bit, but any NaN for a NaN: Rust leaves a NaN's sign and
    /// payload unspecified (and Miri picks them at random).
    fn same(got: [f32; 4], want: [f32; 4]) {
        let bits = |v: [f32; 4]| {
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

    fn mask(m: M4, want: [bool; 4]) {
        let bits = (0..4).fold(0, |b, i| b | (u32::from(want[i]) << i));
        assert_eq!(m.bits(), bits, "{want:?}");
    }

    /// Every operation is the scalar one lane by lane, bit for bit, with
    /// SSE's rule for min and max (the second operand when either is NaN).
    #[test]
    fn lanes_are_the_scalar_operations() {
        for i in 0..=4 {
            let (a, b, x, y) = (lanes(i).0, lanes(i).1, lanes(i).2, lanes(i).3);
            let f = |op: fn(f32, f32) -> f32| std::array::from_fn(|k| op(x[k], y[k]));
            same(a.add(b).to_array(), f(|p, q| p + q));
            same(a.sub(b).to_array(), f(|p, q| p - q));
            same(a.mul(b).to_array(), f(|p, q| p * q));
            same(a.div(b).to_array(), f(|p, q| p / q));
            same(a.min(b).to_array(), f(|p, q| if p < q { p } else { q }));
            same(a.max(b).to_array(), f(|p, q| if p > q { p } else { q }));
            same(a.sqrt().to_array(), x.map(f32::sqrt));
            same(a.abs().to_array(), x.map(f32::abs));
            same(F4::splat(x[0]).to_array(), [x[0]; 4]);
            let g = |op: fn(f32, f32) -> bool| std::array::from_fn(|k| op(x[k], y[k]));
            mask(a.le(b), g(|p, q| p <= q));
            mask(a.lt(b), g(|p, q| p < q));
            mask(a.ge(b), g(|p, q| p >= q));
            mask(a.ne(b), g(|p, q| p != q));
            mask(a.le(b).and(a.ne(b)), g(|p, q| p < q));
            let pick = F4::select(a.lt(b), a, b).to_array();
            same(pick, f(|p, q| if p < q { p } else { q }));
            let mut out = [9.0; 6];
            a.store_slice(&mut out[1..]);
            same(out[1..5].try_into().unwrap(), x);
            assert_eq!([out[0], out[5]], [9.0, 9.0]);
        }
    }
}
