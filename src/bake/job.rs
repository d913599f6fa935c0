//! The whole sequence of a density bake, owned by the library as
//! [`crate::job::RenderJob`] owns a render's ([`BakeJob`]): check the
//! outputs, the settings and the memory before any work, load the scene,
//! build the world, bake (in this process, or on a timely dataflow of
//! threads or processes), write the display mesh atomically. The command
//! line (`kalos bake`) and the Python package (`kalos.bake`) only translate
//! their arguments and show progress.
//!
//! With [`BakeJob::lightmap`] set, the job bakes a lightmap instead of the
//! display mesh ([`crate::bake::lightmap::bake`]): the same particles, the
//! irradiance estimated at every texel of an atlas, written as EXR images
//! (the atlas and its standard errors).

use std::cell::RefCell;
use std::path::{Path, PathBuf};
use std::sync::atomic::AtomicBool;
use std::sync::Arc;
use std::time::Instant;

use crate::bake::lightmap::bake::{
    self as lightmap, LightmapBake, LightmapError, LightmapSettings,
};
use crate::bake::lightmap::dataflow as lm_dataflow;
use crate::bake::lightmap::glb as lightmap_glb;
use crate::bake::lightmap::live::{Cadence, Watch};
use crate::bake::lightmap::{Lightmap, LightmapUv};
use crate::bake::{gltf, ply, BakedMesh};
use crate::color::Rgb;
use crate::image_io::ImageIoError;
use crate::job::{self, SceneInput, SetupEvent};
use crate::memory::MemoryItem;
use crate::methods::density::control::{Control, Limits, Phase, Tick};
use crate::methods::density::dataflow::{self, DataflowError, Workers};
use crate::methods::density::hits::Hit;
use crate::methods::density::{self, DensityError, Storage};
use crate::methods::{MethodConfig, MethodError};
use crate::outputs::{self, OutputError};
use crate::render::{self, MemoryError};
use crate::scene::SceneError;
use crate::scene::{ReadPolicy, Scene};
use crate::world::World;

/// A bake from start to finish: what to bake, how, and what to write. Its
/// fields are plain settings; [`BakeJob::check`] checks them and the files
/// before any work, [`CheckedBake::run`] does the work.
pub struct BakeJob {
    /// The scene.
    pub scene: SceneInput,
    /// The density method's settings, seed and longest path included.
    pub settings: density::Settings,
    /// The display mesh to write (.glb); None writes none.
    pub glb: Option<PathBuf>,
    /// The irradiance mesh to write (.ply); None writes none.
    pub ply: Option<PathBuf>,
    /// Size the thread pool ([`job::set_threads`]) before loading.
    pub threads: Option<usize>,
    /// The most memory the bake may plan to use ([`job::memory_limit`]);
    /// None: the machine's memory.
    pub max_memory: Option<u64>,
    /// The name of [`BakeJob::max_memory`] in the front end, which the
    /// error names ("--max-memory").
    pub max_memory_flag: &'static str,
    /// Bake a lightmap instead of the display mesh (the .glb is not
    /// written: its writer is another stage); None: the display mesh.
    pub lightmap: Option<LightmapSettings>,
    /// Seconds the bake may take from the start of [`CheckedBake::run`]
    /// (loading included): the particles stop between batches when the
    /// rest would not fit. None: every particle.
    pub time: Option<f64>,
    /// Rays the bake may trace (the particles', and for a lightmap the
    /// texels' visibility rays). None: every particle.
    pub rays: Option<u64>,
    /// A lightmap bake watched live: the asset as [`BakeEvent::Asset`]
    /// before any particle, then a preview of the atlas
    /// ([`BakeEvent::Preview`]) at most every this many seconds of
    /// tracing, on [`Cadence`]'s schedule. None: no previews.
    pub watch_every: Option<f64>,
}

impl BakeJob {
    /// A bake of `scene` with `settings`: nothing written, no limit but
    /// the machine's memory.
    pub fn new(scene: SceneInput, settings: density::Settings) -> Self {
        BakeJob {
            scene,
            settings,
            glb: None,
            ply: None,
            threads: None,
            max_memory: None,
            max_memory_flag: "--max-memory",
            lightmap: None,
            time: None,
            rays: None,
            watch_every: None,
        }
    }

