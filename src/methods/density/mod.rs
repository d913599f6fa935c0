//! `density`: global illumination by density estimation (Shirley, Wade,
//! Hubbard, Zareski, Walter and Greenberg 1995), the view-independent
//! method, and the baker behind `kalos bake`.
//!
//! Three phases, each parallel and deterministic per seed, run in order by
//! [`bake`], one function each in [`pipeline`]:
//! 1. [`particles`]: particle tracing into a hit store ([`hits`]: 12 bytes a
//!    hit; the [`hitfile`] on disk, in a self-removing [`scratch`]
//!    directory, or memory), grouped by surface side ([`surfaces::SurfaceId`]);
//! 2. [`kernel`]: per surface ([`surfaces`]), the irradiance H(u, v) by
//!    kernel density estimation, sampled on an over-mesh;
//! 3. [`decimate`]: Schroeder-style vertex decimation of the illumination
//!    mesh in (u, v, brightness) space, with a priority queue and the
//!    height-field check.
//!
//! [`dataflow`] runs the same phases as a timely dataflow across worker
//! threads or processes (`kalos bake --workers N`), with the same bytes out.
//!
//! The image is the paper's view-dependent second pass: a camera ray that
//! meets a diffuse surface reads L = R·H/π from the display mesh ([`mesh`]);
//! mirrors, glass and the non-diffuse part of other surfaces (a glossy lobe,
//! a plastic's coat) are ray-traced onward by sampling their BSDF (see
//! [`view_radiance`]).
//!
//! Non-Lambertian surfaces. §1 of the paper: "all diffuse surfaces will be
//! portrayed accurately regardless of display method ... Non-diffuse
//! surfaces ... accurately if displayed in a view-dependent second pass".
//! A material with a diffuse part (`phong`'s kd, the base of `plastic` and
//! `roughplastic`: [`crate::bsdf::DiffusePart`]) records hits and gets a
//! display mesh of Ĥ; its vertex colours carry R_d·Ĥ/π. What remains an
//! approximation: for the coated models the baked colour uses the coat's
//! mean transmittance T̄ in place of T(cos θo) (the view pass uses the exact
//! one), and a purely glossy material (`roughconductor`, `phong` with
//! kd = 0) has no view-independent part at all: it is ray-traced only.
//!
//! The [`Density`] method bakes in [`Method::prepare_within`], inside the
//! driver's clock with the particle rays counted (a failed bake is the
//! render's error); every step then adds one jittered sample per pixel of
//! the view pass. The budget ([`control`]): `--time` and `--rays` stop the
//! tracing between batches of particles when the rest of the bake and one
//! view pass would not fit, and the estimate is made from the particles
//! traced; `--spp` counts view passes (what a sample per pixel is for the
//! camera), so a spp budget bakes every particle of `--particles`. The
//! cancel flag stops the bake between units of work.
//!
//! Colour: one RGB pass. Every particle carries RGB power (its luminaire's
//! colour, tinted by every reflection), so the three channels of the estimate
//! are made from the same hits and their noise is correlated: no "visible
//! coloured texture" (§4.4), which the paper's per-channel runs show because
//! each channel's hits are independent. `Channel::Single` keeps the paper's
//! per-channel runs for the measurement in docs/notebook/density.md. The price
//! is 4 more bytes per hit (RGB9E5 power: 12 bytes instead of 8), against
//! three runs of 8 bytes (24 bytes for the same particles per channel).
//!
//! Bias. Kernel density estimation blurs the irradiance over the kernel's
//! width (the boundary correction of [`kernel`] removes only the first
//! order of the loss at a surface's edges), and the display mesh's
//! decimation smooths it further, so the image is biased: light is moved
//! from where it is concentrated to where it is not. The bias falls as
//! more particles narrow the kernel but does not average out over view
//! passes. Measured against the
//! Mitsuba 3 reference of two-rooms-baffle (image mean, default settings;
//! issue #38): about 1.8 % dark. Other scenes' figures, with their
//! commands, are in docs/notebook/density.md. A user who needs the
//! unbiased image should use `path`, `light` or `plb`.
//!
//! ```text
//! kalos render scenes/cbox/cbox.xml --method density --particles 4M --spp 16 -o d.exr
//! kalos bake scenes/cbox/cbox.xml -o cbox.glb --stats
//! ```

