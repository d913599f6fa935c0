//! The lightmap bake, stage by stage: the second uv set, the texels, the
//! particles (phase 1 of the density bake, as is), the estimate at every
//! texel ([`super::estimate`]), the padding of charts, and the writers.
//!
//! Steered as the density bake is ([`Control`]): progress by phase, the
//! cancel flag read between batches of particles and slices of texels,
//! and `--time` / `--rays` stopping the tracing between batches when the
//! estimate would not fit any more. The estimate's work is counted as
//! rays at phase 1's rate: its visibility rays, and for the k-nearest
//! query of each texel [`KNN_RAYS`] rays' worth.
//!
//! The uv set is the asset's own TEXCOORD_1 when valid, else generated
//! ([`super::uv`]); the texels are every texel a triangle touches, each
//! owned by one triangle, its point clamped onto it ([`super::raster`]).

use std::path::PathBuf;
use std::sync::atomic::AtomicBool;
use std::time::Instant;

use super::estimate::{self, Estimator, HitIndex, Options, HIT_MEMORY};
use super::gather::{self, Atlas, Gather, GatherOptions};
use super::glb::GlbError;
use super::live::{Previews, SharedHits, Watch};
use super::uv::{self, UvError, UvOptions};
use super::{raster, DensityAtlas, Lightmap, LightmapUv, Texel};
use crate::color::Rgb;
use crate::film::Image;
use crate::image_io::{self, ImageIoError, PngOptions};
use crate::memory::MemoryItem;
use crate::methods::density::control::{Control, Limits, Phase, Tick};
use crate::methods::density::{self, pipeline, surfaces, DensityError};
use crate::scene::Scene;
use crate::world::World;

/// The default atlas side when neither a texel density nor a size is set.
pub const DEFAULT_SIZE: u32 = 512;
/// Largest atlas side.
pub const MAX_SIZE: u32 = 16384;
/// The k-nearest query of a texel costs about as much as this many rays
/// (measured on the Cornell box, k = 256).
pub const KNN_RAYS: u64 = 8;
/// Hits a particle leaves on average, to size the hits before the bake
/// (as the density bake's hit file assumes).
pub const HITS_PER_PARTICLE: u64 = 4;

/// What a lightmap bake makes and writes.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct LightmapSettings {
    /// Texels per metre (per scene unit); None: [`LightmapSettings::size`].
    pub texel_density: Option<f32>,
    /// The atlas's side in texels; None with no density either:
    /// [`DEFAULT_SIZE`].
    pub size: Option<u32>,
    /// Pack a generated uv set's charts by rows, not by their shapes
    /// ([`UvOptions::fast_packing`]).
    pub fast_packing: bool,
    /// Write the atlas (irradiance, linear RGB) as an EXR here.
    pub atlas: Option<PathBuf>,
    /// Write each texel's standard error as an EXR here.
    pub error: Option<PathBuf>,
    /// The estimator's settings.
    pub estimator: Options,
    /// The final gather from the density atlas (its `rays` and `lights`
    /// at 0: the density estimate is the atlas, as the paper's method
    /// gives it).
    pub gather: GatherOptions,
}

impl LightmapSettings {
    /// Rejects settings that cannot work.
    pub fn check(&self) -> Result<(), LightmapError> {
        if let Some(d) = self.texel_density {
            if !(d.is_finite() && d > 0.0) {
                return Err(LightmapError::Settings(format!(
                    "--texel-density must be a positive number of texels per metre, got {d}"
                )));
            }
        }
        if let Some(n) = self.size {
            if !(1..=MAX_SIZE).contains(&n) {
                return Err(LightmapError::Settings(format!(
                    "--lightmap-size must be between 1 and {MAX_SIZE} texels, got {n}"
                )));
            }
        }
        if self.texel_density.is_some() && self.size.is_some() {
            return Err(LightmapError::Settings(
                "give --texel-density or --lightmap-size, not both".into(),
            ));
        }
        if self.estimator.neighbours == Some(0) {
            return Err(LightmapError::Settings(
                "the estimator's neighbour count must be positive".into(),
            ));
        }
        let c = self.estimator.growth;
        if !(c.is_finite() && c > 0.0) {
            return Err(LightmapError::Settings(format!(
                "the estimator's growth must be a positive number, got {c}"
            )));
        }
        Ok(())
    }

