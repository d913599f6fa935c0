//! Scene files whose few bytes describe something huge or endless: glTF node
//! cycles and multiplying instances, lying header lengths, include fan-out.
//! Each must end in a clear error naming the file, never an abort or a hang.
//! The inputs are small equivalents of the reproducers of issue 18, built
//! here in a temporary folder.

use crate::common::kalos;
use std::path::{Path, PathBuf};

use kalos::scene::{self, EmitterDesc};

/// A fresh temporary folder, removed when dropped.
fn tmp() -> tempfile::TempDir {
    tempfile::Builder::new()
        .prefix("kalos-limits-")
        .tempdir()
        .unwrap()
}

/// Loads `path`, expecting an error that names the file and holds every
/// needle (case-insensitive).
fn expect_error(path: &Path, needles: &[&str]) -> String {
    let e = match scene::load(path) {
        Ok(s) => panic!(
            "{}: loaded without error ({} triangles)",
            path.display(),
            s.triangles.len()
        ),
        Err(e) => e.to_string(),
    };
    let name = path.file_name().unwrap().to_str().unwrap();
    assert!(e.contains(name), "the error does not name `{name}`: {e}");
    for n in needles {
        assert!(
            e.to_lowercase().contains(&n.to_lowercase()),
            "`{n}` not in: {e}"
        );
    }
    e
}

// ---------------------------------------------------------------------------
// glTF node graphs

/// Writes a glTF file with one one-triangle mesh (in `tri.bin`) and the given
/// nodes (JSON objects), the scene's roots being `roots`.
fn gltf_with_nodes(dir: &Path, name: &str, nodes: &[String], roots: &[usize]) -> PathBuf {
    let mut bin = Vec::new();
    for v in [0.0f32, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0, 0.0] {
        bin.extend(v.to_le_bytes());
    }
    std::fs::write(dir.join("tri.bin"), &bin).unwrap();
    let json = format!(
        r#"{{"asset":{{"version":"2.0"}},"scene":0,"scenes":[{{"nodes":{roots:?}}}],
        "nodes":[{}],
        "meshes":[{{"primitives":[{{"attributes":{{"POSITION":0}}}}]}}],
        "accessors":[{{"bufferView":0,"componentType":5126,"count":3,"type":"VEC3",
                       "min":[0,0,0],"max":[1,1,0]}}],
        "bufferViews":[{{"buffer":0,"byteOffset":0,"byteLength":36}}],
        "buffers":[{{"byteLength":36,"uri":"tri.bin"}}]}}"#,
        nodes.join(",")
    );
    let p = dir.join(name);
    std::fs::write(&p, json).unwrap();
    p
}