pub mod baked;
pub mod control;
pub mod dataflow;
pub mod decimate;
pub mod hitfile;
pub mod hits;
pub mod kernel;
pub mod mesh;
pub mod particles;
pub mod pipeline;
pub mod scratch;
pub mod surfaces;

use std::f32::consts::PI;
use std::path::PathBuf;
use std::time::Instant;

use rayon::prelude::*;

use super::{
    film_item, no_exact_merge, Common, Method, MethodError, MethodSettings, Setup, StepStats,
    World, FILM, IMAGE,
};
use crate::bsdf::{Bsdf, Mode};
use crate::film::{Film, Image};
use crate::geometry::{offset_point, Ray};
use crate::memory::MemoryItem;
use crate::sampling::Pcg32;
use crate::scene::Rgb;
use crate::state::{ShardKind, State};
use crate::transport::orient;
use control::{Control, Phase};
use hitfile::HitFileError;
use hits::{HitSink, HitSource, MemoryWriter, HIT_BYTES};
use mesh::DisplayMesh;
use scratch::ScratchDir;
use surfaces::Surfaces;

pub use baked::BakedMesh;

/// Settings of the density method (defaults inside the paper's ranges).
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields)]
#[cfg_attr(feature = "cli", derive(clap::Args))]
pub struct Settings {
    /// Master seed (set from [`super::Common`]).
    #[cfg_attr(feature = "cli", arg(skip))]
    pub seed: u64,
    /// Longest path in segments, as for every method (set from
    /// [`super::Common`]); None = unlimited.
    #[cfg_attr(feature = "cli", arg(skip))]
    pub max_depth: Option<u32>,
    /// Particles n traced (per channel run with `per_channel`); accepts 4M.
    /// The most the bake traces: --time and --rays stop it sooner, leaving
    /// room for the estimate and a view pass. --spp counts the samples per
    /// pixel of the view pass after the bake (its camera rays), not
    /// particles, so --spp alone traces all n.
    #[cfg_attr(feature = "cli", arg(long, default_value = "4M", value_parser = super::cli::parse_count))]
    pub particles: u64,
    /// Kernel width factor C1 of h = C1·√(A/n); the paper found 10–40 useful.
    #[cfg_attr(feature = "cli", arg(long, default_value_t = 20.0))]
    pub c1: f32,
    /// Grid spacing factor C2 of the over-mesh; the paper: C1/10 to C1/2.
    #[cfg_attr(feature = "cli", arg(long, default_value_t = 8.0))]
    pub c2: f32,
    /// Error bound ε of the decimation, in Stevens brightness units.
    #[cfg_attr(feature = "cli", arg(long, default_value_t = 0.01))]
    pub epsilon: f32,
    /// Whether phase 3 decimates the over-mesh (the default); false keeps
    /// the over-mesh as the display mesh. On the command line, the switch
    /// `--no-decimate` sets it to false.
    #[cfg_attr(feature = "cli", arg(long = "no-decimate", action = clap::ArgAction::SetFalse,
        help = "Keep the over-mesh as the display mesh: skip decimation (phase 3)"))]
    pub decimate: bool,
    /// One RGB particle pass (rgb), or the paper's three per-channel runs
    /// (per-channel).
    #[cfg_attr(feature = "cli", arg(long = "variant", value_name = "rgb|per-channel", default_value = "rgb", value_parser = channels, action = clap::ArgAction::Set))]
    pub per_channel: bool,
    /// Cap on over-mesh vertices per surface.
    #[cfg_attr(feature = "cli", arg(long, default_value_t = 1 << 20, value_parser = super::cli::parse_usize))]
    pub max_verts: usize,
    /// An existing directory in which a fresh scratch directory for the hit
    /// file is made and removed after the bake (default: the system's
    /// temporary directory).
    #[cfg_attr(feature = "cli", arg(long))]
    pub scratch: Option<PathBuf>,
    /// Keep the hit file at this path instead of deleting it.
    #[cfg_attr(feature = "cli", arg(long = "hits"))]
    pub keep_hits: Option<PathBuf>,
    /// Most hit records held in memory at once, in phase 2 (a surface with
    /// more hits is streamed in chunks of this size) and in the bucket sort
    /// of phase 1; accepts 2M.
    #[cfg_attr(feature = "cli", arg(long, default_value_t = 1 << 21, value_parser = super::cli::parse_usize))]
    pub chunk_hits: usize,
}

