//! `plb`: progressive light path building (Szirmay-Kalos, Antal and Sbert),
//! self-correcting iteration over a population of photon hits.
//!
//! Each step of `iterate` is the paper's `Iterate`: pick hit i with
//! probability s_i or the lights with probability 1 − Σs_i; shoot from the
//! light, or reflect hit i into a direction sampled from its cosine-weighted
//! BSDF, with the listing's power weights (Φ_e/(1 − Σs_i), or
//! Φ_i f cos/(p s_i)); multiply every stored power by (1 − 1/m); trace; and
//! append the new hit with power Φ/m and its parent. The (1 − 1/m) scaling is
//! lazy: hits store their power in units of a per-lane factor σ, and only σ is
//! multiplied.
//!
//! Steps are grouped into phases (§4, §5; 400 steps by default). At the end
//! of a phase, in this order: the phase image M L_m (the lights' image plus
//! every hit connected to the camera with g(x), the BSDF in importance
//! mode), `ComputeImportance` (eqs. (8), (9) and λ), and the random purge
//! (survival k_i ∝ s_i, survivors' power divided by k_i, expected population
//! capped). The final image is the average of the phase images.
//!
//! Choices the paper leaves open, made here (each is cited where it is coded):
//! - *Lights against hits.* `ComputeImportance` normalises Σs_i to 1, which
//!   would never pick the light again; the lights must keep a positive
//!   probability for E\[T*L\] = TL. The split is §3's power rule: the lights
//!   are chosen with Φ_e / (Φ_e + Σ Lum(Φ_i a_i)) (for a closed scene 1 − ā,
//!   as the paper says of s), and the rest is shared among the hits in
//!   proportion to their importance.
//! - *Hits born during a phase* have importance = potential impact, eq. (9),
//!   until the next `ComputeImportance` (they have no children yet), so that
//!   every hit can spawn at once (again needed for E\[T*L\] = TL).
//! - *The step counter m across phases.* The survivors of a purge carry the
//!   estimate L_m; restarting m at 1 would erase them (τ_1 = 1) and keep the
//!   start-up defect of a 400-step run in every phase, while letting m grow
//!   for ever would freeze the few survivors (new hits get weight 1/m → 0).
//!   Here the first phase runs m = 1…P and every later phase m = P+1…2P: the
//!   survivors count as P steps of history. The expected estimate then obeys
//!   E_m = E_{m−1} + (Le + T E_{m−1} − E_{m−1})/m, whose error shrinks by
//!   about 2^−(1−a) per phase, so the phase images become unbiased
//!   geometrically fast and the average of N phase images has a start-up
//!   defect of order 1/N (measured in tests/plb.rs). `--discard K` drops the
//!   first K phases of each lane from the average.
//! - *Importance after the purge.* The importance of eqs. (8)–(9) is an
//!   impact, linear in the hit's power, so a survivor whose power is divided
//!   by k_i has its importance divided by k_i too (this keeps the ratio
//!   Φ_i/s_i that the spawned ray's weight depends on).
//! - *The lights' own image* (the Le term of every phase image) is estimated
//!   from the emission samples that the light-selection steps take anyway,
//!   each weighted by 1/P(light), and averaged over all steps.
//! - *The camera connection of a hit* is deterministic (one visibility ray),
//!   so it is made once, when the hit is born, and kept in the hit record as
//!   its image contribution; later phase images rescale it with the hit's
//!   power instead of tracing it again.
//! - Delta surfaces (mirrors, smooth glass) cannot be measured nor hold a
//!   useful hit: a ray passes through delta chains to the first non-delta
//!   point, as in `light --variant iteration`
//!   ([`crate::transport::follow_delta_chain`]).
//!
//! Forms (`--variant`). `paper` is the method exactly as published (the
//! choices above are where the paper is silent). Two forms are ours:
//!
//! - `pooled`: eq. (9) has no visibility in it, and eq. (8) judges a hit
//!   by its own one or two children, so on a scene lit through a gap the
//!   paper's importance barely prefers the hits that matter (docs/notebook/plb.md,
//!   plb diagnosis). The pooled rule keeps, per cell of a 16³ grid over the
//!   scene, the mean image impact per unit power of every ray ever spawned
//!   from that cell (`ImportanceGrid`), and sets a hit's importance to its
//!   output luminance times that mean (shrunk toward the global mean, with
//!   a floor so that every hit can still spawn). The iteration, power
//!   weights, phases and purge are unchanged, so it is unbiased for the
//!   same reason; only where the next ray starts changes.
//! - `guided` (the default) builds on `pooled`:
//!   - a ray's value counts what its landing point passes on, its output
//!     luminance times its own cell's value, not only what it shows the
//!     camera (`iterate::landing_value`), so a landing hidden behind a
//!     screen is worth its onward light;
//!   - spawned rays, and the rays the lights emit, are drawn from a
//!     mixture of the BSDF (the emitter's cosine) and a learnt directional
//!     histogram per cell, with the mixture pdf in the weight (`guide`);
//!   - the lights are chosen by importance (their power times the value
//!     of their rays) against the hits, floored at a tenth of their share
//!     by power;
//!   - each hit is measured once, at birth (`--measure birth`, also
//!     available to the other forms): the image averages over the steps the
//!     camera contribution of each new hit at the power Φ of the ray that
//!     made it. Each step's new hit has expected power T(Le + L_{m−1}), so
//!     this has the phase images' expectation without the purge's noise;
//!   - the camera pass takes glossy first vertices too, sharing the sharp
//!     lobes (peak density at least κ) with the light paths by MIS
//!     ([`crate::transport::camera_pass`]);
//!   - plain light-tracing walks run beside the population (`--mix`, on
//!     by default) and the two images are combined by their variances
//!     measured across lanes, each pass's work going mostly to the one
//!     with less variance per unit of work (`mix`): where light arrives
//!     easily (a Cornell box) the walks carry the image, where it does
//!     not (a gap) the population does;
//!   - on scenes where no camera pass is needed, `path`'s estimator runs
//!     beside them as a third estimate (`--mix-path`, on by default),
//!     measured by its pixels' spread; it takes the walks' place where
//!     they beat the population and it beats them: on cbox, where
//!     next-event estimation finds the light at every vertex, so the
//!     default method is not 3–4× behind `path` there.
//!
//!   Every change moves where rays go or when they are counted, never the
//!   expectation (tests/it/plb.rs checks each form against `path`, light
//!   or the Mitsuba reference).
//!
//! Parallelism: a fixed number of lanes (8), each with its own population,
//! films and random streams keyed by (seed, pass, lane); lanes are merged in
//! order, so a seed gives the same image whatever the thread count.
//!
//! ```text
//! kalos render scenes/two-rooms/scene.xml --method plb --time 30 -o p.exr
//! kalos render scenes/two-rooms/scene.xml --method plb --variant paper --lambda 1 --phase-len 400 --population 100 --rays 30M -o p.exr
//! ```

