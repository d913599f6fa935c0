//! `kalos bake`: view-independent lighting by density estimation, written
//! as a glTF binary display mesh (and optionally an irradiance PLY).

use std::path::PathBuf;
use std::time::Instant;

use anyhow::{bail, Result};
use clap::Args;
use indicatif::{ProgressBar, ProgressStyle};

use kalos::bake::job::{BakeError, BakeEvent, BakeJob, BakeOutcome, Baked};
use kalos::bake::lightmap::bake::{LightmapBake, LightmapError, LightmapSettings};
use kalos::bake::lightmap::{estimate, gather};
use kalos::job::SceneInput;
use kalos::methods::density;
use kalos::methods::density::control::{Phase, Tick};
use kalos::methods::density::dataflow::Workers;
use kalos::methods::density::DensityError;

use crate::view::LiveBake;
use crate::{progress, say, signals};

/// The flags of `kalos bake`.
#[derive(Args)]
pub struct BakeArgs {
    /// Scene file; omit (or say `builtin`) for the built-in Cornell box.
    scene: Option<PathBuf>,
    /// Output display mesh (.glb).
    #[arg(short, long, default_value = "out.glb")]
    output: PathBuf,
    /// Also write the irradiance mesh as PLY.
    #[arg(long)]
    ply: Option<PathBuf>,
    #[command(flatten)]
    defines: crate::Defines,
    #[command(flatten)]
    env: crate::EnvArgs,
    /// Random seed: the same seed gives the same hit file whatever --threads.
    #[arg(long, default_value_t = 0)]
    seed: u64,
    /// Worker threads (default: all cores).
    #[arg(long)]
    threads: Option<usize>,
    /// Longest path in segments (Mitsuba's max_depth: 2 = direct light
    /// only); default unlimited.
    #[arg(long)]
    max_depth: Option<u32>,
    /// Most memory the bake may plan to use; accepts 8G, 500M (default:
    /// this machine's memory).
    #[arg(long, value_parser = kalos::methods::cli::parse_count)]
    max_memory: Option<u64>,
    /// Print particles, hits, bytes per hit, time per phase, peak memory,
    /// triangles before and after decimation.
    #[arg(long)]
    stats: bool,
    /// No progress on stderr.
    #[arg(short, long)]
    quiet: bool,
    /// Stop tracing particles when the bake would not end within this
    /// many seconds (loading included); default: every particle.
    #[arg(long, value_name = "SECONDS")]
    time: Option<f64>,
    /// Stop tracing particles before this many rays; accepts 10M.
    #[arg(long, value_parser = kalos::methods::cli::parse_count)]
    rays: Option<u64>,
    #[command(flatten)]
    lightmap: LightmapArgs,
    /// The density method's settings.
    #[command(flatten)]
    density: density::Settings,
    #[command(flatten)]
    dataflow: DataflowArgs,
}