    /// The memory of a bake of an atlas of `width` × `height` texels with
    /// `particles` particles: the atlas with its texels, and the hits.
    pub fn memory(&self, width: u32, height: u32, particles: u64) -> Vec<MemoryItem> {
        let texels = width as u64 * height as u64;
        // irradiance, error, covered, and a Texel per texel
        let per_texel = (2 * std::mem::size_of::<Rgb>() + 1 + std::mem::size_of::<Texel>()) as u64;
        // the grouped records (16 bytes each in memory) and their index
        let per_hit = 16 + HIT_MEMORY;
        vec![
            MemoryItem {
                what: format!("the lightmap atlas ({width}×{height} texels)"),
                bytes: texels.saturating_mul(per_texel),
                remedy: "lower --lightmap-size or --texel-density",
            },
            MemoryItem {
                what: format!(
                    "the lightmap's hits (about {} from {particles} particles)",
                    particles.saturating_mul(HITS_PER_PARTICLE)
                ),
                bytes: particles
                    .saturating_mul(HITS_PER_PARTICLE)
                    .saturating_mul(per_hit),
                remedy: "lower --particles",
            },
        ]
    }
}

/// Why a lightmap bake stopped.
#[derive(Debug, thiserror::Error)]
pub enum LightmapError {
    /// Settings that cannot work.
    #[error("{0}")]
    Settings(String),
    /// An atlas too large for its texel density.
    #[error("a texel density of {density} per metre needs an atlas of {side}×{side} texels, more than the largest ({MAX_SIZE}×{MAX_SIZE}): lower --texel-density")]
    TooLarge {
        /// The density asked for.
        density: f32,
        /// The side it would need.
        side: u64,
    },
    /// The particles could not be traced, or the bake was cancelled.
    #[error(transparent)]
    Density(#[from] DensityError),
    /// An output that cannot be written.
    #[error(transparent)]
    Write(#[from] ImageIoError),
    /// The second uv set could not be made.
    #[error(transparent)]
    Uv(#[from] UvError),
    /// The lightmapped .glb could not be written.
    #[error(transparent)]
    Glb(#[from] GlbError),
    /// A bake across workers failed (its layout, its network, a peer).
    #[error(transparent)]
    Dataflow(#[from] crate::methods::density::dataflow::DataflowError),
}

/// Figures of a lightmap bake.
#[derive(Clone, Debug, Default)]
pub struct LightmapStats {
    /// Particles traced.
    pub particles: u64,
    /// Hits recorded.
    pub hits: u64,
    /// Rays of the particles.
    pub rays: u64,
    /// Texels estimated.
    pub texels: u64,
    /// Seconds making the uv set (unwrapping, unless the asset has one)
    /// and the texels.
    pub t_uv: f64,
    /// Seconds tracing the particles.
    pub t_trace: f64,
    /// Seconds grouping the hits and building their index.
    pub t_index: f64,
    /// Seconds estimating the texels (the final gather included).
    pub t_estimate: f64,
    /// Rays of the final gather.
    pub gather_rays: u64,
    /// Texels the final gather found hidden (their rays met back faces),
    /// left for the padding to fill.
    pub gather_hidden: u64,
    /// In a bake across workers, each worker's share (empty in one
    /// process).
    pub workers: Vec<LightmapWorker>,
}

/// One worker's share of a lightmap bake across workers
/// ([`super::dataflow`]).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct LightmapWorker {
    /// Texels it owns (estimated, and gathered).
    pub texels: u64,
    /// Texel estimates it made: its texels, and again those whose reach
    /// its halo did not hold yet.
    pub estimates: u64,
    /// Hits of its tiles and surfaces.
    pub hits: u64,
    /// Halo hits it received.
    pub halo: u64,
    /// Rounds of the halo.
    pub rounds: u64,
}

impl LightmapStats {
    /// The most loaded worker's texel estimates over the mean (1 when
    /// even; None in one process).
    pub fn balance(&self) -> Option<f64> {
        let n = self.workers.len() as f64;
        let total: u64 = self.workers.iter().map(|w| w.estimates).sum();
        let max = self.workers.iter().map(|w| w.estimates).max()?;
        Some(if total == 0 {
            1.0
        } else {
            max as f64 * n / total as f64
        })
    }
}

/// A baked lightmap: its uv set and its atlas.
#[derive(Clone, Debug)]
pub struct LightmapBake {
    /// The second uv set the atlas is laid out on.
    pub uv: LightmapUv,
    /// The atlas: irradiance and standard error per texel, padded.
    pub lightmap: Lightmap,
    /// Figures.
    pub stats: LightmapStats,
}

/// The atlas side to plan memory for before the unwrap: `size`, or for a
/// texel density `d` the side of a square holding the scene's surface
/// area at `d`² texels per unit area with the charts filling about 60 %
/// of it (the unwrapper's atlas use measured on the repository's scenes
/// was 68-86 %, see the lightmap-uv notebook page: planning at 60 % errs
/// on the side of refusing). The unwrap refuses past [`MAX_SIZE`].
pub fn atlas_side(scene: &Scene, lm: &LightmapSettings) -> Result<u32, LightmapError> {
    let Some(d) = lm.texel_density else {
        return Ok(lm.size.unwrap_or(DEFAULT_SIZE));
    };
    let area: f64 = (0..scene.triangles.len() as u32)
        .map(|t| {
            let [a, b, c] = scene.tri_vertices(t);
            0.5 * (b - a).cross(c - a).length() as f64
        })
        .sum();
    let side = ((area / 0.6).sqrt() * d as f64).ceil() as u64;
    if side > MAX_SIZE as u64 {
        return Err(LightmapError::TooLarge { density: d, side });
    }
    Ok((side as u32).max(8))
}

/// The mean world area of one texel of `uv`'s atlas: the surface's area over
/// the texels its charts cover (the unit of the estimator's adaptive k).
/// None for an atlas without area.
pub fn texel_area(scene: &Scene, uv: &LightmapUv) -> Option<f32> {
    let (mut world, mut atlas) = (0.0f64, 0.0f64);
    for s in &uv.shapes {
        for t in &s.triangles {
            let p = t.map(|i| scene.positions[s.xref[i as usize] as usize]);
            let q = t.map(|i| s.uv[i as usize]);
            world += 0.5 * (p[1] - p[0]).cross(p[2] - p[0]).length() as f64;
            atlas += 0.5 * (q[1] - q[0]).perp_dot(q[2] - q[0]).abs() as f64;
        }
    }
    let texels = atlas * uv.width as f64 * uv.height as f64;
    (world > 0.0 && texels > 0.0).then(|| (world / texels) as f32)
}

/// Pads the charts: `passes` rings of uncovered texels next to covered ones
/// take their neighbours' mean ([`raster::dilate`]), irradiance and error
/// alike, so that bilinear filtering at a chart's border never reads an
/// empty texel. The texels so filled stay marked uncovered.
pub fn dilate(lm: &mut Lightmap, passes: u32) {
    let (w, h) = (lm.width, lm.height);
    raster::dilate(&mut lm.irradiance, &lm.covered, w, h, passes);
    raster::dilate(&mut lm.std_error, &lm.covered, w, h, passes);
}

/// The limits and the cancel flag a lightmap bake runs under, and who
/// hears its progress.
pub struct Steering<'a> {
    /// When the clock started (the job's start).
    pub start: Instant,
    /// Seconds from `start` the bake may take.
    pub time: Option<f64>,
    /// Rays the bake may trace.
    pub rays: Option<u64>,
    /// The cancel flag.
    pub cancel: Option<&'a AtomicBool>,
    /// Hears each step.
    pub on_tick: &'a mut dyn FnMut(&Tick),
}

impl<'a> Steering<'a> {
    /// No limit and no cancel flag, the clock started now: a bake of all
    /// its particles (tests, examples, references).
    pub fn unlimited(on_tick: &'a mut dyn FnMut(&Tick)) -> Self {
        Steering {
            start: Instant::now(),
            time: None,
            rays: None,
            cancel: None,
            on_tick,
        }
    }
}

/// The stages before the particles: the uv set (the asset's own
/// TEXCOORD_1 when valid, else generated), the texels, and the settings
/// with the estimator's texel area filled in for the adaptive k (the same
/// for the previews and the final estimate).
pub fn prepare(
    scene: &Scene,
    lm: &LightmapSettings,
) -> Result<(LightmapUv, Vec<Texel>, LightmapSettings), LightmapError> {
    let asset_uv1 = (!scene.uv1.is_empty()).then_some(&scene.uv1[..]);
    let opts = UvOptions {
        texel_density: lm.texel_density,
        size: lm
            .texel_density
            .is_none()
            .then(|| lm.size.unwrap_or(DEFAULT_SIZE)),
        fast_packing: lm.fast_packing,
        ..Default::default()
    };
    let uv = uv::lightmap_uv(scene, asset_uv1, &opts)?;
    let texels = raster::texels(scene, &uv);
    let estimator = Options {
        texel_area: lm.estimator.texel_area.or(texel_area(scene, &uv)),
        ..lm.estimator
    };
    let lm = LightmapSettings {
        estimator,
        ..lm.clone()
    };
    Ok((uv, texels, lm))
}

/// Bakes a lightmap of `world`: the uv set, the texels, the particles of
/// `s` (as many as `steer`'s limits allow), the estimate of each texel, the
/// padding. Writes nothing.
pub fn bake_lightmap(
    world: &World,
    s: &density::Settings,
    lm: &LightmapSettings,
    steer: Steering,
) -> Result<LightmapBake, LightmapError> {
    bake_lightmap_watched(world, s, lm, steer, None)
}

/// [`bake_lightmap`], with `watch` (when given) told when the uv set is
/// made and handed previews of the atlas between batches of particles
/// ([`super::live`]); the same particles and atlas as without.
pub fn bake_lightmap_watched(
    world: &World,
    s: &density::Settings,
    lm: &LightmapSettings,
    steer: Steering,
    watch: Option<&mut dyn Watch>,
) -> Result<LightmapBake, LightmapError> {
    lm.check()?;
    s.check().map_err(DensityError::from)?;
    let scene = &world.scene;
    let t = Instant::now();
    let (uv, texels, lm) = prepare(scene, lm)?;
    let (lm, opts) = (&lm, lm.estimator);
    let t_uv = t.elapsed().as_secs_f64();

    let sectors = lm.estimator.sectors.min(estimate::MAX_SECTORS) as u64;
    let limits = Limits {
        time: steer.time,
        rays: steer.rays,
        view_rays: texels.len() as u64 * (sectors + KNN_RAYS + lm.gather.rays_per_texel()),
    };
    let surfaces = surfaces::build(scene);
    let mut sink = SharedHits::default();
    let mut previews = watch.map(|w| {
        let hits = sink.clone();
        Previews::new(w, world, &surfaces, &uv, &texels, s, lm, hits, steer.cancel)
    });
    let user_tick = steer.on_tick;
    let mut on_tick = |t: &Tick| {
        user_tick(t);
        if let Some(p) = &mut previews {
            p.tick(t);
        }
    };
    let mut ctl = Control::new(steer.start, limits, steer.cancel).on_tick(&mut on_tick);
    let mut stats = LightmapStats {
        texels: texels.len() as u64,
        t_uv,
        ..Default::default()
    };

    // The particles, as the density bake traces them
    let t = Instant::now();
    let traced = pipeline::trace_within(world, &surfaces, s, &mut sink, &mut ctl)?;
    stats.particles = traced.particles;
    stats.hits = traced.hits;
    stats.rays = traced.rays;
    stats.t_trace = t.elapsed().as_secs_f64();

    // Grouped and indexed
    let t = Instant::now();
    ctl.tick(Phase::Group, 0, 1);
    let hits = pipeline::group(sink)?;
    let index = HitIndex::build(world, &surfaces, &hits, s.chunk_hits as u64)
        .map_err(DensityError::from)?;
    drop(hits);
    ctl.check()?;
    stats.t_index = t.elapsed().as_secs_f64();

    // Every texel
    let t = Instant::now();
    let est = Estimator::new(world, &surfaces, &index, traced.phi, opts);
    let cancel = ctl.cancel_flag();
    let mut density = {
        let mut progress = |done, total| ctl.tick(Phase::Estimate, done, total);
        let size = (uv.width, uv.height);
        let both = lm.gather.is_on();
        estimate::estimate_density(&est, &texels, size, both, cancel, &mut progress)
    };
    ctl.check()?;
    density.dilate(2);

    // The final gather, reading the density atlas
    let lightmap = if lm.gather.is_on() {
        let gather = gather_with(world, &est, &density, &uv, s, lm);
        let (gathered, rays, hidden) = {
            let mut progress = |done, total| ctl.tick(Phase::Gather, done, total);
            gather::gather_texels(&gather, &texels, &density.held, cancel, &mut progress)
        };
        ctl.check()?;
        stats.gather_rays = rays;
        stats.gather_hidden = hidden;
        combined(gathered, &density.held, &texels, &uv)
    } else {
        density.held
    };
    stats.t_estimate = t.elapsed().as_secs_f64();
    Ok(LightmapBake {
        uv,
        lightmap,
        stats,
    })
}

/// The final gather of a bake, reading the padded density atlases.
pub fn gather_with<'a>(
    world: &'a World,
    est: &'a Estimator<'a>,
    density: &'a DensityAtlas,
    uv: &LightmapUv,
    s: &density::Settings,
    lm: &LightmapSettings,
) -> Gather<'a> {
    let g = GatherOptions {
        seed: s.seed,
        ..lm.gather
    };
    let atlas = Atlas::new(density, uv, &world.scene);
    Gather::new(world, est, atlas, g, s.max_depth)
}

/// The gathered atlas combined with the density estimate
/// ([`gather::combine_with_density`]) and padded: the atlas a bake with a
/// final gather writes.
pub fn combined(
    mut gathered: Lightmap,
    density: &Lightmap,
    texels: &[Texel],
    uv: &LightmapUv,
) -> Lightmap {
    let chart = gather::texel_charts(texels, uv);
    gather::combine_with_density(&mut gathered, density, &chart);
    dilate(&mut gathered, 2);
    gathered
}

/// The atlas's irradiance as an image.
pub fn irradiance_image(lm: &Lightmap) -> Image {
    Image {
        width: lm.width,
        height: lm.height,
        data: lm.irradiance.clone(),
    }
}

/// The atlas's standard errors as an image.
pub fn error_image(lm: &Lightmap) -> Image {
    Image {
        width: lm.width,
        height: lm.height,
        data: lm.std_error.clone(),
    }
}

/// Writes the atlas and the error map where `lm` asks (atomically, EXR).
pub fn write_images(bake: &LightmapBake, lm: &LightmapSettings) -> Result<(), LightmapError> {
    let opts = PngOptions::default();
    if let Some(p) = &lm.atlas {
        image_io::write_image(p, &irradiance_image(&bake.lightmap), &opts)?;
    }
    if let Some(p) = &lm.error {
        image_io::write_image(p, &error_image(&bake.lightmap), &opts)?;
    }
    Ok(())
}
