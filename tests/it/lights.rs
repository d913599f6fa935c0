//! Light selection for next-event estimation, by power and by the shading
//! point (`--light-selection`, the light tree of `emitter`): the
//! probability that sampling reports is the one the pdf functions give
//! (which MIS in `path` relies on), the probabilities sum to one, and both
//! selections estimate the same direct light (Lambert's closed form for
//! polygons) and the same image.

use std::path::Path;

use glam::Vec3;
use kalos::emitter::{LightSelection, Lights};
use kalos::methods::{path, MethodConfig};
use kalos::sampling::{uniform_sphere, Pcg32};
use kalos::scene::{self, Material, Scene, Texture};
use kalos::world::World;

use crate::common::{block_stats, max_block_z, render};

const BOTH: [LightSelection; 2] = [LightSelection::Power, LightSelection::Spatial];

fn diffuse(scene: &mut Scene) -> u32 {
    scene.add_material(Material::Diffuse {
        reflectance: Texture::Constant(Vec3::splat(0.5)),
    })
}

/// Adds the quad with corners `c` (counter-clockwise seen from the side it
/// emits toward) as two triangles emitting `le`.
fn quad(s: &mut Scene, m: u32, c: [Vec3; 4], le: Vec3) {
    s.add_mesh("quad", &c, None, None, &[[0, 1, 2], [0, 2, 3]], m, Some(le));
}

/// A horizontal quad of half-size `h` centred at `o`, facing down.
fn ceiling_quad(o: Vec3, h: f32) -> [Vec3; 4] {
    [
        o + Vec3::new(-h, -h, 0.0),
        o + Vec3::new(-h, h, 0.0),
        o + Vec3::new(h, h, 0.0),
        o + Vec3::new(h, -h, 0.0),
    ]
}

/// 300 emitting triangles of random size, place and orientation in
/// [-5, 5]³, with random radiances, and a constant environment.
fn random_lights() -> Lights {
    let mut s = Scene::empty("random lights");
    let m = diffuse(&mut s);
    let mut rng = Pcg32::new(5, 0);
    for _ in 0..300 {
        let o = (Vec3::new(rng.next_f32(), rng.next_f32(), rng.next_f32()) - 0.5) * 10.0;
        let size = 0.05 + rng.next_f32();
        let a = uniform_sphere(rng.next_2d()) * size;
        let b = uniform_sphere(rng.next_2d()) * size;
        let le = Vec3::new(rng.next_f32(), rng.next_f32(), rng.next_f32()) * 10.0;
        s.add_mesh(
            "tri",
            &[o, o + a, o + b],
            None,
            None,
            &[[0, 1, 2]],
            m,
            Some(le),
        );
    }
    s.emitters.push(scene::EmitterDesc::Constant {
        radiance: Vec3::splat(0.01),
    });
    World::new(s).lights
}

/// A 12 × 12 ceiling of 144 quads facing down at z = 3, as in a large room.
fn ceiling_lights() -> Lights {
    let mut s = Scene::empty("ceiling");
    let m = diffuse(&mut s);
    for i in 0..12 {
        for j in 0..12 {
            let o = Vec3::new(i as f32 - 5.5, j as f32 - 5.5, 3.0);
            let le = Vec3::splat(1.0 + ((i * 7 + j * 3) % 5) as f32);
            quad(&mut s, m, ceiling_quad(o, 0.3), le);
        }
    }
    World::new(s).lights
}

fn emitting_tris(lights: &Lights, count: u32) -> Vec<u32> {
    (0..count).filter(|&t| lights.is_emitter(t)).collect()
}

