//! `path`: the reference path tracer. Unidirectional, with next-event
//! estimation and multiple importance sampling (power heuristic) between
//! light sampling and BSDF sampling, Russian roulette on the throughput, and
//! unlimited depth unless `--max-depth` is given (Mitsuba's convention: depth
//! 1 shows only directly visible emitters, 2 adds direct lighting).
//!
//! ```text
//! kalos render scenes/cbox/cbox.xml --method path --spp 256 -o out.exr
//! ```
//!
//! `--sampler sobol`, the default, draws Owen-scrambled Sobol points
//! ([`crate::sampling::sobol`]): the pass is the sample index, each pixel
//! its own randomisation, each vertex its own dimensions. The AVX lanes
//! draw from it as from independent numbers
//! ([`crate::transport::lanes::LaneSampler`]): each lane its own pixel's
//! point, the scalar path's dimensions at each vertex. At equal time its
//! error is 0.56 of independent numbers' on cbox and 0.54 on a textured
//! room, and within 5 % on the baffle and glass-mirror
//! (docs/notebook/path.md, "A cheap Sobol draw"); `--sampler independent`
//! gives PCG32 streams, the images of before.

use rayon::prelude::*;

use super::{
    film_item, Common, Method, MethodError, MethodSettings, StepStats, World, FILM, IMAGE,
};
use crate::accel::Hit;
use crate::emitter::LightSelection;
use crate::film::{Film, Image};
use crate::geometry::Ray;
use crate::memory::MemoryItem;
use crate::sampling::{Pcg32, SamplerKind};
use crate::scene::Rgb;
use crate::state::{Shard, ShardKind, State};
use crate::transport::lanes::camera_row;
use crate::transport::{radiance_from_hit, DepthLimits};

/// Settings of the path tracer.
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
    /// Depth from which Russian roulette may stop a path (Mitsuba's default
    /// 5, so that noise compares like for like).
    #[cfg_attr(feature = "cli", arg(long, default_value_t = 5))]
    pub rr_depth: u32,
    /// How next-event estimation chooses the light: spatially, by each
    /// light's importance at the shading point (power, distance,
    /// orientation; pbrt-v4's light tree; the default), or by power alone
    /// (Mitsuba's choice).
    #[cfg_attr(feature = "cli", arg(long, value_enum, default_value = "spatial"))]
    pub light_selection: LightSelection,
    /// The numbers the paths draw: Owen-scrambled Sobol points (the
    /// default), which stratify each pixel's samples in every 2D draw of
    /// every vertex, or independent ones (PCG32 streams). At equal time
    /// Sobol's error against independent's: cbox 0.56, big-room-textured
    /// 0.54, glass-mirror 0.99, the baffle 1.05 (docs/notebook/path.md, "A
    /// cheap Sobol draw"). A partial-result file without the field was
    /// written with independent numbers ([`SamplerKind`]'s own default).
    #[cfg_attr(feature = "cli", arg(long, value_enum, default_value = "sobol"))]
    #[serde(default, skip_serializing_if = "SamplerKind::is_independent")]
    pub sampler: SamplerKind,
}

impl Default for Settings {
    fn default() -> Self {
        Settings {
            seed: 0,
            max_depth: None,
            rr_depth: DepthLimits::default().rr_depth,
            light_selection: DepthLimits::default().light_selection,
            sampler: SamplerKind::Sobol,
        }
    }
}

impl Settings {
    /// Rejects settings that cannot work.
    pub fn validate(&self) -> Result<(), MethodError> {
        if self.rr_depth == 0 {
            return Err(MethodError(
                "--rr-depth must be at least 1 (the depth from which Russian roulette may stop a path)"
                    .into(),
            ));
        }
        Ok(())
    }
}

impl MethodSettings for Settings {
    fn validate(&self) -> Result<(), MethodError> {
        Settings::validate(self)
    }

    /// Exact: a shard owns the pixel rows y ≡ K (mod N) of every pass (the
    /// streams are keyed by (seed, pass, pixel)).
    fn shard_kind(&self) -> Result<ShardKind, MethodError> {
        Ok(ShardKind::Exact)
    }

    fn check_shard_count(&self, _count: u32) -> Result<(), MethodError> {
        Ok(())
    }

    fn resumable(&self) -> Result<(), &'static str> {
        Ok(())
    }

    fn merge_exact(
        &self,
        states: &[&State],
        width: u32,
        height: u32,
    ) -> Result<Image, MethodError> {
        merge_image(states, width, height)
    }

    /// The film and the image.
    fn memory(&self, width: u32, height: u32) -> Vec<MemoryItem> {
        vec![film_item(width, height, FILM + IMAGE, "")]
    }

    fn create(&self, world: &World, common: &Common) -> Box<dyn Method> {
        Box::new(PathTracer::new(
            world,
            Settings {
                seed: common.seed,
                max_depth: common.max_depth,
                ..self.clone()
            },
        ))
    }
}