    /// Checks, before any work, the files to write (format, folder,
    /// permissions), the settings and the bake's own buffers against the
    /// memory limit.
    pub fn check(self) -> Result<CheckedBake, BakeError> {
        if let Some(p) = &self.glb {
            outputs::check_output(p, &["glb"])?;
        }
        if let Some(p) = &self.ply {
            outputs::check_output(p, &["ply"])?;
        }
        self.settings.validate()?;
        if self.settings.max_depth == Some(0) {
            return Err(BakeError::MaxDepth);
        }
        if let Some(t) = self.time {
            if !(t.is_finite() && t > 0.0) {
                return Err(BakeError::Budget(format!(
                    "--time must be a positive number of seconds, got {t}"
                )));
            }
        }
        if self.rays == Some(0) {
            return Err(BakeError::Budget("--rays must be positive".into()));
        }
        if let Some(e) = self.watch_every {
            if !(e.is_finite() && e >= 0.0) {
                return Err(BakeError::Budget(format!(
                    "--view-every must be a number of seconds, 0 or more, got {e}"
                )));
            }
            if self.lightmap.is_none() {
                return Err(BakeError::Budget(
                    "only a lightmap bake is shown live: add --lightmap".into(),
                ));
            }
        }
        if let Some(lm) = &self.lightmap {
            lm.check()?;
            if self.ply.is_some() {
                return Err(BakeError::Lightmap(LightmapError::Settings(
                    "--ply writes the display mesh's irradiance; a lightmap bake has none".into(),
                )));
            }
            for p in [&lm.atlas, &lm.error].into_iter().flatten() {
                outputs::check_output(p, &["exr"])?;
            }
            if let Some(p) = &self.glb {
                outputs::check_output(p, &["glb"])?;
            }
            // the atlas, when its size is known before loading, and the hits
            if let Some((limit, source)) = job::memory_limit(self.max_memory, self.max_memory_flag)
            {
                let side = if lm.texel_density.is_none() {
                    lm.size.unwrap_or(lightmap::DEFAULT_SIZE)
                } else {
                    0
                };
                let items = self.lightmap_memory(lm, side);
                render::check_memory(&items, limit, &source)?;
            }
            return Ok(CheckedBake { job: self });
        }
        if let Some((limit, source)) = job::memory_limit(self.max_memory, self.max_memory_flag) {
            // no film: only the bake's own buffers
            let config = MethodConfig::Density(self.settings.clone());
            render::check_memory(&render::memory_estimate(&config, 0, 0), limit, &source)?;
        }
        Ok(CheckedBake { job: self })
    }
}

impl BakeJob {
    /// The memory of a lightmap bake with an atlas of side `side`: the
    /// atlas and the hits, and for a watched bake the previews' copy of
    /// the hits (the index the previews build is the final one's size).
    fn lightmap_memory(&self, lm: &LightmapSettings, side: u32) -> Vec<MemoryItem> {
        let particles = self.settings.particles;
        let mut items = lm.memory(side, side, particles);
        if self.watch_every.is_some() {
            let hits = particles.saturating_mul(lightmap::HITS_PER_PARTICLE);
            items.push(MemoryItem {
                what: format!("the live view's copy of the hits (about {hits})"),
                bytes: hits.saturating_mul(std::mem::size_of::<Hit>() as u64),
                remedy: "lower --particles, or drop --view",
            });
        }
        items
    }
}

