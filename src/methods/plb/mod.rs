//! `plb`: progressive light path building (Szirmay-Kalos, Antal and Sbert),
//! self-correcting iteration over a population of photon hits.
//!
//! Each step of [`iterate`] is the paper's `Iterate`: pick hit i with
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
//!   probability for E[T*L] = TL. The split is §3's power rule: the lights
//!   are chosen with Φ_e / (Φ_e + Σ Lum(Φ_i a_i)) (for a closed scene 1 − ā,
//!   as the paper says of s), and the rest is shared among the hits in
//!   proportion to their importance.
//! - *Hits born during a phase* have importance = potential impact, eq. (9),
//!   until the next `ComputeImportance` (they have no children yet), so that
//!   every hit can spawn at once (again needed for E[T*L] = TL).
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
//! `--variant pooled` (our extension, not in the paper; the default is the
//! paper's `ComputeImportance`): eq. (9) has no visibility in it, and
//! eq. (8) judges a hit by its own one or two children, so on a scene lit
//! through a gap the paper's importance barely prefers the hits that matter
//! (BENCHMARKS.md, plb diagnosis). The pooled rule keeps, per cell of a 16³
//! grid over the scene, the mean image impact per unit power of every ray
//! ever spawned from that cell ([`ImportanceGrid`]), and sets a hit's
//! importance to its output luminance times that mean (shrunk toward the
//! global mean, with a floor so that every hit can still spawn). The
//! iteration, power weights, phases and purge are unchanged, so it is
//! unbiased for the same reason; only where the next ray starts changes.
//!
//! Parallelism: a fixed number of lanes (8), each with its own population,
//! films and random streams keyed by (seed, pass, lane); lanes are merged in
//! order, so a seed gives the same image whatever the thread count.
//!
//! ```text
//! kalos render scenes/two-rooms/scene.xml --method plb --time 30 -o p.exr
//! kalos render scenes/two-rooms/scene.xml --method plb --lambda 1 --phase-len 400 --population 100 --rays 30M -o p.exr
//! ```

use glam::Vec2;
use rayon::prelude::*;

use super::{Method, MethodError, StepStats, World};
use crate::film::{Film, Image};
use crate::geometry::{offset_point, Ray};
use crate::sampling::Pcg32;
use crate::scene::{luminance, Rgb, SurfacePoint};
use crate::transport::camera_pass::CameraPass;
use crate::transport::{
    connect_emission, connect_to_camera, follow_delta_chain, scatter, Landing, Vertex,
};

/// Settings of progressive light path building.
#[derive(Clone, Debug, PartialEq)]
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
    /// cannot reach (delta surfaces seen by the camera, the environment):
    /// on, or off for the raw method.
    #[cfg_attr(feature = "cli", arg(long, value_name = "on|off", default_value = "on", value_parser = super::cli::on_off, action = clap::ArgAction::Set))]
    pub camera_pass: bool,
    /// How a hit's importance is found: the paper's rule (§3.1, eqs. 8–9),
    /// or pooled over a grid of measured image impact (our extension).
    #[cfg_attr(
        feature = "cli",
        arg(
            long = "variant",
            value_name = "VARIANT",
            value_enum,
            default_value = "paper"
        )
    )]
    pub importance: Importance,
}

/// The hit-selection rule.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "cli", derive(clap::ValueEnum))]
pub enum Importance {
    /// §3.1 as the paper gives it: potential impact (eq. (9)) plus λ times
    /// the children's measured impact (eq. (8)).
    Paper,
    /// Not in the paper (`--variant pooled`): the output luminance times the
    /// measured image impact per unit power of the rays spawned from the
    /// same grid cell, pooled over all hits ever spawned there, with a
    /// defensive floor. See [`ImportanceGrid`].
    Pooled,
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
            importance: Importance::Paper,
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
}

/// No parent: the hit was shot from a light.
const NO_PARENT: u32 = u32::MAX;