/// The path tracer's progressive state: a sum per pixel and the pass count.
pub struct PathTracer {
    settings: Settings,
    film: Film,
    passes: u64,
    /// The rows this process renders: y ≡ K (mod N) for shard K/N.
    shard: Shard,
}

impl PathTracer {
    /// A path tracer for `world`.
    pub fn new(world: &World, settings: Settings) -> Self {
        PathTracer {
            settings,
            film: Film::new(world.camera.width, world.camera.height),
            passes: 0,
            shard: Shard::WHOLE,
        }
    }
}

impl Method for PathTracer {
    fn name(&self) -> &'static str {
        "path"
    }

    fn step(&mut self, world: &World, pass: u64) -> StepStats {
        self.steps(world, pass, 1)
    }

    /// Passes `pass` … `pass + k − 1` row by row: each row takes its `k`
    /// samples per pixel in pass order, so every pixel's sum adds the same
    /// numbers in the same order as `k` passes one after the other (the
    /// same bits), and the threads meet once per call instead of once per
    /// pass. Beside another busy process on two cores, the driver's
    /// batches took 0.886 of the time of single passes, and the same time
    /// on a quiet machine (docs/notebook/sampling.md).
    fn steps(&mut self, world: &World, pass: u64, k: u64) -> StepStats {
        let w = world.camera.width as usize;
        let seed = self.settings.seed;
        let settings = &self.settings;
        let limits = limits(settings);
        let shard = self.shard;
        // One sample per pixel; rows in parallel, each pixel with its own
        // stream keyed by (seed, pass, pixel), so the image does not depend on
        // the thread count.
        let rays: u64 = self
            .film
            .sum
            .par_chunks_mut(w)
            .enumerate()
            .map(|(y, row)| {
                if !shard.owns(y as u64) {
                    return 0;
                }
                (pass..pass + k)
                    .map(|p| camera_row(world, &limits, settings.sampler, seed, p, y, row, None))
                    .sum::<u64>()
            })
            .sum();
        self.passes += k;
        StepStats { rays }
    }

    fn batches(&self) -> bool {
        true
    }

    fn image(&self, _world: &World) -> Image {
        self.film.mean(self.passes)
    }

    fn spp(&self) -> f64 {
        self.passes as f64
    }

    /// A shard renders the rows y ≡ K (mod N), every pass: each pixel's
    /// sum then runs over the same streams in the same order as in one run.
    fn set_shard(&mut self, shard: Shard) -> Result<(), MethodError> {
        self.shard = shard;
        Ok(())
    }

    fn state(&self) -> Option<State> {
        Some(State {
            counters: vec![("passes".into(), self.passes)],
            buffers: vec![("film".into(), self.film.sum.clone())],
            ..Default::default()
        })
    }

    fn restore(&mut self, state: &State) -> Result<(), MethodError> {
        let film = state.need_buffer("film", self.film.sum.len())?;
        self.passes = state.need_counter("passes")?;
        self.film.sum.copy_from_slice(film);
        Ok(())
    }
}

/// The image of a render split into shards, from the states of shards 0 to
/// N − 1 in order: each row from the shard that owns it, divided by that
/// shard's passes, exactly as [`PathTracer::image`] divides in one run.
pub fn merge_image(states: &[&State], width: u32, height: u32) -> Result<Image, MethodError> {
    let pixels = width as usize * height as usize;
    let n = states.len().max(1);
    let films = states
        .iter()
        .map(|s| Ok((s.need_buffer("film", pixels)?, s.need_counter("passes")?)))
        .collect::<Result<Vec<_>, MethodError>>()?;
    let mut img = Image::new(width, height);
    for (i, p) in img.data.iter_mut().enumerate() {
        let (film, passes) = films[(i / width as usize) % n];
        let scale = if passes == 0 {
            0.0
        } else {
            1.0 / passes as f64
        };
        *p = (film[i] * scale).as_vec3();
    }
    Ok(img)
}

/// Radiance arriving along a primary `ray` and the number of rays traced for
/// it: the transport layer's camera-side estimator from the eye.
#[inline(always)]
pub fn radiance(world: &World, settings: &Settings, ray: Ray, rng: &mut Pcg32) -> (Rgb, u64) {
    radiance_hit(world, settings, ray, None, rng)
}

/// [`radiance`] with the primary ray's closest hit already found, when
/// `first` holds it (see [`radiance_from_hit`]).
#[inline(always)]
fn radiance_hit(
    world: &World,
    settings: &Settings,
    ray: Ray,
    first: Option<Option<Hit>>,
    rng: &mut Pcg32,
) -> (Rgb, u64) {
    radiance_from_hit(world, &limits(settings), ray, first, rng, 1)
}

/// The transport layer's limits for `settings`.
#[inline(always)]
fn limits(settings: &Settings) -> DepthLimits {
    DepthLimits {
        max_depth: settings.max_depth,
        rr_depth: settings.rr_depth,
        light_selection: settings.light_selection,
    }
}
