//! pbrt-v4 scenes: each directive family on small files written to a
//! temporary folder, the errors (file and line, never a panic), and the
//! Cornell box against the same scene written as Mitsuba XML.

use std::path::{Path, PathBuf};

use glam::Vec3;
use kalos::scene::{self, EmitterDesc, Material, Scene, SceneError, Texture};

use crate::common::{block_stats, max_block_z, path, render};

fn repo(p: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join(p)
}

/// Writes `files` (name, text) into a fresh folder and loads the first;
/// the folder is removed when the result is returned.
fn load_files(files: &[(&str, &str)]) -> Result<Scene, SceneError> {
    let dir = tempfile::Builder::new()
        .prefix("kalos-pbrt-")
        .tempdir()
        .unwrap();
    for (name, text) in files {
        let p = dir.path().join(name);
        std::fs::create_dir_all(p.parent().unwrap()).unwrap();
        std::fs::write(p, text).unwrap();
    }
    scene::load(&dir.path().join(files[0].0))
}

fn load(text: &str) -> Result<Scene, SceneError> {
    load_files(&[("main.pbrt", text)])
}

/// The error of a file that must be rejected, with its line.
fn error(text: &str) -> SceneError {
    match load(text) {
        Ok(_) => panic!("the file loaded, but should be rejected:\n{text}"),
        Err(e) => e,
    }
}

const TRIANGLE: &str =
    r#"Shape "trianglemesh" "point3 P" [0 0 0  1 0 0  0 1 0] "integer indices" [0 1 2]"#;

/// A scene with one light, so that it is complete; `body` follows.
fn world(body: &str) -> String {
    format!("WorldBegin\nLightSource \"infinite\" \"rgb L\" [1 1 1]\n{body}\n")
}

fn approx(a: Vec3, b: Vec3) -> bool {
    (a - b).abs().max_element() < 1e-4
}

fn corners(s: &Scene, shape: usize) -> Vec<Vec3> {
    let sh = &s.shapes[shape];
    (sh.first_tri..sh.first_tri + sh.tri_count)
        .flat_map(|t| s.tri_vertices(t))
        .collect()
}

#[test]
fn transforms_compose_as_in_pbrt() {
    // Translate then Scale: a point p goes to T(S(p))
    let s = load(&world(&format!(
        "Translate 10 0 0\nScale 2 2 2\n{TRIANGLE}"
    )))
    .unwrap();
    assert!(approx(s.tri_vertices(0)[1], Vec3::new(12.0, 0.0, 0.0)));
    // Rotate 90 about z takes x to y
    let s = load(&world(&format!("Rotate 90 0 0 1\n{TRIANGLE}"))).unwrap();
    assert!(approx(s.tri_vertices(0)[1], Vec3::new(0.0, 1.0, 0.0)));
    // Transform replaces, ConcatTransform multiplies; matrices are
    // column-major with the translation last, as pbrt writes them
    let m = "[1 0 0 0  0 1 0 0  0 0 1 0  0 0 5 1]";
    let s = load(&world(&format!(
        "Translate 100 0 0\nTransform {m}\n{TRIANGLE}"
    )))
    .unwrap();
    assert!(approx(s.tri_vertices(0)[0], Vec3::new(0.0, 0.0, 5.0)));
    let s = load(&world(&format!(
        "Translate 100 0 0\nConcatTransform {m}\n{TRIANGLE}"
    )))
    .unwrap();
    assert!(approx(s.tri_vertices(0)[0], Vec3::new(100.0, 0.0, 5.0)));
    // Identity, and a named coordinate system restored
    let s = load(&world(&format!(
        "Translate 0 3 0\nCoordinateSystem \"up\"\nIdentity\nTranslate 7 0 0\nCoordSysTransform \"up\"\n{TRIANGLE}"
    )))
    .unwrap();
    assert!(approx(s.tri_vertices(0)[0], Vec3::new(0.0, 3.0, 0.0)));
    let e = error(&world("CoordSysTransform \"nowhere\""));
    assert_eq!(e.line, 3, "{e}");
}

