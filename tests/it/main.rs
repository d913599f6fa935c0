//! The integration tests, in one crate so that the suite links once (the
//! kalos library and its dependencies are large; 12 test crates linked 12
//! times on a 2-core machine).
//!
//! `methods.rs` is the method × scene table: furnace, longest path and
//! determinism for every method of `kalos::methods::all()`;
//! `reference.rs` iterates the same table against the Mitsuba references.
//!
//! Two tiers. `cargo test --release` runs the quick one; the statistical
//! renders and the long runs carry
//! `#[ignore = "slow tier: cargo test --release -- --ignored"]`, and that
//! command runs them alone (CI runs both). `#[ignore]` means the slow tier
//! and nothing else: a test that needs what CI lacks must skip itself by
//! another check, or `--ignored` would run it there.

#![allow(clippy::disallowed_methods)] // std::fs is denied only in the scene loaders (clippy.toml)
mod common;

mod bsdf;
mod bundle;
mod camera_pass;
mod cli;
mod density;
mod density_smooth;
mod driver;
mod env;
mod farm;
mod fuzz;
mod fuzz_found;
mod geometry;
mod glb;
mod gltf_brdf;
mod gltf_glass;
mod gltf_normalmap;
mod image_io;
mod lightmap;
mod lightmap_gather;
mod lightmap_glb;
mod lightmap_seams;
mod lightmap_uv;
mod lights;
mod loader;
mod loader_limits;
mod methods;
mod pbrt;
mod plb;
mod punctual;
mod reference;
mod replay;
mod sampler;
mod transport;
mod untrusted;
mod untrusted_mp;
mod view;