/// Parses `--variant`: true for the paper's per-channel runs.
#[cfg(feature = "cli")]
fn channels(s: &str) -> Result<bool, String> {
    match s {
        "rgb" => Ok(false),
        "per-channel" => Ok(true),
        _ => Err(format!("expected rgb or per-channel, got '{s}'")),
    }
}

impl Default for Settings {
    fn default() -> Self {
        Settings {
            seed: 0,
            max_depth: None,
            particles: 4_000_000,
            c1: 20.0,
            c2: 8.0,
            epsilon: 0.01,
            decimate: true,
            per_channel: false,
            max_verts: 1 << 20,
            scratch: None,
            keep_hits: None,
            chunk_hits: 1 << 21,
        }
    }
}

impl MethodSettings for Settings {
    fn validate(&self) -> Result<(), MethodError> {
        Settings::validate(self)
    }

    /// Refused (see [`crate::partial`]): the kernel's width follows the
    /// particle count of one shard.
    fn shard_kind(&self) -> Result<ShardKind, MethodError> {
        Err(MethodError(
            "method 'density' cannot be split into shards: averaging N particle sets keeps \
             the kernel blur of one set, so it would not converge to the image of N times \
             the particles; raise --particles instead"
                .into(),
        ))
    }

    fn check_shard_count(&self, _count: u32) -> Result<(), MethodError> {
        Ok(())
    }

    fn resumable(&self) -> Result<(), &'static str> {
        Err("its bake (hit file, display mesh) is not saved")
    }

    fn merge_exact(&self, _: &[&State], _: u32, _: u32) -> Result<Image, MethodError> {
        Err(no_exact_merge("density"))
    }

    /// The film and the image, and a chunk of records read from the hit
    /// file with its decoding.
    fn memory(&self, width: u32, height: u32) -> Vec<MemoryItem> {
        let per_hit = (HIT_BYTES + std::mem::size_of::<hits::Hit>()) as u64;
        vec![
            film_item(width, height, FILM + IMAGE, ""),
            MemoryItem {
                what: format!("density's hit chunk ({} hits)", self.chunk_hits),
                bytes: (self.chunk_hits as u64).saturating_mul(per_hit),
                remedy: "lower --chunk-hits",
            },
        ]
    }

    fn create(&self, world: &World, common: &Common) -> Box<dyn Method> {
        Box::new(Density::new(
            world,
            Settings {
                seed: common.seed,
                max_depth: common.max_depth,
                ..self.clone()
            },
        ))
    }
}

impl Settings {
    /// Rejects settings that cannot work.
    pub fn validate(&self) -> Result<(), MethodError> {
        self.check()
    }

    /// Rejects settings that cannot work.
    pub fn check(&self) -> Result<(), MethodError> {
        if !(self.c1.is_finite() && self.c1 > 0.0) {
            return Err(MethodError(format!(
                "--c1 must be positive, got {}",
                self.c1
            )));
        }
        if !(self.c2.is_finite() && self.c2 > 0.0) {
            return Err(MethodError(format!(
                "--c2 must be positive, got {}",
                self.c2
            )));
        }
        if !(self.epsilon.is_finite() && self.epsilon >= 0.0) {
            return Err(MethodError(format!(
                "--epsilon must be ≥ 0, got {}",
                self.epsilon
            )));
        }
        if self.particles == 0 {
            return Err(MethodError("--particles must be positive".into()));
        }
        if self.chunk_hits == 0 {
            return Err(MethodError("the hit chunk size must be positive".into()));
        }
        Ok(())
    }
}

