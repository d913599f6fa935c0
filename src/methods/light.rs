//! `light`: light tracing, the single-ray form of stochastic iteration (§4 of
//! the 1999 stochastic-iteration paper).
//!
//! Particles leave the lights (chosen by power, cosine-distributed
//! directions), and at every non-delta vertex x the walk is connected to the
//! camera: Φ · f_r(ω_in, x, ω_eye) · cos θ · g(x) is added to the pixel that
//! sees x when the segment is clear, g(x) being the pixel weight of §2 of the
//! light-path-building paper ([`crate::camera::Camera::project`]). Emitter
//! points connect to the camera directly, so visible lights appear. The BSDF
//! is evaluated in importance mode, with the shading-normal correction.
//!
//! Two variants (`--variant`):
//! - `walk` (default): independent random walks, each ended by Russian
//!   roulette on the albedo, so a particle keeps its power while it lives.
//! - `iteration`: the operator sequence L_n = Le + T*_n L_{n−1} of eq. (11),
//!   with the single-ray operator of eq. (19). Each step sends one ray that
//!   carries the whole power of L_{n−1}: from the point last hit, with
//!   probability a·Φ_n / (Φ_e + a·Φ_n), or from the lights (for Φ_n = Φ_e this
//!   is the a/(1+a) of the paper's end of §4, and the ray carries Φ(1+a)).
//!   The image is the running average P̃ of eqs. (12)–(13); `--discard K`
//!   drops the first K steps of each chain (the power-defect correction after
//!   eq. (18)).
//!
//! Limit of the raw method: a delta surface (mirror, smooth glass) seen
//! directly by the camera cannot be reached by a camera connection, so it
//! stays black, as in other light tracers (caustics on diffuse surfaces do
//! appear). By default the camera pass ([`crate::transport::camera_pass`])
//! estimates exactly that part of path space from the camera;
//! `--camera-pass off` shows the raw method.
//!
//! Parallelism: a fixed number of lanes, each with its own film and random
//! stream keyed by (seed, pass, lane); lanes are merged in order, so a seed
//! gives the same image whatever the thread count.
//!
//! Numbers (`--sampler`): Owen-scrambled Sobol points (the default), or
//! independent PCG32 streams per lane. With `sobol`, walk k of a pass
//! (counted over all lanes, lane l's walks a contiguous range whatever the
//! thread count) is point k of a Sobol sequence randomised by (seed, pass)
//! ([`crate::sampling::SobolWalkSampler`]: the emission in dimensions
//! 0–4, four per vertex after), and the camera pass draws per (seed,
//! pixel, pass) ([`crate::transport::camera_pass`]). Where the CPU has
//! AVX2, the Sobol walks run eight at a time in lanes
//! ([`crate::transport::lanes::light_walks`]), to the same bits as one by
//! one; the independent walks share a lane's stream one after another and
//! run one by one. The iteration variant's
//! steps always draw from PCG32: a lane's steps form one Markov chain (each
//! step starts from the point the last one landed on, chosen by the
//! chain's state), so the steps are not independent samples of one
//! integrand, and giving step k the k-th point of a low-discrepancy set
//! stratifies nothing that the estimate averages; `--sampler` then sets
//! the camera pass only.
//!
//! ```text
//! kalos render scenes/cbox/cbox.xml --method light --time 10 -o l.exr
//! ```

use rayon::prelude::*;

use super::{
    camera_pass, film_item, Common, Method, MethodError, MethodSettings, StepStats, World, FILM,
    IMAGE,
};
use crate::film::{Film, Image};
use crate::geometry::{offset_point, Ray};
use crate::memory::MemoryItem;
use crate::sampling::{Pcg32, SamplerKind};
use crate::scene::{luminance, Rgb};
use crate::simd::dispatched;
use crate::state::{Shard, ShardKind, State};
use crate::transport::camera_pass::CameraPass;
use crate::transport::{
    connect_emission_sample, connect_to_camera, follow_delta_chain, lanes, light_tracing_walk,
    scatter, Landing, Roulette, WalkKind,
};

