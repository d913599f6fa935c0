//! `plb` (progressive light path building) against the Mitsuba reference on
//! `cbox`, and against `light` on `two-rooms`. All tolerances come from
//! noise measured in the same test (independent seeds), never from stored
//! expected values.

use crate::common;

use std::path::PathBuf;

use kalos::film::Image;
use kalos::image_io::read_image;
use kalos::methods::{plb, MethodConfig};
use kalos::metrics::{channel_means, rel_mse, rel_mse_pair};
use kalos::scene::{self, Scene};

fn root() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

fn load(file: &str) -> Scene {
    scene::load(&root().join(file)).expect("scene loads")
}

/// Renders with `method`'s default settings.
fn render(scene: &Scene, method: &str, seed: u64, passes: u64) -> Image {
    let cfg = (kalos::methods::by_name(method).expect("method").default)();
    common::render(scene, &cfg, seed, passes).0
}

/// Per-channel image means of several renders: their average and the
/// standard error of that average, from the spread across seeds (the seeds
/// are independent, whatever the correlation between pixels of one render).
fn means_and_se(imgs: &[Image]) -> ([f64; 3], [f64; 3]) {
    let k = imgs.len() as f64;
    let ms: Vec<[f64; 3]> = imgs
        .iter()
        .map(|i| {
            let m = channel_means(i);
            [m.x, m.y, m.z]
        })
        .collect();
    let mut mean = [0.0; 3];
    let mut se = [0.0; 3];
    for ch in 0..3 {
        mean[ch] = ms.iter().map(|m| m[ch]).sum::<f64>() / k;
        let var = ms.iter().map(|m| (m[ch] - mean[ch]).powi(2)).sum::<f64>() / (k - 1.0);
        se[ch] = (var / k).sqrt();
    }
    (mean, se)
}

/// Pixel-wise average of images.
fn average(imgs: &[Image]) -> Image {
    let mut out = imgs[0].clone();
    for (i, p) in out.data.iter_mut().enumerate() {
        *p = imgs.iter().map(|im| im.data[i]).sum::<glam::Vec3>() / imgs.len() as f32;
    }
    out
}

