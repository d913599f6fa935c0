//! Diagnostic: direct irradiance at one point by light sampling and by
//! cosine sampling through the accel (geometric cosine), and path's own
//! estimate (`--max-depth 2`) from the camera toward the point, split into
//! its two MIS halves. The wall albedo 0.05 is assumed when turning path's
//! radiance into irradiance. Usage: probe_direct SCENE x y z nx ny nz
#![allow(clippy::disallowed_methods)] // std::fs is denied only in the scene loaders (clippy.toml)
use std::path::Path;

use glam::Vec3;
use kalos::geometry::{offset_point, Frame, Ray};
use kalos::methods::World;
use kalos::sampling::Pcg32;

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let usage = "usage: probe_direct SCENE x y z nx ny nz";
    let a: Vec<String> = std::env::args().collect();
    if a.len() < 8 {
        return Err(usage.into());
    }
    let f = a[2..8]
        .iter()
        .map(|s| s.parse::<f32>())
        .collect::<Result<Vec<f32>, _>>()?;
    let world = World::new(kalos::scene::load(Path::new(&a[1]))?);
    let (p, n) = (Vec3::new(f[0], f[1], f[2]), Vec3::new(f[3], f[4], f[5]));
    let frame = Frame::from_normal(n);
    let mut rng = Pcg32::keyed(&[1]);
    let m = 400_000;
    let (mut e_nee, mut e_bsdf, mut hits_tri) =
        (0f64, 0f64, std::collections::BTreeMap::<u32, u64>::new());
    for _ in 0..m {
        if let Some(ls) = world.lights.sample_li(p, rng.next_f32(), rng.next_2d()) {
            let c = ls.wi.dot(n);
            if c > 0.0
                && !world
                    .accel
                    .occluded(offset_point(p, n, ls.wi), offset_point(ls.p, ls.n, -ls.wi))
            {
                e_nee += (ls.le.x * c / ls.pdf) as f64;
            }
        }
        let u = rng.next_2d();
        let r = u.x.sqrt();
        let phi = 2.0 * std::f32::consts::PI * u.y;
        let wl = Vec3::new(r * phi.cos(), r * phi.sin(), (1.0 - u.x).max(0.0).sqrt());
        let wi = frame.to_world(wl);
        if let Some(hit) = world.accel.intersect(&Ray::new(offset_point(p, n, wi), wi)) {
            *hits_tri.entry(hit.tri).or_default() += 1;
            let sp = world.scene.surface_point(hit.tri, hit.b1, hit.b2);
            e_bsdf += (world.lights.le_tri(hit.tri, sp.ng, -wi).x * std::f32::consts::PI) as f64;
        }
    }
    let st = kalos::methods::path::Settings {
        seed: 0,
        max_depth: Some(2),
        rr_depth: 5,
        light_selection: Default::default(),
        sampler: Default::default(),
    };
    let mut lp = 0f64;
    let cam = world.camera.position();
    let dir = (p - cam).normalize();
    for _ in 0..m {
        lp += kalos::methods::path::radiance(&world, &st, Ray::new(cam, dir), &mut rng)
            .0
            .x as f64;
    }
    println!(
        "path radiance from {cam:?} along {dir:?}: {:.5} (E = {:.5})",
        lp / m as f64,
        lp / m as f64 * std::f64::consts::PI / 0.05
    );
    // path's first vertex, split into its two MIS halves
    let (mut a_nee, mut a_bsdf) = (0f64, 0f64);
    let mut shown = false;
    let mut emit_hits = std::collections::BTreeMap::<u32, (u64, f64)>::new();
    for _ in 0..m {
        let ray = Ray::new(cam, dir);
        let Some(hit) = world.accel.intersect(&ray) else {
            return Err("the camera ray toward the point hits nothing".into());
        };
        let sp = world.scene.surface_point(hit.tri, hit.b1, hit.b2);
        let wo_world = -ray.d;
        let material = world.scene.material_of(&sp);
        let bsdf = material.bsdf(sp.uv);
        let (frame, ng) =
            kalos::transport::orient(sp.frame, sp.ng, wo_world, material.is_two_sided());
        let wo = frame.to_local(wo_world);
        if !shown {
            shown = true;
            eprintln!(
                "camera ray hits triangle {} at {:?}: n_g {:?}, n_s {:?}, {:?}",
                hit.tri, sp.p, sp.ng, frame.n, bsdf
            );
        }
        let (u_sel, u_l) = (rng.next_f32(), rng.next_2d());
        if let Some(ls) = world.lights.sample_li(sp.p, u_sel, u_l) {
            let wi = frame.to_local(ls.wi);
            let f = bsdf.eval(wo, wi, kalos::bsdf::Mode::Radiance) * wi.z.abs();
            if f != Vec3::ZERO && ls.wi.dot(ng) * wi.z > 0.0 {
                let origin = offset_point(sp.p, ng, ls.wi);
                if !world
                    .accel
                    .occluded(origin, offset_point(ls.p, ls.n, -ls.wi))
                {
                    let w = kalos::sampling::power_heuristic(ls.pdf, bsdf.pdf(wo, wi));
                    a_nee += (f * ls.le * (w / ls.pdf)).x as f64;
                }
            }
        }
        let (uc, u) = (rng.next_f32(), rng.next_2d());
        let Some(s) = bsdf.sample(wo, uc, u, kalos::bsdf::Mode::Radiance) else {
            continue;
        };
        let wi_world = frame.to_world(s.wi);
        let beta = s.f * (s.wi.z.abs() / s.pdf);
        let r2 = Ray::new(offset_point(sp.p, sp.ng, wi_world), wi_world);
        if let Some(h2) = world.accel.intersect(&r2) {
            if world.lights.is_emitter(h2.tri) {
                let sp2 = world.scene.surface_point(h2.tri, h2.b1, h2.b2);
                let le = world.lights.le_tri(h2.tri, sp2.frame.n, -wi_world);
                let w = kalos::sampling::power_heuristic(
                    s.pdf,
                    world.lights.pdf_li_tri(sp.p, sp2.p, sp2.ng, h2.tri),
                );
                let c = (beta * le * w).x as f64;
                a_bsdf += c;
                let e = emit_hits.entry(h2.tri).or_default();
                e.0 += 1;
                e.1 += c;
            }
        }
    }
    println!(
        "path halves: NEE {:.5}, BSDF {:.5}; emitter hits {emit_hits:?}",
        a_nee / m as f64,
        a_bsdf / m as f64
    );
    println!(
        "E by light sampling {:.5}, by cosine sampling {:.5}",
        e_nee / m as f64,
        e_bsdf / m as f64
    );
    println!("hits per triangle: {hits_tri:?}");
    Ok(())
}