#[test]
fn gltf_node_cycles_are_errors() {
    let d = tmp();
    // a node that is its own child (reproducer r1)
    let p = gltf_with_nodes(
        d.path(),
        "self.gltf",
        &[r#"{"mesh":0,"children":[0]}"#.into()],
        &[0],
    );
    expect_error(&p, &["node 0", "own child"]);
    // a longer cycle below a root: 0 → 1 → 2 → 1
    let p = gltf_with_nodes(
        d.path(),
        "cycle.gltf",
        &[
            r#"{"children":[1]}"#.into(),
            r#"{"mesh":0,"children":[2]}"#.into(),
            r#"{"children":[1]}"#.into(),
        ],
        &[0],
    );
    expect_error(&p, &["node 1", "own ancestor"]);
}

#[test]
fn gltf_shared_nodes_load_until_they_multiply_too_far() {
    let d = tmp();
    // node k has node k+1 twice as a child: 2^levels instances of the mesh
    let chain = |levels: usize| -> Vec<String> {
        (0..levels)
            .map(|k| format!(r#"{{"children":[{},{}]}}"#, k + 1, k + 1))
            .chain([r#"{"mesh":0}"#.to_string()])
            .collect()
    };
    // a small DAG is fine: 2^4 instances of the triangle
    let p = gltf_with_nodes(d.path(), "dag.gltf", &chain(4), &[0]);
    let s = scene::load(&p).unwrap_or_else(|e| panic!("{e}"));
    assert_eq!(s.triangles.len(), 16);
    // 2^40 instances: refused before any is made, with the count
    let p = gltf_with_nodes(d.path(), "huge.gltf", &chain(40), &[0]);
    expect_error(&p, &[&(1u64 << 40).to_string(), "triangles"]);
}

// ---------------------------------------------------------------------------
// Header lengths beyond the file

#[test]
fn glb_lengths_beyond_the_file_are_errors() {
    let d = tmp();
    let json = b"{\"asset\":{\"version\":\"2.0\"}}    ";
    let glb = |total: u32, chunk: u32| {
        let mut b = Vec::new();
        for w in [0x4654_6C67u32, 2, total, chunk, 0x4E4F_534A] {
            b.extend(w.to_le_bytes());
        }
        b.extend(json);
        b
    };
    let size = 20 + json.len() as u32;
    // the header claims 4 GB (reproducer r2)
    let p = d.path().join("total.glb");
    std::fs::write(&p, glb(u32::MAX, json.len() as u32)).unwrap();
    expect_error(&p, &["4294967295", &size.to_string()]);
    // the header is right, the JSON chunk claims more than remains
    let p = d.path().join("chunk.glb");
    std::fs::write(&p, glb(size, 1 << 30)).unwrap();
    expect_error(&p, &["chunk 0", &(1u32 << 30).to_string()]);
}

#[test]
fn ply_counts_beyond_the_file_are_errors() {
    let d = tmp();
    let header = |format: &str, vertices: u64| {
        format!(
            "ply\nformat {format} 1.0\nelement vertex {vertices}\nproperty float x\n\
             property float y\nproperty float z\nelement face 1\n\
             property list uchar int vertex_indices\nend_header\n"
        )
    };
    // binary: three vertices and a face take 36 + 13 bytes; a count of 10^12
    // is refused from the header, naming its line
    let mut b = header("binary_little_endian", 1_000_000_000_000).into_bytes();
    for v in [0.0f32, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0, 0.0] {
        b.extend(v.to_le_bytes());
    }
    b.push(3);
    for i in [0i32, 1, 2] {
        b.extend(i.to_le_bytes());
    }
    let p = d.path().join("count.ply");
    std::fs::write(&p, &b).unwrap();
    let e = expect_error(&p, &["1000000000000", "vertex"]);
    assert!(e.contains("count.ply:3:"), "not the element's line: {e}");
    // ASCII too
    let a = header("ascii", 1 << 40) + "0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n";
    let p = d.path().join("ascii.ply");
    std::fs::write(&p, a).unwrap();
    expect_error(&p, &[&(1u64 << 40).to_string()]);
    // the honest file loads
    let good = header("ascii", 3) + "0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n";
    let p = d.path().join("good.ply");
    std::fs::write(&p, good).unwrap();
    assert_eq!(scene::load(&p).unwrap().triangles.len(), 1);
}

#[test]
fn a_ply_header_past_the_triangle_cap_is_refused_from_the_header() {
    let d = tmp();
    let faces = kalos::scene::MAX_TRIANGLES + 1;
    let header = format!(
        "ply\nformat binary_little_endian 1.0\nelement vertex 3\nproperty float x\n\
         property float y\nproperty float z\nelement face {faces}\n\
         property list uchar int vertex_indices\nend_header\n"
    );
    // a body large enough for the count (one byte a face at least), sparse:
    // refused from the header alone, without reading the 64 MiB after it
    let p = d.path().join("cap.ply");
    let f = std::fs::File::create(&p).unwrap();
    std::io::Write::write_all(&mut &f, header.as_bytes()).unwrap();
    f.set_len(header.len() as u64 + 36 + faces).unwrap();
    let start = std::time::Instant::now();
    let e = expect_error(
        &p,
        &[&faces.to_string(), &kalos::scene::MAX_TRIANGLES.to_string()],
    );
    assert!(e.contains("cap.ply:7:"), "not the element's line: {e}");
    assert!(
        start.elapsed() < std::time::Duration::from_millis(500),
        "{:?}: the body was read",
        start.elapsed()
    );
    // the same from bytes, as pbrt's loader parses them
    let e = kalos::scene::ply::parse_ply(header.as_bytes(), &p).unwrap_err();
    assert!(e.to_string().contains("at most"), "{e}");
}

// ---------------------------------------------------------------------------
// Includes

#[test]
fn include_fan_out_and_depth_are_capped() {
    let d = tmp();
    // each level includes the next ten times, six levels (reproducer r4)
    for lvl in 0..6 {
        let inner = if lvl < 5 {
            format!("<include filename=\"fan{}.xml\"/>\n", lvl + 1).repeat(10)
        } else {
            "<shape type=\"rectangle\"/>".to_string()
        };
        let xml = format!("<scene version=\"3.0.0\">\n{inner}</scene>\n");
        std::fs::write(d.path().join(format!("fan{lvl}.xml")), xml).unwrap();
    }
    // the cap is met inside some level's file, at one of its include lines
    let e = scene::load(&d.path().join("fan0.xml")).unwrap_err();
    assert!(e.file.to_string_lossy().contains("fan"), "{e}");
    assert!((2..=11).contains(&e.line), "not an include line: {e}");
    assert!(e.msg.contains("includes"), "{e}");

    // a chain of 40 files, each including the next once
    for k in 0..40 {
        let body = if k < 39 {
            format!("<include filename=\"chain{}.xml\"/>", k + 1)
        } else {
            "<shape type=\"rectangle\"/>".into()
        };
        std::fs::write(
            d.path().join(format!("chain{k}.xml")),
            format!("<scene version=\"3.0.0\">\n{body}\n</scene>"),
        )
        .unwrap();
    }
    let e = scene::load(&d.path().join("chain0.xml")).unwrap_err();
    assert!(e.msg.contains("nested"), "{e}");
    assert_eq!(e.line, 2, "{e}");
    // a short chain is fine
    let s = scene::load(&d.path().join("chain35.xml")).unwrap_or_else(|e| panic!("{e}"));
    assert_eq!(s.shapes.len(), 1);
}

// ---------------------------------------------------------------------------
// Emission and other numbers

fn write(dir: &Path, name: &str, text: &str) -> PathBuf {
    let p = dir.join(name);
    std::fs::write(&p, text).unwrap();
    p
}

#[test]
fn negative_emission_is_an_error_naming_the_emitter() {
    let d = tmp();
    let xml = |emitter: &str| {
        format!(
            "<scene version=\"3.0.0\">\n<shape type=\"rectangle\">\n{emitter}\n</shape>\n</scene>"
        )
    };
    let p = write(
        d.path(),
        "area.xml",
        &xml("<emitter type=\"area\"><rgb name=\"radiance\" value=\"1, -1, 1\"/></emitter>"),
    );
    let e = expect_error(&p, &["`radiance`", "non-negative", "area"]);
    assert!(e.contains("area.xml:3:"), "{e}");
    let p = write(
        d.path(),
        "const.xml",
        "<scene version=\"3.0.0\">\n<shape type=\"cube\"/>\n<emitter type=\"constant\">\n\
         <rgb name=\"radiance\" value=\"-2\"/></emitter>\n</scene>",
    );
    let e = expect_error(&p, &["constant", "radiance"]);
    assert!(e.contains("const.xml:4:"), "{e}");
    // non-finite numbers are refused where they are read
    let p = write(
        d.path(),
        "inf.xml",
        &xml("<emitter type=\"area\"><rgb name=\"radiance\" value=\"inf\"/></emitter>"),
    );
    expect_error(&p, &["number"]);
    // OBJ: a negative Ke
    write(
        d.path(),
        "neg.mtl",
        "newmtl lamp\nKd 0.5 0.5 0.5\nKe -1 2 2\n",
    );
    let p = write(
        d.path(),
        "neg.obj",
        "mtllib neg.mtl\nv 0 0 0\nv 1 0 0\nv 0 1 0\nusemtl lamp\nf 1 2 3\n",
    );
    expect_error(&p, &["lamp", "Ke", "non-negative"]);
    // glTF: a negative emissive factor
    let p = gltf_with_nodes(d.path(), "neg.gltf", &[r#"{"mesh":0}"#.into()], &[0]);
    let text = std::fs::read_to_string(&p).unwrap().replace(
        r#""accessors""#,
        r#""materials":[{"name":"glow","emissiveFactor":[1,-1,0]}],"accessors""#,
    );
    let text = text.replace(
        r#"{"attributes":{"POSITION":0}}"#,
        r#"{"attributes":{"POSITION":0},"material":0}"#,
    );
    std::fs::write(&p, text).unwrap();
    expect_error(&p, &["glow", "emission", "non-negative"]);
}

#[test]
fn negative_reflectance_is_an_error() {
    let d = tmp();
    let p = write(
        d.path(),
        "refl.xml",
        "<scene version=\"3.0.0\">\n<shape type=\"cube\">\n<bsdf type=\"diffuse\">\n\
         <rgb name=\"reflectance\" value=\"0.5, -0.1, 0.5\"/>\n</bsdf></shape>\n</scene>",
    );
    let e = expect_error(&p, &["`reflectance`", "diffuse", "non-negative"]);
    assert!(e.contains("refl.xml:4:"), "{e}");
    write(d.path(), "nan.mtl", "newmtl grey\nKd nan 0.5 0.5\n");
    let p = write(
        d.path(),
        "kd.obj",
        "mtllib nan.mtl\nv 0 0 0\nv 1 0 0\nv 0 1 0\nusemtl grey\nf 1 2 3\n",
    );
    expect_error(&p, &["grey", "Kd", "finite"]);
}

#[test]
fn non_finite_positions_are_errors() {
    let d = tmp();
    let p = write(
        d.path(),
        "nan.obj",
        "v 0 0 0\nv nan 0 0\nv 0 1 0\nf 1 2 3\n",
    );
    expect_error(&p, &["vertex 1", "not finite"]);
    let p = write(
        d.path(),
        "nan.ply",
        "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\n\
         property float z\nelement face 1\nproperty list uchar int vertex_indices\nend_header\n\
         0 0 0\n1 inf 0\n0 1 0\n3 0 1 2\n",
    );
    expect_error(&p, &["vertex 1", "not finite"]);
}

#[test]
fn emitterless_meshes_get_a_default_environment_and_a_note() {
    let d = tmp();
    let p = write(d.path(), "bare.obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n");
    let s = scene::load(&p).unwrap_or_else(|e| panic!("{e}"));
    assert!(
        matches!(s.emitters[..], [EmitterDesc::Constant { radiance }] if radiance == glam::Vec3::ONE),
        "{:?}",
        s.emitters
    );
    assert!(s
        .notes
        .iter()
        .any(|n| n.contains("default white environment")));
    let p = gltf_with_nodes(d.path(), "bare.gltf", &[r#"{"mesh":0}"#.into()], &[0]);
    let s = scene::load(&p).unwrap_or_else(|e| panic!("{e}"));
    assert_eq!(s.emitters.len(), 1);
    assert_eq!(s.notes.len(), 1);
    // an OBJ with its own light gets none
    write(d.path(), "lamp.mtl", "newmtl lamp\nKe 4 4 4\n");
    let p = write(
        d.path(),
        "lit.obj",
        "mtllib lamp.mtl\nv 0 0 0\nv 1 0 0\nv 0 1 0\nusemtl lamp\nf 1 2 3\n",
    );
    let s = scene::load(&p).unwrap_or_else(|e| panic!("{e}"));
    assert!(matches!(s.emitters[..], [EmitterDesc::Area { .. }]));
    assert!(s.notes.is_empty());
    // a Mitsuba scene is taken as written
    let p = write(
        d.path(),
        "dark.xml",
        "<scene version=\"3.0.0\"><shape type=\"cube\"/></scene>",
    );
    assert!(scene::load(&p).unwrap().emitters.is_empty());
}

// ---------------------------------------------------------------------------
// Parameters: the sample count and -D

#[test]
fn the_sampler_sample_count_is_read() {
    let d = tmp();
    let xml = |n: &str| {
        format!(
            "<scene version=\"3.0.0\">\n<default name=\"spp\" value=\"{n}\"/>\n\
             <sensor type=\"perspective\">\n<sampler type=\"independent\">\n\
             <integer name=\"sample_count\" value=\"$spp\"/>\n</sampler>\n</sensor>\n\
             <shape type=\"cube\"/>\n</scene>"
        )
    };
    let p = write(d.path(), "spp.xml", &xml("12"));
    assert_eq!(scene::load(&p).unwrap().sample_count, Some(12));
    let p = write(d.path(), "zero.xml", &xml("0"));
    let e = expect_error(&p, &["sample_count", "positive"]);
    assert!(e.contains("zero.xml:4:"), "{e}");
    let p = write(
        d.path(),
        "none.xml",
        "<scene version=\"3.0.0\"><shape type=\"cube\"/></scene>",
    );
    assert_eq!(scene::load(&p).unwrap().sample_count, None);
}

#[test]
fn defines_fill_and_override_defaults() {
    let d = tmp();
    let p = write(
        d.path(),
        "param.xml",
        "<scene version=\"3.0.0\">\n<default name=\"r\" value=\"1\"/>\n\
         <shape type=\"sphere\">\n<float name=\"radius\" value=\"$r\"/>\n\
         <point name=\"center\" x=\"$x\" y=\"0\" z=\"0\"/>\n</shape>\n</scene>",
    );
    let def = |pairs: &[(&str, &str)]| -> Vec<(String, String)> {
        pairs
            .iter()
            .map(|(n, v)| (n.to_string(), v.to_string()))
            .collect()
    };
    // `$x` has no default: an error naming it and its line
    let e = expect_error(&p, &["`$x`", "-D x="]);
    assert!(e.contains("param.xml:5:"), "{e}");
    // -D fills it, and overrides the file's `r`
    let bounds = |defs: &[(&str, &str)]| {
        let s = scene::load_with(&p, &def(defs)).unwrap_or_else(|e| panic!("{e}"));
        (s.bounds(), s.warnings)
    };
    let ((lo, hi), w) = bounds(&[("x", "5")]);
    assert!(
        (hi.x - lo.x - 2.0).abs() < 0.01 && (lo.x - 4.0).abs() < 0.01,
        "{lo} {hi}"
    );
    // No define is reported unused (the warning's own words: the file's
    // path may hold "-D", as in a temporary directory "kalos-limits-D…")
    assert!(!w.iter().any(|w| w.contains("is unused")), "{w:?}");
    let ((lo, hi), w) = bounds(&[("x", "0"), ("r", "3"), ("unused", "1")]);
    assert!((hi.x - lo.x - 6.0).abs() < 0.01, "{lo} {hi}");
    assert!(
        w.iter()
            .any(|w| w.contains("-D unused=1") && w.contains("unused")),
        "{w:?}"
    );
}

#[test]
fn pfm_is_read_as_a_texture_and_an_environment_map() {
    let d = tmp();
    // a 2×1 PFM, little-endian: rows bottom first, one row here
    let mut pfm = b"PF\n2 1\n-1.0\n".to_vec();
    for v in [0.25f32, 0.5, 0.75, 2.0, 4.0, 8.0] {
        pfm.extend(v.to_le_bytes());
    }
    std::fs::write(d.path().join("tex.pfm"), &pfm).unwrap();
    let p = write(
        d.path(),
        "pfm.xml",
        "<scene version=\"3.0.0\">\n<emitter type=\"envmap\"><string name=\"filename\" value=\"tex.pfm\"/></emitter>\n\
         <shape type=\"rectangle\"><bsdf type=\"diffuse\"><texture type=\"bitmap\" name=\"reflectance\">\n\
         <string name=\"filename\" value=\"tex.pfm\"/></texture></bsdf></shape>\n</scene>",
    );
    let s = scene::load(&p).unwrap_or_else(|e| panic!("{e}"));
    let EmitterDesc::EnvMap { image, .. } = &s.emitters[0] else {
        panic!("{:?}", s.emitters)
    };
    // linear, as stored (no sRGB decoding)
    assert_eq!((image.width, image.height), (2, 1));
    let data: Vec<_> = image.pixels().collect();
    assert!(data.contains(&glam::Vec3::new(2.0, 4.0, 8.0)), "{data:?}");
    assert!(data.contains(&glam::Vec3::new(0.25, 0.5, 0.75)));
    // a NaN texel is an error naming the image
    let mut bad = b"PF\n1 1\n-1.0\n".to_vec();
    for v in [f32::NAN, 0.0, 0.0] {
        bad.extend(v.to_le_bytes());
    }
    std::fs::write(d.path().join("nan.pfm"), &bad).unwrap();
    let p = write(
        d.path(),
        "nanpfm.xml",
        "<scene version=\"3.0.0\">\n<emitter type=\"envmap\"><string name=\"filename\" value=\"nan.pfm\"/></emitter>\n</scene>",
    );
    let e = expect_error(&p, &["nan.pfm", "not finite"]);
    assert!(e.contains("nanpfm.xml:2:"), "{e}");
}

#[test]
fn gltf_emissive_strength_scales_the_emission() {
    let d = tmp();
    let p = gltf_with_nodes(d.path(), "strong.gltf", &[r#"{"mesh":0}"#.into()], &[0]);
    let text = std::fs::read_to_string(&p).unwrap().replace(
        r#""accessors""#,
        r#""extensionsUsed":["KHR_materials_emissive_strength"],
        "materials":[{"emissiveFactor":[1,0.5,0.25],
                      "extensions":{"KHR_materials_emissive_strength":{"emissiveStrength":8}}}],
        "accessors""#,
    );
    let text = text.replace(
        r#"{"attributes":{"POSITION":0}}"#,
        r#"{"attributes":{"POSITION":0},"material":0}"#,
    );
    std::fs::write(&p, text).unwrap();
    let s = scene::load(&p).unwrap_or_else(|e| panic!("{e}"));
    let [EmitterDesc::Area { radiance, .. }] = s.emitters[..] else {
        panic!("{:?}", s.emitters)
    };
    assert_eq!(radiance, glam::Vec3::new(8.0, 4.0, 2.0));
}

// ---------------------------------------------------------------------------
// What the command line says about it

#[test]
fn cli_says_where_light_and_budget_come_from() {
    let d = tmp();
    let out = d.path().join("o.pfm");
    let out = out.to_str().unwrap();
    // a Mitsuba scene without emitters: refused before rendering
    let dark = write(
        d.path(),
        "dark.xml",
        "<scene version=\"3.0.0\"><shape type=\"cube\"/></scene>",
    );
    let o = kalos(&["render", dark.to_str().unwrap(), "--res", "8x8", "-o", out]);
    let e = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success(), "{e}");
    assert!(e.contains("dark.xml") && e.contains("no emitters"), "{e}");
    assert!(!Path::new(out).exists());
    // a bare OBJ: rendered under the default environment, with a note
    let obj = write(d.path(), "bare.obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n");
    let o = kalos(&[
        "render",
        obj.to_str().unwrap(),
        "--res",
        "8x8",
        "--spp",
        "1",
        "-o",
        out,
    ]);
    let e = String::from_utf8_lossy(&o.stderr);
    assert!(o.status.success(), "{e}");
    assert!(
        e.contains("note:") && e.contains("default white environment"),
        "{e}"
    );
    // the scene's sample count, set by -D, is the budget, and the summary says so
    let xml = write(
        d.path(),
        "spp.xml",
        "<scene version=\"3.0.0\"><default name=\"spp\" value=\"64\"/>\
         <sensor type=\"perspective\"><sampler type=\"independent\">\
         <integer name=\"sample_count\" value=\"$spp\"/></sampler></sensor>\
         <emitter type=\"constant\"/><shape type=\"cube\"/></scene>",
    );
    let o = kalos(&[
        "render",
        xml.to_str().unwrap(),
        "-D",
        "spp=3",
        "-D",
        "nothing=1",
        "--res",
        "8x8",
        "-o",
        out,
    ]);
    let (so, e) = (
        String::from_utf8_lossy(&o.stdout),
        String::from_utf8_lossy(&o.stderr),
    );
    assert!(o.status.success(), "{e}");
    assert!(so.contains("3.0 spp (the scene's sample_count 3)"), "{so}");
    assert!(e.contains("-D nothing=1 is unused"), "{e}");
    // a malformed -D is a usage error
    let o = kalos(&["info", xml.to_str().unwrap(), "-D", "novalue"]);
    assert!(!o.status.success());
    assert!(String::from_utf8_lossy(&o.stderr).contains("NAME=VALUE"));
}
