//! The `kalos` command line: parses arguments, shows progress and writes
//! files. Everything else lives in the library.

use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::Instant;

use anyhow::{bail, Context, Result};
use clap::{Args, Parser, Subcommand, ValueEnum};
use indicatif::{ProgressBar, ProgressStyle};

use kalos::image_io::{self, PngOptions, Tonemap};
use kalos::methods::{self, Budget, Driver, Options, World};
use kalos::metrics;
use kalos::plot::{self, PlotOptions, XAxis};
use kalos::scene::{self, Scene};

/// `println!` that ends the process quietly when stdout is closed (as in
/// `kalos compare a b | head -1`) instead of panicking. Output files are
/// always written before anything is printed.
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
    /// Render a scene (Mitsuba XML, OBJ, PLY) to EXR, PFM or PNG.
    Render(Box<RenderArgs>),
    /// Compare an image with a reference: relMSE, RMSE, channel means.
    Compare(CompareArgs),
    /// Print what a scene holds: triangles, emitters, materials, bounds.
    Info {
        /// Scene file (omit for the built-in Cornell box).
        scene: Option<PathBuf>,
    },
    /// Plot convergence logs (CSV from `render --log`): error against time.
    Plot(PlotArgs),
    /// Measure the ray core's throughput (Mrays/s), one thread and all.
    Bench(BenchArgs),
    /// Bake view-independent lighting by density estimation into a glTF
    /// binary display mesh (vertex colours), optionally an irradiance PLY.
    Bake(BakeArgs),
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
const GEN_SCENES: &[&str] = &["sphereflake", "teapot-room", "terrain", "big-room"];

#[derive(Clone, Copy, ValueEnum)]
enum OnOff {
    On,
    Off,
}

#[derive(Args)]
struct BakeArgs {
    /// Scene file; omit (or say `builtin`) for the built-in Cornell box.
    scene: Option<PathBuf>,
    /// Output display mesh (.glb).
    #[arg(short, long, default_value = "out.glb")]
    output: PathBuf,
    /// Also write the irradiance mesh as PLY.
    #[arg(long)]
    ply: Option<PathBuf>,
    /// Keep the hit file at this path.
    #[arg(long)]
    hits: Option<PathBuf>,
    /// Directory for the hit file's buckets (default: the system temp dir).
    #[arg(long)]
    scratch: Option<PathBuf>,
    /// Most hit records held in memory at once (phase 2 and the bucket
    /// sort); a surface with more hits is streamed in chunks of this size.
    /// Accepts 2M. Default 2M.
    #[arg(long, value_parser = parse_count)]
    chunk_hits: Option<u64>,
    #[command(flatten)]
    density: DensityArgs,
    /// `rgb` (one pass, default) or `per-channel` (the paper's three runs).
    #[arg(long)]
    variant: Option<String>,
    /// Skip the decimation phase.
    #[arg(long)]
    no_decimate: bool,
    /// Random seed: the same seed gives the same hit file whatever --threads.
    #[arg(long, default_value_t = 0)]
    seed: u64,
    /// Worker threads (default: all cores).
    #[arg(long)]
    threads: Option<usize>,
    /// Longest particle path in segments; default unlimited.
    #[arg(long)]
    max_depth: Option<u32>,
    /// Print particles, hits, bytes per hit, time per phase, peak memory,
    /// triangles before and after decimation.
    #[arg(long)]
    stats: bool,
}

/// The density method's parameters, shared by `render` and `bake`.
#[derive(Args)]
struct DensityArgs {
    /// Density: particles traced (per channel run); accepts 4M, 96M.
    #[arg(long, value_parser = parse_count)]
    particles: Option<u64>,
    /// Density: kernel width h = C1·√(A/n) (paper: 10–40).
    #[arg(long)]
    c1: Option<f32>,
    /// Density: grid spacing C2·√(A/n) (paper: C1/10 – C1/2).
    #[arg(long)]
    c2: Option<f32>,
    /// Density: decimation error bound ε (Stevens brightness units).
    #[arg(long)]
    epsilon: Option<f32>,
}

