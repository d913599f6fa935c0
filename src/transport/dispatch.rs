//! Runtime dispatch to the x86-64-v3 copies of the hot loops: now in
//! [`crate::simd::dispatch`], on the ground floor with the other vector
//! code; [`has_v3`] is re-exported here for the code that names it by this
//! path.

pub use crate::simd::dispatch::has_v3;
