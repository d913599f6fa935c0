//! Equal-time and equal-ray comparisons of several methods on one scene,
//! for the plb evaluation in docs/notebook/plb.md (issue #12).
//!
//! ```text
//! cargo run --release --features cli --example plb_eval -- SCENE K BUDGETS METHODS [ref=IMAGE] [region=BOXES] [csv=PREFIX]
//! ```
//!
//! - `BUDGETS`: comma-separated `time=S` or `rays=N` (e.g. `time=1,time=4`).
//! - `METHODS`: `;`-separated method command lines, e.g.
//!   `path;light;plb --variant paper;plb`.
//! - `ref=IMAGE`: also report relMSE against this reference (the mean over
//!   the K renders).
//! - `region=x0,y0,z0,x1,y1,z1[/…]`: boxes in world space; a pixel is in the
//!   region when the primary ray through its centre first hits a point
//!   inside one of them. Errors are then reported for the region and for
//!   the rest as well.
//! - `csv=PREFIX`: per method, a file PREFIX-N.csv (N its position in
//!   METHODS) in the layout of `kalos render --log` (time_s, rays, spp,
//!   rel_mse), one row per budget, with the reference's relMSE (or, with no
//!   reference, the mean variance) in the last column, for `kalos plot`.
//!
//! For each budget the K seeds run in turn, and within a seed every method,
//! so that a shared machine's load falls on all methods alike. The error
//! measures are the mean over pixels and channels of the per-pixel variance
//! across the K seeds, and, with a reference, the mean relMSE of the
//! renders.

#![allow(clippy::disallowed_methods)] // std::fs is denied only in the scene loaders (clippy.toml)
use std::io::Write;
use std::time::Instant;

use glam::{DVec3, Vec3};
use kalos::film::Image;
use kalos::image_io::read_image;
use kalos::methods::{self, Budget, Common, MethodConfig, World};
use kalos::render::Render;

type Boxes = Vec<(Vec3, Vec3)>;

fn parse_boxes(s: &str) -> Result<Boxes, Box<dyn std::error::Error>> {
    s.split('/')
        .map(|b| {
            let v: Vec<f32> = b
                .split(',')
                .map(|x| x.trim().parse::<f32>())
                .collect::<Result<_, _>>()?;
            if v.len() != 6 {
                return Err("a box is x0,y0,z0,x1,y1,z1".into());
            }
            Ok((Vec3::new(v[0], v[1], v[2]), Vec3::new(v[3], v[4], v[5])))
        })
        .collect()
}

fn method(line: &str) -> Result<MethodConfig, Box<dyn std::error::Error>> {
    let mut words = line.split_whitespace();
    let name = words.next().ok_or("empty method")?;
    let info = methods::by_name(name).map_err(|e| e.to_string())?;
    let flags: Vec<&str> = words.collect();
    let m = (info.args)(clap::Command::new(info.name).no_binary_name(true))
        .try_get_matches_from(&flags)?;
    Ok((info.from_args)(&m)?)
}

/// Per-pixel sums over seeds, and the relMSE sums.
struct Acc {
    sum: Vec<DVec3>,
    sq: Vec<DVec3>,
    rel: [f64; 3], // all, region, rest
    rays: u64,
    secs: f64,
    spp: f64,
}

/// Mean over the pixels of `mask` (all when None) and channels of `f`.
fn mean_over(n: usize, mask: Option<(&[bool], bool)>, f: impl Fn(usize) -> f64) -> f64 {
    let (mut s, mut c) = (0.0, 0usize);
    for i in 0..n {
        if mask.is_none_or(|(m, want)| m[i] == want) {
            s += f(i);
            c += 1;
        }
    }
    if c == 0 {
        f64::NAN
    } else {
        s / c as f64
    }
}

