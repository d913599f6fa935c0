//! The mixture with plain light tracing (`--mix on`, guided only), and
//! with `path` (`--mix-path on`).
//!
//! Where light reaches the camera easily (a Cornell box), the population
//! adds little per ray and each of plb's rays costs about twice a light
//! tracing ray, so plb alone loses to `light` at equal time. Here plb runs
//! beside independent light-tracing walks that estimate the same image (the
//! lights' paths, the camera pass excluded, with the same glossy MIS split
//! as plb's own camera connections), and the two estimates are combined
//! with weights inversely proportional to their measured variances.
//!
//! - *The variances* come from the lanes: each estimate is the mean of
//!   [`LANES`] independent lane images, so its variance is the spread
//!   across lanes divided by their number, which holds whatever the
//!   correlation between a lane's pixels or steps (a population's hits are
//!   correlated). They are relative ((x − x̄)² / (m² + 0.01), m the smaller
//!   of the two estimates' means, so that a firefly does not hide itself by
//!   raising m) and pooled over tiles of [`TILE`]² pixels, shrunk toward
//!   the mean tile, so that a weight does not follow one pixel's noise.
//! - *The split of the work* between the two: each pass gives the one that
//!   has the lower variance per unit of work all but [`FLOOR`] of it, and
//!   the other [`FLOOR`], so that the other keeps learning (plb's guiding
//!   improves as it runs) and its variance stays measured. Work is counted
//!   in rays, a plb ray as [`PLB_RAY_COST`] walk rays (callgrind: 1591
//!   against 818 instructions per ray on cbox, 2737 against 1296 on
//!   two-rooms-baffle; with the walks in AVX lanes, 39b6393, about 1490
//!   against 720 on cbox and 3050 against 1170 on the baffle), so that the
//!   split, like everything else, depends on the seed only, never on the
//!   machine's load.
//! - *The size of a pass* stays that of a pass of plb alone: plb's share
//!   is paid in whole phases, one every few passes when its share is
//!   small, and the walks fill the rest. A pass sized by plb's least work
//!   (a phase per lane) and the walks' share of it would be some thirty
//!   times larger, and the camera pass, one sample per pixel a pass, would
//!   get a thirtieth of its share (on the glass-mirror scene, 22 passes
//!   for 6 M rays instead of 437, and the sphere's edge, which only the
//!   camera pass reaches, 20 % dark in two seeds' mean).
//!
//! - *The walks' Russian roulette* is on the throughput
//!   ([`crate::transport::Roulette::Throughput`]), not on the albedo as
//!   `light`'s (the papers'): the walks carry the image where light
//!   arrives easily, and there (cbox) it gives 7–9 % less error per ray;
//!   where light arrives through a gap, which the throughput's roulette
//!   serves worse, the population carries the image and the walks get
//!   [`FLOOR`] of the work.
//! - *The walks' numbers* (`--sampler`): Sobol points by default, walk k
//!   of a pass taking point k, eight walks at a time in AVX lanes as
//!   `light`'s ([`crate::transport::lanes::light_walks`]); on cbox that
//!   took plb from 1.22× light's error at equal time to 1.01×
//!   (docs/notebook/plb.md). `--sampler independent` draws PCG32 streams
//!   per (seed, pass, lane), one walk after another, as before.
//!
//! - *`path` beside them* (`--mix-path`, on by default), where the
//!   light paths estimate the whole image (the scene needs no camera
//!   pass): a third estimate, `path`'s own samples, measured by each
//!   pixel's spread of its samples ([`PathArm`]) and combined with the
//!   light paths' combination by the same rule, tile by tile. It competes
//!   with the walks only: where the walks beat the population and the arm
//!   beats the walks, it takes their place (all of each pass but a floor
//!   for each of the other two); otherwise it gets no work at all, and its
//!   first measurement stands (it learns nothing as it runs). Judged
//!   against the population too, it took the work on two-rooms, where the
//!   population does better than it is measured, and doubled the error.
//!   Its first two samples are run before it is measured, within
//!   [`FIRST_SAMPLES`] of the work. On cbox it wins (next-event estimation
//!   finds the light at every vertex), and plb there goes from light's
//!   error to about `path`'s (docs/notebook/plb.md, "`path` in the
//!   mixture").
//!
//! The estimates are unbiased; the combined one has a bias of the order of
//! the weights' own noise times the correlation between a pixel and the
//! weights, which pool a tile's pixels, far below the noise.

use glam::DVec3;
use rayon::prelude::*;

use crate::film::{Film, Image};
use crate::methods::World;
use crate::sampling::{Pcg32, SamplerKind};
use crate::simd::dispatched;
use crate::transport::{lanes, light_tracing_walk, DepthLimits, WalkKind};

/// Independent walk lanes (films and streams), fixed so that results do not
/// depend on the thread count.
pub(super) const LANES: usize = 8;

