//! The progressive methods, the trait they share, and the driver that gives
//! them budgets, progress, Ctrl-C and convergence logs.
//!
//! Every method is a progressive estimator: [`Method::step`] adds one pass of
//! work (one sample per pixel for `path`, a fixed batch of light paths for
//! `light`...) and reports the rays it traced; [`Method::image`] is the
//! current estimate. Methods never print and never touch files.
//!
//! Each method owns a typed `Settings` (with `Default`, serde and clap
//! derives) in its own folder; the settings every method shares (seed,
//! longest path) are [`Common`]; [`MethodConfig`] is one method with its
//! settings, and [`all`] is the table of methods that the command line and
//! the tests iterate (Tungsten's integrator factory).
//!
//! The table is the only place that knows which methods there are. Each
//! `Settings` implements the contract [`MethodSettings`]: its checks, how
//! it is split into shards and whether it resumes from checkpoints, its
//! exact merge of shard states, its memory estimate, and building the
//! method. [`MethodConfig`] hands each question to it with one dispatch
//! (the `dispatch!` macro here), and `partial`, `render` and the command
//! line ask [`MethodConfig`], never a method by name. A new method is
//! therefore a new folder whose `Settings` implements [`MethodSettings`]
//! (the compiler names every function still missing), one variant of
//! [`MethodConfig`] with its arm of `dispatch!` and its name in
//! [`MethodConfig::name`] (the compiler names those too), and one row of
//! [`all`].

pub mod bundle;
#[cfg(feature = "cli")]
pub mod cli;
mod contract;
pub mod density;
mod driver;
pub mod light;
pub mod path;
pub mod plb;

pub use driver::{Budget, Checkpoint, Driver, Hooks, LogRow, Progress, RenderResult, Setup, Watch};

pub use contract::{camera_pass, film_item, no_exact_merge, MethodSettings, FILM, IMAGE};

use crate::film::Image;
use crate::memory::{MemoryError, MemoryItem};
use crate::state::{Shard, ShardKind, State, StateError};
pub use crate::world::World;

/// What one step did.
#[derive(Clone, Copy, Debug, Default)]
pub struct StepStats {
    /// Rays traced (closest-hit and occlusion queries alike).
    pub rays: u64,
}

/// A progressive estimator.
pub trait Method: Send {
    /// The method's name on the command line.
    fn name(&self) -> &'static str;
    /// One-time setup that needs the world and may fail (the camera pass's
    /// pre-pass, bundle's patches and transfer tables, density's bake). The
    /// driver runs it once, before the first step, inside its clock, and
    /// counts its rays like a step's, so that equal-time and equal-ray
    /// comparisons include it.
    fn prepare(&mut self, _world: &World) -> Result<StepStats, MethodError> {
        Ok(StepStats::default())
    }
    /// [`Method::prepare`] for a setup that must itself obey the budget,
    /// honour the cancel flag and report progress (density's bake): the
    /// driver calls this one. The default runs [`Method::prepare`].
    fn prepare_within(
        &mut self,
        world: &World,
        _setup: &mut Setup<'_>,
    ) -> Result<StepStats, MethodError> {
        self.prepare(world)
    }
    /// Adds one pass of work; `pass` counts from 0 and keys the random streams.
    fn step(&mut self, world: &World, pass: u64) -> StepStats;
    /// Adds the `k` passes `pass` … `pass + k − 1`: the same image, to the
    /// bit, as `k` calls of [`Method::step`], which the default makes. A
    /// method whose passes are independent per pixel may run them row by
    /// row with one synchronisation of its threads instead of `k`
    /// ([`Method::batches`]).
    fn steps(&mut self, world: &World, pass: u64, k: u64) -> StepStats {
        let mut rays = 0;
        for p in pass..pass + k {
            rays += self.step(world, p).rays;
        }
        StepStats { rays }
    }
    /// Whether the driver should give [`Method::steps`] several passes at a
    /// time; a method that says so takes one sample per pixel per pass.
    /// The default: one pass per call.
    fn batches(&self) -> bool {
        false
    }
    /// The current estimate.
    fn image(&self, world: &World) -> Image;
    /// Work done so far, in samples per pixel or the method's equivalent
    /// (light paths per pixel for the light-based methods).
    fn spp(&self) -> f64;
    /// A one-line summary of method-specific statistics (phase timings,
    /// memory), printed by the CLI after a render.
    fn report(&self) -> Option<String> {
        None
    }
    /// Restricts the method to shard `shard` of a render split exactly
    /// (see [`crate::partial`]): from now on it runs only its part of the
    /// random streams of each pass. The default refuses.
    fn set_shard(&mut self, shard: Shard) -> Result<(), MethodError> {
        let _ = shard;
        Err(MethodError(format!(
            "method '{}' cannot be split into exact shards",
            self.name()
        )))
    }
    /// The progressive state (counters and per-pixel sums) from which
    /// [`Method::restore`] continues exactly, for checkpoints and shards;
    /// None for a method whose state cannot be saved (the default). The
    /// driver fills in its own counts.
    fn state(&self) -> Option<State> {
        None
    }
    /// Continues from a state that [`Method::state`] gave, after
    /// [`Method::prepare`]. The default refuses.
    fn restore(&mut self, state: &State) -> Result<(), MethodError> {
        let _ = state;
        Err(MethodError(format!(
            "method '{}' cannot resume from a checkpoint: its state cannot be saved",
            self.name()
        )))
    }
}