/// Which form of the method.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "kebab-case")]
#[cfg_attr(feature = "cli", derive(clap::ValueEnum))]
pub enum Variant {
    /// Independent walks with Russian roulette on the albedo.
    Walk,
    /// The operator sequence of eq. (11), averaged as in eq. (13).
    Iteration,
}

/// Settings of the light tracer.
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
    /// Independent walks with Russian roulette (walk), or the operator
    /// sequence of eq. (11) averaged as in eq. (13) (iteration).
    #[cfg_attr(feature = "cli", arg(long, value_enum, default_value = "walk"))]
    pub variant: Variant,
    /// Independent lanes (films and streams); fixed so that results do not
    /// depend on the thread count.
    #[cfg_attr(feature = "cli", arg(skip = 8usize))]
    pub lanes: usize,
    /// Walks (or iteration steps) per pass; 0 means one per pixel.
    #[cfg_attr(feature = "cli", arg(skip))]
    pub paths_per_pass: u64,
    /// Iteration variant: steps dropped at the start of each chain (the
    /// power-defect correction after eq. (18) of the 1999 paper).
    #[cfg_attr(feature = "cli", arg(long, default_value_t = 0))]
    pub discard: u64,
    /// The camera pass, which estimates from the camera what light paths
    /// cannot reach (delta surfaces seen by the camera, the environment):
    /// on, or off for the raw method.
    #[cfg_attr(feature = "cli", arg(long, value_name = "on|off", default_value = "on", value_parser = super::cli::on_off, action = clap::ArgAction::Set))]
    pub camera_pass: bool,
    /// The numbers the walks and the camera pass draw: Owen-scrambled
    /// Sobol points (the default), walk k of a pass taking point k of a
    /// sequence randomised per pass, or independent ones (PCG32 streams;
    /// the iteration variant's steps are always independent). Per walk
    /// sobol's relMSE is 0.94–1.00 of independent's at 256 walks per pixel
    /// (cbox, the baffle, glass-mirror, big-room-textured); its walks run
    /// eight at a time in AVX lanes ([`crate::transport::lanes::light_walks`]),
    /// so at equal time (8 s, three seeds) its relMSE is 0.74 of
    /// independent's on cbox, 0.80 on the baffle, 0.98 on glass-mirror and
    /// 0.88 on big-room-textured (docs/notebook/light.md). A partial-result
    /// file without the field was written with independent numbers
    /// ([`SamplerKind`]'s own default).
    #[cfg_attr(feature = "cli", arg(long, value_enum, default_value = "sobol"))]
    #[serde(default, skip_serializing_if = "SamplerKind::is_independent")]
    pub sampler: SamplerKind,
}

impl Default for Settings {
    fn default() -> Self {
        Settings {
            seed: 0,
            max_depth: None,
            variant: Variant::Walk,
            lanes: 8,
            paths_per_pass: 0,
            discard: 0,
            camera_pass: true,
            sampler: SamplerKind::Sobol,
        }
    }
}

impl Settings {
    /// Rejects settings that cannot work.
    pub fn validate(&self) -> Result<(), MethodError> {
        if self.discard > 0 && self.variant != Variant::Iteration {
            return Err(MethodError(
                "--discard applies to light's iteration variant only (--variant iteration): \
                 independent walks have no start-up transient to drop"
                    .into(),
            ));
        }
        if self.lanes == 0 {
            return Err(MethodError("light needs at least one lane".into()));
        }
        Ok(())
    }
}

/// The state of one iteration chain between passes.
#[derive(Clone, Debug, Default)]
struct Chain {
    /// Steps taken so far.
    steps: u64,
    /// Steps that were accumulated into the film.
    counted: u64,
    /// The single point of T*_n L_{n−1}, which received the last transfer
    /// (if the last ray hit one): the vertex, seen from where the power came
    /// from, the power, and the segments of the walk so far.
    last: Option<Landing>,
}