/// Figures of a bake.
#[derive(Clone, Debug, Default)]
pub struct BakeStats {
    /// Particles emitted (all channel runs).
    pub particles: u64,
    /// Hits recorded.
    pub hits: u64,
    /// Bytes per hit record.
    pub bytes_per_hit: usize,
    /// Size of the hit file's records.
    pub hit_file_bytes: u64,
    /// Rays traced by the particles.
    pub rays: u64,
    /// Seconds in phase 1 (tracing, including the bucket sort).
    pub t_trace: f64,
    /// Seconds in phase 2 (density estimation and over-meshing).
    pub t_estimate: f64,
    /// Seconds in phase 3 (decimation).
    pub t_decimate: f64,
    /// Display triangles before decimation.
    pub tris_before: u64,
    /// Display triangles after decimation.
    pub tris_after: u64,
    /// Largest brightness error the decimation caused, measured at every
    /// removed vertex (Stevens units, ≤ ε).
    pub max_brightness_error: f32,
    /// Mean brightness error over removed vertices.
    pub mean_brightness_error: f32,
    /// Number of receiving surfaces (planar groups and curved triangles).
    pub surfaces: usize,
    /// Largest number of hit records held in memory at once in phase 2
    /// (bounded by `Settings::chunk_hits`, whatever the particle count).
    pub max_hits_in_memory: u64,
    /// Largest number of hit records the bucket sort of phase 1 held at once.
    pub max_sort_records: u64,
    /// A dataflow bake's estimate work, worker by worker (empty in one
    /// process).
    pub workers: Vec<WorkerLoad>,
}

/// One dataflow worker's estimate work in phase 2.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct WorkerLoad {
    /// Hit records it estimated from: its surfaces' and tiles' hits and
    /// the halo it received.
    pub hits: u64,
    /// Over-mesh vertices it estimated (all of its surfaces', those of its
    /// tiles, three per triangle of its curved shapes).
    pub verts: u64,
    /// Of `hits`, those of the halo: hits of other workers' tiles within a
    /// kernel width of its own.
    pub halo: u64,
}

impl WorkerLoad {
    /// The work: hits plus vertices.
    pub fn work(&self) -> u64 {
        self.hits + self.verts
    }
}

impl BakeStats {
    /// The most loaded worker's estimate work over the mean (1 when even;
    /// None in one process).
    pub fn balance(&self) -> Option<f64> {
        let n = self.workers.len();
        let total: u64 = self.workers.iter().map(WorkerLoad::work).sum();
        let max = self.workers.iter().map(WorkerLoad::work).max()?;
        if total == 0 {
            return Some(1.0);
        }
        Some(max as f64 * n as f64 / total as f64)
    }
}

impl std::fmt::Display for BakeStats {
    /// The figures of `kalos bake --stats`, one per line.
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let total = self.t_trace + self.t_estimate + self.t_decimate;
        let pct = |t: f64| if total > 0.0 { 100.0 * t / total } else { 0.0 };
        writeln!(f, "particles        {}", self.particles)?;
        writeln!(f, "hits             {}", self.hits)?;
        writeln!(f, "bytes per hit    {}", self.bytes_per_hit)?;
        writeln!(
            f,
            "hit file         {:.1} MB",
            self.hit_file_bytes as f64 / 1e6
        )?;
        writeln!(f, "surfaces         {}", self.surfaces)?;
        for (name, t) in [
            ("phase 1 trace   ", self.t_trace),
            ("phase 2 estimate", self.t_estimate),
            ("phase 3 decimate", self.t_decimate),
        ] {
            writeln!(f, "{name} {t:.2} s ({:.0}%)", pct(t))?;
        }
        writeln!(f, "triangles before {}", self.tris_before)?;
        let removed = if self.tris_before > 0 {
            100.0 * (1.0 - self.tris_after as f64 / self.tris_before as f64)
        } else {
            0.0
        };
        writeln!(
            f,
            "triangles after  {} ({removed:.1}% removed)",
            self.tris_after
        )?;
        writeln!(
            f,
            "brightness error max {:.4}, mean {:.4}",
            self.max_brightness_error, self.mean_brightness_error
        )?;
        write!(
            f,
            "hits in memory   {} at most in phase 2, {} in the bucket sort",
            self.max_hits_in_memory, self.max_sort_records
        )?;
        if let Some(b) = self.balance() {
            write!(
                f,
                "\nbalance: {b:.3} (the most loaded worker's estimate work over the mean; \
                 work = hits + over-mesh vertices)"
            )?;
            for (i, w) in self.workers.iter().enumerate() {
                write!(
                    f,
                    "\n  worker {i:<3} {} hits (halo {}) + {} vertices = {}",
                    w.hits,
                    w.halo,
                    w.verts,
                    w.work()
                )?;
            }
        }
        Ok(())
    }
}

