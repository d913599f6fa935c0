//! Per-texel error of a lightmap atlas against a reference, for the
//! lightmap benchmarks (docs/notebook/lightmap-estimator.md, BENCHMARKS.md).
//!
//! ```text
//! cargo run --release --example lightmap_error -- compare SCENE SIZE REF.exr REF-a.exr REF-b.exr X.exr...
//! cargo run --release --example lightmap_error -- reference SCENE SIZE OUT PASSES PARTICLES H_TEXELS
//! ```
//!
//! `compare`: the relative RMS of each atlas X (a `kalos bake --lightmap`
//! `.lightmap.exr`) against the reference R = REF.exr, over the texels the
//! atlas of SCENE at SIZE² covers (kalos's own uv set and texels, so the
//! padding is left out) and every channel with R > 10⁻³ × the median of R
//! there: sqrt(mean(((X − R)/R)²) − mean(((A − B)/(2R))²)), A and B two
//! independent halves whose mean is R, the second term the reference's own
//! noise, subtracted in quadrature. The same definition as the Cycles
//! benchmark's script (benches/peers/cycles_lightmap.py). It also prints
//! the raw value, the reference's noise and mean(X)/mean(R).
//!
//! `reference`: an unbiased-as-can-be reference made by kalos itself:
//! PASSES bakes of PARTICLES particles each (seeds 1, 2, ...), each texel
//! estimated with the same fixed bandwidth h = H_TEXELS texel widths (the
//! atlas's mean texel area, square-rooted), averaged. A fixed h makes the
//! passes' mean the estimate of all their particles at that h: its noise
//! falls as 1/√PASSES and its bias is the blur of a kernel of H_TEXELS
//! texels, not of a k-nearest one. Writes OUT.exr (the mean), OUT-a.exr and
//! OUT-b.exr (the odd and the even passes).

#![allow(clippy::disallowed_methods)] // std::fs is denied only in the scene loaders (clippy.toml)
use std::path::{Path, PathBuf};
use std::time::Instant;

use kalos::bake::lightmap::bake::{self as lmbake, LightmapSettings, Steering};
use kalos::bake::lightmap::estimate::Options;
use kalos::bake::lightmap::raster;
use kalos::bake::lightmap::uv::{self, UvOptions};
use kalos::color::Rgb;
use kalos::film::Image;
use kalos::image_io::{read_image, write_image, PngOptions};
use kalos::methods::density::Settings;
use kalos::methods::World;

type Res<T> = Result<T, Box<dyn std::error::Error>>;

fn main() -> Res<()> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let usage = "usage: compare SCENE SIZE REF REF-a REF-b X...\n       reference SCENE SIZE OUT PASSES PARTICLES H_TEXELS";
    if args.len() < 4 {
        return Err(usage.into());
    }
    let scene = kalos::scene::load(Path::new(&args[1]))?;
    let size: u32 = args[2].parse()?;
    let uv_opts = UvOptions {
        size: Some(size),
        ..Default::default()
    };
    let asset_uv1 = (!scene.uv1.is_empty()).then_some(&scene.uv1[..]);
    let uvs = uv::lightmap_uv(&scene, asset_uv1, &uv_opts)?;
    match args[0].as_str() {
        "compare" if args.len() >= 7 => {
            let mut covered = vec![false; (size * size) as usize];
            for t in raster::texels(&scene, &uvs) {
                covered[(t.y * size + t.x) as usize] = true;
            }
            let rd = |p: &str| -> Res<Image> {
                let img = read_image(Path::new(p))?;
                if (img.width, img.height) != (size, size) {
                    return Err(format!("{p}: {}×{}, not {size}²", img.width, img.height).into());
                }
                Ok(img)
            };
            let (r, a, b) = (rd(&args[3])?, rd(&args[4])?, rd(&args[5])?);
            println!(
                "{} covered texels; reference {}",
                covered.iter().filter(|&&c| c).count(),
                args[3]
            );
            for name in &args[6..] {
                let x = rd(name).map_err(|e| format!("{name}: {e}"))?;
                let (c, raw, noise, ratio) = rel_rms(&x, &r, &a, &b, &covered);
                println!(
                    "{name}: relative RMS {:.2} % (raw {:.2} %, reference noise {:.2} %), mean ratio {ratio:.4}",
                    100.0 * c,
                    100.0 * raw,
                    100.0 * noise
                );
                if std::env::var_os("LIGHTMAP_ERROR_DETAIL").is_some() {
                    let (c5, _, _, _) = rel_rms_above(&x, &r, &a, &b, &covered, 0.05);
                    println!(
                        "  over R > 5 % of the median: relative RMS {:.2} %",
                        100.0 * c5
                    );
                    println!("  {}", leak(&x, &r, &covered));
                    detail(name, &x, &r, &covered)?;
                }
            }
            Ok(())
        }
        "reference" if args.len() == 7 => {
            let out = PathBuf::from(&args[3]);
            let passes: u32 = args[4].parse()?;
            let particles = kalos::methods::cli::parse_count(&args[5])?;
            let h_texels: f32 = args[6].parse()?;
            let area = lmbake::texel_area(&scene, &uvs).ok_or("an atlas without area")?;
            let h = h_texels * area.sqrt();
            let world = World::new(scene);
            reference(&world, size, &out, passes, particles, h)
        }
        _ => Err(usage.into()),
    }
}