impl MethodSettings for Settings {
    fn validate(&self) -> Result<(), MethodError> {
        Settings::validate(self)
    }

    /// Exact: a shard owns the lanes l ≡ K (mod N) (their streams are
    /// keyed by (seed, pass, lane)) and, for the camera pass, the rows
    /// y ≡ K (mod N).
    fn shard_kind(&self) -> Result<ShardKind, MethodError> {
        Ok(ShardKind::Exact)
    }

    fn check_shard_count(&self, count: u32) -> Result<(), MethodError> {
        if count as usize > self.lanes {
            return Err(MethodError(format!(
                "light splits into at most {} shards (one per lane: the streams that keep its \
                 image independent of the thread count), not {}",
                self.lanes, count
            )));
        }
        Ok(())
    }

    fn resumable(&self) -> Result<(), &'static str> {
        match self.variant {
            Variant::Walk => Ok(()),
            Variant::Iteration => Err(
                "its iteration chains carry a surface point from pass to pass (use --variant walk)",
            ),
        }
    }

    fn merge_exact(
        &self,
        states: &[&State],
        width: u32,
        height: u32,
    ) -> Result<Image, MethodError> {
        merge_image(states, width, height)
    }

    /// One film per lane, their merge, the image, and the camera pass.
    fn memory(&self, width: u32, height: u32) -> Vec<MemoryItem> {
        let lanes = self.lanes.max(1) as u64;
        vec![film_item(
            width,
            height,
            (lanes + 1) * FILM + IMAGE + camera_pass(self.camera_pass),
            &format!(" ({lanes} lanes)"),
        )]
    }

    fn create(&self, world: &World, common: &Common) -> Box<dyn Method> {
        Box::new(LightTracer::new(
            world,
            Settings {
                seed: common.seed,
                max_depth: common.max_depth,
                ..self.clone()
            },
        ))
    }
}

/// The light tracer's progressive state.
pub struct LightTracer {
    settings: Settings,
    films: Vec<Film>,
    chains: Vec<Chain>,
    /// Walks traced (walk variant), in all lanes: what one run of the same
    /// passes traces, also when this process is a shard.
    walks: u64,
    /// Walks traced in each lane by this process.
    lane_walks: Vec<u64>,
    pixels: u64,
    camera_pass: CameraPass,
    /// The lanes this process runs: l ≡ K (mod N) for shard K/N.
    shard: Shard,
}

impl LightTracer {
    /// A light tracer for `world`.
    pub fn new(world: &World, settings: Settings) -> Self {
        let (w, h) = (world.camera.width, world.camera.height);
        let lanes = settings.lanes.max(1);
        LightTracer {
            camera_pass: CameraPass::new(
                world,
                settings.camera_pass,
                false,
                settings.seed,
                settings.max_depth,
                settings.sampler,
            ),
            films: (0..lanes).map(|_| Film::new(w, h)).collect(),
            chains: vec![Chain::default(); lanes],
            lane_walks: vec![0; lanes],
            settings,
            walks: 0,
            pixels: w as u64 * h as u64,
            shard: Shard::WHOLE,
        }
    }

    fn per_pass(&self) -> u64 {
        if self.settings.paths_per_pass > 0 {
            self.settings.paths_per_pass
        } else {
            self.pixels
        }
    }
}