/// The least share of a pass's work that each estimate gets. 3 % until
/// 2026-11-27; 1 % gave 4 % less error at equal time on cbox (seeds 1–6)
/// and 6 % less on two-rooms-baffle (seeds 1–3), 10 s each, with the
/// measurement every 64th pass (docs/notebook/plb.md, "The floor and the
/// measurement's cost").
const FLOOR: f64 = 0.01;

/// The side of the square tiles over which the weights are pooled.
const TILE: u32 = 16;

/// What one plb ray costs, in light-tracing walk rays.
const PLB_RAY_COST: f64 = 2.0;

/// The most of the work that the path arm's first two samples take, while
/// it has no share (it is not measured yet): they run in the first passes
/// unless the image is large against a pass's work. On the baffle they are
/// 0.36 M rays, 1.8 % of a 20 M-ray render.
const FIRST_SAMPLES: f64 = 0.1;

/// What one ray of the path arm costs, in light-tracing walk rays.
/// Callgrind, whole runs at two budgets, the difference over the rays'
/// difference (128 × 96, one thread): `path` 680 instructions a ray
/// against `light`'s 706 on cbox, 835 against 1130 on two-rooms-baffle
/// (docs/notebook/plb.md, "`path` in the mixture").
const PATH_RAY_COST: f64 = 1.0;

/// `path`'s estimator beside the light paths (`--mix-path`): its samples
/// (one per pixel a sample, the whole image; sample k is Sobol point k of
/// the pixel) and their squares, per pixel, so that its variance is the
/// samples' spread in each pixel. This needs two samples, where the lanes'
/// spread of the other two estimates would need eight: on the baffle eight
/// samples per pixel are 1.4 M rays, 7 % of a 20 M-ray render. The spread
/// treats a pixel's samples as independent; Sobol points do better than
/// that (about 2× on cbox at 64 samples), so it overstates the arm's
/// variance, which errs toward the light paths.
#[derive(Clone, Debug)]
pub(super) struct PathArm {
    /// Sums of the samples and of their squares, per pixel.
    pub(super) film: Film,
    squares: Vec<DVec3>,
    /// Samples per pixel so far.
    pub(super) samples: u64,
    /// Rays traced.
    pub(super) rays: u64,
    /// Work owed to the arm and not yet run, in walk rays (its first
    /// samples run whatever is owed, and are not charged).
    credit: f64,
    /// The samples' seed, depth limits and numbers.
    seed: u64,
    limits: DepthLimits,
    sampler: SamplerKind,
}

impl PathArm {
    /// The arm for a `w` × `h` image: `path`'s estimator under `seed`,
    /// with `limits` and `sampler`.
    pub(super) fn new(
        w: u32,
        h: u32,
        seed: u64,
        limits: DepthLimits,
        sampler: SamplerKind,
    ) -> Self {
        PathArm {
            film: Film::new(w, h),
            squares: vec![DVec3::ZERO; w as usize * h as usize],
            samples: 0,
            rays: 0,
            credit: 0.0,
            seed,
            limits,
            sampler,
        }
    }

    /// Whether each pixel has the two samples that its spread needs.
    pub(super) fn measurable(&self) -> bool {
        self.samples >= 2
    }

    /// Runs `n` samples per pixel, the rows of a sample in parallel
    /// (`path`'s own loop, [`lanes::camera_row`]); returns the rays traced.
    pub(super) fn run(&mut self, world: &World, n: u64) -> u64 {
        let w = world.camera.width as usize;
        let mut rays = 0;
        for _ in 0..n {
            let k = self.samples;
            let (seed, limits, sampler) = (self.seed, &self.limits, self.sampler);
            rays += self
                .film
                .sum
                .par_chunks_mut(w)
                .zip(self.squares.par_chunks_mut(w))
                .enumerate()
                .map(|(y, (row, sq))| {
                    lanes::camera_row(world, limits, sampler, seed, k, y, row, Some(sq))
                })
                .sum::<u64>();
            self.samples += 1;
        }
        self.rays += rays;
        rays
    }

    /// The variance of pixel `j`'s mean, per channel: the samples' spread
    /// over n − 1, divided by n (n ≥ 2).
    #[inline]
    fn variance(&self, j: usize) -> DVec3 {
        let n = self.samples as f64;
        let s = self.film.sum[j];
        ((self.squares[j] - s * s / n) / ((n - 1.0) * n)).max(DVec3::ZERO)
    }
}

