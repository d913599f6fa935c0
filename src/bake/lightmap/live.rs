//! A lightmap bake watched as it runs (`kalos bake --lightmap --view`):
//! between batches of particles, when the watcher asks ([`Watch::due`]),
//! the atlas is estimated from the particles traced so far and handed to
//! it ([`Watch::atlas`]), so that a viewer shows the lightmap refining.
//!
//! A preview is the final estimate's steps on a copy of the hits so far
//! (grouped, indexed, each texel's kernel), at every other texel in each
//! direction: a quarter of the texels, each of the others taking the mean
//! of its estimated neighbours in its chart, then padded as the final
//! atlas. So its texels cost a quarter of the final estimate's (on the
//! Cornell box at 512², a preview from 0.8 M particles took a fifth of the
//! final estimate from 4 M, grouping and indexing included). It draws no
//! random number and traces no particle: the bake's particles, and so its
//! final atlas, are the same with or without a watcher (under `--rays`;
//! under `--time` the previews' seconds count, so fewer particles fit).
//!
//! [`Cadence`] is the usual watcher's schedule: a first preview after a
//! few seconds of tracing, then each once the tracing since the last has
//! taken [`Cadence::RATIO`] times that preview's cost, so that previews
//! take at most 1/(1 + RATIO) of the bake.

use std::cell::RefCell;
use std::rc::Rc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Instant;

use super::bake::{dilate, LightmapSettings};
use super::estimate::{self, Estimator, HitIndex};
use super::{Lightmap, LightmapUv, Texel};
use crate::color::Rgb;
use crate::methods::density;
use crate::methods::density::control::{Phase, Tick};
use crate::methods::density::hitfile::HitFileError;
use crate::methods::density::hits::{Hit, HitSink, MemoryHits, MemoryWriter};
use crate::methods::density::particles;
use crate::methods::density::surfaces::Surfaces;
use crate::world::World;

/// Hears a lightmap bake as it runs.
pub trait Watch {
    /// The uv set is made and no particle is traced yet: the asset can be
    /// shown (with a black atlas).
    fn started(&mut self, uv: &LightmapUv);

    /// After a batch of particles (`tick`: phase 1's particles so far and
    /// the seconds since the bake's clock started): whether to estimate a
    /// preview of the atlas now.
    fn due(&mut self, tick: &Tick) -> bool;

    /// The preview asked for, from `particles` particles, padded as the
    /// final atlas; it took `seconds`.
    fn atlas(&mut self, lm: &Lightmap, particles: u64, seconds: f64);
}

/// When to estimate previews: the first after [`Cadence::every`] seconds
/// of tracing, each next one once the tracing since the last has taken
/// both `every` seconds and [`Cadence::RATIO`] times the last preview's
/// seconds.
#[derive(Clone, Debug)]
pub struct Cadence {
    /// The shortest tracing between two previews, in seconds.
    pub every: f64,
    /// When the last preview ended (or tracing started), in the ticks'
    /// seconds (when it started, while it runs).
    since: Option<f64>,
    /// The last preview's seconds.
    cost: f64,
}

impl Cadence {
    /// Tracing between two previews, over the last preview's cost: the
    /// previews take at most 1/(1 + RATIO) of the bake's time (20 %).
    pub const RATIO: f64 = 4.0;

    /// A schedule of a preview at most every `every` seconds.
    pub fn new(every: f64) -> Self {
        Cadence {
            every,
            since: None,
            cost: 0.0,
        }
    }

    /// Whether a preview is due at `tick` (then [`Cadence::done`] must
    /// follow, with its cost).
    pub fn due(&mut self, tick: &Tick) -> bool {
        if tick.phase != Phase::Trace {
            return false;
        }
        let since = *self.since.get_or_insert(tick.elapsed);
        // nothing traced yet, or everything: the final atlas comes next
        if tick.done == 0 || tick.done >= tick.total {
            return false;
        }
        let due = tick.elapsed - since >= self.every.max(Self::RATIO * self.cost);
        if due {
            self.since = Some(tick.elapsed);
        }
        due
    }