#[test]
fn attributes_restore_transform_and_material() {
    let s = load(&world(&format!(
        "AttributeBegin\nTranslate 5 0 0\nMaterial \"conductor\"\n{TRIANGLE}\nAttributeEnd\n{TRIANGLE}"
    )))
    .unwrap();
    assert_eq!(s.shapes.len(), 2);
    assert!(approx(corners(&s, 0)[0], Vec3::new(5.0, 0.0, 0.0)));
    assert!(approx(corners(&s, 1)[0], Vec3::ZERO));
    let m0 = &s.materials[s.shapes[0].material as usize];
    let m1 = &s.materials[s.shapes[1].material as usize];
    assert!(matches!(m0, Material::TwoSided(b) if matches!(**b, Material::Conductor { .. })));
    // pbrt's default material: diffuse 0.5, reflecting on both sides
    assert!(matches!(m1, Material::TwoSided(b) if matches!(**b, Material::Diffuse { .. })));
    let e = error(&world("AttributeEnd"));
    assert!(e.to_string().contains("main.pbrt:3"), "{e}");
    // `Attribute` gives shape defaults
    let s = load(&world(
        "Attribute \"shape\" \"float radius\" 3\nShape \"sphere\"",
    ))
    .unwrap();
    let (lo, hi) = s.bounds();
    assert!((hi.x - lo.x - 6.0).abs() < 0.01, "{lo} {hi}");
}

#[test]
fn objects_are_instanced_under_their_transform() {
    let s = load(&world(&format!(
        "ObjectBegin \"tri\"\n{TRIANGLE}\nObjectEnd\n\
         AttributeBegin\nTranslate 0 0 4\nObjectInstance \"tri\"\nAttributeEnd\n\
         AttributeBegin\nTranslate 0 0 8\nObjectInstance \"tri\"\nAttributeEnd"
    )))
    .unwrap();
    assert_eq!(s.triangles.len(), 2, "the definition itself is not drawn");
    assert!(approx(s.tri_vertices(0)[0], Vec3::new(0.0, 0.0, 4.0)));
    assert!(approx(s.tri_vertices(1)[0], Vec3::new(0.0, 0.0, 8.0)));
    let e = error(&world("ObjectInstance \"missing\""));
    assert_eq!(e.line, 3, "{e}");
}

#[test]
fn include_and_import_resolve_against_the_main_folder() {
    let s = load_files(&[
        (
            "main.pbrt",
            &world("Include \"geometry/a.pbrt\"\nImport \"geometry/b.pbrt\""),
        ),
        ("geometry/a.pbrt", TRIANGLE),
        ("geometry/b.pbrt", &format!("Translate 0 0 1\n{TRIANGLE}")),
    ])
    .unwrap();
    assert_eq!(s.triangles.len(), 2);
    // an error inside an included file names that file and its line
    let e = load_files(&[
        ("main.pbrt", &world("Include \"bad.pbrt\"")),
        ("bad.pbrt", "\n\nShape \"cylinder\""),
    ])
    .unwrap_err();
    assert!(e.file.ends_with("bad.pbrt") && e.line == 3, "{e}");
    let e = error(&world("Include \"missing.pbrt\""));
    assert!(
        e.to_string().contains("main.pbrt:3") && e.msg.contains("not found"),
        "{e}"
    );
    // a file that includes itself stops at the depth limit
    let e = load_files(&[("main.pbrt", "Include \"main.pbrt\"")]).unwrap_err();
    assert!(e.msg.contains("deep"), "{e}");
}

