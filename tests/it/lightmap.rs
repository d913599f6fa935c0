//! Tests of the lightmap bake (`kalos bake --lightmap`): the estimator's
//! error bars, leaks, seams, and the command line.

use std::path::PathBuf;
use std::time::Instant;

use glam::Vec3;
use kalos::bake::lightmap::bake::{self as lmbake, LightmapBake, LightmapSettings, Steering};
use kalos::bake::lightmap::estimate::{Estimator, HitIndex, Options, TexelEstimate};
use kalos::bake::lightmap::gather::GatherOptions;
use kalos::bake::lightmap::Texel;
use kalos::methods::density::hits::MemoryWriter;
use kalos::methods::density::{pipeline, surfaces, Settings};
use kalos::methods::World;
use kalos::scene;

use crate::common;

fn root() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

pub(crate) fn world(rel: &str) -> World {
    World::new(scene::load(&root().join(rel)).expect("scene loads"))
}

fn settings(particles: u64, seed: u64) -> Settings {
    Settings {
        particles,
        seed,
        ..Default::default()
    }
}

/// A lightmap bake of `w` with the stand-in atlas of side `size`.
fn bake(w: &World, particles: u64, seed: u64, size: u32, opts: Options) -> LightmapBake {
    let lm = LightmapSettings {
        size: Some(size),
        estimator: opts,
        gather: GatherOptions::OFF,
        ..Default::default()
    };
    lmbake::bake_lightmap(
        w,
        &Settings {
            ..settings(particles, seed)
        },
        &lm,
        Steering::unlimited(&mut |_| {}),
    )
    .expect("baked")
}

/// The particles of a bake, indexed, and the estimate at `texels`.
fn estimate_at(
    w: &World,
    particles: u64,
    seed: u64,
    opts: Options,
    texels: &[Texel],
) -> Vec<TexelEstimate> {
    let surfaces = surfaces::build(&w.scene);
    let s = settings(particles, seed);
    let mut sink = MemoryWriter::new();
    let traced = pipeline::trace(w, &surfaces, &s, &mut sink).expect("traced");
    let hits = pipeline::group(sink).expect("grouped");
    let index = HitIndex::build(w, &surfaces, &hits, 1 << 20).expect("indexed");
    let est = Estimator::new(w, &surfaces, &index, traced.phi, opts);
    texels.iter().map(|t| est.texel(t)).collect()
}

/// The z-scores (E1 − E2)/√(se1² + se2²) over the covered texels lit in
/// both, every channel.
pub(crate) fn z_scores(a: &LightmapBake, b: &LightmapBake) -> Vec<f64> {
    let (la, lb) = (&a.lightmap, &b.lightmap);
    let mut z = Vec::new();
    for k in 0..la.irradiance.len() {
        if !(la.covered[k] && lb.covered[k]) {
            continue;
        }
        for c in 0..3 {
            let s2 = la.std_error[k][c].powi(2) + lb.std_error[k][c].powi(2);
            if s2 > 0.0 && la.irradiance[k][c] > 0.0 && lb.irradiance[k][c] > 0.0 {
                z.push(((la.irradiance[k][c] - lb.irradiance[k][c]) / s2.sqrt()) as f64);
            }
        }
    }
    z
}

pub(crate) fn spread(z: &[f64]) -> (f64, f64) {
    let n = z.len() as f64;
    let mean = z.iter().sum::<f64>() / n;
    let var = z.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / (n - 1.0);
    (mean, var.sqrt())
}

/// The scene triangle under `p` whose plane holds it and whose normal is
/// `n`, as a texel.
fn texel_at(s: &scene::Scene, p: Vec3, n: Vec3) -> Texel {
    for t in 0..s.triangles.len() as u32 {
        let [a, b, c] = s.tri_vertices(t);
        let ng = (b - a).cross(c - a).normalize();
        if ng.dot(n) < 0.999 || (p - a).dot(ng).abs() > 1e-4 {
            continue;
        }
        let inside = [(a, b), (b, c), (c, a)]
            .iter()
            .all(|&(u, v)| (v - u).cross(p - u).dot(ng) >= -1e-6);
        if inside {
            return Texel {
                x: 0,
                y: 0,
                tri: t,
                p,
                n: ng,
            };
        }
    }
    panic!("no triangle at {p} facing {n}");
}

