//! The samplers of `path`, `light` and `plb` (`--sampler`): the
//! Owen-scrambled Sobol points checked directly (stratification of every
//! 1D and 2D draw, error that falls faster than 1/√N on smooth
//! integrands, `light`'s walk layout), and the methods with them
//! (furnace, agreement with independent numbers on cbox, the same image
//! whatever the thread count, the flag refused by the other methods).

use crate::common;

use glam::Vec2;
use kalos::film::Image;
use kalos::methods::{light, path, plb, Budget, Common, MethodConfig};
use kalos::sampling::sobol::{owen_scramble, sobol, vertex_dimension, SOBOL_DIMENSIONS};
use kalos::sampling::{Pcg32, Sampler, SamplerKind, SobolSampler, SobolWalkSampler};
use kalos::scene::Scene;

/// The smallest t for which the 2^m points are a (t, m, 2)-net in base 2:
/// every elementary interval [a/2^i, (a+1)/2^i) × [b/2^j, (b+1)/2^j) with
/// i + j = m − t holds exactly 2^t points.
fn t_value(pts: &[Vec2], m: u32) -> u32 {
    assert_eq!(pts.len(), 1 << m);
    (0..=m)
        .find(|&t| {
            let k = m - t;
            (0..=k).all(|i| {
                let j = k - i;
                let mut count = vec![0u32; 1 << k];
                for p in pts {
                    let a = (p.x * (1u32 << i) as f32) as usize;
                    let b = (p.y * (1u32 << j) as f32) as usize;
                    count[(a << j) | b] += 1;
                }
                count.iter().all(|&c| c == 1 << t)
            })
        })
        .expect("t = m always holds")
}

/// The first 2^m samples of one pixel, each drawn at dimension `dim` as a
/// 2D point (`dim` = 0 is the camera's first draw; past it the sampler is
/// moved there as a vertex would be, then advanced by 1D draws).
fn points_2d(seed: u64, pixel: u64, m: u32, dim: u32) -> Vec<Vec2> {
    (0..1u64 << m)
        .map(|i| {
            let mut s = SobolSampler::new(seed, pixel, i);
            if dim > 0 {
                s.start_vertex(1);
                while s.dimension() < dim {
                    s.next_f32();
                }
                assert_eq!(s.dimension(), dim);
            }
            s.next_2d()
        })
        .collect()
}

/// The camera's 2D draw is a scrambled (0,2)-sequence: for every 2^m up to
/// 4096 samples of a pixel, every elementary interval of area 2^−m holds
/// exactly one point, for several pixels and seeds (each its own scramble
/// and shuffle). The raw sequence's first 2^m points are too, and so is a
/// scrambled copy of them: Owen scrambling keeps the property.
#[test]
fn camera_draws_are_a_scrambled_0_2_sequence() {
    for m in 0..=12 {
        for (seed, pixel) in [(0, 0), (1, 7), (42, 123_456)] {
            let pts = points_2d(seed, pixel, m, 0);
            assert_eq!(
                t_value(&pts, m),
                0,
                "seed {seed} pixel {pixel}, 2^{m} points"
            );
        }
        let unit = |x: u32| (x >> 8) as f32 / 16_777_216.0;
        let raw: Vec<Vec2> = (0..1u32 << m)
            .map(|i| Vec2::new(unit(sobol(i, 0)), unit(sobol(i, 1))))
            .collect();
        assert_eq!(t_value(&raw, m), 0);
        let scrambled: Vec<Vec2> = (0..1u32 << m)
            .map(|i| {
                Vec2::new(
                    unit(owen_scramble(sobol(i, 0), 0x1234_5678)),
                    unit(owen_scramble(sobol(i, 1), 0x9abc_def0)),
                )
            })
            .collect();
        assert_eq!(t_value(&scrambled, m), 0);
    }
}