fn rel(img: &Image, r: &Image, i: usize) -> f64 {
    let (a, b) = (img.data[i].as_dvec3(), r.data[i].as_dvec3());
    let d = a - b;
    ((d * d) / (b * b + DVec3::splat(kalos::metrics::EPSILON))).element_sum() / 3.0
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().collect();
    if args.len() < 5 {
        return Err(
            "usage: SCENE K BUDGETS METHODS [ref=IMAGE] [region=BOXES] [csv=PREFIX]".into(),
        );
    }
    let world = World::new(kalos::scene::load(std::path::Path::new(&args[1]))?);
    let k: u64 = args[2].parse()?;
    let budgets: Vec<(String, Budget)> = args[3]
        .split(',')
        .map(|b| -> Result<_, Box<dyn std::error::Error>> {
            let (key, v) = b.split_once('=').ok_or("budget is time=S or rays=N")?;
            let mut budget = Budget::default();
            match key {
                "time" => budget.time = Some(v.parse()?),
                "rays" => budget.rays = Some(v.parse::<f64>()? as u64),
                _ => return Err(format!("unknown budget '{key}'").into()),
            }
            Ok((b.to_string(), budget))
        })
        .collect::<Result<_, _>>()?;
    let lines: Vec<&str> = args[4].split(';').map(str::trim).collect();
    let cfgs: Vec<MethodConfig> = lines.iter().map(|l| method(l)).collect::<Result<_, _>>()?;
    let (mut reference, mut region, mut csv) = (None, None, None);
    for a in &args[5..] {
        match a.split_once('=') {
            Some(("ref", p)) => reference = Some(read_image(std::path::Path::new(p))?),
            Some(("region", b)) => region = Some(parse_boxes(b)?),
            Some(("csv", p)) => csv = Some(p.to_string()),
            _ => return Err(format!("unknown argument '{a}'").into()),
        }
    }
    let (w, h) = (world.camera.width as usize, world.camera.height as usize);
    let n = w * h;
    let mask: Option<Vec<bool>> = region.as_ref().map(|boxes| {
        (0..n)
            .map(|i| {
                let ray = world.camera.ray((i % w) as f32 + 0.5, (i / w) as f32 + 0.5);
                world.accel.intersect(&ray).is_some_and(|hit| {
                    let p = ray.o + ray.d * hit.t;
                    boxes
                        .iter()
                        .any(|(lo, hi)| p.cmpge(*lo).all() && p.cmple(*hi).all())
                })
            })
            .collect()
    });
    if let Some(m) = &mask {
        println!("region: {} of {n} pixels", m.iter().filter(|x| **x).count());
    }
    let mut rows: Vec<Vec<String>> = vec![Vec::new(); cfgs.len()];
    for (label, budget) in &budgets {
        let mut accs: Vec<Acc> = cfgs
            .iter()
            .map(|_| Acc {
                sum: vec![DVec3::ZERO; n],
                sq: vec![DVec3::ZERO; n],
                rel: [0.0; 3],
                rays: 0,
                secs: 0.0,
                spp: 0.0,
            })
            .collect();
        for seed in 1..=k {
            for (cfg, acc) in cfgs.iter().zip(&mut accs) {
                let t = Instant::now();
                let r = Render::new(&world)
                    .method(cfg.clone())
                    .common(Common {
                        seed,
                        max_depth: None,
                    })
                    .budget(*budget)
                    .run(|_| {})?;
                acc.secs += t.elapsed().as_secs_f64();
                acc.rays += r.rays;
                acc.spp += r.spp;
                for (i, p) in r.image.data.iter().enumerate() {
                    let v = p.as_dvec3();
                    acc.sum[i] += v;
                    acc.sq[i] += v * v;
                }
                if let Some(re) = &reference {
                    let m = mask.as_deref();
                    acc.rel[0] += mean_over(n, None, |i| rel(&r.image, re, i));
                    if let Some(m) = m {
                        acc.rel[1] += mean_over(n, Some((m, true)), |i| rel(&r.image, re, i));
                        acc.rel[2] += mean_over(n, Some((m, false)), |i| rel(&r.image, re, i));
                    }
                }
            }
        }
        let kf = k as f64;
        for (j, acc) in accs.iter().enumerate() {
            let var = |i: usize| {
                let m = acc.sum[i] / kf;
                ((acc.sq[i] / kf - m * m) * (kf / (kf - 1.0))).element_sum() / 3.0
            };
            let v_all = mean_over(n, None, var);
            let mut line = format!("{label:>12} | {:<40} | var {:.3e}", lines[j], v_all);
            if let Some(m) = mask.as_deref() {
                line += &format!(
                    " (region {:.3e}, rest {:.3e})",
                    mean_over(n, Some((m, true)), var),
                    mean_over(n, Some((m, false)), var)
                );
            }
            if reference.is_some() {
                line += &format!(" | relMSE {:.3e}", acc.rel[0] / kf);
                if mask.is_some() {
                    line += &format!(
                        " (region {:.3e}, rest {:.3e})",
                        acc.rel[1] / kf,
                        acc.rel[2] / kf
                    );
                }
            }
            line += &format!(
                " | {:.2} M rays, {:.2} s, {:.1} spp per render",
                acc.rays as f64 / kf / 1e6,
                acc.secs / kf,
                acc.spp / kf
            );
            println!("{line}");
            let err = if reference.is_some() {
                acc.rel[0] / kf
            } else {
                v_all
            };
            rows[j].push(format!(
                "{:.4},{},{:.3},{:.6e}",
                acc.secs / kf,
                acc.rays / k,
                acc.spp / kf,
                err
            ));
        }
        std::io::stdout().flush()?;
    }
    if let Some(prefix) = csv {
        for (j, r) in rows.iter().enumerate() {
            let mut f = std::fs::File::create(format!("{prefix}-{j}.csv"))?;
            writeln!(f, "time_s,rays,spp,rel_mse")?;
            for row in r {
                writeln!(f, "{row}")?;
            }
        }
    }
    Ok(())
}
