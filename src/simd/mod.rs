//! The one place where kalos wraps the CPU's vector instructions, on the
//! ground floor so that every layer above may use it without reaching into
//! another (the light tree, bundle's projection and `path`'s lanes once
//! took the CPU detection from `transport`).
//!
//! - [`dispatch`]: whether the CPU has x86-64-v3 (AVX2, FMA...), and the
//!   `dispatched!` macro that compiles a loop twice and picks the copy at
//!   run time.
//! - `F4` and `M4` (`f4.rs`): four f32 lanes in SSE2, which every x86_64
//!   has (plain arrays elsewhere), for the ray core's box tests and the
//!   light tree's importances.
//! - `F8` (`avx8.rs`): eight f32 lanes in AVX, for the code compiled for
//!   AVX2 and run where [`dispatch::has_v3`] says yes.
//! - `transpose8` (`transpose.rs`): the 8 × 8 transpose that loads records
//!   by field.
//! - `prefetch` (`prefetch.rs`): the cache hint.
//!
//! Every wrapper runs the one instruction its name says, so code written
//! with them rounds exactly as the scalar code it mirrors does.

pub mod dispatch;
pub(crate) mod f4;
mod prefetch;

#[cfg(target_arch = "x86_64")]
pub(crate) mod avx8;
#[cfg(target_arch = "x86_64")]
mod transpose;

pub(crate) use dispatch::dispatched;
pub use dispatch::has_v3;
pub(crate) use f4::{F4, M4};
pub(crate) use prefetch::prefetch;

#[cfg(target_arch = "x86_64")]
pub(crate) use avx8::F8;
#[cfg(target_arch = "x86_64")]
pub(crate) use transpose::transpose8;