/// `cbox`: the paper's plb converges to the Mitsuba reference, with a
/// start-up defect that shrinks with run length.
///
/// The defect. The self-correcting iteration starts from L_0 = Le, so the
/// early estimates lack the higher bounces (the power defect of eq. (18) of
/// the 1999 stochastic-iteration paper). With the survivors of a purge
/// weighted as one phase of history (see `src/methods/plb/mod.rs`), the
/// expected error of the phase images falls geometrically, and the average
/// of N phase images keeps a deficit of order 1/N. Measured with these runs
/// (32 seeds at 1 pass, 16 at 8 passes, as here; docs/notebook/plb.md): about −0.6 % of
/// the red channel mean after 1 pass and under −0.1 % after 8 passes, green
/// and blue smaller.
///
/// What is asserted.
/// 1. The deficit shrinks: for the red channel (the largest albedo, so the
///    slowest to converge), the 8-pass deficit is smaller than the 1-pass one
///    by more than 3 standard errors of the difference.
/// 2. The long run is within noise plus the stated bias: on every channel,
///    |mean − reference| ≤ 4 σ + 1.5 · (|short-run deficit| + 2 σ₁)/8, σ
///    being the standard error of the 16-seed mean measured from the seed
///    spread, the second term the 1/N law applied to the deficit measured at
///    1 pass. That deficit is itself a 32-seed estimate with standard error
///    σ₁, so the law is applied to its upper bound at 2 σ₁ (a point
///    estimate understated the blue deficit; docs/notebook/plb.md, plb, "The
///    start-up test's bias bound"), with 50 % slack for the law itself.
/// 3. relMSE of one 8-pass render against the reference is at most 1.5 × its
///    expectation from noise, relMSE(k₁, k₂)/2 + the reference's own
///    half-versus-half figure / 4, as in tests/reference.rs.
#[test]
#[ignore = "slow tier: cargo test --release -- --ignored"]
fn plb_cbox_converges_with_shrinking_startup_defect() {
    let scene = load("scenes/cbox/cbox.xml");
    let reference = read_image(&root().join("refs/cbox.pfm")).expect("reference");
    let mr = channel_means(&reference);
    let mr = [mr.x, mr.y, mr.z];
    let paper = common::plb(plb::Settings {
        variant: plb::Variant::Paper,
        ..Default::default()
    });
    let render = |seed, passes| common::render(&scene, &paper, seed, passes).0;
    let short: Vec<Image> = (1..=32u64).map(|s| render(s, 1)).collect();
    let long: Vec<Image> = (101..=116u64).map(|s| render(s, 8)).collect();
    let (ms, ses) = means_and_se(&short);
    let (ml, sel) = means_and_se(&long);
    for ch in 0..3 {
        eprintln!(
            "channel {ch}: reference {:.6}; 1 pass {:+.4} % ± {:.4} %; 8 passes {:+.4} % ± {:.4} %",
            mr[ch],
            100.0 * (ms[ch] / mr[ch] - 1.0),
            100.0 * ses[ch] / mr[ch],
            100.0 * (ml[ch] / mr[ch] - 1.0),
            100.0 * sel[ch] / mr[ch],
        );
    }

    // 1. the defect shrinks with run length (red channel)
    let (ds, dl) = (ms[0] - mr[0], ml[0] - mr[0]);
    let se_diff = (ses[0].powi(2) + sel[0].powi(2)).sqrt();
    assert!(
        dl.abs() < ds.abs() - 3.0 * se_diff,
        "start-up defect does not shrink: 1 pass {ds:+.3e}, 8 passes {dl:+.3e} (σ of difference {se_diff:.2e})"
    );

    // 2. the long run: noise plus the stated (measured, 1/N) bias
    for ch in 0..3 {
        let bias = 1.5 * ((ms[ch] - mr[ch]).abs() + 2.0 * ses[ch]) / 8.0;
        let tol = 4.0 * sel[ch] + bias;
        assert!(
            (ml[ch] - mr[ch]).abs() <= tol,
            "channel {ch}: 8-pass mean {} vs reference {} (tolerance {tol:.3e} = 4σ + bias {bias:.3e})",
            ml[ch],
            mr[ch]
        );
    }

    // 3. relMSE within its noise expectation
    let own = rel_mse(&long[0], &long[1]).expect("sizes") / 2.0;
    let expected = own + 1.525e-5 / 4.0; // refs/NOISE: cbox half-vs-half
    let got = rel_mse(&long[0], &reference).expect("sizes");
    eprintln!("relMSE {got:.4e}, expected {expected:.4e}");
    assert!(
        got <= 1.5 * expected,
        "relMSE {got:.4e} > 1.5 × expected {expected:.4e}"
    );
}

/// `two-rooms`: plb and light agree within noise at a small budget.
///
/// Tolerances from the measured noise: each method renders with seeds 1 and
/// 2, and x̄ is the average of the two. For independent unbiased estimates,
/// per pixel E[(x₁ − x₂)²/4] = var(x̄), so with the plain (absolute) MSE over
/// pixels and channels, E[MSE(p̄, l̄)] = v_p + v_l with v_x = MSE(x₁, x₂)/4,
/// exactly. The test asserts MSE(p̄, l̄) ≤ 1.5 × (v_p + v_l). (A relative MSE
/// whose denominator is the noisy pair itself is not used: on this
/// firefly-prone scene its denominator noise made the same check fail for
/// reasons unrelated to bias: relMSE(p̄, l̄) was 0.30 against a "predicted"
/// 0.18 while the absolute MSE matched its prediction within 1 %.) The
/// channel means of p̄ and l̄ must agree within 4 standard errors, each
/// estimated from the per-pixel differences of its two seeds (var(pixel) ≈
/// (x₁ − x₂)²/2). plb's start-up defect at this budget (under 0.1 % on cbox,
/// see above) is far below these tolerances.
#[test]
#[ignore = "slow tier: cargo test --release -- --ignored"]
fn plb_agrees_with_light_on_two_rooms() {
    agrees_with_light("scenes/two-rooms/scene.xml", plb::Variant::Paper);
}

