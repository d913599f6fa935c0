//! Diagnostic: directions where the painter's pairs differ from the
//! z-buffer's for the emitters' light (emission only), and the patches that
//! receive differently in the worst one. Usage: painter_vs_z SCENE DIRS MAP_RES
#![allow(clippy::disallowed_methods)] // std::fs is denied only in the scene loaders (clippy.toml)
use std::path::Path;

use glam::Vec3;
use kalos::methods::bundle::patches::{edge_for_count, Patches};
use kalos::methods::bundle::visibility::{sweep, Plane, SweepInput, Visibility};
use kalos::methods::World;
use kalos::sampling::{uniform_sphere, Pcg32};

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let usage = "usage: painter_vs_z SCENE DIRS MAP_RES";
    let a: Vec<String> = std::env::args().collect();
    if a.len() < 4 {
        return Err(usage.into());
    }
    let world = World::new(kalos::scene::load(Path::new(&a[1]))?);
    let dirs: u64 = a[2].parse()?;
    let res: u32 = a[3].parse()?;
    let patches = Patches::build(
        &world.scene,
        &world.lights,
        edge_for_count(&world.scene, 5000),
    );
    // The painter's and the z-buffer's sweeps of the emitters' light along
    // direction d (sequence number k)
    let both = |d: Vec3, k: u64| {
        let le: Vec<Vec3> = patches.p.iter().map(|p| p.le(d)).collect();
        let lem: Vec<Vec3> = patches.p.iter().map(|p| p.le(-d)).collect();
        let run = |v| {
            sweep(
                &patches,
                &SweepInput {
                    plane: Plane {
                        d,
                        res,
                        center: world.lights.center,
                        radius: world.lights.radius,
                        keys: [5, k],
                        visibility: v,
                        centre_rr: true,
                    },
                    l_plus: &le,
                    l_minus: &lem,
                    sky_plus: Vec3::ZERO,
                    sky_minus: Vec3::ZERO,
                },
                &mut Default::default(),
            )
        };
        (run(Visibility::Painter), run(Visibility::ZBuffer))
    };
    let mut worst = Vec::new();
    for k in 0..dirs {
        let d = uniform_sphere(Pcg32::keyed(&[1, k]).next_2d());
        let (p, z) = both(d, k);
        let dp: f32 = p.e_plus.iter().chain(&p.e_minus).map(|v| v.x).sum();
        let dz: f32 = z.e_plus.iter().chain(&z.e_minus).map(|v| v.x).sum();
        if (dp - dz).abs() > 1e-3 * dz.max(1.0) {
            worst.push((dz - dp, k, d));
        }
    }
    worst.sort_by(|a, b| b.0.total_cmp(&a.0));
    println!("{} of {dirs} directions differ", worst.len());
    for w in worst.iter().take(8) {
        println!("lost {:.1} at k {} d {:?}", w.0, w.1, w.2);
    }
    if let Some(&(_, k, d)) = worst.first() {
        let (p, z) = both(d, k);
        for i in 0..patches.len() {
            let (a, b) = (
                p.e_plus[i].x + p.e_minus[i].x,
                z.e_plus[i].x + z.e_minus[i].x,
            );
            if (a - b).abs() > 1e-3 * b.abs().max(1.0) {
                let q = &patches.p[i];
                println!(
                    "patch {i} centroid {:?} ng {:?} le {:?}: painter {a:.1} zbuffer {b:.1}",
                    q.centroid(),
                    q.ng,
                    q.le.x
                );
            }
        }
    }
    Ok(())
}