/// The flags of a lightmap bake.
#[derive(Args)]
struct LightmapArgs {
    /// Bake a lightmap: the irradiance of every diffuse surface in an HDR
    /// atlas on a second uv set, with per-texel standard errors, instead
    /// of the display mesh. -o names the .glb: the asset whole, with
    /// TEXCOORD_1 and the atlas (MOZ_lightmap); the float atlas is written
    /// beside it (OUT.lightmap.exr).
    #[arg(long)]
    lightmap: bool,
    /// Texels per metre (per scene unit) of the atlas.
    #[arg(
        long,
        value_name = "D",
        requires = "lightmap",
        conflicts_with = "lightmap_size"
    )]
    texel_density: Option<f32>,
    /// The atlas's side in texels (default 512).
    #[arg(long, value_name = "N", requires = "lightmap")]
    lightmap_size: Option<u32>,
    /// Pack a generated uv set's charts by rows instead of by their shapes:
    /// much faster with thousands of charts (a large scene), a less dense
    /// atlas. `--stats` shows the time of the uv set.
    #[arg(long, requires = "lightmap")]
    fast_packing: bool,
    /// Write each texel's standard error (linear RGB) to this .exr.
    #[arg(long, value_name = "FILE.exr", requires = "lightmap")]
    lightmap_error: Option<PathBuf>,
    /// A fixed k for the estimator: each texel's kernel reaches its k-th
    /// nearest hit (relative error about √(1.8/k) whatever the particle
    /// count, blur growing with k). Without it k grows with the hits, so
    /// that the error falls with time.
    #[arg(long, value_name = "K", requires = "lightmap")]
    neighbours: Option<usize>,
    /// c of the estimator's adaptive k = c·m^(2/3), m the hits per texel
    /// at the texel: larger is smoother and more biased.
    #[arg(
        long,
        value_name = "C",
        default_value_t = estimate::GROWTH,
        requires = "lightmap",
        conflicts_with = "neighbours"
    )]
    growth: f32,
    /// Visibility rays per texel, cutting the kernel at walls (0: none).
    #[arg(long, value_name = "N", default_value_t = 12, requires = "lightmap")]
    sectors: usize,
    /// The final gather from the density atlas, N indirect rays per texel
    /// (default 64): each texel's direct light by light sampling, its
    /// indirect light by rays reading the atlas one bounce away, combined
    /// with the density estimate by inverse variance (docs/lightmaps.md).
    /// `--gather 0 --gather-lights 0`: no gather, the atlas is the density
    /// estimate (the paper's method).
    #[arg(long, value_name = "N", num_args = 0..=1, default_value_t = gather::DEFAULT_RAYS,
          default_missing_value = "64", requires = "lightmap")]
    gather: u32,
    /// Light samples per texel of the final gather (default: as many as
    /// --gather's rays).
    #[arg(long, value_name = "N", requires = "lightmap")]
    gather_lights: Option<u32>,
    /// Show the lightmap refining in the browser as the bake runs (`kalos
    /// view`'s page; the address is printed): the asset first, then a
    /// preview of the atlas from the particles so far every few seconds
    /// (at most a fifth of the bake's time), then the final atlas. The .glb
    /// is written as without --view, and the page stays up until Ctrl-C.
    #[arg(long, requires = "lightmap")]
    view: bool,
    /// The viewer's port on 127.0.0.1 (default: a free one); needs --view.
    #[arg(long, value_name = "N", requires = "view")]
    port: Option<u16>,
    /// Seconds of tracing between two previews, at least (slow previews
    /// are spaced further, so that they take at most a fifth of the
    /// bake); needs --view.
    #[arg(long, value_name = "SECONDS", default_value_t = 2.0, requires = "view")]
    view_every: f64,
}

/// The flags of a bake on timely dataflow (threads or processes).
#[derive(Args)]
struct DataflowArgs {
    /// Bake on a timely dataflow of N worker threads (per process with
    /// --processes): hits exchanged by surface, large surfaces cut into
    /// tiles shared by the workers; the same bytes as without.
    #[arg(long, value_name = "N")]
    workers: Option<usize>,
    /// This process's index, from 0, in a bake across processes (needs
    /// --processes and --hostfile); process 0 writes the output.
    #[arg(long, value_name = "I", requires_all = ["processes", "hostfile"])]
    process: Option<usize>,
    /// Processes in a bake across processes.
    #[arg(long, value_name = "N", requires_all = ["process", "hostfile"])]
    processes: Option<usize>,
    /// The processes' addresses, one host:port a line, in process order.
    #[arg(long, value_name = "FILE", requires_all = ["process", "processes"])]
    hostfile: Option<PathBuf>,
}

impl DataflowArgs {
    /// The dataflow's layout; None for the single-process bake.
    fn layout(&self) -> Result<Option<Workers>> {
        let threads = self.workers.unwrap_or(1);
        if threads == 0 {
            bail!("--workers must be at least 1");
        }
        match (self.process, self.processes, &self.hostfile) {
            (Some(p), Some(n), Some(file)) => Ok(Some(Workers::cluster(threads, p, n, file)?)),
            _ if self.workers.is_some() => Ok(Some(Workers::Threads(threads))),
            _ => Ok(None),
        }
    }
}

/// Peak resident memory of this process (VmHWM), in bytes, when known.
fn peak_memory() -> Option<u64> {
    let text = std::fs::read_to_string("/proc/self/status").ok()?;
    let line = text.lines().find(|l| l.starts_with("VmHWM:"))?;
    let kb: u64 = line.split_whitespace().nth(1)?.parse().ok()?;
    Some(kb * 1024)
}