/// The result of a bake: surfaces, display mesh, figures.
#[derive(Clone, Debug)]
pub struct Bake {
    /// The receiving surfaces.
    pub surfaces: Surfaces,
    /// The display mesh (decimated unless disabled).
    pub mesh: DisplayMesh,
    /// White point w0 of the brightness axis (radiance, luminance).
    pub w0: f32,
    /// Figures.
    pub stats: BakeStats,
}

/// An error while baking.
#[derive(Debug, thiserror::Error)]
pub enum DensityError {
    /// The scratch directory could not be made in `base`.
    #[error("cannot create a scratch directory in {}", base.display())]
    Scratch {
        /// The directory it was to be made in.
        base: PathBuf,
        /// Why not.
        #[source]
        source: std::io::Error,
    },
    /// Hit-file I/O.
    #[error(transparent)]
    HitFile(#[from] HitFileError),
    /// Bad settings.
    #[error(transparent)]
    Settings(#[from] MethodError),
    /// The cancel flag was set ([`control::Control`]); nothing is kept.
    #[error("the bake was cancelled")]
    Cancelled {
        /// Rays traced before it stopped.
        rays: u64,
    },
}

/// Where the hits wait between phase 1 and phase 2.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum Storage {
    /// The hit file of §4.1 in a [`ScratchDir`]: memory stays bounded
    /// whatever the particle count ([`Settings::chunk_hits`]).
    #[default]
    Disk,
    /// Every hit in memory ([`hits::MemoryWriter`]), no files: for tests and
    /// small runs. The bake is the same, byte for byte.
    Memory,
}

/// Bakes with the hit file on disk: [`bake_with`] and [`Storage::Disk`].
pub fn bake(world: &World, s: &Settings) -> Result<Bake, DensityError> {
    bake_with(world, s, Storage::Disk)
}

/// Runs the phases of [`pipeline`] in order: trace and group the hits,
/// estimate the irradiance, decimate the over-mesh into the display mesh.
pub fn bake_with(world: &World, s: &Settings, storage: Storage) -> Result<Bake, DensityError> {
    bake_within(world, s, storage, &mut Control::none())
}

/// [`bake_with`] steered by `ctl`: tracing within its limits, progress by
/// phase, and [`DensityError::Cancelled`] soon after its cancel flag is
/// set. Whatever way it returns or unwinds, the scratch directory is gone.
pub fn bake_within(
    world: &World,
    s: &Settings,
    storage: Storage,
    ctl: &mut Control,
) -> Result<Bake, DensityError> {
    s.check()?;
    let scene = &world.scene;
    let surfaces = surfaces::build(scene);
    let mut stats = BakeStats {
        bytes_per_hit: HIT_BYTES,
        surfaces: surfaces.list.len(),
        ..Default::default()
    };

    // Phases 1 and 2, the hits in the store asked for; the scratch
    // directory goes as soon as the estimate is made, or on any error
    let estimated = match storage {
        Storage::Disk => {
            let scratch = ScratchDir::new(s)?;
            let sink = pipeline::file_sink(&surfaces, s, &scratch)?;
            trace_and_estimate(world, &surfaces, s, sink, &mut stats, ctl)?
        }
        Storage::Memory => {
            if let Some(p) = &s.keep_hits {
                return Err(MethodError(format!(
                    "cannot keep the hits at {}: the in-memory store writes no hit file",
                    p.display()
                ))
                .into());
            }
            trace_and_estimate(world, &surfaces, s, MemoryWriter::new(), &mut stats, ctl)?
        }
    };
    let pipeline::Estimated { planar, curved, .. } = estimated;
    stats.tris_before = planar.iter().map(|m| m.tris.len() as u64).sum::<u64>()
        + curved.iter().map(|m| m.tris.len() as u64).sum::<u64>();

    // Phase 3: decimation against the white point
    let w0 = pipeline::white_point(scene, &surfaces, &planar);
    let t = Instant::now();
    let planar = if s.decimate {
        let (planar, d) = pipeline::decimate_within(scene, &surfaces, planar, w0, s.epsilon, ctl)?;
        stats.max_brightness_error = d.max_error;
        stats.mean_brightness_error = d.mean_error;
        planar
    } else {
        planar
    };
    stats.t_decimate = t.elapsed().as_secs_f64();
    let mesh = DisplayMesh::new(planar, curved);
    stats.tris_after = mesh.triangle_count();
    Ok(Bake {
        surfaces,
        mesh,
        w0,
        stats,
    })
}

/// Phases 1 and 2 through `sink`, timed into `stats`.
fn trace_and_estimate<S: HitSink>(
    world: &World,
    surfaces: &Surfaces,
    s: &Settings,
    mut sink: S,
    stats: &mut BakeStats,
    ctl: &mut Control,
) -> Result<pipeline::Estimated, DensityError> {
    // Phase 1: particle tracing, then the grouping by surface
    let t = Instant::now();
    let traced = pipeline::trace_within(world, surfaces, s, &mut sink, ctl)?;
    ctl.tick(Phase::Group, 0, 1);
    let hits = pipeline::group(sink)?;
    ctl.check()?;
    stats.particles = traced.particles;
    stats.hits = traced.hits;
    stats.rays = traced.rays;
    stats.hit_file_bytes = hits.hit_count() * HIT_BYTES as u64;
    stats.max_sort_records = hits.max_sort_records();
    stats.t_trace = t.elapsed().as_secs_f64();

    // Phase 2: density estimation, streamed from the store
    let t = Instant::now();
    let estimated = pipeline::estimate_within(&world.scene, surfaces, s, &hits, traced.phi, ctl)?;
    stats.max_hits_in_memory = estimated.max_hits_in_memory;
    stats.t_estimate = t.elapsed().as_secs_f64();
    Ok(estimated)
}

/// The density method's progressive state: the bake, made once by
/// [`Method::prepare`], then one jittered sample per pixel of the view pass
/// per step.
pub struct Density {
    settings: Settings,
    storage: Storage,
    bake: Option<Bake>,
    film: Film,
    passes: u64,
}

impl Density {
    /// A density method for `world`, with the hit file on disk. Cheap: the
    /// particles are traced by [`Method::prepare`].
    pub fn new(world: &World, settings: Settings) -> Self {
        Density {
            settings,
            storage: Storage::Disk,
            bake: None,
            film: Film::new(world.camera.width, world.camera.height),
            passes: 0,
        }
    }