/// A photon hit, the record of §5. Powers are stored in units of the lane's
/// σ (actual power = σ · `phi`), and so are `out_lum`, `contrib` and `s`.
#[derive(Clone, Debug)]
struct Hit {
    /// Location, surface (triangle, shape → BSDF) and normals.
    sp: SurfacePoint,
    /// Incoming direction, reversed (toward where the power came from).
    wo: glam::Vec3,
    /// Incoming power, RGB.
    phi: Rgb,
    /// Output luminance: Lum(Φ · a(ω_in)).
    out_lum: f32,
    /// g*(x) of eq. (9): f² / (|x − eye|² 4π S_p).
    g_star: f32,
    /// Image contribution Φ f cos θ g(x) (eq. (8)), zero when hidden.
    contrib: Rgb,
    /// Film position of the contribution.
    pix: Vec2,
    /// Number of children in the population.
    nchild: u32,
    /// Importance (unnormalised hit-selection weight).
    s: f64,
    /// Index of the parent hit, or [`NO_PARENT`].
    parent: u32,
    /// Segments from the light to this hit.
    depth: u32,
    /// May spawn a ray (non-zero output, below the depth limit).
    spawn: bool,
    /// Cell of the pooled-importance grid (0 without one).
    cell: u32,
}

/// Cells per axis of the pooled-importance grid.
const GRID_RES: usize = 16;
/// Pseudo-count of the grid's prior: a cell's weight is shrunk toward the
/// mean over all cells as if it had this many samples at the mean.
const GRID_PRIOR: f64 = 4.0;
/// Defensive floor of a cell's weight, as a fraction of the mean, so that
/// every hit keeps a positive selection probability (E[T*L] = TL).
const GRID_FLOOR: f64 = 0.05;

/// Pooled importance (`--variant pooled`, not in the paper): a uniform grid
/// over the scene's bounds. Each cell keeps Σr and the count of the rays
/// spawned from hits inside it, where r = Lum(child's image contribution) /
/// Lum(child's power) is the image impact per unit power of where the ray
/// landed (0 when it escaped or landed hidden from the camera). Then
/// W(cell) = (Σr + n₀ r̄) / (n + n₀), shrunk toward the mean r̄ over all
/// cells, estimates how much of the light reflected in that cell reaches
/// the image, pooled over every hit ever spawned there instead of over one
/// hit's children (eq. (8)). A hit's importance is Lum(Φ a) · (W + f r̄).
///
/// The lanes share what they learn: each lane reads the grid as merged at
/// the end of the last pass plus its own records since, and at the end of
/// every pass the lanes' new records are merged in lane order (so a seed
/// still gives the same image whatever the thread count).
#[derive(Clone, Debug)]
struct ImportanceGrid {
    lo: glam::Vec3,
    scale: glam::Vec3,
    /// Everything this lane knows: the shared grid plus `fresh`.
    all: CellStats,
    /// This lane's records since the last merge.
    fresh: CellStats,
}

/// Σr and counts per cell, and over all cells.
#[derive(Clone, Debug)]
struct CellStats {
    sum: Vec<f64>,
    n: Vec<u32>,
    total: f64,
    count: u64,
}

impl CellStats {
    fn new(cells: usize) -> Self {
        CellStats {
            sum: vec![0.0; cells],
            n: vec![0; cells],
            total: 0.0,
            count: 0,
        }
    }

    fn add(&mut self, cell: usize, r: f64) {
        self.sum[cell] += r;
        self.n[cell] += 1;
        self.total += r;
        self.count += 1;
    }

    fn clear(&mut self) {
        self.sum.fill(0.0);
        self.n.fill(0);
        self.total = 0.0;
        self.count = 0;
    }

    fn merge(&mut self, o: &CellStats) {
        for (a, b) in self.sum.iter_mut().zip(&o.sum) {
            *a += b;
        }
        for (a, b) in self.n.iter_mut().zip(&o.n) {
            *a += b;
        }
        self.total += o.total;
        self.count += o.count;
    }
}

impl ImportanceGrid {
    fn new(lo: glam::Vec3, hi: glam::Vec3) -> Self {
        let extent = (hi - lo).max(glam::Vec3::splat(1e-6));
        let cells = GRID_RES * GRID_RES * GRID_RES;
        ImportanceGrid {
            lo,
            scale: glam::Vec3::splat(GRID_RES as f32) / extent,
            all: CellStats::new(cells),
            fresh: CellStats::new(cells),
        }
    }

    fn cell(&self, p: glam::Vec3) -> u32 {
        let q = ((p - self.lo) * self.scale).max(glam::Vec3::ZERO);
        let r = GRID_RES as u32 - 1;
        let (x, y, z) = (
            (q.x as u32).min(r),
            (q.y as u32).min(r),
            (q.z as u32).min(r),
        );
        (z * GRID_RES as u32 + y) * GRID_RES as u32 + x
    }

