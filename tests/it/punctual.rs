//! Punctual lights (glTF `KHR_lights_punctual`): the loader reads points,
//! spots and directional lights with their node transforms and units
//! (candela and lux / 683 lm/W), and the methods render them as the closed
//! forms say: the irradiance of a point light at distance d, I cos θ / d²;
//! a spot's cone (full inside, nothing outside, the smooth falloff
//! between); a directional light on a plane tilted by θ, cos θ · E⊥. And
//! `path`, `light` and `plb` agree on a small room lit by a point lamp;
//! both selections give a lamp its power share; `bundle` refuses a lamp
//! only in the paper's form; a file written by Blender comes back with its
//! lamps' power.
//!
//! Tolerances: each render is compared by blocks of pixels, the variance of
//! a block's mean measured from two independent renders (the spread of
//! their per-pixel difference, [`crate::common::block_stats`]); a block
//! fails at 5 standard deviations. The closed form of a block is the mean
//! over its pixels of the exact pixel value, integrated by 8 × 8 midpoints
//! per pixel (the renders' box filter), with a 0.2 % relative floor (plus
//! 1e-5 absolute) on the deviation for that quadrature and f32 sums.

use std::path::{Path, PathBuf};

use glam::Vec3;
use kalos::geometry::look_at;
use kalos::methods::{light, plb, MethodConfig};
use kalos::scene::{
    self, CameraDesc, EmitterDesc, Material, PunctualKind, PunctualLight, Rgb, Scene, Texture,
};
use kalos::world::World;

use crate::common::{block_stats, max_block_z, path, render};

const RHO: f32 = 0.5;

fn tmp() -> tempfile::TempDir {
    tempfile::Builder::new()
        .prefix("kalos-punctual-")
        .tempdir()
        .unwrap()
}

// ---------------------------------------------------------------------------
// The glTF reader

/// Writes a glTF file with one triangle, the given lights (JSON objects of
/// `extensions.KHR_lights_punctual.lights`) and nodes (JSON objects; node
/// 0 holds the triangle, `nodes` follow from 1, and the scene's roots are
/// 0 and `roots`).
fn gltf_with_lights(dir: &Path, lights: &[&str], nodes: &[&str], roots: &[usize]) -> PathBuf {
    let mut bin = Vec::new();
    for v in [0.0f32, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0, 0.0] {
        bin.extend(v.to_le_bytes());
    }
    std::fs::write(dir.join("tri.bin"), &bin).unwrap();
    let roots: Vec<usize> = [0].iter().chain(roots).copied().collect();
    let json = format!(
        r#"{{"asset":{{"version":"2.0"}},"scene":0,"scenes":[{{"nodes":{roots:?}}}],
        "extensionsUsed":["KHR_lights_punctual"],
        "extensions":{{"KHR_lights_punctual":{{"lights":[{}]}}}},
        "nodes":[{{"mesh":0}},{}],
        "meshes":[{{"primitives":[{{"attributes":{{"POSITION":0}}}}]}}],
        "accessors":[{{"bufferView":0,"componentType":5126,"count":3,"type":"VEC3",
                       "min":[0,0,0],"max":[1,1,0]}}],
        "bufferViews":[{{"buffer":0,"byteOffset":0,"byteLength":36}}],
        "buffers":[{{"byteLength":36,"uri":"tri.bin"}}]}}"#,
        lights.join(","),
        nodes.join(",")
    );
    let p = dir.join("lights.gltf");
    std::fs::write(&p, json).unwrap();
    p
}

fn punctual(s: &Scene) -> Vec<&PunctualLight> {
    s.emitters
        .iter()
        .filter_map(|e| match e {
            EmitterDesc::Punctual(l) => Some(l),
            _ => None,
        })
        .collect()
}

fn near(a: Vec3, b: Vec3) -> bool {
    (a - b).abs().max_element() <= 1e-5 * (1.0 + b.abs().max_element())
}

