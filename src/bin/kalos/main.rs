//! The `kalos` command line: parses arguments, shows progress and writes
//! files. Everything else lives in the library.
#![deny(clippy::undocumented_unsafe_blocks)]

mod bake;
mod bench;
mod merge;
mod progress;
mod render;
mod signals;
mod view;

use std::ffi::OsString;
use std::path::{Path, PathBuf};

use anyhow::{bail, Context, Result};
use clap::{Args, Parser, Subcommand, ValueEnum};

use kalos::image_io::{self, PngOptions, Tonemap};
use kalos::methods;
use kalos::metrics;
use kalos::plot::{self, PlotOptions, XAxis};
use kalos::scene::{self, Scene};

/// `println!` that ends the process quietly when stdout is closed (as in
/// `kalos compare a b | head -1`) instead of panicking. Output files are
/// always written before anything is printed.
#[macro_export]
macro_rules! say {
    ($($t:tt)*) => {{
        use std::io::Write as _;
        if writeln!(std::io::stdout(), $($t)*).is_err() {
            std::process::exit(0);
        }
    }};
}

#[derive(Parser)]
#[command(
    name = "kalos",
    version,
    about = "Global illumination renderer and light baker"
)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Render a scene (Mitsuba XML, OBJ, PLY, glTF) to EXR, PFM or PNG;
    /// `kalos render --method NAME --help` lists a method's settings.
    #[command(disable_help_flag = true)]
    Render {
        /// The render's flags, parsed for the chosen method.
        #[arg(trailing_var_arg = true, allow_hyphen_values = true, num_args = 0..)]
        args: Vec<OsString>,
    },
    /// Compare an image with a reference: relMSE, RMSE, channel means.
    Compare(CompareArgs),
    /// Print what a scene holds: triangles, emitters, materials, bounds.
    Info {
        /// Scene file (omit for the built-in Cornell box).
        scene: Option<PathBuf>,
        #[command(flatten)]
        defines: Defines,
    },
    /// Plot convergence logs (CSV from `render --log`): error against time.
    Plot(PlotArgs),
    /// Measure the ray core's throughput (Mrays/s), one thread and all:
    /// incoherent rays, and recorded camera, bounce and shadow rays.
    Bench(bench::BenchArgs),
    /// Bake view-independent lighting by density estimation into a glTF
    /// binary display mesh (vertex colours), optionally an irradiance PLY.
    Bake(Box<bake::BakeArgs>),
    /// Show a baked mesh (.glb) or an HDR image (.exr, .pfm, .hdr) in the
    /// browser: serves a page on 127.0.0.1 and prints its address.
    View(view::ViewArgs),
    /// Merge the partial results of `render --shard K/N` into one image.
    Merge(merge::MergeArgs),
    /// Write a generated scene (sphereflake, teapot-room, terrain, big-room)
    /// as Mitsuba XML plus OBJ meshes.
    Gen {
        /// Scene name.
        #[arg(value_parser = clap::builder::PossibleValuesParser::new(GEN_SCENES))]
        name: String,
        /// Output directory.
        #[arg(short, long)]
        output: PathBuf,
        /// big-room: seed of the furniture layout.
        #[arg(long, default_value_t = 1)]
        seed: u64,
    },
}

/// The scenes `kalos gen` writes.
const GEN_SCENES: &[&str] = kalos::scenegen::NAMES;

#[derive(Clone, Copy, ValueEnum)]
enum TonemapArg {
    Clamp,
    Reinhard,
    Aces,
}

impl From<TonemapArg> for Tonemap {
    fn from(t: TonemapArg) -> Tonemap {
        match t {
            TonemapArg::Clamp => Tonemap::Clamp,
            TonemapArg::Reinhard => Tonemap::Reinhard,
            TonemapArg::Aces => Tonemap::Aces,
        }
    }
}

#[derive(Args)]
struct CompareArgs {
    /// The image to judge.
    image: PathBuf,
    /// The reference.
    reference: PathBuf,
    /// Write a false-colour relative-error image (PNG).
    #[arg(long)]
    error_image: Option<PathBuf>,
}

#[derive(Args)]
struct PlotArgs {
    /// Convergence logs (CSV), one curve each; label=FILE sets the legend.
    #[arg(required = true)]
    logs: Vec<String>,
    /// Output PNG.
    #[arg(short, long)]
    output: PathBuf,
    /// What the x axis shows.
    #[arg(long, value_enum, default_value = "time")]
    x: XArg,
    /// Plot title.
    #[arg(long, default_value = "")]
    title: String,
    /// Label of the y axis (the logs' last column), when it holds another
    /// error measure than the relative MSE.
    #[arg(long, default_value = "relative MSE")]
    y_label: String,
}