/// `--variant pooled` (the grid-pooled importance, not in the paper) is
/// unbiased too: the same check as above, on the hidden-gap variant where
/// every pixel is lit through the gap (its intended use).
#[test]
fn plb_pooled_agrees_with_light_on_hidden_gap() {
    agrees_with_light("scenes/two-rooms/hidden-gap.xml", plb::Variant::Pooled);
}

/// The check of `plb_agrees_with_light_on_two_rooms`, for a scene and a plb
/// variant.
fn agrees_with_light(file: &str, variant: plb::Variant) {
    let scene = load(file);
    let plb = |seed: u64| {
        let cfg = common::plb(plb::Settings {
            variant,
            ..Default::default()
        });
        common::render(&scene, &cfg, seed, 40).0
    };
    let p = [plb(1), plb(2)];
    let l = [
        render(&scene, "light", 1, 30),
        render(&scene, "light", 2, 30),
    ];
    // MSE with fixed (data-independent) weights: an unbiased estimate of
    // each variance, E[(x₁ − x₂)²/4] = var(x̄), so no denominator noise
    let mse = |a: &Image, b: &Image| {
        a.data
            .iter()
            .zip(&b.data)
            .map(|(x, y)| (*x - *y).as_dvec3().length_squared() / 3.0)
            .sum::<f64>()
            / a.data.len() as f64
    };
    let vp = mse(&p[0], &p[1]) / 4.0;
    let vl = mse(&l[0], &l[1]) / 4.0;
    let (pa, la) = (average(&p), average(&l));
    let got = mse(&pa, &la);
    let rel = rel_mse_pair(&pa, &la).expect("sizes");
    eprintln!(
        "MSE(plb, light) {got:.4e}, expected {:.4e} (plb {vp:.3e}, light {vl:.3e}); relMSE {rel:.3e}",
        vp + vl
    );
    let se = |x: &[Image; 2]| {
        let n = x[0].data.len() as f64;
        let mut out = [0.0; 3];
        for (ch, o) in out.iter_mut().enumerate() {
            let s: f64 = x[0]
                .data
                .iter()
                .zip(&x[1].data)
                .map(|(a, b)| ((a[ch] - b[ch]) as f64).powi(2) / 2.0)
                .sum();
            // variance of one pixel, over n pixels, for a 2-seed average
            *o = (s / n / n / 2.0).sqrt();
        }
        out
    };
    let (sp, sl) = (se(&p), se(&l));
    let (mp, ml) = (channel_means(&pa), channel_means(&la));
    for ch in 0..3 {
        let tol = 4.0 * (sp[ch].powi(2) + sl[ch].powi(2)).sqrt();
        eprintln!(
            "channel {ch}: plb {:.6} light {:.6} (diff {:+.2e}, 4σ {tol:.2e})",
            mp[ch],
            ml[ch],
            mp[ch] - ml[ch]
        );
        assert!(
            (mp[ch] - ml[ch]).abs() <= tol,
            "channel {ch}: plb mean {} vs light {} (4σ = {tol})",
            mp[ch],
            ml[ch]
        );
    }
    assert!(
        got <= 1.5 * (vp + vl),
        "MSE(plb, light) {got:.4e} > 1.5 × {:.4e}",
        vp + vl
    );
}