/// (relative RMS less the reference's noise, raw, the noise, mean ratio).
fn rel_rms(x: &Image, r: &Image, a: &Image, b: &Image, covered: &[bool]) -> (f64, f64, f64, f64) {
    rel_rms_above(x, r, a, b, covered, 1e-3)
}

/// [`rel_rms`] over the channels with R > `floor` × the median of R.
fn rel_rms_above(
    x: &Image,
    r: &Image,
    a: &Image,
    b: &Image,
    covered: &[bool],
    floor: f64,
) -> (f64, f64, f64, f64) {
    let ch = |img: &Image, k: usize, c: usize| img.data[k][c] as f64;
    let mut vals: Vec<f64> = Vec::new();
    for (k, _) in covered.iter().enumerate().filter(|(_, &c)| c) {
        for c in 0..3 {
            vals.push(ch(r, k, c));
        }
    }
    let mut sorted = vals.clone();
    sorted.sort_by(|p, q| p.total_cmp(q));
    let median = sorted.get(sorted.len() / 2).copied().unwrap_or(0.0);
    let (mut raw, mut noise, mut n, mut sx, mut sr) = (0.0, 0.0, 0.0, 0.0, 0.0);
    for (k, _) in covered.iter().enumerate().filter(|(_, &c)| c) {
        for c in 0..3 {
            let rr = ch(r, k, c);
            if rr.is_nan() || rr <= floor * median {
                continue;
            }
            raw += ((ch(x, k, c) - rr) / rr).powi(2);
            noise += ((ch(a, k, c) - ch(b, k, c)) / (2.0 * rr)).powi(2);
            n += 1.0;
            sx += ch(x, k, c);
            sr += rr;
        }
    }
    let (raw, noise) = (raw / n, noise / n);
    (
        (raw - noise).max(0.0).sqrt(),
        raw.sqrt(),
        noise.sqrt(),
        sx / sr,
    )
}

/// Quantiles of the per-texel relative error (mean over channels), the
/// share of the squared error in the worst 1 % of texels, and a map of it
/// (NAME.relerr.png, white at 100 %).
fn detail(name: &str, x: &Image, r: &Image, covered: &[bool]) -> Res<()> {
    let mut map = vec![Rgb::ZERO; covered.len()];
    let mut errs: Vec<(f64, usize)> = Vec::new();
    let mut vals: Vec<f64> = covered
        .iter()
        .enumerate()
        .filter(|(_, &c)| c)
        .flat_map(|(k, _)| (0..3).map(move |c| r.data[k][c] as f64))
        .collect();
    vals.sort_by(f64::total_cmp);
    let floor = 1e-3 * vals.get(vals.len() / 2).copied().unwrap_or(0.0);
    for (k, _) in covered.iter().enumerate().filter(|(_, &c)| c) {
        let mut e = 0.0;
        let mut n = 0.0;
        for c in 0..3 {
            let rr = r.data[k][c] as f64;
            if rr > floor {
                e += ((x.data[k][c] as f64 - rr) / rr).powi(2);
                n += 1.0;
            }
        }
        if n > 0.0 {
            let e = (e / n).sqrt();
            errs.push((e, k));
            map[k] = Rgb::splat(e.min(1.0) as f32);
        }
    }
    errs.sort_by(|a, b| a.0.total_cmp(&b.0));
    let q = |f: f64| errs[((errs.len() - 1) as f64 * f) as usize].0 * 100.0;
    let total: f64 = errs.iter().map(|e| e.0 * e.0).sum();
    let top: f64 = errs[errs.len() * 99 / 100..]
        .iter()
        .map(|e| e.0 * e.0)
        .sum();
    let w = x.width as usize;
    println!(
        "  |rel| quantiles 50 % {:.2} %, 90 % {:.2} %, 99 % {:.2} %, 99.9 % {:.2} %; worst 1 % hold {:.1} % of the squared error; worst at {:?}",
        q(0.5),
        q(0.9),
        q(0.99),
        q(0.999),
        100.0 * top / total,
        errs.iter().rev().take(5).map(|e| (e.1 % w, e.1 / w, (e.0 * 100.0) as i64)).collect::<Vec<_>>()
    );
    let img = Image {
        width: x.width,
        height: x.height,
        data: map,
    };
    write_image(
        Path::new(&format!("{name}.relerr.png")),
        &img,
        &PngOptions::default(),
    )?;
    Ok(())
}