/// An error in a method's settings, or a failure of its setup.
#[derive(Debug, thiserror::Error)]
#[error("{0}")]
pub struct MethodError(pub String);

impl From<StateError> for MethodError {
    fn from(e: StateError) -> Self {
        MethodError(e.0)
    }
}

impl From<MemoryError> for MethodError {
    fn from(e: MemoryError) -> Self {
        MethodError(e.to_string())
    }
}

/// Settings every method shares.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Common {
    /// Master seed: with the same seed a method gives the same image
    /// whatever the thread count.
    pub seed: u64,
    /// Longest path in segments, Mitsuba's `max_depth`: 1 shows only the
    /// emitters seen directly, 2 adds direct light; None = unlimited. A
    /// method that cannot honour it refuses it (see [`MethodInfo::max_depth`]).
    pub max_depth: Option<u32>,
}

/// One method with its settings. Serialised (as in a partial result's
/// header) it is one JSON object keyed by the method's name:
/// `{"path":{"seed":0,"max_depth":null,"rr_depth":5,...}}`.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum MethodConfig {
    /// The reference path tracer.
    Path(path::Settings),
    /// Light tracing, the single-ray stochastic iteration.
    Light(light::Settings),
    /// Progressive light path building.
    Plb(plb::Settings),
    /// Stochastic iteration with global ray bundles.
    Bundle(bundle::Settings),
    /// Density estimation.
    Density(density::Settings),
}

/// Runs `$body` with `$s` bound to the settings of whichever method
/// `$cfg` is: the one place, with [`MethodConfig::name`], that lists the
/// variants (a new one that is missing here is a compile error).
macro_rules! dispatch {
    ($cfg:expr, $s:ident => $body:expr) => {
        match $cfg {
            MethodConfig::Path($s) => $body,
            MethodConfig::Light($s) => $body,
            MethodConfig::Plb($s) => $body,
            MethodConfig::Bundle($s) => $body,
            MethodConfig::Density($s) => $body,
        }
    };
}

