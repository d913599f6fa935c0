//! The lightmapped .glb (`kalos::bake::lightmap::glb`) read back: a glTF
//! input keeps its nodes, meshes, materials, images and triangles and gains
//! TEXCOORD_1 and `MOZ_lightmap`; other inputs become a .glb of their
//! shapes. The uv set and the atlas here are stand-ins built from the
//! scene (one chart per triangle on a grid, and an irradiance that varies
//! per texel), so that the writer is tested apart from the unwrapper and
//! the estimator.
//!
//! With `KALOS_LIGHTMAP_GLB_DIR` set, the .glb files are also left in that
//! folder (`lightmap-cbox.glb`, `lightmap-eevee.glb`, and the cube of the browser
//! test, `cube.gltf` and `cube.glb`), for the Khronos glTF-Validator and
//! the browser test in CI.

use std::path::{Path, PathBuf};

use glam::{Vec2, Vec3};
use kalos::bake::lightmap::glb::{encode_lightmapped, write_lightmapped, MOZ_LIGHTMAP};
use kalos::bake::lightmap::{Lightmap, LightmapUv, ShapeUv, UvSource};
use kalos::scene::Scene;

/// The glTF Cornell box shipped in `scenes/`.
fn eevee_path() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("scenes/cornell-box-gltf/cornellBox-2.80-Eevee-gltf.gltf")
}

/// A stand-in uv set: every triangle its own chart, a right triangle in
/// a cell of a square grid with a one-texel margin, on an atlas of
/// `size`² texels.
fn grid_uv(scene: &Scene, size: u32) -> LightmapUv {
    let n = scene.triangles.len();
    let cols = (n as f32).sqrt().ceil() as usize;
    let cell = 1.0 / cols as f32;
    let margin = 1.0 / size as f32;
    let mut shapes = Vec::new();
    for s in &scene.shapes {
        let mut su = ShapeUv::default();
        for k in 0..s.tri_count {
            let t = (s.first_tri + k) as usize;
            let (cx, cy) = ((t % cols) as f32 * cell, (t / cols) as f32 * cell);
            let a = cell - 2.0 * margin;
            let base = su.xref.len() as u32;
            su.xref.extend(scene.triangles[t]);
            su.uv.extend([
                Vec2::new(cx + margin, cy + margin),
                Vec2::new(cx + margin + a, cy + margin),
                Vec2::new(cx + margin, cy + margin + a),
            ]);
            su.triangles.push([base, base + 1, base + 2]);
        }
        shapes.push(su);
    }
    LightmapUv {
        width: size,
        height: size,
        shapes,
        charts: n as u32,
        source: UvSource::Generated,
        tri_chart: (0..n as u32).collect(),
        warnings: Vec::new(),
    }
}

/// A stand-in atlas: irradiance varying across texels, up to 20 (above the
/// PNG's range where the 99.9th percentile clips), a standard error 5 %.
fn ramp_lightmap(size: u32) -> Lightmap {
    let n = (size * size) as usize;
    let irradiance: Vec<Vec3> = (0..n)
        .map(|i| {
            let (x, y) = ((i as u32 % size) as f32, (i as u32 / size) as f32);
            Vec3::new(x / size as f32 * 20.0, y / size as f32 * 5.0, 1.0)
        })
        .collect();
    Lightmap {
        width: size,
        height: size,
        std_error: irradiance.iter().map(|e| *e * 0.05).collect(),
        irradiance,
        covered: vec![true; n],
    }
}

/// The JSON chunk of a .glb.
fn json_of(glb: &[u8]) -> serde_json::Value {
    assert_eq!(&glb[..4], b"glTF");
    let len = u32::from_le_bytes(glb[12..16].try_into().unwrap()) as usize;
    serde_json::from_slice(&glb[20..20 + len]).unwrap()
}

/// Writes `glb` to the CI folder when `KALOS_LIGHTMAP_GLB_DIR` is set.
fn keep_for_validator(name: &str, glb: &[u8]) {
    if let Some(dir) = std::env::var_os("KALOS_LIGHTMAP_GLB_DIR") {
        std::fs::write(Path::new(&dir).join(name), glb).unwrap();
    }
}