/// The walks beside plb, and what the split has learnt.
#[derive(Clone, Debug)]
pub(super) struct Mix {
    /// One film per walk lane.
    pub(super) films: Vec<Film>,
    /// Walks per lane so far (all lanes run the same number).
    pub(super) walks_per_lane: u64,
    /// Rays of the walks, and of plb's lanes (the camera pass excluded).
    pub(super) walk_rays: u64,
    pub(super) plb_rays: u64,
    /// plb's steps so far, over all lanes.
    pub(super) plb_steps: u64,
    /// The walks' share of the next pass's work.
    pub(super) share: f64,
    /// The path arm's share (0 without it); plb's is what is left.
    path_share: f64,
    /// `path`'s estimator beside them (`--mix-path`), where the light
    /// paths estimate the whole image.
    pub(super) path: Option<PathArm>,
    /// plb's steps per lane owed and not yet run (less than a phase, or
    /// negative after its first pass, which runs a phase whatever it owes).
    credit: f64,
    /// The relative variances of the two estimates (plb, walks), as last
    /// measured; 0 until measured.
    pub(super) var: (f64, f64),
    /// The path arm's, 0 until measured.
    pub(super) var_path: f64,
    /// The same per tile of [`TILE`]² pixels (sums over the tile's pixels
    /// and channels, in the same units): plb, walks, path.
    tiles: Vec<(f64, f64, f64)>,
    /// plb's variance per unit of work in its recent passes (a moving
    /// average over passes), 0 until measured: plb learns as it runs, so
    /// its whole image, early passes included, would understate what its
    /// next pass is worth.
    recent: f64,
    /// plb's rays since the last measurement.
    pub(super) since: u64,
    /// Each plb lane's two films (sums) and counts at the last measurement,
    /// to measure the image of the passes since then.
    prev: Vec<(Vec<DVec3>, u64, Vec<DVec3>, u64)>,
}

impl Mix {
    /// The mixture for a `w` × `h` image, with `path`'s estimator beside
    /// it when `path` holds one.
    pub(super) fn new(w: u32, h: u32, path: Option<PathArm>) -> Self {
        Mix {
            films: (0..LANES).map(|_| Film::new(w, h)).collect(),
            walks_per_lane: 0,
            walk_rays: 0,
            plb_rays: 0,
            plb_steps: 0,
            share: 0.5,
            path_share: 0.0,
            path,
            credit: 0.0,
            var: (0.0, 0.0),
            var_path: 0.0,
            tiles: Vec::new(),
            recent: 0.0,
            since: 0,
            prev: Vec::new(),
        }
    }

    /// plb's steps per lane for the next pass, whole phases. A pass has the
    /// work of a pass of plb alone (`full` steps per lane), of which plb's
    /// share is 1 − share: its steps accumulate until they make a phase,
    /// so a pass is no larger than plb's own and the camera pass, one
    /// sample per pixel a pass, keeps its share of the work. The first
    /// pass runs a phase, so that plb is measured from the start.
    pub(super) fn plb_steps_per_lane(&mut self, full: u64, phase: u64) -> u64 {
        let phase = phase.max(1);
        self.credit += full as f64 * (1.0 - self.share - self.path_share);
        let mut n = (self.credit / phase as f64).floor().max(0.0) as u64 * phase;
        if self.plb_steps == 0 {
            n = n.max(phase);
        }
        self.credit -= n as f64;
        n
    }

    /// Walks per lane for the next pass, whose whole work is that of
    /// `full_steps` plb steps (over all lanes): the walks' share of it, at
    /// the rays per step and per walk measured so far.
    pub(super) fn walks_per_lane_for(&self, full_steps: u64) -> u64 {
        let per_walk = if self.walks_per_lane > 0 {
            (self.walk_rays as f64 / (self.walks_per_lane * LANES as u64) as f64).max(1.0)
        } else {
            4.0
        };
        let walks = self.pass_work(full_steps) * self.share / per_walk;
        (walks / LANES as f64).ceil().max(1.0) as u64
    }

    /// The work of a pass of `full_steps` plb steps (over all lanes), in
    /// walk rays, at the rays per step measured so far.
    fn pass_work(&self, full_steps: u64) -> f64 {
        let per_step = if self.plb_steps > 0 {
            self.plb_rays as f64 / self.plb_steps as f64
        } else {
            2.0
        };
        full_steps as f64 * per_step * PLB_RAY_COST
    }

    /// The path arm's samples per pixel for the next pass, whose whole
    /// work is that of `full_steps` plb steps: its share of the work
    /// accrues and is paid in whole samples, at the rays per sample
    /// measured so far. Until every lane has a sample to measure, a pass
    /// runs one whenever the arm's work so far is at most
    /// [`FIRST_SAMPLES`] of all the work. 0 without the arm.
    fn path_samples_for(&mut self, full_steps: u64, pixels: u64) -> u64 {
        let work = self.pass_work(full_steps) * self.path_share;
        let Some(arm) = self.path.as_mut() else {
            return 0;
        };
        let per_sample = if arm.samples > 0 {
            arm.rays as f64 / arm.samples as f64
        } else {
            4.0 * pixels as f64
        }
        .max(1.0)
            * PATH_RAY_COST;
        arm.credit += work;
        let owed = (arm.credit / per_sample).floor().max(0.0) as u64;
        arm.credit -= owed as f64 * per_sample;
        // Until every lane has a sample, one more whenever the arm's work
        // is below its cap of all the work so far
        let mine = arm.rays as f64 * PATH_RAY_COST;
        let all = mine + self.walk_rays as f64 + self.plb_rays as f64 * PLB_RAY_COST;
        let first = !arm.measurable() && mine <= FIRST_SAMPLES * all;
        owed.max(u64::from(first))
    }