impl Method for LightTracer {
    fn name(&self) -> &'static str {
        "light"
    }

    fn prepare(&mut self, world: &World) -> Result<StepStats, MethodError> {
        Ok(StepStats {
            rays: self.camera_pass.prepare(world),
        })
    }

    fn step(&mut self, world: &World, pass: u64) -> StepStats {
        let n = self.per_pass();
        let lanes = self.films.len() as u64;
        let s = &self.settings;
        let shard = self.shard;
        let rays: u64 = self
            .films
            .par_iter_mut()
            .zip(self.chains.par_iter_mut())
            .zip(self.lane_walks.par_iter_mut())
            .enumerate()
            .map(|(lane, ((film, chain), lane_walks))| {
                if !shard.owns(lane as u64) {
                    return 0;
                }
                let lane = lane as u64;
                let count = n / lanes + u64::from(lane < n % lanes);
                // The lane's walks are indices first..first + count of the pass
                let first = lane * (n / lanes) + lane.min(n % lanes);
                *lane_walks += count;
                let rng = Pcg32::keyed(&[s.seed, pass, lane, 0x11]);
                run_lane(world, s, rng, pass, first, count, film, chain)
            })
            .sum();
        self.walks += n;
        let camera_rays = self.camera_pass.step(world, pass);
        StepStats {
            rays: rays + camera_rays,
        }
    }

    fn image(&self, world: &World) -> Image {
        let mut total = Film::new(world.camera.width, world.camera.height);
        for f in &self.films {
            total.merge(f);
        }
        let n = match self.settings.variant {
            Variant::Walk => self.walks,
            Variant::Iteration => self.chains.iter().map(|c| c.counted).sum(),
        };
        let mut img = total.mean(n);
        self.camera_pass.add_to(&mut img);
        img
    }

    fn spp(&self) -> f64 {
        self.walks as f64 / self.pixels as f64
    }

    /// A shard runs the lanes l ≡ K (mod N) and the camera pass's rows
    /// y ≡ K (mod N), every pass: each lane's film and each camera-pass sum
    /// then runs over the same streams in the same order as in one run.
    fn set_shard(&mut self, shard: Shard) -> Result<(), MethodError> {
        if shard.count as usize > self.films.len() {
            return Err(MethodError(format!(
                "light splits into at most {} shards, not {}",
                self.films.len(),
                shard.count
            )));
        }
        self.shard = shard;
        self.camera_pass.set_shard(shard);
        Ok(())
    }

    /// The films and counts of the lanes this process runs, and the camera
    /// pass's sums: counters `walks` (all lanes), `laneL` (the lane's
    /// divisor: walks, or steps counted by the iteration variant),
    /// `camera_passes`; buffers `laneL`, `camera`.
    fn state(&self) -> Option<State> {
        let mut st = State {
            counters: vec![("walks".into(), self.walks)],
            ..Default::default()
        };
        for (l, film) in self.films.iter().enumerate() {
            if self.shard.owns(l as u64) {
                let n = match self.settings.variant {
                    Variant::Walk => self.lane_walks[l],
                    Variant::Iteration => self.chains[l].counted,
                };
                st.counters.push((format!("lane{l}"), n));
                st.buffers.push((format!("lane{l}"), film.sum.clone()));
            }
        }
        if let Some((sum, passes)) = self.camera_pass.state() {
            st.counters.push(("camera_passes".into(), passes));
            st.buffers.push(("camera".into(), sum.to_vec()));
        }
        Some(st)
    }

    fn restore(&mut self, state: &State) -> Result<(), MethodError> {
        if self.settings.variant == Variant::Iteration {
            return Err(MethodError(
                "light --variant iteration cannot resume from a checkpoint: each chain carries \
                 the surface point that received its last transfer from one pass to the next, \
                 which is not saved; use --variant walk, or render without --resume"
                    .into(),
            ));
        }
        let pixels = self.pixels as usize;
        for l in 0..self.films.len() {
            if self.shard.owns(l as u64) {
                let name = format!("lane{l}");
                let film = state.need_buffer(&name, pixels)?;
                self.lane_walks[l] = state.need_counter(&name)?;
                self.films[l].sum.copy_from_slice(film);
            }
        }
        self.walks = state.need_counter("walks")?;
        if self.camera_pass.state().is_some() {
            let sum = state.need_buffer("camera", pixels)?;
            let passes = state.need_counter("camera_passes")?;
            self.camera_pass.restore(sum, passes);
        }
        Ok(())
    }
}