/// Each triangle's corners in the scene read back from a .glb match the
/// original scene's, in order, and its TEXCOORD_1 is the uv set's. Shapes
/// are matched by name (a shape of a .glb written from another format is
/// named after it, with the primitive's `.0`), since the loader's walk of
/// the nodes need not follow the scene's order.
fn assert_same_triangles(orig: &Scene, back: &Scene, uv: &LightmapUv) {
    assert_eq!(back.triangles.len(), orig.triangles.len());
    assert_eq!(back.shapes.len(), orig.shapes.len());
    assert_eq!(back.uv1.len(), back.positions.len(), "TEXCOORD_1 read back");
    for (i, (s, su)) in orig.shapes.iter().zip(&uv.shapes).enumerate() {
        let b = back
            .shapes
            .iter()
            .position(|b| b.name == s.name || b.name == format!("{}.0", s.name))
            .unwrap_or_else(|| panic!("shape `{}` is not in the .glb", s.name));
        let bs = &back.shapes[b];
        assert_eq!(bs.tri_count, s.tri_count, "shape `{}`", s.name);
        for (j, t) in su.triangles.iter().enumerate() {
            let ot = orig.triangles[s.first_tri as usize + j];
            let bt = back.triangles[bs.first_tri as usize + j];
            for c in 0..3 {
                let (po, pb) = (
                    orig.positions[ot[c] as usize],
                    back.positions[bt[c] as usize],
                );
                assert!(
                    (po - pb).length() < 1e-5,
                    "shape {i} triangle {j} corner {c}: {po} became {pb}"
                );
                // the uv set's corner holding the same scene vertex
                let want = t
                    .iter()
                    .find(|&&v| su.xref[v as usize] == ot[c])
                    .map(|&v| su.uv[v as usize])
                    .unwrap();
                let got = back.uv1[bt[c] as usize];
                assert!(
                    (want - got).length() < 1e-6,
                    "shape {i} triangle {j} corner {c}: uv1 {want} became {got}"
                );
            }
        }
    }
}

#[test]
fn gltf_input_is_kept_whole_with_uv1_and_the_lightmap() {
    let path = eevee_path();
    let scene = kalos::scene::load(&path).unwrap();
    let uv = grid_uv(&scene, 256);
    let lm = ramp_lightmap(256);
    let (glb, info) = encode_lightmapped(&scene, Some(&path), &uv, &lm).unwrap();
    keep_for_validator("lightmap-eevee.glb", &glb);
    let orig: serde_json::Value = serde_json::from_slice(&std::fs::read(&path).unwrap()).unwrap();
    let out = json_of(&glb);
    // the structure of the asset is kept
    for key in ["nodes", "meshes", "materials", "cameras", "scenes"] {
        let n = |v: &serde_json::Value| v[key].as_array().map_or(0, Vec::len);
        assert_eq!(n(&out), n(&orig), "{key}");
    }
    for (a, b) in orig["nodes"]
        .as_array()
        .unwrap()
        .iter()
        .zip(out["nodes"].as_array().unwrap())
    {
        assert_eq!(a, b, "nodes unchanged (no mesh is instanced twice here)");
    }
    // the input's own images are embedded, plus the lightmap's
    let images = out["images"].as_array().unwrap();
    let n_orig = orig["images"].as_array().map_or(0, Vec::len);
    assert_eq!(
        images.len(),
        n_orig + 2,
        "input images + atlas + standard error"
    );
    assert!(images
        .iter()
        .all(|i| i.get("uri").is_none() && i["bufferView"].is_u64()));
    assert_eq!(out["buffers"].as_array().unwrap().len(), 1);
    // every material of a diffuse surface references the lightmap
    let lit = out["materials"]
        .as_array()
        .unwrap()
        .iter()
        .filter(|m| m["extensions"][MOZ_LIGHTMAP].is_object())
        .count();
    assert_eq!(lit, info.lightmapped_materials);
    assert!(lit > 0);
    let ext = &out["materials"]
        .as_array()
        .unwrap()
        .iter()
        .find(|m| m["extensions"][MOZ_LIGHTMAP].is_object())
        .unwrap()["extensions"][MOZ_LIGHTMAP];
    assert_eq!(ext["texCoord"], 1);
    assert!((ext["intensity"].as_f64().unwrap() - info.intensity as f64).abs() < 1e-3);
    // the 99.9th percentile of the ramp's red channel: just under 20
    assert!(
        info.intensity > 19.0 && info.intensity <= 20.0,
        "{}",
        info.intensity
    );

    // read back through kalos's own glTF loader: the same triangles
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("out.glb");
    std::fs::write(&p, &glb).unwrap();
    let back = kalos::scene::load(&p).unwrap();
    assert_same_triangles(&scene, &back, &uv);
    assert_eq!(back.materials.len(), scene.materials.len());
}

