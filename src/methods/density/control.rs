//! How a bake is steered from outside: a cancel flag, the limits a
//! render's budget puts on particle tracing, and progress by phase.
//!
//! Only the length of phase 1 is chosen. The particles are traced in
//! batches of whole chunks (each a fair run of fewer particles, see
//! [`super::particles::Tracer`]), and before each batch
//! [`Control::may_trace`] asks whether the batch, the phases after it and
//! one view pass still fit the budget; the estimate then runs on what was
//! traced, with φ = Φ/(particles traced). Phase 2's time is predicted from
//! phase 1's ([`POST_PER_TRACE`]): both are linear in the hits, since the
//! kernel of eq. (2) covers about (C1/C2)² over-mesh vertices whatever n.
//! Phase 3 only reduces triangles, so under a time limit it stops where the
//! deadline would be passed and leaves the remaining surfaces over-meshed
//! ([`Control::may_decimate`]).
//!
//! The cancel flag is read between batches, by every chunk before it
//! starts, between the reads of phase 2 and between the slices of phase 3:
//! a cancelled bake returns [`super::DensityError::Cancelled`] promptly, and
//! its scratch directory goes with the unwinding of the bake.

use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Instant;

/// Phase 2 (grouping and estimation) takes about this many seconds per
/// second of phase 1 on the scenes we measured (see docs/notebook/density.md), with a
/// margin: the Cornell box, whose rays are cheap, is the worst case.
pub const POST_PER_TRACE: f64 = 1.3;

/// The phases of a bake, in order.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Phase {
    /// Phase 1: particle tracing (`done`/`total` in particles).
    Trace,
    /// Phase 1, end: grouping the hits by surface (the bucket sort).
    Group,
    /// Phase 2: density estimation (`done`/`total` in hits).
    Estimate,
    /// Phase 3: decimation (`done`/`total` in surfaces).
    Decimate,
    /// A lightmap's final gather (`done`/`total` in texels; the lightmap
    /// bake's alone).
    Gather,
}

impl Phase {
    /// The phase's name in progress lines.
    pub fn name(self) -> &'static str {
        match self {
            Phase::Trace => "tracing particles",
            Phase::Group => "grouping hits",
            Phase::Estimate => "estimating",
            Phase::Decimate => "decimating",
            Phase::Gather => "gathering",
        }
    }

    /// The phase's share of a bake's time and where it starts, for a
    /// fraction of the whole bake (the shares of the Cornell box's bake).
    fn span(self) -> (f64, f64) {
        match self {
            Phase::Trace => (0.0, 0.37),
            Phase::Group => (0.37, 0.03),
            Phase::Estimate => (0.4, 0.4),
            Phase::Decimate | Phase::Gather => (0.8, 0.2),
        }
    }
}

/// Progress of a bake, reported between units of work.
#[derive(Clone, Copy, Debug)]
pub struct Tick {
    /// The phase.
    pub phase: Phase,
    /// Work done in the phase.
    pub done: u64,
    /// Work of the whole phase (for phase 1 the particles asked for, which
    /// a budget may cut short).
    pub total: u64,
    /// Rays traced so far.
    pub rays: u64,
    /// Seconds since the clock started.
    pub elapsed: f64,
}

impl Tick {
    /// A guess of the fraction of the bake done, in [0, 1].
    pub fn bake_fraction(&self) -> f64 {
        let (a, w) = self.phase.span();
        let f = if self.total > 0 {
            self.done as f64 / self.total as f64
        } else {
            1.0
        };
        (a + w * f.clamp(0.0, 1.0)).min(1.0)
    }
}

/// Limits on a bake from a render's budget: the view pass that follows
/// needs time and rays too.
#[derive(Clone, Copy, Debug, Default)]
pub struct Limits {
    /// Seconds, from the clock's start, by which the render should end.
    pub time: Option<f64>,
    /// Rays the whole render may trace.
    pub rays: Option<u64>,
    /// Rays one view pass is expected to trace (reserved from both limits).
    pub view_rays: u64,
}