/// Runs `kalos bake`: the library's [`BakeJob`] does the work; this shows
/// its progress and prints its figures.
pub fn run(a: BakeArgs) -> Result<()> {
    let checked = job(&a)?.check()?;
    let layout = a.dataflow.layout()?;
    if layout.is_some() && (a.time.is_some() || a.rays.is_some()) {
        bail!("--time and --rays stop a bake in one process; a bake across workers traces every particle: give --particles instead");
    }
    if layout.is_some() && a.lightmap.view {
        bail!("a lightmap bake across workers is not shown live: drop --view, or --workers, --process and --processes");
    }
    // The viewer's port is taken before the scene loads, so that a port in
    // use fails at once
    let live = match a.lightmap.view {
        true => Some(LiveBake::start(
            a.lightmap.port.unwrap_or(0),
            &a.output.display().to_string(),
        )?),
        false => None,
    };
    let live = live.as_ref();
    let mut setup = progress::Setup::default();
    let mut bars = PhaseBars::new(a.quiet);
    let outcome = checked.run(layout.as_ref(), Some(signals::cancel_flag()), &mut |e| {
        if let Some(l) = live {
            l.event(&e);
        }
        match e {
            BakeEvent::Setup(s) => setup.event(s),
            BakeEvent::Started => {
                setup.finish();
                // Ctrl-C and SIGTERM stop the bake between units of work,
                // so that its scratch directory is removed before the
                // process exits (with 128 + the signal); a second one
                // exits at once
                signals::install();
            }
            BakeEvent::Tick(t) => bars.tick(t),
            BakeEvent::Texels { done, total } => bars.texels(done, total),
            // the live view's alone
            BakeEvent::Asset(_) | BakeEvent::Previewing { .. } | BakeEvent::Preview { .. } => {}
            BakeEvent::Exchanged { hits, bytes } => {
                if a.stats && hits > 0 {
                    say!(
                        "exchanged        {hits} hits to other workers, {:.2} bytes per hit",
                        bytes as f64 / hits as f64
                    );
                }
            }
            BakeEvent::Writing => bars.start("writing", 0, ""),
        }
    });
    setup.finish();
    let outcome = match outcome {
        Ok(o) => o,
        Err(
            BakeError::Density(DensityError::Cancelled { .. })
            | BakeError::Lightmap(LightmapError::Density(DensityError::Cancelled { .. })),
        ) => {
            bars.clear();
            eprintln!(
                "interrupted: the bake was stopped and its scratch files removed; nothing written"
            );
            std::process::exit(signals::exit_code().unwrap_or(130));
        }
        Err(e) => {
            bars.clear();
            return Err(e.into());
        }
    };
    bars.finish();
    if let Some(lm) = &outcome.lightmap {
        if let Some(l) = live {
            l.finish(&lm.lightmap, lm.stats.particles);
        }
        print_lightmap(&a, lm, &outcome, live);
        if let Some(l) = live {
            l.serve_until_signal();
            // the bake is written: closing its viewer is no interruption
            std::process::exit(0);
        }
        return Ok(());
    }
    match &outcome.baked {
        Some(b) => print_figures(&a, b, &outcome),
        None => say!(
            "this process's part of the bake is done; process 0 writes {}",
            a.output.display()
        ),
    }
    Ok(())
}

/// The bake the arguments ask for.
fn job(a: &BakeArgs) -> Result<BakeJob> {
    let l = &a.lightmap;
    let lightmap = if l.lightmap {
        Some(LightmapSettings {
            texel_density: l.texel_density,
            size: l.lightmap_size,
            fast_packing: l.fast_packing,
            atlas: None,
            error: l.lightmap_error.clone(),
            estimator: estimate::Options {
                neighbours: l.neighbours,
                growth: l.growth,
                sectors: l.sectors,
                ..Default::default()
            },
            gather: gather::GatherOptions {
                rays: l.gather,
                lights: l.gather_lights.unwrap_or(l.gather),
                seed: 0,
            },
        })
    } else {
        None
    };
    Ok(BakeJob {
        scene: SceneInput::File {
            path: a.scene.clone(),
            defines: a.defines.define.clone(),
            allow_read: a.defines.allow_read.clone(),
            res: None,
            env: a.env.environment(),
        },
        settings: density::Settings {
            seed: a.seed,
            max_depth: a.max_depth,
            ..a.density.clone()
        },
        glb: Some(a.output.clone()),
        ply: a.ply.clone(),
        threads: a.threads,
        max_memory: a.max_memory,
        max_memory_flag: "--max-memory",
        lightmap,
        time: a.time,
        rays: a.rays,
        watch_every: l.view.then_some(l.view_every),
    })
}