    fn record(&mut self, cell: u32, r: f64) {
        if !r.is_finite() {
            return;
        }
        self.all.add(cell as usize, r);
        self.fresh.add(cell as usize, r);
    }

    /// W(cell) + f r̄, always positive.
    fn weight(&self, cell: u32) -> f64 {
        let a = &self.all;
        let mean = if a.total > 0.0 {
            a.total / a.count as f64
        } else {
            1.0
        };
        let (sum, n) = (a.sum[cell as usize], a.n[cell as usize] as f64);
        (sum + GRID_PRIOR * mean) / (n + GRID_PRIOR) + GRID_FLOOR * mean
    }
}

/// Merges the lanes' fresh records into `shared` in lane order and gives
/// every lane the merged grid.
fn share_grids(shared: &mut CellStats, lanes: &mut [Lane]) {
    for l in lanes.iter() {
        if let Some(g) = &l.grid {
            shared.merge(&g.fresh);
        }
    }
    for l in lanes.iter_mut() {
        if let Some(g) = l.grid.as_mut() {
            g.all.clone_from(shared);
            g.fresh.clear();
        }
    }
}

/// One independent population with its films.
#[derive(Clone, Debug)]
struct Lane {
    hits: Vec<Hit>,
    /// Prefix sums of the hits' selection weights (zero for hits that cannot
    /// spawn), for selection by binary search.
    cum: Vec<f64>,
    /// Σ out_lum over the hits that can spawn, in stored units.
    reflected: f64,
    /// The lazy power factor: actual power = σ · stored power.
    sigma: f64,
    /// Iteration index m of the last step.
    m: u64,
    /// Steps taken in the current phase.
    in_phase: u32,
    /// Phases completed, and those averaged into `hit_film`.
    phases: u64,
    counted: u64,
    /// Steps taken (the lights' image is averaged over them).
    steps: u64,
    /// The lights' image, Σ over steps of the emission-vertex splats.
    le_film: Film,
    /// Σ over the counted phases of the hits' image.
    hit_film: Film,
    /// The pooled-importance grid (`--variant pooled` only).
    grid: Option<ImportanceGrid>,
}

impl Lane {
    fn new(w: u32, h: u32, grid: Option<ImportanceGrid>) -> Self {
        Lane {
            grid,
            hits: Vec::new(),
            cum: Vec::new(),
            reflected: 0.0,
            sigma: 1.0,
            m: 0,
            in_phase: 0,
            phases: 0,
            counted: 0,
            steps: 0,
            le_film: Film::new(w, h),
            hit_film: Film::new(w, h),
        }
    }

    fn push(&mut self, hit: Hit) {
        let w = if hit.spawn { hit.s } else { 0.0 };
        if hit.spawn {
            self.reflected += hit.out_lum as f64;
        }
        self.cum.push(self.cum.last().copied().unwrap_or(0.0) + w);
        self.hits.push(hit);
    }

    /// Rebuilds the prefix sums and Σ out_lum after the purge.
    fn rebuild(&mut self) {
        self.cum.clear();
        self.reflected = 0.0;
        let mut acc = 0.0;
        for h in &self.hits {
            if h.spawn {
                acc += h.s;
                self.reflected += h.out_lum as f64;
            }
            self.cum.push(acc);
        }
    }
}

/// The progressive state of light path building.
pub struct Plb {
    settings: Settings,
    /// The merged pooled-importance grid (`--variant pooled` only).
    shared: Option<CellStats>,
    lanes: Vec<Lane>,
    pixels: u64,
    camera_pass: CameraPass,
}

