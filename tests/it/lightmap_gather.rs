//! The lightmap's final gather (`src/bake/lightmap/gather.rs`): its error
//! bars against a second seed, and its irradiance against the path
//! tracer's at the texels' points.

use kalos::bake::lightmap::bake::{self as lmbake, LightmapBake, LightmapSettings, Steering};
use kalos::bake::lightmap::gather::GatherOptions;
use kalos::bake::lightmap::raster;
use kalos::geometry::Ray;
use kalos::methods::density::Settings;
use kalos::methods::World;
use kalos::sampling::Pcg32;

use crate::lightmap::{spread, world, z_scores};

/// A lightmap bake of `w` at side `size`, with the recommended gather.
fn bake(w: &World, particles: u64, seed: u64, size: u32) -> LightmapBake {
    let lm = LightmapSettings {
        size: Some(size),
        gather: GatherOptions::RECOMMENDED,
        ..Default::default()
    };
    let s = Settings {
        particles,
        seed,
        ..Default::default()
    };
    lmbake::bake_lightmap(w, &s, &lm, Steering::unlimited(&mut |_| {})).expect("baked")
}

/// Two seeds' atlases differ by what their error bars say, or less.
///
/// The gather's samples are stratified, and its variance estimate pairs
/// neighbouring strata (the collapsed-strata estimate), which errs high
/// where the light changes between strata: the spread of z is then below 1
/// (measured 0.85 on the Cornell box at 512², 250 k particles; 0.58 with
/// the independent-sample formula, which ignores the strata). So the test
/// is one-sided where it matters: error bars too small (spread above 1.1,
/// the density estimate's bound) fail it; bars more than 1.5 times too
/// large (spread below 0.67) fail it too.
#[test]
fn two_seeds_agree_within_the_gathers_error_bars() {
    let w = world("scenes/cbox/cbox.xml");
    let a = bake(&w, 200_000, 1, 128);
    let b = bake(&w, 200_000, 2, 128);
    let z = z_scores(&a, &b);
    let (mean, sd) = spread(&z);
    eprintln!(
        "two seeds, gather: {} z, mean {mean:.3}, spread {sd:.3}",
        z.len()
    );
    assert!(z.len() > 10_000, "{} lit texels", z.len());
    assert!(mean.abs() < 0.1, "mean z {mean}");
    assert!((0.67..1.1).contains(&sd), "spread of z {sd}");
}

/// At texels spread over the Cornell box, the gather's irradiance agrees
/// with the path tracer's at the same point, within their joint error.
///
/// The path tracer's irradiance at p with normal n is π/ρ times the
/// radiance a ray from just above p straight down onto it brings back
/// (ρ the diffuse albedo there), averaged over many paths; its standard
/// error is the sample standard deviation over √paths. Sixty texels evenly
/// spaced in the texel list of a 128² bake are taken, the covered ones. With the gather's
/// error bars conservative (above), z = (E_gather − E_path)/√(se² + se²)
/// has a spread of at most 1 for an unbiased gather; 60 values estimate it
/// within ±0.09 (one standard deviation), so the test allows 1.35, and a
/// mean within ±0.5 (about 4 standard errors). The atlas the gather reads
/// is biased by the kernel's blur, one bounce away: a bias that shows here
/// would fail it.
#[test]
fn the_gather_agrees_with_the_path_tracer() {
    let w = world("scenes/cbox/cbox.xml");
    let bk = bake(&w, 200_000, 3, 128);
    let texels = raster::texels(&w.scene, &bk.uv);
    let lm = &bk.lightmap;
    let st = kalos::methods::path::Settings::default();
    let mut rng = Pcg32::keyed(&[11]);
    let mut z = Vec::new();
    for t in texels.iter().step_by((texels.len() / 60).max(1)) {
        let k = (t.y * lm.width + t.x) as usize;
        if !lm.covered[k] || lm.irradiance[k].y <= 0.0 {
            continue;
        }
        let sp = w.scene.surface_point(t.tri, 0.0, 0.0);
        let albedo = w
            .scene
            .material_of(&sp)
            .bsdf(sp.uv)
            .diffuse_part()
            .expect("diffuse")
            .k
            .y
            * std::f32::consts::PI;
        let paths = 4096;
        let (mut sum, mut sum2) = (0.0f64, 0.0f64);
        let o = t.p + t.n * 0.05;
        for _ in 0..paths {
            let (l, _) = kalos::methods::path::radiance(&w, &st, Ray::new(o, -t.n), &mut rng);
            let e = l.y as f64 * std::f64::consts::PI / albedo as f64;
            sum += e;
            sum2 += e * e;
        }
        let mean = sum / paths as f64;
        let var = (sum2 / paths as f64 - mean * mean).max(0.0) / (paths - 1) as f64;
        let se = (var + (lm.std_error[k].y as f64).powi(2)).sqrt();
        z.push((lm.irradiance[k].y as f64 - mean) / se);
    }
    let (mean, sd) = spread(&z);
    eprintln!(
        "gather against path: {} texels, z mean {mean:.3}, spread {sd:.3}",
        z.len()
    );
    assert!(z.len() >= 40, "{} texels", z.len());
    assert!(mean.abs() < 0.5, "mean z {mean}");
    assert!(sd < 1.35, "spread of z {sd}");
}
