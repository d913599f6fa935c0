//! The shared transport layer: the light walk's depth convention (Mitsuba's
//! `max_depth`, as `path` and `light` count) and its hook.

use std::ops::ControlFlow;

use kalos::methods::World;
use kalos::sampling::Pcg32;
use kalos::scene::{self, Rgb, Scene};
use kalos::transport::{light_walk, Spectrum};

fn load(name: &str, res: u32) -> Scene {
    let root = std::path::PathBuf::from(env!("CARGO_MANIFEST_DIR"));
    let mut s = scene::load(&root.join("scenes").join(name)).expect("scene");
    s.set_resolution(res, res);
    s
}

/// The (depth, power) of every vertex the hook sees on walk `i`, traced as
/// `light` traces it (an emission sample, then the walk), with its own
/// stream so that walks can be compared one by one.
fn walk(world: &World, i: u64, max_depth: Option<u32>) -> (Vec<(u32, Rgb)>, u64) {
    let mut rng = Pcg32::keyed(&[3, i]);
    let (u_sel, u_pos, u_dir) = (rng.next_f32(), rng.next_2d(), rng.next_2d());
    let Some(es) = world
        .lights
        .sample_emission(&world.scene, u_sel, u_pos, u_dir)
    else {
        return (Vec::new(), 0);
    };
    let mut seen = Vec::new();
    let rays = light_walk(
        world,
        es.ray(),
        es.phi,
        Spectrum::Rgb,
        max_depth,
        &mut rng,
        |e| {
            seen.push((e.depth, e.beta));
            ControlFlow::Continue(())
        },
    );
    (seen, rays)
}

/// A light path of k segments joins the eye in k + 1: the hook sees depths
/// 1, 2, … below `max_depth` only (none at depth 1, which is emitters
/// only), and a finite depth only truncates the unlimited walk (the same
/// vertices with the same power, bit for bit).
#[test]
fn light_walk_reports_vertices_below_max_depth_only() {
    let world = World::new(load("cbox/cbox.xml", 16));
    let walks = 2000;
    let full: Vec<_> = (0..walks).map(|i| walk(&world, i, None).0).collect();
    assert!(
        full.iter().any(|w| w.len() >= 5),
        "unlimited walks should reach depth 5 in cbox"
    );
    for w in &full {
        let depths: Vec<u32> = w.iter().map(|v| v.0).collect();
        assert_eq!(depths, (1..=w.len() as u32).collect::<Vec<_>>());
    }
    for m in 1..=4u32 {
        let mut deepest = 0;
        for (i, f) in full.iter().enumerate() {
            let (seen, rays) = walk(&world, i as u64, Some(m));
            assert!(seen.iter().all(|v| v.0 < m), "max depth {m}: {seen:?}");
            let n = seen.len();
            assert_eq!(n, f.len().min(m as usize - 1), "max depth {m}, walk {i}");
            assert_eq!(&f[..n], &seen[..], "max depth {m}, walk {i}");
            if m == 1 {
                // the first segment is traced, nothing is measured
                assert!(rays <= 1 && seen.is_empty());
            }
            deepest = deepest.max(n as u32);
        }
        assert_eq!(deepest, m - 1, "max depth {m}");
    }
}

/// The hook can end a walk: breaking at the first vertex leaves one ray.
#[test]
fn a_hook_can_end_the_walk() {
    let world = World::new(load("cbox/cbox.xml", 16));
    let mut ended = 0;
    for i in 0..200 {
        let mut rng = Pcg32::keyed(&[5, i]);
        let (u_sel, u_pos, u_dir) = (rng.next_f32(), rng.next_2d(), rng.next_2d());
        let es = world
            .lights
            .sample_emission(&world.scene, u_sel, u_pos, u_dir)
            .expect("cbox has a light");
        let mut calls = 0;
        let rays = light_walk(
            &world,
            es.ray(),
            es.phi,
            Spectrum::Rgb,
            None,
            &mut rng,
            |_| {
                calls += 1;
                ControlFlow::Break(())
            },
        );
        assert_eq!(rays, 1);
        assert!(calls <= 1);
        ended += calls;
    }
    assert!(ended > 100, "most first rays should hit the closed box");
}