    /// Runs the path arm's samples for the next pass, whose whole work is
    /// that of `full_steps` plb steps ([`Mix::path_samples_for`]); returns
    /// its rays, and whether it has just become measurable, so that the
    /// mixture is measured at once. (0, false) without the arm.
    pub(super) fn run_path(&mut self, world: &World, full_steps: u64) -> (u64, bool) {
        let pixels = self.films[0].sum.len() as u64;
        let n = self.path_samples_for(full_steps, pixels);
        let Some(arm) = self.path.as_mut() else {
            return (0, false);
        };
        let was = arm.measurable();
        let rays = arm.run(world, n);
        (rays, !was && arm.measurable())
    }

    /// Combines plb's image `img` (the lights' paths, without the camera
    /// pass) with the walks' image, tile by tile, and that with the path
    /// arm's image when there is one (the light paths' combined variance
    /// against the arm's).
    pub(super) fn combine(&self, img: &mut Image) {
        let (w, h) = (self.films[0].width, self.films[0].height);
        let mut total = Film::new(w, h);
        for f in &self.films {
            total.merge(f);
        }
        let walks = total.mean(self.walks_per_lane * LANES as u64);
        let global = self.weight();
        let tiles_x = w.div_ceil(TILE);
        // Each tile's variances shrunk toward the mean tile's, so that a
        // tile that one estimate barely reached does not get all the weight
        let nt = self.tiles.len().max(1) as f64;
        let (gp, gw) = (self.var.0, self.var.1);
        let (mp, mw, mc) = if self.tiles.is_empty() {
            (0.0, 0.0, 0.0)
        } else {
            let (sp, sw, sc) = self
                .tiles
                .iter()
                .fold((0.0, 0.0, 0.0), |(a, b, c), t| (a + t.0, b + t.1, c + t.2));
            (sp / nt, sw / nt, sc / nt)
        };
        let path = self
            .path
            .as_ref()
            .filter(|a| a.samples > 0)
            .map(|a| a.film.mean(a.samples));
        let path_global = self.path_weight();
        let measured = gp > 0.0 && gw > 0.0 && mp + mw > 0.0;
        for (i, (p, q)) in img.data.iter_mut().zip(&walks.data).enumerate() {
            let (x, y) = (i as u32 % w, i as u32 / w);
            let t = (y / TILE * tiles_x + x / TILE) as usize;
            let tile = self.tiles.get(t).filter(|_| measured);
            let k = match tile {
                Some(&(vp, vw, _)) => (vp + mp) / (vp + vw + mp + mw),
                None => global,
            } as f32;
            if k > 0.0 {
                *p = *p * (1.0 - k) + *q * k;
            }
            if let Some(c) = &path {
                let kc = match tile {
                    Some(&(vp, vw, vc)) if self.var_path > 0.0 => {
                        // The variance of the light paths' combination
                        let vl = (vp + mp) * (vw + mw) / (vp + vw + mp + mw);
                        vl / (vl + vc + mc)
                    }
                    _ => path_global,
                } as f32;
                *p = *p * (1.0 - kc) + c.data[i] * kc;
            }
        }
    }

    /// The path arm's weight over the whole image: the light paths'
    /// combined variance against the arm's, or the arm's share of the work
    /// while a variance is unknown; 0 without the arm.
    fn path_weight(&self) -> f64 {
        let Some(arm) = &self.path else {
            return 0.0;
        };
        let (vp, vw, vc) = (self.var.0, self.var.1, self.var_path);
        if vp > 0.0 && vw > 0.0 && vc > 0.0 && (vp + vw + vc).is_finite() {
            let vl = vp * vw / (vp + vw);
            vl / (vl + vc)
        } else {
            let wc = arm.rays as f64 * PATH_RAY_COST;
            let all = wc + self.walk_rays as f64 + self.plb_rays as f64 * PLB_RAY_COST;
            if all > 0.0 {
                wc / all
            } else {
                0.0
            }
        }
    }

    /// The weight of the walks' image over the whole image: the share of
    /// the inverse variances, or of the work while a variance is unknown.
    pub(super) fn weight(&self) -> f64 {
        let (vp, vw) = self.var;
        if vp > 0.0 && vw > 0.0 && (vp + vw).is_finite() {
            vp / (vp + vw)
        } else {
            let ww = self.walk_rays as f64;
            let wp = self.plb_rays as f64 * PLB_RAY_COST;
            if ww + wp > 0.0 {
                ww / (ww + wp)
            } else {
                0.0
            }
        }
    }

