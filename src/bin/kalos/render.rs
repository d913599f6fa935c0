//! `kalos render`: the command line is built for the chosen method, so that
//! `--help` lists only its settings and a flag of another method is an error
//! that names both.

use std::ffi::OsString;
use std::path::PathBuf;

use anyhow::Result;
use clap::error::{ContextKind, ContextValue, ErrorKind};
use clap::{Args, Command, FromArgMatches};
use indicatif::{ProgressBar, ProgressStyle};

use kalos::image_io::PngOptions;
use kalos::job::{Reference, RenderEvent, RenderJob, RenderOutcome, SceneInput};
use kalos::methods::{self, cli as mcli, Budget, Common};
use kalos::partial::Shard;

use crate::view::Live;
use crate::{parse_res, progress, signals, TonemapArg};

/// The flags every method shares.
#[derive(Args)]
pub struct RenderArgs {
    /// Scene file (Mitsuba XML, OBJ, PLY, glTF); omit (or say `builtin`)
    /// for the built-in Cornell box.
    scene: Option<PathBuf>,
    /// Output image (.exr, .pfm or .png), or a partial result (.kpart) to
    /// merge with `kalos merge` (what --shard writes).
    #[arg(short, long, default_value = "out.exr")]
    output: PathBuf,
    /// Samples per pixel (light paths per pixel for the light-based
    /// methods). Default 16 when no budget is given.
    #[arg(long, value_parser = mcli::parse_positive)]
    spp: Option<f64>,
    /// Time budget in seconds.
    #[arg(long, value_parser = mcli::parse_positive)]
    time: Option<f64>,
    /// Ray budget (closest-hit and shadow rays together); accepts 30M, 2G.
    #[arg(long, value_parser = mcli::parse_count)]
    rays: Option<u64>,
    #[command(flatten)]
    defines: crate::Defines,
    #[command(flatten)]
    env: crate::EnvArgs,
    /// Random seed: the same seed gives the same image whatever --threads.
    #[arg(long, default_value_t = 0)]
    seed: u64,
    /// Worker threads (default: all cores).
    #[arg(long)]
    threads: Option<usize>,
    /// Override the film resolution, WxH.
    #[arg(long, value_parser = parse_res)]
    res: Option<(u32, u32)>,
    /// Longest path in segments (Mitsuba's max_depth: 1 = emitters seen
    /// directly, 2 = direct light); default unlimited.
    #[arg(long)]
    max_depth: Option<u32>,
    /// Reference image, for the convergence log and the final error.
    #[arg(long = "ref")]
    reference: Option<PathBuf>,
    /// Write a convergence log (time_s,rays,spp,rel_mse) to this CSV file.
    #[arg(long)]
    log: Option<PathBuf>,
    /// Seconds between convergence-log rows.
    #[arg(long, default_value_t = 1.0)]
    log_every: f64,
    /// PNG exposure in stops.
    #[arg(long, default_value_t = 0.0)]
    exposure: f32,
    /// PNG tone mapping.
    #[arg(long, value_enum, default_value = "clamp")]
    tonemap: TonemapArg,
    /// Most memory the render may plan to use, checked before anything
    /// large is allocated; accepts 8G, 500M (default: this machine's
    /// memory).
    #[arg(long, value_parser = mcli::parse_count)]
    max_memory: Option<u64>,
    /// No progress bar.
    #[arg(short, long)]
    quiet: bool,
    /// Show the render as it converges in the browser (`kalos view`'s page,
    /// updated about once a second); the address is printed.
    #[arg(long)]
    view: bool,
    /// The viewer's port on 127.0.0.1 (default: a free one); needs --view.
    #[arg(long, requires = "view")]
    port: Option<u16>,
    /// Render only shard K of N (K from 0), to a partial result (-o
    /// NAME.kpart) that `kalos merge` combines with the others.
    #[arg(long, value_name = "K/N", value_parser = Shard::parse)]
    shard: Option<Shard>,
    /// Write the render's state to this file (.kpart) every
    /// --checkpoint-every seconds, on Ctrl-C and at the end, atomically.
    #[arg(long, value_name = "FILE")]
    checkpoint: Option<PathBuf>,
    /// Seconds between checkpoints.
    #[arg(long, value_name = "S", default_value_t = 300.0, value_parser = mcli::parse_positive)]
    checkpoint_every: f64,
    /// Continue from a checkpoint of the same render (same scene,
    /// method, settings, seed, shard); the budget is the whole render's.
    #[arg(long, value_name = "FILE")]
    resume: Option<PathBuf>,
    /// Check the arguments and the method's settings, then exit without
    /// loading the scene or rendering (to vet a job before it is queued).
    #[arg(long)]
    dry_run: bool,
}