/// Every dimension of the table is stratified alone: 2^m samples put one
/// point in each interval [k/2^m, (k+1)/2^m).
#[test]
fn every_dimension_is_stratified_in_1d() {
    let m = 10;
    let mut samplers: Vec<SobolSampler> = (0..1u64 << m)
        .map(|i| SobolSampler::new(5, 99, i))
        .collect();
    for d in 0..SOBOL_DIMENSIONS {
        let mut hit = vec![false; 1 << m];
        for s in &mut samplers {
            let k = (s.next_f32() * (1u32 << m) as f32) as usize;
            assert!(!hit[k], "dimension {d}: two points in interval {k}");
            hit[k] = true;
        }
    }
}

/// The 2D draws of every vertex (the point on the light, the BSDF
/// direction) are nets with small t: at most 6 for 2^6, 2^8 and 2^10
/// points up to the eighth vertex, at most 3 for the first vertex
/// (measured for the table: 1 to 3 at the first vertex, 6 at worst, at
/// the eighth). Past the table the numbers are independent, and the same
/// check finds their t near m: so it can fail.
#[test]
fn every_vertex_2d_draw_is_a_net_with_small_t() {
    for m in [6, 8, 10] {
        for vertex in 1..=8 {
            let base = vertex_dimension(vertex);
            for dim in [base + 1, base + 4] {
                if dim + 1 >= SOBOL_DIMENSIONS as u32 {
                    continue;
                }
                let t = t_value(&points_2d(3, 17, m, dim), m);
                let bound = if vertex == 1 { 3 } else { 6 };
                assert!(
                    t <= bound,
                    "vertex {vertex} dimensions {dim}, {dim}+1: t = {t} at 2^{m}"
                );
            }
        }
    }
    let past = vertex_dimension(10) + 1;
    assert!(past as usize > SOBOL_DIMENSIONS);
    let t = t_value(&points_2d(3, 17, 10, past), 10);
    assert!(t >= 7, "independent numbers should not be a net: t = {t}");
}

/// The smallest t for which the 2^m points are a (t, m, 4)-net in base 2:
/// every elementary box with 2^a, 2^b, 2^c, 2^d intervals along the four
/// axes, a + b + c + d = m − t, holds exactly 2^t points.
fn t_value_4d(pts: &[[f32; 4]], m: u32) -> u32 {
    assert_eq!(pts.len(), 1 << m);
    (0..=m)
        .find(|&t| {
            let k = m - t;
            let mut parts = Vec::new();
            for a in 0..=k {
                for b in 0..=k - a {
                    for c in 0..=k - a - b {
                        parts.push([a, b, c, k - a - b - c]);
                    }
                }
            }
            parts.iter().all(|e| {
                let mut count = vec![0u32; 1 << k];
                for p in pts {
                    let mut cell = 0usize;
                    for (x, &bits) in p.iter().zip(e) {
                        cell = (cell << bits) | (x * (1u32 << bits) as f32) as usize;
                    }
                    count[cell] += 1;
                }
                count.iter().all(|&c| c == 1 << t)
            })
        })
        .expect("t = m always holds")
}

/// The first vertex's BSDF direction is stratified together with the
/// camera's draw: the 4D points (camera jitter, direction) of a pixel's
/// first 2^m samples are a (t, m, 4)-net with t ≤ 3 for m = 4 … 10
/// (measured: t = 2 or 3, on the Sobol dimensions 0, 1, 3, 4 that
/// `sobol::CAMERA_ROWS` gives the direction). Drawn at the Sobol
/// dimensions 6 and 7, in the order of the draws, t is 4 at 2^6, 2^8,
/// 2^9 and 2^10, so the check fails with that order; it cut cbox's error
/// per sample to 0.945 of it at 64 spp (docs/notebook/sampling.md).
#[test]
fn the_first_direction_is_stratified_with_the_camera() {
    for m in 4..=10 {
        let pts: Vec<[f32; 4]> = (0..1u64 << m)
            .map(|i| {
                let mut s = SobolSampler::new(11, 42, i);
                let camera = s.next_2d();
                s.start_vertex(1);
                s.next_f32(); // the light choice
                s.next_2d(); // the point on the light
                s.next_f32(); // the lobe
                let dir = s.next_2d();
                [camera.x, camera.y, dir.x, dir.y]
            })
            .collect();
        let t = t_value_4d(&pts, m);
        assert!(t <= 3, "camera and first direction: t = {t} at 2^{m}");
    }
}

