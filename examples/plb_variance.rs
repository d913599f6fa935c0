//! Variance across seeds, for the plb experiments in BENCHMARKS-plb.md.
//!
//! Renders a scene K times with seeds 1…K under the same budget and prints
//! the mean over pixels (and channels) of the per-pixel variance across the
//! seeds (`metrics::PixelStats::mean_variance`), the mean rays and seconds
//! per render, and the image mean.
//!
//! ```text
//! cargo run --release --example plb_variance -- SCENE METHOD K (rays=N|time=S|passes=N) [lambda=L] [phase=P] [pop=C] [discard=D] [variant=V]
//! ```

use std::time::Instant;

use kalos::methods::{self, Budget, Driver, Options, World};
use kalos::metrics::{channel_means, PixelStats};

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().collect();
    if args.len() < 5 {
        return Err("usage: SCENE METHOD K (rays=N|time=S|passes=N) [lambda=L] [phase=P] [pop=C] [discard=D] [variant=V]".into());
    }
    let scene = kalos::scene::load(std::path::Path::new(&args[1]))?;
    let method = args[2].as_str();
    let k: u64 = args[3].parse()?;
    let mut budget = Budget::default();
    let mut opts = Options::default();
    for a in &args[4..] {
        let (key, v) = a.split_once('=').ok_or("expected key=value")?;
        match key {
            "rays" => budget.rays = Some(v.parse::<f64>()? as u64),
            "time" => budget.time = Some(v.parse()?),
            "passes" => budget.passes = Some(v.parse()?),
            "lambda" => opts.lambda = Some(v.parse()?),
            "phase" => opts.phase_len = Some(v.parse()?),
            "pop" => opts.population = Some(v.parse()?),
            "discard" => opts.discard = v.parse()?,
            "variant" => opts.variant = Some(v.to_string()),
            _ => return Err(format!("unknown key '{key}'").into()),
        }
    }
    let world = World::new(scene);
    let mut stats = PixelStats::new(world.camera.width, world.camera.height);
    let (mut rays, mut secs) = (0u64, 0.0f64);
    let mut mean = glam::DVec3::ZERO;
    for seed in 1..=k {
        let o = Options {
            seed,
            ..opts.clone()
        };
        let mut m = methods::create(method, &world, &o)?;
        let driver = Driver {
            budget,
            cancel: None,
            reference: None,
            log_every: 0.0,
        };
        let t = Instant::now();
        let r = driver.run(m.as_mut(), &world, |_| {}).expect("render");
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
