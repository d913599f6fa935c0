//! `kalos render`: the command line is built for the chosen method, so that
//! `--help` lists only its settings and a flag of another method is an error
//! that names both.

use std::ffi::OsString;
use std::path::PathBuf;
use std::time::Instant;

use anyhow::{bail, Context, Result};
use clap::error::{ContextKind, ContextValue, ErrorKind};
use clap::{Args, Command, FromArgMatches};
use indicatif::{ProgressBar, ProgressStyle};

use kalos::image_io::{self, PngOptions};
use kalos::methods::{self, cli as mcli, Budget, Common};
use kalos::metrics;
use kalos::partial::{self, Meta, Partial, Shard};
use kalos::render::{self, Render};

use crate::{
    check_output, load_scene, memory_limit, parse_res, read_hdr, set_threads, write_log, TonemapArg,
};

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

/// Runs `kalos render`.
pub fn run(a: RenderArgs, cfg: methods::MethodConfig) -> Result<()> {
    // Check what can be checked before spending any time: the settings,
    // the budget, the files to write (format, folder, permissions) and the
    // reference, so that a bad path fails now and not after the render.
    let common = Common {
        seed: a.seed,
        max_depth: a.max_depth,
    };
    cfg.check(&common)?;
    let mut budget = Budget {
        spp: a.spp,
        time: a.time,
        rays: a.rays,
        passes: None,
    };
    // Without a budget on the command line: the scene's own sample count
    // (Mitsuba's <sampler>, known once it is loaded), else 16 spp
    let default_budget = budget.spp.is_none() && budget.time.is_none() && budget.rays.is_none();
    if default_budget {
        budget.spp = Some(16.0);
    }
    budget.validate()?;
    // An image, or a partial result (what --shard writes)
    let partial_out = crate::extension(&a.output) == "kpart";
    if partial_out {
        check_output(&a.output, &["kpart"])?;
    } else {
        check_output(&a.output, &["exr", "pfm", "png"])?;
    }
    let shard = a.shard.unwrap_or(Shard::WHOLE);
    if partial_out {
        partial::check_shard(&cfg, shard)?;
    }
    if let Some(s) = a.shard {
        partial::check_shard(&cfg, s)?;
        if !partial_out {
            bail!(
                "--shard {s} writes a partial result: -o must end in .kpart (got '{}'); \
                 `kalos merge` makes the image from the parts",
                a.output.display()
            );
        }
    }
    if let Some(c) = &a.checkpoint {
        partial::check_resumable(&cfg)?;
        check_output(c, &["kpart"])?;
    }
    let resume = match &a.resume {
        Some(p) => {
            partial::check_resumable(&cfg)?;
            Some(partial::read(p)?)
        }
        None => None,
    };
    if let Some(log) = &a.log {
        check_output(log, &["csv"])?;
    }
    let reference = match &a.reference {
        Some(p) => Some(read_hdr(p)?),
        None => None,
    };
    if a.dry_run {
        crate::say!("{}: arguments accepted", cfg.name());
        return Ok(());
    }
    // The viewer's port is taken before the scene loads, so that a port in
    // use fails at once
    let mut live = match a.view {
        true => Some(crate::view::Live::start(
            a.port.unwrap_or(0),
            &a.output.display().to_string(),
        )?),
        false => None,
    };
    set_threads(a.threads)?;
    let t0 = Instant::now();
    let mut scene = load_scene(a.scene.as_deref(), &a.defines)?;
    if scene.emitters.is_empty() {
        bail!(
            "{}: the scene has no emitters, so the image would be black; add an <emitter> \
             (an area light on a shape, or <emitter type=\"constant\"/> for a white sky)",
            scene.source
        );
    }
    if let Some((w, h)) = a.res {
        scene.set_resolution(w, h);
    }
    let (w, h) = (scene.camera.width, scene.camera.height);
    if w == 0 || h == 0 {
        bail!("the film is {w}x{h}: an image needs at least one pixel (set --res)");
    }
    if let Some((limit, source)) = memory_limit(a.max_memory) {
        render::check_memory(&render::memory_estimate(&cfg, w, h), limit, &source)?;
    }
    if let (Some(r), Some(p)) = (&reference, &a.reference) {
        if (r.width, r.height) != (w, h) {
            bail!(
                "reference {} is {}x{} but the render is {w}x{h}",
                p.display(),
                r.width,
                r.height,
            );
        }
    }
    let world = crate::progress::build_world(scene);
    let load_s = t0.elapsed().as_secs_f64();
    // From here on the first SIGINT or SIGTERM saves what is rendered;
    // while loading there is nothing to save, and they end kalos at once.
    crate::signals::install();
    let cancel = crate::signals::cancel_flag();
    if world.lights.is_empty() {
        bail!(
            "{}: the scene's {} emitters emit no light (zero radiance, or on shapes with no area), \
             so the image would be black",
            world.scene.source,
            world.scene.emitters.len()
        );
    }
    let mut budget_note = None;
    if let (true, Some(n)) = (default_budget, world.scene.sample_count) {
        budget.spp = Some(n as f64);
        budget.validate()?;
        budget_note = Some(format!(" (the scene's sample_count {n})"));
    }
    let bar = if a.quiet {
        ProgressBar::hidden()
    } else {
        let b = ProgressBar::new(1000);
        b.set_style(
            ProgressStyle::with_template(
                "{spinner} [{elapsed_precise}] {bar:40} {percent:>3}% {msg} (ETA {eta})",
            )
            .unwrap_or_else(|_| ProgressStyle::default_bar()),
        );
        b
    };
    if let Some(l) = &mut live {
        l.set_reference(reference.clone());
    }
    // The render's identity (the scene hash reads every vertex): only
    // when a partial result is written or read
    let meta = if partial_out || a.checkpoint.is_some() || resume.is_some() {
        Some(Meta::new(&world.scene, &cfg, &common, shard)?)
    } else {
        None
    };
    if let (Some(r), Some(p), Some(m)) = (&resume, &a.resume, &meta) {
        check_resume(m, r, p)?;
    }
    // checkpoints written during the render, and the seconds they took
    let written = std::cell::Cell::new((0u32, 0.0f64));
    let mut save = |state: &partial::State| {
        if let (Some(c), Some(meta)) = (&a.checkpoint, &meta) {
            let t0 = Instant::now();
            // A failed checkpoint does not stop the render: the image is
            // still written at the end
            match partial::write(c, meta, state) {
                Ok(()) => {
                    let (n, s) = written.get();
                    written.set((n + 1, s + t0.elapsed().as_secs_f64()));
                }
                Err(e) => eprintln!("warning: checkpoint not written: {e}"),
            }
        }
    };
    let mut render = Render::new(&world)
        .method(cfg)
        .common(common)
        .budget(budget)
        .cancel(cancel)
        .shard(shard);
    if partial_out || a.checkpoint.is_some() {
        render = render.keep_state();
    }
    if a.checkpoint.is_some() {
        render = render.checkpoint(a.checkpoint_every, &mut save);
    }
    if let Some(r) = &resume {
        render = render.resume(&r.state);
    }
    if let Some(r) = &reference {
        render = render.reference(r, if a.log.is_some() { a.log_every } else { 0.0 });
    }
    if let Some(l) = &live {
        render = render.watch(1.0, |img, p| l.image(img, p));
    }
    let result = render.run(|p| {
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
        if let Some(l) = &live {
            l.progress(p);
        }
    });
    bar.finish_and_clear();
    let result = result.context("rendering")?;
    if let Some(l) = &live {
        l.finish(
            &result.image,
            &methods::Progress {
                passes: result.passes,
                rays: result.rays,
                elapsed: result.seconds,
                fraction: 1.0,
                phase: None,
            },
        );
    }
    if result.interrupted && result.passes == 0 {
        // Nothing to save, and a black image must not replace a good one.
        eprintln!("interrupted before the first pass: nothing written");
        return Ok(());
    }

    let png = PngOptions {
        exposure: a.exposure,
        tonemap: a.tonemap.into(),
    };
    let state = result.state.as_ref();
    if let (Some(c), Some(state), Some(meta)) = (&a.checkpoint, state, &meta) {
        partial::write(c, meta, state)?;
    }
    if let (true, Some(meta)) = (partial_out, &meta) {
        let state = state.context("the method gave no state to write as a partial result")?;
        partial::write(&a.output, meta, state)?;
    } else {
        image_io::write_image(&a.output, &result.image, &png)?;
    }
    if let Some(log) = &a.log {
        write_log(log, &result.log)?;
    }
    let mut line = format!(
        "{}: {} {}x{}, {:.1} spp{}, {} passes, {:.2} s (+{:.2} s load/build), {:.1} M rays, {:.2} Mrays/s",
        a.output.display(),
        result.method,
        result.image.width,
        result.image.height,
        result.spp,
        budget_note.as_deref().unwrap_or(""),
        result.passes,
        result.seconds,
        load_s,
        result.rays as f64 / 1e6,
        result.rays as f64 / result.seconds.max(1e-9) / 1e6
    );
    if let Some(r) = &reference {
        line += &format!(", relMSE {:.4e}", metrics::rel_mse(&result.image, r)?);
    }
    if a.shard.is_some() {
        line += &format!(", shard {shard}");
    }
    if let Some(p) = &a.resume {
        line += &format!(", resumed from {}", p.display());
    }
    if let Some(c) = &a.checkpoint {
        let (n, s) = written.get();
        line += &format!(", checkpoint {}", c.display());
        if n > 0 {
            line += &format!(
                " ({n} written during the render, {:.1} ms each)",
                s / n as f64 * 1e3
            );
        }
    }
    if result.interrupted {
        line += " (interrupted: saved what was rendered)";
    }
    crate::say!("{line}");
    if let Some(r) = &result.report {
        crate::say!("{r}");
    }
    Ok(())
}

/// Refuses a checkpoint `r` (read from `path`) that is not of this render,
/// naming what differs.
fn check_resume(meta: &Meta, r: &Partial, path: &std::path::Path) -> Result<()> {
    let name = format!("checkpoint {}", path.display());
    if let Some(d) = meta.difference("this render", &r.meta, &name) {
        bail!("{d}: a checkpoint resumes only the render that wrote it");
    }
    if r.meta.shard != meta.shard {
        bail!(
            "{name} is of shard {}, but this render is shard {}: a checkpoint resumes only the \
             render that wrote it",
            r.meta.shard,
            meta.shard
        );
    }
    Ok(())
}