#[test]
fn shapes_sphere_disk_bilinear_and_ply() {
    let s = load(&world(
        "Translate 1 2 3\nShape \"sphere\" \"float radius\" 2",
    ))
    .unwrap();
    let (lo, hi) = s.bounds();
    assert!(
        approx(lo, Vec3::new(-1.0, 0.0, 1.0)) && approx(hi, Vec3::new(3.0, 4.0, 5.0)),
        "{lo} {hi}"
    );
    let s = load(&world(
        "Shape \"disk\" \"float radius\" 2 \"float height\" 1",
    ))
    .unwrap();
    let area: f32 = (0..s.triangles.len() as u32).map(|t| s.tri_area(t)).sum();
    assert!((area - 4.0 * std::f32::consts::PI).abs() < 0.01, "{area}");
    assert!(s.positions.iter().all(|p| (p.z - 1.0).abs() < 1e-6));
    let s = load(&world(
        "Shape \"bilinearmesh\" \"point3 P\" [0 0 0  1 0 0  0 1 0  1 1 0] \"integer indices\" [0 1 2 3]",
    ))
    .unwrap();
    assert_eq!(s.triangles.len(), 2);
    let area: f32 = (0..2).map(|t| s.tri_area(t)).sum();
    assert!((area - 1.0).abs() < 1e-6);
    // a patch keeps pbrt's normal, cross(p10 − p00, p01 − p00) = +z
    let [a, b, c] = s.tri_vertices(0);
    assert!((b - a).cross(c - a).z > 0.0);

    let ply = "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\n\
               property float z\nelement face 1\nproperty list uchar int vertex_indices\nend_header\n\
               0 0 0\n2 0 0\n0 2 0\n3 0 1 2\n";
    let s = load_files(&[
        (
            "main.pbrt",
            &world("Shape \"plymesh\" \"string filename\" \"m.ply\""),
        ),
        ("m.ply", ply),
    ])
    .unwrap();
    assert!((s.tri_area(0) - 2.0).abs() < 1e-6);
    // gzip-compressed, as pbrt-v4 scenes ship them; a file that only
    // claims to be gzip is an error that says so
    let dir = tempfile::tempdir().unwrap();
    let gz = |name: &str, data: &[u8]| {
        use std::io::Write;
        let mut e = flate2::write::GzEncoder::new(Vec::new(), flate2::Compression::default());
        e.write_all(data).unwrap();
        std::fs::write(dir.path().join(name), e.finish().unwrap()).unwrap();
    };
    gz("m.ply.gz", ply.as_bytes());
    gz(
        "main.pbrt.gz",
        world("Shape \"plymesh\" \"string filename\" \"m.ply.gz\"").as_bytes(),
    );
    let s = scene::load(&dir.path().join("main.pbrt.gz")).unwrap();
    assert!((s.tri_area(0) - 2.0).abs() < 1e-6);
    std::fs::write(dir.path().join("bad.ply.gz"), ply).unwrap();
    std::fs::write(
        dir.path().join("bad.pbrt"),
        world("Shape \"plymesh\" \"string filename\" \"bad.ply.gz\""),
    )
    .unwrap();
    let e = scene::load(&dir.path().join("bad.pbrt")).unwrap_err();
    assert!(
        e.line == 3 && e.msg.contains("not a valid gzip file"),
        "{e}"
    );
}

#[test]
fn orientation_follows_pbrt() {
    // a mirroring transform keeps the normal (+z here), ReverseOrientation
    // flips it; an area light emits on that side
    let n = |s: &Scene| {
        let [a, b, c] = s.tri_vertices(0);
        (b - a).cross(c - a).normalize()
    };
    let s = load(&world(&format!("Scale -1 1 1\n{TRIANGLE}"))).unwrap();
    assert!(n(&s).z > 0.99);
    let s = load(&world(&format!("ReverseOrientation\n{TRIANGLE}"))).unwrap();
    assert!(n(&s).z < -0.99);
    // normals decide the side
    let s = load(&world(&format!(
        "{TRIANGLE} \"normal N\" [0 0 -1  0 0 -1  0 0 -1]"
    )))
    .unwrap();
    assert!(n(&s).z < -0.99);
}

fn material_of(body: &str) -> (Material, Scene) {
    let s = load(&world(&format!("{body}\n{TRIANGLE}"))).unwrap();
    let m = s.materials[s.shapes[0].material as usize].clone();
    let inner = match m {
        Material::TwoSided(b) => *b,
        m => m,
    };
    (inner, s)
}

