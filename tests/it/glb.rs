//! The bake's .glb (`kalos::bake::gltf`) read back with the `gltf` crate:
//! the GLB container, the binary chunk's layout, and the mesh, colours,
//! materials and camera the JSON describes. (The Khronos glTF-Validator runs
//! on real bakes in CI: `tests/validator/validate.mjs`.)

use glam::{Mat4, Vec3};
use gltf::mesh::util::ReadIndices;
use gltf::Semantic;
use kalos::bake::gltf::{display_colors, encode_glb};
use kalos::bake::BakedMesh;
use kalos::scene::CameraDesc;

/// Lit surfaces: a quad and a triangle, with radiance that differs per
/// vertex and goes above the white point 2 (so COLOR_0 clamps some
/// channels) and positions with no short binary form (0.1).
fn lit() -> BakedMesh {
    let positions = vec![
        Vec3::new(-1.0, 0.1, 0.0),
        Vec3::new(1.0, 0.1, 0.0),
        Vec3::new(1.0, 2.5, 0.0),
        Vec3::new(-1.0, 2.5, 0.0),
        Vec3::new(0.0, 0.1, -3.0),
    ];
    BakedMesh {
        normals: vec![Vec3::Z, Vec3::Z, Vec3::Z, Vec3::Z, Vec3::Y],
        irradiance: vec![Vec3::ONE; positions.len()],
        radiance: vec![
            Vec3::new(0.5, 0.25, 0.125),
            Vec3::new(3.0, 1.0, 0.0),
            Vec3::new(0.0, 2.0, 4.0),
            Vec3::new(1.0, 1.5, 0.75),
            Vec3::new(10.0, 0.01, 2.0),
        ],
        indices: vec![[0, 1, 2], [0, 2, 3], [0, 4, 1]],
        positions,
    }
}

/// Non-diffuse surfaces: one triangle.
fn other() -> BakedMesh {
    BakedMesh {
        positions: vec![
            Vec3::new(5.0, -1.0, 2.0),
            Vec3::new(6.0, -1.0, 2.0),
            Vec3::new(5.0, 0.5, 2.25),
        ],
        normals: vec![Vec3::X; 3],
        irradiance: vec![],
        radiance: vec![],
        indices: vec![[0, 1, 2]],
    }
}

fn camera() -> CameraDesc {
    CameraDesc {
        to_world: Mat4::from_translation(Vec3::new(0.0, 1.0, 5.0)),
        fov_x_deg: 40.0,
        width: 300,
        height: 200,
        near_clip: 0.0,
    }
}

const W0: f32 = 2.0;

/// The chunks of a .glb, checking its container as the glTF 2.0
/// specification lays it out: (JSON text, BIN chunk or None).
fn chunks(glb: &[u8]) -> (String, Option<Vec<u8>>) {
    let u32_at = |i: usize| u32::from_le_bytes(glb[i..i + 4].try_into().unwrap()) as usize;
    assert_eq!(&glb[0..4], b"glTF", "magic");
    assert_eq!(u32_at(4), 2, "container version");
    assert_eq!(u32_at(8), glb.len(), "the header's length is the file's");
    let json_len = u32_at(12);
    assert_eq!(&glb[16..20], b"JSON", "the first chunk is the JSON");
    assert_eq!(json_len % 4, 0, "JSON chunk aligned to 4 bytes");
    let json = std::str::from_utf8(&glb[20..20 + json_len]).expect("UTF-8 JSON");
    let text = json.trim_end_matches(' ');
    assert!(text.ends_with('}'), "JSON padded with spaces only");
    assert!(json.len() - text.len() < 4, "at most 3 bytes of padding");
    let rest = &glb[20 + json_len..];
    if rest.is_empty() {
        return (text.to_string(), None);
    }
    let bin_len = u32_at(20 + json_len);
    assert_eq!(&rest[4..8], b"BIN\0", "the second chunk is BIN");
    assert_eq!(bin_len % 4, 0, "BIN chunk aligned to 4 bytes");
    assert_eq!(rest.len(), 8 + bin_len, "nothing after the BIN chunk");
    (text.to_string(), Some(rest[8..].to_vec()))
}

fn le_bytes(out: &mut Vec<u8>, v: &[Vec3]) {
    for x in v.iter().flat_map(|v| v.to_array()) {
        out.extend_from_slice(&x.to_le_bytes());
    }
}

fn le_indices(out: &mut Vec<u8>, t: &[[u32; 3]]) {
    for i in t.iter().flatten() {
        out.extend_from_slice(&i.to_le_bytes());
    }
}

