//! glTF's metallic–roughness BRDF as kalos reads it: a dielectric is a GGX
//! coat of index 1.5 (F0 = 0.04) with α = roughness² over its base colour
//! (`roughplastic`, `plastic` when smooth), a metal is a conductor tinted by
//! its base colour, and both keep what the density method and the lightmap
//! bake need (a dielectric's diffuse part). Each file is written by hand
//! here: one square, its materials given as JSON.
//!
//! Tolerances: Monte Carlo albedos are compared with 5 standard errors
//! (their spread measured from the same samples); renders compare image
//! means with the same rule.

use std::path::{Path, PathBuf};

use glam::{Vec2, Vec3};
use kalos::bsdf::{Bsdf, Mode};
use kalos::geometry::look_at;
use kalos::sampling::Pcg32;
use kalos::scene::{self, CameraDesc, Coat, Material, MicrofacetKind, Rgb, Scene, Texture};

use crate::common::{mean_and_se, path, render};

fn tmp() -> tempfile::TempDir {
    tempfile::Builder::new()
        .prefix("kalos-gltf-brdf-")
        .tempdir()
        .unwrap()
}

/// Writes `name` in `dir`: a glTF file with one square of half-side `s` in
/// the y = 0 plane, facing +y, uv (0, 0) at (−s, −s) and (1, 1) at (s, s)
/// (u along x, v along z), drawn with material 0. `materials` is the JSON
/// array of materials; `rest` more top-level members (`"textures":[…]`
/// and the like), with a leading comma, or empty.
pub(crate) fn square(dir: &Path, name: &str, s: f32, materials: &str, rest: &str) -> PathBuf {
    let mut bin = Vec::new();
    let corners = [[-s, -s], [-s, s], [s, s], [s, -s]];
    for [x, z] in corners {
        for v in [x, 0.0, z] {
            bin.extend(v.to_le_bytes());
        }
    }
    for _ in corners {
        for v in [0.0f32, 1.0, 0.0] {
            bin.extend(v.to_le_bytes());
        }
    }
    for [x, z] in corners {
        for v in [(x + s) / (2.0 * s), (z + s) / (2.0 * s)] {
            bin.extend(v.to_le_bytes());
        }
    }
    for i in [0u16, 1, 2, 0, 2, 3] {
        bin.extend(i.to_le_bytes());
    }
    std::fs::write(dir.join(format!("{name}.bin")), &bin).unwrap();
    let json = format!(
        r#"{{"asset":{{"version":"2.0"}},"scene":0,"scenes":[{{"nodes":[0]}}],
"nodes":[{{"mesh":0}}],
"meshes":[{{"primitives":[{{"attributes":{{"POSITION":0,"NORMAL":1,"TEXCOORD_0":2}},
  "indices":3,"material":0}}]}}],
"materials":{materials},
"accessors":[{{"bufferView":0,"componentType":5126,"count":4,"type":"VEC3",
               "min":[{m},0,{m}],"max":[{s},0,{s}]}},
             {{"bufferView":1,"componentType":5126,"count":4,"type":"VEC3"}},
             {{"bufferView":2,"componentType":5126,"count":4,"type":"VEC2"}},
             {{"bufferView":3,"componentType":5123,"count":6,"type":"SCALAR"}}],
"bufferViews":[{{"buffer":0,"byteOffset":0,"byteLength":48}},
               {{"buffer":0,"byteOffset":48,"byteLength":48}},
               {{"buffer":0,"byteOffset":96,"byteLength":32}},
               {{"buffer":0,"byteOffset":128,"byteLength":12}}],
"buffers":[{{"byteLength":140,"uri":"{name}.bin"}}]{rest}}}"#,
        m = -s
    );
    let p = dir.join(format!("{name}.gltf"));
    std::fs::write(&p, json).unwrap();
    p
}

fn load(p: &Path) -> Scene {
    scene::load(p).unwrap_or_else(|e| panic!("{e}"))
}

