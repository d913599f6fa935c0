//! The `kalos` command line: parses arguments, shows progress and writes
//! files. Everything else lives in the library.
#![deny(clippy::undocumented_unsafe_blocks)]
// std::fs is denied only in the scene loaders (see clippy.toml)
#![allow(clippy::disallowed_methods)]

mod bake;
mod bench;
mod merge;
mod progress;
mod render;
mod signals;
mod view;

use std::ffi::OsString;
use std::path::{Path, PathBuf};

use anyhow::{bail, Result};
use clap::{Args, CommandFactory, FromArgMatches, Parser, Subcommand, ValueEnum};

use kalos::image_io::{self, PngOptions, Tonemap};
use kalos::job;
use kalos::metrics;
use kalos::outputs::{check_output, extension, read_hdr};
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
    /// Let the scene read files under DIR too (repeatable). By default a
    /// scene may read only the files under its own folder.
    #[arg(long = "allow-read", value_name = "DIR")]
    allow_read: Vec<PathBuf>,
}

impl Defines {
    /// The load options they give, with the machine's memory as the limit.
    fn options(&self) -> kalos::scene::LoadOptions {
        kalos::scene::LoadOptions {
            defines: self.define.clone(),
            read: kalos::scene::ReadPolicy {
                allow_read: self.allow_read.clone(),
                memory_limit: job::memory_limit(None, "--max-memory"),
            },
        }
    }
}

/// An environment for a scene that carries no sky, for `render` and `bake`.
#[derive(Args, Clone, Default)]
struct EnvArgs {
    /// Light the scene with a latitude-longitude environment map (linear
    /// .exr, .hdr or .pfm; Mitsuba's `envmap` orientation, +y up). For
    /// scenes without an environment: one that has a sky is refused
    #[arg(long, value_name = "FILE", conflicts_with = "env_constant")]
    env: Option<PathBuf>,
    /// Multiplier of the --env map's radiance
    #[arg(long, value_name = "S", default_value_t = 1.0, requires = "env")]
    env_scale: f32,
    /// Light the scene with a uniform environment of radiance R,G,B
    /// (W/(m²·sr); one value for grey), as Mitsuba's `constant` emitter. For
    /// scenes without an environment: one that has a sky is refused
    #[arg(
        long,
        value_name = "R,G,B",
        allow_hyphen_values = true,
        value_parser = kalos::scene::Environment::parse_constant
    )]
    env_constant: Option<kalos::scene::Rgb>,
}

impl EnvArgs {
    /// The environment asked for, if any.
    fn environment(&self) -> Option<kalos::scene::Environment> {
        use kalos::scene::Environment;
        match (&self.env, self.env_constant) {
            (Some(path), _) => Some(Environment::Map {
                path: path.clone(),
                scale: self.env_scale,
            }),
            (None, Some(c)) => Some(Environment::Constant(c)),
            (None, None) => None,
        }
    }
}

fn parse_define(s: &str) -> Result<(String, String), String> {
    match s.split_once('=') {
        Some((n, v)) if !n.trim().is_empty() => Ok((n.trim().to_string(), v.to_string())),
        _ => Err(format!("expected NAME=VALUE, got '{s}'")),
    }
}

/// Loads a scene for `info` and `bench` (a spinner while a file loads),
/// printing its warnings and notes.
fn load_scene(path: Option<&Path>, defines: &Defines) -> Result<Scene> {
    let loaded = match path {
        Some(p) if !job::is_builtin(path) => {
            progress::with_spinner(&format!("loading {}", p.display()), |_| {
                job::load_scene(path, &defines.options())
            })?
        }
        _ => job::load_scene(path, &defines.options())?,
    };
    for w in &loaded.warnings {
        eprintln!("warning: {w}");
    }
    for n in &loaded.notes {
        eprintln!("note: {n}");
    }
    Ok(loaded.scene)
}

fn main() {
    let matches = Cli::command().get_matches();
    let cli = Cli::from_arg_matches(&matches).unwrap_or_else(|e| e.exit());
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