/// The image of a render split into shards, from the states of shards 0 to
/// N − 1 in order, computed as [`LightTracer::image`] computes it in one
/// run: the lanes' films summed in lane order and divided by the walks of
/// all lanes, then each pixel's camera-pass mean, from the shard that owns
/// its row.
pub fn merge_image(states: &[&State], width: u32, height: u32) -> Result<Image, MethodError> {
    let pixels = width as usize * height as usize;
    let mut lanes: Vec<(usize, &[glam::DVec3], u64)> = Vec::new();
    for st in states {
        for (name, _) in &st.buffers {
            if let Some(l) = name.strip_prefix("lane").and_then(|l| l.parse().ok()) {
                lanes.push((l, st.need_buffer(name, pixels)?, st.need_counter(name)?));
            }
        }
    }
    lanes.sort_by_key(|l| l.0);
    if lanes.iter().enumerate().any(|(i, l)| l.0 != i) {
        return Err(MethodError(
            "the shards' lanes are not each given once (parts of another split?)".into(),
        ));
    }
    let mut total = Film::new(width, height);
    let mut n = 0;
    for (_, sum, walks) in &lanes {
        for (a, b) in total.sum.iter_mut().zip(sum.iter()) {
            *a += *b;
        }
        n += walks;
    }
    let mut img = total.mean(n);
    if states.iter().all(|s| s.counter("camera_passes").is_some()) {
        let cams = states
            .iter()
            .map(|s| {
                Ok((
                    s.need_buffer("camera", pixels)?,
                    s.need_counter("camera_passes")?,
                ))
            })
            .collect::<Result<Vec<_>, MethodError>>()?;
        let k = states.len().max(1);
        for (i, p) in img.data.iter_mut().enumerate() {
            let (sum, passes) = cams[(i / width as usize) % k];
            if passes > 0 {
                *p += (sum[i] * (1.0 / passes as f64)).as_vec3();
            }
        }
    }
    Ok(img)
}

dispatched! {
    /// Traces `count` walks (or iteration steps) of one lane into its film;
    /// returns the rays traced. With Sobol points the walks are indices
    /// `first..first + count` of pass `pass`'s sequence; otherwise they
    /// draw from `rng`. The per-pass loop that runtime dispatch compiles
    /// for x86-64-v3 ([`crate::transport::dispatch`]).
    #[allow(clippy::too_many_arguments)]
    fn run_lane(
        world: &World,
        s: &Settings,
        rng: Pcg32,
        pass: u64,
        first: u64,
        count: u64,
        film: &mut Film,
        chain: &mut Chain,
    ) -> u64 {
        // Plain loops: an iterator adaptor would be a function of its own,
        // compiled for the baseline only
        let mut rng = rng;
        let mut rays = 0;
        // The splats are held back a few at a time (same sums, bit for
        // bit), and settled before the film is read
        film.begin_queue();
        let kind = WalkKind {
            max_depth: s.max_depth,
            roulette: Roulette::Albedo,
            glossy_split: false,
        };
        match (s.variant, s.sampler) {
            (Variant::Walk, SamplerKind::Independent) => {
                for _ in 0..count {
                    rays += light_tracing_walk(world, &kind, &mut rng, film);
                }
            }
            (Variant::Walk, SamplerKind::Sobol) => {
                let walks = first..first + count;
                rays += lanes::light_walks(world, &kind, s.seed, pass, walks, film);
            }
            (Variant::Iteration, _) => {
                for _ in 0..count {
                    rays += iterate(world, s, &mut rng, film, chain);
                }
            }
        }
        film.settle();
        rays
    }
}