/// The directional albedo ∫ f cos θi dωi of `b` seen from `wo`, by `n`
/// samples of `sample` (delta lobes included), with its standard error.
fn albedo(b: &Bsdf, wo: Vec3, n: usize, seed: u64) -> (f64, f64) {
    let mut rng = Pcg32::new(0xa1be, seed);
    let (mut s1, mut s2) = (0.0f64, 0.0f64);
    for _ in 0..n {
        let uc = rng.next_f32();
        let u = rng.next_2d();
        let w = match b.sample(wo, uc, u, Mode::Radiance) {
            Some(s) => (s.f.y * s.wi.z.abs() / s.pdf) as f64,
            None => 0.0,
        };
        s1 += w;
        s2 += w * w;
    }
    let mean = s1 / n as f64;
    let var = (s2 / n as f64 - mean * mean).max(0.0);
    (mean, (var / n as f64).sqrt())
}

/// A direction at cos θ = `c` from the normal.
fn at_cos(c: f32) -> Vec3 {
    Vec3::new((1.0 - c * c).max(0.0).sqrt(), 0.0, c)
}

fn mat(base: [f32; 3], metallic: f32, roughness: f32) -> String {
    format!(
        r#"{{"pbrMetallicRoughness":{{"baseColorFactor":[{},{},{},1],
            "metallicFactor":{metallic},"roughnessFactor":{roughness}}}}}"#,
        base[0], base[1], base[2]
    )
}

/// A rough non-metal becomes `roughplastic` with GGX α = roughness², η =
/// 1.5 (F0 = 0.04) and the base colour as its (linear) diffuse base; a
/// smooth one `plastic`; a metal stays a tinted conductor. The dielectric
/// keeps a diffuse part, whose reflectance is about its base colour.
#[test]
fn dielectrics_get_a_coat_of_index_one_and_a_half_and_metals_stay() {
    let d = tmp();
    let mats = format!(
        "[{},{},{}]",
        mat([0.8, 0.4, 0.2], 0.0, 0.5),
        mat([0.8, 0.4, 0.2], 0.2, 0.0),
        mat([0.9, 0.6, 0.3], 1.0, 0.5)
    );
    let s = load(&square(d.path(), "kinds", 1.0, &mats, ""));
    let base = Rgb::new(0.8, 0.4, 0.2);
    match &s.materials[0] {
        Material::RoughPlastic {
            diffuse_reflectance: Texture::Constant(c),
            specular_reflectance: Texture::Constant(w),
            distribution: MicrofacetKind::Ggx,
            alpha,
            eta,
            nonlinear: false,
            coat: Coat::Gltf { specular },
        } => {
            // the base colour as given: the coat's kind makes it the coated
            // base's diffuse reflectance (checked below)
            assert_eq!(*c, base);
            assert_eq!(*specular, 1.0);
            assert_eq!(*w, Rgb::ONE);
            assert!((alpha - 0.25).abs() < 1e-6, "α {alpha}");
            let f0 = ((eta - 1.0) / (eta + 1.0)).powi(2);
            assert!((f0 - 0.04).abs() < 1e-6, "F0 {f0}");
        }
        m => panic!("not a GGX roughplastic: {m:?}"),
    }
    assert!(
        matches!(&s.materials[1], Material::Plastic { eta, nonlinear: false, .. } if *eta == 1.5),
        "{:?}",
        s.materials[1]
    );
    assert!(
        matches!(
            &s.materials[2],
            Material::RoughConductor { alpha, distribution: MicrofacetKind::Ggx, .. }
                if (alpha - 0.25).abs() < 1e-6
        ),
        "{:?}",
        s.materials[2]
    );
    // the diffuse part the density method and the bake store: its
    // reflectance R_d is the base colour, through either coat
    for m in &s.materials[..2] {
        let dp = m
            .bsdf(Vec2::splat(0.5))
            .diffuse_part()
            .expect("a dielectric keeps a diffuse part");
        let rd = dp.rd();
        assert!(
            (rd / base - Rgb::ONE).abs().max_element() < 1e-3,
            "R_d {rd} against the base colour {base}"
        );
    }
    assert!(s.materials[2]
        .bsdf(Vec2::splat(0.5))
        .diffuse_part()
        .is_none());
}