/// Root-mean-square error, over 64 pixels (independent randomisations), of
/// the N-sample estimate of ∫∫ f over [0,1)², for N = 2^4 … 2^10, with the
/// 2D draw that `draw` makes; returns the slope of log RMSE against log N.
fn error_slope(draw: &dyn Fn(u64, u64) -> Vec2, f: &dyn Fn(Vec2) -> f64, exact: f64) -> f64 {
    let (mut xs, mut ys) = (Vec::new(), Vec::new());
    for k in 4..=10u32 {
        let n = 1u64 << k;
        let mse = (0..64u64)
            .map(|pixel| {
                let est = (0..n).map(|i| f(draw(pixel, i))).sum::<f64>() / n as f64;
                (est - exact).powi(2)
            })
            .sum::<f64>()
            / 64.0;
        xs.push(k as f64);
        ys.push(0.5 * mse.log2());
    }
    let (mx, my) = (
        xs.iter().sum::<f64>() / xs.len() as f64,
        ys.iter().sum::<f64>() / ys.len() as f64,
    );
    let sxy: f64 = xs.iter().zip(&ys).map(|(x, y)| (x - mx) * (y - my)).sum();
    let sxx: f64 = xs.iter().map(|x| (x - mx).powi(2)).sum();
    sxy / sxx
}

/// A smooth integrand's error falls faster than 1/√N. Owen-scrambled nets
/// give an RMSE of O(N^−3/2 (log N)^(1/2)) for smooth integrands (Owen
/// 1997), asymptotically; over 2^4 … 2^10 samples the measured slopes
/// are −1.46 for the camera draw (a (0,2)-sequence) and −1.17 for the
/// first vertex's light point (drawn at dimensions 3 and 4, which take the
/// Sobol dimensions 5 and 6, `sobol::CAMERA_ROWS`; their nets have t = 1
/// to 3 there); independent numbers give −1/2 (measured −0.55). The
/// asserts: steeper than −1.2 and −0.8, and flatter than −0.75 for
/// independent numbers (so that the measure tells them apart).
#[test]
fn smooth_integrand_error_falls_faster_than_one_over_sqrt_n() {
    let f = |p: Vec2| f64::from(p.x).exp() * (std::f64::consts::PI * f64::from(p.y)).sin();
    let exact = (std::f64::consts::E - 1.0) * 2.0 / std::f64::consts::PI;
    let camera = |pixel: u64, i: u64| SobolSampler::new(9, pixel, i).next_2d();
    let light = |pixel: u64, i: u64| {
        let mut s = SobolSampler::new(9, pixel, i);
        s.next_2d();
        s.start_vertex(1);
        s.next_f32();
        s.next_2d()
    };
    let independent = |pixel: u64, i: u64| Pcg32::keyed(&[9, i, pixel]).next_2d();
    let (sc, sl, si) = (
        error_slope(&camera, &f, exact),
        error_slope(&light, &f, exact),
        error_slope(&independent, &f, exact),
    );
    eprintln!("slopes: camera {sc:.2}, light point {sl:.2}, independent {si:.2}");
    assert!(sc < -1.2, "camera draw: slope {sc}");
    assert!(sl < -0.8, "light point: slope {sl}");
    assert!(si > -0.75, "independent: slope {si}");
}

fn path_with(sampler: SamplerKind) -> MethodConfig {
    MethodConfig::Path(path::Settings {
        sampler,
        ..Default::default()
    })
}

/// Mean over pixels and channels of one render.
fn image_mean(scene: &Scene, cfg: &MethodConfig, seed: u64, passes: u64) -> f64 {
    let (img, _) = common::render(scene, cfg, seed, passes);
    assert!(img.data.iter().all(|p| p.is_finite()));
    (0..3).map(|c| common::mean_and_se(&img, c).0).sum::<f64>() / 3.0
}