/// At random points and normals (the zero normal included), the choice
/// that [`Lights::select`] makes comes with the probability that
/// [`Lights::selection_pmf`] gives for it, bit for bit, and the solid-angle
/// pdf of a light sample is the one `pdf_li_tri_from` gives for its point
/// (relative 1e-4: the two compute dist²/cos from different vectors). The
/// probabilities over all lights and the environment never exceed 1.
#[test]
fn selection_pmf_is_the_sampled_one() {
    let lights = random_lights();
    let tris = emitting_tris(&lights, 300);
    assert_eq!(tris.len(), 300);
    let mut rng = Pcg32::new(6, 0);
    for k in 0..200 {
        let p = (Vec3::new(rng.next_f32(), rng.next_f32(), rng.next_f32()) - 0.5) * 12.0;
        let n = if k % 4 == 0 {
            Vec3::ZERO
        } else {
            uniform_sphere(rng.next_2d())
        };
        for sel in BOTH {
            let sum: f64 = tris
                .iter()
                .chain([u32::MAX].iter())
                .map(|&t| lights.selection_pmf(sel, p, n, t) as f64)
                .sum();
            assert!(sum <= 1.0 + 1e-4, "{sel:?} at {p}: pmfs sum to {sum}");
            for _ in 0..20 {
                let (u_sel, u) = (rng.next_f32(), rng.next_2d());
                let Some((tri, pmf)) = lights.select(sel, p, n, u_sel) else {
                    continue;
                };
                assert!(pmf > 0.0, "{sel:?}: chose {tri} with probability 0");
                assert_eq!(
                    pmf,
                    lights.selection_pmf(sel, p, n, tri),
                    "{sel:?} at {p}, n {n}: light {tri}"
                );
                let Some(ls) = lights.sample_li_from(sel, p, n, u_sel, u) else {
                    continue;
                };
                if ls.is_env {
                    assert_eq!(tri, u32::MAX);
                    continue;
                }
                let back = lights.pdf_li_tri_from(sel, p, n, ls.p, ls.n, tri);
                assert!(
                    (back - ls.pdf).abs() <= 1e-4 * ls.pdf,
                    "{sel:?}: pdf_li_tri_from {back} vs the sample's {}",
                    ls.pdf
                );
            }
        }
    }
}

/// Below a ceiling of lights that all face the points, every light can be
/// reached, so the probabilities over the 288 triangles sum to 1 (to
/// rounding: 1e-4) for both selections; the spatial one gives the nearest
/// lights more than their power share.
#[test]
fn selection_pmfs_sum_to_one() {
    let lights = ceiling_lights();
    let tris = emitting_tris(&lights, 288);
    assert_eq!(tris.len(), 288);
    let mut rng = Pcg32::new(7, 0);
    for _ in 0..100 {
        let p = Vec3::new(
            (rng.next_f32() - 0.5) * 14.0,
            (rng.next_f32() - 0.5) * 14.0,
            rng.next_f32() * 2.5,
        );
        let n = uniform_sphere(rng.next_2d());
        for sel in BOTH {
            let sum: f64 = tris
                .iter()
                .map(|&t| lights.selection_pmf(sel, p, n, t) as f64)
                .sum();
            assert!((sum - 1.0).abs() <= 1e-4, "{sel:?} at {p}: sum {sum}");
        }
    }
    // Under the light at (−5.5, −5.5), at the floor: its two triangles
    // carry 1/144 of the ceiling's area, but most of the spatial choice
    let p = Vec3::new(-5.5, -5.5, 0.0);
    let near: f32 = (0..2)
        .map(|t| lights.selection_pmf(LightSelection::Spatial, p, Vec3::Z, t))
        .sum();
    let power: f32 = (0..2)
        .map(|t| lights.selection_pmf(LightSelection::Power, p, Vec3::Z, t))
        .sum();
    assert!(near > 10.0 * power, "spatial {near} vs power {power}");
}