#[derive(Clone, Copy, ValueEnum)]
enum TonemapArg {
    Clamp,
    Reinhard,
    Aces,
}

#[derive(Args)]
struct RenderArgs {
    /// Scene file; omit (or say `builtin`) for the built-in Cornell box.
    scene: Option<PathBuf>,
    /// Output image (.exr, .pfm or .png).
    #[arg(short, long, default_value = "out.exr")]
    output: PathBuf,
    /// Rendering method.
    #[arg(short, long, default_value = "path", value_parser = clap::builder::PossibleValuesParser::new(methods::METHODS))]
    method: String,
    /// Method variant (light: walk | iteration; density: rgb | per-channel; plb: paper | pooled).
    #[arg(long)]
    variant: Option<String>,
    /// Samples per pixel (light paths per pixel for the light-based methods).
    #[arg(long)]
    spp: Option<f64>,
    /// Time budget in seconds.
    #[arg(long)]
    time: Option<f64>,
    /// Ray budget (closest-hit and shadow rays together); accepts 30M, 2G.
    #[arg(long, value_parser = parse_count)]
    rays: Option<u64>,
    /// Random seed: the same seed gives the same image whatever --threads.
    #[arg(long, default_value_t = 0)]
    seed: u64,
    /// Worker threads (default: all cores).
    #[arg(long)]
    threads: Option<usize>,
    /// Override the film resolution, WxH.
    #[arg(long, value_parser = parse_res)]
    res: Option<(u32, u32)>,
    /// Longest path in segments (Mitsuba's max_depth); default unlimited.
    #[arg(long)]
    max_depth: Option<u32>,
    /// Iteration variants: steps discarded at the start of each chain
    /// (plb: phases discarded at the start of each lane).
    #[arg(long, default_value_t = 0)]
    discard: u64,
    /// Light-based methods: the camera pass for delta surfaces seen by the
    /// camera (on), or the raw method (off).
    #[arg(long, value_enum, default_value = "on")]
    camera_pass: OnOff,
    /// bundle: target number of patches.
    #[arg(long)]
    patches: Option<usize>,
    /// bundle: target patch edge length in scene units (overrides --patches).
    #[arg(long)]
    patch_edge: Option<f32>,
    /// bundle: global directions (random, halton, hammersley, frac).
    #[arg(long)]
    sequence: Option<String>,
    /// bundle: visibility-map resolution.
    #[arg(long)]
    map_res: Option<u32>,
    /// bundle: image estimate (phong, gouraud).
    #[arg(long)]
    bundle_image: Option<String>,
    /// bundle: visibility algorithm (painter, zbuffer).
    #[arg(long)]
    visibility: Option<String>,
    /// plb: λ, the weight of the children's image impact in the importance.
    #[arg(long)]
    lambda: Option<f32>,
    /// plb: steps per phase (default 400).
    #[arg(long)]
    phase_len: Option<u32>,
    /// plb: population cap after each purge (default 1000).
    #[arg(long)]
    population: Option<usize>,
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
    /// No progress bar.
    #[arg(short, long)]
    quiet: bool,
    #[command(flatten)]
    density: DensityArgs,
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
}

#[derive(Clone, Copy, ValueEnum)]
enum XArg {
    Time,
    Rays,
    Spp,
}

#[derive(Args)]
struct BenchArgs {
    /// Scene to trace (omit for a generated scene of about 1 M triangles).
    scene: Option<PathBuf>,
    /// Rays per measurement.
    #[arg(long, default_value_t = 4_000_000)]
    rays: u64,
    /// Triangles in the generated scene.
    #[arg(long, default_value_t = 1_000_000)]
    triangles: u64,
}