#[test]
fn a_mesh_shared_by_two_nodes_is_duplicated() {
    // the Eevee box with one more node instancing mesh 0, moved
    let path = eevee_path();
    let dir = tempfile::tempdir().unwrap();
    let mut j: serde_json::Value = serde_json::from_slice(&std::fs::read(&path).unwrap()).unwrap();
    let mesh0 = j["nodes"]
        .as_array()
        .unwrap()
        .iter()
        .position(|n| n["mesh"] == 0)
        .unwrap();
    let nodes = j["nodes"].as_array_mut().unwrap();
    nodes.push(serde_json::json!({ "mesh": 0, "translation": [0.0, 5.0, 0.0], "name": "copy" }));
    let new = nodes.len() - 1;
    j["scenes"][0]["nodes"]
        .as_array_mut()
        .unwrap()
        .push(new.into());
    let bin = path.with_extension("bin");
    std::fs::copy(&bin, dir.path().join(bin.file_name().unwrap())).unwrap();
    for img in j["images"].as_array().unwrap() {
        let name = img["uri"].as_str().unwrap();
        std::fs::copy(path.with_file_name(name), dir.path().join(name)).unwrap();
    }
    let src = dir.path().join("twice.gltf");
    std::fs::write(&src, serde_json::to_vec(&j).unwrap()).unwrap();
    let scene = kalos::scene::load(&src).unwrap();
    let uv = grid_uv(&scene, 128);
    let lm = ramp_lightmap(128);
    let out_path = dir.path().join("twice.glb");
    let info = write_lightmapped(&out_path, &scene, Some(&src), &uv, &lm).unwrap();
    assert!(info.exr.exists(), "the float atlas next to the .glb");
    let out = json_of(&std::fs::read(&out_path).unwrap());
    let meshes = out["meshes"].as_array().unwrap().len();
    assert_eq!(meshes, j["meshes"].as_array().unwrap().len() + 1);
    assert_ne!(out["nodes"][mesh0]["mesh"], out["nodes"][new]["mesh"]);
    let back = kalos::scene::load(&out_path).unwrap();
    assert_same_triangles(&scene, &back, &uv);
    let _ = mesh0;
}

#[test]
fn other_inputs_become_a_glb_of_their_shapes() {
    let scene = kalos::scene::builtin::cornell_box().unwrap();
    let uv = grid_uv(&scene, 128);
    let lm = ramp_lightmap(128);
    let (glb, info) = encode_lightmapped(&scene, None, &uv, &lm).unwrap();
    keep_for_validator("lightmap-cbox.glb", &glb);
    let out = json_of(&glb);
    assert!(info.lightmapped_materials > 0);
    assert_eq!(out["cameras"].as_array().unwrap().len(), 1);
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("cbox.glb");
    std::fs::write(&p, &glb).unwrap();
    let back = kalos::scene::load(&p).unwrap();
    assert_same_triangles(&scene, &back, &uv);
}

#[test]
fn a_uv_set_of_another_scene_is_refused() {
    let scene = kalos::scene::builtin::cornell_box().unwrap();
    let mut uv = grid_uv(&scene, 64);
    uv.shapes.pop();
    let lm = ramp_lightmap(64);
    let e = encode_lightmapped(&scene, None, &uv, &lm).unwrap_err();
    assert!(e.to_string().contains("shapes"), "{e}");
}

