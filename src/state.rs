//! A render's progressive state and how it is split, below the methods and
//! the transport that fill them: [`Shard`] (which part of a render a method
//! runs), [`ShardKind`] (how a method splits), [`State`] (what a method
//! saves and resumes from) and [`shard_seed`]. Plain data: `methods`,
//! `transport` and `partial` (which writes and merges states) all build on
//! it, and it depends on none of them.

use std::fmt;

use glam::DVec3;

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

/// How a method is split into shards (see [`crate::partial`]).
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
    pub fn need_counter(&self, name: &str) -> Result<u64, StateError> {
        self.counter(name)
            .ok_or_else(|| StateError(format!("the saved state has no counter '{name}'")))
    }

    /// The buffer called `name` with `len` pixels, or an error naming it.
    pub fn need_buffer(&self, name: &str, len: usize) -> Result<&[DVec3], StateError> {
        let b = self
            .buffer(name)
            .ok_or_else(|| StateError(format!("the saved state has no buffer '{name}'")))?;
        if b.len() != len {
            return Err(StateError(format!(
                "the saved buffer '{name}' has {} pixels, expected {len}",
                b.len()
            )));
        }
        Ok(b)
    }
}

/// A counter or buffer missing from a saved [`State`], or of the wrong
/// size.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("{0}")]
pub struct StateError(pub String);