/// The same seed gives the same image (the lanes are fixed and merged in
/// order), and the settings reach the method.
#[test]
fn plb_is_deterministic_per_seed() {
    let scene = load("scenes/cbox/cbox.xml");
    let a = render(&scene, "plb", 7, 1);
    let b = render(&scene, "plb", 7, 1);
    assert_eq!(a.data, b.data);
    let opts = common::plb(plb::Settings {
        lambda: 0.0,
        phase_len: 100,
        population: 50,
        ..Default::default()
    });
    let c = common::render(&scene, &opts, 7, 1).0;
    assert_ne!(a.data, c.data);
    let bad = MethodConfig::Plb(plb::Settings {
        phase_len: 0,
        ..Default::default()
    });
    let pooled = common::plb(plb::Settings {
        variant: plb::Variant::Pooled,
        ..Default::default()
    });
    let d = common::render(&scene, &pooled, 7, 1).0;
    assert_ne!(a.data, d.data);
    assert_eq!(d.data, common::render(&scene, &pooled, 7, 1).0.data);
    // The guided form alone, without the light-tracing walks beside it
    let alone = common::plb(plb::Settings {
        mix: false,
        ..Default::default()
    });
    let e = common::render(&scene, &alone, 7, 1).0;
    assert_ne!(a.data, e.data);
    assert_eq!(e.data, common::render(&scene, &alone, 7, 1).0.data);
    // The mixture without `path` beside it (cbox needs no camera pass, so
    // the default runs it)
    let no_path = common::plb(plb::Settings {
        mix_path: false,
        ..Default::default()
    });
    let f = common::render(&scene, &no_path, 7, 1).0;
    assert_ne!(a.data, f.data);
    assert_ne!(e.data, f.data);
    assert_eq!(f.data, common::render(&scene, &no_path, 7, 1).0.data);
    let world = kalos::methods::World::new(scene);
    let err = bad
        .create(&world, &Default::default())
        .err()
        .expect("phase length 0 is refused");
    assert!(err.to_string().contains("--phase-len"), "{err}");
}

/// kalos's default plb (`--variant guided`: pooled importance learnt
/// through the path, guided spawned and emitted rays, hits measured at
/// birth, the glossy camera pass with MIS) against `path`, block by block.
///
/// How images are compared. Each method renders twice with independent
/// seeds; the images are cut into 16×16-pixel blocks. A block mean of the
/// two-render average has variance var_b, estimated per block from the
/// pixels, Σ_pixels (x₁ − x₂)²/4 / n² ([`common::block_stats`], which
/// assumes independent pixels). plb's pixels are not independent (a
/// population's hits light neighbouring pixels together), so the pixel
/// estimate is scaled by an inflation c, measured from the same renders:
/// over all blocks and channels, c = Σ (m₁ − m₂)²/4 / Σ var_b, m₁ and m₂
/// the block's means in each render (an unbiased estimate of the same
/// variance whatever the correlation, pooled over the blocks because one
/// block's two renders give it one degree of freedom); c is floored at 1.
/// Then z = (m_a − m_b)/√(c_a var_a + c_b var_b) per block and channel, and
/// the threshold is Šidák's for a 1 % false-alarm rate over all of them,
/// Φ⁻¹(1 − 0.01/(2·3·blocks)), plus 0.5 for the imperfect normality of
/// block means made of heavy-tailed pixels (the margin tests/it/camera_pass.rs
/// uses); a small absolute floor (1e-4) covers blocks black in both. Blocks
/// of 16×16 (not 8×8) and twice plb's rays for `path`: on two-rooms-baffle
/// the path tracer's pixels behind the screen are rare large values, and
/// smaller blocks left its block means visibly skewed (measured: path
/// against the Mitsuba reference gave |z| up to 13 at 8×8 and 12 M rays,
/// with no bias at larger budgets).
fn guided_agrees_with_path(file: &str, rays: u64) {
    let scene = load(file);
    let run = |cfg: &MethodConfig, seed, rays| {
        let budget = kalos::methods::Budget {
            rays: Some(rays),
            ..Default::default()
        };
        let c = kalos::methods::Common {
            seed,
            max_depth: None,
        };
        common::render_budget(&scene, cfg, &c, budget).0
    };
    let guided = common::plb(plb::Settings::default());
    let path = common::path();
    let (g1, g2) = (run(&guided, 21, rays), run(&guided, 22, rays));
    let (p1, p2) = (run(&path, 21, 2 * rays), run(&path, 22, 2 * rays));
    const B: u32 = 16;
    let g = common::block_stats(&g1, &g2, B, &|_, _| true);
    let p = common::block_stats(&p1, &p2, B, &|_, _| true);
    let (cg, cp) = (inflation(&g1, &g2, &g, B), inflation(&p1, &p2, &p, B));
    let scale = |s: &[Option<([f64; 3], [f64; 3])>], c: f64| -> Vec<_> {
        s.iter()
            .map(|b| b.map(|(m, v)| (m, v.map(|x| x * c))))
            .collect()
    };
    let (g, p) = (scale(&g, cg), scale(&p, cp));
    let blocks = g.iter().filter(|b| b.is_some()).count();
    let z_max = sidak_z(0.01, 2 * 3 * blocks) + 0.5;
    let (z, block) = common::max_block_z(&g, &p, 1e-4);
    eprintln!(
        "{file}: guided plb vs path: max |z| = {z:.2} (block {block}, threshold {z_max:.2}; inflation plb {cg:.2}, path {cp:.2})"
    );
    assert!(
        z < z_max,
        "{file}: guided plb disagrees with path: |z| = {z:.2} in block {block} (threshold {z_max:.2})"
    );
}