    /// Whether to measure after pass `pass`: after passes 0, 1, 3, 7, …
    /// (doubling) and then every 64th. A measurement reads every lane's
    /// films and is bound by memory, not arithmetic: on cbox (256², two
    /// threads) one took about 18 ms, 1.8 % of a 10 s run measured every
    /// 64th pass (timed with `Instant` around the step's parts: walks 95 %,
    /// plb's lanes 1.7 %, the grids and guide 0.6 %).
    pub(super) fn due(pass: u64) -> bool {
        (pass + 1).is_power_of_two() || (pass + 1).is_multiple_of(64)
    }

    /// Measures the two variances from the lane images (`plb`: plb's lanes
    /// as (the lights' film, its samples, the hits' film, its samples)), and
    /// plb's variance per unit of work in the passes since the last
    /// measurement (its rays in them: [`Mix::since`]), and sets the split
    /// of the next passes. The pixels are measured a row of tiles at a
    /// time on every core ([`measure_tile_row`]), and the rows' sums added
    /// in row order, so the figures do not depend on the thread count.
    pub(super) fn measure(&mut self, plb: &[(&Film, u64, &Film, u64)]) {
        let pass_rays = std::mem::take(&mut self.since);
        let nw = self.walks_per_lane;
        let n = self.films[0].sum.len();
        if self.prev.len() != plb.len() {
            self.prev = plb
                .iter()
                .map(|_| (vec![DVec3::ZERO; n], 0, vec![DVec3::ZERO; n], 0))
                .collect();
        }
        if nw == 0 || plb.len() < 2 {
            return;
        }
        let inv = |n: u64| if n == 0 { 0.0 } else { 1.0 / n as f64 };
        // Per lane: the scales of its whole image and of this pass's image
        let scales: Vec<[f64; 4]> = plb
            .iter()
            .zip(&self.prev)
            .map(|((_, a, _, b), (_, pa, _, pb))| [inv(*a), inv(*b), inv(a - pa), inv(b - pb)])
            .collect();
        let width = self.films[0].width as usize;
        let tiles_x = width.div_ceil(TILE as usize);
        // Each lane's previous films, cut into rows of tiles
        let chunk = TILE as usize * width;
        let mut rows: Vec<Vec<(&mut [DVec3], &mut [DVec3])>> =
            (0..n.div_ceil(chunk)).map(|_| Vec::new()).collect();
        for (pl, _, ph, _) in &mut self.prev {
            for (row, cut) in rows
                .iter_mut()
                .zip(pl.chunks_mut(chunk).zip(ph.chunks_mut(chunk)))
            {
                row.push(cut);
            }
        }
        // The path arm, once its pixels have two samples each
        let arm = self.path.as_ref().filter(|a| a.measurable());
        let input = MeasureInput {
            plb,
            scales: &scales,
            walks: &self.films,
            walk_scale: inv(nw),
            path: arm,
            width,
            tiles_x,
        };
        let parts: Vec<TileRow> = rows
            .into_par_iter()
            .enumerate()
            .map(|(r, mut prev)| measure_tile_row(&input, r * chunk, &mut prev))
            .collect();
        let (mut vp, mut vw, mut vd, mut vc) = (0.0f64, 0.0f64, 0.0f64, 0.0f64);
        self.tiles.clear();
        for part in parts {
            vp += part.vp;
            vw += part.vw;
            vd += part.vd;
            vc += part.vc;
            self.tiles.extend(part.tiles);
        }
        for ((_, pa, _, pb), (_, a, _, b)) in self.prev.iter_mut().zip(plb) {
            *pa = *a;
            *pb = *b;
        }
        let (lp, lw) = (plb.len() as f64, LANES as f64);
        // The variance of a mean of L lanes: the lanes' spread / (L − 1) / L
        let norm = 1.0 / (3.0 * n as f64);
        let lanes_p = norm / (lp * (lp - 1.0));
        let lanes_w = norm / (lw * (lw - 1.0));
        self.var = (vp * lanes_p, vw * lanes_w);
        // The path arm's are the variances of its pixels' means already
        self.var_path = vc * norm;
        for t in &mut self.tiles {
            *t = (t.0 * lanes_p, t.1 * lanes_w, t.2 * norm);
        }
        // Variance times work: what each would reach with all the work
        let pass = vd * lanes_p * pass_rays as f64 * PLB_RAY_COST;
        if pass.is_finite() && pass > 0.0 {
            self.recent = if self.recent > 0.0 {
                0.5 * (self.recent + pass)
            } else {
                pass
            };
        }
        let ep = self.recent;
        let ew = self.var.1 * self.walk_rays as f64;
        let ec = self
            .path
            .as_ref()
            .map_or(0.0, |a| self.var_path * a.rays as f64 * PATH_RAY_COST);
        if ep > 0.0 && ew > 0.0 && ec > 0.0 && (ep + ew + ec).is_finite() {
            // Three estimates. The population against the walks as without
            // the path arm; where the walks win, the arm takes their place
            // if it does better than they do, leaving them a floor. It
            // never competes with the population itself: plb learns as it
            // runs, and its recent passes' variance is measured on few
            // samples (on two-rooms, judged against the population, the arm
            // took the work and doubled the error)
            let (share, path_share) = if ew < ep {
                if ec < ew {
                    (FLOOR, 1.0 - 2.0 * FLOOR)
                } else {
                    (1.0 - FLOOR, 0.0)
                }
            } else {
                (FLOOR, 0.0)
            };
            self.share = share;
            self.path_share = path_share;
        } else if ep > 0.0 && ew > 0.0 && (ep + ew).is_finite() {
            self.share = if ew < ep { 1.0 - FLOOR } else { FLOOR };
        }
    }
}

