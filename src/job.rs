//! The whole sequence of a render, owned by the library, so that the front
//! ends (the command line, the Python package) only translate their
//! arguments and show progress ([`RenderJob`]): check everything that can
//! be checked before any work (settings, budget, outputs, checkpoint,
//! reference), load the scene, size the memory against a limit, build the
//! world, run the method, write the outputs atomically. The bake's job
//! ([`crate::bake::job`]) shares the steps defined here: [`memory_limit`],
//! [`load_scene`], [`set_threads`] and the [`SetupEvent`]s of loading and
//! building.
//!
//! ```no_run
//! use kalos::job::{RenderEvent, RenderJob, SceneInput};
//! use kalos::methods::MethodConfig;
//!
//! let mut job = RenderJob::new(SceneInput::builtin(), MethodConfig::Path(Default::default()));
//! job.budget.spp = Some(8.0);
//! job.output = Some("cbox.exr".into());
//! let outcome = job.check()?.run(None, &mut |e| {
//!     if let RenderEvent::Progress(p) = e {
//!         eprintln!("{:.0} %", 100.0 * p.fraction)
//!     }
//! })?;
//! println!("{} rays", outcome.result.rays);
//! # Ok::<(), kalos::job::JobError>(())
//! ```

use std::cell::{Cell, RefCell};
use std::path::{Path, PathBuf};
use std::sync::atomic::AtomicBool;
use std::sync::Arc;
use std::time::Instant;

use crate::film::Image;
use crate::image_io::{self, ImageIoError, PngOptions};
use crate::methods::{Budget, Common, MethodConfig, MethodError, Progress, RenderResult};
use crate::metrics::{self, MetricsError};
use crate::outputs::{self, OutputError};
use crate::partial::{self, Meta, Partial, PartialError, Shard, State};
use crate::render::{self, MemoryError, Render};
use crate::scene::{self, LoadOptions, ReadPolicy, Scene, SceneError};
use crate::world::{BuildEvent, World};

/// Where a job's scene comes from.
pub enum SceneInput {
    /// A scene file (Mitsuba XML, OBJ, PLY, glTF, pbrt-v4), or the
    /// built-in Cornell box when `path` is None or `builtin`; loaded and
    /// built by the job.
    File {
        /// The file; None (or `builtin`) for the built-in Cornell box.
        path: Option<PathBuf>,
        /// `-D NAME=VALUE`: fills `$NAME` in a Mitsuba scene.
        defines: Vec<(String, String)>,
        /// `--allow-read DIR`: folders the scene may read besides its own.
        allow_read: Vec<PathBuf>,
        /// The film's resolution, overriding the scene's.
        res: Option<(u32, u32)>,
        /// `--env`, `--env-constant`: an environment added to a scene
        /// without one ([`Scene::add_environment`]).
        env: Option<scene::Environment>,
    },
    /// A world already built (the Python package's `kalos.Scene`): what
    /// can be checked against it is checked with the arguments.
    World(Arc<World>),
}

impl SceneInput {
    /// The built-in Cornell box, as the scene file sets it.
    pub fn builtin() -> Self {
        SceneInput::File {
            path: None,
            defines: Vec::new(),
            allow_read: Vec::new(),
            res: None,
            env: None,
        }
    }
}

/// Whether `path` names the built-in Cornell box (no path, or `builtin`).
pub fn is_builtin(path: Option<&Path>) -> bool {
    path.is_none_or(|p| p.as_os_str() == "builtin")
}

/// A scene as [`load_scene`] gives it, with what the user should hear
/// about it.
pub struct LoadedScene {
    /// The scene.
    pub scene: Scene,
    /// The loader's warnings the user should see: all of a file's; of the
    /// built-in scene only those about `-D` (its own, such as its skipped
    /// integrator, are known and not the user's concern). All stay in
    /// [`Scene::warnings`].
    pub warnings: Vec<String>,
    /// What the loader added or chose that changes the image.
    pub notes: Vec<String>,
}

