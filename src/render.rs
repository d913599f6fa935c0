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
//! The command line, the tests and the examples all render through it.

use std::sync::atomic::AtomicBool;

use crate::film::Image;
use crate::methods::{Budget, Common, Driver, MethodConfig, MethodError, Progress, RenderResult};
use crate::world::World;

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
        }
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

    /// Builds the method, prepares it and runs it until the budget is
    /// spent; `on_progress` is called after every pass.
    pub fn run(self, on_progress: impl FnMut(&Progress)) -> Result<RenderResult, MethodError> {
        let mut method = self.method.create(self.world, &self.common)?;
        Driver {
            budget: self.budget,
            cancel: self.cancel,
            reference: self.reference,
            log_every: self.log_every,
        }
        .run(method.as_mut(), self.world, on_progress)
    }
}