    /// Records that the preview last due took `seconds`.
    pub fn done(&mut self, seconds: f64) {
        self.since = self.since.map(|t| t + seconds);
        self.cost = seconds;
    }
}

/// The hits as they are traced: phase 1 pushes into them, the previews
/// read a copy between batches.
#[derive(Clone, Default)]
pub(crate) struct SharedHits(Rc<RefCell<MemoryWriter>>);

impl SharedHits {
    /// The hits so far, grouped (a copy).
    fn grouped(&self) -> Result<MemoryHits, HitFileError> {
        let copy = self.0.borrow().clone();
        copy.finish()
    }
}

impl HitSink for SharedHits {
    type Source = MemoryHits;

    fn push(&mut self, hits: &[Hit]) -> Result<(), HitFileError> {
        self.0.borrow_mut().push(hits)
    }

    fn finish(self) -> Result<MemoryHits, HitFileError> {
        std::mem::take(&mut *self.0.borrow_mut()).finish()
    }
}

/// What a preview reads, and the watcher it is for.
pub(crate) struct Previews<'a> {
    watch: &'a mut dyn Watch,
    world: &'a World,
    surfaces: &'a Surfaces,
    /// The texels estimated: those at even (x, y), and those with no
    /// such texel of their chart among their eight neighbours.
    texels: Vec<Texel>,
    /// Every texel a triangle covers.
    covered: Vec<bool>,
    /// Each texel's chart ([`NO_CHART`]: none).
    chart: Vec<u32>,
    width: u32,
    height: u32,
    settings: &'a density::Settings,
    lm: &'a LightmapSettings,
    hits: SharedHits,
    cancel: Option<&'a AtomicBool>,
    /// The power of all the luminaires: φ = power / particles.
    power: f64,
}

impl<'a> Previews<'a> {
    /// Previews of the bake of `texels` on `uv` for `watch`, reading
    /// `hits`; tells `watch` the uv set is made.
    #[allow(clippy::too_many_arguments)]
    pub(crate) fn new(
        watch: &'a mut dyn Watch,
        world: &'a World,
        surfaces: &'a Surfaces,
        uv: &LightmapUv,
        texels: &[Texel],
        settings: &'a density::Settings,
        lm: &'a LightmapSettings,
        hits: SharedHits,
        cancel: Option<&'a AtomicBool>,
    ) -> Self {
        watch.started(uv);
        let (w, h) = (uv.width, uv.height);
        let mut chart = vec![NO_CHART; w as usize * h as usize];
        for t in texels.iter().filter(|t| t.x < w && t.y < h) {
            let c = uv.tri_chart.get(t.tri as usize).copied();
            chart[(t.y * w + t.x) as usize] = c.unwrap_or(NO_CHART - 1);
        }
        let even = |x: u32, y: u32| x.is_multiple_of(2) && y.is_multiple_of(2);
        let texels = texels
            .iter()
            .filter(|t| {
                let c = chart[(t.y.min(h - 1) * w + t.x.min(w - 1)) as usize];
                even(t.x, t.y)
                    || neighbours(w, h, t.x, t.y).all(|(x, y, k)| !even(x, y) || chart[k] != c)
            })
            .copied()
            .collect();
        let covered = chart.iter().map(|c| *c != NO_CHART).collect();
        Previews {
            watch,
            world,
            surfaces,
            texels,
            covered,
            chart,
            width: w,
            height: h,
            settings,
            lm,
            hits,
            cancel,
            power: particles::phi_unit(&particles::luminaires(world), 1),
        }
    }

    /// After a batch: a preview, when the watcher wants one.
    pub(crate) fn tick(&mut self, t: &Tick) {
        if t.phase != Phase::Trace || !self.watch.due(t) {
            return;
        }
        let start = Instant::now();
        // a preview the cancel flag cut short is not shown
        if let Some(lm) = self.preview(t.done).filter(|_| !self.cancelled()) {
            self.watch.atlas(&lm, t.done, start.elapsed().as_secs_f64());
        }
    }

