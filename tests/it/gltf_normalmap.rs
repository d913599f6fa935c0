//! glTF normal maps (`normalTexture`, tangent space): a quad with a
//! constant normal map tilted by a known angle, lit by a directional light
//! (`KHR_lights_punctual`), shows the cosine of the tilted normal in
//! `path` (to f32 rounding: next-event estimation on a lone plane is
//! exact) and in `light` (within noise); the asset's `TANGENT` and
//! MikkTSpace tangents agree, also under a mirroring node; a flat
//! (0.5, 0.5, 1) map gives the image of no map.
//!
//! The quad is written by hand: side 8 at z = 0 facing +z, uv u along +x
//! (or −x, mirrored) and glTF's v down −y, so that the image stands upright
//! on it; its material is replaced by a Lambertian one after loading, for
//! the closed form ρ/π · E⊥ · max(0, n'·l).

use std::path::{Path, PathBuf};

use glam::{DVec3, Vec3};
use kalos::geometry::look_at;
use kalos::scene::{self, CameraDesc, Material, Scene, Texture};

use crate::common::{mean_and_se, path, render};

const RHO: f32 = 0.5;
/// The directional light's illuminance, lux (E⊥ = 2 W/m² at 683 lm/W).
const LUX: f32 = 1366.0;

fn tmp() -> tempfile::TempDir {
    tempfile::Builder::new()
        .prefix("kalos-normalmap-")
        .tempdir()
        .unwrap()
}

/// A 1 × 1 RGB PNG of 16-bit values.
fn png16(c: [u16; 3]) -> Vec<u8> {
    let img = image::ImageBuffer::<image::Rgb<u16>, Vec<u16>>::from_raw(1, 1, c.to_vec())
        .expect("one pixel");
    let mut out = Vec::new();
    image::DynamicImage::ImageRgb16(img)
        .write_to(&mut std::io::Cursor::new(&mut out), image::ImageFormat::Png)
        .expect("PNG");
    out
}

/// A tangent-space normal as 16-bit texel values, and the normal they
/// decode to (c / 65535 · 2 − 1, as the specification reads them).
fn encode(n: DVec3) -> ([u16; 3], DVec3) {
    let c = n
        .to_array()
        .map(|x| ((x + 1.0) * 0.5 * 65535.0).round() as u16);
    let back = DVec3::from_array(c.map(|v| v as f64 / 65535.0 * 2.0 - 1.0));
    (c, back)
}

/// What a test quad carries.
#[derive(Clone, Default)]
struct Quad {
    /// u runs along −x instead of +x.
    mirror_u: bool,
    /// A TANGENT attribute, the same at every vertex.
    tangent: Option<[f32; 4]>,
    /// The normal texture's texel and its scale.
    normal: Option<([u16; 3], f32)>,
    /// The quad's node scales x by −1 (a mirroring transform).
    mirror_node: bool,
}