/// What a bake reports while it runs, for a progress display.
pub enum BakeEvent<'e> {
    /// Loading the scene and building the world.
    Setup(SetupEvent<'e>),
    /// The world is built and holds light: the bake begins, and from now
    /// on the cancel flag stops it (its scratch files removed).
    Started,
    /// Progress within a phase of the bake.
    Tick(&'e Tick),
    /// A bake on a dataflow exchanged `hits` hit records with other
    /// workers, in `bytes` bytes as serialized.
    Exchanged {
        /// Hit records sent.
        hits: u64,
        /// Their bytes.
        bytes: u64,
    },
    /// The bake is done; its meshes are made and written next.
    Writing,
    /// A lightmap's texels are being estimated: `done` of `total`.
    Texels {
        /// Texels done.
        done: u64,
        /// Texels in all.
        total: u64,
    },
    /// A lightmap bake watched live ([`BakeJob::watch_every`]): the .glb
    /// the bake will write, with a black atlas, before any particle.
    Asset(&'e [u8]),
    /// A watched lightmap bake starts a preview of the atlas from
    /// `particles` particles.
    Previewing {
        /// Particles so far.
        particles: u64,
    },
    /// A watched lightmap bake's preview of the atlas (padded).
    Preview {
        /// The atlas.
        lightmap: &'e Lightmap,
        /// Particles it was estimated from.
        particles: u64,
        /// Seconds it took.
        seconds: f64,
    },
}

/// A bake with its meshes.
pub struct Baked {
    /// The bake: surfaces, display mesh, white point, figures.
    pub bake: density::Bake,
    /// The lit display mesh (the diffuse surfaces).
    pub lit: BakedMesh,
    /// The surfaces with no diffuse part (glass, metal), unlit.
    pub unlit: BakedMesh,
}

/// What a bake gave, once its outputs are written.
pub struct BakeOutcome {
    /// The bake; None in a bake across processes, except in process 0,
    /// which writes the outputs, and in a lightmap bake.
    pub baked: Option<Baked>,
    /// The lightmap of a lightmap bake.
    pub lightmap: Option<LightmapBake>,
    /// Seconds spent loading the scene and building the world.
    pub load_seconds: f64,
    /// Seconds spent making and writing the meshes.
    pub write_seconds: f64,
}

/// A [`BakeJob`] whose arguments and files are checked, ready to run.
pub struct CheckedBake {
    job: BakeJob,
}

impl CheckedBake {
    /// Runs the bake: loads the scene and builds the world (unless it is
    /// built), bakes in this process (`workers` None) or on a dataflow,
    /// until done or `cancel` is set, then makes the meshes and writes the
    /// outputs atomically. `on_event` hears each step.
    pub fn run(
        self,
        workers: Option<&Workers>,
        cancel: Option<&AtomicBool>,
        on_event: &mut dyn FnMut(BakeEvent),
    ) -> Result<BakeOutcome, BakeError> {
        let j = &self.job;
        if let Some(t) = j.threads {
            job::set_threads(t).map_err(BakeError::Threads)?;
        }
        let t0 = Instant::now();
        let world = match &j.scene {
            SceneInput::World(w) => w.clone(),
            SceneInput::File {
                path,
                defines,
                allow_read,
                res,
                env,
            } => {
                let on = &mut |e: SetupEvent| on_event(BakeEvent::Setup(e));
                let opts = job::load_options(defines, allow_read, j.max_memory, j.max_memory_flag);
                let scene = job::load_step(path.as_deref(), &opts, *res, env.as_ref(), on)?;
                job::build_step(scene, on)
            }
        };
        let load_seconds = t0.elapsed().as_secs_f64();
        if world.lights.is_empty() {
            return Err(BakeError::NoLight {
                scene: world.scene.source.clone(),
            });
        }
        if let Some(lm) = &j.lightmap {
            let at = (t0, load_seconds);
            return self.run_lightmap(lm, &world, at, workers, cancel, on_event);
        }
        on_event(BakeEvent::Started);
        let Some(bake) = self.bake(&world, t0, workers, cancel, on_event)? else {
            return Ok(BakeOutcome {
                baked: None,
                lightmap: None,
                load_seconds,
                write_seconds: 0.0,
            });
        };

        // Make the meshes and write them
        on_event(BakeEvent::Writing);
        let t1 = Instant::now();
        let (lit, unlit) = bake.baked_meshes(&world.scene);
        if let Some(p) = &j.glb {
            gltf::write_glb(p, &lit, &unlit, bake.w0, Some(&world.scene.camera))?;
        }
        if let Some(p) = &j.ply {
            ply::write_ply(p, &lit)?;
        }
        Ok(BakeOutcome {
            baked: Some(Baked { bake, lit, unlit }),
            lightmap: None,
            load_seconds,
            write_seconds: t1.elapsed().as_secs_f64(),
        })
    }

    /// The lightmap bake, in this process: the atlas checked against the
    /// memory limit once its size is known (before any particle), the
    /// bake, and the images written.
    fn run_lightmap(
        &self,
        lm: &LightmapSettings,
        world: &Arc<World>,
        (start, load_seconds): (Instant, f64),
        workers: Option<&Workers>,
        cancel: Option<&AtomicBool>,
        on_event: &mut dyn FnMut(BakeEvent),
    ) -> Result<BakeOutcome, BakeError> {
        let j = &self.job;
        if workers.is_some() && j.watch_every.is_some() {
            return Err(BakeError::Lightmap(LightmapError::Settings(
                "a lightmap bake across workers is not shown live: drop --view or the workers"
                    .into(),
            )));
        }
        let side = lightmap::atlas_side(&world.scene, lm)?;
        if let Some((limit, source)) = job::memory_limit(j.max_memory, j.max_memory_flag) {
            let items = j.lightmap_memory(lm, side);
            render::check_memory(&items, limit, &source)?;
        }
        on_event(BakeEvent::Started);
        if let Some(w) = workers {
            let at = (start, load_seconds);
            return self.run_lightmap_dataflow(lm, world, at, w, cancel, on_event);
        }
        let (source, read) = self.asset_source();
        let events = RefCell::new(on_event);
        let mut on_tick = |t: &Tick| events.borrow_mut()(lightmap_event(t));
        let steer = lightmap::Steering {
            start,
            time: j.time,
            rays: j.rays,
            cancel,
            on_tick: &mut on_tick,
        };
        let mut watcher = j.watch_every.map(|every| LiveWatch {
            cadence: Cadence::new(every),
            scene: &world.scene,
            source,
            read: &read,
            events: &events,
        });
        let watch = watcher.as_mut().map(|w| w as &mut dyn Watch);
        let baked = lightmap::bake_lightmap_watched(world, &j.settings, lm, steer, watch)?;
        let on_event = &mut *events.borrow_mut();
        on_event(BakeEvent::Writing);
        let t1 = Instant::now();
        self.write_lightmap(&baked, lm, &world.scene)?;
        Ok(BakeOutcome {
            baked: None,
            lightmap: Some(baked),
            load_seconds,
            write_seconds: t1.elapsed().as_secs_f64(),
        })
    }

    /// The lightmap bake on a dataflow of threads or processes
    /// ([`crate::bake::lightmap::dataflow`]): the same atlas as in one
    /// process; the process of worker 0 writes the outputs, the others
    /// nothing. Not shown live.
    fn run_lightmap_dataflow(
        &self,
        lm: &LightmapSettings,
        world: &Arc<World>,
        (start, load_seconds): (Instant, f64),
        workers: &Workers,
        cancel: Option<&AtomicBool>,
        on_event: &mut dyn FnMut(BakeEvent),
    ) -> Result<BakeOutcome, BakeError> {
        let j = &self.job;
        let limits = Limits {
            time: j.time,
            rays: j.rays,
            view_rays: 0,
        };
        let done = {
            let mut on_tick = |t: &Tick| on_event(lightmap_event(t));
            let mut ctl = Control::new(start, limits, cancel).on_tick(&mut on_tick);
            let s = &j.settings;
            match lm_dataflow::bake_lightmap_dataflow(world.clone(), s, lm, workers, &mut ctl) {
                Ok(d) => d,
                Err(LightmapError::Dataflow(DataflowError::Density(e))) => return Err(e.into()),
                Err(LightmapError::Dataflow(e)) => return Err(BakeError::Dataflow(e)),
                Err(e) => return Err(e.into()),
            }
        };
        on_event(BakeEvent::Exchanged {
            hits: done.hits_sent,
            bytes: done.bytes_sent,
        });
        let Some(baked) = done.out else {
            return Ok(BakeOutcome {
                baked: None,
                lightmap: None,
                load_seconds,
                write_seconds: 0.0,
            });
        };
        on_event(BakeEvent::Writing);
        let t1 = Instant::now();
        self.write_lightmap(&baked, lm, &world.scene)?;
        Ok(BakeOutcome {
            baked: None,
            lightmap: Some(baked),
            load_seconds,
            write_seconds: t1.elapsed().as_secs_f64(),
        })
    }

    /// The scene's file (None for the built-in scene or a world given
    /// whole) and what it may read: the asset a lightmapped .glb copies.
    fn asset_source(&self) -> (Option<&Path>, ReadPolicy) {
        let (source, allow_read) = match &self.job.scene {
            SceneInput::File {
                path, allow_read, ..
            } => (
                path.as_deref().filter(|p| !job::is_builtin(Some(p))),
                &allow_read[..],
            ),
            SceneInput::World(_) => (None, &[][..]),
        };
        let read = ReadPolicy {
            allow_read: allow_read.to_vec(),
            memory_limit: None,
        };
        (source, read)
    }

    /// Writes a baked lightmap's images and .glb where the job asks.
    fn write_lightmap(
        &self,
        baked: &LightmapBake,
        lm: &LightmapSettings,
        scene: &Scene,
    ) -> Result<(), BakeError> {
        let j = &self.job;
        let (source, read) = self.asset_source();
        lightmap::write_images(baked, lm)?;
        if let Some(glb) = &j.glb {
            lightmap_glb::write_lightmapped_with(
                glb,
                scene,
                source,
                &read,
                &baked.uv,
                &baked.lightmap,
            )
            .map_err(LightmapError::from)?;
        }
        Ok(())
    }

    /// The bake itself, here or on a dataflow; None in a process other
    /// than the one that writes.
    fn bake(
        &self,
        world: &Arc<World>,
        start: Instant,
        workers: Option<&Workers>,
        cancel: Option<&AtomicBool>,
        on_event: &mut dyn FnMut(BakeEvent),
    ) -> Result<Option<density::Bake>, BakeError> {
        let s = &self.job.settings;
        let mut on_tick = |t: &Tick| on_event(BakeEvent::Tick(t));
        let limits = Limits {
            time: self.job.time,
            rays: self.job.rays,
            view_rays: 0,
        };
        let mut ctl = Control::new(start, limits, cancel).on_tick(&mut on_tick);
        let Some(w) = workers else {
            return Ok(Some(density::bake_within(
                world,
                s,
                Storage::Disk,
                &mut ctl,
            )?));
        };
        let d = match dataflow::bake_dataflow(world.clone(), s, w, &mut ctl) {
            Ok(d) => d,
            Err(DataflowError::Density(e)) => return Err(e.into()),
            Err(e) => return Err(BakeError::Dataflow(e)),
        };
        on_event(BakeEvent::Exchanged {
            hits: d.hits_sent,
            bytes: d.bytes_sent,
        });
        Ok(d.bake)
    }
}

/// A lightmap bake's tick as an event: its texels while it estimates.
fn lightmap_event<'t>(t: &'t Tick) -> BakeEvent<'t> {
    match t.phase {
        Phase::Estimate => BakeEvent::Texels {
            done: t.done,
            total: t.total,
        },
        _ => BakeEvent::Tick(t),
    }
}