    fn cancelled(&self) -> bool {
        self.cancel.is_some_and(|c| c.load(Ordering::Relaxed))
    }

    /// The atlas from the hits of `particles` particles (per channel), as
    /// bake.rs estimates the final one, at a quarter of the texels.
    fn preview(&self, particles: u64) -> Option<Lightmap> {
        let hits = self.hits.grouped().ok()?;
        let index = HitIndex::build(
            self.world,
            self.surfaces,
            &hits,
            self.settings.chunk_hits as u64,
        )
        .ok()?;
        drop(hits);
        let phi = self.power / particles.max(1) as f64;
        let est = Estimator::new(self.world, self.surfaces, &index, phi, self.lm.estimator);
        let (w, h) = (self.width, self.height);
        let mut lm =
            estimate::estimate_texels(&est, &self.texels, w, h, self.cancel, &mut |_, _| {});
        self.fill(&mut lm);
        lm.covered.clone_from(&self.covered);
        dilate(&mut lm, 2);
        Some(lm)
    }

    /// Gives each covered texel not estimated the mean of its estimated
    /// neighbours of the same chart (every one has one).
    fn fill(&self, lm: &mut Lightmap) {
        let (w, h) = (self.width, self.height);
        let estimated = lm.covered.clone();
        for y in 0..h {
            for x in 0..w {
                let k = (y * w + x) as usize;
                if estimated[k] || self.chart[k] == NO_CHART {
                    continue;
                }
                let (mut e, mut se, mut n) = (Rgb::ZERO, Rgb::ZERO, 0.0f32);
                for (_, _, j) in neighbours(w, h, x, y) {
                    if estimated[j] && self.chart[j] == self.chart[k] {
                        e += lm.irradiance[j];
                        se += lm.std_error[j];
                        n += 1.0;
                    }
                }
                if n > 0.0 {
                    lm.irradiance[k] = e / n;
                    lm.std_error[k] = se / n;
                }
            }
        }
    }
}

/// A texel of no chart.
const NO_CHART: u32 = u32::MAX;