/// Irradiance at `p` (normal `n`) from a polygon of radiance `le` entirely
/// above p's tangent plane (Lambert's formula): E = (L/2) Σᵢ βᵢ (n · γᵢ),
/// βᵢ the angle edge i subtends at p and γᵢ the unit normal of the plane
/// through p and that edge.
fn lambert(p: Vec3, n: Vec3, c: &[Vec3], le: f32) -> f64 {
    let mut s = 0.0f64;
    for i in 0..c.len() {
        let (a, b) = (
            (c[i] - p).normalize(),
            (c[(i + 1) % c.len()] - p).normalize(),
        );
        let beta = a.dot(b).clamp(-1.0, 1.0).acos() as f64;
        s += beta * n.dot(a.cross(b).normalize()) as f64;
    }
    (s.abs() * 0.5) * le as f64
}

/// Both selections estimate the exact direct irradiance from five quads at
/// distances from 0.5 m to 4 m (one facing away: it sends nothing to the
/// points, and the spatial selection may not choose it), at three points of
/// the floor. The estimate is the mean of Le (n·ωᵢ)⁺ / pdf over 100,000
/// light samples; the tolerance is 4 standard errors of that mean,
/// measured from the samples, for each selection against Lambert's closed
/// form and for their difference. Near a light (the first two points) the
/// spatial selection also has the smaller variance, which is what it is
/// for; at the third, far from every light, the tree's coarse bounds may
/// do worse than power, and only agreement is asserted.
#[test]
fn both_selections_estimate_the_exact_direct_light() {
    let mut s = Scene::empty("five quads");
    let m = diffuse(&mut s);
    let quads = [
        (ceiling_quad(Vec3::new(-2.0, -2.0, 0.5), 0.2), 4.0),
        (ceiling_quad(Vec3::new(2.0, 2.0, 1.5), 0.3), 2.0),
        (ceiling_quad(Vec3::new(0.0, 0.0, 3.0), 0.5), 1.0),
        (ceiling_quad(Vec3::new(-2.0, 2.0, 4.0), 0.25), 8.0),
    ];
    for (c, le) in &quads {
        quad(&mut s, m, *c, Vec3::splat(*le));
    }
    // facing up: the points are behind it
    let mut up = ceiling_quad(Vec3::new(2.0, -2.0, 1.0), 0.4);
    up.reverse();
    quad(&mut s, m, up, Vec3::splat(3.0));
    let lights = World::new(s).lights;

    let n_samples = 100_000;
    for (k, p) in [
        Vec3::new(-2.0, -2.0, 0.0),
        Vec3::new(1.0, 1.5, 0.0),
        Vec3::new(0.0, -3.0, 0.0),
    ]
    .into_iter()
    .enumerate()
    {
        let n = Vec3::Z;
        let exact: f64 = quads.iter().map(|(c, le)| lambert(p, n, c, *le)).sum();
        let mut stats = Vec::new();
        for sel in BOTH {
            let mut rng = Pcg32::new(8, k as u64);
            let (mut sum, mut sum2) = (0.0f64, 0.0f64);
            for _ in 0..n_samples {
                if let Some(ls) = lights.sample_li_from(sel, p, n, rng.next_f32(), rng.next_2d()) {
                    let x = (ls.le.x * ls.wi.dot(n).max(0.0) / ls.pdf) as f64;
                    sum += x;
                    sum2 += x * x;
                }
            }
            let mean = sum / n_samples as f64;
            let var = sum2 / n_samples as f64 - mean * mean;
            let se = (var / n_samples as f64).sqrt();
            assert!(
                (mean - exact).abs() <= 4.0 * se,
                "{sel:?} at {p}: E {mean} vs exact {exact} (4 se = {})",
                4.0 * se
            );
            stats.push((mean, se, var));
        }
        let ((mp, sp, vp), (ms, ss, vs)) = (stats[0], stats[1]);
        let tol = 4.0 * (sp * sp + ss * ss).sqrt();
        assert!(
            (mp - ms).abs() <= tol,
            "at {p}: power {mp} vs spatial {ms} (tol {tol})"
        );
        eprintln!("at {p}: variance power {vp:.4e}, spatial {vs:.4e}");
        if k < 2 {
            assert!(vs < vp, "at {p}: spatial variance {vs} ≥ power {vp}");
        }
    }
}

