//! The progressive methods, the trait they share, and the driver that gives
//! them budgets, progress, Ctrl-C and convergence logs.
//!
//! Every method is a progressive estimator: [`Method::step`] adds one pass of
//! work (one sample per pixel for `path`, a fixed batch of light paths for
//! `light`...) and reports the rays it traced; [`Method::image`] is the
//! current estimate. Methods never print and never touch files.

pub mod bundle;
pub mod density;
pub mod light;
pub mod path;
pub mod plb;

use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Instant;

use crate::film::Image;
use crate::metrics;
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
}

/// Settings shared by the methods; each method reads what it needs.
#[derive(Clone, Debug)]
pub struct Options {
    /// Master seed.
    pub seed: u64,
    /// Longest path, in segments (Mitsuba's `max_depth`); None = unlimited.
    pub max_depth: Option<u32>,
    /// Method variant (`light`: `walk` or `iteration`).
    pub variant: Option<String>,
    /// Light tracing / iteration: number of first passes to discard (the
    /// power-defect correction after eq. (18) of the 1999 paper).
    pub discard: u64,
    /// Light-based methods: run the camera pass for delta surfaces seen by
    /// the camera and the environment (on by default).
    pub camera_pass: bool,
    /// `bundle`: target number of patches.
    pub patches: Option<usize>,
    /// `bundle`: target patch edge length (overrides `patches`).
    pub patch_edge: Option<f32>,
    /// `bundle`: sequence of global directions (random, halton, hammersley, frac).
    pub sequence: Option<String>,
    /// `bundle`: visibility-map resolution.
    pub map_res: Option<u32>,
    /// `bundle`: image estimate (phong, gouraud).
    pub bundle_image: Option<String>,
    /// `bundle`: visibility algorithm (painter, zbuffer).
    pub visibility: Option<String>,
    /// `plb`: λ of `ComputeImportance` (None: the method's default).
    pub lambda: Option<f32>,
    /// `plb`: steps per phase (None: the method's default).
    pub phase_len: Option<u32>,
    /// `plb`: population cap after each purge (None: the method's default).
    pub population: Option<usize>,
    /// Density estimation: particles per run (None: the method's default).
    pub particles: Option<u64>,
    /// Density estimation: kernel width factor C1.
    pub c1: Option<f32>,
    /// Density estimation: grid spacing factor C2.
    pub c2: Option<f32>,
    /// Density estimation: decimation error bound ε.
    pub epsilon: Option<f32>,
}

impl Default for Options {
    fn default() -> Self {
        Options {
            seed: 0,
            max_depth: None,
            variant: None,
            discard: 0,
            camera_pass: true,
            patches: None,
            patch_edge: None,
            sequence: None,
            map_res: None,
            bundle_image: None,
            visibility: None,
            lambda: None,
            phase_len: None,
            population: None,
            particles: None,
            c1: None,
            c2: None,
            epsilon: None,
        }
    }
}

/// An error in the method's settings.
#[derive(Debug, thiserror::Error)]
#[error("{0}")]
pub struct MethodError(pub String);

/// The names of the methods, in the order `--help` shows them.
pub const METHODS: &[&str] = &["path", "light", "plb", "bundle", "density"];

/// The method table: name → constructor (Tungsten's integrator factory).
pub fn create(name: &str, world: &World, opts: &Options) -> Result<Box<dyn Method>, MethodError> {
    match name {
        "path" => Ok(Box::new(path::PathTracer::new(
            world,
            path::Settings::from_options(opts)?,
        ))),
        "light" => Ok(Box::new(light::LightTracer::new(
            world,
            light::Settings::from_options(opts)?,
        ))),
        "bundle" => Ok(Box::new(bundle::Bundle::new(
            world,
            bundle::Settings::from_options(opts)?,
        ))),
        "plb" => Ok(Box::new(plb::Plb::new(
            world,
            plb::Settings::from_options(opts)?,
        ))),
        "density" => Ok(Box::new(density::Density::new(
            world,
            density::Settings::from_options(opts)?,
        ))),
        other => Err(MethodError(format!(
            "unknown method '{other}'; known methods: {}",
            METHODS.join(", ")
        ))),
    }
}

/// When to stop. Several limits may be set; the first reached stops.
#[derive(Clone, Copy, Debug, Default)]
pub struct Budget {
    /// Samples per pixel (passes, for methods whose pass is one spp).
    pub spp: Option<f64>,
    /// Wall time in seconds.
    pub time: Option<f64>,
    /// Rays traced.
    pub rays: Option<u64>,
    /// Number of passes.
    pub passes: Option<u64>,
}