/// Mean and standard error of replicas.
fn mean_se(v: &[f64]) -> (f64, f64) {
    let n = v.len() as f64;
    let m = v.iter().sum::<f64>() / n;
    let var = v.iter().map(|x| (x - m).powi(2)).sum::<f64>() / (n - 1.0);
    (m, (var / n).sqrt())
}

/// The white furnace (albedo 0.5, Le = 1: L = 2 everywhere) with Sobol
/// points: 8 replicas (seeds) of 16 spp at 16 × 16; the bound is the
/// 99.9 % Student-t quantile for 7 degrees of freedom (5.41) times their
/// standard error, and must be under 1 % of the value.
#[test]
fn path_with_sobol_passes_the_furnace() {
    let scene = common::furnace(0.5, 1.0, 16);
    let v: Vec<f64> = (0..8)
        .map(|s| image_mean(&scene, &path_with(SamplerKind::Sobol), 100 + s, 16))
        .collect();
    let (m, se) = mean_se(&v);
    let tol = 5.41 * se;
    eprintln!("furnace, sobol: {m:.5} ± {tol:.1e}");
    assert!((m - 2.0).abs() <= tol, "mean {m} vs 2 ± {tol}");
    assert!(tol < 0.02, "tolerance {tol} too wide to judge");
}

fn cbox(res: u32) -> Scene {
    let root = std::path::PathBuf::from(env!("CARGO_MANIFEST_DIR"));
    let mut s = kalos::scene::load(&root.join("scenes/cbox/cbox.xml")).expect("scene");
    s.set_resolution(res, res);
    s
}

/// On cbox, Sobol and independent numbers estimate the same image: the
/// image means of 8 replicas (48 × 48, 128 spp) each agree within 5.41 standard errors of
/// their difference (Welch; 5.41 is the 99.9 % t quantile for the 7
/// degrees of freedom of one side, conservative for both), and 8 × 8
/// blocks of two renders of 64 spp each agree within |z| < 4.5 (108
/// block-channel z values: a false alarm about once in 1000 runs).
#[test]
fn path_with_sobol_agrees_with_independent_on_cbox() {
    let (sobol, indep) = (
        path_with(SamplerKind::Sobol),
        path_with(SamplerKind::Independent),
    );
    sobol_agrees_with_independent(&cbox(48), "path", &sobol, &indep, 128);
}

/// The two tests of a Sobol method against its independent form on
/// `scene`: the image means of 8 replicas of `spp` samples (or passes)
/// within 5.41 standard errors of their difference, and 8 × 8 blocks of
/// two renders of 64 within |z| < 4.5.
fn sobol_agrees_with_independent(
    scene: &Scene,
    label: &str,
    sobol: &MethodConfig,
    indep: &MethodConfig,
    spp: u64,
) {
    let vs: Vec<f64> = (0..8)
        .map(|s| image_mean(scene, sobol, 10 + s, spp))
        .collect();
    let vi: Vec<f64> = (0..8)
        .map(|s| image_mean(scene, indep, 10 + s, spp))
        .collect();
    let ((ms, ss), (mi, si)) = (mean_se(&vs), mean_se(&vi));
    let tol = 5.41 * (ss * ss + si * si).sqrt();
    eprintln!("cbox {label} means: sobol {ms:.5}, independent {mi:.5}, tolerance {tol:.1e}");
    assert!(
        (ms - mi).abs() <= tol,
        "sobol {ms} vs independent {mi} ± {tol}"
    );
    assert!(tol < 0.02 * mi, "tolerance {tol} too wide to judge");

    let blocks = |cfg: &MethodConfig| {
        let (a, _) = common::render(scene, cfg, 1, 64);
        let (b, _) = common::render(scene, cfg, 2, 64);
        common::block_stats(&a, &b, 8, &|_, _| true)
    };
    let (z, block) = common::max_block_z(&blocks(sobol), &blocks(indep), 1e-4);
    assert!(z < 4.5, "block {block} differs by {z:.2} standard errors");
}

