//! kalos: a global-illumination renderer and light baker built on three
//! papers: density-estimation global illumination (Shirley et al. 1995),
//! stochastic iteration (Szirmay-Kalos 1999) and progressive light path
//! building (Szirmay-Kalos et al.), with a reference path tracer to judge
//! them.
#![warn(missing_docs)]
#![deny(clippy::undocumented_unsafe_blocks)]
// std::fs is denied only in the scene loaders (see clippy.toml)
#![allow(clippy::disallowed_methods)]

pub mod accel;
pub mod bake;
pub mod bench;
pub mod bsdf;
pub mod camera;
pub mod color;
pub mod emitter;
pub mod film;
pub mod geometry;
pub mod image_io;
pub mod job;
pub mod memory;
pub mod methods;
pub mod metrics;
pub mod outputs;
pub mod partial;
#[cfg(feature = "cli")]
pub mod plot;
pub mod render;
pub mod sampling;
pub mod scene;
pub mod scenegen;
pub mod simd;
pub mod state;
pub mod transport;
pub mod world;