/// What steers a bake: the clock, the limits, the cancel flag and the
/// progress callback. [`Control::none`] steers nothing (a bake of every
/// particle asked for, silent, not cancellable).
pub struct Control<'a> {
    start: Instant,
    limits: Limits,
    cancel: Option<&'a AtomicBool>,
    on_tick: Option<&'a mut dyn FnMut(&Tick)>,
    /// When phase 1 started, and the seconds per view pass it predicts.
    trace_start: Option<Instant>,
    view_secs: f64,
    rays: u64,
}

impl<'a> Control<'a> {
    /// No limits, no cancel flag, no progress.
    pub fn none() -> Self {
        Self::new(Instant::now(), Limits::default(), None)
    }

    /// Limits counted from `start`, and a cancel flag.
    pub fn new(start: Instant, limits: Limits, cancel: Option<&'a AtomicBool>) -> Self {
        Control {
            start,
            limits,
            cancel,
            on_tick: None,
            trace_start: None,
            view_secs: 0.0,
            rays: 0,
        }
    }

    /// Calls `f` with the progress between units of work.
    pub fn on_tick(mut self, f: &'a mut dyn FnMut(&Tick)) -> Self {
        self.on_tick = Some(f);
        self
    }

    /// The cancel flag, for the workers of a phase.
    pub fn cancel_flag(&self) -> Option<&'a AtomicBool> {
        self.cancel
    }

    /// True once the cancel flag is set.
    pub fn cancelled(&self) -> bool {
        self.cancel.is_some_and(|c| c.load(Ordering::Relaxed))
    }

    /// Seconds since the clock started.
    pub fn elapsed(&self) -> f64 {
        self.start.elapsed().as_secs_f64()
    }

    /// Reports progress.
    pub fn tick(&mut self, phase: Phase, done: u64, total: u64) {
        let elapsed = self.elapsed();
        let rays = self.rays;
        if let Some(f) = self.on_tick.as_mut() {
            f(&Tick {
                phase,
                done,
                total,
                rays,
                elapsed,
            });
        }
    }

    /// Sets the rays traced so far (phase 1's particles).
    pub fn set_rays(&mut self, rays: u64) {
        self.rays = rays;
    }

    /// The rays traced so far.
    pub fn rays(&self) -> u64 {
        self.rays
    }

    /// [`super::DensityError::Cancelled`] once the cancel flag is set.
    pub fn check(&self) -> Result<(), super::DensityError> {
        if self.cancelled() {
            return Err(super::DensityError::Cancelled { rays: self.rays });
        }
        Ok(())
    }

    /// Marks the start of phase 1.
    pub fn start_tracing(&mut self) {
        self.trace_start = Some(Instant::now());
    }

    /// Whether one more batch fits, after batches that traced `rays` rays in
    /// all, the last of them `batch_rays` rays in `batch_secs` seconds: the
    /// batch, phase 2 for everything traced by then, and one view pass
    /// must end within the time limit, and the batch and one view pass
    /// within the ray limit.
    pub fn may_trace(&mut self, rays: u64, batch_rays: u64, batch_secs: f64) -> bool {
        if self.cancelled() {
            return false;
        }
        let traced_secs = self.trace_start.map_or(0.0, |t| t.elapsed().as_secs_f64());
        // A view pass traces rays at about phase 1's rate
        self.view_secs = self.limits.view_rays as f64 * traced_secs / rays.max(1) as f64;
        if let Some(r) = self.limits.rays {
            if rays + batch_rays + self.limits.view_rays > r {
                return false;
            }
        }
        if let Some(t) = self.limits.time {
            let end = self.elapsed()
                + batch_secs
                + POST_PER_TRACE * (traced_secs + batch_secs)
                + self.view_secs;
            if end > t - margin(t) {
                return false;
            }
        }
        true
    }

    /// Whether phase 3 may decimate one more slice: under a time limit,
    /// while one view pass still fits before the deadline.
    pub fn may_decimate(&self) -> bool {
        self.limits
            .time
            .is_none_or(|t| self.elapsed() + self.view_secs < t - margin(t))
    }
}

/// Time kept in hand under a time limit of `t` seconds, for what the
/// predictions miss.
fn margin(t: f64) -> f64 {
    0.03 * t + 0.1
}