#[test]
fn materials_map_onto_kalos_bsdfs() {
    let (m, _) = material_of("Material \"diffuse\" \"rgb reflectance\" [0.2 0.3 0.4]");
    assert!(
        matches!(m, Material::Diffuse { reflectance: Texture::Constant(c) } if approx(c, Vec3::new(0.2, 0.3, 0.4)))
    );
    // roughness is remapped to α = √r, as pbrt's RoughnessToAlpha
    let (m, s) = material_of("Material \"coateddiffuse\" \"float roughness\" 0.04");
    assert!(
        matches!(m, Material::RoughPlastic { alpha, .. } if (alpha - 0.2).abs() < 1e-6),
        "{m:?}"
    );
    assert!(s.notes.iter().any(|n| n.contains("coateddiffuse")));
    let (m, _) = material_of(
        "Material \"conductor\" \"spectrum eta\" \"metal-Au-eta\" \"spectrum k\" \"metal-Au-k\"",
    );
    let Material::Conductor { eta, k, .. } = m else {
        panic!("{m:?}")
    };
    assert!(eta.z > eta.x && k.x > k.z, "gold: {eta} {k}");
    let (m, _) = material_of(
        "Material \"conductor\" \"float roughness\" 0.01 \"bool remaproughness\" false",
    );
    assert!(matches!(m, Material::RoughConductor { alpha, .. } if (alpha - 0.01).abs() < 1e-6));
    let (m, _) = material_of("Material \"dielectric\" \"float eta\" 1.33");
    assert!(matches!(m, Material::Dielectric { eta, .. } if (eta - 1.33).abs() < 1e-6));
    let (m, _) = material_of("Material \"dielectric\" \"spectrum eta\" \"glass-BK7\"");
    assert!(matches!(m, Material::Dielectric { eta, .. } if (eta - 1.5168).abs() < 1e-4));
    let (m, _) = material_of("Material \"thindielectric\"");
    assert!(matches!(m, Material::ThinDielectric { .. }));
    let (m, s) = material_of("Material \"diffusetransmission\"");
    assert!(matches!(m, Material::Diffuse { .. }));
    assert!(s
        .notes
        .iter()
        .any(|n| n.contains("diffusetransmission") && n.contains("stand-in")));
    // two diffuse materials mix exactly
    let (m, _) = material_of(
        "MakeNamedMaterial \"a\" \"string type\" \"diffuse\" \"rgb reflectance\" [0 0 0]\n\
         MakeNamedMaterial \"b\" \"string type\" \"diffuse\" \"rgb reflectance\" [1 1 1]\n\
         Material \"mix\" \"string materials\" [\"a\" \"b\"] \"float amount\" 0.25",
    );
    assert!(
        matches!(m, Material::Diffuse { reflectance: Texture::Constant(c) } if approx(c, Vec3::splat(0.25))),
        "{m:?}"
    );
    let (m, s) = material_of(
        "MakeNamedMaterial \"a\" \"string type\" \"diffuse\"\n\
         MakeNamedMaterial \"b\" \"string type\" \"conductor\"\n\
         Material \"mix\" \"string materials\" [\"a\" \"b\"] \"float amount\" 0.75",
    );
    assert!(matches!(m, Material::Conductor { .. }));
    assert!(s
        .notes
        .iter()
        .any(|n| n.contains("mix") && n.contains("\"b\"")));
    let (m, s) = material_of("Material \"coatedconductor\"");
    assert!(matches!(m, Material::Conductor { .. }));
    assert!(s.notes.iter().any(|n| n.contains("coatedconductor")));
    let (_, s) = material_of("Material \"hair\"");
    assert!(s.notes.iter().any(|n| n.contains("`hair`")));
}

#[test]
fn textures_imagemap_checkerboard_scale_mix() {
    let (m, _) = material_of(
        "Texture \"c\" \"spectrum\" \"checkerboard\" \"rgb tex1\" [1 0 0] \"rgb tex2\" [0 0 1] \"float uscale\" 4\n\
         Material \"diffuse\" \"texture reflectance\" \"c\"",
    );
    let Material::Diffuse { reflectance: t } = m else {
        panic!()
    };
    // pbrt: tex1 where ⌊s⌋ + ⌊t⌋ is even, s = 4u
    assert!(approx(
        t.eval(glam::Vec2::new(0.1, 0.5)),
        Vec3::new(1.0, 0.0, 0.0)
    ));
    assert!(approx(
        t.eval(glam::Vec2::new(0.3, 0.5)),
        Vec3::new(0.0, 0.0, 1.0)
    ));
    let (m, _) = material_of(
        "Texture \"a\" \"spectrum\" \"constant\" \"rgb value\" [0.5 0.5 0.5]\n\
         Texture \"s\" \"spectrum\" \"scale\" \"texture tex\" \"a\" \"float scale\" 0.5\n\
         Texture \"m\" \"spectrum\" \"mix\" \"texture tex1\" \"s\" \"rgb tex2\" [1 1 1] \"float amount\" 0.5\n\
         Material \"diffuse\" \"texture reflectance\" \"m\"",
    );
    let Material::Diffuse { reflectance: t } = m else {
        panic!()
    };
    assert!(approx(t.mean(), Vec3::splat(0.625)), "{:?}", t.mean());

    // an imagemap: a 2×1 PFM, left texel red, right blue
    let dir = tempfile::Builder::new()
        .prefix("kalos-pbrt-")
        .tempdir()
        .unwrap();
    let img = kalos::film::Image {
        width: 2,
        height: 1,
        data: vec![Vec3::new(1.0, 0.0, 0.0), Vec3::new(0.0, 0.0, 1.0)],
    };
    std::fs::write(dir.path().join("t.pfm"), kalos::image_io::encode_pfm(&img)).unwrap();
    std::fs::write(
        dir.path().join("main.pbrt"),
        world(&format!(
            "Texture \"i\" \"spectrum\" \"imagemap\" \"string filename\" \"t.pfm\"\n\
             Material \"diffuse\" \"texture reflectance\" \"i\"\n{TRIANGLE}"
        )),
    )
    .unwrap();
    let s = scene::load(&dir.path().join("main.pbrt")).unwrap();
    let Material::TwoSided(b) = &s.materials[s.shapes[0].material as usize] else {
        panic!()
    };
    let Material::Diffuse { reflectance: t } = &**b else {
        panic!()
    };
    // texel centres (the lookup is bilinear)
    assert!(approx(t.eval(glam::Vec2::new(0.25, 0.5)), Vec3::X));
    assert!(approx(t.eval(glam::Vec2::new(0.75, 0.5)), Vec3::Z));
    let e = error(&world(
        "Material \"diffuse\" \"texture reflectance\" \"none\"",
    ));
    assert!(e.line == 3 && e.msg.contains("none"), "{e}");
}