use rayon::prelude::*;

use super::{
    camera_pass, film_item, no_exact_merge, Common, Method, MethodError, MethodSettings, StepStats,
    World, FILM, IMAGE,
};
use crate::film::{Film, Image};
use crate::memory::MemoryItem;
use crate::sampling::{Pcg32, SamplerKind};
use crate::state::{ShardKind, State};
use crate::transport::camera_pass::CameraPass;
use crate::transport::{DepthLimits, Roulette, WalkKind};

mod guide;
mod importance;
mod iterate;
mod mix;
mod purge;

use std::sync::Arc;

use guide::{DirGuide, DirStats};
use importance::{share_grids, CellStats, ImportanceGrid, SLOTS};
use iterate::{run_lane, Form, Lane};
use mix::{run_walks, Mix, PathArm};

/// Settings of progressive light path building.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields)]
#[cfg_attr(feature = "cli", derive(clap::Args))]
pub struct Settings {
    /// Master seed (set from [`super::Common`]).
    #[cfg_attr(feature = "cli", arg(skip))]
    pub seed: u64,
    /// Longest path in segments; None = unlimited (set from [`super::Common`]).
    #[cfg_attr(feature = "cli", arg(skip))]
    pub max_depth: Option<u32>,
    /// λ: weight of the children's measured image impact, eq. (8), against
    /// the potential impact, eq. (9), in `ComputeImportance`.
    #[cfg_attr(feature = "cli", arg(long, default_value_t = 1.0))]
    pub lambda: f32,
    /// Steps per phase (the paper: 400).
    #[cfg_attr(feature = "cli", arg(long, default_value_t = 400))]
    pub phase_len: u32,
    /// Population cap: the expected number of hits that survive a purge.
    #[cfg_attr(feature = "cli", arg(long, default_value_t = 1000))]
    pub population: usize,
    /// Independent lanes (populations, films, streams); fixed so that
    /// results do not depend on the thread count.
    #[cfg_attr(feature = "cli", arg(skip = 8usize))]
    pub lanes: usize,
    /// Steps per pass over all lanes; 0 means about one per pixel (rounded
    /// up to whole phases).
    #[cfg_attr(feature = "cli", arg(skip))]
    pub steps_per_pass: u64,
    /// Phases dropped from the average at the start of each lane.
    #[cfg_attr(feature = "cli", arg(long, default_value_t = 0))]
    pub discard: u64,
    /// The camera pass, which estimates from the camera what light paths
    /// cannot reach (delta surfaces seen by the camera, the environment)
    /// and, with `--variant guided`, shares sharp glossy surfaces seen by
    /// the camera with the light paths by MIS: on, or off for the raw method.
    #[cfg_attr(feature = "cli", arg(long, value_name = "on|off", default_value = "on", value_parser = super::cli::on_off, action = clap::ArgAction::Set))]
    pub camera_pass: bool,
    /// Which form of the method: the paper's (§3, eqs. 8–9, measured at
    /// every phase end), `pooled` importance, or kalos's `guided` form
    /// (pooled importance learnt through the path, directional guiding of
    /// spawned and emitted rays, each hit measured once, the glossy camera
    /// pass).
    #[cfg_attr(
        feature = "cli",
        arg(long, value_name = "VARIANT", value_enum, default_value = "guided")
    )]
    pub variant: Variant,
    /// When a hit's camera contribution enters the image: at every phase
    /// end with its current power (the paper's phase images, §5), or once,
    /// at birth. Unset: the variant's own (`paper` and `pooled`: phase,
    /// `guided`: birth).
    #[cfg_attr(feature = "cli", arg(long, value_name = "WHEN", value_enum))]
    pub measure: Option<Measure>,
    /// `--variant guided` only: run plain light-tracing walks beside the
    /// population and combine the two images by their measured variances,
    /// giving each pass's work mostly to the one that does better per unit
    /// of work (`mix`), so that plb does not lose to `light` where light
    /// arrives easily. Off: plb alone. The other variants never mix.
    #[cfg_attr(feature = "cli", arg(long, value_name = "on|off", default_value = "on", value_parser = super::cli::on_off, action = clap::ArgAction::Set))]
    #[serde(default = "mix_default")]
    pub mix: bool,
    /// With `--mix on`: run `path`'s estimator beside the light paths too,
    /// as a third estimate of the image in the same combination, on scenes
    /// where the light paths estimate the whole image (no camera pass is
    /// needed: no delta lobe, no glossy lobe that is or may be sharp, no
    /// environment).
    /// It takes the walks' place where they beat the population and it
    /// does better per unit of work than they do (a Cornell box, where it
    /// finds the light by next-event estimation); where light arrives
    /// through a gap, the population keeps the work (`mix`). Off: the
    /// population and the walks only. A partial-result file without the
    /// field was written without it.
    #[cfg_attr(feature = "cli", arg(long, value_name = "on|off", default_value = "on", value_parser = super::cli::on_off, action = clap::ArgAction::Set))]
    #[serde(default)]
    pub mix_path: bool,
    /// The numbers the camera pass and the mixed walks draw:
    /// Owen-scrambled Sobol points (the default), or independent ones
    /// (PCG32 streams). The camera pass's are per pixel, the pass as the
    /// sample index ([`crate::transport::camera_pass`]); the mixed walks'
    /// are `light`'s, walk k of a pass taking point k, eight walks at a
    /// time in AVX lanes (`mix`). The population draws independent numbers
    /// either way. Per sample, the camera pass's Sobol relMSE against
    /// independent's on glass-mirror: 0.77 at 64 spp, 0.89 at 256 (8
    /// seeds), at 1.003× the instructions (docs/notebook/light.md); the
    /// walks in lanes took plb on cbox from 1.22× light's error at equal
    /// time to 1.01× (docs/notebook/plb.md). A partial-result file without
    /// the field was written with independent numbers.
    #[cfg_attr(feature = "cli", arg(long, value_enum, default_value = "sobol"))]
    #[serde(default, skip_serializing_if = "SamplerKind::is_independent")]
    pub sampler: SamplerKind,
}