/// A row of the convergence log.
#[derive(Clone, Copy, Debug)]
pub struct LogRow {
    /// Seconds since the start.
    pub time_s: f64,
    /// Rays traced so far.
    pub rays: u64,
    /// Samples per pixel so far.
    pub spp: f64,
    /// relMSE against the reference, when one was given.
    pub rel_mse: Option<f64>,
}

/// Progress reported to the caller after every pass.
#[derive(Clone, Copy, Debug)]
pub struct Progress {
    /// Passes done.
    pub passes: u64,
    /// Rays so far.
    pub rays: u64,
    /// Seconds so far.
    pub elapsed: f64,
    /// Fraction of the budget used, in [0, 1].
    pub fraction: f64,
}

/// The outcome of a render.
pub struct RenderResult {
    /// The final estimate.
    pub image: Image,
    /// Rays traced.
    pub rays: u64,
    /// Passes run.
    pub passes: u64,
    /// Samples per pixel (or equivalent).
    pub spp: f64,
    /// Wall time in seconds.
    pub seconds: f64,
    /// True when the render was interrupted.
    pub interrupted: bool,
    /// The convergence log.
    pub log: Vec<LogRow>,
}

/// Runs a method until its budget is spent or `cancel` is set (Ctrl-C).
/// With a reference, records the relMSE every `log_every` seconds (and at the
/// end); the time spent computing the error is not counted as render time.
pub struct Driver<'a> {
    /// The budget.
    pub budget: Budget,
    /// Set from another thread to stop after the current pass.
    pub cancel: Option<&'a AtomicBool>,
    /// Reference image for the convergence log.
    pub reference: Option<&'a Image>,
    /// Seconds between log rows (0 disables intermediate rows).
    pub log_every: f64,
}

impl Driver<'_> {
    /// Runs `method`; `on_progress` is called after every pass.
    pub fn run(
        &self,
        method: &mut dyn Method,
        world: &World,
        mut on_progress: impl FnMut(&Progress),
    ) -> Result<RenderResult, MethodError> {
        let start = Instant::now();
        let mut excluded = 0.0f64; // time spent on logging, not rendering
                                   // Setup runs inside the clock and its rays count toward the budget
        let mut rays = method.prepare(world)?.rays;
        let mut pass = 0u64;
        let mut log = Vec::new();
        let mut next_log = self.log_every;
        let mut interrupted = false;
        let budget = self.budget;
        let unlimited = budget.spp.is_none()
            && budget.time.is_none()
            && budget.rays.is_none()
            && budget.passes.is_none();
        loop {
            let elapsed = start.elapsed().as_secs_f64() - excluded;
            let mut fraction: f64 = 0.0;
            if let Some(s) = budget.spp {
                fraction = fraction.max(method.spp() / s);
            }
            if let Some(t) = budget.time {
                fraction = fraction.max(elapsed / t);
            }
            if let Some(r) = budget.rays {
                fraction = fraction.max(rays as f64 / r as f64);
            }
            if let Some(p) = budget.passes {
                fraction = fraction.max(pass as f64 / p as f64);
            }
            if unlimited && pass >= 1 {
                fraction = 1.0;
            }
            on_progress(&Progress {
                passes: pass,
                rays,
                elapsed,
                fraction: fraction.min(1.0),
            });
            if fraction >= 1.0 {
                break;
            }
            if self.cancel.is_some_and(|c| c.load(Ordering::Relaxed)) {
                interrupted = true;
                break;
            }
            let stats = method.step(world, pass);
            rays += stats.rays;
            pass += 1;
            if let Some(r) = self.reference {
                let now = start.elapsed().as_secs_f64() - excluded;
                if self.log_every > 0.0 && now >= next_log {
                    let t0 = Instant::now();
                    let e = metrics::rel_mse(&method.image(world), r).ok();
                    log.push(LogRow {
                        time_s: now,
                        rays,
                        spp: method.spp(),
                        rel_mse: e,
                    });
                    next_log = now + self.log_every;
                    excluded += t0.elapsed().as_secs_f64();
                }
            }
        }
        let seconds = start.elapsed().as_secs_f64() - excluded;
        let image = method.image(world);
        let rel_mse = self
            .reference
            .and_then(|r| metrics::rel_mse(&image, r).ok());
        log.push(LogRow {
            time_s: seconds,
            rays,
            spp: method.spp(),
            rel_mse,
        });
        Ok(RenderResult {
            image,
            rays,
            passes: pass,
            spp: method.spp(),
            seconds,
            interrupted,
            log,
        })
    }
}