#[test]
fn lights_camera_and_film() {
    let s = load(&format!(
        "LookAt 0 0 -5  0 0 0  0 1 0\nCamera \"perspective\" \"float fov\" 30\n\
         Film \"rgb\" \"integer xresolution\" 200 \"integer yresolution\" 100\n\
         Sampler \"halton\" \"integer pixelsamples\" 32\nWorldBegin\n\
         AttributeBegin\nAreaLightSource \"diffuse\" \"rgb L\" [1 2 3] \"float scale\" 2\n{TRIANGLE}\nAttributeEnd\n\
         LightSource \"infinite\" \"blackbody L\" 5000 \"float scale\" 3"
    ))
    .unwrap();
    assert_eq!((s.camera.width, s.camera.height), (200, 100));
    assert_eq!(s.sample_count, Some(32));
    // pbrt's fov is on the shorter axis (y here)
    let tx = (15f32.to_radians().tan() * 2.0).atan().to_degrees() * 2.0;
    assert!(
        (s.camera.fov_x_deg - tx).abs() < 1e-3,
        "{}",
        s.camera.fov_x_deg
    );
    // the camera looks along +z from (0, 0, −5) with +x on the image's right:
    // kalos's camera x (the image's left) is world −x
    let m = s.camera.to_world;
    assert!(approx(m.w_axis.truncate(), Vec3::new(0.0, 0.0, -5.0)));
    assert!(approx(m.z_axis.truncate().normalize(), Vec3::Z));
    assert!(approx(m.x_axis.truncate().normalize(), -Vec3::X));
    let area = s.emitters.iter().find_map(|e| match e {
        EmitterDesc::Area { radiance, .. } => Some(*radiance),
        _ => None,
    });
    assert!(approx(area.unwrap(), Vec3::new(2.0, 4.0, 6.0)));
    // a blackbody is normalised to luminance 1, then scaled
    let sky = s.emitters.iter().find_map(|e| match e {
        EmitterDesc::Constant { radiance } => Some(*radiance),
        _ => None,
    });
    let sky = sky.unwrap();
    assert!(
        (scene::luminance(sky) - 3.0).abs() < 1e-3 && sky.x > sky.z,
        "{sky}"
    );
}