/// A white glTF dielectric neither creates energy nor loses much of it at
/// normal incidence (a furnace on the BSDF as loaded); a black one reflects
/// only its coat: about F0 = 0.04 at normal incidence, and several times
/// more at grazing angles (the old mapping, pure diffuse, reflected
/// nothing at either).
#[test]
fn gltf_dielectric_furnace_and_fresnel_coat() {
    let d = tmp();
    let mats = format!(
        "[{},{},{},{},{},{}]",
        mat([0.0, 0.0, 0.0], 0.0, 0.3),
        mat([0.0, 0.0, 0.0], 0.0, 0.0),
        mat([1.0, 1.0, 1.0], 0.0, 0.5),
        mat([1.0, 1.0, 1.0], 0.0, 0.0),
        // glTF's default roughness, where Mitsuba's single-scattering coat
        // would pass on only 0.88 at normal incidence
        mat([1.0, 1.0, 1.0], 0.0, 1.0),
        mat([1.0, 1.0, 1.0], 0.0, 0.75)
    );
    let s = load(&square(d.path(), "furnace", 1.0, &mats, ""));
    let uv = Vec2::splat(0.5);
    const N: usize = 200_000;
    for (k, m) in s.materials[2..].iter().enumerate() {
        let b = m.bsdf(uv);
        for (j, c) in [1.0f32, 0.5, 0.15].into_iter().enumerate() {
            let (a, se) = albedo(&b, at_cos(c), N, (k * 8 + j) as u64);
            eprintln!("white, material {k}, cos θo {c}: albedo {a:.4} ± {se:.4}");
            assert!(a <= 1.0 + 5.0 * se + 2e-3, "material {k} cos {c}: {a}");
            if c >= 0.5 {
                assert!(a >= 0.95 - 5.0 * se, "material {k} cos {c}: {a}");
            }
        }
    }
    for (k, m) in s.materials[..2].iter().enumerate() {
        let b = m.bsdf(uv);
        let (n0, se0) = albedo(&b, at_cos(1.0), N, 100 + k as u64);
        let (g, seg) = albedo(&b, at_cos(0.1), N, 200 + k as u64);
        eprintln!("black, material {k}: normal {n0:.4} ± {se0:.4}, grazing {g:.4} ± {seg:.4}");
        assert!(
            (n0 - 0.04).abs() < 0.005 + 5.0 * se0,
            "material {k}: {n0} at normal incidence"
        );
        assert!(
            g > 4.0 * n0 + 5.0 * (seg + 4.0 * se0),
            "material {k}: {g} at grazing incidence, {n0} at normal"
        );
    }
}

/// The same through the renderer: a black rough dielectric floor under the
/// white sky a glTF file without lights gets, seen by `path` from above
/// and from 84° off the normal. The pixel values are the coat's
/// directional albedo; the grazing view must be several times brighter.
#[test]
fn a_gltf_dielectric_reflects_more_at_grazing_angles_in_a_render() {
    let d = tmp();
    let mats = format!("[{}]", mat([0.0, 0.0, 0.0], 0.0, 0.3));
    let mut s = load(&square(d.path(), "floor", 1000.0, &mats, ""));
    assert!(
        s.notes.iter().any(|n| n.contains("white")) || !s.emitters.is_empty(),
        "the file has no light: it gets the default sky"
    );
    let view = |s: &mut Scene, theta_deg: f32| {
        let t = theta_deg.to_radians();
        let eye = Vec3::new(0.0, t.cos(), t.sin());
        s.camera = CameraDesc::from_fov(
            // the view stays in the y–z plane: x is always across it
            look_at(eye, Vec3::ZERO, Vec3::X),
            2.0,
            "x",
            8,
            8,
        )
        .unwrap();
    };
    let mut means = Vec::new();
    for (k, theta) in [0.0f32, 84.0].into_iter().enumerate() {
        view(&mut s, theta);
        let (img, _) = render(&s, &path(), 7 + k as u64, 256);
        let (m, se) = mean_and_se(&img, 1);
        eprintln!("θ {theta}°: {m:.4} ± {se:.4}");
        means.push((m, se));
    }
    let ((n0, se0), (g, seg)) = (means[0], means[1]);
    assert!((n0 - 0.04).abs() < 0.005 + 5.0 * se0, "normal: {n0}");
    assert!(
        g > 4.0 * n0 + 5.0 * (seg + 4.0 * se0),
        "grazing {g}, normal {n0}"
    );
}

// ---------------------------------------------------------------------------
// Textures