/// A seed gives the same image with Sobol points whatever the thread
/// count; another seed gives another, and independent numbers another.
#[test]
fn sobol_images_do_not_depend_on_the_thread_count() {
    assert_same_image_whatever_the_threads(
        &cbox(24),
        &path_with(SamplerKind::Sobol),
        &path_with(SamplerKind::Independent),
    );
}

/// Three passes of `cfg` on `scene` under `seed`, on a pool of `threads`.
fn render_on(threads: usize, scene: &Scene, cfg: &MethodConfig, seed: u64) -> (Image, u64) {
    rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .build()
        .expect("pool")
        .install(|| {
            common::render_budget(
                scene,
                cfg,
                &Common {
                    seed,
                    max_depth: None,
                },
                Budget {
                    passes: Some(3),
                    ..Default::default()
                },
            )
        })
}

/// Seed 42 gives `sobol` the same image on 1, 2 and 3 threads (and the
/// same ray count on 1 and 2); seed 43 gives another, and `indep` (the
/// same method with independent numbers) another, so the check can fail.
fn assert_same_image_whatever_the_threads(
    scene: &Scene,
    sobol: &MethodConfig,
    indep: &MethodConfig,
) {
    let one = render_on(1, scene, sobol, 42);
    let two = render_on(2, scene, sobol, 42);
    let three = render_on(3, scene, sobol, 42);
    assert_eq!(one.1, two.1, "{sobol:?}: ray counts differ");
    assert!(
        one.0 == two.0 && two.0 == three.0,
        "{sobol:?}: images differ with the thread count"
    );
    assert!(
        render_on(2, scene, sobol, 43).0 != one.0,
        "{sobol:?}: the seed changes nothing"
    );
    assert!(
        render_on(2, scene, indep, 42).0 != one.0,
        "{sobol:?}: the sampler changes nothing"
    );
}

/// `path`'s eight AVX lanes draw from the Sobol sampler as the scalar
/// path does (each lane its own pixel's point, each vertex its own
/// dimensions) and give every pixel the scalar estimator's radiance and
/// ray count bit for bit, as `transport::lanes_give_the_scalar_radiance_bit_for_bit`
/// checks for independent numbers: on scenes that mix diffuse surfaces
/// with glass, mirrors and rough metal, with both light selections, with
/// a depth limit and early Russian roulette, and with paths of 14 vertices
/// that reach the hashed dimensions past the table; at passes 0, 1, 37 and
/// 300 (the shuffled sample index: one, two and three nibbles of the
/// tables); the jitters are drawn and the camera rays made in lanes too.
/// On a CPU without AVX2 both sides are the scalar code and the test shows
/// nothing.
#[test]
fn sobol_lanes_give_the_scalar_radiance_bit_for_bit() {
    use kalos::emitter::LightSelection;
    use kalos::scene::Rgb;
    use kalos::transport::lanes::radiance_camera_row;
    use kalos::transport::{radiance_from_hit, DepthLimits};
    use kalos::world::World;
    let root = std::path::PathBuf::from(env!("CARGO_MANIFEST_DIR"));
    let mut deep = 0;
    for (name, res) in [
        ("glass-mirror/scene.xml", 37),
        ("teapot-room/scene.xml", 32),
        ("cbox/cbox.xml", 32),
    ] {
        let mut scene = kalos::scene::load(&root.join("scenes").join(name)).expect("scene");
        scene.set_resolution(res, res);
        let world = World::new(scene);
        let w = world.camera.width as usize;
        for (pass, light_selection, max_depth, rr_depth) in [
            (0, LightSelection::Spatial, None, 5),
            (1, LightSelection::Power, Some(4), 1),
            (37, LightSelection::Spatial, Some(14), 20),
            (300, LightSelection::Power, None, 5),
        ] {
            let limits = DepthLimits {
                max_depth,
                rr_depth,
                light_selection,
            };
            let mut nonzero = 0;
            for y in 0..world.camera.height as usize {
                let sampler = |x: usize| SobolSampler::new(7, (y * w + x) as u64, pass);
                let start = |x: usize| {
                    let mut s = sampler(x);
                    let j = s.next_2d();
                    (s, world.camera.ray(x as f32 + j.x, y as f32 + j.y))
                };
                let mut lanes = vec![None; w];
                radiance_camera_row(&world, &limits, y, sampler, |x, l, n| {
                    assert!(lanes[x].is_none(), "pixel {x} finished twice");
                    lanes[x] = Some((l.to_array().map(f32::to_bits), n));
                });
                for (x, got) in lanes.iter().enumerate() {
                    let (mut s, ray) = start(x);
                    let (l, n) = radiance_from_hit(&world, &limits, ray, None, &mut s, 1);
                    nonzero += usize::from(l != Rgb::ZERO);
                    deep += usize::from(s.dimension() as usize > SOBOL_DIMENSIONS);
                    assert_eq!(
                        *got,
                        Some((l.to_array().map(f32::to_bits), n)),
                        "{name}, pass {pass}, {light_selection:?}, pixel ({x}, {y})"
                    );
                }
            }
            assert!(
                nonzero > w * w / 4,
                "{name}: too few lit pixels ({nonzero})"
            );
        }
    }
    assert!(
        deep > 100,
        "only {deep} paths reached the hashed dimensions"
    );
}