/// The watcher of a lightmap bake with [`BakeJob::watch_every`]: the asset
/// encoded as the bake will write it, and previews on [`Cadence`]'s
/// schedule, each told as a [`BakeEvent`].
struct LiveWatch<'a, 'e> {
    cadence: Cadence,
    scene: &'a Scene,
    source: Option<&'a Path>,
    read: &'a ReadPolicy,
    events: &'a RefCell<&'e mut dyn FnMut(BakeEvent)>,
}

impl Watch for LiveWatch<'_, '_> {
    fn started(&mut self, uv: &LightmapUv) {
        let n = uv.width as usize * uv.height as usize;
        let black = Lightmap {
            width: uv.width,
            height: uv.height,
            irradiance: vec![Rgb::ZERO; n],
            std_error: vec![Rgb::ZERO; n],
            covered: vec![false; n],
        };
        let on_event = &mut *self.events.borrow_mut();
        match lightmap_glb::encode_lightmapped_with(self.scene, self.source, self.read, uv, &black)
        {
            Ok((bytes, _)) => on_event(BakeEvent::Asset(&bytes)),
            // the bake goes on; its own write will say what is wrong
            Err(e) => on_event(BakeEvent::Setup(SetupEvent::Warning(format!(
                "the live view cannot show the asset: {e}"
            )))),
        }
    }