/// Two bakes with different seeds agree within their error bars: over the
/// texels of the Cornell box, z = (E1 − E2)/√(se1² + se2²) has unit
/// spread. Each texel's k comes from its pilot (the default rule grows k
/// with the local density of hits), so k and h differ a little between
/// the bakes and so does the kernel's bias; this checks the variance,
/// that difference of bias included. Tolerance: the z of nearby texels
/// share hits, so the ~250k z are worth far fewer independent draws (about
/// the atlas's area over a kernel's, some thousands); the sample spread of
/// a few thousand unit normals is within ±0.03, and the pilot's bandwidth
/// (a 9 % spread in h between the bakes) adds a little: measured 0.97–1.02
/// over seeds with a fixed k (1.008 for these), 1.034 with the grown k
/// (mean 0.06); we allow 0.9–1.1, for both.
#[test]
fn two_seeds_agree_within_their_error_bars() {
    let w = world("scenes/cbox/cbox.xml");
    let fixed = Options {
        neighbours: Some(256),
        ..Options::default()
    };
    for (what, opts) in [("grown k", Options::default()), ("k = 256", fixed)] {
        let a = bake(&w, 300_000, 1, 128, opts);
        let b = bake(&w, 300_000, 2, 128, opts);
        let z = z_scores(&a, &b);
        let (mean, sd) = spread(&z);
        eprintln!(
            "two seeds, {what}: {} z, mean {mean:.3}, spread {sd:.3}",
            z.len()
        );
        assert!(z.len() > 10_000, "{what}: {} lit texels", z.len());
        assert!(mean.abs() < 0.1, "{what}: mean z {mean}");
        assert!((0.9..1.1).contains(&sd), "{what}: spread of z {sd}");
    }
}

/// The median relative standard error over the lit texels and channels.
fn median_relative_error(b: &LightmapBake) -> f64 {
    let l = &b.lightmap;
    let mut r: Vec<f64> = (0..l.irradiance.len())
        .filter(|&k| l.covered[k])
        .flat_map(|k| (0..3).map(move |c| (k, c)))
        .filter(|&(k, c)| l.irradiance[k][c] > 0.0)
        .map(|(k, c)| (l.std_error[k][c] / l.irradiance[k][c]) as f64)
        .collect();
    r.sort_by(f64::total_cmp);
    r[r.len() / 2]
}

/// The error falls as particles are added: with the grown k (k ∝ m^(2/3),
/// m the hits per texel), 8 times the particles give 4 times the k and
/// half the relative standard error (8^(1/3) = 2; measured 2.03); with a
/// fixed k it stays where it was (measured 1.01), which is what the test
/// would see without the rule. Tolerances: ≥ 1.6 and 0.9–1.1.
#[test]
fn the_error_falls_with_the_particles() {
    let w = world("scenes/cbox/cbox.xml");
    let fixed = Options {
        neighbours: Some(256),
        ..Options::default()
    };
    let ratio = |opts: Options| {
        let few = median_relative_error(&bake(&w, 100_000, 1, 128, opts));
        let many = median_relative_error(&bake(&w, 800_000, 2, 128, opts));
        few / many
    };
    let grown = ratio(Options::default());
    let fixed = ratio(fixed);
    eprintln!("8x the particles: relative error / {grown:.3} (grown k), / {fixed:.3} (k = 256)");
    assert!(grown >= 1.6, "grown k: the error fell by {grown}");
    assert!(
        (0.9..1.1).contains(&fixed),
        "fixed k: the error fell by {fixed}"
    );
}