impl Plb {
    /// Light path building for `world`.
    pub fn new(world: &World, settings: Settings) -> Self {
        let (w, h) = (world.camera.width, world.camera.height);
        let n = settings.lanes.max(1);
        Plb {
            camera_pass: CameraPass::new(
                world,
                settings.camera_pass,
                settings.seed,
                settings.max_depth,
            ),
            lanes: (0..n)
                .map(|_| {
                    let grid = (settings.importance == Importance::Pooled).then(|| {
                        let (lo, hi) = world.scene.bounds();
                        ImportanceGrid::new(lo, hi)
                    });
                    Lane::new(w, h, grid)
                })
                .collect(),
            shared: (settings.importance == Importance::Pooled)
                .then(|| CellStats::new(GRID_RES * GRID_RES * GRID_RES)),
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
        let b = hits.to_image(inv(counted));
        let mut img = Image {
            width: w,
            height: h,
            data: a.data.iter().zip(&b.data).map(|(x, y)| *x + *y).collect(),
        };
        self.camera_pass.add_to(&mut img);
        img
    }
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
        let n = self.steps_per_lane();
        let s = &self.settings;
        let rays = self
            .lanes
            .par_iter_mut()
            .enumerate()
            .map(|(i, lane)| {
                let mut rng = Pcg32::keyed(&[s.seed, pass, i as u64, 0x91b]);
                (0..n)
                    .map(|_| iterate(world, s, &mut rng, lane))
                    .sum::<u64>()
            })
            .sum::<u64>();
        if let Some(shared) = self.shared.as_mut() {
            share_grids(shared, &mut self.lanes);
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
        steps as f64 / self.pixels as f64
    }
}

/// One step of `Iterate` (§3), ending the phase when it is full. Returns the
/// rays traced.
fn iterate(world: &World, s: &Settings, rng: &mut Pcg32, lane: &mut Lane) -> u64 {
    let max_depth = s.max_depth.unwrap_or(u32::MAX);
    let mut rays = 0;
    let m = lane.m + 1;
    lane.m = m;
    lane.steps += 1;

    // Select the lights or hit i: the lights by their share of the power of
    // L_{m−1} (§3), the hits in proportion to their importance (§3.1)
    let phi_e = world.lights.total_power();
    let w_hits = lane.cum.last().copied().unwrap_or(0.0);
    let refl = lane.sigma * lane.reflected;
    let p_light = if w_hits > 0.0 && refl > 0.0 {
        phi_e / (phi_e + refl)
    } else {
        1.0
    };
    let u = rng.next_f64();
    let mut shot: Option<(Ray, Rgb, u32, u32)> = None; // ray, Φ, parent, depth
    if u < p_light {
        // Sample the light source: Φ = Le cos θ / p_e / (1 − Σs_i)
        let (u_sel, u_pos, u_dir) = (rng.next_f32(), rng.next_2d(), rng.next_2d());
        if let Some(es) = world
            .lights
            .sample_emission(&world.scene, u_sel, u_pos, u_dir)
        {
            let inv_p = (1.0 / p_light) as f32;
            if !es.is_env {
                rays += connect_emission(world, es.p, es.n, es.phi_pos * inv_p, &mut lane.le_film);
            }
            let ray = es.ray();
            shot = Some((ray, es.phi * inv_p, NO_PARENT, 1));
        }
    } else {
        // Select hit i with s_i = (1 − P(light)) w_i / Σw, then sample a
        // direction from its cosine-weighted BSDF:
        // Φ = Φ_i f cos θ / p / s_i
        let t = rng.next_f64() * w_hits;
        let i = lane
            .cum
            .partition_point(|&c| c <= t)
            .min(lane.hits.len() - 1);
        let h = &lane.hits[i];
        let s_i = (1.0 - p_light) * h.s / w_hits;
        if s_i > 0.0 {
            let v = Vertex::new(world, h.sp, h.wo);
            if let Some((wi, w)) = scatter(&v, rng) {
                let phi = h.phi * w * (lane.sigma / s_i) as f32;
                let ray = Ray::new(offset_point(h.sp.p, h.sp.ng, wi), wi);
                shot = Some((ray, phi, i as u32, h.depth + 1));
            }
        }
    }

    // Multiply every stored power by (1 − 1/m), lazily through σ
    if m == 1 {
        lane.hits.clear();
        lane.cum.clear();
        lane.reflected = 0.0;
        lane.sigma = 1.0;
    } else {
        lane.sigma *= 1.0 - 1.0 / m as f64;
    }

    // Trace, and append the new hit with power Φ/m
    if let Some((ray, phi, parent, depth)) = shot {
        let stored = phi * (1.0 / (m as f64 * lane.sigma)) as f32;
        let before = lane.hits.len();
        rays += trace(world, ray, stored, parent, depth, max_depth, rng, lane);
        // Pooled importance: the image impact per unit power of where the
        // ray from the parent's cell landed (0 if it added no visible hit)
        if let Some(g) = lane.grid.as_mut().filter(|_| parent != NO_PARENT) {
            let r = lane.hits.get(before).map_or(0.0, |c| {
                let l = luminance(c.phi) as f64;
                if l > 0.0 {
                    luminance(c.contrib).max(0.0) as f64 / l
                } else {
                    0.0
                }
            });
            g.record(lane.hits[parent as usize].cell, r);
        }
    }

    lane.in_phase += 1;
    if lane.in_phase >= s.phase_len {
        end_phase(s, rng, lane);
    }
    rays
}

/// Sends stored power `phi` along `ray`, through delta chains
/// ([`follow_delta_chain`]), and appends the first non-delta hit with its
/// camera connection. Returns the rays.
#[allow(clippy::too_many_arguments)]
fn trace(
    world: &World,
    ray: Ray,
    phi: Rgb,
    parent: u32,
    depth: u32,
    max_depth: u32,
    rng: &mut Pcg32,
    lane: &mut Lane,
) -> u64 {
    let mut rays = 0;
    let Some(Landing {
        vertex: v,
        phi,
        depth,
    }) = follow_delta_chain(world, ray, phi, depth, rng, &mut rays)
    else {
        return rays;
    };

    // The hit's image contribution, eq. (8), made once (deterministic)
    let mut contrib = Rgb::ZERO;
    let mut pix = Vec2::ZERO;
    if depth < max_depth && v.bsdf.has_smooth() {
        if let Some((p, c)) = connect_to_camera(world, &v, phi, &mut rays) {
            contrib = c;
            pix = p;
        }
    }
    // The potential impact, eq. (9): Φ a g*(x), g* = f²/(|x − eye|² 4π S_p)
    let sp = v.sp;
    let a = v.bsdf.albedo(v.wo_local);
    let out_lum = luminance(phi * a).max(0.0);
    let r2 = (sp.p - world.camera.position()).length_squared().max(1e-12);
    let g_star = world.camera.pixels_per_area() / (r2 * 4.0 * std::f32::consts::PI);
    let spawn = out_lum > 0.0 && depth.saturating_add(1) < max_depth && out_lum.is_finite();
    if !(phi.is_finite() && out_lum.is_finite()) {
        return rays;
    }
    let (cell, s) = match &lane.grid {
        Some(g) => {
            let cell = g.cell(sp.p);
            (cell, out_lum as f64 * g.weight(cell))
        }
        None => (0, (out_lum * g_star) as f64),
    };
    lane.push(Hit {
        sp,
        wo: v.wo,
        phi,
        out_lum,
        g_star,
        contrib,
        pix,
        nchild: 0,
        s,
        parent,
        depth,
        spawn,
        cell,
    });
    rays
}

/// The end of a phase (§5): the image estimate, `ComputeImportance`, and the
/// random purge.
fn end_phase(s: &Settings, rng: &mut Pcg32, lane: &mut Lane) {
    lane.in_phase = 0;
    lane.phases += 1;

    // The phase image: every hit's camera contribution at its current power
    if lane.phases > s.discard {
        lane.counted += 1;
        let sigma = lane.sigma as f32;
        for h in &lane.hits {
            if h.contrib != Rgb::ZERO {
                lane.hit_film.splat(h.pix.x, h.pix.y, h.contrib * sigma);
            }
        }
    }

    match &lane.grid {
        Some(g) => {
            for h in lane.hits.iter_mut() {
                h.s = h.out_lum as f64 * g.weight(h.cell);
            }
        }
        None => compute_importance(&mut lane.hits, s.lambda as f64),
    }
    purge(&mut lane.hits, lane.sigma, s.population, rng);
    lane.sigma = 1.0;
    lane.rebuild();
    // The survivors carry the estimate with the weight of one phase (see the
    // module docs): the next phase runs m = P+1 … 2P
    lane.m = s.phase_len as u64;
}

/// `ComputeImportance` of §3.1: the potential impact of eq. (9) plus λ times
/// the image impact of each child, eq. (8), averaged over the hit and its
/// children. Left unnormalised (the selection normalises by the sum).
fn compute_importance(hits: &mut [Hit], lambda: f64) {
    for h in hits.iter_mut() {
        h.s = 0.0;
        h.nchild = 0;
    }
    for i in 0..hits.len() {
        let potential = (hits[i].out_lum * hits[i].g_star) as f64;
        hits[i].s += potential;
        let p = hits[i].parent;
        if p != NO_PARENT {
            let impact = luminance(hits[i].contrib).max(0.0) as f64;
            let parent = &mut hits[p as usize];
            parent.s += lambda * impact;
            parent.nchild += 1;
        }
    }
    for h in hits.iter_mut() {
        h.s /= (h.nchild + 1) as f64;
    }
}

/// The random purge of §4: hit i survives with k_i = min(1, c s_i), c chosen
/// so that Σk_i = `cap` (when more than `cap` hits have s_i > 0); survivors'
/// power and importance are divided by k_i, and σ is folded into the stored
/// powers. Parent links to killed hits are cut.
///
/// The survivors are compacted in place, in order, so the population keeps
/// its allocation from phase to phase (building a new vector each phase
/// reallocated the whole population whenever the next phase outgrew it:
/// callgrind counted 8.6 % more instructions for plb pooled on hidden-gap).
fn purge(hits: &mut Vec<Hit>, sigma: f64, cap: usize, rng: &mut Pcg32) {
    let n = hits.len();
    let c = survival_scale(hits.iter().map(|h| h.s), cap);
    let mut new_index = vec![NO_PARENT; n];
    let (mut i, mut kept) = (0, 0);
    // retain_mut visits the hits once each, in order
    hits.retain_mut(|h| {
        let index = i;
        i += 1;
        let k = match c {
            None => 1.0,
            Some(c) => (c * h.s).min(1.0),
        };
        if k <= 0.0 || (k < 1.0 && rng.next_f64() >= k) {
            return false;
        }
        let f = (sigma / k) as f32;
        h.phi *= f;
        h.contrib *= f;
        h.out_lum *= f;
        h.s *= sigma / k;
        new_index[index] = kept;
        kept += 1;
        true
    });
    for h in hits.iter_mut() {
        if h.parent != NO_PARENT {
            h.parent = new_index[h.parent as usize];
        }
    }
}

/// The c with Σ min(1, c s_i) = `cap`, or None when every hit with s_i > 0
/// can survive (then all hits are kept with k_i = 1). Found by the
/// fixed-point iteration c ← (cap − #saturated) / Σ_unsaturated s_i from
/// c = cap / Σs_i, which increases monotonically to the root (no sort: the
/// purge runs once per phase over the whole population).
fn survival_scale(s: impl Iterator<Item = f64> + Clone, cap: usize) -> Option<f64> {
    let (n, total) = s
        .clone()
        .filter(|x| *x > 0.0)
        .fold((0usize, 0.0f64), |(n, t), x| (n + 1, t + x));
    if n <= cap || total <= 0.0 {
        return None;
    }
    let mut c = cap as f64 / total;
    for _ in 0..64 {
        let (sat, rest) = s
            .clone()
            .filter(|x| *x > 0.0)
            .fold((0usize, 0.0f64), |(k, r), x| {
                if c * x >= 1.0 {
                    (k + 1, r)
                } else {
                    (k, r + x)
                }
            });
        if sat >= cap || rest <= 0.0 {
            return Some(c);
        }
        let next = (cap - sat) as f64 / rest;
        if next <= c * (1.0 + 1e-12) {
            return Some(next.max(c));
        }
        c = next;
    }
    Some(c)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// c against Σ min(1, c s_i) = cap on populations with many saturated
    /// hits, over a range of caps.
    #[test]
    fn survival_scale_solves_the_cap_equation() {
        let mut rng = Pcg32::keyed(&[7]);
        for n in [5usize, 50, 1400] {
            for cap in [1usize, 3, n / 2, n - 1] {
                let s: Vec<f64> = (0..n)
                    .map(|_| {
                        let u = rng.next_f64();
                        if u < 0.1 {
                            0.0
                        } else {
                            u.powi(8) * 1e3
                        }
                    })
                    .collect();
                let Some(c) = survival_scale(s.iter().copied(), cap) else {
                    assert!(s.iter().filter(|x| **x > 0.0).count() <= cap);
                    continue;
                };
                let sum: f64 = s.iter().map(|x| (c * x).min(1.0)).sum();
                assert!(
                    (sum - cap as f64).abs() < 1e-6 * cap as f64,
                    "n {n} cap {cap}: Σk = {sum}"
                );
            }
        }
    }

    #[test]
    fn survival_scale_sums_to_cap() {
        let s = [10.0, 1.0, 1.0, 1.0, 0.5, 0.0, 0.25];
        let c = survival_scale(s.iter().copied(), 3).unwrap();
        let sum: f64 = s.iter().map(|x| (c * x).min(1.0)).sum();
        assert!((sum - 3.0).abs() < 1e-9, "{sum}");
        assert!(survival_scale(s.iter().copied(), 6).is_none());
    }
}