fn mix_default() -> bool {
    true
}

/// The form of the method.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "kebab-case")]
#[cfg_attr(feature = "cli", derive(clap::ValueEnum))]
pub enum Variant {
    /// §3.1 as the paper gives it: potential impact (eq. (9)) plus λ times
    /// the children's measured impact (eq. (8)); rays spawned by BSDF
    /// sampling, the lights chosen by power.
    Paper,
    /// Not in the paper: the output luminance times the measured image
    /// impact per unit power of the rays spawned from the same grid cell,
    /// pooled over all hits ever spawned there, with a defensive floor
    /// (`importance::ImportanceGrid`). Otherwise the paper's method.
    Pooled,
    /// kalos's form (the default), not in the paper: pooled importance
    /// that counts what a ray's landing point passes on (not only what it
    /// shows the camera directly), spawned and emitted rays drawn from a
    /// mixture of the BSDF (or the emitter's cosine) and a learnt
    /// directional distribution per grid cell (`guide`), the lights chosen
    /// by importance, hits measured at birth, and the camera pass extended
    /// to glossy surfaces with MIS.
    Guided,
}

/// When a hit's camera contribution is measured.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "kebab-case")]
#[cfg_attr(feature = "cli", derive(clap::ValueEnum))]
pub enum Measure {
    /// At every phase end, at the hit's current power (§5): the phase image
    /// M L_m; the final image averages the phase images.
    Phase,
    /// Once, when the hit is born, at the power of the ray that made it
    /// (Φ, not Φ/m); the final image averages over the steps. Same
    /// expectation as the phase images (each step's new hit has expected
    /// power T(Le + L_{m−1}), the same operator the phase images average),
    /// without the purge's noise in the measurement.
    Birth,
}