/// A PNG of `w`×`h` RGB texels, as a `data:` URI.
fn png_uri(w: u32, h: u32, texels: &[[u8; 3]]) -> String {
    let img = image::RgbImage::from_raw(w, h, texels.concat()).unwrap();
    let mut out = std::io::Cursor::new(Vec::new());
    img.write_to(&mut out, image::ImageFormat::Png).unwrap();
    format!("data:image/png;base64,{}", base64(&out.into_inner()))
}

/// Base64, standard alphabet, padded.
fn base64(bytes: &[u8]) -> String {
    const A: &[u8] = b"ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/";
    let mut s = String::new();
    for c in bytes.chunks(3) {
        let n = (c[0] as u32) << 16
            | (*c.get(1).unwrap_or(&0) as u32) << 8
            | *c.get(2).unwrap_or(&0) as u32;
        for k in 0..4 {
            if k <= c.len() {
                s.push(A[(n >> (18 - 6 * k) & 63) as usize] as char);
            } else {
                s.push('=');
            }
        }
    }
    s
}

/// A `metallicRoughnessTexture` is read per texel, as linear values: blue
/// is the metalness, green the roughness, each times its factor. Here the
/// left texel is a metal of roughness 0.5 × 128/255, the right one a
/// dielectric of roughness 0.5; the base colour texture (sRGB) gives each
/// its colour, and the dielectric's diffuse part reflects that colour.
#[test]
fn metallic_roughness_textures_are_read_per_texel() {
    let d = tmp();
    let mr = png_uri(2, 1, &[[0, 128, 255], [0, 255, 0]]);
    let base = png_uri(2, 1, &[[255, 188, 0], [0, 188, 255]]);
    let mats = r#"[{"pbrMetallicRoughness":{"metallicFactor":1,"roughnessFactor":0.5,
        "baseColorTexture":{"index":1},"metallicRoughnessTexture":{"index":0}}}]"#;
    let rest = format!(
        r#","textures":[{{"source":0}},{{"source":1}}],"images":[{{"uri":"{mr}"}},{{"uri":"{base}"}}]"#
    );
    let s = load(&square(d.path(), "mr", 1.0, mats, &rest));
    assert!(
        !s.warnings.iter().any(|w| w.contains("ignored")),
        "{:?}",
        s.warnings
    );
    let m = &s.materials[0];
    let srgb = |b: f32| ((b / 255.0 + 0.055) / 1.055).powf(2.4);
    // texel centres: bilinear lookups there give the texels themselves
    let (left, right) = (Vec2::new(0.25, 0.5), Vec2::new(0.75, 0.5));
    match m.bsdf(left) {
        Bsdf::RoughConductor { dist, s: tint, .. } => {
            let r = 0.5 * 128.0 / 255.0;
            assert!((dist.alpha - r * r).abs() < 1e-5, "α {}", dist.alpha);
            let want = Rgb::new(1.0, srgb(188.0), 0.0);
            assert!((tint - want).abs().max_element() < 1e-5, "{tint}");
        }
        b => panic!("the left texel is a metal: {b:?}"),
    }
    match m.bsdf(right) {
        b @ Bsdf::RoughPlastic { dist, eta, .. } => {
            assert!((dist.alpha - 0.25).abs() < 1e-5, "α {}", dist.alpha);
            assert_eq!(eta, 1.5);
            let rd = b.diffuse_part().expect("a diffuse part").rd();
            let want = Rgb::new(0.0, srgb(188.0), 1.0);
            assert!((rd - want).abs().max_element() < 1e-3, "R_d {rd}");
        }
        b => panic!("the right texel is a dielectric: {b:?}"),
    }
    // without a base colour texture, the base colour factor is a one-texel
    // bitmap: the diffuse part varies over the surface all the same
    let flat = r#"[{"pbrMetallicRoughness":{"baseColorFactor":[0.5,0.25,0.125,1],
        "metallicRoughnessTexture":{"index":0}}}]"#;
    let rest = format!(r#","textures":[{{"source":0}}],"images":[{{"uri":"{mr}"}}]"#);
    let s = load(&square(d.path(), "flat", 1.0, flat, &rest));
    match s.materials[0].diffuse_texture() {
        Some(t @ Texture::Bitmap { .. }) => {
            assert_eq!(t.eval(right), Rgb::new(0.5, 0.25, 0.125));
        }
        t => panic!("{t:?}"),
    }
    assert!(matches!(
        s.materials[0].bsdf(left),
        Bsdf::RoughConductor { .. }
    ));
    // the same file with the factors alone (no texture) is one metal
    let plain = r#"[{"pbrMetallicRoughness":{"metallicFactor":1,"roughnessFactor":0.5}}]"#;
    let s = load(&square(d.path(), "plain", 1.0, plain, ""));
    assert!(matches!(
        s.materials[0].bsdf(right),
        Bsdf::RoughConductor { .. }
    ));
}

