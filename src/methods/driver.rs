//! The driver: runs a method until its budget is spent or it is cancelled,
//! with progress callbacks and a convergence log.

use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Instant;

use super::{Method, MethodError, World};
use crate::film::Image;
use crate::metrics;
use crate::state::State;

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

impl Budget {
    /// Rejects limits that could never be reached or make no sense: a
    /// sample count or time that is not a finite number > 0 (NaN would run
    /// for ever: no comparison with it is ever true), or a ray or pass
    /// count of 0.
    pub fn validate(&self) -> Result<(), MethodError> {
        for (name, v) in [("--spp", self.spp), ("--time", self.time)] {
            if let Some(v) = v {
                if !(v.is_finite() && v > 0.0) {
                    return Err(MethodError(format!(
                        "{name} must be a finite number > 0, got {v}"
                    )));
                }
            }
        }
        for (name, v) in [("--rays", self.rays), ("passes", self.passes)] {
            if v == Some(0) {
                return Err(MethodError(format!("{name} must be at least 1, got 0")));
            }
        }
        Ok(())
    }

    /// The fraction of the time and ray limits that `elapsed` seconds and
    /// `rays` rays have spent (0 when there are none).
    fn spent(&self, elapsed: f64, rays: u64) -> f64 {
        let t = self.time.map_or(0.0, |t| elapsed / t);
        let r = self.rays.map_or(0.0, |r| rays as f64 / r as f64);
        t.max(r)
    }
}

/// Seconds of passes a method that batches them ([`Method::batches`]) is
/// given per call, at most: the progress, the cancel flag, checkpoints and
/// the log are served between calls.
const BATCH_SECONDS: f64 = 0.25;

/// Passes per call at most, for a method that batches them.
const MAX_BATCH: u64 = 64;

/// How many passes to give a method that batches them, one sample per
/// pixel each: as many as take about `granularity` seconds at `rate`
/// (seconds and rays per pass so far; one pass until a pass has been
/// measured), and no more than the budget has left, so that a budget of
/// passes, samples or rays is met as by single passes and a time budget
/// is overrun by at most one pass, as before.
fn batch_len(
    budget: &Budget,
    spp: f64,
    pass: u64,
    rays: u64,
    elapsed: f64,
    rate: Option<(f64, f64)>,
    granularity: f64,
) -> u64 {
    let Some((secs, rays_per_pass)) = rate else {
        return 1;
    };
    let fit = |room: f64, per: f64| {
        if per > 0.0 && room.is_finite() {
            (room / per).floor().max(1.0).min(MAX_BATCH as f64) as u64
        } else {
            MAX_BATCH
        }
    };
    let mut k = fit(granularity, secs);
    if let Some(t) = budget.time {
        k = k.min(fit(t - elapsed, secs));
    }
    if let Some(r) = budget.rays {
        k = k.min(fit(r.saturating_sub(rays) as f64, rays_per_pass));
    }
    if let Some(s) = budget.spp {
        k = k.min((s - spp).ceil().max(1.0).min(MAX_BATCH as f64) as u64);
    }
    if let Some(p) = budget.passes {
        k = k.min(p.saturating_sub(pass).max(1));
    }
    k
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
    /// What a method's setup is doing, while it runs ([`Setup::report`]:
    /// density's bake names its phases); None during the passes.
    pub phase: Option<&'static str>,
}

/// What a method's setup sees of the driver, for a setup that must itself
/// obey the budget and the cancel flag and show its progress (density's
/// bake traces particles until the budget says stop): see
/// [`Method::prepare_within`](super::Method::prepare_within).
pub struct Setup<'a> {
    /// The render's budget.
    pub budget: Budget,
    /// When the driver's clock started.
    pub start: Instant,
    /// The cancel flag, when the caller gave one.
    pub cancel: Option<&'a AtomicBool>,
    on_progress: &'a mut dyn FnMut(&Progress),
    last: f64,
}