impl Variant {
    /// The measurement this variant uses unless `--measure` says otherwise.
    pub fn default_measure(self) -> Measure {
        match self {
            Variant::Paper | Variant::Pooled => Measure::Phase,
            Variant::Guided => Measure::Birth,
        }
    }
}

impl Default for Settings {
    fn default() -> Self {
        Settings {
            seed: 0,
            max_depth: None,
            lambda: 1.0,
            phase_len: 400,
            population: 1000,
            lanes: 8,
            steps_per_pass: 0,
            discard: 0,
            camera_pass: true,
            variant: Variant::Guided,
            measure: None,
            mix: true,
            mix_path: true,
            sampler: SamplerKind::Sobol,
        }
    }
}

impl Settings {
    /// Rejects settings that cannot work.
    pub fn validate(&self) -> Result<(), MethodError> {
        if !(self.lambda.is_finite() && self.lambda >= 0.0) {
            return Err(MethodError(format!(
                "--lambda must be a finite number ≥ 0, got {}",
                self.lambda
            )));
        }
        if self.phase_len == 0 {
            return Err(MethodError("--phase-len must be at least 1".into()));
        }
        if self.population == 0 {
            return Err(MethodError("--population must be at least 1".into()));
        }
        if self.lanes == 0 {
            return Err(MethodError("plb needs at least one lane".into()));
        }
        Ok(())
    }

