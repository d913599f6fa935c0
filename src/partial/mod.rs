//! Partial results: a render's state (film sums, counts, settings, the
//! scene's hash) that can be written, merged and resumed. One mechanism
//! gives shards on a farm (`kalos render --shard K/N`, `kalos merge`) and
//! checkpoints (`--checkpoint`, `--resume`).
//!
//! How a method is split into shards ([`ShardKind`]):
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

use glam::DVec3;

use crate::methods::{Common, MethodConfig, MethodError};
use crate::scene::Scene;

/// Shard K of N (K counts from 0, as Slurm's `--array=0-3` and Kubernetes'
/// completion index do).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Shard {
    /// This shard, in 0..count.
    pub index: u32,
    /// How many shards make the whole render.
    pub count: u32,
}

impl Shard {
    /// The whole render: shard 0 of 1.
    pub const WHOLE: Shard = Shard { index: 0, count: 1 };

    /// Parses `K/N` with 0 ≤ K < N.
    pub fn parse(s: &str) -> Result<Shard, String> {
        let (k, n) = s
            .split_once('/')
            .ok_or_else(|| format!("expected K/N (e.g. 0/4), got '{s}'"))?;
        let k: u32 = k
            .trim()
            .parse()
            .map_err(|_| format!("K in K/N must be a whole number, got '{k}'"))?;
        let n: u32 = n
            .trim()
            .parse()
            .map_err(|_| format!("N in K/N must be a whole number, got '{n}'"))?;
        if n == 0 {
            return Err("N in K/N must be at least 1".into());
        }
        if k >= n {
            return Err(format!(
                "K in K/N counts from 0 and must be below N: got {k}/{n} (the shards of {n} are 0/{n} to {}/{n})",
                n - 1
            ));
        }
        Ok(Shard { index: k, count: n })
    }

    /// True when this shard owns item `i` (a row, a lane) of a split by
    /// residue: i ≡ K (mod N).
    #[inline]
    pub fn owns(&self, i: u64) -> bool {
        i % self.count as u64 == self.index as u64
    }
}

impl fmt::Display for Shard {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}/{}", self.index, self.count)
    }
}

/// How a method is split into shards (see the module docs).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ShardKind {
    /// Each shard owns part of the random streams of every pass; merged,
    /// the bytes of one run.
    Exact,
    /// Each shard is an independent chain; merged, their average.
    Chains,
}

impl ShardKind {
    /// The word in a partial file.
    pub fn word(self) -> &'static str {
        match self {
            ShardKind::Exact => "exact",
            ShardKind::Chains => "chains",
        }
    }
}

/// How `method` is split into shards, or why it cannot be.
pub fn shard_kind(method: &MethodConfig) -> Result<ShardKind, MethodError> {
    match method {
        MethodConfig::Path(_) | MethodConfig::Light(_) => Ok(ShardKind::Exact),
        MethodConfig::Plb(_) | MethodConfig::Bundle(_) => Ok(ShardKind::Chains),
        MethodConfig::Density(_) => Err(MethodError(
            "method 'density' cannot be split into shards: averaging N particle sets keeps \
             the kernel blur of one set, so it would not converge to the image of N times \
             the particles; raise --particles instead"
                .into(),
        )),
    }
}

/// Checks before any work that `method` can be split into `shard.count`
/// shards, and says how.
pub fn check_shard(method: &MethodConfig, shard: Shard) -> Result<ShardKind, MethodError> {
    let kind = shard_kind(method)?;
    if let MethodConfig::Light(s) = method {
        if shard.count as usize > s.lanes {
            return Err(MethodError(format!(
                "light splits into at most {} shards (one per lane: the streams that keep its \
                 image independent of the thread count), not {}",
                s.lanes, shard.count
            )));
        }
    }
    Ok(kind)
}