impl Setup<'_> {
    /// Seconds since the driver's clock started.
    pub fn elapsed(&self) -> f64 {
        self.start.elapsed().as_secs_f64()
    }

    /// True once the cancel flag is set.
    pub fn cancelled(&self) -> bool {
        self.cancel.is_some_and(|c| c.load(Ordering::Relaxed))
    }

    /// Reports progress during the setup: `rays` so far, the method's own
    /// guess of the fraction of the whole render done (the driver takes the
    /// larger of it and the time and ray fractions it measures itself), and
    /// the phase.
    pub fn report(&mut self, rays: u64, fraction: f64, phase: &'static str) {
        let elapsed = self.elapsed();
        let f = fraction.max(self.budget.spent(elapsed, rays));
        self.last = self.last.max(f.clamp(0.0, 1.0));
        (self.on_progress)(&Progress {
            passes: 0,
            rays,
            elapsed,
            fraction: self.last,
            phase: Some(phase),
        });
    }
}

/// The outcome of a render.
pub struct RenderResult {
    /// The method's name.
    pub method: &'static str,
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
    /// The method's own statistics (phase timings, memory), when it keeps
    /// any ([`Method::report`]).
    pub report: Option<String>,
    /// The final state, when [`Hooks::keep_state`] asked for it and the
    /// method can give one ([`Method::state`]).
    pub state: Option<State>,
}

/// Where the state goes every so many seconds: the interval and the
/// function that writes the checkpoint.
pub type Checkpoint<'a> = (f64, &'a mut dyn FnMut(&State));

/// What a render keeps of its state besides the image: where it resumes
/// from, and when it hands its state out (checkpoints, shards). The
/// default does none of it.
#[derive(Default)]
pub struct Hooks<'a> {
    /// Continue from this state (a checkpoint) instead of from nothing:
    /// the method restores it after its setup, and the passes, rays and
    /// seconds go on from its counts, so that the budget is the whole
    /// render's. The setup's rays are not counted again.
    pub resume: Option<&'a State>,
    /// Every so many seconds, the state is handed to the function (which
    /// writes the checkpoint). The time this takes is not render time. A
    /// method without state ([`Method::state`] gives None) hands out
    /// nothing: check first ([`super::MethodConfig::check_resumable`]).
    pub checkpoint: Option<Checkpoint<'a>>,
    /// Put the final state into [`RenderResult::state`].
    pub keep_state: bool,
    /// Show the estimate while it converges (the live viewer).
    pub watch: Option<Watch<'a>>,
}

/// The method's state with the driver's counts filled in.
fn snapshot(method: &dyn Method, passes: u64, rays: u64, seconds: f64) -> Option<State> {
    method.state().map(|s| State {
        passes,
        rays,
        seconds,
        spp: method.spp(),
        ..s
    })
}

/// Runs a method until its budget is spent or `cancel` is set (Ctrl-C).
/// With a reference, records the relMSE every `log_every` seconds (and at the
/// end); the time spent computing the error is not counted as render time.
pub struct Driver<'a> {
    /// The budget.
    pub budget: Budget,
    /// Set from another thread to stop after the current pass (or the
    /// current passes of a method that batches them, at most
    /// [`BATCH_SECONDS`] of them).
    pub cancel: Option<&'a AtomicBool>,
    /// Reference image for the convergence log.
    pub reference: Option<&'a Image>,
    /// Seconds between log rows (0 disables intermediate rows).
    pub log_every: f64,
}

/// A watcher of the estimate while it converges (the live viewer): called
/// with the current image at most every `every` seconds of render time,
/// once the first pass is done and until the last (whose image the result
/// holds); the time [`Method::image`] and the call take is not counted as
/// render time, as for the convergence log.
pub struct Watch<'a> {
    /// Seconds of render time between calls.
    pub every: f64,
    /// Called with the current estimate and the progress it shows.
    pub on_image: &'a mut dyn FnMut(&Image, &Progress),
}