/// One file per unsupported directive class: each is an error naming the
/// file and line, never a panic or a silent skip.
#[test]
fn unsupported_input_is_an_error_with_file_and_line() {
    let cases: &[(&str, &str)] = &[
        (
            "LightSource \"point\" \"rgb I\" [1 1 1]",
            "need lights with an area",
        ),
        ("LightSource \"spot\"", "need lights with an area"),
        ("LightSource \"distant\"", "need lights with an area"),
        ("Shape \"cylinder\"", "unsupported shape"),
        ("Shape \"curve\"", "unsupported shape"),
        ("Shape \"sphere\" \"float zmax\" 0.5", "partial spheres"),
        ("Shape \"blob\"", "unknown shape"),
        ("Material \"velvet\"", "unknown material"),
        (
            "Texture \"t\" \"spectrum\" \"wrinkled\"",
            "unsupported texture",
        ),
        ("Camera \"orthographic\"", "perspective camera only"),
        (
            "Shape \"sphere\" \"float radiuss\" 2",
            "unknown parameter \"float radiuss\"",
        ),
        ("Shape \"sphere\" \"rgb radius\" [1 1 1]", "expected float"),
        (
            "Shape \"sphere\" \"floot radius\" 2",
            "unknown parameter type",
        ),
        ("Shape \"sphere\" \"string radius\" 2", "quoted strings"),
        ("Shape \"sphere\" \"float radius\" [1 2", "no closing"),
        ("Translate 1 2", "takes 3 numbers"),
        (
            "Material \"diffuse\" \"rgb reflectance\" [2 2 2]",
            "at most 1",
        ),
        (
            "Material \"conductor\" \"spectrum eta\" \"metal-Unobtainium-eta\"",
            "named spectrum",
        ),
        (
            "Shape \"trianglemesh\" \"point3 P\" [0 0 0 1 0 0 0 1 0] \"integer indices\" [0 1 5]",
            "out of range",
        ),
        ("Frobnicate 1", "unknown directive `Frobnicate`"),
        ("Identity \"float x\" 1", "takes no parameters"),
        ("Shape \"sphere\" \"string note", "not closed"),
        ("Include \"more.pbrt.gz\"", "not found"),
    ];
    for (body, want) in cases {
        let e = error(&world(body));
        assert!(
            e.file.ends_with("main.pbrt") && e.line == 3 && e.msg.contains(want),
            "`{body}` gave `{e}`, expected line 3 and \"{want}\""
        );
    }
}

#[test]
fn non_ascii_comments_and_spacing_are_read() {
    // pbrt4 0.2.0's own tokenizer panics on the accented comment and reads
    // the spaced value as 2
    let s = load(&world(
        "# café ☕\nShape \"sphere\"  \"float radius\"    2.5",
    ))
    .unwrap();
    let (lo, hi) = s.bounds();
    assert!((hi.x - lo.x - 5.0).abs() < 0.01, "{lo} {hi}");
    // a spectrum file (λ, value pairs) relative to the main file
    let s = load_files(&[
        ("main.pbrt", &world(&format!("Material \"conductor\" \"spectrum eta\" \"spds/e.spd\" \"spectrum k\" [300 2  800 2]\n{TRIANGLE}"))),
        ("spds/e.spd", "# flat\n300 1.5\n800 1.5\n"),
    ])
    .unwrap();
    let Material::TwoSided(b) = &s.materials[s.shapes[0].material as usize] else {
        panic!()
    };
    let Material::Conductor { eta, k, .. } = &**b else {
        panic!()
    };
    assert!(
        approx(*eta, Vec3::splat(1.5)) && approx(*k, Vec3::splat(2.0)),
        "{eta} {k}"
    );
    // warnings for what is skipped
    let s = load(&format!(
        "Integrator \"volpath\"\n{}",
        world("MakeNamedMedium \"fog\" \"string type\" \"homogeneous\"")
    ))
    .unwrap();
    assert!(s.warnings.iter().any(|w| w.contains("Integrator")));
    assert!(s.warnings.iter().any(|w| w.contains("media")));
}