/// A textured cube (checkerBJS.png on every face, TEXCOORD_0 over each
/// face) with a camera seeing three of its faces, as a .gltf with its .bin
/// and image in `dir`. It has no emitter, so kalos lights it with a
/// constant white sky of radiance 1; being convex, each face sees the
/// whole sky: its irradiance is π everywhere, and it shows its albedo. Its
/// material has no specular layer (`KHR_materials_specular`), so that what
/// it shows is its albedo alone.
fn write_cube(dir: &Path) -> PathBuf {
    use glam::{Mat3, Quat};
    let mut pos: Vec<[f32; 3]> = Vec::new();
    let mut nrm: Vec<[f32; 3]> = Vec::new();
    let mut uv0: Vec<[f32; 2]> = Vec::new();
    let mut idx: Vec<u16> = Vec::new();
    for axis in 0..3 {
        for sign in [-1.0f32, 1.0] {
            let mut n = Vec3::ZERO;
            n[axis] = sign;
            // two tangents with u × v = n
            let (u, v) = {
                let a = Vec3::new(n.y.abs(), n.z.abs(), n.x.abs());
                let t = n.cross(a).normalize();
                (t, n.cross(t))
            };
            let base = pos.len() as u16;
            for (su, sv) in [(-1.0, -1.0), (1.0, -1.0), (1.0, 1.0), (-1.0, 1.0)] {
                pos.push((n + u * su + v * sv).to_array());
                nrm.push(n.to_array());
                uv0.push([(su + 1.0) * 0.5, (1.0 - sv) * 0.5]);
            }
            idx.extend([base, base + 1, base + 2, base, base + 2, base + 3]);
        }
    }
    let mut bin: Vec<u8> = Vec::new();
    let f = |v: &[f32]| v.iter().flat_map(|x| x.to_le_bytes()).collect::<Vec<u8>>();
    let views = [
        f(&pos.concat()),
        f(&nrm.concat()),
        f(&uv0.concat()),
        idx.iter().flat_map(|i| i.to_le_bytes()).collect(),
    ];
    let mut json_views = Vec::new();
    for v in &views {
        json_views.push(
            serde_json::json!({ "buffer": 0, "byteOffset": bin.len(), "byteLength": v.len() }),
        );
        bin.extend_from_slice(v);
    }
    std::fs::write(dir.join("cube.bin"), &bin).unwrap();
    std::fs::copy(
        eevee_path().with_file_name("checkerBJS.png"),
        dir.join("checker.png"),
    )
    .unwrap();
    let eye = Vec3::new(3.2, 2.6, 4.0);
    // glTF cameras look along their −z, with +y up
    let z = eye.normalize();
    let x = Vec3::Y.cross(z).normalize();
    let rot = Quat::from_mat3(&Mat3::from_cols(x, z.cross(x), z)).normalize();
    let j = serde_json::json!({
        "asset": { "version": "2.0" },
        "scene": 0,
        "scenes": [{ "nodes": [0, 1] }],
        "nodes": [
            { "mesh": 0, "name": "cube" },
            { "camera": 0, "name": "camera", "translation": eye.to_array(), "rotation": rot.to_array() },
        ],
        "cameras": [{ "type": "perspective",
                      "perspective": { "yfov": 0.7, "aspectRatio": 1.0, "znear": 0.05 } }],
        "meshes": [{ "primitives": [{
            "attributes": { "POSITION": 0, "NORMAL": 1, "TEXCOORD_0": 2 },
            "indices": 3, "material": 0 }] }],
        // no specular layer (KHR_materials_specular's factor 0): the cube
        // is Lambertian in kalos and in three.js alike, so that the
        // viewer, which has no sky to reflect, can match kalos's render
        "extensionsUsed": ["KHR_materials_specular"],
        "materials": [{ "name": "checker", "pbrMetallicRoughness": {
            "baseColorTexture": { "index": 0 }, "metallicFactor": 0.0, "roughnessFactor": 1.0 },
            "extensions": { "KHR_materials_specular": { "specularFactor": 0.0 } } }],
        "textures": [{ "source": 0 }],
        "images": [{ "uri": "checker.png" }],
        "accessors": [
            { "bufferView": 0, "componentType": 5126, "count": 24, "type": "VEC3",
              "min": [-1.0, -1.0, -1.0], "max": [1.0, 1.0, 1.0] },
            { "bufferView": 1, "componentType": 5126, "count": 24, "type": "VEC3" },
            { "bufferView": 2, "componentType": 5126, "count": 24, "type": "VEC2" },
            { "bufferView": 3, "componentType": 5123, "count": 36, "type": "SCALAR" },
        ],
        "bufferViews": json_views,
        "buffers": [{ "uri": "cube.bin", "byteLength": bin.len() }],
    });
    let p = dir.join("cube.gltf");
    std::fs::write(&p, serde_json::to_vec_pretty(&j).unwrap()).unwrap();
    p
}

