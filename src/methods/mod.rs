//! The progressive methods, the trait they share, and the driver that gives
//! them budgets, progress, Ctrl-C and convergence logs.
//!
//! Every method is a progressive estimator: [`Method::step`] adds one pass of
//! work (one sample per pixel for `path`, a fixed batch of light paths for
//! `light`...) and reports the rays it traced; [`Method::image`] is the
//! current estimate. Methods never print and never touch files.
//!
//! Each method owns a typed `Settings` (with `Default` and `validate()`);
//! the settings every method shares (seed, longest path) are [`Common`];
//! [`MethodConfig`] is one method with its settings, and [`all`] is the
//! table of methods that the command line and the tests iterate
//! (Tungsten's integrator factory). A new method is a new folder, one
//! variant of [`MethodConfig`] and one row of [`all`].

pub mod bundle;
#[cfg(feature = "cli")]
pub mod cli;
pub mod density;
mod driver;
pub mod light;
pub mod path;
pub mod plb;

pub use driver::{Budget, Checkpoint, Driver, Hooks, LogRow, Progress, RenderResult, Setup, Watch};

use crate::film::Image;
use crate::partial::{Shard, State};
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

/// One method with its settings.
#[derive(Clone, Debug, PartialEq)]
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
        match self {
            MethodConfig::Path(s) => s.validate(),
            MethodConfig::Light(s) => s.validate(),
            MethodConfig::Plb(s) => s.validate(),
            MethodConfig::Bundle(s) => s.validate(),
            MethodConfig::Density(s) => s.validate(),
        }
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
        let (seed, max_depth) = (common.seed, common.max_depth);
        Ok(match self.clone() {
            MethodConfig::Path(s) => Box::new(path::PathTracer::new(
                world,
                path::Settings {
                    seed,
                    max_depth,
                    ..s
                },
            )),
            MethodConfig::Light(s) => Box::new(light::LightTracer::new(
                world,
                light::Settings {
                    seed,
                    max_depth,
                    ..s
                },
            )),
            MethodConfig::Plb(s) => Box::new(plb::Plb::new(
                world,
                plb::Settings {
                    seed,
                    max_depth,
                    ..s
                },
            )),
            MethodConfig::Bundle(s) => {
                Box::new(bundle::Bundle::new(world, bundle::Settings { seed, ..s }))
            }
            MethodConfig::Density(s) => Box::new(density::Density::new(
                world,
                density::Settings {
                    seed,
                    max_depth,
                    ..s
                },
            )),
        })
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