/// A lightmap bake's line, and with `--stats` its figures.
fn print_lightmap(a: &BakeArgs, lm: &LightmapBake, o: &BakeOutcome, live: Option<&LiveBake>) {
    let st = &lm.stats;
    let m = &lm.lightmap;
    for w in &lm.uv.warnings {
        eprintln!("warning: {w}");
    }
    say!(
        "{}: {}×{} lightmap, {} texels, {} particles, {} hits",
        a.output.display(),
        m.width,
        m.height,
        st.texels,
        st.particles,
        st.hits
    );
    if a.stats {
        say!("rays             {}", st.rays);
        say!("uv + texels      {:.2} s", st.t_uv);
        say!("trace            {:.2} s", st.t_trace);
        say!("group + index    {:.2} s", st.t_index);
        say!("estimate texels  {:.2} s", st.t_estimate);
        if st.gather_rays > 0 {
            say!(
                "gather           {} rays, {} texels hidden (back faces seen)",
                st.gather_rays,
                st.gather_hidden
            );
        }
        if let Some(b) = st.balance() {
            say!("balance: {b:.3} (the most loaded worker's texel estimates over the mean)");
            for (i, w) in st.workers.iter().enumerate() {
                say!(
                    "  worker {i:<3} {} texels, {} estimates, {} hits (halo {} in {} rounds)",
                    w.texels,
                    w.estimates,
                    w.hits,
                    w.halo,
                    w.rounds
                );
            }
        }
        if let Some((n, secs)) = live.map(|l| l.previews()) {
            say!("live previews    {n}, {secs:.2} s (within trace)");
        }
        say!("load + BVH       {:.2} s", o.load_seconds);
        say!("write            {:.2} s", o.write_seconds);
        match peak_memory() {
            Some(m) => say!("peak memory      {:.1} MB", m as f64 / 1e6),
            None => say!("peak memory      unknown"),
        }
    }
}

/// The bake's line, and with `--stats` its figures.
fn print_figures(a: &BakeArgs, b: &Baked, o: &BakeOutcome) {
    let st = &b.bake.stats;
    say!(
        "{}: {} triangles ({} before decimation), white point {:.4e} W/(m²·sr)",
        a.output.display(),
        st.tris_after,
        st.tris_before,
        b.bake.w0
    );
    if a.stats {
        say!("{st}");
        say!(
            "settings         epsilon {}, chunk {} hits",
            a.density.epsilon,
            a.density.chunk_hits
        );
        say!("load + BVH       {:.2} s", o.load_seconds);
        say!("write            {:.2} s", o.write_seconds);
        match peak_memory() {
            Some(m) => say!("peak memory      {:.1} MB", m as f64 / 1e6),
            None => say!("peak memory      unknown"),
        }
    }
}

/// One progress bar per phase of the bake, on stderr (hidden with `-q` or
/// when stderr is not a terminal); a finished phase leaves one line.
struct PhaseBars {
    quiet: bool,
    bar: Option<(ProgressBar, &'static str, Instant)>,
}

impl PhaseBars {
    fn new(quiet: bool) -> Self {
        PhaseBars { quiet, bar: None }
    }

    /// Starts a bar for `name`, of `len` units (a spinner when 0).
    fn start(&mut self, name: &'static str, len: u64, unit: &str) {
        self.finish();
        if self.quiet {
            return;
        }
        let template = if len > 0 {
            format!("{{spinner}} {name:<18} [{{elapsed_precise}}] {{bar:40}} {{pos}}/{{len}} {unit} (ETA {{eta}})")
        } else {
            format!("{{spinner}} {name:<18} [{{elapsed_precise}}]")
        };
        let bar = ProgressBar::new(len);
        bar.set_style(
            ProgressStyle::with_template(&template)
                .unwrap_or_else(|_| ProgressStyle::default_bar()),
        );
        bar.enable_steady_tick(std::time::Duration::from_millis(200));
        self.bar = Some((bar, name, Instant::now()));
    }

    /// Moves the bar of the tick's phase, starting it on a new phase.
    fn tick(&mut self, t: &Tick) {
        let name = t.phase.name();
        if self.bar.as_ref().is_none_or(|b| b.1 != name) {
            let unit = match t.phase {
                Phase::Trace => "particles",
                Phase::Group => "",
                Phase::Estimate => "hits",
                Phase::Decimate => "surfaces",
                Phase::Gather => "texels",
            };
            let len = if t.phase == Phase::Group { 0 } else { t.total };
            self.start(name, len, unit);
        }
        if let Some((bar, ..)) = &self.bar {
            bar.set_position(t.done);
        }
    }

    /// Moves the bar of a lightmap's texels.
    fn texels(&mut self, done: u64, total: u64) {
        if self.bar.as_ref().is_none_or(|b| b.1 != "estimating texels") {
            self.start("estimating texels", total, "texels");
        }
        if let Some((bar, ..)) = &self.bar {
            bar.set_position(done);
        }
    }

    /// Leaves the current phase as one line with its time.
    fn finish(&mut self) {
        if let Some((bar, name, t0)) = self.bar.take() {
            bar.finish_and_clear();
            eprintln!("{name:<18} {:.2} s", t0.elapsed().as_secs_f64());
        }
    }

    /// Removes the current bar without a line.
    fn clear(&mut self) {
        if let Some((bar, ..)) = self.bar.take() {
            bar.finish_and_clear();
        }
    }
}