impl Driver<'_> {
    /// Runs `method`; `on_progress` is called after every pass (every
    /// call of [`Method::steps`] for a method that batches its passes).
    pub fn run(
        &self,
        method: &mut dyn Method,
        world: &World,
        on_progress: impl FnMut(&Progress),
    ) -> Result<RenderResult, MethodError> {
        self.run_with(method, world, Hooks::default(), on_progress)
    }

    /// [`Driver::run`] with hooks: resumes from a state, hands out the
    /// state now and then and at the end, and shows the estimate while it
    /// converges (see [`Hooks`]).
    pub fn run_with(
        &self,
        method: &mut dyn Method,
        world: &World,
        mut hooks: Hooks<'_>,
        mut on_progress: impl FnMut(&Progress),
    ) -> Result<RenderResult, MethodError> {
        self.budget.validate()?;
        let start = Instant::now();
        // time spent on logging and checkpoints, not rendering; a resumed
        // render starts from the seconds already spent
        let mut excluded = -hooks.resume.map_or(0.0, |s| s.seconds);

        // Setup runs inside the clock and its rays count toward the budget
        let mut setup = Setup {
            budget: self.budget,
            start,
            cancel: self.cancel,
            on_progress: &mut on_progress,
            last: 0.0,
        };
        let mut rays = method.prepare_within(world, &mut setup)?.rays;
        // The bar does not step back when the passes take over from a setup
        // that reported its own progress
        let shown = setup.last;
        let mut pass = 0u64;
        if let Some(state) = hooks.resume {
            method.restore(state)?;
            pass = state.passes;
            rays = state.rays;
        }
        let mut next_checkpoint = hooks.checkpoint.as_ref().map_or(f64::INFINITY, |c| c.0);
        let mut log = Vec::new();
        let mut next_log = self.log_every;
        let mut next_watch = 0.0;
        let mut interrupted = false;
        let budget = self.budget;
        let unlimited = budget.spp.is_none()
            && budget.time.is_none()
            && budget.rays.is_none()
            && budget.passes.is_none();
        // Seconds, pass and rays when the passes began: the rate of a pass
        // for a method that batches them
        let first = (start.elapsed().as_secs_f64() - excluded, pass, rays);
        // ... and the most seconds of them per call: the hooks' intervals
        let granularity = [
            hooks.checkpoint.as_ref().map(|c| c.0),
            hooks.watch.as_ref().map(|w| w.every),
            self.reference
                .filter(|_| self.log_every > 0.0)
                .map(|_| self.log_every),
        ]
        .into_iter()
        .flatten()
        .fold(BATCH_SECONDS, f64::min);
        loop {
            let elapsed = start.elapsed().as_secs_f64() - excluded;
            let mut fraction = budget.spent(elapsed, rays);
            if let Some(s) = budget.spp {
                fraction = fraction.max(method.spp() / s);
            }
            if let Some(p) = budget.passes {
                fraction = fraction.max(pass as f64 / p as f64);
            }
            if unlimited && pass >= 1 {
                fraction = 1.0;
            }
            let progress = Progress {
                passes: pass,
                rays,
                elapsed,
                fraction: fraction.max(shown).min(1.0),
                phase: None,
            };
            on_progress(&progress);
            if let Some(w) = hooks
                .watch
                .as_mut()
                .filter(|_| pass >= 1 && elapsed >= next_watch && progress.fraction < 1.0)
            {
                let t0 = Instant::now();
                (w.on_image)(&method.image(world), &progress);
                next_watch = elapsed + w.every;
                excluded += t0.elapsed().as_secs_f64();
            }
            if fraction >= 1.0 {
                break;
            }
            if self.cancel.is_some_and(|c| c.load(Ordering::Relaxed)) {
                interrupted = true;
                break;
            }
            let k = if method.batches() {
                let rate = (pass > first.1).then(|| {
                    let n = (pass - first.1) as f64;
                    ((elapsed - first.0) / n, (rays - first.2) as f64 / n)
                });
                batch_len(
                    &budget,
                    method.spp(),
                    pass,
                    rays,
                    elapsed,
                    rate,
                    granularity,
                )
            } else {
                1
            };
            let stats = method.steps(world, pass, k);
            rays += stats.rays;
            pass += k;
            if let Some((every, save)) = hooks.checkpoint.as_mut() {
                let now = start.elapsed().as_secs_f64() - excluded;
                if now >= next_checkpoint {
                    let t0 = Instant::now();
                    if let Some(s) = snapshot(method, pass, rays, now) {
                        save(&s);
                    }
                    next_checkpoint = now + *every;
                    excluded += t0.elapsed().as_secs_f64();
                }
            }
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
        let state = if hooks.keep_state {
            snapshot(method, pass, rays, seconds)
        } else {
            None
        };
        Ok(RenderResult {
            state,
            method: method.name(),
            report: method.report(),
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
