//! Light tracing with and without the camera pass, against the path tracer,
//! on a glass sphere and a mirror sphere above a diffuse floor
//! (scenes/glass-mirror), and on cbox where the camera pass must change
//! nothing.
//!
//! How images are compared. Each method renders the scene twice with
//! independent seeds; the images are cut into 8×8-pixel blocks, and each
//! block mean gets a variance estimated from the two renders
//! ([`common::block_stats`]). Two methods agree when every block and channel
//! has |z| below the threshold, z = (m_a − m_b)/√(var_a + var_b). With 64
//! blocks × 3 channels, a per-test false-alarm rate of 1 % needs
//! |z| < 4.05 under normality (Šidák: Φ⁻¹(1 − 0.01/(2·192)) = 4.046); the
//! caustics give the path tracer heavy-tailed pixels, so the threshold is
//! 4.5 to allow for the imperfect normality of the block means (a small
//! absolute floor, 1e-4, covers blocks that are black in both).

use crate::common;

use crate::common::{block_stats, max_block_z, render, render_budget};
use kalos::film::Image;
use kalos::methods::{light, plb, Budget, Common, MethodConfig, World};
use kalos::sampling::SamplerKind;
use kalos::scene::{self, Scene};
use kalos::transport::camera_pass::CameraPass;

const Z_MAX: f64 = 4.5;