/// The irradiance of the cube under the white sky: π on the texels the
/// uv set's triangles cover (centre inside, then grown by one texel so
/// that bilinear filtering at a chart's edge reads no black), 0 elsewhere,
/// so that a wrong TEXCOORD_1 or a flipped atlas shows black. Standard
/// error: 2 %.
fn sky_lightmap(uv: &LightmapUv) -> Lightmap {
    let (w, h) = (uv.width as usize, uv.height as usize);
    let mut inside = vec![false; w * h];
    for su in &uv.shapes {
        for t in &su.triangles {
            let [a, b, c] = t.map(|i| su.uv[i as usize] * Vec2::new(w as f32, h as f32));
            let cross = |p: Vec2, q: Vec2, r: Vec2| (q - p).perp_dot(r - p);
            let area = cross(a, b, c);
            for (i, cell) in inside.iter_mut().enumerate() {
                let p = Vec2::new((i % w) as f32 + 0.5, (i / w) as f32 + 0.5);
                let (u, v, s) = (cross(b, c, p), cross(c, a, p), cross(a, b, p));
                if [u, v, s].iter().all(|x| x * area.signum() >= 0.0) {
                    *cell = true;
                }
            }
        }
    }
    let covered = inside.clone();
    let mut grown = inside.clone();
    for y in 0..h {
        for x in 0..w {
            if inside[y * w + x] {
                for (dx, dy) in [
                    (-1i64, 0i64),
                    (1, 0),
                    (0, -1),
                    (0, 1),
                    (-1, -1),
                    (1, 1),
                    (-1, 1),
                    (1, -1),
                ] {
                    let (xx, yy) = (x as i64 + dx, y as i64 + dy);
                    if xx >= 0 && yy >= 0 && (xx as usize) < w && (yy as usize) < h {
                        grown[yy as usize * w + xx as usize] = true;
                    }
                }
            }
        }
    }
    let pi = Vec3::splat(std::f32::consts::PI);
    let irradiance: Vec<Vec3> = grown
        .iter()
        .map(|&g| if g { pi } else { Vec3::ZERO })
        .collect();
    Lightmap {
        width: uv.width,
        height: uv.height,
        std_error: irradiance.iter().map(|e| *e * 0.02).collect(),
        irradiance,
        covered,
    }
}

#[test]
fn the_cube_under_the_sky_has_a_lightmap_of_pi() {
    let dir = tempfile::tempdir().unwrap();
    let keep = std::env::var_os("KALOS_LIGHTMAP_GLB_DIR").map(PathBuf::from);
    let out = keep.as_deref().unwrap_or(dir.path());
    let src = write_cube(out);
    let scene = kalos::scene::load(&src).unwrap();
    assert_eq!(scene.triangles.len(), 12);
    let uv = grid_uv(&scene, 64);
    let lm = sky_lightmap(&uv);
    let glb = out.join("cube.glb");
    let info = write_lightmapped(&glb, &scene, Some(&src), &uv, &lm).unwrap();
    // every covered texel is π: the intensity is π, the PNG holds 255
    assert!((info.intensity - std::f32::consts::PI).abs() < 1e-6);
    let back = kalos::scene::load(&glb).unwrap();
    assert_same_triangles(&scene, &back, &uv);
}
