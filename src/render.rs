//! The library API for embedding: a scene's [`World`], a method, a budget,
//! a progress callback, an image (rpt's `Renderer` builder).
//!
//! ```no_run
//! use kalos::methods::{plb, MethodConfig};
//! use kalos::render::Render;
//! use kalos::world::World;
//!
//! let world = World::new(kalos::scene::builtin::cornell_box()?);
//! let result = Render::new(&world)
//!     .method(MethodConfig::Plb(plb::Settings {
//!         lambda: 2.0,
//!         ..Default::default()
//!     }))
//!     .seed(7)
//!     .spp(8.0)
//!     .run(|p| eprintln!("{} passes", p.passes))?;
//! println!("{} rays, mean {:?}", result.rays, result.image.data[0]);
//! # Ok::<(), Box<dyn std::error::Error>>(())
//! ```
//!
//! The command line, the tests and the examples all render through it. The
//! whole sequence a front end runs (check the outputs, load the scene, size
//! the memory, build the world, render, write) is `kalos::job::RenderJob`,
//! which renders through this builder.
//!
//! Before anything large is allocated, [`memory_estimate`] sizes a render's
//! big buffers (the film with every per-lane copy, bundle's visibility map
//! and patches, plb's populations, density's hit chunk) and
//! [`check_memory`] refuses one past a limit, naming what is too large: a
//! failed allocation would abort the process instead of reporting.

use std::sync::atomic::AtomicBool;

use crate::film::Image;
pub use crate::memory::{check_memory, format_bytes, MemoryError, MemoryItem};
use crate::methods::{
    Budget, Checkpoint, Common, Driver, Hooks, MethodConfig, MethodError, Progress, RenderResult,
    Watch,
};
use crate::state::{shard_seed, Shard, ShardKind, State};
use crate::world::World;

/// What [`Render::watch`] calls with each image it shows.
type OnImage<'a> = Box<dyn FnMut(&Image, &Progress) + 'a>;

/// A render being set up: the method with its settings, the shared
/// settings, the budget, and what the driver watches.
pub struct Render<'a> {
    world: &'a World,
    method: MethodConfig,
    common: Common,
    budget: Budget,
    cancel: Option<&'a AtomicBool>,
    reference: Option<&'a Image>,
    log_every: f64,
    max_memory: Option<u64>,
    watch: Option<(f64, OnImage<'a>)>,
    shard: Shard,
    resume: Option<&'a State>,
    checkpoint: Option<Checkpoint<'a>>,
    keep_state: bool,
}

impl<'a> Render<'a> {
    /// A render of `world` with the path tracer's defaults, seed 0 and a
    /// budget of 16 samples per pixel.
    pub fn new(world: &'a World) -> Self {
        Render {
            world,
            method: MethodConfig::Path(Default::default()),
            common: Common::default(),
            budget: Budget {
                spp: Some(16.0),
                ..Default::default()
            },
            cancel: None,
            reference: None,
            log_every: 0.0,
            max_memory: None,
            watch: None,
            shard: Shard::WHOLE,
            resume: None,
            checkpoint: None,
            keep_state: false,
        }
    }

    /// Renders only shard `shard` of the render (see [`crate::partial`]):
    /// part of the streams of every pass (`path`, `light`), or an
    /// independent chain with its own seed (`plb`, `bundle`). Keep its
    /// state ([`Render::keep_state`]) to merge it.
    pub fn shard(mut self, shard: Shard) -> Self {
        self.shard = shard;
        self
    }

    /// Continues from `state` (a checkpoint of the same render, as
    /// [`RenderResult::state`] or the checkpoint function gave it).
    pub fn resume(mut self, state: &'a State) -> Self {
        self.resume = Some(state);
        self
    }

    /// Hands the render's state to `save` every `every` seconds.
    pub fn checkpoint(mut self, every: f64, save: &'a mut dyn FnMut(&State)) -> Self {
        self.checkpoint = Some((every, save));
        self
    }

    /// Puts the final state into [`RenderResult::state`] (for a chain
    /// shard, its image), to write as a partial result.
    pub fn keep_state(mut self) -> Self {
        self.keep_state = true;
        self
    }

    /// Refuses to start a render whose [`memory_estimate`] passes `bytes`
    /// (default: no limit).
    pub fn max_memory(mut self, bytes: u64) -> Self {
        self.max_memory = Some(bytes);
        self
    }

    /// The method and its settings.
    pub fn method(mut self, method: MethodConfig) -> Self {
        self.method = method;
        self
    }

    /// The shared settings (seed, longest path).
    pub fn common(mut self, common: Common) -> Self {
        self.common = common;
        self
    }

    /// The master seed.
    pub fn seed(mut self, seed: u64) -> Self {
        self.common.seed = seed;
        self
    }

    /// The longest path in segments (Mitsuba's `max_depth`).
    pub fn max_depth(mut self, max_depth: Option<u32>) -> Self {
        self.common.max_depth = max_depth;
        self
    }