/// An emissive texture (sRGB) multiplies `emissiveFactor` × strength; kalos's
/// area lights being uniform, the product is averaged over the primitive,
/// with a warning. One texel of sRGB 188 on a factor (2, 1, 0.5) and a
/// strength of 3 gives 3 × (2, 1, 0.5) × 0.502.
#[test]
fn emissive_textures_multiply_the_emission() {
    let d = tmp();
    let tex = png_uri(1, 1, &[[188, 188, 188]]);
    let mats = r#"[{"emissiveFactor":[1,0.5,0.25],"emissiveTexture":{"index":0},
        "extensions":{"KHR_materials_emissive_strength":{"emissiveStrength":6}}}]"#;
    let rest = format!(r#","textures":[{{"source":0}}],"images":[{{"uri":"{tex}"}}]"#);
    let s = load(&square(d.path(), "glow", 1.0, mats, &rest));
    let e = s
        .emitters
        .iter()
        .find_map(|e| match e {
            scene::EmitterDesc::Area { radiance, .. } => Some(*radiance),
            _ => None,
        })
        .expect("an area light");
    let t = ((188.0f32 / 255.0 + 0.055) / 1.055).powf(2.4);
    let want = Rgb::new(6.0, 3.0, 1.5) * t;
    assert!((e - want).abs().max_element() < 1e-4, "{e} against {want}");
    assert!(
        s.warnings.iter().any(|w| w.contains("averaged")),
        "{:?}",
        s.warnings
    );
    // half black, half white: the mean over the square lies between
    let tex = png_uri(2, 1, &[[255, 255, 255], [0, 0, 0]]);
    let mats = r#"[{"emissiveFactor":[1,1,1],"emissiveTexture":{"index":0}}]"#;
    let rest = format!(r#","textures":[{{"source":0}}],"images":[{{"uri":"{tex}"}}]"#);
    let s = load(&square(d.path(), "half", 1.0, mats, &rest));
    let e = s
        .emitters
        .iter()
        .find_map(|e| match e {
            scene::EmitterDesc::Area { radiance, .. } => Some(*radiance),
            _ => None,
        })
        .expect("an area light");
    assert!((e.x - 0.5).abs() < 0.1 && e.x == e.y && e.y == e.z, "{e}");
}

/// `KHR_texture_transform` maps the uvs before the lookup: scale, rotation
/// (counter-clockwise in glTF's uv space) and offset, as the extension's
/// `translation * rotation * scale`. The extension's own example (offset
/// (0, 1), a quarter turn, scale ½) shows the lower-left quadrant of the
/// image, rotated: the square's uv (½, ½) lands on the centre of the
/// bottom-left texel of a 2 × 2 image and (½, 3/2) on the bottom-right
/// one; an offset of (½, 0) moves the top-left texel's centre to the
/// top-right one's.
#[test]
fn texture_transforms_map_the_uvs() {
    let d = tmp();
    let (red, green, blue, white) = (
        Rgb::new(1.0, 0.0, 0.0),
        Rgb::new(0.0, 1.0, 0.0),
        Rgb::new(0.0, 0.0, 1.0),
        Rgb::ONE,
    );
    let tex = png_uri(
        2,
        2,
        &[[255, 0, 0], [0, 255, 0], [0, 0, 255], [255, 255, 255]],
    );
    let with = |name: &str, transform: &str| {
        let mats = format!(
            r#"[{{"pbrMetallicRoughness":{{"metallicFactor":1,"roughnessFactor":0.5,
                "baseColorTexture":{{"index":0{transform}}}}}}}]"#
        );
        let rest = format!(
            r#","extensionsUsed":["KHR_texture_transform"],
            "textures":[{{"source":0}}],"images":[{{"uri":"{tex}"}}]"#
        );
        let s = load(&square(d.path(), name, 1.0, &mats, &rest));
        s.materials[0].base_texture().clone()
    };
    let at = |t: &Texture, u: f32, v: f32, want: Rgb| {
        let c = t.eval(Vec2::new(u, v));
        assert!(
            (c - want).abs().max_element() < 1e-3,
            "uv ({u}, {v}): {c}, expected {want}"
        );
    };
    let plain = with("plain", "");
    at(&plain, 0.25, 0.25, red);
    at(&plain, 0.75, 0.25, green);
    at(&plain, 0.25, 0.75, blue);
    let example = with(
        "example",
        r#","extensions":{"KHR_texture_transform":
            {"offset":[0,1],"rotation":1.57079632679,"scale":[0.5,0.5]}}"#,
    );
    at(&example, 0.5, 0.5, blue);
    at(&example, 0.5, 1.5, white);
    let offset = with(
        "offset",
        r#","extensions":{"KHR_texture_transform":{"offset":[0.5,0]}}"#,
    );
    at(&offset, 0.25, 0.25, green);
    at(&offset, 0.25, 0.75, white);
}