/// The `render` command for `method`: the shared flags, `--method`, and the
/// method's own settings.
fn command(method: &str) -> Result<Command> {
    let info = methods::by_name(method)?;
    let mut others = String::from("Other methods have other settings; see them with:");
    for m in methods::all() {
        others += &format!("\n  kalos render --method {} --help", m.name);
    }
    let cmd = Command::new("render")
        .bin_name("kalos render")
        .allow_negative_numbers(true)
        .after_help(others);
    let cmd = RenderArgs::augment_args(cmd).arg(mcli::method_arg());
    // a one-time string for the life of the process
    let heading: &'static str = Box::leak(format!("Settings of '{}'", info.name).into_boxed_str());
    let cmd = cmd.next_help_heading(heading);
    // the settings type's own doc would otherwise be the command's about
    Ok((info.args)(cmd).about(format!(
        "Render a scene with method '{}': {}",
        info.name, info.about
    )))
}

/// Parses `args` (what follows `kalos render`) for the method they name.
pub fn parse(args: Vec<OsString>) -> Result<(RenderArgs, methods::MethodConfig)> {
    let method = mcli::scan_method(&args).unwrap_or_else(|| "path".to_string());
    // An unknown method is parsed as `path`'s command, whose --method
    // parser reports the bad value with the list of methods
    let info = methods::by_name(&method).unwrap_or(&methods::all()[0]);
    let matches = match command(info.name)?
        .try_get_matches_from(std::iter::once(OsString::from("render")).chain(args))
    {
        Ok(m) => m,
        Err(e) => {
            if e.kind() == ErrorKind::UnknownArgument {
                if let Some(ContextValue::String(flag)) = e.get(ContextKind::InvalidArg) {
                    if let Some(msg) = mcli::foreign_flag_message(info.name, flag) {
                        eprintln!("error: {msg}");
                        std::process::exit(2);
                    }
                }
            }
            e.exit()
        }
    };
    let a = RenderArgs::from_arg_matches(&matches).unwrap_or_else(|e| e.exit());
    let cfg = (info.from_args)(&matches).unwrap_or_else(|e| e.exit());
    Ok((a, cfg))
}

/// Runs `kalos render`: the library's [`RenderJob`] does the work; this
/// shows its progress and prints its figures.
pub fn run(a: RenderArgs, cfg: methods::MethodConfig) -> Result<()> {
    let name = cfg.name();
    let checked = job(&a, cfg).check()?;
    if a.dry_run {
        crate::say!("{name}: arguments accepted");
        return Ok(());
    }
    // The viewer's port is taken before the scene loads, so that a port in
    // use fails at once
    let mut live = match a.view {
        true => Some(Live::start(
            a.port.unwrap_or(0),
            &a.output.display().to_string(),
        )?),
        false => None,
    };
    if let Some(l) = &mut live {
        l.set_reference(checked.reference().cloned());
    }
    let mut shown = Shown::new(a.quiet, live.as_ref());
    let outcome = checked.run(Some(signals::cancel_flag()), &mut |e| shown.event(e));
    shown.clear();
    let outcome = outcome?;
    if !outcome.written {
        // Nothing to save, and a black image must not replace a good one.
        eprintln!("interrupted before the first pass: nothing written");
        return Ok(());
    }
    crate::say!("{}", summary(&a, &outcome));
    if let Some(r) = &outcome.result.report {
        crate::say!("{r}");
    }
    Ok(())
}

/// The render the arguments ask for.
fn job(a: &RenderArgs, method: methods::MethodConfig) -> RenderJob {
    RenderJob {
        scene: SceneInput::File {
            path: a.scene.clone(),
            defines: a.defines.define.clone(),
            allow_read: a.defines.allow_read.clone(),
            res: a.res,
            env: a.env.environment(),
        },
        method,
        common: Common {
            seed: a.seed,
            max_depth: a.max_depth,
        },
        budget: Budget {
            spp: a.spp,
            time: a.time,
            rays: a.rays,
            passes: None,
        },
        output: Some(a.output.clone()),
        png: PngOptions {
            exposure: a.exposure,
            tonemap: a.tonemap.into(),
        },
        shard: a.shard,
        checkpoint: a.checkpoint.clone(),
        checkpoint_every: a.checkpoint_every,
        resume: a.resume.clone(),
        reference: a.reference.clone().map(Reference::File),
        log: a.log.clone(),
        log_every: if a.log.is_some() { a.log_every } else { 0.0 },
        watch_every: a.view.then_some(1.0),
        threads: a.threads,
        max_memory: a.max_memory,
        max_memory_flag: "--max-memory",
    }
}