#[derive(Clone, Copy, ValueEnum)]
enum XArg {
    Time,
    Rays,
    Spp,
}

fn parse_res(s: &str) -> Result<(u32, u32), String> {
    let (w, h) = s
        .split_once(['x', 'X'])
        .ok_or_else(|| format!("expected WxH such as 512x512, got '{s}'"))?;
    let w: u32 = w
        .trim()
        .parse()
        .map_err(|_| format!("bad width in '{s}'"))?;
    let h: u32 = h
        .trim()
        .parse()
        .map_err(|_| format!("bad height in '{s}'"))?;
    if w == 0 || h == 0 || w > 16384 || h > 16384 {
        return Err(format!("resolution out of range (1..16384): '{s}'"));
    }
    Ok((w, h))
}

/// Mitsuba-style scene parameters, for every command that loads a scene.
#[derive(Args, Clone, Default)]
struct Defines {
    /// Set a scene parameter: fills `$NAME` in a Mitsuba scene, overriding
    /// its `<default name="NAME">` (repeatable).
    #[arg(short = 'D', value_name = "NAME=VALUE", value_parser = parse_define)]
    define: Vec<(String, String)>,
}

fn parse_define(s: &str) -> Result<(String, String), String> {
    match s.split_once('=') {
        Some((n, v)) if !n.trim().is_empty() => Ok((n.trim().to_string(), v.to_string())),
        _ => Err(format!("expected NAME=VALUE, got '{s}'")),
    }
}

fn load_scene(path: Option<&Path>, defines: &Defines) -> Result<Scene> {
    let builtin = path.is_none_or(|p| p.as_os_str() == "builtin");
    let s = match path {
        Some(p) if !builtin => progress::with_spinner(&format!("loading {}", p.display()), |_| {
            scene::load_with(p, &defines.define)
        })?,
        _ => scene::builtin::cornell_box_with(&defines.define)?,
    };
    // the built-in scene's own warnings (its skipped integrator) are known
    // and not the user's concern; an unused -D is
    for w in s
        .warnings
        .iter()
        .filter(|w| !builtin || w.contains(": -D "))
    {
        eprintln!("warning: {w}");
    }
    for n in &s.notes {
        eprintln!("note: {n}");
    }
    Ok(s)
}

fn main() {
    let cli = Cli::parse();
    let r = match cli.command {
        Command::Render { args } => render::parse(args).and_then(|(a, m)| render::run(a, m)),
        Command::Compare(a) => compare(a),
        Command::Info { scene, defines } => info(scene.as_deref(), &defines),
        Command::Plot(a) => plot_cmd(a),
        Command::Bench(a) => bench::run(a),
        Command::Bake(a) => bake::run(*a),
        Command::Merge(a) => merge::run(a),
        Command::Gen { name, output, seed } => gen_cmd(&name, &output, seed),
        Command::View(a) => view::run(a),
    };
    // An interrupted command exits with the signal's code (130, 143),
    // after it has saved what it had.
    let interrupted = signals::exit_code();
    if let Err(e) = r {
        eprintln!("error: {}", error_text(&e));
        std::process::exit(interrupted.unwrap_or(1));
    }
    if let Some(code) = interrupted {
        std::process::exit(code);
    }
}

/// The error and its causes on one line, each cause once: a library error
/// that already quotes its source (`"x.exr: Permission denied"`) is not
/// followed by the same words again, as `{:#}` would print them.
fn error_text(e: &anyhow::Error) -> String {
    let mut text = String::new();
    for cause in e.chain() {
        let s = cause.to_string();
        if text.contains(&s) {
            continue;
        }
        if !text.is_empty() {
            text += ": ";
        }
        text += &s;
    }
    text
}

/// The memory limit of a render and where it comes from: `--max-memory`
/// when given, else the machine's memory (Linux's `/proc/meminfo`), else
/// none.
fn memory_limit(flag: Option<u64>) -> Option<(u64, String)> {
    if let Some(m) = flag {
        return Some((m, "--max-memory".into()));
    }
    let text = std::fs::read_to_string("/proc/meminfo").ok()?;
    let total = kalos::render::mem_total(&text)?;
    Some((total, "this machine's memory".into()))
}

/// Checks an output file before any work: its extension is one of `exts`
/// (lower case, without the dot), and it can be written there
/// ([`image_io::check_writable`]).
fn check_output(path: &Path, exts: &[&str]) -> Result<()> {
    let ext = extension(path);
    if !exts.contains(&ext.as_str()) {
        let list: Vec<String> = exts.iter().map(|e| format!(".{e}")).collect();
        let list = match list.split_last() {
            Some((last, rest)) if !rest.is_empty() => format!("{} or {last}", rest.join(", ")),
            _ => list.join(""),
        };
        bail!("output '{}' must end in {list}", path.display());
    }
    image_io::check_writable(path)?;
    Ok(())
}