impl MethodConfig {
    /// The method's name on the command line.
    pub fn name(&self) -> &'static str {
        match self {
            MethodConfig::Path(_) => "path",
            MethodConfig::Light(_) => "light",
            MethodConfig::Plb(_) => "plb",
            MethodConfig::Bundle(_) => "bundle",
            MethodConfig::Density(_) => "density",
        }
    }

    /// The method's row of the table.
    pub fn info(&self) -> &'static MethodInfo {
        by_name(self.name()).expect("every MethodConfig variant has a row in all()")
    }

    /// Rejects settings that cannot work, naming the flag.
    pub fn validate(&self) -> Result<(), MethodError> {
        dispatch!(self, s => MethodSettings::validate(s))
    }

    /// Validates the settings together with the shared ones: a method that
    /// cannot honour `--max-depth` refuses it.
    pub fn check(&self, common: &Common) -> Result<(), MethodError> {
        if common.max_depth.is_some() && !self.info().max_depth {
            return Err(MethodError(format!(
                "method '{}' cannot honour --max-depth: {}",
                self.name(),
                self.info().max_depth_note
            )));
        }
        if common.max_depth == Some(0) {
            return Err(MethodError(
                "--max-depth must be at least 1 (1 shows only the emitters, 2 adds direct light)"
                    .into(),
            ));
        }
        self.validate()
    }

    /// Checks the settings with `common` and builds the method. Cheap:
    /// the work that needs the world runs in [`Method::prepare`].
    pub fn create(&self, world: &World, common: &Common) -> Result<Box<dyn Method>, MethodError> {
        self.check(common)?;
        if let MethodConfig::Bundle(b) = self {
            b.check_lights(world)?;
        }
        Ok(dispatch!(self, s => s.create(world, common)))
    }

    /// How the method is split into shards, or why it cannot be (see
    /// [`crate::partial`]).
    pub fn shard_kind(&self) -> Result<ShardKind, MethodError> {
        dispatch!(self, s => s.shard_kind())
    }

    /// Checks before any work that the method can be split into
    /// `shard.count` shards, and says how.
    pub fn check_shard(&self, shard: Shard) -> Result<ShardKind, MethodError> {
        let kind = self.shard_kind()?;
        dispatch!(self, s => s.check_shard_count(shard.count))?;
        Ok(kind)
    }

    /// Checks before any work that the method can write checkpoints and
    /// resume from them exactly; the error says why not and which methods
    /// can.
    pub fn check_resumable(&self) -> Result<(), MethodError> {
        let Err(why) = dispatch!(self, s => s.resumable()) else {
            return Ok(());
        };
        let able: Vec<&str> = ALL
            .iter()
            .filter(|m| dispatch!(&(m.default)(), s => s.resumable()).is_ok())
            .map(|m| m.name)
            .collect();
        let list = match able.split_last() {
            Some((last, [])) => last.to_string(),
            Some((last, rest)) => format!("{} and {last}", rest.join(", ")),
            None => "no method".into(),
        };
        Err(MethodError(format!(
            "method '{}' cannot write checkpoints or resume: {why}; checkpoints work with {list}",
            self.name()
        )))
    }

    /// The image of a render split exactly from the states of all its
    /// shards, in shard order (see [`MethodSettings::merge_exact`]).
    pub fn merge_exact(
        &self,
        states: &[&State],
        width: u32,
        height: u32,
    ) -> Result<Image, MethodError> {
        dispatch!(self, s => s.merge_exact(states, width, height))
    }

    /// The large allocations of a `width` × `height` render (see
    /// [`crate::render::memory_estimate`]).
    pub fn memory(&self, width: u32, height: u32) -> Vec<MemoryItem> {
        dispatch!(self, s => s.memory(width, height))
    }
}

/// A row of the method table.
pub struct MethodInfo {
    /// The name on the command line.
    pub name: &'static str,
    /// One line for `--help`.
    pub about: &'static str,
    /// Whether the method honours [`Common::max_depth`].
    pub max_depth: bool,
    /// Why not, when it does not.
    pub max_depth_note: &'static str,
    /// The method with its default settings.
    pub default: fn() -> MethodConfig,
    /// Adds the method's own flags to a command line.
    #[cfg(feature = "cli")]
    pub args: fn(clap::Command) -> clap::Command,
    /// Reads the method's settings back from parsed flags.
    #[cfg(feature = "cli")]
    pub from_args: fn(&clap::ArgMatches) -> Result<MethodConfig, clap::Error>,
}