/// Loads the scene at `path`, or the built-in Cornell box when it is None
/// or `builtin` ([`is_builtin`]), with `opts`: its `defines` fill a
/// Mitsuba scene's `$NAME`s, its read policy says what else the scene may
/// read and allocate. Nothing is printed: the warnings and notes are
/// returned.
pub fn load_scene(path: Option<&Path>, opts: &LoadOptions) -> Result<LoadedScene, SceneError> {
    let builtin = is_builtin(path);
    let scene = match path {
        Some(p) if !builtin => scene::load_opts(p, opts)?,
        _ => scene::builtin::cornell_box_with(&opts.defines)?,
    };
    let warnings = scene
        .warnings
        .iter()
        .filter(|w| !builtin || w.contains(": -D "))
        .cloned()
        .collect();
    let notes = scene.notes.clone();
    Ok(LoadedScene {
        scene,
        warnings,
        notes,
    })
}

/// The options a job loads its scene with: its `-D`s, its `--allow-read`
/// folders, and its memory limit ([`memory_limit`]), which the loaders
/// check the scene's data against before allocating it.
pub(crate) fn load_options(
    defines: &[(String, String)],
    allow_read: &[PathBuf],
    max_memory: Option<u64>,
    max_memory_flag: &str,
) -> LoadOptions {
    LoadOptions {
        defines: defines.to_vec(),
        read: ReadPolicy {
            allow_read: allow_read.to_vec(),
            memory_limit: memory_limit(max_memory, max_memory_flag),
        },
    }
}

/// The memory limit of a render or a bake and where it comes from: `flag`
/// when given (`flag_name` says where, "--max-memory"), else the machine's
/// memory (Linux's `/proc/meminfo`, through [`render::mem_total`]), else
/// none.
pub fn memory_limit(flag: Option<u64>, flag_name: &str) -> Option<(u64, String)> {
    if let Some(m) = flag {
        return Some((m, flag_name.to_string()));
    }
    let text = std::fs::read_to_string("/proc/meminfo").ok()?;
    let total = render::mem_total(&text)?;
    Some((total, "this machine's memory".into()))
}

/// Sizes the global thread pool (rayon's) to `threads` workers (at least
/// one). It can be sized once, before the first parallel work.
pub fn set_threads(threads: usize) -> Result<(), rayon::ThreadPoolBuildError> {
    rayon::ThreadPoolBuilder::new()
        .num_threads(threads.max(1))
        .build_global()
}

/// What a job reports while it loads the scene and builds the world, for
/// a spinner.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum SetupEvent<'e> {
    /// The scene starts loading: from this file, or (None) the built-in
    /// scene.
    Load(Option<&'e Path>),
    /// The world (BVH, lights) starts being built.
    Build,
    /// A phase of the build starts ([`BuildEvent::Phase`]).
    Phase(String),
    /// Something the user should hear about: a loader's warning
    /// ([`LoadedScene::warnings`]) or the build's ([`BuildEvent::Warning`]).
    Warning(String),
    /// What the loader added or chose that changes the image.
    Note(String),
}

/// Loads the scene at `path` ([`load_scene`]), adds `env` to it and sets
/// its resolution, reporting each step, warning and note to `on_event`.
pub(crate) fn load_step(
    path: Option<&Path>,
    opts: &LoadOptions,
    res: Option<(u32, u32)>,
    env: Option<&scene::Environment>,
    on_event: &mut dyn FnMut(SetupEvent),
) -> Result<Scene, SceneError> {
    on_event(SetupEvent::Load(path.filter(|_| !is_builtin(path))));
    let mut loaded = load_scene(path, opts)?;
    if let Some(env) = env {
        loaded.scene.add_environment(env)?;
        loaded.notes = loaded.scene.notes.clone();
    }
    for w in loaded.warnings {
        on_event(SetupEvent::Warning(w));
    }
    for n in loaded.notes {
        on_event(SetupEvent::Note(n));
    }
    let mut scene = loaded.scene;
    if let Some((w, h)) = res {
        scene.set_resolution(w, h);
    }
    Ok(scene)
}