    /// The same method with the hits kept in `storage`.
    pub fn with_storage(mut self, storage: Storage) -> Self {
        self.storage = storage;
        self
    }

    /// The bake, once prepared.
    pub fn bake(&self) -> Option<&Bake> {
        self.bake.as_ref()
    }
}

/// `e` and its sources, joined by ": ", as one line.
pub(crate) fn error_chain(e: &dyn std::error::Error) -> String {
    let mut line = e.to_string();
    let mut source = e.source();
    while let Some(s) = source {
        line.push_str(": ");
        line.push_str(&s.to_string());
        source = s.source();
    }
    line
}

impl Density {
    /// The bake steered by `ctl`; a cancelled bake leaves no bake and
    /// counts the rays it traced.
    fn bake_steered(&mut self, world: &World, ctl: &mut Control) -> Result<StepStats, MethodError> {
        match bake_within(world, &self.settings, self.storage, ctl) {
            Ok(b) => {
                let rays = b.stats.rays;
                self.bake = Some(b);
                Ok(StepStats { rays })
            }
            Err(DensityError::Cancelled { rays }) => Ok(StepStats { rays }),
            Err(e) => Err(MethodError(format!("density bake: {}", error_chain(&e)))),
        }
    }

    /// One view pass, pass index `pass`, added to `film`; returns its rays.
    fn view_pass(&self, world: &World, bk: &Bake, film: &mut Film, pass: u64) -> u64 {
        let w = world.camera.width as usize;
        let seed = self.settings.seed;
        film.sum
            .par_chunks_mut(w)
            .enumerate()
            .map(|(y, row)| {
                let mut r = 0;
                for (x, acc) in row.iter_mut().enumerate() {
                    let pixel = (y * w + x) as u64;
                    let mut rng = Pcg32::keyed(&[seed, pass, pixel, 0xDE]);
                    let j = rng.next_2d();
                    let ray = world.camera.ray(x as f32 + j.x, y as f32 + j.y);
                    let (l, n) = view_radiance(world, bk, ray, &mut rng);
                    r += n;
                    if l.is_finite() {
                        *acc += l.as_dvec3();
                    }
                }
                r
            })
            .sum::<u64>()
    }
}

/// The rays a view pass is expected to trace: a camera ray per pixel, and
/// as many again for the specular surfaces it follows.
fn view_pass_rays(world: &World) -> u64 {
    2 * world.camera.width as u64 * world.camera.height as u64
}

impl Method for Density {
    fn name(&self) -> &'static str {
        "density"
    }

