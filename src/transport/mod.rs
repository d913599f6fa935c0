//! Transport: what every method shares, so that no method imports another.
//!
//! - [`Vertex`] ([`World::vertex`]): a surface hit made ready for scattering:
//!   the BSDF, the shading frame and geometric normal oriented for
//!   two-sided materials ([`orient`]), and `wo`.
//! - [`scatter`]: the next direction of a light path, in importance mode,
//!   with the shading-normal correction.
//! - [`connect_to_camera`], [`connect_emission`],
//!   [`connect_emission_sample`]: the camera connections of light paths,
//!   with the pixel weight g(x) of §2 of the light-path-building paper
//!   ([`connect_then`] and [`emission_to_camera`]: the contribution and
//!   its pixel, told before the visibility ray, to prefetch the film).
//! - [`light_tracing_walk`]: `light`'s walk, an emission sample and a
//!   [`light_walk`] joined to the camera at every non-delta vertex.
//! - [`follow_delta_chain`]: power carried through mirrors and glass to the
//!   first surface that can be measured, with a named depth limit
//!   ([`DELTA_CHAIN_DEPTH_LIMIT`]).
//! - [`light_walk`]: the one light-path walk (Russian roulette on the
//!   albedo or the throughput, [`Roulette`]), with a per-vertex hook; `light`, `density` and the diagnostics
//!   put their own measurement in the hook. [`LightWalk::step`] is its loop
//!   body, for the lanes.
//! - [`direct_light`], [`shadow_clear`]: next-event estimation alone (one
//!   light sample, no MIS), for bundle's first shot.
//! - [`radiance_from`]: the camera-side estimator (next-event estimation
//!   with MIS), which `path` is and the camera pass uses.
//! - [`lanes`]: that estimator for eight of `path`'s camera paths at a
//!   time, bounce by bounce, the common vertex shaded in AVX lanes and the
//!   rest by the same step ([`CameraPath::scatter`]) lane by lane; and
//!   eight of `light`'s Sobol walks at a time, likewise
//!   ([`lanes::light_walks`]); and the camera pass's paths after their
//!   first vertex ([`lanes::radiance_continued`]). [`lanes::camera_row`]
//!   is the row loop of one sample per pixel that `path` runs, and plb's
//!   mixture for its path estimate.
//! - [`camera_pass`]: the part of path space that light paths cannot reach,
//!   estimated from the camera for `light` and `plb`.
//!
//! Depths follow Mitsuba's `max_depth` everywhere: a path of depth 1 is an
//! emitter seen directly, depth 2 adds direct lighting. A camera path counts
//! its segments from the eye; a light path of k segments, joined to the eye
//! by a camera connection (or by the density method's view pass), makes a
//! path of k + 1 segments, so its vertices contribute only while k <
//! `max_depth`.
//!
//! Transport reads the [`World`] and the layers below it, never a method:
//! the data flow of DESIGN.md goes one way.

pub mod camera_pass;
mod connect;
mod direct;
pub mod dispatch;
pub mod lanes;
mod radiance;
mod vertex;
mod walk;

pub use connect::{
    connect_emission, connect_emission_sample, connect_then, connect_to_camera,
    emission_sample_to_camera, emission_to_camera, light_tracing_walk, splat_to_camera,
};
pub use direct::{direct_light, shadow_clear};
pub use radiance::{radiance_from, radiance_from_hit, CameraPath, DepthLimits};
pub use vertex::{orient, scatter, Shading, Vertex};
pub use walk::{
    follow_delta_chain, light_walk, Landing, LightVertex, LightWalk, Roulette, Spectrum, WalkKind,
    DELTA_CHAIN_DEPTH_LIMIT,
};

#[cfg(doc)]
use crate::world::World;
