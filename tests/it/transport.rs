//! The shared transport layer: the light walk's depth convention (Mitsuba's
//! `max_depth`, as `path` and `light` count), its hook, the density method
//! that now follows the same convention, and setup rays counted by
//! `Method::prepare`.

use std::ops::ControlFlow;

use kalos::methods::{bundle, density, Common, MethodConfig, World};
use kalos::sampling::{Pcg32, SamplerKind};
use kalos::scene::{self, Rgb, Scene};
use kalos::transport::camera_pass::CameraPass;
use kalos::transport::{light_walk, Roulette, Spectrum};

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
    walk_with(world, i, max_depth, Roulette::Albedo)
}

/// [`walk`] with the given Russian roulette.
fn walk_with(
    world: &World,
    i: u64,
    max_depth: Option<u32>,
    roulette: Roulette,
) -> (Vec<(u32, Rgb)>, u64) {
    let mut rng = Pcg32::keyed(&[3, i]);
    let (u_sel, u_pos, u_dir) = (rng.next_f32(), rng.next_2d(), rng.next_2d());
    let Some(es) = world.lights.sample_emission(u_sel, u_pos, u_dir) else {
        return (Vec::new(), 0);
    };
    let mut seen = Vec::new();
    let rays = light_walk(
        world,
        es.ray(),
        es.phi,
        Spectrum::Rgb,
        roulette,
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

/// Both roulettes are unbiased: the power a walk brings to the vertices of
/// depths 2 to 5 of cbox has the same mean under each. The tolerance is
/// derived from the measured variances: |difference| ≤ 5 standard errors
/// of the difference, per channel and depth (the walks of the two are
/// independent streams). The throughput's roulette also ends walks sooner
/// on cbox's coloured walls: fewer rays, checked too.
#[test]
fn both_roulettes_carry_the_same_mean_power() {
    let world = World::new(load("cbox/cbox.xml", 16));
    let walks = 40_000u64;
    let depths = 2..=5u32;
    // per roulette: per depth, the sum and sum of squares of each channel
    let stats = |roulette: Roulette, offset: u64| {
        let mut sum = vec![[0.0f64; 3]; 6];
        let mut sq = vec![[0.0f64; 3]; 6];
        let mut rays = 0;
        for i in 0..walks {
            let (seen, r) = walk_with(&world, offset + i, None, roulette);
            rays += r;
            let mut per = [[0.0f64; 3]; 6];
            for (d, beta) in seen {
                if (d as usize) < per.len() {
                    for c in 0..3 {
                        per[d as usize][c] += beta[c] as f64;
                    }
                }
            }
            for d in 0..per.len() {
                for c in 0..3 {
                    sum[d][c] += per[d][c];
                    sq[d][c] += per[d][c] * per[d][c];
                }
            }
        }
        (sum, sq, rays)
    };
    let (sa, qa, rays_a) = stats(Roulette::Albedo, 0);
    let (st, qt, rays_t) = stats(Roulette::Throughput, 1 << 40);
    let n = walks as f64;
    for d in depths {
        for c in 0..3 {
            let (d, c) = (d as usize, c);
            let (ma, mt) = (sa[d][c] / n, st[d][c] / n);
            let va = (qa[d][c] / n - ma * ma).max(0.0) / n;
            let vt = (qt[d][c] / n - mt * mt).max(0.0) / n;
            let se = (va + vt).sqrt();
            assert!(ma > 0.0 && mt > 0.0, "depth {d} channel {c}: no power");
            assert!(
                (ma - mt).abs() <= 5.0 * se,
                "depth {d} channel {c}: albedo {ma} against throughput {mt}, {} standard errors",
                (ma - mt).abs() / se
            );
        }
    }
    assert!(
        rays_t < rays_a,
        "the throughput's roulette should end walks sooner on cbox: {rays_t} against {rays_a} rays"
    );
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
            .sample_emission(u_sel, u_pos, u_dir)
            .expect("cbox has a light");
        let mut calls = 0;
        let rays = light_walk(
            &world,
            es.ray(),
            es.phi,
            Spectrum::Rgb,
            Roulette::Albedo,
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

/// Density estimation follows the same convention: at `max_depth` 1 no
/// particle hit is recorded (a hit of depth 1 joined to the eye is a path
/// of two segments), so only the emitters are seen; at 2 the walls are lit.
#[test]
fn density_at_max_depth_1_shows_only_the_emitters() {
    let world = World::new(load("cbox/cbox.xml", 24));
    let render = |max_depth| {
        let cfg = MethodConfig::Density(density::Settings {
            particles: 20_000,
            ..Default::default()
        });
        let common = Common {
            seed: 0,
            max_depth: Some(max_depth),
        };
        let mut m = cfg.create(&world, &common).expect("method");
        m.prepare(&world).expect("prepare");
        m.step(&world, 0);
        m.image(&world)
    };
    // pixels that see an emitter nowhere (centre and four inset corners)
    let (w, h) = (world.camera.width, world.camera.height);
    let sees_light = |x: u32, y: u32| {
        [
            (0.5, 0.5),
            (0.01, 0.01),
            (0.99, 0.01),
            (0.01, 0.99),
            (0.99, 0.99),
        ]
        .iter()
        .any(|&(dx, dy)| {
            let ray = world.camera.ray(x as f32 + dx, y as f32 + dy);
            world
                .accel
                .intersect(&ray)
                .is_some_and(|hit| world.lights.is_emitter(hit.tri))
        })
    };
    let d1 = render(1);
    let d2 = render(2);
    let (mut dark, mut lit, mut light) = (0, 0, 0);
    for y in 0..h {
        for x in 0..w {
            let i = (y * w + x) as usize;
            if sees_light(x, y) {
                light += u32::from(d1.data[i].max_element() > 0.0);
                continue;
            }
            assert_eq!(d1.data[i], glam::Vec3::ZERO, "pixel ({x}, {y}) at depth 1");
            dark += 1;
            lit += u32::from(d2.data[i].max_element() > 0.0);
        }
    }
    assert!(light > 0, "the light itself must show at depth 1");
    assert!(lit > dark / 2, "depth 2 lights the walls: {lit} of {dark}");
}

/// Setup is counted: the camera pass's pre-pass traces between one and 16
/// rays per pixel in `prepare` (and nothing in a scene that needs no camera
/// pass), and bundle's view with fixed positions traces at least one ray
/// per pixel sample there.
#[test]
fn prepare_counts_the_setup_rays() {
    let res = 24u64;
    let glass = World::new(load("glass-mirror/scene.xml", res as u32));
    let mut cp = CameraPass::new(&glass, true, false, 0, None, SamplerKind::Independent);
    let rays = cp.prepare(&glass);
    assert!(
        (res * res..=16 * res * res).contains(&rays),
        "pre-pass rays {rays}"
    );
    assert_eq!(cp.prepare(&glass), 0, "the pre-pass runs once");

    let light_cfg = MethodConfig::Light(Default::default());
    let mut light = light_cfg
        .create(&glass, &Common::default())
        .expect("method");
    assert_eq!(light.prepare(&glass).expect("prepare").rays, rays);
    let cbox = World::new(load("cbox/cbox.xml", res as u32));
    let mut light = light_cfg.create(&cbox, &Common::default()).expect("method");
    assert_eq!(light.prepare(&cbox).expect("prepare").rays, 0);

    let cfg = MethodConfig::Bundle(bundle::Settings {
        patches: 300,
        map_res: Some(64),
        positions: bundle::image::Positions::Fixed,
        ..Default::default()
    });
    let mut bundle = cfg.create(&cbox, &Common::default()).expect("method");
    let setup = bundle.prepare(&cbox).expect("prepare").rays;
    assert!(setup >= 4 * res * res, "bundle setup rays {setup}");
}

/// The x86-64-v3 copies of the dispatched loops (`transport::dispatch`) give
/// the same bytes as the baseline copies, which `KALOS_DISPATCH=baseline`
/// forces: a seed must give the same image on every x86-64 machine. On a CPU
/// without AVX2 both runs take the baseline copy and the test shows nothing.
/// Covers `path`, and `light` with its camera pass on a scene with glass and
/// a mirror (the pass's dispatched rows run there).
#[test]
fn dispatched_copies_give_the_same_image() {
    let root = std::path::PathBuf::from(env!("CARGO_MANIFEST_DIR"));
    let dir = tempfile::tempdir().expect("tempdir");
    for scene in ["cbox/cbox.xml", "glass-mirror/scene.xml"] {
        let scene = root.join("scenes").join(scene);
        for method in ["path", "light"] {
            let render = |baseline: bool| {
                let out = dir.path().join(format!("{method}-{baseline}.pfm"));
                let mut cmd = std::process::Command::new(env!("CARGO_BIN_EXE_kalos"));
                cmd.args(["render", scene.to_str().expect("utf-8 path")])
                    .args(["--method", method, "--res", "24x24", "--spp", "3"])
                    .args(["--seed", "5", "-q", "-o", out.to_str().expect("utf-8 path")]);
                if baseline {
                    cmd.env("KALOS_DISPATCH", "baseline");
                } else {
                    cmd.env_remove("KALOS_DISPATCH");
                }
                let o = cmd.output().expect("kalos runs");
                assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
                std::fs::read(&out).expect("output")
            };
            assert!(
                render(false) == render(true),
                "{method} on {}: the x86-64-v3 copy differs from the baseline",
                scene.display()
            );
        }
    }
}

/// `path`'s eight lanes (`lanes::radiance_camera_row`: the jitters and
/// camera rays made in lanes, paths advanced together, the diffuse
/// vertices shaded in AVX lanes, the others by the scalar step lane by
/// lane) give every pixel the radiance and ray count of the scalar
/// estimator (`radiance_from_hit` from `Camera::ray`), bit for bit: on
/// scenes that mix diffuse surfaces with glass, mirrors and rough metal,
/// with both light selections, and with a depth limit and early Russian
/// roulette, on rows whose width (37) leaves a last group of five. On a
/// CPU without AVX2 both sides are the scalar code and the test shows
/// nothing.
#[test]
fn lanes_give_the_scalar_radiance_bit_for_bit() {
    use kalos::emitter::LightSelection;
    use kalos::transport::lanes::radiance_camera_row;
    use kalos::transport::{radiance_from_hit, DepthLimits};
    for (name, res) in [
        ("glass-mirror/scene.xml", 37),
        ("teapot-room/scene.xml", 32),
        ("cbox/cbox.xml", 32),
    ] {
        let world = World::new(load(name, res));
        for (light_selection, max_depth, rr_depth) in [
            (LightSelection::Spatial, None, 5),
            (LightSelection::Power, Some(4), 1),
        ] {
            let limits = DepthLimits {
                max_depth,
                rr_depth,
                light_selection,
            };
            let w = world.camera.width as usize;
            let mut nonzero = 0;
            for y in 0..world.camera.height as usize {
                let sampler = |x: usize| Pcg32::keyed(&[7, y as u64, x as u64]);
                let start = |x: usize| {
                    let mut rng = sampler(x);
                    let j = rng.next_2d();
                    (rng, world.camera.ray(x as f32 + j.x, y as f32 + j.y))
                };
                let mut lanes = vec![None; w];
                radiance_camera_row(&world, &limits, y, sampler, |x, l, n| {
                    assert!(lanes[x].is_none(), "pixel {x} finished twice");
                    lanes[x] = Some((l.to_array().map(f32::to_bits), n));
                });
                for (x, got) in lanes.iter().enumerate() {
                    let (mut rng, ray) = start(x);
                    let (l, n) = radiance_from_hit(&world, &limits, ray, None, &mut rng, 1);
                    nonzero += usize::from(l != Rgb::ZERO);
                    assert_eq!(
                        *got,
                        Some((l.to_array().map(f32::to_bits), n)),
                        "{name}, {light_selection:?}, pixel ({x}, {y})"
                    );
                }
            }
            assert!(
                nonzero > w * w / 4,
                "{name}: too few lit pixels ({nonzero})"
            );
        }
    }
}

/// Paths begun elsewhere and continued in AVX lanes
/// ([`kalos::transport::lanes::radiance_continued`], the camera pass's
/// paths after their first vertex) give what [`radiance_from`] gives one by
/// one: the same radiance bits and rays, for both samplers, from samplers
/// that have already drawn (as the camera pass's first vertex draws). The
/// paths leave the first hits of a grid of camera rays in cosine-sampled
/// directions; 37 × 37 of them, so chunks of 64 and a last group of fewer
/// than eight are crossed.
#[test]
fn continued_lanes_give_the_scalar_radiance_bit_for_bit() {
    use kalos::emitter::LightSelection;
    use kalos::geometry::{offset_point, Ray};
    use kalos::sampling::{cosine_hemisphere, Sampler, SobolSampler};
    use kalos::transport::lanes::{radiance_continued, LaneSampler};
    use kalos::transport::{radiance_from, DepthLimits};

    /// Checks `paths` in lanes against one by one; returns how many
    /// carried light.
    fn check<S: LaneSampler>(
        world: &World,
        limits: &DepthLimits,
        paths: &[(S, Ray)],
        what: &str,
    ) -> usize {
        let mut lanes = vec![None; paths.len()];
        let mut moved = paths.to_vec();
        radiance_continued(world, limits, 2, &mut moved, |k, l, n| {
            assert!(lanes[k].is_none(), "{what}: path {k} finished twice");
            lanes[k] = Some((l.to_array().map(f32::to_bits), n));
        });
        let mut lit = 0;
        for (k, (s, ray)) in paths.iter().enumerate() {
            let mut s = s.clone();
            let (l, n) = radiance_from(world, limits, *ray, &mut s, 2);
            lit += usize::from(l != Rgb::ZERO);
            let want = Some((l.to_array().map(f32::to_bits), n));
            assert_eq!(lanes[k], want, "{what}, path {k}");
        }
        lit
    }

    let res = 37;
    for name in [
        "glass-mirror/scene.xml",
        "teapot-room/scene.xml",
        "two-rooms/glossy-floor.xml",
    ] {
        let world = World::new(load(name, res));
        let limits = DepthLimits {
            max_depth: None,
            rr_depth: 3,
            light_selection: LightSelection::Power,
        };
        // The second segments: from each pixel's first hit, a cosine
        // direction about the normal that faces the camera
        let mut rays = Vec::new();
        for k in 0..(res * res) as u64 {
            let (x, y) = ((k % res as u64) as f32 + 0.5, (k / res as u64) as f32 + 0.5);
            let ray = world.camera.ray(x, y);
            let Some(hit) = world.accel.intersect(&ray) else {
                continue;
            };
            let v = world.vertex(&ray, &hit);
            let mut u = Pcg32::keyed(&[11, k]);
            let wi = v.frame.to_world(cosine_hemisphere(u.next_2d()));
            rays.push((k, Ray::new(offset_point(v.sp.p, v.sp.ng, wi), wi)));
        }
        assert!(rays.len() > 500, "{name}: {} paths", rays.len());
        let pcg: Vec<_> = rays
            .iter()
            .map(|&(k, r)| {
                let mut s = Pcg32::keyed(&[5, k]);
                // the first vertex's draws
                let _ = (s.next_f32(), s.next_2d());
                (s, r)
            })
            .collect();
        let sobol: Vec<_> = rays
            .iter()
            .map(|&(k, r)| {
                let mut s = SobolSampler::new(5, k, 3);
                // the camera pass's draws before its second vertex
                let _ = (s.next_2d(), s.next_f32(), s.next_2d());
                (s, r)
            })
            .collect();
        // Some paths must carry light (glass-mirror's small lamp lights
        // about one in twenty of them)
        let lit = check(&world, &limits, &pcg, &format!("{name}, independent"));
        assert!(lit > rays.len() / 50, "{name}: {lit} lit paths");
        let lit = check(&world, &limits, &sobol, &format!("{name}, sobol"));
        assert!(lit > rays.len() / 50, "{name}: {lit} lit paths");
    }
}

/// Light-tracing walks with Sobol points in AVX lanes
/// ([`kalos::transport::lanes::light_walks`]) splat what the walks run one
/// by one ([`kalos::transport::light_tracing_walk`]) splat, in the same
/// order: the film's sums and the rays are the same bits. Both forms:
/// `light`'s (the albedo's roulette) and plb's mixture walks (the
/// throughput's roulette, the glossy split). Scenes with glass and mirrors
/// (glass-mirror), a glossy floor and smooth normals, whose vertices take
/// the scalar step, and with a depth limit. On a CPU without AVX2 both
/// sides are the scalar code and the test shows nothing.
#[test]
fn light_walk_lanes_give_the_scalar_splats_bit_for_bit() {
    use kalos::film::Film;
    use kalos::sampling::SobolWalkSampler;
    use kalos::transport::lanes::light_walks;
    use kalos::transport::{light_tracing_walk, WalkKind};
    // (scene, the share of pixels the walks must light: the glossy
    // floor's room is lit through a door, and most of it stays dark)
    for (name, lit_share) in [
        ("glass-mirror/scene.xml", 4),
        ("two-rooms/glossy-floor.xml", 16),
        ("teapot-room/scene.xml", 4),
        ("cbox/cbox.xml", 4),
    ] {
        let world = World::new(load(name, 24));
        let (w, h) = (world.camera.width, world.camera.height);
        for (max_depth, roulette, glossy_split) in [
            (None, Roulette::Albedo, false),
            (Some(3), Roulette::Albedo, false),
            (None, Roulette::Throughput, true),
        ] {
            let kind = WalkKind {
                max_depth,
                roulette,
                glossy_split,
            };
            let (seed, pass, walks) = (11, 2, 500..30_500);
            let mut lanes = Film::new(w, h);
            let rays_lanes = light_walks(&world, &kind, seed, pass, walks.clone(), &mut lanes);
            let mut one = Film::new(w, h);
            let mut rays_one = 0;
            for k in walks {
                let mut rng = SobolWalkSampler::new(seed, pass, k);
                rays_one += light_tracing_walk(&world, &kind, &mut rng, &mut one);
            }
            assert_eq!(rays_lanes, rays_one, "{name}, {kind:?}: rays");
            let bits = |f: &Film| -> Vec<[u64; 3]> {
                f.sum
                    .iter()
                    .map(|v| v.to_array().map(f64::to_bits))
                    .collect()
            };
            let lit = one.sum.iter().filter(|v| v.max_element() > 0.0).count();
            assert!(
                lit > (w * h / lit_share) as usize,
                "{name}: {lit} pixels lit"
            );
            assert!(bits(&lanes) == bits(&one), "{name}, {kind:?}: sums differ");
        }
    }
}
