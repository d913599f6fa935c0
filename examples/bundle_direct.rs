//! Diagnostic: direct irradiance of every patch from one sweep per global
//! direction (emission only), against a Monte Carlo integral over the
//! emitting patches, and the image means they give (64 × 64 pixel centres,
//! diffuse surfaces). `ZB=1` uses the z-buffer instead of the painter.
//! The hit points of pixel column 32 go to stderr.
//! Usage: bundle_direct SCENE DIRS MAP_RES [EDGE]
#![allow(clippy::disallowed_methods)] // std::fs is denied only in the scene loaders (clippy.toml)
use std::path::Path;

use glam::Vec3;
use kalos::methods::bundle::patches::{edge_for_count, Patches};
use kalos::methods::bundle::visibility::{sweep, Plane, SweepInput, Visibility};
use kalos::methods::World;
use kalos::sampling::{uniform_sphere, uniform_triangle, Pcg32};

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let usage = "usage: bundle_direct SCENE DIRS MAP_RES [EDGE]";
    let a: Vec<String> = std::env::args().collect();
    if a.len() < 4 {
        return Err(usage.into());
    }
    let mut scene = kalos::scene::load(Path::new(&a[1]))?;
    scene.camera.width = 64;
    scene.camera.height = 64;
    let world = World::new(scene);
    let dirs: u64 = a[2].parse()?;
    let res: u32 = a[3].parse()?;
    let edge = match a.get(4) {
        Some(e) => e.parse()?,
        None => edge_for_count(&world.scene, 5000),
    };
    let patches = Patches::build(&world.scene, &world.lights, edge);
    let n = patches.len();
    let mut est = vec![0f64; n];
    for k in 0..dirs {
        let d = uniform_sphere(Pcg32::keyed(&[1, k]).next_2d());
        let lp: Vec<Vec3> = patches.p.iter().map(|p| p.le(d)).collect();
        let lm: Vec<Vec3> = patches.p.iter().map(|p| p.le(-d)).collect();
        let inc = sweep(
            &patches,
            &SweepInput {
                plane: Plane {
                    d,
                    res,
                    center: world.lights.center,
                    radius: world.lights.radius,
                    keys: [5, k],
                    visibility: if std::env::var("ZB").is_ok() {
                        Visibility::ZBuffer
                    } else {
                        Visibility::Painter
                    },
                    centre_rr: true,
                },
                l_plus: &lp,
                l_minus: &lm,
                sky_plus: Vec3::ZERO,
                sky_minus: Vec3::ZERO,
            },
            &mut Default::default(),
        );
        for (i, p) in patches.p.iter().enumerate() {
            let mut e = 0.0;
            if p.ng.dot(d) < 0.0 {
                e += inc.e_plus[i].x;
            }
            if p.ng.dot(-d) < 0.0 {
                e += inc.e_minus[i].x;
            }
            est[i] += (2.0 * std::f32::consts::PI * e / p.area) as f64;
        }
    }
    // reference: Monte Carlo over points of the patch and of the emitters
    let em: Vec<usize> = (0..n).filter(|&i| patches.p[i].le.x > 0.0).collect();
    let aem: f64 = em.iter().map(|&i| patches.p[i].area as f64).sum();
    let mut groups: std::collections::BTreeMap<String, [f64; 3]> = Default::default();
    let mut eref = vec![0f64; n];
    let samples = 256;
    for i in 0..n {
        let p = &patches.p[i];
        if p.le.x > 0.0 {
            continue;
        }
        let mut rng = Pcg32::keyed(&[9, i as u64]);
        let mut e = 0.0f64;
        for _ in 0..samples {
            let b = uniform_triangle(rng.next_2d());
            let x = p.v[0] * (1.0 - b.x - b.y) + p.v[1] * b.x + p.v[2] * b.y;
            // pick an emitter patch by area
            let mut u = rng.next_f32() as f64 * aem;
            let mut j = em[0];
            for &jj in &em {
                j = jj;
                u -= patches.p[jj].area as f64;
                if u <= 0.0 {
                    break;
                }
            }
            let q = &patches.p[j];
            let b = uniform_triangle(rng.next_2d());
            let y = q.v[0] * (1.0 - b.x - b.y) + q.v[1] * b.x + q.v[2] * b.y;
            let w = y - x;
            let r2 = w.length_squared();
            let w = w / r2.sqrt();
            let cx = p.ng.dot(w);
            let cy = -q.ng.dot(w);
            if cx <= 0.0 || cy <= 0.0 {
                continue;
            }
            if world.accel.occluded(x + p.ng * 1e-4, y + q.ng * 1e-4) {
                continue;
            }
            e += (q.le.x * cx * cy / r2) as f64 * aem;
        }
        e /= samples as f64;
        eref[i] = e;
        let key = format!("{:+.0},{:+.0},{:+.0}", p.ng.x, p.ng.y, p.ng.z);
        let g = groups.entry(key).or_default();
        g[0] += est[i] / dirs as f64 * p.area as f64;
        g[1] += e * p.area as f64;
        g[2] += p.area as f64;
    }
    // expected image means: pixel centres, diffuse albedo a/π times the patch's E
    let cam = &world.camera;
    let (mut ib, mut ir, mut ipt, mut np) = (0f64, 0f64, 0f64, 0usize);
    for y in 0..cam.height {
        for x in 0..cam.width {
            np += 1;
            let Some(hit) = world
                .accel
                .intersect(&cam.ray(x as f32 + 0.5, y as f32 + 0.5))
            else {
                continue;
            };
            let sp = world.scene.surface_point(hit.tri, hit.b1, hit.b2);
            let a = world
                .scene
                .material_of(&sp)
                .bsdf(sp.uv)
                .eval(Vec3::Z, Vec3::Z, kalos::bsdf::Mode::Radiance)
                .x as f64;
            let (i, _) = patches.locate(hit.tri, hit.b1, hit.b2);
            ib += a * est[i as usize] / dirs as f64;
            ir += a * eref[i as usize];
            // the same integral at the pixel's own point
            let mut rng = Pcg32::keyed(&[11, (y * cam.width + x) as u64]);
            let mut e = 0.0f64;
            let ns = 1024;
            for _ in 0..ns {
                let mut u = rng.next_f32() as f64 * aem;
                let mut j = em[0];
                for &jj in &em {
                    j = jj;
                    u -= patches.p[jj].area as f64;
                    if u <= 0.0 {
                        break;
                    }
                }
                let q = &patches.p[j];
                let b = uniform_triangle(rng.next_2d());
                let yq = q.v[0] * (1.0 - b.x - b.y) + q.v[1] * b.x + q.v[2] * b.y;
                let w = yq - sp.p;
                let r2 = w.length_squared();
                let w = w / r2.sqrt();
                let (cx, cy) = (sp.ng.dot(w), -q.ng.dot(w));
                if cx <= 0.0
                    || cy <= 0.0
                    || world.accel.occluded(sp.p + sp.ng * 1e-4, yq + q.ng * 1e-4)
                {
                    continue;
                }
                e += (q.le.x * cx * cy / r2) as f64 * aem;
            }
            ipt += a * e / ns as f64;
            if x == 32 && y % 8 == 4 {
                eprintln!(
                    "pixel ({x},{y}): p {:?} ng {:?} L {:.5}",
                    sp.p,
                    sp.ng,
                    a * e / ns as f64
                );
            }
        }
    }
    println!(
        "image mean from bundle E {:.6}, from reference E {:.6}, pointwise {:.6}",
        ib / np as f64,
        ir / np as f64,
        ipt / np as f64
    );
    println!("{n} patches, edge {edge}, {dirs} dirs, map {res}");
    let (tb, tr): (f64, f64) =
        (0..n)
            .filter(|&i| patches.p[i].le.x == 0.0)
            .fold((0.0, 0.0), |a, i| {
                (
                    a.0 + est[i] / dirs as f64 * patches.p[i].area as f64,
                    a.1 + eref[i] * patches.p[i].area as f64,
                )
            });
    println!(
        "total received power: bundle {tb:.1}, reference {tr:.1}, ratio {:.4}",
        tb / tr
    );
    for (k, g) in groups {
        println!(
            "normal {k}: area {:.3}  bundle power {:.4}  reference {:.4}  ratio {:.4}",
            g[2],
            g[0],
            g[1],
            g[0] / g[1]
        );
    }
    Ok(())
}
