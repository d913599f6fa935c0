//! Partial results: a render's state (film sums, counts, settings, the
//! scene's hash) that can be written, merged and resumed. One mechanism
//! gives shards on a farm (`kalos render --shard K/N`, `kalos merge`) and
//! checkpoints (`--checkpoint`, `--resume`).
//!
//! This module knows no method: each method's settings answer, through the
//! method contract ([`crate::methods::MethodSettings`], asked through
//! [`MethodConfig`]), how the method is split into shards
//! ([`MethodConfig::shard_kind`], [`MethodConfig::check_shard`]), whether
//! it resumes from checkpoints ([`MethodConfig::check_resumable`]) and how
//! the states of an exact split merge into its image
//! ([`MethodConfig::merge_exact`]); the average of chains is the same for
//! every method and lives here. A partial result's header holds the
//! [`MethodConfig`] itself, as one line of JSON that reads back into the
//! equal value (see [`write`]). The types a method fills ([`Shard`],
//! [`State`]) live below the methods, in [`crate::state`], and are
//! re-exported here.
//!
//! How the methods are split into shards today ([`ShardKind`]):
//!
//! - **Exact** (`path`, `light`): a shard owns a fixed part of the random
//!   streams for *every* pass: `path` the pixel rows y ≡ K (mod N) (its
//!   streams are keyed by (seed, pass, pixel)), `light` the lanes
//!   l ≡ K (mod N) (keyed by (seed, pass, lane)) and, for its camera pass,
//!   the rows y ≡ K (mod N). Each pixel sum or lane film is therefore
//!   accumulated in the same order, from the same streams, as in one run,
//!   and the merge combines them in the order of one run: the merged image
//!   has exactly the bytes of one run with the same passes. Splitting by
//!   pass instead would change the order of the floating-point sums (and
//!   would break light's iteration chains, which carry a point from one
//!   pass to the next), so the bytes could differ.
//! - **Chains** (`plb`, `bundle`): a shard is an independent run of the
//!   method with its own seed ([`shard_seed`]; shard 0 keeps the render's
//!   seed), and the merge is the average of the shards' images weighted by
//!   their samples per pixel. Each chain is a consistent estimator of the
//!   same image (plb's population and bundle's iteration converge to it
//!   whatever the seed), and the chains are independent, so their average
//!   converges to it too, with the variance of one chain divided by N;
//!   a start-up transient (bundle's first iterations) is paid once per
//!   chain, as `--discard` documents.
//! - **Refused** (`density`): averaging N particle sets keeps the kernel
//!   blur of one set (the kernel's width follows the particle count of one
//!   shard), so the merged image would not converge to that of N times
//!   the particles. More particles come from tracing them on more workers
//!   (the density pipeline, `kalos bake`).

mod format;
mod merge;

pub use format::{read, write};
pub use merge::merge;

use std::fmt;
use std::path::PathBuf;

pub use crate::state::{shard_seed, Shard, ShardKind, State, StateError};

use crate::methods::{Common, MethodConfig, MethodError};
use crate::scene::Scene;

/// How `method` is split into shards, or why it cannot be: the method's
/// own answer ([`MethodConfig::shard_kind`]).
pub fn shard_kind(method: &MethodConfig) -> Result<ShardKind, MethodError> {
    method.shard_kind()
}

/// Checks before any work that `method` can be split into `shard.count`
/// shards, and says how ([`MethodConfig::check_shard`]).
pub fn check_shard(method: &MethodConfig, shard: Shard) -> Result<ShardKind, MethodError> {
    method.check_shard(shard)
}

/// Checks before any work that `method` can write checkpoints and resume
/// from them ([`MethodConfig::check_resumable`]): a method resumes when it
/// restores its state exactly; the others keep state that is not saved.
pub fn check_resumable(method: &MethodConfig) -> Result<(), MethodError> {
    method.check_resumable()
}

/// What identifies a render, so that parts of it can be told apart from
/// parts of another: compared field by field before a merge or a resume.
#[derive(Clone, Debug, PartialEq)]
pub struct Meta {
    /// The method with its settings (the shared ones are the fields
    /// below).
    pub settings: MethodConfig,
    /// The master seed.
    pub seed: u64,
    /// `--max-depth`, when given.
    pub max_depth: Option<u32>,
    /// [`scene_hash`] of the scene.
    pub scene_hash: u64,
    /// Where the scene came from (for messages only; not compared).
    pub scene_source: String,
    /// Film width.
    pub width: u32,
    /// Film height.
    pub height: u32,
    /// Which shard this is.
    pub shard: Shard,
    /// How the method is split.
    pub kind: ShardKind,
}

impl Meta {
    /// The identity of a render of `scene` with `method` and `common`, as
    /// shard `shard`.
    pub fn new(
        scene: &Scene,
        method: &MethodConfig,
        common: &Common,
        shard: Shard,
    ) -> Result<Meta, MethodError> {
        Ok(Meta {
            settings: method.clone(),
            seed: common.seed,
            max_depth: common.max_depth,
            scene_hash: scene_hash(scene),
            scene_source: scene.source.clone(),
            width: scene.camera.width,
            height: scene.camera.height,
            shard,
            kind: method.shard_kind().unwrap_or(ShardKind::Exact),
        })
    }