/// What [`measure_tile_row`] reads: plb's lanes, their scales (whole image,
/// this pass's image; lights' and hits' films), the walks' films and their
/// scale, and the image's width in pixels and in tiles.
struct MeasureInput<'a> {
    plb: &'a [(&'a Film, u64, &'a Film, u64)],
    scales: &'a [[f64; 4]],
    walks: &'a [Film],
    walk_scale: f64,
    /// The path arm (none without it, or before it can be measured).
    path: Option<&'a PathArm>,
    width: usize,
    tiles_x: usize,
}

/// One row of tiles' relative spreads, as sums over its pixels and
/// channels: plb's lanes' (`vp`), the walks' (`vw`), plb's lanes' over the
/// passes since the last measurement (`vd`), the path arm's lanes' (`vc`),
/// and plb's, the walks' and the path arm's per tile.
struct TileRow {
    vp: f64,
    vw: f64,
    vd: f64,
    vc: f64,
    tiles: Vec<(f64, f64, f64)>,
}

/// Measures the pixels from `first` on, one row of tiles, and moves each
/// plb lane's previous films (`prev`, the same pixels) to its films now.
fn measure_tile_row(
    input: &MeasureInput,
    first: usize,
    prev: &mut [(&mut [DVec3], &mut [DVec3])],
) -> TileRow {
    let mut out = TileRow {
        vp: 0.0,
        vw: 0.0,
        vd: 0.0,
        vc: 0.0,
        tiles: vec![(0.0, 0.0, 0.0); input.tiles_x],
    };
    let (lp, lw) = (input.plb.len() as f64, input.walks.len() as f64);
    let mut xp = vec![DVec3::ZERO; input.plb.len()];
    let mut xd = vec![DVec3::ZERO; input.plb.len()];
    let spread =
        |xs: &[DVec3], mean: DVec3| xs.iter().map(|x| (*x - mean) * (*x - mean)).sum::<DVec3>();
    for o in 0..prev.first().map_or(0, |p| p.0.len()) {
        let j = first + o;
        let (mut mp, mut md) = (DVec3::ZERO, DVec3::ZERO);
        for (i, ((le, _, hits, _), (pl, ph))) in input.plb.iter().zip(prev.iter_mut()).enumerate() {
            let k = input.scales[i];
            xp[i] = le.sum[j] * k[0] + hits.sum[j] * k[1];
            xd[i] = (le.sum[j] - pl[o]) * k[2] + (hits.sum[j] - ph[o]) * k[3];
            pl[o] = le.sum[j];
            ph[o] = hits.sum[j];
            mp += xp[i];
            md += xd[i];
        }
        mp /= lp;
        md /= lp;
        let mut mw = DVec3::ZERO;
        for f in input.walks {
            mw += f.sum[j] * input.walk_scale;
        }
        mw /= lw;
        // The smallest of the means: a firefly in one estimate
        // must not shrink the relative variance it causes
        let m = match input.path {
            None => mp.min(mw),
            Some(a) => mp.min(mw).min(a.film.sum[j] / a.samples as f64),
        }
        .max(DVec3::ZERO);
        let w = DVec3::ONE / (m * m + crate::metrics::EPSILON);
        let mut sq = DVec3::ZERO;
        for f in input.walks {
            let d = f.sum[j] * input.walk_scale - mw;
            sq += d * d;
        }
        let sc = input.path.map_or(DVec3::ZERO, |a| a.variance(j));
        let (a, b) = ((spread(&xp, mp) * w).element_sum(), (sq * w).element_sum());
        let c = (sc * w).element_sum();
        let t = &mut out.tiles[j % input.width / TILE as usize];
        t.0 += a;
        t.1 += b;
        t.2 += c;
        out.vc += c;
        out.vp += a;
        out.vd += (spread(&xd, md) * w).element_sum();
        out.vw += b;
    }
    out
}

