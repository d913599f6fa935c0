//! Variance across seeds, for the plb experiments in docs/notebook/plb.md.
//!
//! Renders a scene K times with seeds 1…K under the same budget and prints
//! the mean over pixels (and channels) of the per-pixel variance across the
//! seeds (`metrics::PixelStats::mean_variance`), the mean rays and seconds
//! per render, and the image mean.
//!
//! ```text
//! cargo run --release --example plb_variance -- SCENE METHOD K (rays=N|time=S|passes=N) [METHOD FLAGS...]
//! ```
//!
//! The method's flags are those of `kalos render --method METHOD`, e.g.
//! `--lambda 2 --variant pooled` for plb; the short forms `lambda=L`,
//! `phase=P`, `pop=C`, `discard=D` and `variant=V` that docs/notebook/plb.md
//! records are read as those flags.

#![allow(clippy::disallowed_methods)] // std::fs is denied only in the scene loaders (clippy.toml)
use std::time::Instant;

use kalos::methods::{self, Budget, Common, World};
use kalos::metrics::{channel_means, PixelStats};
use kalos::render::Render;

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().collect();
    if args.len() < 5 {
        return Err("usage: SCENE METHOD K (rays=N|time=S|passes=N) [METHOD FLAGS...]".into());
    }
    let scene = kalos::scene::load(std::path::Path::new(&args[1]))?;
    let method = args[2].as_str();
    let k: u64 = args[3].parse()?;
    let mut budget = Budget::default();
    let (key, v) = args[4]
        .split_once('=')
        .ok_or("expected rays=N, time=S or passes=N")?;
    match key {
        "rays" => budget.rays = Some(v.parse::<f64>()? as u64),
        "time" => budget.time = Some(v.parse()?),
        "passes" => budget.passes = Some(v.parse()?),
        _ => return Err(format!("unknown budget '{key}'").into()),
    }
    // The method's own flags, parsed as `kalos render --method METHOD` does
    let info = methods::by_name(method).map_err(|e| e.to_string())?;
    let mut flags = Vec::new();
    for a in &args[5..] {
        let long = |f: &str, v: &str| [format!("--{f}"), v.to_string()];
        match a.split_once('=') {
            Some(("lambda", v)) => flags.extend(long("lambda", v)),
            Some(("phase", v)) => flags.extend(long("phase-len", v)),
            Some(("pop", v)) => flags.extend(long("population", v)),
            Some(("discard", v)) => flags.extend(long("discard", v)),
            Some(("variant", v)) => flags.extend(long("variant", v)),
            _ => flags.push(a.clone()),
        }
    }
    let matches = (info.args)(clap::Command::new(info.name).no_binary_name(true))
        .try_get_matches_from(&flags)?;
    let cfg = (info.from_args)(&matches)?;
    let world = World::new(scene);
    let mut stats = PixelStats::new(world.camera.width, world.camera.height);
    let (mut rays, mut secs) = (0u64, 0.0f64);
    let mut mean = glam::DVec3::ZERO;
    for seed in 1..=k {
        let t = Instant::now();
        let r = Render::new(&world)
            .method(cfg.clone())
            .common(Common {
                seed,
                max_depth: None,
            })
            .budget(budget)
            .run(|_| {})?;
        secs += t.elapsed().as_secs_f64();
        rays += r.rays;
        mean += channel_means(&r.image);
        stats.add(&r.image)?;
    }
    let kf = k as f64;
    println!(
        "{method} {}: mean_var {:.4e}  rays/render {:.2}M  s/render {:.2}  mean ({:.5}, {:.5}, {:.5})",
        args[4..].join(" "),
        stats.mean_variance()?,
        rays as f64 / kf / 1e6,
        secs / kf,
        mean.x / kf,
        mean.y / kf,
        mean.z / kf
    );
    Ok(())
}