/// Against a bake of 16 times the particles: z has a spread near 1 where
/// the kernel's bias is small against the noise. Measured, not asserted
/// tightly: the bias (the blur of a kernel of k hits) is in E1 − E_long
/// and not in the error bars. With the grown k (wider kernels than k = 256
/// at 300 k particles) measured 1.29, mean −0.07 (seeds 1 and 7).
#[test]
#[ignore = "slow tier: cargo test --release -- --ignored"]
fn against_a_longer_bake_the_error_bars_hold() {
    let w = world("scenes/cbox/cbox.xml");
    let opts = Options::default();
    let a = bake(&w, 300_000, 1, 128, opts);
    let long = bake(&w, 4_800_000, 7, 128, opts);
    let z = z_scores(&a, &long);
    let (mean, sd) = spread(&z);
    eprintln!("against 16x: {} z, mean {mean:.3}, spread {sd:.3}", z.len());
    assert!(mean.abs() < 0.2, "mean z {mean}");
    assert!((0.85..1.3).contains(&sd), "spread of z {sd}");
}

/// On two-rooms-baffle no light reaches the floor under the dividing wall
/// (|x| < 0.05, the wall stands on the floor slab, which is one surface
/// across both rooms): texels there take nothing, while the same texels
/// with the visibility test off take the light room's hits. And next to
/// the wall on the dark side, the floor is far darker than on the lit
/// side (the light comes to it only through the gap).
#[test]
fn no_light_under_the_dividing_wall() {
    let w = world("scenes/two-rooms-baffle/scene.xml");
    let up = Vec3::Y;
    let mut under = Vec::new();
    let mut near = Vec::new();
    for i in 0..20 {
        let z = 0.1 + 1.5 * i as f32 / 19.0; // before the gap, z in [0.1, 1.6]
        for x in [-0.04f32, -0.02, 0.0, 0.02, 0.04] {
            under.push(texel_at(&w.scene, Vec3::new(x, 0.0, z), up));
        }
        near.push((
            texel_at(&w.scene, Vec3::new(-0.08, 0.0, z), up),
            texel_at(&w.scene, Vec3::new(0.08, 0.0, z), up),
        ));
    }
    let opts = Options::default();
    let e = estimate_at(&w, 400_000, 3, opts, &under);
    let lit: Vec<_> = e.iter().filter(|e| e.e.max_element() > 0.0).collect();
    assert!(
        lit.is_empty(),
        "{} of {} texels under the wall lit: {:?}",
        lit.len(),
        e.len(),
        lit.first()
    );
    let off = Options { sectors: 0, ..opts };
    let leaky = estimate_at(&w, 400_000, 3, off, &under);
    let n_leaky = leaky.iter().filter(|e| e.e.max_element() > 0.0).count();
    eprintln!(
        "without the visibility test {n_leaky} of {} lit",
        leaky.len()
    );
    assert!(
        n_leaky > leaky.len() / 2,
        "the test can fail: {n_leaky} leak without it"
    );

    let pairs: Vec<Texel> = near.iter().flat_map(|(a, b)| [*a, *b]).collect();
    let e = estimate_at(&w, 400_000, 3, opts, &pairs);
    let (mut lit_side, mut dark_side) = (0.0, 0.0);
    for p in e.chunks(2) {
        lit_side += p[0].e.y;
        dark_side += p[1].e.y;
    }
    eprintln!("by the wall: lit side {lit_side}, dark side {dark_side}");
    assert!(
        dark_side < 0.1 * lit_side,
        "lit {lit_side}, dark {dark_side}"
    );
}