/// A point, a spot and a directional light, on nodes with a translation, a
/// rotation (90° about x: −z becomes −y... +y, see below) and a parent:
/// positions and −z directions in world space, colour × intensity / 683,
/// the spot's cone cosines, names; `range` is ignored with a warning; the
/// file's lights replace the default environment.
#[test]
fn gltf_lights_are_read_with_their_transforms_and_units() {
    let d = tmp();
    // q = (sin 45°, 0, 0, cos 45°): 90° about +x maps −z to +y
    let s45 = std::f32::consts::FRAC_1_SQRT_2;
    let p = gltf_with_lights(
        d.path(),
        &[
            r#"{"type":"point","intensity":683,"color":[1,0.5,0.25],"name":"bulb","range":10}"#,
            r#"{"type":"spot","intensity":1366,"spot":{"innerConeAngle":0.25,"outerConeAngle":0.5}}"#,
            r#"{"type":"directional","intensity":6830,"name":"sun"}"#,
        ],
        &[
            r#"{"translation":[1,2,3],"extensions":{"KHR_lights_punctual":{"light":0}}}"#,
            &format!(r#"{{"translation":[0,0,5],"rotation":[{s45},0,0,{s45}],"children":[3]}}"#),
            r#"{"translation":[1,0,0],"extensions":{"KHR_lights_punctual":{"light":1}}}"#,
            r#"{"extensions":{"KHR_lights_punctual":{"light":2}}}"#,
        ],
        &[1, 2, 4],
    );
    let s = scene::load(&p).unwrap_or_else(|e| panic!("{e}"));
    let l = punctual(&s);
    assert_eq!(l.len(), 3, "{:?}", s.emitters);
    assert!(
        !s.emitters
            .iter()
            .any(|e| matches!(e, EmitterDesc::Constant { .. })),
        "a file with lights gets no default environment"
    );
    let bulb = l.iter().find(|l| l.name == "bulb").expect("bulb");
    assert_eq!(bulb.kind, PunctualKind::Point);
    assert!(near(bulb.position, Vec3::new(1.0, 2.0, 3.0)));
    assert!(
        near(bulb.intensity, Vec3::new(1.0, 0.5, 0.25)),
        "{}",
        bulb.intensity
    );
    assert!(s
        .warnings
        .iter()
        .any(|w| w.contains("bulb") && w.contains("range ignored")));

    let spot = l
        .iter()
        .find(|l| matches!(l.kind, PunctualKind::Spot { .. }))
        .expect("spot");
    // The child's (1, 0, 0) under the parent's rotation and translation
    assert!(
        near(spot.position, Vec3::new(1.0, 0.0, 5.0)),
        "{}",
        spot.position
    );
    assert!(near(spot.direction, Vec3::Y), "{}", spot.direction);
    assert!(near(spot.intensity, Vec3::splat(2.0)));
    assert_eq!(spot.name, "light 1");
    let PunctualKind::Spot {
        cos_inner,
        cos_outer,
    } = spot.kind
    else {
        unreachable!()
    };
    assert!((cos_inner - 0.25f32.cos()).abs() < 1e-6);
    assert!((cos_outer - 0.5f32.cos()).abs() < 1e-6);

    let sun = l.iter().find(|l| l.name == "sun").expect("sun");
    assert_eq!(sun.kind, PunctualKind::Directional);
    assert!(near(sun.direction, Vec3::NEG_Z));
    assert!(near(sun.intensity, Vec3::splat(10.0)));
}

/// A node naming a light the file does not have, a light of an unknown
/// type or a negative intensity is an error naming the file and what is
/// wrong (no panic; the `gltf` crate's validation may catch the first two
/// before kalos's own checks do).
#[test]
fn gltf_bad_lights_are_errors() {
    let d = tmp();
    let p = gltf_with_lights(
        d.path(),
        &[r#"{"type":"point"}"#],
        &[r#"{"extensions":{"KHR_lights_punctual":{"light":7}}}"#],
        &[1],
    );
    let e = scene::load(&p).expect_err("missing light").to_string();
    let lower = e.to_lowercase();
    assert!(
        e.contains("lights.gltf") && lower.contains("lightspunctual") && lower.contains("light"),
        "{e}"
    );
    assert!(
        lower.contains("out of bounds") || lower.contains("does not exist"),
        "{e}"
    );

    let p = gltf_with_lights(
        d.path(),
        &[r#"{"type":"area"}"#],
        &[r#"{"extensions":{"KHR_lights_punctual":{"light":0}}}"#],
        &[1],
    );
    let e = scene::load(&p).expect_err("unknown type").to_string();
    assert!(e.contains("lights.gltf") && e.contains("type"), "{e}");

    let p = gltf_with_lights(
        d.path(),
        &[r#"{"type":"point","intensity":-1}"#],
        &[r#"{"extensions":{"KHR_lights_punctual":{"light":0}}}"#],
        &[1],
    );
    let e = scene::load(&p).expect_err("negative intensity").to_string();
    assert!(e.contains("intensity must be"), "{e}");
}

// ---------------------------------------------------------------------------
// Closed forms

/// A diffuse square of albedo `RHO` and half-size 4 at z = 0 facing +z,
/// seen from (0, 0, 6) looking down at a 32 × 32 film, lit by `l` alone.
fn plane_scene(l: PunctualLight) -> Scene {
    let mut s = Scene::empty("punctual plane");
    let m = s.add_material(Material::Diffuse {
        reflectance: Texture::Constant(Vec3::splat(RHO)),
    });
    let c = [
        Vec3::new(-4.0, -4.0, 0.0),
        Vec3::new(4.0, -4.0, 0.0),
        Vec3::new(4.0, 4.0, 0.0),
        Vec3::new(-4.0, 4.0, 0.0),
    ];
    s.add_mesh("plane", &c, None, None, &[[0, 1, 2], [0, 2, 3]], m, None);
    s.emitters.push(EmitterDesc::Punctual(l));
    s.camera = CameraDesc {
        to_world: look_at(Vec3::new(0.0, 0.0, 6.0), Vec3::ZERO, Vec3::Y),
        fov_x_deg: 60.0,
        width: 32,
        height: 32,
        near_clip: 1e-3,
    };
    s
}

/// Renders `scene` with `method` twice (seeds 11 and 12, `passes` each)
/// and compares 4 × 4-pixel blocks with the closed form: the radiance
/// RHO/π · E(q) of the plane point q seen through each pixel, E given by
/// `irradiance`. Returns the worst z and the renders' image mean (channel 0).
fn against_closed_form(
    scene: &Scene,
    method: &MethodConfig,
    passes: u64,
    irradiance: &dyn Fn(Vec3) -> f64,
) -> (f64, f64) {
    let (a, _) = render(scene, method, 11, passes);
    let (b, _) = render(scene, method, 12, passes);
    let stats = block_stats(&a, &b, 4, &|_, _| true);
    let world = World::new(scene.clone());
    let (w, h) = (a.width, a.height);
    let sub = 8;
    let exact_pixel = |x: u32, y: u32| -> f64 {
        let mut s = 0.0;
        for i in 0..sub {
            for j in 0..sub {
                let r = world.camera.ray(
                    x as f32 + (i as f32 + 0.5) / sub as f32,
                    y as f32 + (j as f32 + 0.5) / sub as f32,
                );
                let t = -r.o.z / r.d.z;
                let q = r.o + r.d * t;
                assert!(
                    q.x.abs() < 4.0 && q.y.abs() < 4.0,
                    "the film sees past the plane"
                );
                s += RHO as f64 / std::f64::consts::PI * irradiance(q);
            }
        }
        s / (sub * sub) as f64
    };
    let mut worst = 0.0f64;
    let mut total = 0.0;
    for (k, st) in stats.iter().enumerate() {
        let Some((m, v)) = st else { continue };
        let (bx, by) = (k as u32 % (w / 4), k as u32 / (w / 4));
        let mut e = 0.0;
        for y in by * 4..by * 4 + 4 {
            for x in bx * 4..bx * 4 + 4 {
                e += exact_pixel(x, y);
            }
        }
        e /= 16.0;
        total += m[0];
        for c in 0..3 {
            // (and 1e-5 absolute, for blocks on the spot's outer edge,
            // where the lit part of a pixel is a sliver)
            let floor = 2e-3 * e + 1e-5;
            let z = (m[c] - e).abs() / (v[c] + floor * floor + 1e-24).sqrt();
            assert!(
                z <= 5.0,
                "block ({bx}, {by}) channel {c}: {} vs closed form {e} (σ {})",
                m[c],
                v[c].sqrt()
            );
            worst = worst.max(z);
        }
    }
    (worst, total / (w * h / 16) as f64)
}

fn light_tracing() -> MethodConfig {
    MethodConfig::Light(light::Settings::default())
}

/// The closed form of a point light of intensity `i` at `pos` on the plane
/// z = 0 (normal +z): I cos θ / d² with cos θ = h/d.
fn point_irradiance(pos: Vec3, i: f32) -> impl Fn(Vec3) -> f64 {
    move |q: Vec3| {
        let d = (pos - q).as_dvec3();
        let d2 = d.length_squared();
        i as f64 * (d.z / d2.sqrt()) / d2
    }
}

/// A point light 1.5 above the plane, off centre: `path` (next-event
/// estimation) and `light` (particles) give I cos θ / d².
#[test]
fn point_light_irradiance_is_inverse_square_cosine() {
    let pos = Vec3::new(0.3, -0.2, 1.5);
    let l = PunctualLight {
        kind: PunctualKind::Point,
        position: pos,
        direction: Vec3::NEG_Z,
        intensity: Rgb::splat(3.0),
        name: "point".into(),
    };
    let s = plane_scene(l);
    let e = point_irradiance(pos, 3.0);
    let (zp, mean) = against_closed_form(&s, &path(), 16, &e);
    let (zl, _) = against_closed_form(&s, &light_tracing(), 16, &e);
    assert!(mean > 0.02, "the image is lit: mean {mean}");
    eprintln!("point: worst z path {zp:.2}, light {zl:.2}");
}

/// The extension's spot falloff, written here again from the
/// specification: clamp((cos θ − cos θ_o)/(cos θ_i − cos θ_o), 0, 1)².
fn falloff(c: f64, ci: f64, co: f64) -> f64 {
    ((c - co) / (ci - co)).clamp(0.0, 1.0).powi(2)
}

/// A spot 2 above the plane, tilted by 0.3 rad, cone 15°..30°: the image
/// is I f(θ) cos θ / d² in both methods, and it holds pixels inside the
/// inner cone (full intensity), outside the outer cone (black) and in the
/// falloff between.
#[test]
fn spot_light_cone_and_falloff() {
    let pos = Vec3::new(0.0, 0.0, 2.0);
    let dir = Vec3::new(0.3f32.sin(), 0.0, -0.3f32.cos());
    let (ti, to) = (15f64.to_radians(), 30f64.to_radians());
    let l = PunctualLight {
        kind: PunctualKind::Spot {
            cos_inner: ti.cos() as f32,
            cos_outer: to.cos() as f32,
        },
        position: pos,
        direction: dir,
        intensity: Rgb::new(4.0, 2.0, 1.0),
        name: "spot".into(),
    };
    let s = plane_scene(l);
    let world = World::new(s.clone());
    let mut regions = [0u32; 3]; // outside, falloff, inside, at pixel centres
    for y in 0..32 {
        for x in 0..32 {
            let r = world.camera.ray(x as f32 + 0.5, y as f32 + 0.5);
            let q = r.o + r.d * (-r.o.z / r.d.z);
            let c = dir.as_dvec3().dot((q - pos).as_dvec3().normalize());
            regions[if c <= to.cos() {
                0
            } else if c < ti.cos() {
                1
            } else {
                2
            }] += 1;
        }
    }
    assert!(regions.iter().all(|&n| n >= 20), "regions {regions:?}");
    for (ch, k) in [(0usize, 4.0f64), (2, 1.0)] {
        let e = move |q: Vec3| {
            let d = (pos - q).as_dvec3();
            let dist = d.length();
            let c = dir.as_dvec3().dot(-d / dist);
            k * falloff(c, ti.cos(), to.cos()) * (d.z / dist) / (dist * dist)
        };
        // Each channel against its own closed form: render once per channel
        // of interest by scaling the light to grey
        let mut sc = s.clone();
        if let Some(EmitterDesc::Punctual(l)) = sc.emitters.last_mut() {
            l.intensity = Rgb::splat(k as f32);
        }
        let (zp, mean) = against_closed_form(&sc, &path(), 16, &e);
        let (zl, _) = against_closed_form(&sc, &light_tracing(), 16, &e);
        assert!(mean > 1e-3, "channel {ch}: the cone is lit: mean {mean}");
        eprintln!("spot ×{k}: worst z path {zp:.2}, light {zl:.2}");
    }
    // Outside the outer cone nothing arrives, in either method
    for m in [path(), light_tracing()] {
        let (img, _) = render(&s, &m, 3, 8);
        for y in 0..32 {
            for x in 0..32 {
                let r = world.camera.ray(x as f32 + 0.5, y as f32 + 0.5);
                let q = r.o + r.d * (-r.o.z / r.d.z);
                // a pixel's footprint is ~0.22 wide, ~0.1 rad from the
                // spot: keep two footprints outside
                let c = dir.dot((q - pos).normalize());
                if c < (to + 0.2).cos() as f32 {
                    assert_eq!(
                        img.get(x, y),
                        Vec3::ZERO,
                        "pixel ({x}, {y}) outside the cone"
                    );
                }
            }
        }
    }
}

/// A directional light at θ = 50° from the plane's normal: every pixel is
/// RHO/π · cos θ · E⊥ in both methods (light tracing shoots parallel rays
/// from the disk around the scene).
#[test]
fn directional_light_on_a_tilted_plane() {
    let theta = 50f32.to_radians();
    let e_perp = 2.0f32;
    let l = PunctualLight {
        kind: PunctualKind::Directional,
        position: Vec3::ZERO,
        direction: Vec3::new(theta.sin(), 0.0, -theta.cos()),
        intensity: Rgb::splat(e_perp),
        name: "sun".into(),
    };
    let s = plane_scene(l);
    let e = move |_: Vec3| (theta.cos() * e_perp) as f64;
    let (zp, mean) = against_closed_form(&s, &path(), 4, &e);
    let want = RHO as f64 / std::f64::consts::PI * e(Vec3::ZERO);
    assert!((mean - want).abs() < 1e-5 * want, "{mean} vs {want}");
    let (zl, _) = against_closed_form(&s, &light_tracing(), 16, &e);
    eprintln!("directional: worst z path {zp:.2}, light {zl:.2}");
}

// ---------------------------------------------------------------------------
// path against the light-based methods

/// A small room (floor, back and side walls, a floating occluder) lit by a
/// point lamp and a dim emitting quad: `light` and `plb` agree with `path`
/// block by block (8 × 8 pixels at 32 × 32, z ≤ 5 with the measured
/// variance of both), shadows and inter-reflections included.
#[test]
fn path_light_and_plb_agree_with_a_point_lamp() {
    let mut s = Scene::empty("punctual room");
    let m = s.add_material(Material::Diffuse {
        reflectance: Texture::Constant(Vec3::new(0.7, 0.6, 0.5)),
    });
    let quad = |s: &mut Scene, c: [Vec3; 4], le: Option<Rgb>| {
        s.add_mesh("q", &c, None, None, &[[0, 1, 2], [0, 2, 3]], m, le);
    };
    let v = Vec3::new;
    quad(
        &mut s,
        [
            v(-2., -2., 0.),
            v(2., -2., 0.),
            v(2., 2., 0.),
            v(-2., 2., 0.),
        ],
        None,
    );
    quad(
        &mut s,
        [v(-2., 2., 0.), v(2., 2., 0.), v(2., 2., 3.), v(-2., 2., 3.)],
        None,
    );
    quad(
        &mut s,
        [
            v(-2., -2., 0.),
            v(-2., 2., 0.),
            v(-2., 2., 3.),
            v(-2., -2., 3.),
        ],
        None,
    );
    // the occluder, facing up and down (two quads)
    let o = [
        v(-0.5, -0.2, 1.0),
        v(0.5, -0.2, 1.0),
        v(0.5, 0.8, 1.0),
        v(-0.5, 0.8, 1.0),
    ];
    quad(&mut s, o, None);
    quad(&mut s, [o[0], o[3], o[2], o[1]], None);
    // a dim area light on the right, facing −x
    quad(
        &mut s,
        [
            v(1.9, -0.5, 0.5),
            v(1.9, -0.5, 1.5),
            v(1.9, 0.5, 1.5),
            v(1.9, 0.5, 0.5),
        ],
        Some(Rgb::splat(0.5)),
    );
    s.emitters.push(EmitterDesc::Punctual(PunctualLight {
        kind: PunctualKind::Point,
        position: v(0.2, 0.3, 2.2),
        direction: Vec3::NEG_Z,
        intensity: Rgb::new(2.0, 2.0, 1.5),
        name: "lamp".into(),
    }));
    s.camera = CameraDesc {
        to_world: look_at(v(0.0, -5.0, 2.0), v(0.0, 0.0, 1.0), Vec3::Z),
        fov_x_deg: 55.0,
        width: 32,
        height: 32,
        near_clip: 1e-3,
    };
    let stats = |m: &MethodConfig, seeds: (u64, u64), passes| {
        let (a, _) = render(&s, m, seeds.0, passes);
        let (b, _) = render(&s, m, seeds.1, passes);
        block_stats(&a, &b, 8, &|_, _| true)
    };
    let p = stats(&path(), (1, 2), 64);
    let l = stats(&light_tracing(), (3, 4), 64);
    let lit = p.iter().flatten().filter(|(m, _)| m[0] > 0.01).count();
    assert!(lit >= 8, "the room is lit ({lit} blocks)");
    let (z, block) = max_block_z(&p, &l, 1e-4);
    assert!(z <= 5.0, "light, block {block}: z = {z}");
    let g = stats(&crate::common::plb(plb::Settings::default()), (5, 6), 64);
    let (zg, block) = max_block_z(&p, &g, 1e-4);
    assert!(zg <= 5.0, "plb, block {block}: z = {zg}");
    eprintln!("room: worst block z light {z:.2}, plb {zg:.2}");
}

// ---------------------------------------------------------------------------
// A file written by Blender

/// Blender's glTF exporter (5.0.1, `punctual/make_blender_lamps.py`) writes
/// a P-watt point or spot lamp as P/(4π) · 683 cd and a sun of S W/m² as
/// S · 683 lx; read back, each has the intensity Cycles renders it with
/// (P/(4π) W/sr, S W/m²), its Blender position and −z direction (Blender's
/// z-up axes become glTF's y-up ones: (x, y, z) → (x, z, −y)), and the
/// spot's cone (outer = size/2, inner = outer · (1 − blend)).
#[test]
fn blender_lamps_come_back_with_their_power() {
    let p = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("tests/it/punctual/blender-lamps.gltf");
    let s = scene::load(&p).unwrap_or_else(|e| panic!("{e}"));
    let l = punctual(&s);
    assert_eq!(l.len(), 3);
    let by_name = |n: &str| *l.iter().find(|l| l.name == n).expect(n);
    let to_gltf = |v: Vec3| Vec3::new(v.x, v.z, -v.y);
    let close = |a: Vec3, b: Vec3| (a - b).abs().max_element() < 1e-4 * (1.0 + b.length());
    let four_pi = 4.0 * std::f32::consts::PI;

    let pt = by_name("pt");
    assert_eq!(pt.kind, PunctualKind::Point);
    assert!(close(pt.position, to_gltf(Vec3::new(0.0, 0.0, 2.0))));
    assert!(
        close(pt.intensity, Vec3::splat(100.0 / four_pi)),
        "{}",
        pt.intensity
    );

    let sp = by_name("sp");
    assert!(close(sp.position, to_gltf(Vec3::new(1.0, 0.0, 2.0))));
    let blender_dir = glam::Mat3::from_rotation_x(0.3) * Vec3::NEG_Z;
    assert!(
        close(sp.direction, to_gltf(blender_dir)),
        "{}",
        sp.direction
    );
    assert!(
        close(sp.intensity, Vec3::splat(200.0 / four_pi)),
        "{}",
        sp.intensity
    );
    let PunctualKind::Spot {
        cos_inner,
        cos_outer,
    } = sp.kind
    else {
        panic!("sp is a {:?}", sp.kind)
    };
    assert!((cos_outer - 30f32.to_radians().cos()).abs() < 1e-5);
    assert!((cos_inner - 22.5f32.to_radians().cos()).abs() < 1e-5);

    let sun = by_name("sun");
    assert_eq!(sun.kind, PunctualKind::Directional);
    // Blender's XYZ Euler angles: R = Rz · Ry · Rx
    let r = glam::Mat3::from_euler(glam::EulerRot::ZYX, 0.0, 0.2, 0.5);
    assert!(
        close(sun.direction, to_gltf(r * Vec3::NEG_Z)),
        "{}",
        sun.direction
    );
    assert!(close(sun.intensity, Vec3::splat(3.0)), "{}", sun.intensity);
}

// ---------------------------------------------------------------------------
// Selection, and the method that refuses lamps

/// With 144 ceiling quads (a light tree whose choices depend on the
/// shading point), a point lamp and a constant environment, both
/// selections choose the lamp with its power share, 4π lum(I)/Φ (the
/// tree's part is only the triangles'); the environment's share stays the
/// one `pdf_li_env` gives, and a lamp sample is always `delta` with
/// `pdf` equal to the share. Tolerance: 4 binomial standard deviations of
/// the observed frequency.
#[test]
fn lamps_take_their_power_share_under_both_selections() {
    use kalos::emitter::LightSelection;
    let mut s = Scene::empty("ceiling and lamp");
    let m = s.add_material(Material::Diffuse {
        reflectance: Texture::Constant(Vec3::splat(0.5)),
    });
    for i in 0..12 {
        for j in 0..12 {
            let o = Vec3::new(i as f32 - 5.5, j as f32 - 5.5, 3.0);
            let c = [
                o + Vec3::new(-0.3, -0.3, 0.0),
                o + Vec3::new(-0.3, 0.3, 0.0),
                o + Vec3::new(0.3, 0.3, 0.0),
                o + Vec3::new(0.3, -0.3, 0.0),
            ];
            s.add_mesh(
                "q",
                &c,
                None,
                None,
                &[[0, 1, 2], [0, 2, 3]],
                m,
                Some(Rgb::ONE),
            );
        }
    }
    let i_lamp = 2.0f32;
    s.emitters.push(EmitterDesc::Punctual(PunctualLight {
        kind: PunctualKind::Point,
        position: Vec3::new(0.0, 0.0, 2.0),
        direction: Vec3::NEG_Z,
        intensity: Rgb::splat(i_lamp),
        name: "lamp".into(),
    }));
    s.emitters.push(EmitterDesc::Constant {
        radiance: Rgb::splat(0.01),
    });
    let lights = World::new(s).lights;
    let share = (4.0 * std::f64::consts::PI * i_lamp as f64) / lights.total_power();
    assert!(share > 0.05 && share < 0.95, "share {share}");
    let mut rng = kalos::sampling::Pcg32::new(9, 0);
    let n = 40_000;
    for sel in [LightSelection::Power, LightSelection::Spatial] {
        let (mut lamp, mut env) = (0u32, 0u32);
        let p = Vec3::new(-5.0, -5.0, 0.0);
        for _ in 0..n {
            let Some(ls) = lights.sample_li_from(sel, p, Vec3::Z, rng.next_f32(), rng.next_2d())
            else {
                continue;
            };
            if ls.delta {
                lamp += 1;
                assert!(
                    ((ls.pdf as f64) - share).abs() < 1e-4 * share,
                    "{sel:?} pdf {}",
                    ls.pdf
                );
            } else if ls.is_env {
                env += 1;
            }
        }
        let f = lamp as f64 / n as f64;
        let sd = (share * (1.0 - share) / n as f64).sqrt();
        assert!(
            (f - share).abs() <= 4.0 * sd,
            "{sel:?}: lamp chosen {f}, share {share}"
        );
        let env_share = lights.selection_pmf(sel, p, Vec3::Z, u32::MAX) as f64;
        let fe = env as f64 / n as f64;
        let sde = (env_share * (1.0 - env_share) / n as f64).sqrt();
        assert!(
            (fe - env_share).abs() <= 4.0 * sde + 1e-9,
            "{sel:?}: environment chosen {fe}, share {env_share}"
        );
    }
}

/// `bundle --direct bundles` refuses a scene with a lamp, naming it and
/// saying why; the default first shot (`--direct nee`) renders it.
#[test]
fn bundle_refuses_lamps_only_in_the_papers_form() {
    use kalos::methods::bundle::{self, Direct};
    use kalos::methods::Budget;
    use kalos::render::Render;
    let s = plane_scene(PunctualLight {
        kind: PunctualKind::Point,
        position: Vec3::new(0.0, 0.0, 1.5),
        direction: Vec3::NEG_Z,
        intensity: Rgb::splat(3.0),
        name: "desk lamp".into(),
    });
    let world = World::new(s.clone());
    let run = |direct| {
        Render::new(&world)
            .method(MethodConfig::Bundle(bundle::Settings {
                direct,
                patches: 200,
                ..Default::default()
            }))
            .budget(Budget {
                passes: Some(1),
                ..Default::default()
            })
            .run(|_| {})
    };
    let e = run(Direct::Bundles).err().expect("refused").to_string();
    assert!(
        e.contains("desk lamp") && e.contains("--direct nee") && e.contains("no surface"),
        "{e}"
    );
    let r = run(Direct::Nee).unwrap_or_else(|e| panic!("{e}"));
    let mean: f32 = r.image.data.iter().map(|p| p.x).sum::<f32>() / r.image.data.len() as f32;
    assert!(mean > 0.01, "the first shot lights the plane: mean {mean}");
}