/// The command-line half of a row: `args` and `from_args` for a method
/// whose settings type is `$settings`, wrapped by `$variant`.
#[cfg(feature = "cli")]
macro_rules! cli_row {
    ($settings:ty, $variant:path) => {
        (
            <$settings as clap::Args>::augment_args,
            |m: &clap::ArgMatches| {
                <$settings as clap::FromArgMatches>::from_arg_matches(m).map($variant)
            },
        )
    };
}

static ALL: [MethodInfo; 5] = [
    MethodInfo {
        name: "path",
        about: "reference path tracer: next-event estimation, MIS, Russian roulette",
        max_depth: true,
        max_depth_note: "",
        default: || MethodConfig::Path(path::Settings::default()),
        #[cfg(feature = "cli")]
        args: cli_row!(path::Settings, MethodConfig::Path).0,
        #[cfg(feature = "cli")]
        from_args: cli_row!(path::Settings, MethodConfig::Path).1,
    },
    MethodInfo {
        name: "light",
        about: "light tracing, the single-ray stochastic iteration (1999 paper, §4)",
        max_depth: true,
        max_depth_note: "",
        default: || MethodConfig::Light(light::Settings::default()),
        #[cfg(feature = "cli")]
        args: cli_row!(light::Settings, MethodConfig::Light).0,
        #[cfg(feature = "cli")]
        from_args: cli_row!(light::Settings, MethodConfig::Light).1,
    },
    MethodInfo {
        name: "plb",
        about: "progressive light path building: a self-correcting population of photon hits",
        max_depth: true,
        max_depth_note: "",
        default: || MethodConfig::Plb(plb::Settings::default()),
        #[cfg(feature = "cli")]
        args: cli_row!(plb::Settings, MethodConfig::Plb).0,
        #[cfg(feature = "cli")]
        from_args: cli_row!(plb::Settings, MethodConfig::Plb).1,
    },
    MethodInfo {
        name: "bundle",
        about: "stochastic iteration with global ray bundles and painter's visibility maps",
        max_depth: false,
        max_depth_note: "stochastic iteration transfers each patch's whole current radiance, \
            in which light of every bounce count is mixed, so no path length can be limited",
        default: || MethodConfig::Bundle(bundle::Settings::default()),
        #[cfg(feature = "cli")]
        args: cli_row!(bundle::Settings, MethodConfig::Bundle).0,
        #[cfg(feature = "cli")]
        from_args: cli_row!(bundle::Settings, MethodConfig::Bundle).1,
    },
    MethodInfo {
        name: "density",
        about: "density estimation: particle tracing, kernel estimate, decimated display mesh",
        max_depth: true,
        max_depth_note: "",
        default: || MethodConfig::Density(density::Settings::default()),
        #[cfg(feature = "cli")]
        args: cli_row!(density::Settings, MethodConfig::Density).0,
        #[cfg(feature = "cli")]
        from_args: cli_row!(density::Settings, MethodConfig::Density).1,
    },
];

/// The table of methods, in the order `--help` shows them.
pub fn all() -> &'static [MethodInfo] {
    &ALL
}

/// The row of the method called `name`.
pub fn by_name(name: &str) -> Result<&'static MethodInfo, MethodError> {
    ALL.iter().find(|m| m.name == name).ok_or_else(|| {
        MethodError(format!(
            "unknown method '{name}'; known methods: {}",
            names().join(", ")
        ))
    })
}

/// The names of the methods, in the order of [`all`].
pub fn names() -> Vec<&'static str> {
    ALL.iter().map(|m| m.name).collect()
}