/// Checks before any work that `method` can write checkpoints and resume
/// from them: `path` and `light --variant walk` restore their state
/// exactly; the others keep state that is not saved (plb's population,
/// bundle's patch radiances, density's hit file, light's iteration chains).
pub fn check_resumable(method: &MethodConfig) -> Result<(), MethodError> {
    let why = match method {
        MethodConfig::Path(_) => return Ok(()),
        MethodConfig::Light(s) if s.variant == crate::methods::light::Variant::Walk => {
            return Ok(())
        }
        MethodConfig::Light(_) => {
            "its iteration chains carry a surface point from pass to pass (use --variant walk)"
        }
        MethodConfig::Plb(_) => "its population of photon hits is not saved",
        MethodConfig::Bundle(_) => "its patches' radiance is not saved",
        MethodConfig::Density(_) => "its bake (hit file, display mesh) is not saved",
    };
    Err(MethodError(format!(
        "method '{}' cannot write checkpoints or resume: {why}; checkpoints work with path and light",
        method.name()
    )))
}

/// The seed of chain shard `shard` of a render seeded with `seed`: shard 0
/// keeps it (so that one shard of one is the plain render); the others get
/// unrelated streams, hashed like every other stream key.
pub fn shard_seed(seed: u64, shard: Shard) -> u64 {
    if shard.index == 0 {
        seed
    } else {
        crate::sampling::mix64(seed ^ crate::sampling::mix64(0x5AA2D ^ shard.index as u64))
    }
}

/// The progressive state of a method, as [`crate::methods::Method::state`]
/// gives it and [`crate::methods::Method::restore`] takes it back: named
/// counters and named per-pixel sums, plus the driver's own counts.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct State {
    /// Passes run.
    pub passes: u64,
    /// Rays traced.
    pub rays: u64,
    /// Seconds of rendering.
    pub seconds: f64,
    /// Samples per pixel (or the method's equivalent) so far.
    pub spp: f64,
    /// The method's counters, by name.
    pub counters: Vec<(String, u64)>,
    /// The method's per-pixel sums, by name (row-major, top row first).
    pub buffers: Vec<(String, Vec<DVec3>)>,
}

impl State {
    /// The counter called `name`.
    pub fn counter(&self, name: &str) -> Option<u64> {
        self.counters.iter().find(|c| c.0 == name).map(|c| c.1)
    }

    /// The buffer called `name`.
    pub fn buffer(&self, name: &str) -> Option<&[DVec3]> {
        self.buffers
            .iter()
            .find(|b| b.0 == name)
            .map(|b| b.1.as_slice())
    }

    /// The counter called `name`, or an error naming it.
    pub fn need_counter(&self, name: &str) -> Result<u64, MethodError> {
        self.counter(name)
            .ok_or_else(|| MethodError(format!("the saved state has no counter '{name}'")))
    }

    /// The buffer called `name` with `len` pixels, or an error naming it.
    pub fn need_buffer(&self, name: &str, len: usize) -> Result<&[DVec3], MethodError> {
        let b = self
            .buffer(name)
            .ok_or_else(|| MethodError(format!("the saved state has no buffer '{name}'")))?;
        if b.len() != len {
            return Err(MethodError(format!(
                "the saved buffer '{name}' has {} pixels, expected {len}",
                b.len()
            )));
        }
        Ok(b)
    }
}

/// What identifies a render, so that parts of it can be told apart from
/// parts of another: compared field by field before a merge or a resume.
#[derive(Clone, Debug, PartialEq)]
pub struct Meta {
    /// The method's name.
    pub method: String,
    /// The method's settings as text (its `Debug` form).
    pub settings: String,
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
            method: method.name().to_string(),
            settings: format!("{method:?}"),
            seed: common.seed,
            max_depth: common.max_depth,
            scene_hash: scene_hash(scene),
            scene_source: scene.source.clone(),
            width: scene.camera.width,
            height: scene.camera.height,
            shard,
            kind: shard_kind(method).unwrap_or(ShardKind::Exact),
        })
    }

    /// The first field in which `other` (called `other_name` in the
    /// message) differs from this one (called `name`), in words, ignoring
    /// the shard index; None when they are parts of the same render.
    pub fn difference(&self, name: &str, other: &Meta, other_name: &str) -> Option<String> {
        let d = |what: &str, a: &dyn fmt::Display, b: &dyn fmt::Display| {
            Some(format!("{other_name} has {what} {b}, but {name} has {a}"))
        };
        if self.method != other.method {
            return d("method", &self.method, &other.method);
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
            return d("settings", &self.settings, &other.settings);
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