/// `--sampler` is a setting of `path`, `light` and `plb`: another method
/// refuses it with the message that names them, and `path` refuses an
/// unknown sampler.
#[test]
fn other_methods_refuse_the_sampler_flag() {
    let o = common::kalos(&[
        "render",
        "--method",
        "density",
        "--res",
        "8x8",
        "--spp",
        "1",
        "--sampler",
        "sobol",
        "-o",
        "/dev/null",
    ]);
    assert!(!o.status.success());
    let e = common::stderr(&o);
    assert!(
        e.contains("--sampler") && e.contains("'path'") && e.contains("'light'"),
        "{e}"
    );
    let o = common::kalos(&[
        "render",
        "--res",
        "8x8",
        "--spp",
        "1",
        "--sampler",
        "halton",
    ]);
    assert!(!o.status.success());
    assert!(common::stderr(&o).contains("halton"));
}

/// The first 2^m walks of a pass as `light --sampler sobol` draws them:
/// each walk's numbers at dimensions 0 to 8 (the emission's five, then the
/// first vertex's roulette, lobe and direction), in the walk's order.
fn walk_points(seed: u64, pass: u64, m: u32) -> Vec<[f32; 9]> {
    (0..1u64 << m)
        .map(|k| {
            let mut s = SobolWalkSampler::new(seed, pass, k);
            let (sel, pos, dir) = (s.next_f32(), s.next_2d(), s.next_2d());
            s.start_vertex(1);
            assert_eq!(s.dimension(), 5);
            let (rr, lobe, wi) = (s.next_f32(), s.next_f32(), s.next_2d());
            [sel, pos.x, pos.y, dir.x, dir.y, rr, lobe, wi.x, wi.y]
        })
        .collect()
}