    /// The bake: its particle rays are the rays of the setup, and a failed
    /// bake (an unwritable scratch directory, a full disk) is the render's
    /// error, with its reason.
    fn prepare(&mut self, world: &World) -> Result<StepStats, MethodError> {
        self.bake_steered(world, &mut Control::none())
    }

    /// The bake within the render's budget: the particles are traced in
    /// batches while the time and ray limits leave room for phases 2 and 3
    /// and one view pass (at most `--particles`), the bake's phases are
    /// shown, and the cancel flag stops it between batches (the image is
    /// then black: nothing was estimated).
    fn prepare_within(
        &mut self,
        world: &World,
        setup: &mut Setup<'_>,
    ) -> Result<StepStats, MethodError> {
        let budget = setup.budget;
        let limits = control::Limits {
            time: budget.time,
            rays: budget.rays,
            view_rays: view_pass_rays(world),
        };
        // The view passes a spp or pass budget asks for, to guess how much
        // of the render the bake is
        let passes = match (budget.spp, budget.passes) {
            (Some(a), Some(b)) => a.min(b as f64),
            (Some(a), None) => a,
            (None, Some(b)) => b as f64,
            (None, None) => 0.0,
        };
        let (cancel, start) = (setup.cancel, setup.start);
        let mut on_tick = |t: &control::Tick| {
            let f = t.bake_fraction();
            // seconds for the whole bake, and for the passes at the rate of
            // phase 1's rays
            let bake_s = t.elapsed / f.max(1e-3);
            let view_s = passes * limits.view_rays as f64 * t.elapsed / t.rays.max(1) as f64;
            // (without a spp or pass budget the driver's own time and
            // ray fractions are the progress)
            let whole = if t.rays > 0 && passes > 0.0 {
                t.elapsed / (bake_s + view_s)
            } else {
                0.0
            };
            setup.report(t.rays, whole, t.phase.name());
        };
        let mut ctl = Control::new(start, limits, cancel).on_tick(&mut on_tick);
        self.bake_steered(world, &mut ctl)
    }

    fn step(&mut self, world: &World, pass: u64) -> StepStats {
        let Some(bk) = &self.bake else {
            // cancelled during the bake: nothing to show, but the pass
            // counts, so that a budget of passes still ends
            self.passes += 1;
            return StepStats::default();
        };
        let mut film = std::mem::replace(&mut self.film, Film::new(0, 0));
        let rays = self.view_pass(world, bk, &mut film, pass);
        self.film = film;
        self.passes += 1;
        StepStats { rays }
    }

    /// The mean of the view passes; when the budget ended with the bake,
    /// before any pass, one pass made here (pass 0, as the first step's).
    fn image(&self, world: &World) -> Image {
        match &self.bake {
            Some(bk) if self.passes == 0 => {
                let mut film = Film::new(world.camera.width, world.camera.height);
                self.view_pass(world, bk, &mut film, 0);
                film.mean(1)
            }
            _ => self.film.mean(self.passes),
        }
    }