/// Writes `name.gltf` (and its buffer and image) in `dir`: the quad, with
/// a directional light on a node turned so that the light travels along
/// `d` (unit, d.z < 0). Returns its path.
fn write_quad(dir: &Path, name: &str, q: &Quad, d: Vec3) -> PathBuf {
    let pos = [
        [-4.0f32, -4.0, 0.0],
        [4.0, -4.0, 0.0],
        [4.0, 4.0, 0.0],
        [-4.0, 4.0, 0.0],
    ];
    let mut bin = Vec::new();
    for p in pos {
        bin.extend(p.iter().flat_map(|v| v.to_le_bytes()));
    }
    for _ in pos {
        bin.extend([0.0f32, 0.0, 1.0].iter().flat_map(|v| v.to_le_bytes()));
    }
    for p in pos {
        let u = (p[0] + 4.0) / 8.0;
        let u = if q.mirror_u { 1.0 - u } else { u };
        let v = (4.0 - p[1]) / 8.0;
        bin.extend([u, v].iter().flat_map(|v| v.to_le_bytes()));
    }
    for i in [0u16, 1, 2, 0, 2, 3] {
        bin.extend(i.to_le_bytes());
    }
    let idx_len = 12;
    let tan_at = bin.len();
    if let Some(t) = q.tangent {
        for _ in pos {
            bin.extend(t.iter().flat_map(|v| v.to_le_bytes()));
        }
    }
    std::fs::write(dir.join(format!("{name}.bin")), &bin).unwrap();
    let mut accessors = vec![
        r#"{"bufferView":0,"componentType":5126,"count":4,"type":"VEC3","min":[-4,-4,0],"max":[4,4,0]}"#.to_string(),
        r#"{"bufferView":1,"componentType":5126,"count":4,"type":"VEC3"}"#.into(),
        r#"{"bufferView":2,"componentType":5126,"count":4,"type":"VEC2"}"#.into(),
        r#"{"bufferView":3,"componentType":5123,"count":6,"type":"SCALAR"}"#.into(),
    ];
    let mut views = vec![
        r#"{"buffer":0,"byteOffset":0,"byteLength":48}"#.to_string(),
        r#"{"buffer":0,"byteOffset":48,"byteLength":48}"#.into(),
        r#"{"buffer":0,"byteOffset":96,"byteLength":32}"#.into(),
        format!(r#"{{"buffer":0,"byteOffset":128,"byteLength":{idx_len}}}"#),
    ];
    let mut attributes = r#""POSITION":0,"NORMAL":1,"TEXCOORD_0":2"#.to_string();
    if q.tangent.is_some() {
        accessors.push(r#"{"bufferView":4,"componentType":5126,"count":4,"type":"VEC4"}"#.into());
        views.push(format!(
            r#"{{"buffer":0,"byteOffset":{tan_at},"byteLength":64}}"#
        ));
        attributes.push_str(r#","TANGENT":4"#);
    }
    let (normal_texture, images) = match q.normal {
        Some((c, scale)) => {
            std::fs::write(dir.join(format!("{name}.png")), png16(c)).unwrap();
            (
                format!(r#","normalTexture":{{"index":0,"scale":{scale}}}"#),
                format!(r#","images":[{{"uri":"{name}.png"}}],"textures":[{{"source":0}}]"#),
            )
        }
        None => (String::new(), String::new()),
    };
    // the light's node turns −z into d: a rotation about y by φ maps −z to
    // (−sin φ, 0, −cos φ), one about x by ψ maps it to (0, sin ψ, −cos ψ)
    let rot = if d.y.abs() < 1e-6 {
        let phi = (-d.x).atan2(-d.z);
        [0.0, (phi / 2.0).sin(), 0.0, (phi / 2.0).cos()]
    } else {
        assert!(d.x.abs() < 1e-6, "light directions in the xz or yz plane");
        let psi = d.y.atan2(-d.z);
        [(psi / 2.0).sin(), 0.0, 0.0, (psi / 2.0).cos()]
    };
    let quad_node = if q.mirror_node {
        r#"{"mesh":0,"scale":[-1,1,1]}"#
    } else {
        r#"{"mesh":0}"#
    };
    let json = format!(
        r#"{{"asset":{{"version":"2.0"}},"scene":0,"scenes":[{{"nodes":[0,1]}}],
        "extensionsUsed":["KHR_lights_punctual"],
        "extensions":{{"KHR_lights_punctual":{{"lights":[{{"type":"directional","intensity":{LUX}}}]}}}},
        "nodes":[{quad_node},{{"rotation":{rot:?},"extensions":{{"KHR_lights_punctual":{{"light":0}}}}}}],
        "meshes":[{{"primitives":[{{"attributes":{{{attributes}}},"indices":3,"material":0}}]}}],
        "materials":[{{"pbrMetallicRoughness":{{"metallicFactor":0}}{normal_texture}}}]{images},
        "accessors":[{}],
        "bufferViews":[{}],
        "buffers":[{{"byteLength":{},"uri":"{name}.bin"}}]}}"#,
        accessors.join(","),
        views.join(","),
        bin.len()
    );
    let p = dir.join(format!("{name}.gltf"));
    std::fs::write(&p, json).unwrap();
    p
}

/// Loads a test quad, makes its material Lambertian (albedo `RHO`) and
/// looks straight down at it from (0, 0, 6) (16 × 16 pixels, the film
/// inside the quad).
fn load(p: &Path) -> Scene {
    let mut s = scene::load(p).unwrap_or_else(|e| panic!("{e}"));
    assert_eq!(s.shapes.len(), 1);
    let m = s.shapes[0].material as usize;
    s.materials[m] = Material::Diffuse {
        reflectance: Texture::Constant(Vec3::splat(RHO)),
    };
    s.camera = CameraDesc {
        to_world: look_at(Vec3::new(0.0, 0.0, 6.0), Vec3::ZERO, Vec3::Y),
        fov_x_deg: 60.0,
        width: 16,
        height: 16,
        near_clip: 1e-3,
    };
    s
}

/// A normal map tilting the normal by 25° toward +x (red), then toward +y
/// (green), then by 25° with scale 0.6, under a directional light 40° from
/// the zenith on the tilt's side: every pixel of `path` is
/// ρ/π · E⊥ · cos(n', l) with n' = normalize(T x s + B y s + N z), T = +x,
/// B = +y, to 1e-4; `light` gives it within noise. Without the map the
/// image is ρ/π · E⊥ · cos 40°, which the tilted one is not.
#[test]
fn a_tilted_normal_map_follows_the_cosine_of_the_tilted_normal() {
    let d = tmp();
    let (alpha, theta) = (25f64.to_radians(), 40f64.to_radians());
    let e_perp = LUX as f64 / 683.0;
    let k = RHO as f64 / std::f64::consts::PI * e_perp;
    let mut tested = 0;
    for (axis, scale) in [("x", 1.0f32), ("y", 1.0), ("x", 0.6)] {
        let (nt, l) = match axis {
            "x" => (
                DVec3::new(alpha.sin(), 0.0, alpha.cos()),
                DVec3::new(theta.sin(), 0.0, theta.cos()),
            ),
            _ => (
                DVec3::new(0.0, alpha.sin(), alpha.cos()),
                DVec3::new(0.0, theta.sin(), theta.cos()),
            ),
        };
        let (c, nt) = encode(nt);
        let name = format!("tilt-{axis}-{tested}");
        let q = Quad {
            normal: Some((c, scale)),
            ..Default::default()
        };
        // the light travels along −l
        let p = write_quad(d.path(), &name, &q, (-l).as_vec3());
        let s = load(&p);
        let nm = s.shapes[0].normal_map.as_ref().expect("a normal map");
        assert_eq!(nm.tangents.len(), 2);
        let s64 = scale as f64;
        let n = DVec3::new(nt.x * s64, nt.y * s64, nt.z).normalize();
        let want = k * n.dot(l).max(0.0);
        let flat = k * theta.cos();
        assert!(
            (want - flat).abs() > 0.1 * flat,
            "the tilt shows: {want} vs {flat}"
        );
        let (img, _) = render(&s, &path(), 1, 2);
        for (i, px) in img.data.iter().enumerate() {
            for ch in 0..3 {
                let v = px[ch] as f64;
                assert!(
                    (v - want).abs() <= 1e-4 * want,
                    "{axis} ×{scale}: pixel {i} channel {ch}: {v} vs {want} (untilted {flat})"
                );
            }
        }
        let (img, _) = render(&s, &crate::common::light(Default::default()), 2, 16);
        let (mean, se) = mean_and_se(&img, 1);
        assert!(
            (mean - want).abs() <= 5.0 * se + 2e-3 * want,
            "{axis} ×{scale}: light tracing {mean} ± {se} vs {want}"
        );
        tested += 1;
    }
    assert_eq!(tested, 3);
}

/// The same mirrored mapping four ways: u along −x with TANGENT
/// (−1, 0, 0, −1), u along −x with MikkTSpace tangents, and the quad with
/// u along +x under a node scaling x by −1, with TANGENT (1, 0, 0, 1) and
/// with MikkTSpace. In world space each is T = −x with w = −1 (B = +y,
/// the image's up), and the renders of a normal map tilted toward both x
/// and y agree (to 1e-5: the tangents are equal to f32 rounding).
#[test]
fn given_and_generated_tangents_agree() {
    let d = tmp();
    let a = 30f64.to_radians();
    let (c, _) = encode(DVec3::new(a.sin() * 0.6, a.sin() * 0.8, a.cos()));
    let light = Vec3::new(0.3, 0.0, -1.0).normalize();
    let cases = [
        ("given", true, Some([-1.0, 0.0, 0.0, -1.0]), false),
        ("generated", true, None, false),
        ("node-given", false, Some([1.0, 0.0, 0.0, 1.0]), true),
        ("node-generated", false, None, true),
    ];
    let mut images = Vec::new();
    for (name, mirror_u, tangent, mirror_node) in cases {
        let q = Quad {
            mirror_u,
            tangent,
            normal: Some((c, 1.0)),
            mirror_node,
        };
        let s = load(&write_quad(d.path(), name, &q, light));
        let nm = s.shapes[0].normal_map.as_ref().expect("a normal map");
        for t in nm.tangents.iter().flatten() {
            assert!(
                (t.truncate() - Vec3::NEG_X).length() < 1e-5 && t.w == -1.0,
                "{name}: tangent {t}"
            );
        }
        images.push((name, render(&s, &path(), 7, 2).0));
    }
    let (_, first) = &images[0];
    let mean = mean_and_se(first, 0).0;
    assert!(mean > 0.05, "lit: {mean}");
    for (name, img) in &images[1..] {
        for (i, (a, b)) in first.data.iter().zip(&img.data).enumerate() {
            assert!(
                (*a - *b).abs().max_element() <= 1e-5 * a.max_element(),
                "{name}: pixel {i}: {b} vs {a}"
            );
        }
    }
}

/// A flat normal map, (0.5, 0.5, 1) as 16-bit texels (32768 is 0.5 to
/// 1.5e-5), gives the image of the same quad without a map, to 1e-4.
#[test]
fn a_flat_normal_map_gives_the_image_of_no_map() {
    let d = tmp();
    let light = Vec3::new(-0.4, 0.0, -1.0).normalize();
    let flat = Quad {
        normal: Some(([32768, 32768, 65535], 1.0)),
        ..Default::default()
    };
    let s = load(&write_quad(d.path(), "flat", &flat, light));
    assert!(s.shapes[0].normal_map.is_some());
    let plain = load(&write_quad(d.path(), "plain", &Quad::default(), light));
    assert!(plain.shapes[0].normal_map.is_none());
    let (a, _) = render(&s, &path(), 3, 2);
    let (b, _) = render(&plain, &path(), 3, 2);
    assert!(mean_and_se(&b, 0).0 > 0.05);
    for (i, (x, y)) in a.data.iter().zip(&b.data).enumerate() {
        assert!(
            (*x - *y).abs().max_element() <= 1e-4 * y.max_element(),
            "pixel {i}: {x} vs {y}"
        );
    }
}

/// `path`'s AVX lanes shade diffuse vertices themselves when every light
/// is a triangle: on the tilted quad lit by an emitting quad (its lamp
/// replaced), the lanes give every pixel the scalar estimator's radiance
/// bit for bit, so they see the normal map; and the map shows (the image
/// differs from the unmapped quad's by more than 10 %). On a CPU without
/// AVX2 both sides are the scalar code.
#[test]
fn path_lanes_see_the_normal_map() {
    use kalos::emitter::LightSelection;
    use kalos::sampling::Pcg32;
    use kalos::scene::{EmitterDesc, Rgb};
    use kalos::transport::lanes::radiance_camera_row;
    use kalos::transport::{radiance_from_hit, DepthLimits};
    use kalos::world::World;
    let d = tmp();
    let a = 35f64.to_radians();
    let (c, _) = encode(DVec3::new(a.sin(), 0.0, a.cos()));
    let light = Vec3::new(0.3, 0.0, -1.0).normalize();
    let lamp_lit = |q: &Quad, name: &str| {
        let mut s = load(&write_quad(d.path(), name, q, light));
        s.emitters
            .retain(|e| !matches!(e, EmitterDesc::Punctual(_)));
        let m = s.shapes[0].material;
        // a lamp off to +x, facing down (its winding clockwise seen from
        // above)
        let v = Vec3::new;
        let lamp = [v(3., -1., 2.), v(3., 1., 2.), v(5., 1., 2.), v(5., -1., 2.)];
        s.add_mesh(
            "lamp",
            &lamp,
            None,
            None,
            &[[0, 1, 2], [0, 2, 3]],
            m,
            Some(Rgb::splat(5.0)),
        );
        World::new(s)
    };
    let mapped = Quad {
        normal: Some((c, 1.0)),
        ..Default::default()
    };
    let limits = DepthLimits {
        max_depth: None,
        rr_depth: 5,
        light_selection: LightSelection::Power,
    };
    let mut means = Vec::new();
    for (name, q) in [("lanes-mapped", mapped), ("lanes-plain", Quad::default())] {
        let world = lamp_lit(&q, name);
        assert!(world
            .scene
            .emitters
            .iter()
            .all(|e| matches!(e, EmitterDesc::Area { .. })));
        let w = world.camera.width as usize;
        let mut sum = 0.0f64;
        for y in 0..world.camera.height as usize {
            let sampler = |x: usize| Pcg32::keyed(&[5, y as u64, x as u64]);
            let start = |x: usize| {
                let mut rng = sampler(x);
                let j = rng.next_2d();
                (rng, world.camera.ray(x as f32 + j.x, y as f32 + j.y))
            };
            let mut lanes = vec![None; w];
            radiance_camera_row(&world, &limits, y, sampler, |x, l, n| {
                lanes[x] = Some((l.to_array().map(f32::to_bits), n));
            });
            for (x, got) in lanes.iter().enumerate() {
                let (mut rng, ray) = start(x);
                let (l, n) = radiance_from_hit(&world, &limits, ray, None, &mut rng, 1);
                sum += l.x as f64;
                assert_eq!(
                    *got,
                    Some((l.to_array().map(f32::to_bits), n)),
                    "{name}: pixel ({x}, {y})"
                );
            }
        }
        means.push(sum);
    }
    assert!(
        (means[0] - means[1]).abs() > 0.1 * means[1] && means[1] > 0.0,
        "the map shows: {means:?}"
    );
}