/// `KHR_materials_specular`: a factor of 0 leaves a plain Lambertian base
/// (the specification's F0 = F90 = 0), a factor w between weights the
/// coat's lobe by w (a black base reflects w times what it does at w = 1)
/// and lets the base keep what the lobe does not take (a white base still
/// reflects 1: the furnace). Extensions kalos does not read are named in a
/// warning.
#[test]
fn the_specular_extension_weights_the_coat_and_unread_extensions_are_named() {
    let d = tmp();
    let spec = |base: f32, w: f32| {
        format!(
            r#"{{"pbrMetallicRoughness":{{"baseColorFactor":[{base},{base},{base},1],
                "metallicFactor":0,"roughnessFactor":0.6}},
                "extensions":{{"KHR_materials_specular":{{"specularFactor":{w}}}}}}}"#
        )
    };
    let mats = format!(
        "[{},{},{},{}]",
        spec(0.6, 0.0),
        spec(0.0, 0.5),
        spec(1.0, 0.5),
        spec(0.0, 1.0)
    );
    let rest = r#","extensionsUsed":["KHR_materials_specular","KHR_materials_clearcoat"]"#;
    let s = load(&square(d.path(), "specular", 1.0, &mats, rest));
    assert!(
        matches!(&s.materials[0], Material::Diffuse { reflectance: Texture::Constant(c) }
            if *c == Rgb::splat(0.6)),
        "{:?}",
        s.materials[0]
    );
    let uv = Vec2::splat(0.5);
    const N: usize = 200_000;
    let (n0, se0) = albedo(&s.materials[1].bsdf(uv), at_cos(1.0), N, 7);
    let (n1, se1) = albedo(&s.materials[3].bsdf(uv), at_cos(1.0), N, 8);
    eprintln!("black at normal incidence: w = 0.5: {n0:.4} ± {se0:.4}, w = 1: {n1:.4} ± {se1:.4}");
    assert!(
        (n0 - 0.5 * n1).abs() < 5.0 * (se0 + 0.5 * se1),
        "{n0} against half of {n1}"
    );
    for (j, c) in [1.0f32, 0.5, 0.15].into_iter().enumerate() {
        let (a, se) = albedo(&s.materials[2].bsdf(uv), at_cos(c), N, 20 + j as u64);
        eprintln!("white, w = 0.5, cos θo {c}: {a:.4} ± {se:.4}");
        assert!((a - 1.0).abs() < 5.0 * se + 2e-3, "cos {c}: {a}");
    }
    let named: Vec<_> = s
        .warnings
        .iter()
        .filter(|w| w.contains("KHR_materials_clearcoat"))
        .collect();
    assert_eq!(named.len(), 1, "{:?}", s.warnings);
    assert!(
        !s.warnings
            .iter()
            .any(|w| w.contains("KHR_materials_specular")),
        "{:?}",
        s.warnings
    );
}
