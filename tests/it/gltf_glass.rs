//! Glass as glTF exporters write it: `KHR_materials_ior` on the ordinary
//! dielectric (its coat's index), and `KHR_materials_transmission` (with
//! `KHR_materials_volume`) as kalos's `dielectric` or `thindielectric`.
//! Each extension has a small file written by hand here (one square, its
//! materials given as JSON), and the Blender export of the interior with a
//! glass vase (`scenes/interior/interior-lamp-glass.glb`) is read and
//! rendered by each method that takes it.
//!
//! Tolerances: Monte Carlo albedos are compared with 5 standard errors
//! (their spread measured from the same samples).

use std::path::{Path, PathBuf};

use glam::{Vec2, Vec3};
use kalos::bsdf::{Bsdf, Mode};
use kalos::sampling::Pcg32;
use kalos::scene::{self, Material, Rgb, Scene, Texture};

fn tmp() -> tempfile::TempDir {
    tempfile::Builder::new()
        .prefix("kalos-gltf-glass-")
        .tempdir()
        .unwrap()
}

/// Writes `name` in `dir`: a glTF file with one square of half-side 1 in
/// the y = 0 plane, facing +y, drawn with material 0. `materials` is the
/// JSON array of materials.
fn square(dir: &Path, name: &str, materials: &str) -> PathBuf {
    let mut bin = Vec::new();
    let corners = [[-1.0f32, -1.0], [-1.0, 1.0], [1.0, 1.0], [1.0, -1.0]];
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
    for i in [0u16, 1, 2, 0, 2, 3] {
        bin.extend(i.to_le_bytes());
    }
    std::fs::write(dir.join(format!("{name}.bin")), &bin).unwrap();
    let json = format!(
        r#"{{"asset":{{"version":"2.0"}},"scene":0,"scenes":[{{"nodes":[0]}}],
"extensionsUsed":["KHR_materials_ior","KHR_materials_transmission","KHR_materials_volume"],
"nodes":[{{"mesh":0}}],
"meshes":[{{"primitives":[{{"attributes":{{"POSITION":0,"NORMAL":1}},
  "indices":2,"material":0}}]}}],
"materials":{materials},
"accessors":[{{"bufferView":0,"componentType":5126,"count":4,"type":"VEC3",
               "min":[-1,0,-1],"max":[1,0,1]}},
             {{"bufferView":1,"componentType":5126,"count":4,"type":"VEC3"}},
             {{"bufferView":2,"componentType":5123,"count":6,"type":"SCALAR"}}],
"bufferViews":[{{"buffer":0,"byteOffset":0,"byteLength":48}},
               {{"buffer":0,"byteOffset":48,"byteLength":48}},
               {{"buffer":0,"byteOffset":96,"byteLength":12}}],
"buffers":[{{"byteLength":108,"uri":"{name}.bin"}}]}}"#
    );
    let p = dir.join(format!("{name}.gltf"));
    std::fs::write(&p, json).unwrap();
    p
}

fn load(p: &Path) -> Scene {
    scene::load(p).unwrap_or_else(|e| panic!("{e}"))
}

/// A glTF material: base colour, roughness (metallic 0) and the JSON of
/// its `extensions` object's members (empty for none).
fn mat(base: [f32; 3], roughness: f32, extensions: &str) -> String {
    format!(
        r#"{{"pbrMetallicRoughness":{{"baseColorFactor":[{},{},{},1],
            "metallicFactor":0,"roughnessFactor":{roughness}}},
            "extensions":{{{extensions}}}}}"#,
        base[0], base[1], base[2]
    )
}