fn root() -> std::path::PathBuf {
    std::path::PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

fn glass_mirror() -> Scene {
    let mut s = scene::load(&root().join("scenes/glass-mirror/scene.xml")).expect("scene");
    s.set_resolution(64, 64);
    s
}

fn two_renders(scene: &Scene, method: &str, camera_pass: bool, rays: u64) -> (Image, Image) {
    let cfg = match method {
        "path" => common::path(),
        "light" => common::light(light::Settings {
            camera_pass,
            ..Default::default()
        }),
        "plb" => common::plb(plb::Settings {
            camera_pass,
            ..Default::default()
        }),
        other => panic!("no camera pass test for {other}"),
    };
    let run = |seed| {
        let budget = Budget {
            rays: Some(rays),
            ..Default::default()
        };
        let common = Common {
            seed,
            max_depth: None,
        };
        render_budget(scene, &cfg, &common, budget).0
    };
    (run(11), run(12))
}

const RAYS: u64 = 6_000_000;

fn camera_pass_matches_path_and_raw_does_not(method: &str) {
    let scene = glass_mirror();
    let (p1, p2) = two_renders(&scene, "path", true, RAYS);
    let path = block_stats(&p1, &p2, 8, &|_, _| true);

    let (l1, l2) = two_renders(&scene, method, true, RAYS);
    let with = block_stats(&l1, &l2, 8, &|_, _| true);
    let (z, block) = max_block_z(&path, &with, 1e-4);
    eprintln!("{method} + camera pass vs path: max |z| = {z:.2} (block {block})");
    assert!(
        z < Z_MAX,
        "{method} with the camera pass disagrees with path: |z| = {z:.2} in block {block}"
    );

    // The same test must fail without the camera pass (the spheres are black)
    let (r1, r2) = two_renders(&scene, method, false, RAYS);
    let raw = block_stats(&r1, &r2, 8, &|_, _| true);
    let (z, block) = max_block_z(&path, &raw, 1e-4);
    eprintln!("raw {method} vs path: max |z| = {z:.2} (block {block})");
    assert!(
        z >= Z_MAX,
        "the raw {method} should miss the delta surfaces (|z| = {z:.2})"
    );
}

#[test]
#[ignore = "slow tier: cargo test --release -- --ignored"]
fn light_with_camera_pass_matches_path_everywhere_and_raw_light_does_not() {
    camera_pass_matches_path_and_raw_does_not("light");
}

#[test]
#[ignore = "slow tier: cargo test --release -- --ignored"]
fn plb_with_camera_pass_matches_path_everywhere_and_raw_plb_does_not() {
    camera_pass_matches_path_and_raw_does_not("plb");
}

/// The caustic under the glass sphere: the light tracer alone (no camera
/// pass) and the path tracer agree on the floor at equal rays.
#[test]
fn light_and_path_agree_on_the_caustic_floor() {
    let scene = glass_mirror();
    let world = World::new(scene.clone());
    // floor pixels: the primary ray through the pixel centre hits the floor (shape 0)
    let floor: Vec<bool> = (0..64 * 64)
        .map(|i| {
            let ray = world
                .camera
                .ray((i % 64) as f32 + 0.5, (i / 64) as f32 + 0.5);
            world
                .accel
                .intersect(&ray)
                .is_some_and(|h| world.scene.tri_shape[h.tri as usize] == 0)
        })
        .collect();
    let keep = |x: u32, y: u32| floor[(y * 64 + x) as usize];
    let (p1, p2) = two_renders(&scene, "path", true, RAYS);
    let (l1, l2) = two_renders(&scene, "light", false, RAYS);
    let path = block_stats(&p1, &p2, 8, &keep);
    let light = block_stats(&l1, &l2, 8, &keep);
    assert!(
        path.iter().filter(|b| b.is_some()).count() >= 20,
        "too few floor blocks"
    );
    let (z, block) = max_block_z(&path, &light, 1e-4);
    eprintln!("caustic floor, light vs path: max |z| = {z:.2} (block {block})");
    assert!(
        z < Z_MAX,
        "light and path disagree on the floor: |z| = {z:.2} in block {block}"
    );
}

/// cbox has no delta surface and no environment: the camera pass is off,
/// traces nothing, and the image is bit for bit the raw method's.
#[test]
fn camera_pass_costs_nothing_on_cbox() {
    let mut s = scene::load(&root().join("scenes/cbox/cbox.xml")).expect("scene");
    s.set_resolution(32, 32);
    let world = World::new(s.clone());
    assert!(!CameraPass::new(&world, true, false, 0, None, SamplerKind::Independent).is_active());
    let on = MethodConfig::Light(light::Settings {
        camera_pass: true,
        ..Default::default()
    });
    let off = MethodConfig::Light(light::Settings {
        camera_pass: false,
        ..Default::default()
    });
    let (a, ra) = render(&s, &on, 5, 4);
    let (b, rb) = render(&s, &off, 5, 4);
    assert_eq!(ra, rb);
    assert_eq!(a, b);
}

/// The glossy camera pass takes a share only of sharp lobes
/// ([`kalos::transport::camera_pass::is_sharp`]): where it does, the camera
/// side takes at least half of the lobe's peak path; elsewhere it takes
/// none, on any path. The polished floor of two-rooms/glossy-floor.xml is
/// sharp; the rough plastics of two-rooms-baffle are not, so the baffle's
/// glossy lobes stay with the light side.
#[test]
fn the_glossy_camera_pass_takes_sharp_lobes_only() {
    use glam::{Vec2, Vec3};
    use kalos::sampling::{cosine_hemisphere, Pcg32};
    use kalos::transport::camera_pass::{camera_share, is_sharp};
    for (name, sharp_wanted) in [
        ("scenes/two-rooms/glossy-floor.xml", 1),
        ("scenes/two-rooms-baffle/scene.xml", 0),
    ] {
        let scene = scene::load(&root().join(name)).expect("scene");
        let mut sharp = 0;
        for m in &scene.materials {
            let b = m.bsdf(Vec2::ZERO);
            if is_sharp(&b) {
                sharp += 1;
                assert!(camera_share(&b, Vec3::Z, Vec3::Z) >= 0.5, "{name}: {b:?}");
                continue;
            }
            let mut rng = Pcg32::keyed(&[9]);
            for _ in 0..200 {
                let (wo, wi) = (
                    cosine_hemisphere(rng.next_2d()),
                    cosine_hemisphere(rng.next_2d()),
                );
                assert_eq!(camera_share(&b, wo, wi), 0.0, "{name}: {b:?}");
            }
        }
        assert_eq!(sharp, sharp_wanted, "{name}: sharp glossy materials");
        // Materials without textures: the pass runs only where a lobe is
        // sharp (or delta, or the environment is seen)
        assert!(scene.materials.iter().all(|m| m.is_uniform()), "{name}");
        let world = World::new(scene);
        let pass = CameraPass::new(&world, true, true, 1, None, SamplerKind::Sobol);
        assert_eq!(
            pass.is_active(),
            sharp_wanted > 0,
            "{name}: camera pass active"
        );
    }
}