/// Builds the world of `scene` ([`World::build`]), reporting to `on_event`.
pub(crate) fn build_step(scene: Scene, on_event: &mut dyn FnMut(SetupEvent)) -> Arc<World> {
    on_event(SetupEvent::Build);
    Arc::new(World::build(scene, &mut |e| match e {
        BuildEvent::Phase(p) => on_event(SetupEvent::Phase(p)),
        BuildEvent::Warning(w) => on_event(SetupEvent::Warning(w)),
    }))
}

/// The image a render is measured against.
pub enum Reference {
    /// An HDR image file ([`outputs::read_hdr`]), read when the job is
    /// checked.
    File(PathBuf),
    /// An image in memory.
    Image(Image),
}

/// A render from start to finish: what to render, how, and what to write.
/// Its fields are plain settings; [`RenderJob::check`] checks them and the
/// files before any work, [`CheckedRender::run`] does the work.
pub struct RenderJob {
    /// The scene.
    pub scene: SceneInput,
    /// The method and its settings.
    pub method: MethodConfig,
    /// The shared settings (seed, longest path).
    pub common: Common,
    /// The budget; with no spp, time nor rays, the scene's sample count
    /// (Mitsuba's `<sampler>`), else 16 spp.
    pub budget: Budget,
    /// The image to write (.exr, .pfm, .png), or a partial result (.kpart)
    /// for `kalos merge`; None writes nothing.
    pub output: Option<PathBuf>,
    /// How a PNG output is tone-mapped.
    pub png: PngOptions,
    /// Render only this shard (the output must be a .kpart).
    pub shard: Option<Shard>,
    /// Write the render's state here (.kpart) every
    /// [`RenderJob::checkpoint_every`] seconds and at the end.
    pub checkpoint: Option<PathBuf>,
    /// Seconds between checkpoints.
    pub checkpoint_every: f64,
    /// Continue from this checkpoint of the same render.
    pub resume: Option<PathBuf>,
    /// The image to measure the render against.
    pub reference: Option<Reference>,
    /// Write the convergence log here (CSV).
    pub log: Option<PathBuf>,
    /// Seconds between the convergence log's rows (0: only at the end).
    pub log_every: f64,
    /// Report the current image ([`RenderEvent::Image`]) at most every
    /// this many seconds of render time (a live preview).
    pub watch_every: Option<f64>,
    /// Size the thread pool ([`set_threads`]) before loading.
    pub threads: Option<usize>,
    /// The most memory the render may plan to use ([`memory_limit`]);
    /// None: the machine's memory.
    pub max_memory: Option<u64>,
    /// The name of [`RenderJob::max_memory`] in the front end, which the
    /// error names ("--max-memory").
    pub max_memory_flag: &'static str,
}

impl RenderJob {
    /// A render of `scene` with `method`: the default budget, seed 0,
    /// nothing written, no limit but the machine's memory.
    pub fn new(scene: SceneInput, method: MethodConfig) -> Self {
        RenderJob {
            scene,
            method,
            common: Common::default(),
            budget: Budget::default(),
            output: None,
            png: PngOptions::default(),
            shard: None,
            checkpoint: None,
            checkpoint_every: 300.0,
            resume: None,
            reference: None,
            log: None,
            log_every: 0.0,
            watch_every: None,
            threads: None,
            max_memory: None,
            max_memory_flag: "--max-memory",
        }
    }