    /// Whether light-tracing walks run beside the population (`--mix`,
    /// guided only).
    pub fn mixes(&self) -> bool {
        self.mix && self.variant == Variant::Guided
    }

    /// Bytes of the hit populations at their largest, for the memory check
    /// before a render ([`crate::render::memory_estimate`]): per lane, the
    /// cap plus the phase's new hits (each step appends one, the purge at
    /// the phase's end brings them back to the cap), each with its prefix
    /// sum and the purge's two buffers (its importance, its new index), and
    /// its [`iterate::Measured`] part when the form keeps one.
    pub fn population_bytes(&self) -> u64 {
        let measured = if iterate::Form::of(self).measured {
            std::mem::size_of::<iterate::Measured>()
        } else {
            0
        };
        let per_hit = (std::mem::size_of::<iterate::Hit>()
            + measured
            + 2 * std::mem::size_of::<f64>()
            + std::mem::size_of::<u32>()) as u64;
        let hits = self.population as u64 + u64::from(self.phase_len);
        self.lanes as u64 * hits * per_hit
    }
}

impl MethodSettings for Settings {
    fn validate(&self) -> Result<(), MethodError> {
        Settings::validate(self)
    }

    /// Chains: each shard is an independent population with its own seed.
    fn shard_kind(&self) -> Result<ShardKind, MethodError> {
        Ok(ShardKind::Chains)
    }

    fn check_shard_count(&self, _count: u32) -> Result<(), MethodError> {
        Ok(())
    }

    fn resumable(&self) -> Result<(), &'static str> {
        Err("its population of photon hits is not saved")
    }

    fn merge_exact(&self, _: &[&State], _: u32, _: u32) -> Result<Image, MethodError> {
        Err(no_exact_merge("plb"))
    }

    /// Two films per lane (light and hits), their two merges and images,
    /// the final image, the camera pass; when mixing, the walks' films,
    /// their merge and image, and a copy of each lane's two films (the
    /// pass's own image is measured against it), and with `--mix-path` the
    /// path arm's film, its squares and its image; and the populations.
    fn memory(&self, width: u32, height: u32) -> Vec<MemoryItem> {
        let lanes = self.lanes.max(1) as u64;
        // The path arm: its film, its squares and its image (counted
        // whenever it may run: the scene decides at the start)
        let path = if self.mix_path { 2 * FILM + IMAGE } else { 0 };
        let mix = if self.mixes() {
            (mix::LANES as u64 + 1 + 2 * lanes) * FILM + IMAGE + path
        } else {
            0
        };
        vec![
            film_item(
                width,
                height,
                (2 * lanes + 2) * FILM + 3 * IMAGE + camera_pass(self.camera_pass) + mix,
                &format!(" ({lanes} lanes)"),
            ),
            MemoryItem {
                what: format!(
                    "plb's populations ({} lanes of {} hits)",
                    self.lanes, self.population
                ),
                bytes: self.population_bytes(),
                remedy: "lower --population",
            },
        ]
    }

    fn create(&self, world: &World, common: &Common) -> Box<dyn Method> {
        Box::new(Plb::new(
            world,
            Settings {
                seed: common.seed,
                max_depth: common.max_depth,
                ..self.clone()
            },
        ))
    }
}

/// The progressive state of light path building.
pub struct Plb {
    settings: Settings,
    /// The merged pooled-importance grid (`--variant pooled`, `guided`).
    shared: Option<CellStats>,
    /// The merged directional records and the densities built from them
    /// (`--variant guided`).
    shared_dirs: Option<(DirStats, Arc<DirGuide>)>,
    lanes: Vec<Lane>,
    /// The light-tracing walks beside the population (`--mix`).
    mix: Option<Mix>,
    pixels: u64,
    camera_pass: CameraPass,
}