dispatched! {
    /// Lane `lane`'s `count` light-tracing walks of pass `pass` into
    /// `film` ([`light_tracing_walk`] of the form `kind`); returns the rays
    /// traced. With Sobol points the walks are indices `lane · count ..
    /// (lane + 1) · count` of the pass's sequence, eight at a time in AVX
    /// lanes ([`lanes::light_walks`]); otherwise they draw from the lane's
    /// PCG32 stream, keyed by (seed, pass, lane). Compiled for x86-64-v3 by
    /// runtime dispatch, as `light`'s.
    #[allow(clippy::too_many_arguments)]
    pub(super) fn run_walks(
        world: &World,
        kind: &WalkKind,
        sampler: SamplerKind,
        seed: u64,
        pass: u64,
        lane: u64,
        count: u64,
        film: &mut Film,
    ) -> u64 {
        let mut rays = 0;
        // splats held back a few at a time, as `light`'s (same bits)
        film.begin_queue();
        match sampler {
            SamplerKind::Independent => {
                let mut rng = Pcg32::keyed(&[seed, pass, lane, 0x3a1]);
                for _ in 0..count {
                    rays += light_tracing_walk(world, kind, &mut rng, film);
                }
            }
            SamplerKind::Sobol => {
                let walks = lane * count..(lane + 1) * count;
                rays += lanes::light_walks(world, kind, seed, pass, walks, film);
            }
        }
        film.settle();
        rays
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A film whose every pixel holds `v` (a sum).
    fn film(v: f64) -> Film {
        let mut f = Film::new(32, 16);
        f.sum.iter_mut().for_each(|p| *p = DVec3::splat(v));
        f
    }

    #[test]
    fn measures_on_a_doubling_then_regular_schedule() {
        let due: Vec<u64> = (0..200).filter(|&p| Mix::due(p)).collect();
        assert_eq!(due, [0, 1, 3, 7, 15, 31, 63, 127, 191]);
    }

    #[test]
    fn plb_keeps_whole_phases_and_its_share_of_each_pass() {
        let mut m = Mix::new(4, 4, None);
        // The first pass runs a phase whatever plb's share
        m.share = 0.97;
        assert_eq!(m.plb_steps_per_lane(800, 400), 400);
        m.plb_steps = 400;
        // Then 3 % of 800 steps a pass: a phase once 400 are owed, and
        // over many passes plb's share of the steps
        let runs: Vec<u64> = (0..40).map(|_| m.plb_steps_per_lane(800, 400)).collect();
        assert!(runs.iter().all(|&n| n == 0 || n == 400), "{runs:?}");
        let ran: u64 = runs.iter().sum::<u64>() + 400;
        assert!((ran as f64 - 0.03 * 800.0 * 41.0).abs() <= 400.0, "{ran}");
        // Half: a phase a pass of two phases; all: the whole pass
        m.share = 0.5;
        m.credit = 0.0;
        assert_eq!(m.plb_steps_per_lane(800, 400), 400);
        m.share = 0.0;
        assert_eq!(m.plb_steps_per_lane(2400, 400), 2400);
    }

    /// The walks take their share of a pass's work, counted in plb rays.
    #[test]
    fn walks_take_their_share_of_the_pass() {
        let mut m = Mix::new(4, 4, None);
        m.plb_rays = 3000;
        m.plb_steps = 1000;
        m.walk_rays = 8 * 100 * 5;
        m.walks_per_lane = 100;
        m.share = 0.5;
        // 8000 steps × 3 rays × cost 2 = 48000 walk rays; half at 5 a walk
        assert_eq!(m.walks_per_lane_for(8000), 4800 / 8);
    }

    /// A mixture measured once: 8 walk lanes of 10 walks and 8 plb lanes of
    /// 10 steps, every pixel of lane i at 5 + `walk(i)` (walks) and
    /// 5 + `plb(i)` (plb's lights' film; its hits' film empty), as sums.
    fn measured(walk: impl Fn(f64) -> f64, plb: impl Fn(f64) -> f64) -> Mix {
        measured_with(Mix::new(32, 16, None), walk, plb)
    }

    /// [`measured`] on the mixture `m`.
    fn measured_with(mut m: Mix, walk: impl Fn(f64) -> f64, plb: impl Fn(f64) -> f64) -> Mix {
        m.walks_per_lane = 10;
        m.walk_rays = 8 * 10 * 4;
        m.plb_rays = 8 * 10 * 2;
        m.plb_steps = 8 * 10;
        for (i, f) in m.films.iter_mut().enumerate() {
            *f = film(5.0 + walk(i as f64));
        }
        let lanes: Vec<(Film, Film)> = (0..8)
            .map(|i| (film(5.0 + plb(i as f64)), film(0.0)))
            .collect();
        let lanes: Vec<_> = lanes.iter().map(|(a, b)| (a, 10, b, 10)).collect();
        m.since = 160;
        m.measure(&lanes);
        m
    }

    /// Walk lanes that agree, plb lanes that scatter: the walks get the
    /// weight and the next pass's work, and back when the roles swap.
    #[test]
    fn the_less_noisy_estimate_gets_the_weight_and_the_work() {
        // Walk lanes (10 walks of 0.5 per pixel) with a small spread; plb
        // lanes with the same mean and fifty times the walks' spread
        let m = measured(|i| 0.01 * i, |i| 0.5 * (i - 3.5));
        let (vp, vw) = m.var;
        assert!(vp > 100.0 * vw, "variances {vp:e} {vw:e}");
        assert!(m.weight() > 0.99, "walks' weight {}", m.weight());
        assert_eq!(m.share, 1.0 - FLOOR);
        // The combination follows the weights, tile by tile
        assert_combines_to_half(&m);

        // Swap the roles: plb lanes that agree, walks that scatter
        let m2 = measured(|i| 0.5 * (i - 3.5), |i| 0.01 * i);
        assert!(m2.weight() < 0.01, "walks' weight {}", m2.weight());
        assert_eq!(m2.share, FLOOR);
    }

    /// `m` combines an image of ones (plb's) into one of 0.5 (the walks'
    /// and the path arm's), tile by tile: the weight is on the others.
    fn assert_combines_to_half(m: &Mix) {
        let mut img = Image::new(32, 16);
        img.data
            .iter_mut()
            .for_each(|p| *p = glam::Vec3::splat(1.0));
        m.combine(&mut img);
        for p in &img.data {
            assert!((p.x - 0.5).abs() < 0.01, "{p:?}");
        }
    }

    /// A path arm with `path`'s defaults.
    fn arm(w: u32, h: u32) -> PathArm {
        PathArm::new(w, h, 0, DepthLimits::default(), SamplerKind::Sobol)
    }

    /// A mixture with the path arm, its pixels' samples (4, the same mean
    /// as the others', 0.5) spread with variance `v` each, at the walks'
    /// rays.
    fn with_path(v: f64) -> Mix {
        let mut m = Mix::new(32, 16, Some(arm(32, 16)));
        let arm = m.path.as_mut().expect("the arm");
        arm.samples = 4;
        arm.rays = 8 * 10 * 4;
        arm.film.sum.iter_mut().for_each(|p| *p = DVec3::splat(2.0));
        // Σx² = (Σx)²/n + (n − 1)·v
        arm.squares
            .iter_mut()
            .for_each(|q| *q = DVec3::splat(1.0 + 3.0 * v));
        m
    }

    /// The path arm is measured by its pixels' spread: where the walks
    /// beat the population and the arm beats the walks it gets the work
    /// (all but a floor for each other) and the weight; where it does not,
    /// no work and little weight, and the other two split as without it.
    #[test]
    fn the_path_arm_gets_the_work_only_where_it_does_best() {
        let (walks, plb) = (|i| 0.05 * (i - 3.5), |i| 0.5 * (i - 3.5));
        // Walks' lanes: 10 walks each, so a lane's mean spreads by 0.005
        // (i − 3.5) around 0.5, a variance of the lanes' mean of 1.9e-5;
        // the arm's pixels' means, 2.5e-8
        let m = measured_with(with_path(1e-7), walks, plb);
        let (vp, vw) = m.var;
        assert!(
            m.var_path > 0.0 && m.var_path < 0.01 * vw,
            "{} {vw:e}",
            m.var_path
        );
        assert_eq!((m.share, m.path_share), (FLOOR, 1.0 - 2.0 * FLOOR));
        assert!(vw < vp);
        assert!(m.path_weight() > 0.99, "{}", m.path_weight());
        assert_combines_to_half(&m);

        // An arm far noisier than the walks (a variance of its pixels'
        // means of 1): no work, and the walks get theirs as without it
        let m2 = measured_with(with_path(4.0), walks, plb);
        assert!(
            m2.var_path > 10.0 * m2.var.1,
            "{} {:e}",
            m2.var_path,
            m2.var.1
        );
        assert_eq!((m2.share, m2.path_share), (1.0 - FLOOR, 0.0));
        assert!(m2.path_weight() < 0.01, "{}", m2.path_weight());
        let m3 = measured(walks, plb);
        assert_eq!(m3.share, m2.share);

        // Where the population beats the walks it keeps the work, even
        // against an arm that seems better still: the arm only ever takes
        // the walks' place
        let m4 = measured_with(with_path(1e-7), plb, walks);
        assert!(m4.var_path < 0.01 * m4.var.0);
        assert_eq!((m4.share, m4.path_share), (FLOOR, 0.0));
    }

    /// Before the arm can be measured, a pass runs one of its samples
    /// while its work is within [`FIRST_SAMPLES`] of all the work, and
    /// none once it is measurable and owed nothing.
    #[test]
    fn the_path_arm_takes_its_first_samples_within_a_cap() {
        let mut m = Mix::new(4, 4, Some(arm(4, 4)));
        m.walk_rays = 1000;
        assert_eq!(m.path_samples_for(100, 16), 1);
        let arm = m.path.as_mut().expect("the arm");
        arm.samples = 1;
        arm.rays = 200;
        // 200 of 1200 is above the cap: wait
        assert_eq!(m.path_samples_for(100, 16), 0);
        m.walk_rays = 3000;
        assert_eq!(m.path_samples_for(100, 16), 1);
        let arm = m.path.as_mut().expect("the arm");
        arm.samples = 2;
        assert_eq!(m.path_samples_for(100, 16), 0);
    }
}