/// The inflation c ≥ 1 of the pixel-based block variances `stats` of the
/// two renders x₁, x₂ (see `guided_agrees_with_path`).
fn inflation(x1: &Image, x2: &Image, stats: &[Option<([f64; 3], [f64; 3])>], b: u32) -> f64 {
    let one = common::block_stats(x1, x1, b, &|_, _| true);
    let two = common::block_stats(x2, x2, b, &|_, _| true);
    let (mut seed, mut pixel) = (0.0, 0.0);
    for ((s, m1), m2) in stats.iter().zip(&one).zip(&two) {
        if let (Some((_, v)), Some((m1, _)), Some((m2, _))) = (s, m1, m2) {
            for c in 0..3 {
                seed += (m1[c] - m2[c]).powi(2) / 4.0;
                pixel += v[c];
            }
        }
    }
    if pixel > 0.0 {
        (seed / pixel).max(1.0)
    } else {
        1.0
    }
}

/// Φ⁻¹(1 − α/n): the two-sided Šidák bound for n tests (as one-sided
/// quantile of n = 2 × tests), by bisection on the normal tail
/// erfc(z/√2)/2, which is exact enough for a threshold.
fn sidak_z(alpha: f64, n: usize) -> f64 {
    let target = alpha / n as f64;
    let tail = |z: f64| 0.5 * kalos::sampling::erfc(z / std::f64::consts::SQRT_2);
    let (mut lo, mut hi) = (0.0f64, 10.0f64);
    for _ in 0..100 {
        let mid = 0.5 * (lo + hi);
        if tail(mid) > target {
            lo = mid;
        } else {
            hi = mid;
        }
    }
    0.5 * (lo + hi)
}

#[test]
fn sidak_threshold_matches_the_normal_table() {
    // Φ⁻¹(1 − 0.005) = 2.5758, Φ⁻¹(1 − 0.01/384) = 4.046 (the bound
    // in tests/it/camera_pass.rs)
    assert!((sidak_z(0.01, 2) - 2.5758).abs() < 1e-3);
    assert!((sidak_z(0.01, 384) - 4.046).abs() < 0.01);
}

/// The scene the guided form is for: light through the gap lands first
/// behind a screen that hides it from the camera.
#[test]
#[ignore = "slow tier: cargo test --release -- --ignored"]
fn guided_plb_agrees_with_path_on_two_rooms_baffle() {
    guided_agrees_with_path("scenes/two-rooms-baffle/scene.xml", 12_000_000);
}

/// A polished floor in view: the glossy camera pass and the light paths
/// share the floor's paths by MIS; double counting would brighten the
/// floor's reflections.
#[test]
#[ignore = "slow tier: cargo test --release -- --ignored"]
fn guided_plb_agrees_with_path_on_a_glossy_floor() {
    guided_agrees_with_path("scenes/two-rooms/glossy-floor.xml", 12_000_000);
}

#[test]
#[ignore = "slow tier: cargo test --release -- --ignored"]
fn guided_plb_agrees_with_path_on_cbox() {
    guided_agrees_with_path("scenes/cbox/cbox.xml", 12_000_000);
}