impl Plb {
    /// Light path building for `world`.
    pub fn new(world: &World, settings: Settings) -> Self {
        let (w, h) = (world.camera.width, world.camera.height);
        let n = settings.lanes.max(1);
        let pooled = settings.variant != Variant::Paper;
        let guided = settings.variant == Variant::Guided;
        let camera_pass = CameraPass::new(
            world,
            settings.camera_pass,
            guided,
            settings.seed,
            settings.max_depth,
            settings.sampler,
        );
        // `path` beside the light paths where they estimate the whole
        // image: the camera pass on, and needed nowhere in this scene. Its
        // own seed, so that its samples are not `path --seed`'s
        let arm = settings.mixes() && settings.mix_path;
        let path = (arm && settings.camera_pass && !camera_pass.is_active()).then(|| {
            let limits = DepthLimits {
                max_depth: settings.max_depth,
                ..Default::default()
            };
            let seed = crate::sampling::mix64(settings.seed ^ 0x7061_7468_6172_6d00);
            PathArm::new(w, h, seed, limits, settings.sampler)
        });
        Plb {
            camera_pass,
            lanes: (0..n)
                .map(|_| {
                    let grid = pooled.then(|| {
                        let (lo, hi) = world.scene.bounds();
                        ImportanceGrid::new(lo, hi)
                    });
                    Lane::new(w, h, grid, guided.then(Vec::new))
                })
                .collect(),
            mix: settings.mixes().then(|| Mix::new(w, h, path)),
            shared: pooled.then(|| CellStats::new(SLOTS)),
            shared_dirs: guided.then(|| (DirStats::new(SLOTS), Arc::new(DirGuide::new(SLOTS)))),
            settings,
            pixels: w as u64 * h as u64,
        }
    }

    /// Steps per lane and pass: whole phases.
    fn steps_per_lane(&self) -> u64 {
        let total = if self.settings.steps_per_pass > 0 {
            self.settings.steps_per_pass
        } else {
            self.pixels
        };
        let p = self.settings.phase_len.max(1) as u64;
        let lanes = self.lanes.len() as u64;
        total.div_ceil(lanes * p).max(1) * p
    }

    /// Phases completed and counted, summed over lanes (for tests and logs).
    pub fn phases(&self) -> (u64, u64) {
        self.lanes
            .iter()
            .fold((0, 0), |(a, b), l| (a + l.phases, b + l.counted))
    }

    /// The final image: the lights' image averaged over all steps plus the
    /// hits' image averaged over the counted phases, lanes merged in order.
    /// This is the one place where the estimate is assembled.
    fn assemble(&self, world: &World) -> Image {
        let (w, h) = (world.camera.width, world.camera.height);
        let mut le = Film::new(w, h);
        let mut hits = Film::new(w, h);
        let (mut steps, mut counted) = (0u64, 0u64);
        for l in &self.lanes {
            le.merge(&l.le_film);
            hits.merge(&l.hit_film);
            steps += l.steps;
            counted += l.counted;
        }
        let inv = |n: u64| if n == 0 { 0.0 } else { 1.0 / n as f64 };
        let a = le.to_image(inv(steps));
        let born: u64 = self.lanes.iter().map(|l| l.born).sum();
        let b = if Form::of(&self.settings).birth {
            hits.to_image(inv(born))
        } else {
            hits.to_image(inv(counted))
        };
        let mut img = Image {
            width: w,
            height: h,
            data: a.data.iter().zip(&b.data).map(|(x, y)| *x + *y).collect(),
        };
        if let Some(mix) = &self.mix {
            // The two estimates of the lights' paths, by their variances
            mix.combine(&mut img);
        }
        self.camera_pass.add_to(&mut img);
        img
    }
}