/// The directional albedo ∫ f cos θi dωi of `b` seen from `wo` (delta
/// lobes included), split into reflection (wi on wo's side) and
/// transmission, each with its standard error, from `n` samples.
fn albedo(b: &Bsdf, wo: Vec3, n: usize, seed: u64) -> [(f64, f64); 2] {
    let mut rng = Pcg32::new(0x91a5, seed);
    let mut s = [[0.0f64; 2]; 2];
    for _ in 0..n {
        let uc = rng.next_f32();
        let u = rng.next_2d();
        if let Some(x) = b.sample(wo, uc, u, Mode::Radiance) {
            let w = (x.f.y * x.wi.z.abs() / x.pdf) as f64;
            let side = usize::from(x.wi.z * wo.z < 0.0);
            s[side][0] += w;
            s[side][1] += w * w;
        }
    }
    s.map(|[s1, s2]| {
        let mean = s1 / n as f64;
        let var = (s2 / n as f64 - mean * mean).max(0.0);
        (mean, (var / n as f64).sqrt())
    })
}

/// Normal-incidence Fresnel reflectance of index `eta`.
fn f0(eta: f32) -> f32 {
    ((eta - 1.0) / (eta + 1.0)).powi(2)
}

// ---------------------------------------------------------------------------
// KHR_materials_ior

/// `KHR_materials_ior` sets the coat's index of an ordinary dielectric
/// (rough and smooth), the base keeps its diffuse reflectance (the base's
/// gain is computed for that index), a black one reflects F0 = ((η −
/// 1)/(η + 1))² at normal incidence; ior 0 is the extension's F = 1, a
/// white mirror; an ior the extension does not allow is read as 1.5 with a
/// warning.
#[test]
fn ior_sets_the_coat_index_of_a_dielectric() {
    let d = tmp();
    let ior = |x: f32| format!(r#""KHR_materials_ior":{{"ior":{x}}}"#);
    let mats = format!(
        "[{},{},{},{},{},{}]",
        mat([0.8, 0.4, 0.2], 0.5, &ior(2.0)),
        mat([0.8, 0.4, 0.2], 0.0, &ior(2.0)),
        mat([0.0, 0.0, 0.0], 0.0, &ior(2.0)),
        mat([0.8, 0.4, 0.2], 0.0, &ior(0.0)),
        mat([0.8, 0.4, 0.2], 0.0, &ior(0.5)),
        mat([0.0, 0.0, 0.0], 0.3, &ior(1.33)),
    );
    let s = load(&square(d.path(), "ior", &mats));
    let base = Rgb::new(0.8, 0.4, 0.2);
    match &s.materials[0] {
        Material::RoughPlastic { eta, .. } => assert_eq!(*eta, 2.0),
        m => panic!("not a roughplastic: {m:?}"),
    }
    match &s.materials[1] {
        Material::Plastic { eta, .. } => assert_eq!(*eta, 2.0),
        m => panic!("not a plastic: {m:?}"),
    }
    // the diffuse part's reflectance is still the base colour: the gain on
    // the base follows the coat's index
    for m in &s.materials[..2] {
        let rd = m
            .bsdf(Vec2::splat(0.5))
            .diffuse_part()
            .expect("a dielectric keeps a diffuse part")
            .rd();
        assert!(
            (rd / base - Rgb::ONE).abs().max_element() < 2e-3,
            "R_d {rd} against the base colour {base}"
        );
    }
    // a black dielectric reflects its coat's F0 at normal incidence
    for (k, eta) in [(2usize, 2.0f32), (5, 1.33)] {
        let [(r, se), _] = albedo(&s.materials[k].bsdf(Vec2::ZERO), Vec3::Z, 100_000, k as u64);
        assert!(
            (r - f0(eta) as f64).abs() < 0.004 + 5.0 * se,
            "material {k}: reflects {r} ± {se}, F0 {}",
            f0(eta)
        );
    }
    assert!(
        matches!(&s.materials[3], Material::Conductor { eta, k, specular_reflectance: Texture::Constant(c) }
            if *eta == Rgb::ZERO && *k == Rgb::ONE && *c == Rgb::ONE),
        "ior 0: {:?}",
        s.materials[3]
    );
    assert!(
        matches!(&s.materials[4], Material::Plastic { eta, .. } if *eta == 1.5),
        "ior 0.5: {:?}",
        s.materials[4]
    );
    assert!(
        s.warnings
            .iter()
            .any(|w| w.contains("KHR_materials_ior 0.5")),
        "{:?}",
        s.warnings
    );
}
