//! Tests of the density-estimation method (`--method density`, `kalos bake`).

mod common;

use common::{furnace, mean_and_se};
use kalos::methods::density::{self, Settings};
use kalos::methods::{Method, World};

fn settings(particles: u64, seed: u64) -> Settings {
    Settings {
        seed,
        particles,
        ..Default::default()
    }
}

#[test]
fn furnace_debug() {
    let world = World::new(furnace(0.5, 1.0, 16));
    let mut m = density::Density::new(&world, settings(200_000, 1));
    m.step(&world, 0);
    let b = m.bake().expect("bake");
    eprintln!("{:?}", b.stats);
    for pm in &b.mesh.planar {
        let mean = pm.h.iter().copied().sum::<glam::Vec3>() / pm.h.len() as f32;
        eprintln!(
            "surface {:x} hits {} bw {} verts {} mean H {}",
            pm.surface,
            pm.hits,
            pm.bandwidth,
            pm.verts.len(),
            mean
        );
    }
    let img = m.image(&world);
    eprintln!("{:?}", mean_and_se(&img, 0));
}