    /// The method's name.
    pub fn method(&self) -> &'static str {
        self.settings.name()
    }

    /// The first field in which `other` (called `other_name` in the
    /// message) differs from this one (called `name`), in words, ignoring
    /// the shard index; None when they are parts of the same render.
    pub fn difference(&self, name: &str, other: &Meta, other_name: &str) -> Option<String> {
        let d = |what: &str, a: &dyn fmt::Display, b: &dyn fmt::Display| {
            Some(format!("{other_name} has {what} {b}, but {name} has {a}"))
        };
        if self.method() != other.method() {
            return d("method", &self.method(), &other.method());
        }
        if self.scene_hash != other.scene_hash
            || (self.width, self.height) != (other.width, other.height)
        {
            return Some(format!(
                "{other_name} is of another scene (hash {:016x}, {}x{}, from {}) than {name} \
                 (hash {:016x}, {}x{}, from {})",
                other.scene_hash,
                other.width,
                other.height,
                other.scene_source,
                self.scene_hash,
                self.width,
                self.height,
                self.scene_source
            ));
        }
        if self.settings != other.settings {
            let (a, b) = settings_difference(&self.settings, &other.settings);
            return d("settings", &a, &b);
        }
        if self.seed != other.seed {
            return d("seed", &self.seed, &other.seed);
        }
        if self.max_depth != other.max_depth {
            let show = |m: Option<u32>| m.map_or("none".to_string(), |m| m.to_string());
            return d("--max-depth", &show(self.max_depth), &show(other.max_depth));
        }
        if self.shard.count != other.shard.count {
            return d("a shard count of", &self.shard.count, &other.shard.count);
        }
        None
    }
}

/// The first field in which the settings `a` and `b` of one method differ,
/// as `name: value` for each (`rr_depth: 5`, `rr_depth: 2`), read from
/// their serde form; both whole, as JSON, when no single field tells them
/// apart.
fn settings_difference(a: &MethodConfig, b: &MethodConfig) -> (String, String) {
    let value = |m: &MethodConfig| serde_json::to_value(m).unwrap_or_default();
    let (va, vb) = (value(a), value(b));
    let fields = |v: &serde_json::Value| {
        v.as_object()
            .and_then(|o| o.get(a.name()))
            .and_then(|s| s.as_object())
            .cloned()
    };
    if let (Some(fa), Some(fb)) = (fields(&va), fields(&vb)) {
        for (k, x) in &fa {
            let y = fb.get(k).unwrap_or(&serde_json::Value::Null);
            if x != y {
                return (format!("{k}: {x}"), format!("{k}: {y}"));
            }
        }
    }
    (va.to_string(), vb.to_string())
}

/// A partial result: what render it belongs to, and its state.
#[derive(Clone, Debug, PartialEq)]
pub struct Partial {
    /// The render it belongs to.
    pub meta: Meta,
    /// The state.
    pub state: State,
}

/// An error reading, checking or merging partial results: one line that
/// names the file and what was expected.
#[derive(Debug, thiserror::Error)]
pub enum PartialError {
    /// A file that is not a partial result, or is damaged.
    #[error("{path}: {reason}", path = .path.display())]
    Malformed {
        /// The file.
        path: PathBuf,
        /// What was wrong.
        reason: String,
    },
    /// Reading or writing failed.
    #[error("{path}: {source}", path = .path.display())]
    Io {
        /// The file.
        path: PathBuf,
        /// The operating system's error.
        #[source]
        source: std::io::Error,
    },
    /// Parts that do not belong together, or a set of parts that is not
    /// whole.
    #[error("{0}")]
    Incompatible(String),
    /// Writing atomically failed.
    #[error(transparent)]
    Write(#[from] crate::image_io::ImageIoError),
}

/// A 64-bit hash of everything in `scene` that shapes an image: geometry,
/// attributes, materials, emitters, shapes and the camera (with its
/// resolution), so that parts of renders of different scenes, or of one
/// scene with other `-D` values or `--res`, are told apart. Not the file
/// name: the same scene moved to another folder hashes the same.
pub fn scene_hash(scene: &Scene) -> u64 {
    let mut h = Fnv(0xcbf2_9ce4_8422_2325);
    let floats =
        |h: &mut Fnv, v: &[f32]| v.iter().for_each(|x| h.bytes(&x.to_bits().to_le_bytes()));
    for p in &scene.positions {
        floats(&mut h, &p.to_array());
    }
    for n in &scene.normals {
        floats(&mut h, &n.to_array());
    }
    for uv in &scene.uvs {
        floats(&mut h, &uv.to_array());
    }
    for t in &scene.triangles {
        t.iter().for_each(|i| h.bytes(&i.to_le_bytes()));
    }
    scene
        .tri_shape
        .iter()
        .for_each(|i| h.bytes(&i.to_le_bytes()));
    // The rest is small and has no other canonical form than its Debug text,
    // streamed into the hash rather than built as a string.
    use std::fmt::Write;
    let _ = write!(
        h,
        "{:?}{:?}{:?}{:?}",
        scene.shapes, scene.materials, scene.emitters, scene.camera
    );
    h.0
}

/// FNV-1a, 64 bits: stable across builds and platforms (std's hasher is not
/// promised to be), which a hash written into files needs.
struct Fnv(u64);

impl Fnv {
    fn bytes(&mut self, b: &[u8]) {
        for &x in b {
            self.0 = (self.0 ^ x as u64).wrapping_mul(0x100_0000_01b3);
        }
    }
}

impl fmt::Write for Fnv {
    fn write_str(&mut self, s: &str) -> fmt::Result {
        self.bytes(s.as_bytes());
        Ok(())
    }
}