/// The texels of the 3×3 block about (x, y) inside a `w` × `h` atlas, (x,
/// y) included, with their indices.
fn neighbours(w: u32, h: u32, x: u32, y: u32) -> impl Iterator<Item = (u32, u32, usize)> {
    (y.saturating_sub(1)..(y + 2).min(h)).flat_map(move |ny| {
        (x.saturating_sub(1)..(x + 2).min(w)).map(move |nx| (nx, ny, (ny * w + nx) as usize))
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::bake::lightmap::bake::{bake_lightmap, bake_lightmap_watched, Steering};

    fn tick(done: u64, total: u64, elapsed: f64) -> Tick {
        Tick {
            phase: Phase::Trace,
            done,
            total,
            rays: 0,
            elapsed,
        }
    }

    #[test]
    fn the_cadence_waits_for_its_seconds_then_for_four_times_the_last_cost() {
        let mut c = Cadence::new(2.0);
        // tracing starts at 1 s: nothing traced yet
        assert!(!c.due(&tick(0, 100, 1.0)));
        assert!(!c.due(&tick(10, 100, 2.9)));
        assert!(c.due(&tick(20, 100, 3.0)));
        // that preview took 1 s: the next after 4 s more of tracing
        c.done(1.0);
        assert!(!c.due(&tick(30, 100, 7.9)));
        assert!(c.due(&tick(40, 100, 8.0)));
        c.done(0.1);
        // a cheap one: `every` again
        assert!(!c.due(&tick(50, 100, 9.9)));
        assert!(c.due(&tick(60, 100, 10.1)));
        c.done(0.1);
        // never once every particle is traced, nor in another phase
        assert!(!c.due(&tick(100, 100, 50.0)));
        let mut other = tick(5, 10, 50.0);
        other.phase = Phase::Estimate;
        assert!(!c.due(&other));
    }

    /// Keeps every preview.
    struct Keep {
        cadence: Cadence,
        uv: Option<(u32, u32)>,
        previews: Vec<(Lightmap, u64)>,
    }

    impl Watch for Keep {
        fn started(&mut self, uv: &LightmapUv) {
            self.uv = Some((uv.width, uv.height));
        }
        fn due(&mut self, tick: &Tick) -> bool {
            self.cadence.due(tick)
        }
        fn atlas(&mut self, lm: &Lightmap, particles: u64, seconds: f64) {
            self.cadence.done(seconds);
            self.previews.push((lm.clone(), particles));
        }
    }

    fn fin_count(covered: &[bool]) -> usize {
        covered.iter().filter(|c| **c).count()
    }

    #[test]
    fn a_watched_bake_gives_previews_and_the_same_atlas() {
        let world = World::new(crate::scene::builtin::cornell_box().expect("built in"));
        // more particles than one batch, so that a preview comes between
        let s = density::Settings {
            particles: 700_000,
            seed: 3,
            ..Default::default()
        };
        let lm = LightmapSettings {
            size: Some(32),
            ..Default::default()
        };
        fn steer<'a>(on_tick: &'a mut dyn FnMut(&Tick)) -> Steering<'a> {
            Steering::unlimited(on_tick)
        }
        let (mut quiet, mut quiet2) = (|_: &Tick| {}, |_: &Tick| {});
        let plain = bake_lightmap(&world, &s, &lm, steer(&mut quiet)).expect("baked");
        let mut keep = Keep {
            cadence: Cadence::new(0.0),
            uv: None,
            previews: Vec::new(),
        };
        let watched = bake_lightmap_watched(&world, &s, &lm, steer(&mut quiet2), Some(&mut keep))
            .expect("baked");
        assert_eq!(keep.uv, Some((32, 32)));
        assert_eq!(plain.lightmap.irradiance, watched.lightmap.irradiance);
        assert_eq!(plain.lightmap.std_error, watched.lightmap.std_error);
        assert_eq!(plain.stats.particles, watched.stats.particles);
        let (first, particles) = keep.previews.first().expect("a preview");
        assert!(*particles > 0 && *particles < s.particles);
        // the preview covers what the uv set covers; the final leaves out
        // besides the texels its leak test finds hidden (inside a solid),
        // which a preview tests at only a quarter of the texels
        assert!(watched
            .lightmap
            .covered
            .iter()
            .zip(&first.covered)
            .all(|(f, p)| !*f || *p));
        let hidden =
            first.covered.iter().filter(|c| **c).count() - fin_count(&watched.lightmap.covered);
        assert!(hidden * 10 < fin_count(&watched.lightmap.covered));
        // every covered texel has a value, near the final one on average
        let fin = &watched.lightmap;
        // the texels both cover, in the same order
        let both = |lm: &'_ Lightmap| {
            (0..lm.covered.len())
                .filter(|&k| first.covered[k] && fin.covered[k])
                .map(|k| crate::color::luminance(lm.irradiance[k]))
                .collect::<Vec<f32>>()
        };
        let (p, f) = (both(first), both(fin));
        // black where the final is not (the final is black on the light,
        // which has no diffuse part, and under the boxes, from where a
        // preview's texel next to them takes its neighbour's black)
        let black = p
            .iter()
            .zip(&f)
            .filter(|(p, f)| **p <= 0.0 && **f > 0.0)
            .count();
        let black_final = f.iter().filter(|f| **f <= 0.0).count();
        assert!(
            black * 50 <= p.len(),
            "{black} of {} black, the final {black_final}",
            p.len()
        );
        let (mp, mf) = (
            p.iter().sum::<f32>() / p.len() as f32,
            f.iter().sum::<f32>() / f.len() as f32,
        );
        assert!((mp / mf - 1.0).abs() < 0.1, "preview {mp}, final {mf}");
    }
}