/// `cornell-box.pbrt` and `cornell-box.xml` (the same scene written as
/// Mitsuba XML) render the same image within noise. Each is rendered twice
/// with independent seeds; the per-pixel difference of the two renders
/// measures the variance of each 16×16 block mean (`block_stats`), and
/// every block and channel must agree within 5 standard errors: with 48
/// such z-scores, a true match exceeds 5 with probability about 3·10⁻⁵.
/// The blocks compare the image's halves too, so a mirrored camera fails.
#[test]
fn cornell_box_pbrt_matches_its_mitsuba_version() {
    let load_at = |f: &str| {
        let mut s = scene::load(&repo(f)).unwrap();
        s.set_resolution(64, 64);
        s
    };
    let pbrt = load_at("scenes/cornell-box-pbrt/cornell-box.pbrt");
    let xml = load_at("scenes/cornell-box-pbrt/cornell-box.xml");
    let passes = 16;
    let (p1, _) = render(&pbrt, &path(), 1, passes);
    let (p2, _) = render(&pbrt, &path(), 2, passes);
    let (x1, _) = render(&xml, &path(), 3, passes);
    let (x2, _) = render(&xml, &path(), 4, passes);
    let all = |_: u32, _: u32| true;
    let a = block_stats(&p1, &p2, 16, &all);
    let b = block_stats(&x1, &x2, 16, &all);
    let (z, block) = max_block_z(&a, &b, 1e-4);
    assert!(z < 5.0, "block {block} differs by {z:.2} standard errors");
    // and the red wall (x = 552.8) is on the image's right, as pbrt draws it
    let red = |img: &kalos::film::Image, x0: u32| -> f32 {
        (0..64)
            .flat_map(|y| (x0..x0 + 8).map(move |x| (x, y)))
            .map(|(x, y)| {
                let c = img.get(x, y);
                c.x - c.y
            })
            .sum()
    };
    assert!(red(&p1, 56) > red(&p1, 0) + 1.0);
}

/// An image `infinite` light: pbrt-v4's square equal-area image resampled
/// to kalos's latitude–longitude map, directions kept. In a 2×2 image the
/// texel (1, 1) holds the directions with x > 0 and y > 0; in the 4×2 map
/// pixel (x, y) looks along (sin θ sin φ, cos θ, −sin θ cos φ).
#[test]
fn image_infinite_light_keeps_directions() {
    let dir = tempfile::Builder::new()
        .prefix("kalos-pbrt-")
        .tempdir()
        .unwrap();
    let mut data = vec![Vec3::ZERO; 4];
    data[3] = Vec3::X;
    let img = kalos::film::Image {
        width: 2,
        height: 2,
        data,
    };
    // PFM rows are stored bottom-up; encode_pfm takes row 0 as the top
    std::fs::write(
        dir.path().join("sky.pfm"),
        kalos::image_io::encode_pfm(&img),
    )
    .unwrap();
    let main = dir.path().join("main.pbrt");
    std::fs::write(
        &main,
        "WorldBegin\nLightSource \"infinite\" \"string filename\" \"sky.pfm\" \"float scale\" 2\n",
    )
    .unwrap();
    let s = scene::load(&main).unwrap();
    let EmitterDesc::EnvMap { image, scale, .. } = &s.emitters[0] else {
        panic!("{:?}", s.emitters)
    };
    assert_eq!((image.width, image.height, *scale), (4, 2, 2.0));
    assert_eq!(image.texel(1, 0), Vec3::X);
    assert_eq!(image.texel(3, 0), Vec3::ZERO);
    assert_eq!(image.texel(1, 1), Vec3::ZERO);
    std::fs::write(
        dir.path().join("wide.pfm"),
        kalos::image_io::encode_pfm(&kalos::film::Image {
            width: 2,
            height: 1,
            data: vec![Vec3::ONE; 2],
        }),
    )
    .unwrap();
    std::fs::write(
        &main,
        "WorldBegin\nLightSource \"infinite\" \"string filename\" \"wide.pfm\"\n",
    )
    .unwrap();
    let e = scene::load(&main).unwrap_err();
    assert!(e.line == 2 && e.msg.contains("square"), "{e}");
}

/// The command line reads `.pbrt` files: `info` shows the box, and a bad
/// file ends in one error line naming the file and line (exit 1, no panic).
#[test]
fn cli_info_reads_pbrt_files() {
    let run = |file: &Path| {
        std::process::Command::new(env!("CARGO_BIN_EXE_kalos"))
            .arg("info")
            .arg(file)
            .output()
            .unwrap()
    };
    let out = run(&repo("scenes/cornell-box-pbrt/cornell-box.pbrt"));
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(out.status.success(), "{out:?}");
    assert!(
        stdout.contains("triangles  32") && stdout.contains("1080x1080"),
        "{stdout}"
    );
    let dir = tempfile::Builder::new()
        .prefix("kalos-pbrt-")
        .tempdir()
        .unwrap();
    let bad = dir.path().join("bad.pbrt");
    std::fs::write(&bad, world("LightSource \"spot\"")).unwrap();
    let out = run(&bad);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "{stderr}");
    assert!(
        stderr.contains("bad.pbrt:3:") && !stderr.contains("panicked"),
        "{stderr}"
    );
}