/// One step of the operator sequence of eq. (11): estimates M(Le) with its
/// own emission sample, picks where the next ray starts in proportion to the
/// power of L_{n−1} (the lights, or the point last hit), sends the whole
/// power along one ray, and measures the new point. Returns the rays traced.
fn iterate(
    world: &World,
    s: &Settings,
    rng: &mut Pcg32,
    film: &mut Film,
    chain: &mut Chain,
) -> u64 {
    let max_depth = s.max_depth.unwrap_or(u32::MAX);
    let lights = &world.lights;
    let phi_e = lights.total_power() as f32;
    let mut rays = 0;
    let counted = chain.steps >= s.discard;
    chain.steps += 1;
    if counted {
        chain.counted += 1;
    }
    let mut sink = Film::new(0, 0);
    let target: &mut Film = if counted { film } else { &mut sink };

    // M(Le): the lights' own image, one emission sample per step
    let (u_sel, u_pos, u_dir) = (rng.next_f32(), rng.next_2d(), rng.next_2d());
    if let Some(es) = lights.sample_emission(u_sel, u_pos, u_dir) {
        rays += connect_emission_sample(world, &es, 1.0, target);
    }

    // The power of L_{n−1}: Φ_e from the lights plus a·Φ reflected by the
    // point that received the last transfer.
    let last = chain.last.take();
    let mut start = None;
    if let Some(t) = &last {
        // A point whose next transfer could not reach the eye within
        // max_depth (it would land at depth + 1 and join the eye at depth +
        // 2) has no power left to transfer: L_{n−1} is then the lights' alone
        if t.depth < max_depth.saturating_sub(1) {
            let a = t
                .vertex
                .bsdf
                .albedo(t.vertex.wo_local)
                .max_element()
                .clamp(0.0, 1.0);
            let reflected = a * luminance(t.phi);
            let p_point = reflected / (phi_e + reflected);
            if p_point > 0.0 && rng.next_f32() < p_point {
                start = Some((t, p_point));
            } else if p_point > 0.0 {
                // selected the lights with probability 1 − p_point
                return rays + emit_and_transfer(world, s, rng, target, chain, 1.0 - p_point);
            }
        }
    }
    let Some((t, p_point)) = start else {
        return rays + emit_and_transfer(world, s, rng, target, chain, 1.0);
    };

    // Reflect the point's power into a direction sampled from f cos
    let Some((wi, w)) = scatter(&t.vertex, rng) else {
        return rays;
    };
    let phi = t.phi * w / p_point;
    let sp = &t.vertex.sp;
    rays + transfer(
        world,
        s,
        Ray::new(offset_point(sp.p, sp.ng, wi), wi),
        phi,
        t.depth + 1,
        rng,
        target,
        chain,
    )
}

/// Starts a new ray from the lights, carrying Φ_e/prob.
fn emit_and_transfer(
    world: &World,
    s: &Settings,
    rng: &mut Pcg32,
    film: &mut Film,
    chain: &mut Chain,
    prob: f32,
) -> u64 {
    let (u_sel, u_pos, u_dir) = (rng.next_f32(), rng.next_2d(), rng.next_2d());
    let Some(es) = world.lights.sample_emission(u_sel, u_pos, u_dir) else {
        return 0;
    };
    let ray = es.ray();
    transfer(world, s, ray, es.phi / prob, 1, rng, film, chain)
}

/// Sends power `phi` along `ray`; the hit point becomes T*_n L_{n−1}, and is
/// measured through a camera connection. Delta surfaces cannot be measured
/// and pass the power on at once ([`follow_delta_chain`]): the operator over
/// a delta chain is one transfer to the first non-delta point. A point
/// reached by more segments than `max_depth` allows before the eye is
/// neither measured nor kept.
#[allow(clippy::too_many_arguments)]
fn transfer(
    world: &World,
    s: &Settings,
    ray: Ray,
    phi: Rgb,
    depth: u32,
    rng: &mut Pcg32,
    film: &mut Film,
    chain: &mut Chain,
) -> u64 {
    let mut rays = 0;
    let Some(landing) = follow_delta_chain(world, ray, phi, depth, rng, &mut rays) else {
        return rays;
    };
    // A light path of `depth` segments joined to the eye has depth + 1
    if landing.depth >= s.max_depth.unwrap_or(u32::MAX) {
        return rays;
    }
    if let Some((pix, c)) = connect_to_camera(world, &landing.vertex, landing.phi, false, &mut rays)
    {
        film.splat(pix.x, pix.y, c);
    }
    chain.last = Some(landing);
    rays
}