/// Light where the reference has none: over the covered texels whose
/// reference is 0 in every channel (a reference that is unbiased there,
/// such as a path-traced one: occluded surface), the mean of X over the
/// median of R elsewhere. The relative RMS cannot see these texels.
fn leak(x: &Image, r: &Image, covered: &[bool]) -> String {
    let (mut lit, mut dark) = (Vec::new(), Vec::new());
    for (k, _) in covered.iter().enumerate().filter(|(_, &c)| c) {
        let (xv, rv) = (x.data[k], r.data[k]);
        if rv.max_element() <= 0.0 {
            dark.push(xv.element_sum() as f64 / 3.0);
        } else {
            lit.push(rv.element_sum() as f64 / 3.0);
        }
    }
    lit.sort_by(f64::total_cmp);
    let median = lit.get(lit.len() / 2).copied().unwrap_or(0.0);
    let mean = dark.iter().sum::<f64>() / dark.len().max(1) as f64;
    let max = dark.iter().fold(0.0f64, |a, &b| a.max(b));
    format!(
        "{} texels dark in the reference: mean {:.2} %, max {:.0} % of the lit median",
        dark.len(),
        100.0 * mean / median,
        100.0 * max / median
    )
}

/// PASSES bakes with a fixed bandwidth `h`, averaged (see the top).
fn reference(world: &World, size: u32, out: &Path, passes: u32, particles: u64, h: f32) -> Res<()> {
    let n = (size * size) as usize;
    let mut sums = [vec![Rgb::ZERO; n], vec![Rgb::ZERO; n]];
    let mut counts = [0u32; 2];
    let t0 = Instant::now();
    for pass in 0..passes {
        let lm = LightmapSettings {
            size: Some(size),
            estimator: Options {
                bandwidth: Some(h),
                ..Default::default()
            },
            ..Default::default()
        };
        let s = Settings {
            particles,
            seed: pass as u64 + 1,
            ..Default::default()
        };
        let bake = lmbake::bake_lightmap(world, &s, &lm, Steering::unlimited(&mut |_| {}))?;
        let half = (pass % 2) as usize;
        for (acc, e) in sums[half].iter_mut().zip(&bake.lightmap.irradiance) {
            *acc += *e;
        }
        counts[half] += 1;
        eprintln!(
            "pass {} of {passes}: {} hits, {:.0} s",
            pass + 1,
            bake.stats.hits,
            t0.elapsed().as_secs_f64()
        );
    }
    let img = |data: Vec<Rgb>| Image {
        width: size,
        height: size,
        data,
    };
    let mean = |s: &[Rgb], c: u32| s.iter().map(|v| *v / c.max(1) as f32).collect::<Vec<_>>();
    let (a, b) = (mean(&sums[0], counts[0]), mean(&sums[1], counts[1]));
    let all: Vec<Rgb> = a.iter().zip(&b).map(|(x, y)| (*x + *y) * 0.5).collect();
    let with = |tail: &str| {
        let mut p = out.as_os_str().to_owned();
        p.push(tail);
        PathBuf::from(p)
    };
    let o = PngOptions::default();
    write_image(&with(".exr"), &img(all), &o)?;
    write_image(&with("-a.exr"), &img(a), &o)?;
    write_image(&with("-b.exr"), &img(b), &o)?;
    eprintln!("h = {h} (world units); wrote {}", with(".exr").display());
    Ok(())
}
