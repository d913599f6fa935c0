//! The method contract: what every method's `Settings` answers for the
//! rest of kalos, so that only the method table ([`super::MethodConfig`]
//! and [`super::all`]) knows which methods there are. `partial` (shards,
//! checkpoints, merges), `render` (the memory check) and the command line
//! ask [`super::MethodConfig`], which hands each question to the method's
//! [`MethodSettings`]; none of them names a method.
//!
//! Every function of the trait is required, so that a new method's
//! `impl MethodSettings` is refused by the compiler until it answers each
//! question, as is the variant it adds to [`super::MethodConfig`] until
//! the dispatch in `methods/mod.rs` has its arm.

use std::mem::size_of;

use glam::{DVec3, Vec3};

use super::{Common, Method, MethodError};
use crate::film::Image;
use crate::memory::MemoryItem;
use crate::state::{ShardKind, State};
use crate::world::World;

/// What a method's `Settings` answers for the table (see the module docs).
pub trait MethodSettings {
    /// Rejects settings that cannot work, naming the flag.
    fn validate(&self) -> Result<(), MethodError>;

    /// How the method is split into shards ([`ShardKind::Exact`] or
    /// [`ShardKind::Chains`], see [`crate::partial`]), or why it cannot
    /// be, in a sentence that names the method.
    fn shard_kind(&self) -> Result<ShardKind, MethodError>;

    /// Checks that the method can be split into `count` shards of the
    /// kind [`MethodSettings::shard_kind`] gives (light: one lane at
    /// least per shard). Called only when the method shards at all.
    fn check_shard_count(&self, count: u32) -> Result<(), MethodError>;

    /// Whether the method can write checkpoints and resume from them
    /// exactly; when not, why not (one clause: "its population of photon
    /// hits is not saved").
    fn resumable(&self) -> Result<(), &'static str>;

    /// The image of a render split exactly ([`ShardKind::Exact`]) from the
    /// states of all its shards, in shard order, for a `width` × `height`
    /// film: the bytes of one run with the same passes. A method that does
    /// not split exactly answers [`no_exact_merge`].
    fn merge_exact(&self, states: &[&State], width: u32, height: u32)
        -> Result<Image, MethodError>;

    /// The large allocations that rendering a `width` × `height` film
    /// makes, before any of them is made (see
    /// [`crate::render::memory_estimate`]): the film item first
    /// ([`film_item`]), then the method's own big structures.
    fn memory(&self, width: u32, height: u32) -> Vec<MemoryItem>;

    /// Builds the method with the shared settings `common` (seed, longest
    /// path) in force, after the settings were checked. Cheap: the work
    /// that needs the world runs in [`Method::prepare`].
    fn create(&self, world: &World, common: &Common) -> Box<dyn Method>;
}

/// The answer of [`MethodSettings::merge_exact`] for a method that does
/// not split exactly.
pub fn no_exact_merge(name: &str) -> MethodError {
    MethodError(format!("method '{name}' has no exact merge"))
}

/// Bytes per pixel of a film: one f64 RGB sum.
pub const FILM: u64 = size_of::<DVec3>() as u64;

/// Bytes per pixel of the f32 image a method returns.
pub const IMAGE: u64 = size_of::<Vec3>() as u64;

/// Bytes per pixel of the camera pass when it is `on`: its per-pixel sum,
/// its mask, and the pre-pass's (mask, rays) pairs collected before the
/// mask is kept.
pub fn camera_pass(on: bool) -> u64 {
    if on {
        FILM + (size_of::<bool>() + size_of::<(bool, u64)>()) as u64
    } else {
        0
    }
}

/// The per-pixel buffers of a `width` × `height` render, at `per_pixel`
/// bytes a pixel; `detail` follows the size in the text (" (8 lanes)").
pub fn film_item(width: u32, height: u32, per_pixel: u64, detail: &str) -> MemoryItem {
    let pixels = u64::from(width) * u64::from(height);
    MemoryItem {
        what: format!("the film {width}×{height}{detail}"),
        bytes: pixels.saturating_mul(per_pixel),
        remedy: "lower --res",
    }
}