    /// Checks what can be checked before spending any time, so that a bad
    /// argument or path fails now and not after the render: the settings,
    /// the budget, the files to write (format, folder, permissions), the
    /// shard, the checkpoint to resume and the reference (read here). With
    /// a built world, also the reference's size and the scene's budget.
    pub fn check(self) -> Result<CheckedRender, JobError> {
        self.method.check(&self.common)?;
        let mut budget = self.budget;
        let default_budget = budget.spp.is_none() && budget.time.is_none() && budget.rays.is_none();
        if default_budget {
            budget.spp = Some(16.0);
        }
        budget.validate()?;
        let partial_out = self.check_outputs()?;
        let resume = match &self.resume {
            Some(p) => {
                partial::check_resumable(&self.method)?;
                Some(partial::read(p)?)
            }
            None => None,
        };
        if let Some(log) = &self.log {
            outputs::check_output(log, &["csv"])?;
        }
        let reference = match &self.reference {
            Some(Reference::File(p)) => Some((Some(p.clone()), outputs::read_hdr(p)?)),
            Some(Reference::Image(img)) => Some((None, img.clone())),
            None => None,
        };
        let mut checked = CheckedRender {
            job: self,
            budget,
            default_budget,
            scene_sample_count: None,
            partial_out,
            resume,
            reference,
        };
        if let SceneInput::World(w) = &checked.job.scene {
            let w = w.clone();
            checked.scene_budget(&w.scene)?;
            checked.check_reference(w.camera.width, w.camera.height)?;
        }
        Ok(checked)
    }

    /// Checks the output, the shard and the checkpoint file; true when the
    /// output is a partial result.
    fn check_outputs(&self) -> Result<bool, JobError> {
        let partial_out = self
            .output
            .as_deref()
            .is_some_and(|o| outputs::extension(o) == "kpart");
        if let Some(out) = &self.output {
            let exts: &[&str] = if partial_out {
                &["kpart"]
            } else {
                &["exr", "pfm", "png"]
            };
            outputs::check_output(out, exts)?;
        }
        if partial_out {
            partial::check_shard(&self.method, self.shard.unwrap_or(Shard::WHOLE))?;
        }
        if let Some(s) = self.shard {
            partial::check_shard(&self.method, s)?;
            if !partial_out {
                return Err(JobError::ShardNeedsPartial {
                    shard: s,
                    output: self.output.clone().unwrap_or_default(),
                });
            }
        }
        if let Some(c) = &self.checkpoint {
            partial::check_resumable(&self.method)?;
            outputs::check_output(c, &["kpart"])?;
        }
        Ok(partial_out)
    }
}

