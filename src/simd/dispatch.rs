//! Runtime dispatch of the hot per-pass loops to a copy compiled for
//! x86-64-v3 (AVX2, FMA, BMI1/2, LZCNT, POPCNT) when the running CPU has
//! those features, and to the baseline x86-64 copy otherwise.
//!
//! The default build targets baseline x86-64 so that it runs on any x86-64
//! machine. `dispatched!` compiles one loop body twice: once plain and once
//! inside a `#[target_feature]` function, which gives VEX encodings and
//! SSE4.1 rounding to everything inlined into it. Code that the body calls
//! without inlining it stays baseline, which is why the shading functions
//! the loops reach are marked `#[inline(always)]` or `#[inline]`.
//!
//! Images do not depend on the copy that runs: Rust never contracts
//! `a * b + c` into a fused multiply-add unless the code asks for
//! `mul_add`, so both copies round every operation alike.
//! `KALOS_DISPATCH=baseline` in the environment forces the baseline copies,
//! so that one binary can compare the two.

use std::sync::atomic::{AtomicU8, Ordering};

/// [`has_v3`]'s answer: 0 not yet detected, 1 no, 2 yes.
static V3: AtomicU8 = AtomicU8::new(0);

/// Whether the x86-64-v3 copies may run on this CPU: detected once, then
/// one load, since a dispatched function may be called once per vertex.
#[inline]
pub fn has_v3() -> bool {
    match V3.load(Ordering::Relaxed) {
        0 => {
            let yes = detect_v3();
            V3.store(1 + u8::from(yes), Ordering::Relaxed);
            yes
        }
        v => v == 2,
    }
}

#[cold]
fn detect_v3() -> bool {
    // For benchmarks: the same binary with and without the x86-64-v3 copies
    if std::env::var_os("KALOS_DISPATCH").is_some_and(|v| v == "baseline") {
        return false;
    }
    #[cfg(target_arch = "x86_64")]
    {
        std::arch::is_x86_feature_detected!("avx2")
            && std::arch::is_x86_feature_detected!("fma")
            && std::arch::is_x86_feature_detected!("bmi1")
            && std::arch::is_x86_feature_detected!("bmi2")
            && std::arch::is_x86_feature_detected!("lzcnt")
            && std::arch::is_x86_feature_detected!("popcnt")
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        false
    }
}

/// Defines `fn NAME(ARGS) -> RET { BODY }` whose body is compiled twice,
/// baseline and x86-64-v3, and which runs the x86-64-v3 copy when
/// [`has_v3`] says the CPU can. The arguments must be plain identifiers.
macro_rules! dispatched {
    (
        $(#[$attr:meta])*
        $vis:vis fn $name:ident($($arg:ident: $ty:ty),* $(,)?) -> $ret:ty $body:block
    ) => {
        $(#[$attr])*
        $vis fn $name($($arg: $ty),*) -> $ret {
            #[inline(always)]
            fn body($($arg: $ty),*) -> $ret $body

            #[cfg(target_arch = "x86_64")]
            #[target_feature(enable = "avx2,fma,bmi1,bmi2,lzcnt,popcnt")]
            fn body_v3($($arg: $ty),*) -> $ret {
                body($($arg),*)
            }

            #[cfg(target_arch = "x86_64")]
            if $crate::simd::dispatch::has_v3() {
                // SAFETY: the CPU has every feature body_v3 is compiled for
                // (checked by has_v3 just above).
                return unsafe { body_v3($($arg),*) };
            }
            body($($arg),*)
        }
    };
}

pub(crate) use dispatched;
