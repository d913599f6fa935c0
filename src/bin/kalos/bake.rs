//! `kalos bake`: view-independent lighting by density estimation, written
//! as a glTF binary display mesh (and optionally an irradiance PLY).

use std::path::PathBuf;
use std::time::Instant;

use anyhow::{bail, Result};
use clap::Args;
use indicatif::{ProgressBar, ProgressStyle};

use kalos::methods::density::control::{Control, Limits, Phase, Tick};
use kalos::methods::density::dataflow::{self, DataflowError, Workers};
use kalos::methods::density::{DensityError, Storage};
use kalos::methods::{density, MethodConfig};

use crate::{check_output, load_scene, say, set_threads};

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
    /// The density method's settings.
    #[command(flatten)]
    density: density::Settings,
    #[command(flatten)]
    dataflow: DataflowArgs,
}

/// The flags of a bake on timely dataflow (threads or processes).
#[derive(Args)]
struct DataflowArgs {
    /// Bake on a timely dataflow of N worker threads (per process with
    /// --processes): hits exchanged by surface, each worker estimating and
    /// decimating its own surfaces; the same bytes as without.
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

/// Runs `kalos bake`.
pub fn run(a: BakeArgs) -> Result<()> {
    check_output(&a.output, &["glb"])?;
    if let Some(p) = &a.ply {
        check_output(p, &["ply"])?;
    }
    let s = density::Settings {
        seed: a.seed,
        max_depth: a.max_depth,
        ..a.density.clone()
    };
    s.validate()?;
    if let Some((limit, source)) = crate::memory_limit(a.max_memory) {
        // no film: only the bake's own buffers
        let items = kalos::render::memory_estimate(&MethodConfig::Density(s.clone()), 0, 0);
        kalos::render::check_memory(&items, limit, &source)?;
    }
    if a.max_depth == Some(0) {
        bail!("--max-depth must be at least 1 (1 shows only the emitters, 2 adds direct light)");
    }
    let layout = a.dataflow.layout()?;
    set_threads(a.threads)?;
    let t0 = Instant::now();
    let world = std::sync::Arc::new(crate::progress::build_world(load_scene(
        a.scene.as_deref(),
        &a.defines,
    )?));
    let load_s = t0.elapsed().as_secs_f64();
    if world.lights.is_empty() {
        bail!("the scene has no emitters: nothing to bake");
    }

    // Ctrl-C and SIGTERM stop the bake between units of work, so that its
    // scratch directory is removed before the process exits (with 128 + the
    // signal); a second one exits at once
    crate::signals::install();
    let cancel = crate::signals::cancel_flag();
    let mut bars = PhaseBars::new(a.quiet);
    let mut on_tick = |t: &Tick| bars.tick(t);
    let mut ctl =
        Control::new(Instant::now(), Limits::default(), Some(cancel)).on_tick(&mut on_tick);
    let baked = match &layout {
        None => density::bake_within(&world, &s, Storage::Disk, &mut ctl).map(Some),
        Some(w) => match dataflow::bake_dataflow(world.clone(), &s, w, &mut ctl) {
            Ok(d) => {
                if a.stats && d.hits_sent > 0 {
                    say!(
                        "exchanged        {} hits to other workers, {:.2} bytes per hit",
                        d.hits_sent,
                        d.bytes_sent as f64 / d.hits_sent as f64
                    );
                }
                Ok(d.bake)
            }
            Err(DataflowError::Density(e)) => Err(e),
            Err(e) => {
                bars.clear();
                return Err(e.into());
            }
        },
    };
    let b = match baked {
        Ok(Some(b)) => b,
        Ok(None) => {
            bars.finish();
            say!(
                "this process's part of the bake is done; process 0 writes {}",
                a.output.display()
            );
            return Ok(());
        }
        Err(DensityError::Cancelled { .. }) => {
            bars.clear();
            eprintln!(
                "interrupted: the bake was stopped and its scratch files removed; nothing written"
            );
            std::process::exit(crate::signals::exit_code().unwrap_or(130));
        }
        Err(e) => {
            bars.clear();
            return Err(e.into());
        }
    };
    bars.start("writing", 0, "");
    let t1 = Instant::now();
    let (lit, other) = b.baked_meshes(&world.scene);
    kalos::bake::gltf::write_glb(&a.output, &lit, &other, b.w0, Some(&world.scene.camera))?;
    if let Some(p) = &a.ply {
        kalos::bake::ply::write_ply(p, &lit)?;
    }
    let write_s = t1.elapsed().as_secs_f64();
    bars.finish();
    let st = &b.stats;
    say!(
        "{}: {} triangles ({} before decimation), white point {:.4e} W/(m²·sr)",
        a.output.display(),
        st.tris_after,
        st.tris_before,
        b.w0
    );
    if a.stats {
        say!("{st}");
        say!(
            "settings         epsilon {}, chunk {} hits",
            s.epsilon,
            s.chunk_hits
        );
        say!("load + BVH       {load_s:.2} s");
        say!("write            {write_s:.2} s");
        match peak_memory() {
            Some(m) => say!("peak memory      {:.1} MB", m as f64 / 1e6),
            None => say!("peak memory      unknown"),
        }
    }
    Ok(())
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
            };
            let len = if t.phase == Phase::Group { 0 } else { t.total };
            self.start(name, len, unit);
        }
        if let Some((bar, ..)) = &self.bar {
            bar.set_position(t.done);
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