fn parse_count(s: &str) -> Result<u64, String> {
    let s = s.trim();
    let (num, mult) = match s.chars().last() {
        Some('k' | 'K') => (&s[..s.len() - 1], 1e3),
        Some('m' | 'M') => (&s[..s.len() - 1], 1e6),
        Some('g' | 'G') => (&s[..s.len() - 1], 1e9),
        _ => (s, 1.0),
    };
    let v: f64 = num
        .parse()
        .map_err(|_| format!("expected a count such as 1000000 or 30M, got '{s}'"))?;
    if !(v.is_finite() && v > 0.0) {
        return Err(format!("expected a positive count, got '{s}'"));
    }
    Ok((v * mult).round() as u64)
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

fn load_scene(path: Option<&Path>) -> Result<Scene> {
    match path {
        None => Ok(scene::builtin::cornell_box()?),
        Some(p) if p.as_os_str() == "builtin" => Ok(scene::builtin::cornell_box()?),
        Some(p) => {
            let s = scene::load(p)?;
            for w in &s.warnings {
                eprintln!("warning: {w}");
            }
            Ok(s)
        }
    }
}

fn main() {
    let cli = Cli::parse();
    let r = match cli.command {
        Command::Render(a) => render(*a),
        Command::Compare(a) => compare(a),
        Command::Info { scene } => info(scene.as_deref()),
        Command::Plot(a) => plot_cmd(a),
        Command::Bench(a) => bench(a),
        Command::Bake(a) => bake_cmd(a),
        Command::Gen { name, output, seed } => gen_cmd(&name, &output, seed),
    };
    if let Err(e) = r {
        eprintln!("error: {e:#}");
        std::process::exit(1);
    }
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

fn render(a: RenderArgs) -> Result<()> {
    // Check the output path before spending any time.
    let ext = extension(&a.output);
    if !matches!(ext.as_str(), "exr" | "pfm" | "png") {
        bail!(
            "output '{}' must end in .exr, .pfm or .png",
            a.output.display()
        );
    }
    set_threads(a.threads)?;
    let t0 = Instant::now();
    let mut scene = load_scene(a.scene.as_deref())?;
    if let Some((w, h)) = a.res {
        scene.set_resolution(w, h);
    }
    let reference = match &a.reference {
        Some(p) => {
            let r = image_io::read_image(p)?;
            if (r.width, r.height) != (scene.camera.width, scene.camera.height) {
                bail!(
                    "reference {} is {}x{} but the render is {}x{}",
                    p.display(),
                    r.width,
                    r.height,
                    scene.camera.width,
                    scene.camera.height
                );
            }
            Some(r)
        }
        None => None,
    };
    let world = World::new(scene);
    let load_s = t0.elapsed().as_secs_f64();
    if world.lights.is_empty() {
        eprintln!("warning: the scene has no emitters; the image will be black");
    }
    let opts = Options {
        seed: a.seed,
        max_depth: a.max_depth,
        variant: a.variant.clone(),
        discard: a.discard,
        camera_pass: matches!(a.camera_pass, OnOff::On),
        patches: a.patches,
        patch_edge: a.patch_edge,
        sequence: a.sequence.clone(),
        map_res: a.map_res,
        bundle_image: a.bundle_image.clone(),
        visibility: a.visibility.clone(),
        lambda: a.lambda,
        phase_len: a.phase_len,
        population: a.population,
        particles: a.density.particles,
        c1: a.density.c1,
        c2: a.density.c2,
        epsilon: a.density.epsilon,
    };
    let mut method = methods::create(&a.method, &world, &opts)?;
    let mut budget = Budget {
        spp: a.spp,
        time: a.time,
        rays: a.rays,
        passes: None,
    };
    if budget.spp.is_none() && budget.time.is_none() && budget.rays.is_none() {
        budget.spp = Some(16.0);
    }

    let cancel = Arc::new(AtomicBool::new(false));
    {
        let c = cancel.clone();
        // A second Ctrl-C while saving is left to the default handler.
        let _ = ctrlc::set_handler(move || {
            if c.swap(true, Ordering::SeqCst) {
                std::process::exit(130);
            }
        });
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
    let driver = Driver {
        budget,
        cancel: Some(&cancel),
        reference: reference.as_ref(),
        log_every: if a.log.is_some() { a.log_every } else { 0.0 },
    };
    let result = driver.run(method.as_mut(), &world, |p| {
        bar.set_position((p.fraction * 1000.0) as u64);
        let mrays = if p.elapsed > 0.0 {
            p.rays as f64 / p.elapsed / 1e6
        } else {
            0.0
        };
        bar.set_message(format!("{} passes, {:.2} Mrays/s", p.passes, mrays));
    })?;
    bar.finish_and_clear();

    let png = PngOptions {
        exposure: a.exposure,
        tonemap: match a.tonemap {
            TonemapArg::Clamp => Tonemap::Clamp,
            TonemapArg::Reinhard => Tonemap::Reinhard,
            TonemapArg::Aces => Tonemap::Aces,
        },
    };
    image_io::write_image(&a.output, &result.image, &png)?;
    if let Some(log) = &a.log {
        write_log(log, &result.log)?;
    }
    let mut line = format!(
        "{}: {} {}x{}, {:.1} spp, {} passes, {:.2} s (+{:.2} s load/build), {:.1} M rays, {:.2} Mrays/s",
        a.output.display(),
        method.name(),
        result.image.width,
        result.image.height,
        result.spp,
        result.passes,
        result.seconds,
        load_s,
        result.rays as f64 / 1e6,
        result.rays as f64 / result.seconds.max(1e-9) / 1e6
    );
    if let Some(r) = &reference {
        line += &format!(", relMSE {:.4e}", metrics::rel_mse(&result.image, r)?);
    }
    if result.interrupted {
        line += " (interrupted: saved what was rendered)";
    }
    say!("{line}");
    if let Some(r) = method.report() {
        say!("{r}");
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
    // atomic: a temporary file beside the target, then a rename
    let tmp = path.with_extension(format!("csv.tmp-{}", std::process::id()));
    std::fs::write(&tmp, text.as_bytes())
        .and_then(|_| std::fs::rename(&tmp, path))
        .with_context(|| format!("writing {}", path.display()))?;
    Ok(())
}

fn compare(a: CompareArgs) -> Result<()> {
    let img = image_io::read_image(&a.image)?;
    let r = image_io::read_image(&a.reference)?;
    let rel = metrics::rel_mse(&img, &r)?;
    let rmse = metrics::rmse(&img, &r)?;
    let mi = metrics::channel_means(&img);
    let mr = metrics::channel_means(&r);
    say!("relMSE  {rel:.6e}");
    say!("RMSE    {rmse:.6e}");
    say!("relL1   {:.6e}", metrics::rel_l1(&img, &r)?);
    say!(
        "means   image ({:.6}, {:.6}, {:.6})  reference ({:.6}, {:.6}, {:.6})",
        mi.x,
        mi.y,
        mi.z,
        mr.x,
        mr.y,
        mr.z
    );
    if let Some(out) = &a.error_image {
        let e = metrics::false_color_error(&img, &r)?;
        image_io::write_image(out, &e, &PngOptions::default())?;
        say!("error image written to {}", out.display());
    }
    Ok(())
}

fn info(path: Option<&Path>) -> Result<()> {
    let s = load_scene(path)?;
    let (lo, hi) = s.bounds();
    say!("scene      {}", s.source);
    say!("triangles  {}", s.triangles.len());
    say!("vertices   {}", s.positions.len());
    say!("shapes     {}", s.shapes.len());
    say!("materials  {}", s.materials.len());
    for (i, m) in s.materials.iter().enumerate() {
        say!("  [{i}] {}", material_name(m));
    }
    say!("emitters   {}", s.emitters.len());
    for e in &s.emitters {
        match e {
            scene::EmitterDesc::Area { shape, radiance } => say!(
                "  area on '{}', radiance ({}, {}, {})",
                s.shapes[*shape as usize].name,
                radiance.x,
                radiance.y,
                radiance.z
            ),
            scene::EmitterDesc::Constant { radiance } => {
                say!(
                    "  constant, radiance ({}, {}, {})",
                    radiance.x,
                    radiance.y,
                    radiance.z
                )
            }
            scene::EmitterDesc::EnvMap { image, scale, .. } => {
                say!("  envmap {}x{}, scale {scale}", image.width, image.height)
            }
        }
    }
    say!(
        "bounds     ({}, {}, {}) .. ({}, {}, {})",
        lo.x,
        lo.y,
        lo.z,
        hi.x,
        hi.y,
        hi.z
    );
    say!(
        "camera     {}x{}, fov_x {:.3} deg",
        s.camera.width,
        s.camera.height,
        s.camera.fov_x_deg
    );
    Ok(())
}

fn material_name(m: &scene::Material) -> String {
    use scene::Material as M;
    match m {
        M::Diffuse { .. } => "diffuse".into(),
        M::Phong { .. } => "phong".into(),
        M::Conductor { .. } => "conductor".into(),
        M::RoughConductor { .. } => "roughconductor".into(),
        M::Plastic { .. } => "plastic".into(),
        M::RoughPlastic { .. } => "roughplastic".into(),
        M::Dielectric { .. } => "dielectric".into(),
        M::ThinDielectric { .. } => "thindielectric".into(),
        M::TwoSided(inner) => format!("twosided({})", material_name(inner)),
    }
}

fn plot_cmd(a: PlotArgs) -> Result<()> {
    let x = match a.x {
        XArg::Time => XAxis::TimeSeconds,
        XArg::Rays => XAxis::Rays,
        XArg::Spp => XAxis::Spp,
    };
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
    plot::plot_convergence(&series, &a.output, &opts)?;
    say!("plot written to {}", a.output.display());
    Ok(())
}

fn bench(a: BenchArgs) -> Result<()> {
    let scene = match &a.scene {
        Some(p) => load_scene(Some(p))?,
        None => kalos::bench::generated_scene(a.triangles),
    };
    say!(
        "scene: {} ({} triangles)",
        scene.source,
        scene.triangles.len()
    );
    let t = Instant::now();
    let world = World::new(scene);
    say!("BVH build: {:.2} s", t.elapsed().as_secs_f64());
    let one = kalos::bench::incoherent_closest_hits(&world, a.rays, 1);
    let all_threads = rayon::current_num_threads();
    let all = kalos::bench::incoherent_closest_hits(&world, a.rays, all_threads);
    say!(
        "incoherent closest hits, 1 thread:  {:.2} Mrays/s ({} hits of {} rays)",
        one.mrays_per_s,
        one.hits,
        one.rays
    );
    say!(
        "incoherent closest hits, {all_threads} threads: {:.2} Mrays/s (ratio {:.2}x)",
        all.mrays_per_s,
        all.mrays_per_s / one.mrays_per_s
    );
    Ok(())
}

/// Peak resident memory of this process (VmHWM), in bytes, when known.
fn peak_memory() -> Option<u64> {
    let text = std::fs::read_to_string("/proc/self/status").ok()?;
    let line = text.lines().find(|l| l.starts_with("VmHWM:"))?;
    let kb: u64 = line.split_whitespace().nth(1)?.parse().ok()?;
    Some(kb * 1024)
}

fn bake_cmd(a: BakeArgs) -> Result<()> {
    use kalos::methods::density;
    let ext = extension(&a.output);
    if ext != "glb" {
        bail!("output '{}' must end in .glb", a.output.display());
    }
    set_threads(a.threads)?;
    let t0 = Instant::now();
    let world = World::new(load_scene(a.scene.as_deref())?);
    let load_s = t0.elapsed().as_secs_f64();
    if world.lights.is_empty() {
        bail!("the scene has no emitters: nothing to bake");
    }
    let opts = Options {
        seed: a.seed,
        max_depth: a.max_depth,
        variant: a.variant.clone(),
        particles: a.density.particles,
        c1: a.density.c1,
        c2: a.density.c2,
        epsilon: a.density.epsilon,
        ..Default::default()
    };
    let mut s = density::Settings::from_options(&opts)?;
    s.decimate = !a.no_decimate;
    s.keep_hits = a.hits.clone();
    s.scratch = a.scratch.clone();
    if let Some(c) = a.chunk_hits {
        s.chunk_hits = usize::try_from(c).unwrap_or(usize::MAX);
    }
    let b = density::bake(&world, &s)?;
    let t1 = Instant::now();
    let (lit, other) = b.baked_meshes(&world.scene);
    kalos::bake::gltf::write_glb(&a.output, &lit, &other, b.w0)?;
    if let Some(p) = &a.ply {
        kalos::bake::ply::write_ply(p, &lit)?;
    }
    let write_s = t1.elapsed().as_secs_f64();
    let st = &b.stats;
    say!(
        "{}: {} triangles ({} before decimation), white point {:.4e} W/(m²·sr)",
        a.output.display(),
        st.tris_after,
        st.tris_before,
        b.w0
    );
    if a.stats {
        let total = st.t_trace + st.t_estimate + st.t_decimate;
        let pct = |t: f64| if total > 0.0 { 100.0 * t / total } else { 0.0 };
        say!("particles        {}", st.particles);
        say!("hits             {}", st.hits);
        say!("bytes per hit    {}", st.bytes_per_hit);
        say!("hit file         {:.1} MB", st.hit_file_bytes as f64 / 1e6);
        say!("surfaces         {}", st.surfaces);
        say!("load + BVH       {load_s:.2} s");
        say!(
            "phase 1 trace    {:.2} s ({:.0}%)",
            st.t_trace,
            pct(st.t_trace)
        );
        say!(
            "phase 2 estimate {:.2} s ({:.0}%)",
            st.t_estimate,
            pct(st.t_estimate)
        );
        say!(
            "phase 3 decimate {:.2} s ({:.0}%)",
            st.t_decimate,
            pct(st.t_decimate)
        );
        say!("write            {write_s:.2} s");
        say!("triangles before {}", st.tris_before);
        say!(
            "triangles after  {} ({:.1}% removed)",
            st.tris_after,
            if st.tris_before > 0 {
                100.0 * (1.0 - st.tris_after as f64 / st.tris_before as f64)
            } else {
                0.0
            }
        );
        say!(
            "brightness error max {:.4}, mean {:.4} (epsilon {})",
            st.max_brightness_error,
            st.mean_brightness_error,
            s.epsilon
        );
        say!(
            "hits in memory   {} at most in phase 2, {} in the bucket sort (chunk {})",
            st.max_hits_in_memory,
            st.max_sort_records,
            s.chunk_hits
        );
        match peak_memory() {
            Some(m) => say!("peak memory      {:.1} MB", m as f64 / 1e6),
            None => say!("peak memory      unknown"),
        }
    }
    Ok(())
}

fn gen_cmd(what: &str, output: &Path, seed: u64) -> Result<()> {
    match what {
        "big-room" => {
            let n = kalos::bake::gen::big_room(output, seed)?;
            say!("{}: big-room with {n} triangles", output.display());
            Ok(())
        }
        other => scene::gen::generate(other, output)
            .map(|p| say!("wrote {}", p.display()))
            .with_context(|| format!("writing {}", output.display())),
    }
}