/// `light`'s walks with Sobol points: the first 2^m walks of a pass put
/// one number in each interval [k/2^m, (k+1)/2^m) of every 1D draw (the
/// light choice, the roulette, the lobe), and their 2D draws (the point
/// on the light, the direction of emission, the first bounce's direction)
/// are nets of small t (1 to 3 at 2^6 … 2^12, the t of Joe and Kuo's
/// dimensions 1–2, 3–4 and 7–8, which the scramble keeps; bound 3). Another
/// pass is another randomisation; each vertex starts at its own four
/// dimensions; past the table the numbers are independent.
#[test]
fn light_walk_draws_are_stratified_within_a_pass() {
    for m in [6, 8, 10, 12] {
        for (seed, pass) in [(0, 0), (7, 3)] {
            let pts = walk_points(seed, pass, m);
            for d in [0, 5, 6] {
                let mut hit = vec![false; 1 << m];
                for p in &pts {
                    let k = (p[d] * (1u32 << m) as f32) as usize;
                    assert!(!hit[k], "2^{m}, dimension {d}: two walks in interval {k}");
                    hit[k] = true;
                }
            }
            for d in [1, 3, 7] {
                let xy: Vec<Vec2> = pts.iter().map(|p| Vec2::new(p[d], p[d + 1])).collect();
                let t = t_value(&xy, m);
                assert!(t <= 3, "2^{m}, dimensions {d}, {}: t = {t}", d + 1);
            }
        }
    }
    assert!(
        walk_points(0, 0, 4) != walk_points(0, 1, 4),
        "the pass changes nothing"
    );
    for depth in 1..20 {
        let mut s = SobolWalkSampler::new(1, 2, 3);
        s.start_vertex(depth);
        assert_eq!(s.dimension(), 5 + 4 * (depth - 1));
    }
    // Vertex 16's direction is past the table: independent numbers
    let past: Vec<Vec2> = (0..1u64 << 10)
        .map(|k| {
            let mut s = SobolWalkSampler::new(3, 4, k);
            s.start_vertex(16);
            s.next_f32();
            s.next_f32();
            assert!(s.dimension() as usize >= SOBOL_DIMENSIONS);
            s.next_2d()
        })
        .collect();
    let t = t_value(&past, 10);
    assert!(t >= 7, "independent numbers should not be a net: t = {t}");
}

fn light_with(sampler: SamplerKind) -> MethodConfig {
    common::light(light::Settings {
        sampler,
        ..Default::default()
    })
}

/// The white furnace (L = 2) with `light --sampler sobol`: 8 replicas of
/// 256 passes at 16 × 16, within 5.41 standard errors (the 99.9 % t
/// quantile, 7 degrees of freedom), a bound under 2 % of the value.
#[test]
fn light_with_sobol_passes_the_furnace() {
    let scene = common::furnace(0.5, 1.0, 16);
    let v: Vec<f64> = (0..8)
        .map(|s| image_mean(&scene, &light_with(SamplerKind::Sobol), 100 + s, 256))
        .collect();
    let (m, se) = mean_se(&v);
    let tol = 5.41 * se;
    eprintln!("furnace, light sobol: {m:.5} ± {tol:.1e}");
    assert!((m - 2.0).abs() <= tol, "mean {m} vs 2 ± {tol}");
    assert!(tol < 0.04, "tolerance {tol} too wide to judge");
}

/// On cbox, `light` estimates the same image with Sobol points as with
/// independent numbers: image means of 8 replicas (32 × 32, 64 passes)
/// within 5.41 standard errors of their difference, and 8 × 8 blocks of
/// two renders of 64 passes each within |z| < 4.5.
#[test]
fn light_with_sobol_agrees_with_independent_on_cbox() {
    let (sobol, indep) = (
        light_with(SamplerKind::Sobol),
        light_with(SamplerKind::Independent),
    );
    sobol_agrees_with_independent(&cbox(32), "light", &sobol, &indep, 64);
}

/// `light --sampler sobol` (walks and camera pass) and `plb --sampler
/// sobol` (camera pass) give a seed the same image whatever the thread
/// count, on glass-mirror (mirror and glass seen by the camera, so the
/// camera pass runs); another seed, or independent numbers, another.
#[test]
fn light_and_plb_sobol_images_do_not_depend_on_the_thread_count() {
    let root = std::path::PathBuf::from(env!("CARGO_MANIFEST_DIR"));
    let mut scene = kalos::scene::load(&root.join("scenes/glass-mirror/scene.xml")).expect("scene");
    scene.set_resolution(24, 24);
    let plb_with = |sampler| {
        common::plb(plb::Settings {
            sampler,
            ..Default::default()
        })
    };
    for (sobol, indep) in [
        (
            light_with(SamplerKind::Sobol),
            light_with(SamplerKind::Independent),
        ),
        (
            plb_with(SamplerKind::Sobol),
            plb_with(SamplerKind::Independent),
        ),
    ] {
        assert_same_image_whatever_the_threads(&scene, &sobol, &indep);
    }
}