/// Whether the directional densities are rebuilt after pass `pass`: after
/// passes 0, 1, 3, 7, … (doubling, while they learn fast) and then every
/// 32nd, so that merging the lanes' records costs little per pass.
fn guide_refresh(pass: u64) -> bool {
    (pass + 1).is_power_of_two() || (pass + 1).is_multiple_of(32)
}

impl Method for Plb {
    fn name(&self) -> &'static str {
        "plb"
    }

    fn prepare(&mut self, world: &World) -> Result<StepStats, MethodError> {
        Ok(StepStats {
            rays: self.camera_pass.prepare(world),
        })
    }

    fn step(&mut self, world: &World, pass: u64) -> StepStats {
        let full = self.steps_per_lane();
        let n = match self.mix.as_mut() {
            Some(m) => m.plb_steps_per_lane(full, self.settings.phase_len as u64),
            None => full,
        };
        let s = &self.settings;
        let mut rays = self
            .lanes
            .par_iter_mut()
            .enumerate()
            .map(|(i, lane)| {
                let rng = Pcg32::keyed(&[s.seed, pass, i as u64, 0x91b]);
                run_lane(world, s, rng, n, lane)
            })
            .sum::<u64>();
        if let Some(mix) = self.mix.as_mut() {
            let steps = n * self.lanes.len() as u64;
            let count = mix.walks_per_lane_for(full * self.lanes.len() as u64);
            let kind = WalkKind {
                max_depth: s.max_depth,
                roulette: Roulette::Throughput,
                glossy_split: Form::of(s).glossy_split,
            };
            let walk_rays = mix
                .films
                .par_iter_mut()
                .enumerate()
                .map(|(i, film)| {
                    let (seed, lane) = (s.seed, i as u64);
                    run_walks(world, &kind, s.sampler, seed, pass, lane, count, film)
                })
                .sum::<u64>();
            mix.walks_per_lane += count;
            mix.walk_rays += walk_rays;
            mix.plb_rays += rays;
            mix.since += rays;
            mix.plb_steps += steps;
            rays += walk_rays;
            let (path_rays, ready) = mix.run_path(world, full * self.lanes.len() as u64);
            rays += path_rays;
            if Mix::due(pass) || ready {
                let birth = Form::of(s).birth;
                let lanes: Vec<_> = self
                    .lanes
                    .iter()
                    .map(|l| {
                        let b = if birth { l.born } else { l.counted };
                        (&l.le_film, l.steps, &l.hit_film, b)
                    })
                    .collect();
                mix.measure(&lanes);
            }
        }
        if let Some(shared) = self.shared.as_mut() {
            share_grids(shared, &mut self.lanes);
        }
        if let Some((shared, guide)) = self.shared_dirs.as_mut().filter(|_| guide_refresh(pass)) {
            // Merge the lanes' directional records in lane order, rebuild
            // the densities of the cells they touched, and give every lane
            // the densities built from all records so far
            for l in &mut self.lanes {
                l.guide = None;
                if let Some(d) = l.dirs.as_mut() {
                    shared.drain_from(d);
                }
            }
            Arc::make_mut(guide).update_touched(shared);
            shared.untouch();
            for l in &mut self.lanes {
                l.guide = Some(guide.clone());
            }
        }
        let camera_rays = self.camera_pass.step(world, pass);
        StepStats {
            rays: rays + camera_rays,
        }
    }

    fn image(&self, world: &World) -> Image {
        self.assemble(world)
    }

    fn spp(&self) -> f64 {
        let steps: u64 = self.lanes.iter().map(|l| l.steps).sum();
        let walks = self
            .mix
            .as_ref()
            .map_or(0, |m| m.walks_per_lane * mix::LANES as u64);
        let path = self
            .mix
            .as_ref()
            .and_then(|m| m.path.as_ref())
            .map_or(0, |a| a.samples);
        (steps + walks) as f64 / self.pixels as f64 + path as f64
    }
}