/// The BIN chunk holds, in this order and tightly packed: the lit
/// positions, normals, display colours, radiance and indices, then the
/// other surfaces' positions, normals and indices (the layout of the
/// hand-written writer this one replaced, so that bakes keep their bytes).
#[test]
fn the_binary_chunk_keeps_its_layout() {
    let (lit, other) = (lit(), other());
    let glb = encode_glb(&lit, &other, W0, Some(&camera()));
    let (_, bin) = chunks(&glb);
    let mut want = Vec::new();
    le_bytes(&mut want, &lit.positions);
    le_bytes(&mut want, &lit.normals);
    le_bytes(&mut want, &display_colors(&lit, W0));
    le_bytes(&mut want, &lit.radiance);
    le_indices(&mut want, &lit.indices);
    le_bytes(&mut want, &other.positions);
    le_bytes(&mut want, &other.normals);
    le_indices(&mut want, &other.indices);
    assert_eq!(want.len() % 4, 0);
    assert_eq!(bin.expect("a BIN chunk"), want);
}

/// The mesh read back through the `gltf` crate's accessors equals what was
/// written: vertex counts, indices, normals, COLOR_0 (the radiance over the
/// white point, clamped), `_RADIANCE`, the POSITION bounds; and the
/// materials, names, camera and generator.
#[test]
fn the_mesh_reads_back_with_the_gltf_crate() {
    let (lit, other) = (lit(), other());
    let glb = encode_glb(&lit, &other, W0, Some(&camera()));
    let g = gltf::Gltf::from_slice(&glb).expect("a valid .glb");
    let blob = g.blob.as_deref().expect("the BIN chunk");
    let doc = &g.document;
    assert_eq!(doc.buffers().count(), 1);
    assert_eq!(doc.buffers().next().unwrap().length(), blob.len());
    assert_eq!(
        doc.as_json().asset.generator.as_deref(),
        Some("kalos bake (density estimation)")
    );
    assert_eq!(doc.as_json().asset.version, "2.0");
    assert_eq!(
        doc.extensions_used().collect::<Vec<_>>(),
        ["KHR_materials_unlit"]
    );

    // One mesh with the lit and the other primitive
    let mesh = doc.meshes().next().expect("a mesh");
    assert_eq!(doc.meshes().count(), 1);
    assert_eq!(mesh.name(), Some("display mesh"));
    let prims: Vec<_> = mesh.primitives().collect();
    assert_eq!(prims.len(), 2);
    for (prim, m) in prims.iter().zip([&lit, &other]) {
        assert_eq!(prim.mode(), gltf::mesh::Mode::Triangles);
        let r = prim.reader(|b| (b.index() == 0).then_some(blob));
        let pos: Vec<Vec3> = r
            .read_positions()
            .expect("POSITION")
            .map(Vec3::from)
            .collect();
        assert_eq!(pos, m.positions);
        let nor: Vec<Vec3> = r.read_normals().expect("NORMAL").map(Vec3::from).collect();
        assert_eq!(nor, m.normals);
        let Some(ReadIndices::U32(idx)) = r.read_indices() else {
            panic!("u32 indices");
        };
        let idx: Vec<u32> = idx.collect();
        assert_eq!(idx, m.indices.iter().flatten().copied().collect::<Vec<_>>());
        // POSITION's bounds, exactly (written with the fewest digits that
        // read back as the same f32)
        let bounds = prim.get(&Semantic::Positions).unwrap();
        let lo = m.positions.iter().fold(Vec3::INFINITY, |a, b| a.min(*b));
        let hi = m
            .positions
            .iter()
            .fold(Vec3::NEG_INFINITY, |a, b| a.max(*b));
        let read = |v: gltf::json::Value| -> Vec3 {
            let a: Vec<f32> = v
                .as_array()
                .expect("an array")
                .iter()
                .map(|x| x.as_f64().expect("a number") as f32)
                .collect();
            Vec3::from_slice(&a)
        };
        assert_eq!(read(bounds.min().expect("min")), lo);
        assert_eq!(read(bounds.max().expect("max")), hi);
    }

    // The lit primitive: COLOR_0 and _RADIANCE per vertex
    let r = prims[0].reader(|b| (b.index() == 0).then_some(blob));
    let colours: Vec<Vec3> = r
        .read_colors(0)
        .expect("COLOR_0")
        .into_rgb_f32()
        .map(Vec3::from)
        .collect();
    assert_eq!(colours, display_colors(&lit, W0));
    assert_eq!(
        colours[1],
        Vec3::new(1.0, 0.5, 0.0),
        "clamped at the white point"
    );
    let radiance = prims[0]
        .get(&Semantic::Extras("RADIANCE".into()))
        .expect("_RADIANCE");
    assert_eq!(radiance.count(), lit.positions.len());
    let view = radiance.view().expect("a buffer view");
    let bytes = &blob[view.offset()..view.offset() + view.length()];
    let mut want = Vec::new();
    le_bytes(&mut want, &lit.radiance);
    assert_eq!(bytes, want.as_slice());
    assert_eq!(prims[1].attributes().count(), 2, "POSITION and NORMAL only");

    // Materials: the unlit baked one, the plain PBR one
    let mats: Vec<_> = doc.materials().collect();
    assert_eq!(mats.len(), 2);
    assert_eq!(prims[0].material().index(), Some(0));
    assert_eq!(prims[1].material().index(), Some(1));
    assert_eq!(mats[0].name(), Some("baked lighting"));
    assert_eq!(mats[1].name(), Some("not baked (specular)"));
    let ext = doc.as_json().materials[0].extensions.as_ref();
    assert!(
        ext.and_then(|e| e.unlit.as_ref()).is_some(),
        "KHR_materials_unlit"
    );
    assert!(doc.as_json().materials[1].extensions.is_none());
    let pbr = mats[1].pbr_metallic_roughness();
    assert_eq!(pbr.base_color_factor(), [0.8, 0.8, 0.8, 1.0]);
    assert_eq!((pbr.metallic_factor(), pbr.roughness_factor()), (1.0, 0.1));

    // The nodes: the mesh, then the camera with its film size in extras
    let scene = doc.default_scene().expect("a default scene");
    let nodes: Vec<_> = scene.nodes().collect();
    assert_eq!(nodes.len(), 2);
    assert_eq!(nodes[0].name(), Some("baked"));
    assert_eq!(nodes[0].mesh().map(|m| m.index()), Some(0));
    assert_eq!(nodes[1].name(), Some("scene camera"));
    let cam = nodes[1].camera().expect("the camera node");
    let gltf::camera::Projection::Perspective(p) = cam.projection() else {
        panic!("a perspective camera");
    };
    assert_eq!(p.aspect_ratio(), Some(1.5));
    assert_eq!(p.znear(), 1e-4, "znear 0 raised to glTF's > 0");
    let extras: gltf::json::Value =
        serde_json_value(cam.extras().as_ref().expect("camera extras").get());
    assert_eq!(extras["width"], 300);
    assert_eq!(extras["height"], 200);
}