    /// The whole budget; the first limit reached stops the render.
    pub fn budget(mut self, budget: Budget) -> Self {
        self.budget = budget;
        self
    }

    /// A budget of samples per pixel only.
    pub fn spp(self, spp: f64) -> Self {
        self.budget(Budget {
            spp: Some(spp),
            ..Default::default()
        })
    }

    /// A budget of passes only.
    pub fn passes(self, passes: u64) -> Self {
        self.budget(Budget {
            passes: Some(passes),
            ..Default::default()
        })
    }

    /// Stops the render after the current pass once `flag` is set.
    pub fn cancel(mut self, flag: &'a AtomicBool) -> Self {
        self.cancel = Some(flag);
        self
    }

    /// Records the relMSE against `reference` every `log_every` seconds
    /// (0: only at the end) in the result's convergence log.
    pub fn reference(mut self, reference: &'a Image, log_every: f64) -> Self {
        self.reference = Some(reference);
        self.log_every = log_every;
        self
    }

    /// Calls `on_image` with the current estimate at most every
    /// `every_seconds` of render time (a live preview); the time it and the
    /// estimate take is not counted as render time
    /// ([`Watch`]).
    pub fn watch(
        mut self,
        every_seconds: f64,
        on_image: impl FnMut(&Image, &Progress) + 'a,
    ) -> Self {
        self.watch = Some((every_seconds, Box::new(on_image)));
        self
    }

    /// Builds the method, prepares it and runs it until the budget is
    /// spent; `on_progress` is called after every pass.
    pub fn run(mut self, on_progress: impl FnMut(&Progress)) -> Result<RenderResult, MethodError> {
        if let Some(limit) = self.max_memory {
            let (w, h) = (self.world.camera.width, self.world.camera.height);
            check_memory(
                &memory_estimate(&self.method, w, h),
                limit,
                "Render::max_memory",
            )?;
        }
        // A whole render is split in no way, but a chain method's state to
        // keep is still its image
        let kind = if self.shard == Shard::WHOLE {
            self.method.shard_kind().ok()
        } else {
            Some(self.method.shard_kind()?)
        };
        if self.checkpoint.is_some() || self.resume.is_some() {
            self.method.check_resumable()?;
        }
        let mut common = self.common.clone();
        if kind == Some(ShardKind::Chains) {
            common.seed = shard_seed(common.seed, self.shard);
        }
        let mut method = self.method.create(self.world, &common)?;
        if kind == Some(ShardKind::Exact) && self.shard != Shard::WHOLE {
            method.set_shard(self.shard)?;
        }
        // both borrowed for the run only (the watch is owned here)
        let hooks = Hooks {
            resume: self.resume,
            checkpoint: self
                .checkpoint
                .as_mut()
                .map(|(every, save)| -> Checkpoint<'_> { (*every, &mut **save) }),
            keep_state: self.keep_state,
            watch: self.watch.as_mut().map(|(every, f)| Watch {
                every: *every,
                on_image: f.as_mut(),
            }),
        };
        let mut result = Driver {
            budget: self.budget,
            cancel: self.cancel,
            reference: self.reference,
            log_every: self.log_every,
        }
        .run_with(method.as_mut(), self.world, hooks, on_progress)?;
        if self.keep_state && kind == Some(ShardKind::Chains) {
            // A chain's part of the merge is its image (see crate::partial)
            result.state = Some(State {
                passes: result.passes,
                rays: result.rays,
                seconds: result.seconds,
                spp: result.spp,
                counters: Vec::new(),
                buffers: vec![(
                    "image".into(),
                    result.image.data.iter().map(|v| v.as_dvec3()).collect(),
                )],
            });
        }
        Ok(result)
    }
}

/// The large allocations that rendering a `width` × `height` film with
/// `method` makes, before any of them is made: what the per-pixel buffers
/// of the method hold (each lane's films, the camera pass's sums, the
/// merged films and the final image: the peak, while the image is
/// assembled), and the method's own big structures. Structures whose size
/// depends on the scene are counted at the largest the settings allow
/// (bundle's map at [`crate::methods::bundle::MAX_AUTO_MAP_RES`] unless
/// `--map-res` is given; its patches only when their number is given).
/// Smaller allocations (the scene, the BVH, per-thread scratch) are not
/// counted. Each method estimates its own, in its folder
/// ([`crate::methods::MethodSettings::memory`]).
pub fn memory_estimate(method: &MethodConfig, width: u32, height: u32) -> Vec<MemoryItem> {
    method.memory(width, height)
}

/// The machine's memory from the text of Linux's `/proc/meminfo` (its
/// `MemTotal` line, in kB), or None when the line is missing or malformed.
/// The caller reads the file: the library reads no files of its own.
pub fn mem_total(meminfo: &str) -> Option<u64> {
    let line = meminfo.lines().find(|l| l.starts_with("MemTotal:"))?;
    let mut words = line.split_whitespace().skip(1);
    let kb: u64 = words.next()?.parse().ok()?;
    match words.next() {
        Some("kB") | None => kb.checked_mul(1024),
        Some(_) => None,
    }
}