    fn due(&mut self, tick: &Tick) -> bool {
        let due = self.cadence.due(tick);
        if due {
            (self.events.borrow_mut())(BakeEvent::Previewing {
                particles: tick.done,
            });
        }
        due
    }

    fn atlas(&mut self, lm: &Lightmap, particles: u64, seconds: f64) {
        self.cadence.done(seconds);
        (self.events.borrow_mut())(BakeEvent::Preview {
            lightmap: lm,
            particles,
            seconds,
        });
    }
}

/// Why a bake job stopped; each message names the file, the setting or the
/// scene at fault.
#[derive(Debug, thiserror::Error)]
pub enum BakeError {
    /// An output that cannot be written.
    #[error(transparent)]
    Output(#[from] OutputError),
    /// Settings the density method refuses.
    #[error(transparent)]
    Settings(#[from] MethodError),
    /// A longest path of 0 segments.
    #[error("--max-depth must be at least 1 (1 shows only the emitters, 2 adds direct light)")]
    MaxDepth,
    /// A bake past the memory limit.
    #[error(transparent)]
    Memory(#[from] MemoryError),
    /// The thread pool could not be sized.
    #[error("setting the thread count")]
    Threads(#[source] rayon::ThreadPoolBuildError),
    /// A scene that cannot be loaded.
    #[error(transparent)]
    Scene(#[from] SceneError),
    /// A scene with no emitter that emits light.
    #[error("the scene has no emitters: nothing to bake")]
    NoLight {
        /// Where the scene came from.
        scene: String,
    },
    /// The bake failed or was cancelled.
    #[error(transparent)]
    Density(#[from] DensityError),
    /// The dataflow failed (its layout, its network).
    #[error(transparent)]
    Dataflow(DataflowError),
    /// A mesh that cannot be written.
    #[error(transparent)]
    Write(#[from] ImageIoError),
    /// A time or ray budget that cannot work.
    #[error("{0}")]
    Budget(String),
    /// A lightmap bake that cannot work, failed, or was cancelled.
    #[error(transparent)]
    Lightmap(#[from] LightmapError),
}

#[cfg(test)]
mod tests {
    use super::*;

    fn settings(particles: u64) -> density::Settings {
        density::Settings {
            particles,
            seed: 2,
            ..Default::default()
        }
    }

    #[test]
    fn a_longest_path_of_zero_is_refused_before_any_work() {
        let mut s = settings(1000);
        s.max_depth = Some(0);
        let e = BakeJob::new(SceneInput::builtin(), s).check().err();
        assert!(matches!(e, Some(BakeError::MaxDepth)));
    }

    #[test]
    fn an_output_of_another_format_is_refused() {
        let mut job = BakeJob::new(SceneInput::builtin(), settings(1000));
        job.glb = Some("out.gltf".into());
        let e = job.check().err().expect("refused");
        assert_eq!(e.to_string(), "output 'out.gltf' must end in .glb");
    }

    #[test]
    fn the_job_bakes_and_writes_the_mesh() {
        let dir = tempfile::tempdir().expect("tempdir");
        let glb = dir.path().join("x.glb");
        let mut job = BakeJob::new(SceneInput::builtin(), settings(20_000));
        job.glb = Some(glb.clone());
        let (mut ticks, mut writing) = (0, false);
        let o = job
            .check()
            .expect("checked")
            .run(None, None, &mut |e| match e {
                BakeEvent::Tick(_) => ticks += 1,
                BakeEvent::Writing => writing = true,
                _ => {}
            })
            .expect("baked");
        let b = o.baked.expect("a bake in this process");
        assert!(!b.lit.indices.is_empty());
        assert!(ticks > 0 && writing);
        let bytes = std::fs::read(&glb).expect("written");
        assert_eq!(&bytes[..4], b"glTF");
    }
}