/// Parses a JSON text with the `gltf` crate's serde_json.
fn serde_json_value(text: &str) -> gltf::json::Value {
    gltf::json::deserialize::from_str(text).expect("JSON")
}

/// Only what a bake has is written: no material, primitive or extension for
/// a missing half, and an empty bake without a camera is a bare asset (no
/// empty mesh, buffer or scene, which glTF forbids) that still loads.
#[test]
fn missing_parts_leave_no_unused_objects() {
    let empty = BakedMesh::default();

    let only_other = encode_glb(&empty, &other(), W0, None);
    let g = gltf::Gltf::from_slice(&only_other).expect("loads");
    assert_eq!(g.materials().count(), 1);
    assert_eq!(g.extensions_used().count(), 0);
    let mesh = g.meshes().next().expect("a mesh");
    assert_eq!(mesh.primitives().count(), 1);
    assert_eq!(
        mesh.primitives().next().unwrap().material().index(),
        Some(0)
    );
    assert_eq!(g.cameras().count(), 0);

    let only_lit = encode_glb(&lit(), &empty, W0, None);
    let g = gltf::Gltf::from_slice(&only_lit).expect("loads");
    assert_eq!(g.materials().count(), 1);
    assert_eq!(g.materials().next().unwrap().name(), Some("baked lighting"));

    let bare = encode_glb(&empty, &empty, W0, None);
    let (json, bin) = chunks(&bare);
    assert!(bin.is_none(), "no BIN chunk for no data");
    let g = gltf::Gltf::from_slice(&bare).expect("loads");
    assert_eq!(
        (g.meshes().count(), g.buffers().count(), g.scenes().count()),
        (0, 0, 0),
        "{json}"
    );

    let camera_only = encode_glb(&empty, &empty, W0, Some(&camera()));
    let g = gltf::Gltf::from_slice(&camera_only).expect("loads");
    let scene = g.default_scene().expect("a scene for the camera node");
    assert_eq!(scene.nodes().count(), 1);
    assert!(scene.nodes().next().unwrap().camera().is_some());
}