/// `kalos bake` without --lightmap writes the bytes it always did: the
/// same .glb as the library's density bake written directly.
#[test]
fn without_lightmap_the_bake_is_unchanged() {
    let dir = tempfile::tempdir().expect("tempdir");
    let out = dir.path().join("a.glb");
    let o = common::kalos(&[
        "bake",
        "--particles",
        "50000",
        "--seed",
        "3",
        "-q",
        "-o",
        out.to_str().expect("utf-8"),
    ]);
    assert!(o.status.success(), "{}", common::stderr(&o));
    let w = World::new(scene::builtin::cornell_box().expect("built in"));
    let bk = kalos::methods::density::bake(&w, &settings(50_000, 3)).expect("baked");
    let (lit, unlit) = bk.baked_meshes(&w.scene);
    let direct = dir.path().join("b.glb");
    kalos::bake::gltf::write_glb(&direct, &lit, &unlit, bk.w0, Some(&w.scene.camera))
        .expect("written");
    assert!(
        std::fs::read(&out).expect("a") == std::fs::read(&direct).expect("b"),
        "the CLI's .glb differs from the library's"
    );
}

/// The command line's lightmap flags: an atlas and an error map written,
/// and clear refusals.
#[test]
fn the_lightmap_flags() {
    let dir = tempfile::tempdir().expect("tempdir");
    let d = |f: &str| dir.path().join(f).to_str().expect("utf-8").to_string();
    // -o names the .glb; the float atlas is written beside it
    let (out, atlas, err) = (d("out.glb"), d("out.lightmap.exr"), d("err.exr"));
    let o = common::kalos(&[
        "bake",
        "--lightmap",
        "--lightmap-size",
        "64",
        "--particles",
        "100000",
        "-q",
        "-o",
        &out,
        "--lightmap-error",
        &err,
    ]);
    let glb_bytes = std::fs::read(&out).expect("the .glb written");
    assert_eq!(&glb_bytes[..4], b"glTF");
    assert!(o.status.success(), "{}", common::stderr(&o));
    for f in [&atlas, &err] {
        let img = kalos::image_io::read_image(std::path::Path::new(f)).expect("an EXR");
        assert_eq!((img.width, img.height), (64, 64));
        assert!(
            img.data.iter().any(|p| p.max_element() > 0.0),
            "{f} is black"
        );
    }

    let refused = |args: &[&str], words: &str| {
        let o = common::kalos(args);
        let e = common::stderr(&o);
        assert!(!o.status.success(), "{args:?} accepted");
        assert!(e.contains(words), "{args:?}: {e}");
    };
    let glb = d("x.glb");
    refused(
        &["bake", "--lightmap-error", &err, "-o", &glb],
        "--lightmap",
    );
    refused(&["bake", "--lightmap", "-o", &atlas], "must end in .glb");
    refused(
        &[
            "bake",
            "--lightmap",
            "--lightmap-size",
            "64",
            "--texel-density",
            "10",
            "-o",
            &glb,
        ],
        "cannot be used with",
    );
    refused(
        &["bake", "--lightmap", "--lightmap-size", "0", "-o", &glb],
        "--lightmap-size must be between",
    );
    refused(
        &["bake", "--lightmap", "--growth", "0", "-o", &glb],
        "growth must be a positive number",
    );
    refused(
        &[
            "bake",
            "--lightmap",
            "--neighbours",
            "64",
            "--growth",
            "40",
            "-o",
            &glb,
        ],
        "cannot be used with",
    );
    refused(
        &["bake", "--lightmap", "--texel-density=-3", "-o", &glb],
        "--texel-density must be",
    );
    refused(
        &[
            "bake",
            "--lightmap",
            "-o",
            &glb,
            "--lightmap-error",
            &d("e.png"),
        ],
        "must end in .exr",
    );
    // an atlas past the memory limit, refused before any work, with its size
    let t = Instant::now();
    refused(
        &[
            "bake",
            "--lightmap",
            "--lightmap-size",
            "16384",
            "--max-memory",
            "1G",
            "-o",
            &d("big.glb"),
        ],
        "the lightmap atlas (16384×16384 texels) needs",
    );
    assert!(t.elapsed().as_secs_f64() < 5.0, "refused only after work");
    assert!(!dir.path().join("big.glb").exists());
}