    /// The bake's particles and phase times.
    fn report(&self) -> Option<String> {
        let st = &self.bake.as_ref()?.stats;
        let runs = if self.settings.per_channel { 3 } else { 1 };
        Some(format!(
            "density bake: {} of {} particles, {} hits; trace {:.2} s, estimate {:.2} s, \
             decimate {:.2} s ({} of {} triangles kept)",
            st.particles,
            self.settings.particles * runs,
            st.hits,
            st.t_trace,
            st.t_estimate,
            st.t_decimate,
            st.tris_after,
            st.tris_before
        ))
    }

    fn spp(&self) -> f64 {
        self.passes as f64
    }
}

/// The view-dependent second pass along one camera ray: emitted radiance,
/// plus at every surface with a diffuse part its diffuse radiance read from
/// the display mesh (R·H/π for a Lambertian surface, k T(cos θo) Ĥ for the
/// others: [`crate::bsdf::DiffusePart`]); the rest of the BSDF (mirrors,
/// glass, glossy lobes, coats) is followed by sampling the BSDF and
/// weighting by (f − f_d) cos θ / pdf, which is unbiased for the
/// non-diffuse integral ∫ (f − f_d) L cos dω (the mixture pdf covers every
/// lobe). A Lambertian surface ends the path.
pub fn view_radiance(world: &World, bk: &Bake, mut ray: Ray, rng: &mut Pcg32) -> (Rgb, u64) {
    let scene = &world.scene;
    let mut l = Rgb::ZERO;
    let mut beta = Rgb::ONE;
    let mut rays = 0;
    for depth in 0..64 {
        rays += 1;
        let Some(hit) = world.accel.intersect(&ray) else {
            l += beta * world.lights.le_env(ray.d);
            break;
        };
        let sp = scene.surface_point(hit.tri, hit.b1, hit.b2);
        let wo_world = -ray.d;
        if world.lights.is_emitter(hit.tri) {
            l += beta * world.lights.le_tri(hit.tri, sp.frame.n, wo_world);
        }
        let sid = bk.surfaces.tri_surface[hit.tri as usize];
        let surf = &bk.surfaces.list[sid as usize];
        let material = scene.material_of(&sp);
        let bsdf = material.bsdf(sp.uv);
        let (frame, ng) = orient(sp.frame, sp.ng, wo_world, material.is_two_sided());
        let wo = frame.to_local(wo_world);
        let mut diffuse = None;
        if surf.diffuse {
            let back = wo_world.dot(sp.ng) < 0.0;
            if back && !material.is_two_sided() {
                break;
            }
            let h = bk
                .mesh
                .irradiance(&bk.surfaces, hit.tri, hit.b1, hit.b2, sp.p, back);
            if let Bsdf::Diffuse { r } = bsdf {
                l += beta * r * h / PI;
                break;
            }
            if let Some(d) = bsdf.diffuse_part() {
                if wo.z > 0.0 {
                    l += beta * d.k * d.t(wo.z) * h;
                }
                diffuse = Some(d);
            }
        }
        // The non-diffuse rest of the BSDF: follow it
        let Some(s) = bsdf.sample(wo, rng.next_f32(), rng.next_2d(), Mode::Radiance) else {
            break;
        };
        let wi = frame.to_world(s.wi);
        if wi.dot(ng) * s.wi.z <= 0.0 || s.pdf <= 0.0 {
            break;
        }
        let f = match diffuse {
            Some(d) if !s.delta => {
                // f − f_d, with the rounding of the two forms of f_d (about
                // 1e-7 of it) taken as zero
                let fd = d.f(wo, s.wi);
                let rest = s.f - fd;
                if rest.max_element() <= 1e-6 * fd.max_element() {
                    Rgb::ZERO
                } else {
                    rest.max(Rgb::ZERO)
                }
            }
            _ => s.f,
        };
        beta *= f * (s.wi.z.abs() / s.pdf);
        if depth > 3 {
            let q = beta.max_element().min(0.95);
            if rng.next_f32() >= q {
                break;
            }
            beta /= q;
        }
        if !beta.is_finite() || beta == Rgb::ZERO {
            break;
        }
        ray = Ray::new(offset_point(sp.p, sp.ng, wi), wi);
    }
    (l, rays)
}
