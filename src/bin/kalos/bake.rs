//! `kalos bake`: view-independent lighting by density estimation, written
//! as a glTF binary display mesh (and optionally an irradiance PLY).

use std::path::PathBuf;
use std::time::Instant;

use anyhow::{bail, Result};
use clap::Args;

use kalos::methods::density;

use crate::{extension, load_scene, say, set_threads};

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
    /// Print particles, hits, bytes per hit, time per phase, peak memory,
    /// triangles before and after decimation.
    #[arg(long)]
    stats: bool,
    /// The density method's settings.
    #[command(flatten)]
    density: density::Settings,
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
    let ext = extension(&a.output);
    if ext != "glb" {
        bail!("output '{}' must end in .glb", a.output.display());
    }
    let s = density::Settings {
        seed: a.seed,
        max_depth: a.max_depth,
        ..a.density.clone()
    };
    s.validate()?;
    if a.max_depth == Some(0) {
        bail!("--max-depth must be at least 1 (1 shows only the emitters, 2 adds direct light)");
    }
    set_threads(a.threads)?;
    let t0 = Instant::now();
    let world = crate::progress::build_world(load_scene(a.scene.as_deref())?);
    let load_s = t0.elapsed().as_secs_f64();
    if world.lights.is_empty() {
        bail!("the scene has no emitters: nothing to bake");
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
