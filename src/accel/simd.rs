//! Four f32 lanes for the traversal kernels: SSE2 on x86_64 (always present
//! there), plain arrays elsewhere. Both give the same results lane for lane,
//! including with NaN: `max(a, b)` and `min(a, b)` return `b` when either is
//! NaN, as SSE's `maxps`/`minps` do. The box test relies on that to ignore
//! the NaN that `0 · ∞` gives for a ray lying in a slab's plane.

#[cfg(target_arch = "x86_64")]
mod imp {
    //! Every `unsafe` block here calls an SSE2 intrinsic, which x86_64
    //! guarantees, on values (the loads and stores say what they touch).
    use std::arch::x86_64::*;

    /// Four f32 lanes.
    #[derive(Clone, Copy)]
    pub struct F4(__m128);

    /// A lane mask from a comparison of [`F4`]s.
    #[derive(Clone, Copy)]
    pub struct M4(__m128);

    impl F4 {
        #[inline(always)]
        pub fn splat(x: f32) -> F4 {
            F4(unsafe { _mm_set1_ps(x) })
        }
        #[inline(always)]
        pub fn load(a: &[f32; 4]) -> F4 {
            // SAFETY: `a` is four readable f32s; the load needs no alignment.
            F4(unsafe { _mm_loadu_ps(a.as_ptr()) })
        }
        #[inline(always)]
        pub fn to_array(self) -> [f32; 4] {
            let mut out = [0.0; 4];
            // SAFETY: `out` is four writable f32s; the store needs no alignment.
            unsafe { _mm_storeu_ps(out.as_mut_ptr(), self.0) };
            out
        }
        #[inline(always)]
        pub fn add(self, b: F4) -> F4 {
            F4(unsafe { _mm_add_ps(self.0, b.0) })
        }
        #[inline(always)]
        pub fn sub(self, b: F4) -> F4 {
            F4(unsafe { _mm_sub_ps(self.0, b.0) })
        }
        #[inline(always)]
        pub fn mul(self, b: F4) -> F4 {
            F4(unsafe { _mm_mul_ps(self.0, b.0) })
        }
        #[inline(always)]
        pub fn div(self, b: F4) -> F4 {
            F4(unsafe { _mm_div_ps(self.0, b.0) })
        }
        /// `self` where `self < b`, else `b` (so `b` when either is NaN).
        #[inline(always)]
        pub fn min(self, b: F4) -> F4 {
            F4(unsafe { _mm_min_ps(self.0, b.0) })
        }
        /// `self` where `self > b`, else `b` (so `b` when either is NaN).
        #[inline(always)]
        pub fn max(self, b: F4) -> F4 {
            F4(unsafe { _mm_max_ps(self.0, b.0) })
        }
        #[inline(always)]
        pub fn le(self, b: F4) -> M4 {
            M4(unsafe { _mm_cmple_ps(self.0, b.0) })
        }
        #[inline(always)]
        pub fn lt(self, b: F4) -> M4 {
            M4(unsafe { _mm_cmplt_ps(self.0, b.0) })
        }
        #[inline(always)]
        pub fn ge(self, b: F4) -> M4 {
            M4(unsafe { _mm_cmpge_ps(self.0, b.0) })
        }
        #[inline(always)]
        pub fn ne(self, b: F4) -> M4 {
            M4(unsafe { _mm_cmpneq_ps(self.0, b.0) })
        }
    }

    impl M4 {
        #[inline(always)]
        pub fn and(self, b: M4) -> M4 {
            M4(unsafe { _mm_and_ps(self.0, b.0) })
        }
        /// One bit per lane, lane 0 in bit 0.
        #[inline(always)]
        pub fn bits(self) -> u32 {
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
        #[inline(always)]
        pub fn splat(x: f32) -> F4 {
            F4([x; 4])
        }
        #[inline(always)]
        pub fn load(a: &[f32; 4]) -> F4 {
            F4(*a)
        }
        #[inline(always)]
        pub fn to_array(self) -> [f32; 4] {
            self.0
        }
        #[inline(always)]
        pub fn add(self, b: F4) -> F4 {
            map(self, b, |x, y| x + y)
        }
        #[inline(always)]
        pub fn sub(self, b: F4) -> F4 {
            map(self, b, |x, y| x - y)
        }
        #[inline(always)]
        pub fn mul(self, b: F4) -> F4 {
            map(self, b, |x, y| x * y)
        }
        #[inline(always)]
        pub fn div(self, b: F4) -> F4 {
            map(self, b, |x, y| x / y)
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
        #[inline(always)]
        pub fn le(self, b: F4) -> M4 {
            cmp(self, b, |x, y| x <= y)
        }
        #[inline(always)]
        pub fn lt(self, b: F4) -> M4 {
            cmp(self, b, |x, y| x < y)
        }
        #[inline(always)]
        pub fn ge(self, b: F4) -> M4 {
            cmp(self, b, |x, y| x >= y)
        }
        #[inline(always)]
        pub fn ne(self, b: F4) -> M4 {
            cmp(self, b, |x, y| x != y)
        }
    }

    impl M4 {
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

pub(super) use imp::F4;