/// What `kalos render` shows while its job runs: the setup's spinners, a
/// progress bar on stderr (hidden with `-q`), and the live viewer's updates.
struct Shown<'l> {
    quiet: bool,
    setup: progress::Setup,
    bar: Option<ProgressBar>,
    live: Option<&'l Live>,
}

impl<'l> Shown<'l> {
    fn new(quiet: bool, live: Option<&'l Live>) -> Self {
        Shown {
            quiet,
            setup: progress::Setup::default(),
            bar: None,
            live,
        }
    }

    fn event(&mut self, e: RenderEvent) {
        match e {
            RenderEvent::Setup(s) => self.setup.event(s),
            RenderEvent::Started => {
                self.setup.finish();
                // From here on the first SIGINT or SIGTERM saves what is
                // rendered; while loading there is nothing to save, and
                // they end kalos at once.
                signals::install();
                self.bar = Some(progress_bar(self.quiet));
            }
            RenderEvent::Progress(p) => {
                if let Some(bar) = &self.bar {
                    show_progress(bar, p);
                }
                if let Some(l) = self.live {
                    l.progress(p);
                }
            }
            RenderEvent::Image(img, p) => {
                if let Some(l) = self.live {
                    l.image(img, p);
                }
            }
            RenderEvent::CheckpointFailed(e) => {
                eprintln!("warning: checkpoint not written: {e}")
            }
            RenderEvent::Rendered(r) => {
                self.clear();
                if let Some(l) = self.live {
                    let p = methods::Progress {
                        passes: r.passes,
                        rays: r.rays,
                        elapsed: r.seconds,
                        fraction: 1.0,
                        phase: None,
                    };
                    l.finish(&r.image, &p);
                }
            }
        }
    }

    /// Clears the spinner or the bar.
    fn clear(&mut self) {
        self.setup.finish();
        if let Some(bar) = self.bar.take() {
            bar.finish_and_clear();
        }
    }
}

/// The render's progress bar on stderr (hidden with `-q`).
fn progress_bar(quiet: bool) -> ProgressBar {
    if quiet {
        return ProgressBar::hidden();
    }
    let b = ProgressBar::new(1000);
    b.set_style(
        ProgressStyle::with_template(
            "{spinner} [{elapsed_precise}] {bar:40} {percent:>3}% {msg} (ETA {eta})",
        )
        .unwrap_or_else(|_| ProgressStyle::default_bar()),
    );
    b
}

/// Moves the bar to `p`: the fraction of the budget, the phase or the
/// passes, and the ray rate.
fn show_progress(bar: &ProgressBar, p: &methods::Progress) {
    bar.set_position((p.fraction * 1000.0) as u64);
    let mrays = if p.elapsed > 0.0 {
        p.rays as f64 / p.elapsed / 1e6
    } else {
        0.0
    };
    bar.set_message(match p.phase {
        Some(phase) => format!("{phase}, {:.2} Mrays/s", mrays),
        None => format!("{} passes, {:.2} Mrays/s", p.passes, mrays),
    });
}

/// The line printed once the outputs are written: the render's figures,
/// and what it wrote or read besides the image.
fn summary(a: &RenderArgs, o: &RenderOutcome) -> String {
    let r = &o.result;
    let budget_note = o
        .scene_sample_count
        .map(|n| format!(" (the scene's sample_count {n})"));
    let mut line = format!(
        "{}: {} {}x{}, {:.1} spp{}, {} passes, {:.2} s (+{:.2} s load/build), {:.1} M rays, {:.2} Mrays/s",
        a.output.display(),
        r.method,
        r.image.width,
        r.image.height,
        r.spp,
        budget_note.as_deref().unwrap_or(""),
        r.passes,
        r.seconds,
        o.load_seconds,
        r.rays as f64 / 1e6,
        r.rays as f64 / r.seconds.max(1e-9) / 1e6
    );
    if let Some(e) = o.rel_mse {
        line += &format!(", relMSE {e:.4e}");
    }
    if let Some(s) = a.shard {
        line += &format!(", shard {s}");
    }
    if let Some(p) = &a.resume {
        line += &format!(", resumed from {}", p.display());
    }
    if let Some(c) = &a.checkpoint {
        line += &format!(", checkpoint {}", c.display());
        let n = o.checkpoints;
        if n > 0 {
            line += &format!(
                " ({n} written during the render, {:.1} ms each)",
                o.checkpoint_seconds / n as f64 * 1e3
            );
        }
    }
    if r.interrupted {
        line += " (interrupted: saved what was rendered)";
    }
    line
}