/// `path` gives the same image with either selection, on a floor lit by
/// quads at several heights (one facing away): each selection renders
/// twice with independent seeds, and every 8 × 8 block mean of the two
/// agrees within |z| < 4.5, z from the variances measured from the renders
/// ([`crate::common::block_stats`]; 16 blocks × 3 channels at a 1 %
/// false-alarm rate under normality need |z| < 3.7, and 4.5 allows for the
/// heavy tails of the pixels that see the lights).
#[test]
fn path_image_is_the_same_with_either_selection() {
    let xml = r#"<scene version="3.0.0">
  <sensor type="perspective">
    <float name="fov" value="70"/>
    <transform name="to_world"><lookat origin="0, 0, 7" target="0, 0, 0" up="0, 1, 0"/></transform>
    <film type="hdrfilm"><integer name="width" value="32"/><integer name="height" value="32"/></film>
  </sensor>
  <shape type="rectangle"><transform name="to_world"><scale value="4"/></transform>
    <bsdf type="diffuse"><rgb name="reflectance" value="0.6"/></bsdf></shape>
  <shape type="rectangle"><transform name="to_world"><scale value="0.2"/><rotate x="1" angle="180"/><translate x="-2" y="-2" z="0.5"/></transform>
    <emitter type="area"><rgb name="radiance" value="8"/></emitter></shape>
  <shape type="rectangle"><transform name="to_world"><scale value="0.3"/><rotate x="1" angle="180"/><translate x="2" y="2" z="1.5"/></transform>
    <emitter type="area"><rgb name="radiance" value="4"/></emitter></shape>
  <shape type="rectangle"><transform name="to_world"><scale value="0.5"/><rotate x="1" angle="180"/><translate x="1" y="-1" z="3"/></transform>
    <emitter type="area"><rgb name="radiance" value="2"/></emitter></shape>
  <shape type="rectangle"><transform name="to_world"><scale value="0.4"/><translate x="-2" y="2" z="1"/></transform>
    <emitter type="area"><rgb name="radiance" value="3"/></emitter></shape>
</scene>"#;
    let s = scene::load_str(xml, Path::new("."), "test.xml").unwrap_or_else(|e| panic!("{e}"));
    let cfg = |light_selection| {
        MethodConfig::Path(path::Settings {
            light_selection,
            ..Default::default()
        })
    };
    let stats = |sel| {
        let (a, _) = render(&s, &cfg(sel), 21, 64);
        let (b, _) = render(&s, &cfg(sel), 22, 64);
        block_stats(&a, &b, 8, &|_, _| true)
    };
    let (p, q) = (stats(LightSelection::Power), stats(LightSelection::Spatial));
    let (z, block) = max_block_z(&p, &q, 1e-4);
    eprintln!("path, power vs spatial selection: max |z| = {z:.2} (block {block})");
    assert!(
        z < 4.5,
        "the selections disagree: |z| = {z:.2} in block {block}"
    );
}

/// With one emitting quad (cbox), no choice depends on the shading point:
/// the spatial selection makes the power selection's choices with the
/// power selection's probabilities, bit for bit, so that its image is the
/// same.
#[test]
fn one_quad_is_chosen_by_power() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let s = scene::load(&root.join("scenes/cbox/cbox.xml")).expect("scene");
    let lights = World::new(s).lights;
    let mut rng = Pcg32::new(9, 0);
    for _ in 0..1000 {
        let p = Vec3::new(rng.next_f32(), rng.next_f32(), rng.next_f32()) * 550.0;
        let n = uniform_sphere(rng.next_2d());
        let u = rng.next_f32();
        assert_eq!(
            lights.select(LightSelection::Spatial, p, n, u),
            lights.select(LightSelection::Power, p, n, u)
        );
    }
}