/// What a render reports while it runs, for a progress display.
pub enum RenderEvent<'e> {
    /// Loading the scene and building the world.
    Setup(SetupEvent<'e>),
    /// The world is built and the render begins: from now on the cancel
    /// flag stops it after the current pass, and what is rendered is
    /// written.
    Started,
    /// A pass is done.
    Progress(&'e Progress),
    /// The current image, every [`RenderJob::watch_every`] seconds.
    Image(&'e Image, &'e Progress),
    /// A checkpoint could not be written; the render goes on, and its
    /// outputs are still written at the end.
    CheckpointFailed(&'e PartialError),
    /// The render is done (or was stopped); its outputs are written next.
    Rendered(&'e RenderResult),
}

/// What a render gave, once its outputs are written.
pub struct RenderOutcome {
    /// The render's image and figures.
    pub result: RenderResult,
    /// Seconds spent loading the scene and building the world.
    pub load_seconds: f64,
    /// The scene's sample count, when the budget was taken from it.
    pub scene_sample_count: Option<u32>,
    /// Checkpoints written during the render (not the last, at its end).
    pub checkpoints: u32,
    /// The seconds they took together.
    pub checkpoint_seconds: f64,
    /// False when the render was stopped before its first pass: nothing
    /// was written, since a black image must not replace a good one.
    pub written: bool,
    /// The relMSE of the image against the reference, when there is one.
    pub rel_mse: Option<f64>,
}

/// A [`RenderJob`] whose arguments and files are checked, ready to run.
pub struct CheckedRender {
    job: RenderJob,
    budget: Budget,
    default_budget: bool,
    scene_sample_count: Option<u32>,
    partial_out: bool,
    resume: Option<Partial>,
    /// The reference and its file.
    reference: Option<(Option<PathBuf>, Image)>,
}

impl CheckedRender {
    /// The method to run.
    pub fn method(&self) -> &MethodConfig {
        &self.job.method
    }

    /// The reference image, read by [`RenderJob::check`].
    pub fn reference(&self) -> Option<&Image> {
        self.reference.as_ref().map(|r| &r.1)
    }

    /// Runs the render: loads the scene and builds the world (unless it is
    /// built), checks them against the settings (emitters, film, memory,
    /// reference), renders until the budget is spent or `cancel` is set,
    /// and writes the outputs atomically. `on_event` hears each step.
    pub fn run(
        mut self,
        cancel: Option<&AtomicBool>,
        on_event: &mut dyn FnMut(RenderEvent),
    ) -> Result<RenderOutcome, JobError> {
        if let Some(t) = self.job.threads {
            set_threads(t).map_err(JobError::Threads)?;
        }
        let t0 = Instant::now();
        let world = self.world(&mut |e| on_event(RenderEvent::Setup(e)))?;
        let load_seconds = t0.elapsed().as_secs_f64();
        on_event(RenderEvent::Started);
        if world.lights.is_empty() {
            return Err(JobError::NoLight {
                scene: world.scene.source.clone(),
                emitters: world.scene.emitters.len(),
            });
        }
        if matches!(self.job.scene, SceneInput::File { .. }) {
            self.scene_budget(&world.scene)?;
        }
        let meta = self.meta(&world)?;
        let (result, (checkpoints, checkpoint_seconds)) =
            self.render(&world, meta.as_ref(), cancel, on_event)?;
        on_event(RenderEvent::Rendered(&result));
        let mut outcome = RenderOutcome {
            result,
            load_seconds,
            scene_sample_count: self.scene_sample_count,
            checkpoints,
            checkpoint_seconds,
            written: false,
            rel_mse: None,
        };
        if outcome.result.interrupted && outcome.result.passes == 0 {
            return Ok(outcome);
        }
        self.write(&outcome.result, meta.as_ref())?;
        outcome.written = true;
        if let Some((_, r)) = &self.reference {
            outcome.rel_mse = Some(metrics::rel_mse(&outcome.result.image, r)?);
        }
        Ok(outcome)
    }

    /// The world to render: the one given, or the scene loaded, checked
    /// against the settings and built.
    fn world(&self, on_event: &mut dyn FnMut(SetupEvent)) -> Result<Arc<World>, JobError> {
        let input = match &self.job.scene {
            SceneInput::World(w) => {
                self.check_memory(w.camera.width, w.camera.height)?;
                return Ok(w.clone());
            }
            SceneInput::File {
                path,
                defines,
                allow_read,
                res,
                env,
            } => (path, defines, allow_read, res, env),
        };
        let (path, defines, allow_read, res, env) = input;
        let opts = load_options(
            defines,
            allow_read,
            self.job.max_memory,
            self.job.max_memory_flag,
        );
        let scene = load_step(path.as_deref(), &opts, *res, env.as_ref(), on_event)?;
        if scene.emitters.is_empty() {
            return Err(JobError::NoEmitters {
                scene: scene.source.clone(),
            });
        }
        let (w, h) = (scene.camera.width, scene.camera.height);
        if w == 0 || h == 0 {
            return Err(JobError::EmptyFilm {
                width: w,
                height: h,
            });
        }
        self.check_memory(w, h)?;
        self.check_reference(w, h)?;
        Ok(build_step(scene, on_event))
    }

    /// Refuses a render whose large buffers would pass the memory limit.
    fn check_memory(&self, width: u32, height: u32) -> Result<(), JobError> {
        if let Some((limit, source)) = memory_limit(self.job.max_memory, self.job.max_memory_flag) {
            let items = render::memory_estimate(&self.job.method, width, height);
            render::check_memory(&items, limit, &source)?;
        }
        Ok(())
    }

    /// Refuses a reference of another size than the film.
    fn check_reference(&self, width: u32, height: u32) -> Result<(), JobError> {
        match &self.reference {
            Some((path, r)) if (r.width, r.height) != (width, height) => {
                Err(JobError::ReferenceSize {
                    path: path.clone(),
                    reference: (r.width, r.height),
                    film: (width, height),
                })
            }
            _ => Ok(()),
        }
    }

    /// Without a budget in the arguments: the scene's own sample count,
    /// when it has one.
    fn scene_budget(&mut self, scene: &Scene) -> Result<(), JobError> {
        if let (true, Some(n)) = (self.default_budget, scene.sample_count) {
            self.budget.spp = Some(n as f64);
            self.budget.validate()?;
            self.scene_sample_count = Some(n);
        }
        Ok(())
    }

    /// The render's identity, only when a partial result is written or
    /// read (the scene hash reads every vertex); a checkpoint to resume
    /// must be of this render.
    fn meta(&self, world: &World) -> Result<Option<Meta>, JobError> {
        let j = &self.job;
        if !(self.partial_out || j.checkpoint.is_some() || self.resume.is_some()) {
            return Ok(None);
        }
        let shard = j.shard.unwrap_or(Shard::WHOLE);
        let meta = Meta::new(&world.scene, &j.method, &j.common, shard)?;
        if let (Some(r), Some(p)) = (&self.resume, &j.resume) {
            check_resume(&meta, r, p)?;
        }
        Ok(Some(meta))
    }

    /// Runs the method through [`Render`]; the checkpoints written during
    /// the render are counted, with the seconds they took.
    fn render(
        &self,
        world: &World,
        meta: Option<&Meta>,
        cancel: Option<&AtomicBool>,
        on_event: &mut dyn FnMut(RenderEvent),
    ) -> Result<(RenderResult, (u32, f64)), JobError> {
        let j = &self.job;
        // the progress, the watch and the checkpoints all report; the
        // driver calls them one at a time
        let events = RefCell::new(on_event);
        let written = Cell::new((0u32, 0.0f64));
        let mut save = |state: &State| {
            if let (Some(c), Some(meta)) = (&j.checkpoint, meta) {
                let t0 = Instant::now();
                // A failed checkpoint does not stop the render: the image
                // is still written at the end
                match partial::write(c, meta, state) {
                    Ok(()) => {
                        let (n, s) = written.get();
                        written.set((n + 1, s + t0.elapsed().as_secs_f64()));
                    }
                    Err(e) => (events.borrow_mut())(RenderEvent::CheckpointFailed(&e)),
                }
            }
        };
        let mut r = Render::new(world)
            .method(j.method.clone())
            .common(j.common.clone())
            .budget(self.budget)
            .shard(j.shard.unwrap_or(Shard::WHOLE));
        if let Some(c) = cancel {
            r = r.cancel(c);
        }
        if self.partial_out || j.checkpoint.is_some() {
            r = r.keep_state();
        }
        if j.checkpoint.is_some() {
            r = r.checkpoint(j.checkpoint_every, &mut save);
        }
        if let Some(p) = &self.resume {
            r = r.resume(&p.state);
        }
        if let Some((_, img)) = &self.reference {
            r = r.reference(img, j.log_every);
        }
        if let Some(every) = j.watch_every {
            r = r.watch(every, |img, p| {
                (events.borrow_mut())(RenderEvent::Image(img, p))
            });
        }
        let result = r
            .run(|p| (events.borrow_mut())(RenderEvent::Progress(p)))
            .map_err(JobError::Render)?;
        Ok((result, written.get()))
    }

    /// Writes the outputs, each atomically: the last checkpoint, the image
    /// or partial result, the convergence log.
    fn write(&self, result: &RenderResult, meta: Option<&Meta>) -> Result<(), JobError> {
        let j = &self.job;
        let state = result.state.as_ref();
        if let (Some(c), Some(state), Some(meta)) = (&j.checkpoint, state, meta) {
            partial::write(c, meta, state)?;
        }
        if let Some(out) = &j.output {
            match (self.partial_out, meta) {
                (true, Some(meta)) => {
                    let state = state.ok_or(JobError::NoState)?;
                    partial::write(out, meta, state)?;
                }
                _ => image_io::write_image(out, &result.image, &j.png)?,
            }
        }
        if let Some(log) = &j.log {
            outputs::write_log(log, &result.log)?;
        }
        Ok(())
    }
}

/// Refuses a checkpoint `r` (read from `path`) that is not of this render,
/// naming what differs.
fn check_resume(meta: &Meta, r: &Partial, path: &Path) -> Result<(), JobError> {
    let name = format!("checkpoint {}", path.display());
    if let Some(d) = meta.difference("this render", &r.meta, &name) {
        return Err(JobError::NotThisRender(d));
    }
    if r.meta.shard != meta.shard {
        return Err(JobError::NotThisRender(format!(
            "{name} is of shard {}, but this render is shard {}",
            r.meta.shard, meta.shard
        )));
    }
    Ok(())
}

/// Why a render job stopped; each message names the file, the setting or
/// the scene at fault.
#[derive(Debug, thiserror::Error)]
pub enum JobError {
    /// Settings, a budget, a shard or a resume the method refuses.
    #[error(transparent)]
    Settings(#[from] MethodError),
    /// An output that cannot be written, or a reference that cannot serve.
    #[error(transparent)]
    Output(#[from] OutputError),
    /// A shard whose output is not a partial result.
    #[error(
        "--shard {shard} writes a partial result: -o must end in .kpart (got '{output}'); \
         `kalos merge` makes the image from the parts",
        output = .output.display()
    )]
    ShardNeedsPartial {
        /// The shard.
        shard: Shard,
        /// The output asked for.
        output: PathBuf,
    },
    /// A partial result or checkpoint that cannot be read or written.
    #[error(transparent)]
    Partial(#[from] PartialError),
    /// A checkpoint of another render; the text says what differs.
    #[error("{0}: a checkpoint resumes only the render that wrote it")]
    NotThisRender(String),
    /// The thread pool could not be sized.
    #[error("setting the thread count")]
    Threads(#[source] rayon::ThreadPoolBuildError),
    /// A scene that cannot be loaded.
    #[error(transparent)]
    Scene(#[from] SceneError),
    /// A scene without emitters.
    #[error(
        "{scene}: the scene has no emitters, so the image would be black; add an <emitter> \
         (an area light on a shape, or <emitter type=\"constant\"/> for a white sky)"
    )]
    NoEmitters {
        /// Where the scene came from.
        scene: String,
    },
    /// A film without pixels.
    #[error("the film is {width}x{height}: an image needs at least one pixel (set --res)")]
    EmptyFilm {
        /// Its width.
        width: u32,
        /// Its height.
        height: u32,
    },
    /// A reference of another size than the film.
    #[error(
        "reference {}is {}x{} but the render is {}x{}",
        path.as_ref().map(|p| format!("{} ", p.display())).unwrap_or_default(),
        reference.0, reference.1, film.0, film.1
    )]
    ReferenceSize {
        /// Its file, when it was read from one.
        path: Option<PathBuf>,
        /// Its size.
        reference: (u32, u32),
        /// The film's.
        film: (u32, u32),
    },
    /// A render past the memory limit.
    #[error(transparent)]
    Memory(#[from] MemoryError),
    /// Emitters that emit nothing.
    #[error(
        "{scene}: the scene's {emitters} emitters emit no light (zero radiance, or on shapes with \
         no area), so the image would be black"
    )]
    NoLight {
        /// Where the scene came from.
        scene: String,
        /// Its emitters.
        emitters: usize,
    },
    /// The method failed while it rendered.
    #[error("rendering")]
    Render(#[source] MethodError),
    /// A partial result asked of a method that gave no state.
    #[error("the method gave no state to write as a partial result")]
    NoState,
    /// An image or log that cannot be written.
    #[error(transparent)]
    Write(#[from] ImageIoError),
    /// The final error against the reference cannot be measured.
    #[error(transparent)]
    Metrics(#[from] MetricsError),
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The built-in Cornell box at `n`×`n`, as a loader and a build give it.
    fn cbox(n: u32) -> SceneInput {
        SceneInput::File {
            path: None,
            defines: Vec::new(),
            allow_read: Vec::new(),
            res: Some((n, n)),
            env: None,
        }
    }

    fn path() -> MethodConfig {
        MethodConfig::Path(Default::default())
    }

    #[test]
    fn a_bad_output_fails_at_check_before_the_scene_loads() {
        let mut job = RenderJob::new(
            SceneInput::File {
                path: Some("no-such-scene-kalos.xml".into()),
                defines: Vec::new(),
                allow_read: Vec::new(),
                res: None,
                env: None,
            },
            path(),
        );
        job.output = Some("out.txt".into());
        let e = job.check().err().expect("refused");
        assert!(matches!(e, JobError::Output(_)), "{e}");
        assert_eq!(
            e.to_string(),
            "output 'out.txt' must end in .exr, .pfm or .png"
        );
    }

    #[test]
    fn a_shard_needs_a_partial_output() {
        let mut job = RenderJob::new(cbox(8), path());
        job.shard = Some(Shard { index: 0, count: 2 });
        let e = job.check().err().expect("refused");
        assert!(
            e.to_string()
                .starts_with("--shard 0/2 writes a partial result"),
            "{e}"
        );
    }

    #[test]
    fn the_memory_limit_names_where_it_comes_from() {
        assert_eq!(
            memory_limit(Some(5), "max_memory"),
            Some((5, "max_memory".to_string()))
        );
        let mut job = RenderJob::new(cbox(64), path());
        job.max_memory = Some(1000);
        let e = job.check().expect("checked").run(None, &mut |_| {});
        let e = e.err().expect("refused");
        assert!(matches!(e, JobError::Memory(_)), "{e}");
        assert!(e.to_string().contains("(--max-memory)"), "{e}");
    }

    #[test]
    fn a_built_world_checks_the_reference_with_the_arguments() {
        let world = Arc::new(World::new(scene::builtin::cornell_box().expect("builtin")));
        let (w, h) = (world.camera.width, world.camera.height);
        let mut job = RenderJob::new(SceneInput::World(world), path());
        job.reference = Some(Reference::Image(Image {
            width: 8,
            height: 8,
            data: vec![glam::Vec3::ONE; 64],
        }));
        let e = job.check().err().expect("refused");
        assert_eq!(
            e.to_string(),
            format!("reference is 8x8 but the render is {w}x{h}")
        );
    }

    #[test]
    fn the_job_renders_what_the_builder_renders_and_writes_it() {
        let dir = tempfile::tempdir().expect("tempdir");
        let (out, log) = (dir.path().join("x.pfm"), dir.path().join("x.csv"));
        let world = World::new({
            let mut s = scene::builtin::cornell_box().expect("builtin");
            s.set_resolution(12, 12);
            s
        });
        let expected = Render::new(&world)
            .seed(3)
            .spp(2.0)
            .run(|_| {})
            .expect("rendered");

        let mut job = RenderJob::new(cbox(12), path());
        job.common.seed = 3;
        job.budget.spp = Some(2.0);
        job.output = Some(out.clone());
        job.log = Some(log.clone());
        job.reference = Some(Reference::Image(expected.image.clone()));
        let mut seen = Vec::new();
        let o = job
            .check()
            .expect("checked")
            .run(None, &mut |e| {
                seen.push(match e {
                    RenderEvent::Setup(SetupEvent::Load(p)) => format!("load {p:?}"),
                    RenderEvent::Setup(SetupEvent::Build) => "build".into(),
                    RenderEvent::Setup(_) => return,
                    RenderEvent::Started => "started".into(),
                    RenderEvent::Progress(_) => "progress".into(),
                    RenderEvent::Image(..) => "image".into(),
                    RenderEvent::CheckpointFailed(_) => "checkpoint failed".into(),
                    RenderEvent::Rendered(_) => "rendered".into(),
                });
            })
            .expect("rendered");
        assert_eq!(o.result.image.data, expected.image.data);
        assert!(o.written);
        assert_eq!(o.rel_mse, Some(0.0));
        seen.dedup();
        assert_eq!(
            seen,
            ["load None", "build", "started", "progress", "rendered"]
        );
        let back = image_io::read_image(&out).expect("written");
        assert_eq!(back.data, expected.image.data);
        let text = std::fs::read_to_string(&log).expect("log written");
        assert!(text.starts_with("time_s,rays,spp,rel_mse\n"), "{text}");
    }
}