/// The lower-case extension of `path` ("" when it has none).
fn extension(path: &Path) -> String {
    path.extension()
        .and_then(|e| e.to_str())
        .map(str::to_ascii_lowercase)
        .unwrap_or_default()
}

/// Sizes the global thread pool when `--threads` is given.
fn set_threads(threads: Option<usize>) -> Result<()> {
    if let Some(t) = threads {
        rayon::ThreadPoolBuilder::new()
            .num_threads(t.max(1))
            .build_global()
            .context("setting the thread count")?;
    }
    Ok(())
}

fn write_log(path: &Path, rows: &[methods::LogRow]) -> Result<()> {
    let mut text = String::from("time_s,rays,spp,rel_mse\n");
    for r in rows {
        text += &format!(
            "{:.4},{},{:.3},{}\n",
            r.time_s,
            r.rays,
            r.spp,
            r.rel_mse.map(|e| format!("{e:.6e}")).unwrap_or_default()
        );
    }
    // atomic, like the images: a temporary file beside the target, then a rename
    image_io::write_atomic(path, |w| {
        use std::io::Write as _;
        w.write_all(text.as_bytes())
            .map_err(|source| image_io::ImageIoError::Io {
                path: path.to_path_buf(),
                source,
            })
    })?;
    Ok(())
}

/// Reads an image to measure or to measure against: linear radiance only
/// (EXR, PFM, Radiance HDR; a PNG or JPEG holds tone-mapped display values,
/// whose error against radiance means nothing), every pixel finite.
fn read_hdr(path: &Path) -> Result<kalos::film::Image> {
    let ext = extension(path);
    if !matches!(ext.as_str(), "exr" | "pfm" | "hdr") {
        bail!(
            "{}: not a linear HDR image; comparisons need .exr, .pfm or .hdr (a .{ext} holds \
             tone-mapped display values, not radiance)",
            path.display()
        );
    }
    let img = image_io::read_image(path)?;
    let bad = metrics::non_finite_pixels(&img);
    if bad > 0 {
        bail!(
            "{}: {bad} of its {} pixels are NaN or infinite, so every figure would be NaN",
            path.display(),
            img.data.len()
        );
    }
    Ok(img)
}

fn compare(a: CompareArgs) -> Result<()> {
    if let Some(out) = &a.error_image {
        check_output(out, &["png", "exr", "pfm"])?;
    }
    let img = read_hdr(&a.image)?;
    let r = read_hdr(&a.reference)?;
    if (img.width, img.height) != (r.width, r.height) {
        bail!(
            "{} is {}x{} but the reference {} is {}x{}",
            a.image.display(),
            img.width,
            img.height,
            a.reference.display(),
            r.width,
            r.height
        );
    }
    say!("{}", metrics::Comparison::new(&img, &r)?);
    if let Some(out) = &a.error_image {
        let e = metrics::false_color_error(&img, &r)?;
        image_io::write_image(out, &e, &PngOptions::default())?;
        say!("error image written to {}", out.display());
    }
    Ok(())
}

fn info(path: Option<&Path>, defines: &Defines) -> Result<()> {
    let s = load_scene(path, defines)?;
    say!("{}", scene::Summary(&s));
    Ok(())
}

fn plot_cmd(a: PlotArgs) -> Result<()> {
    let x = match a.x {
        XArg::Time => XAxis::TimeSeconds,
        XArg::Rays => XAxis::Rays,
        XArg::Spp => XAxis::Spp,
    };
    check_output(&a.output, &["png"])?;
    let mut series = Vec::new();
    for spec in &a.logs {
        let (label, file) = match spec.split_once('=') {
            Some((l, f)) => (l.to_string(), f.to_string()),
            None => (
                Path::new(spec)
                    .file_stem()
                    .map(|s| s.to_string_lossy().into_owned())
                    .unwrap_or_else(|| spec.clone()),
                spec.clone(),
            ),
        };
        series.push(plot::series_from_csv(Path::new(&file), &label, x)?);
    }
    let mut opts = PlotOptions::for_axis(x);
    opts.title = a.title;
    opts.y_label = a.y_label;
    plot::plot_convergence(&series, &a.output, &opts)?;
    say!("plot written to {}", a.output.display());
    Ok(())
}

fn gen_cmd(what: &str, output: &Path, seed: u64) -> Result<()> {
    let xml = kalos::scenegen::generate(what, output, seed)?;
    say!("wrote {}", xml.display());
    Ok(())
}
