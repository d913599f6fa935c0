//! Scene loading: the shipped scenes, analytic shapes, transforms, PLY and
//! OBJ files, and the errors a bad scene file gives (file and line, never a
//! panic).

use std::f32::consts::PI;
use std::path::{Path, PathBuf};

use glam::{Mat4, Vec3};
use kalos::scene::{self, EmitterDesc, Material, Scene, Texture};
use proptest::prelude::*;

fn repo(p: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join(p)
}

/// A fresh temporary folder for one test, removed when dropped.
struct Tmp(tempfile::TempDir);

impl std::ops::Deref for Tmp {
    type Target = Path;
    fn deref(&self) -> &Path {
        self.0.path()
    }
}

fn tmp(name: &str) -> Tmp {
    Tmp(tempfile::Builder::new()
        .prefix(&format!("kalos-loader-{name}-"))
        .tempdir()
        .unwrap())
}

fn approx(a: Vec3, b: Vec3, eps: f32) -> bool {
    (a - b).abs().max_element() <= eps
}

fn total_area(s: &Scene) -> f32 {
    (0..s.triangles.len() as u32).map(|t| s.tri_area(t)).sum()
}

/// A scene with one shape (the XML inside `<scene>`), from a string.
fn scene_of(body: &str) -> Scene {
    let xml = format!("<scene version=\"3.0.0\">\n{body}\n</scene>");
    scene::load_str(&xml, Path::new("."), "test.xml").unwrap_or_else(|e| panic!("{e}"))
}

fn shape_scene(shape: &str, transform: &str) -> Scene {
    scene_of(&format!(
        "<shape type=\"{shape}\"><transform name=\"to_world\">{transform}</transform></shape>"
    ))
}

// ---------------------------------------------------------------------------
// The shipped scenes

#[test]
fn cbox_loads() {
    let s = scene::load(&repo("scenes/cbox/cbox.xml")).unwrap_or_else(|e| panic!("{e}"));
    assert_eq!(s.shapes.len(), 8);
    assert_eq!((s.camera.width, s.camera.height), (256, 256));
    let areas: Vec<_> = s
        .emitters
        .iter()
        .filter_map(|e| match e {
            EmitterDesc::Area { shape, radiance } => Some((*shape, *radiance)),
            _ => None,
        })
        .collect();
    assert_eq!(areas.len(), 1);
    assert_eq!(s.emitters.len(), 1);
    let (shape, radiance) = areas[0];
    assert!(approx(radiance, Vec3::new(18.387, 10.9873, 2.75357), 1e-4));
    // the luminaire is the first shape, moved 0.5 mm down from y = 548.8
    assert_eq!(shape, 0);
    let sh = &s.shapes[shape as usize];
    for t in sh.first_tri..sh.first_tri + sh.tri_count {
        for v in s.tri_vertices(t) {
            assert!((v.y - 548.3).abs() < 1e-3, "{v}");
        }
        // the light faces down, into the box
        assert!(s.surface_point(t, 0.3, 0.3).ng.y < -0.99);
    }
    // its own diffuse reflectance
    match &s.materials[sh.material as usize] {
        Material::Diffuse {
            reflectance: Texture::Constant(c),
        } => assert!(approx(*c, Vec3::new(0.936461, 0.740433, 0.705267), 1e-5)),
        m => panic!("{m:?}"),
    }
    // the lookat camera at (278, 273, -800) looking along +z
    let m = s.camera.to_world;
    assert!(approx(
        m.w_axis.truncate(),
        Vec3::new(278.0, 273.0, -800.0),
        1e-3
    ));
    assert!(approx(m.z_axis.truncate(), Vec3::Z, 1e-6));
    assert!((s.camera.fov_x_deg - 39.3077).abs() < 1e-3);
    assert!((s.camera.near_clip - 10.0).abs() < 1e-6);
    // the floor faces up
    let floor = &s.shapes[1];
    assert!(s.surface_point(floor.first_tri, 0.3, 0.3).ng.y > 0.99);
    assert!(s.warnings.iter().any(|w| w.contains("integrator")));
}

#[test]
fn cornell_box_loads() {
    let s = scene::load(&repo("scenes/cornell-box/scene.xml")).unwrap_or_else(|e| panic!("{e}"));
    assert_eq!(s.shapes.len(), 8);
    // 6 rectangles × 2 + 2 cubes × 12
    assert_eq!(s.triangles.len(), 36);
    assert_eq!(s.emitters.len(), 1);
    let EmitterDesc::Area { shape, radiance } = s.emitters[0] else {
        panic!("not an area light")
    };
    assert_eq!(radiance, Vec3::new(17.0, 12.0, 4.0));
    let light = &s.shapes[shape as usize];
    assert_eq!(light.name, "Light");
    // the light is just under the ceiling (y = 1.98) and faces down
    let sp = s.surface_point(light.first_tri, 0.3, 0.3);
    assert!((sp.p.y - 1.98).abs() < 1e-4);
    assert!(sp.ng.y < -0.99);
    assert!(matches!(
        s.materials[light.material as usize],
        Material::TwoSided(_)
    ));
    assert_eq!((s.camera.width, s.camera.height), (256, 256));
    assert!((s.camera.fov_x_deg - 19.5).abs() < 1e-4);
    assert!(approx(
        s.camera.to_world.w_axis.truncate(),
        Vec3::new(0.0, 1.0, 6.8),
        1e-6
    ));
    // the room is [-1,1] × [0,2] × [-1,1]
    let (lo, hi) = s.bounds();
    assert!(approx(lo, Vec3::new(-1.0, 0.0, -1.0), 1e-3), "{lo}");
    assert!(approx(hi, Vec3::new(1.0, 2.0, 1.0), 1e-3), "{hi}");
}

#[test]
fn gltf_cornell_box_loads() {
    let s = scene::load(&repo(
        "scenes/cornell-box-gltf/cornellBox-2.80-Eevee-gltf.gltf",
    ))
    .unwrap_or_else(|e| panic!("{e}"));
    // 12 meshes, 23 triangle primitives
    assert_eq!(s.shapes.len(), 23);
    // one emissive material, on the lamp, above the floor
    assert_eq!(s.emitters.len(), 1);
    let EmitterDesc::Area { shape, radiance } = s.emitters[0] else {
        panic!("not an area light")
    };
    assert_eq!(radiance, Vec3::ONE);
    let lamp = &s.shapes[shape as usize];
    assert!(lamp.name.starts_with("lamp"), "{}", lamp.name);
    // the checker textures became bitmaps
    assert!(s
        .materials
        .iter()
        .any(|m| matches!(m.diffuse_texture(), Some(Texture::Bitmap { .. }))));
    // no glTF camera: one was synthesised
    assert!(s.warnings.iter().any(|w| w.contains("camera")));
}

// ---------------------------------------------------------------------------
// Analytic shapes

/// Every triangle's geometric normal points away from `center`.
fn outward(s: &Scene, center: Vec3) -> bool {
    (0..s.triangles.len() as u32).all(|t| {
        let [a, b, c] = s.tri_vertices(t);
        let sp = s.surface_point(t, 1.0 / 3.0, 1.0 / 3.0);
        sp.ng.dot((a + b + c) / 3.0 - center) > 0.0
    })
}

#[test]
fn rectangle_area_and_normal() {
    let s = shape_scene("rectangle", "");
    assert!((total_area(&s) - 4.0).abs() < 1e-5);
    for t in 0..s.triangles.len() as u32 {
        assert!(approx(s.surface_point(t, 0.2, 0.2).ng, Vec3::Z, 1e-6));
    }
    let (lo, hi) = s.bounds();
    assert_eq!(
        (lo, hi),
        (Vec3::new(-1.0, -1.0, 0.0), Vec3::new(1.0, 1.0, 0.0))
    );
    // uv follows Mitsuba: ((x+1)/2, (y+1)/2)
    let sp = s.surface_point(0, 0.0, 0.0);
    let p = sp.p;
    assert!(
        (sp.uv.x - 0.5 * (p.x + 1.0)).abs() < 1e-6 && (sp.uv.y - 0.5 * (p.y + 1.0)).abs() < 1e-6
    );
    // a shape without a bsdf gets Mitsuba's default, diffuse 0.5
    match &s.materials[s.shapes[0].material as usize] {
        Material::Diffuse {
            reflectance: Texture::Constant(c),
        } => assert_eq!(*c, Vec3::splat(0.5)),
        m => panic!("{m:?}"),
    }
}

#[test]
fn flip_normals_and_mirror() {
    let s =
        scene_of(r#"<shape type="rectangle"><boolean name="flip_normals" value="true"/></shape>"#);
    assert!(approx(s.surface_point(0, 0.2, 0.2).ng, -Vec3::Z, 1e-6));
    // a mirroring to_world: Mitsuba's analytic normal is the inverse transpose's (-z)
    let s = shape_scene("rectangle", r#"<scale z="-1"/>"#);
    assert!(approx(s.surface_point(0, 0.2, 0.2).ng, -Vec3::Z, 1e-6));
}

#[test]
fn cube_area_and_outward_normals() {
    let s = shape_scene("cube", "");
    assert_eq!(s.triangles.len(), 12);
    assert!((total_area(&s) - 24.0).abs() < 1e-4);
    assert!(outward(&s, Vec3::ZERO));
    let s = shape_scene(
        "cube",
        r#"<scale x="2" y="3" z="0.5"/><translate value="1, 2, 3"/>"#,
    );
    // a 4 × 6 × 1 box
    let want = 2.0 * (4.0 * 6.0 + 4.0 * 1.0 + 6.0 * 1.0);
    assert!((total_area(&s) - want).abs() < 1e-3, "{}", total_area(&s));
    assert!(outward(&s, Vec3::new(1.0, 2.0, 3.0)));
    assert!(!s.shapes[0].smooth);
}

#[test]
fn disk_area_and_normal() {
    let s = shape_scene("disk", "");
    // a polygon of 128 sides: π sin(2π/n)/(2π/n)
    let a = total_area(&s);
    assert!((a - PI).abs() < 2e-3 * PI, "{a}");
    for t in 0..s.triangles.len() as u32 {
        assert!(approx(s.surface_point(t, 0.2, 0.2).ng, Vec3::Z, 1e-5));
    }
    let s = shape_scene("disk", r#"<scale value="3"/>"#);
    assert!((total_area(&s) - 9.0 * PI).abs() < 2e-3 * 9.0 * PI);
}

#[test]
fn sphere_area_and_normals() {
    let s = shape_scene("sphere", "");
    let a = total_area(&s);
    assert!((a - 4.0 * PI).abs() < 5e-3 * 4.0 * PI, "{a}");
    assert!(outward(&s, Vec3::ZERO));
    assert!(s.shapes[0].smooth);

    let s = scene_of(
        r#"<shape type="sphere">
            <point name="center" x="1" y="2" z="3"/>
            <float name="radius" value="2"/>
           </shape>"#,
    );
    let c = Vec3::new(1.0, 2.0, 3.0);
    let a = total_area(&s);
    assert!((a - 16.0 * PI).abs() < 5e-3 * 16.0 * PI, "{a}");
    assert!(outward(&s, c));
    // smooth normals are the exact sphere normals
    for (p, n) in s.positions.iter().zip(&s.normals) {
        assert!(((*p - c).length() - 2.0).abs() < 1e-4);
        assert!(approx(*n, (*p - c).normalize(), 1e-4));
    }
    // to_world after center/radius, with a non-uniform scale: normals by the inverse transpose
    let s = scene_of(
        r#"<shape type="sphere"><transform name="to_world"><scale x="2"/></transform></shape>"#,
    );
    for (p, n) in s.positions.iter().zip(&s.normals) {
        // ellipsoid x²/4 + y² + z² = 1: gradient (x/4, y, z)
        let g = Vec3::new(p.x / 4.0, p.y, p.z).normalize();
        assert!(approx(*n, g, 1e-4), "{p} {n} {g}");
    }
}

// ---------------------------------------------------------------------------
// Transforms

fn camera_of(transform: &str) -> Mat4 {
    scene_of(&format!(
        r#"<sensor type="perspective"><transform name="to_world">{transform}</transform></sensor>
           <shape type="rectangle"/>"#
    ))
    .camera
    .to_world
}

#[test]
fn lookat_matches_mitsuba() {
    // dir = +x, up = +z: left = up × dir = +y, new up = dir × left = +z
    let m = camera_of(r#"<lookat origin="1, 2, 3" target="2, 2, 3" up="0, 0, 1"/>"#);
    let want = Mat4::from_cols(
        Vec3::Y.extend(0.0),
        Vec3::Z.extend(0.0),
        Vec3::X.extend(0.0),
        Vec3::new(1.0, 2.0, 3.0).extend(1.0),
    );
    assert!(m.abs_diff_eq(want, 1e-6), "{m}");
    // up not perpendicular to dir is orthogonalised
    let m = camera_of(r#"<lookat origin="0,0,0" target="0,0,5" up="0, 1, 1"/>"#);
    assert!(approx(m.x_axis.truncate(), Vec3::X, 1e-6));
    assert!(approx(m.y_axis.truncate(), Vec3::Y, 1e-6));
    assert!(approx(m.z_axis.truncate(), Vec3::Z, 1e-6));
}

#[test]
fn rotate_scale_translate_compose_in_order() {
    // rotation by 90° about x maps y to z and z to -y
    let s = shape_scene("rectangle", r#"<rotate x="1" angle="90"/>"#);
    assert!(approx(s.surface_point(0, 0.2, 0.2).ng, -Vec3::Y, 1e-6));
    assert!(s
        .positions
        .iter()
        .any(|p| approx(*p, Vec3::new(1.0, 0.0, 1.0), 1e-6)));
    // the `axis` attribute form
    let m = camera_of(r#"<rotate axis="0, 0, 1" angle="90"/>"#);
    assert!(approx(m.transform_vector3(Vec3::X), Vec3::Y, 1e-6));
    // each new operation applies after the earlier ones: 2p + (1,0,0)
    let m = camera_of(r#"<scale value="2"/><translate x="1"/>"#);
    assert!(approx(
        m.transform_point3(Vec3::ONE),
        Vec3::new(3.0, 2.0, 2.0),
        1e-6
    ));
    let m = camera_of(r#"<translate x="1"/><scale value="2"/>"#);
    assert!(approx(
        m.transform_point3(Vec3::ONE),
        Vec3::new(4.0, 2.0, 2.0),
        1e-6
    ));
    // matrices are row-major, 4×4 or 3×3
    let m = camera_of(r#"<matrix value="1 0 0 5  0 1 0 6  0 0 1 7  0 0 0 1"/>"#);
    assert!(approx(
        m.transform_point3(Vec3::ZERO),
        Vec3::new(5.0, 6.0, 7.0),
        1e-6
    ));
    let m = camera_of(r#"<matrix value="0 -1 0  1 0 0  0 0 1"/>"#);
    assert!(approx(m.transform_vector3(Vec3::X), Vec3::Y, 1e-6));
}

// ---------------------------------------------------------------------------
// Materials, defaults, references

#[test]
fn materials_defaults_and_refs() {
    let s = scene_of(
        r#"<default name="r" value="0.25"/>
           <shape type="rectangle"><ref id="later"/></shape>
           <bsdf type="roughconductor" id="later">
               <string name="material" value="Au"/>
               <float name="alpha" value="$r"/>
           </bsdf>
           <shape type="cube">
               <bsdf type="phong">
                   <rgb name="diffuse_reflectance" value="0.3"/>
                   <spectrum name="specular_reflectance" value="0.4"/>
                   <float name="exponent" value="12"/>
               </bsdf>
           </shape>
           <shape type="disk">
               <bsdf type="roughplastic">
                   <string name="int_ior" value="water"/>
                   <texture type="checkerboard" name="diffuse_reflectance"/>
               </bsdf>
           </shape>
           <shape type="disk"><bsdf type="dielectric"/></shape>
           <shape type="disk"><bsdf type="conductor"/></shape>
           <shape type="disk"><bsdf type="roughdielectric">
               <string name="distribution" value="ggx"/>
               <float name="alpha" value="0.3"/>
               <float name="int_ior" value="1.4"/>
               <rgb name="specular_transmittance" value="0.9, 0.8, 0.7"/>
           </bsdf></shape>
           <shape type="disk"><bsdf type="roughdielectric"/></shape>"#,
    );
    let mat = |i: usize| &s.materials[s.shapes[i].material as usize];
    match mat(0) {
        Material::RoughConductor {
            alpha,
            eta,
            distribution,
            ..
        } => {
            assert_eq!(*alpha, 0.25);
            assert!(eta.x < 0.2 && eta.z > 1.0);
            assert_eq!(*distribution, kalos::scene::MicrofacetKind::Beckmann);
        }
        m => panic!("{m:?}"),
    }
    match mat(1) {
        Material::Phong { exponent, .. } => assert_eq!(*exponent, 12.0),
        m => panic!("{m:?}"),
    }
    match mat(2) {
        Material::RoughPlastic {
            eta,
            diffuse_reflectance: Texture::Checkerboard { color0, color1, .. },
            ..
        } => {
            assert!((eta - 1.333 / 1.000277).abs() < 1e-5);
            assert_eq!((*color0, *color1), (Vec3::splat(0.4), Vec3::splat(0.2)));
        }
        m => panic!("{m:?}"),
    }
    match mat(3) {
        Material::Dielectric { eta, .. } => assert!((eta - 1.5046 / 1.000277).abs() < 1e-5),
        m => panic!("{m:?}"),
    }
    match mat(4) {
        Material::Conductor { eta, k, .. } => assert_eq!((*eta, *k), (Vec3::ZERO, Vec3::ONE)),
        m => panic!("{m:?}"),
    }
    match mat(5) {
        Material::RoughDielectric {
            distribution,
            alpha,
            eta,
            specular_transmittance: Texture::Constant(t),
            ..
        } => {
            assert_eq!(*distribution, kalos::scene::MicrofacetKind::Ggx);
            assert_eq!(*alpha, 0.3);
            assert!((eta - 1.4 / 1.000277).abs() < 1e-5, "{eta}");
            assert_eq!(*t, Vec3::new(0.9, 0.8, 0.7));
        }
        m => panic!("{m:?}"),
    }
    // Mitsuba's defaults: Beckmann, α = 0.1, bk7 in air
    match mat(6) {
        Material::RoughDielectric {
            distribution,
            alpha,
            eta,
            ..
        } => {
            assert_eq!(*distribution, kalos::scene::MicrofacetKind::Beckmann);
            assert_eq!(*alpha, 0.1);
            assert!((eta - 1.5046 / 1.000277).abs() < 1e-5, "{eta}");
        }
        m => panic!("{m:?}"),
    }
}

#[test]
fn spectra_to_rgb() {
    let s = scene_of(
        r#"<shape type="rectangle"><bsdf type="diffuse">
             <spectrum name="reflectance" value="360:0.5, 830:0.5"/>
           </bsdf></shape>
           <shape type="rectangle"><bsdf type="diffuse">
             <spectrum name="reflectance" value="400:0, 560:0, 600:1, 830:1"/>
           </bsdf></shape>"#,
    );
    let c = |i: usize| match &s.materials[s.shapes[i].material as usize] {
        Material::Diffuse {
            reflectance: Texture::Constant(c),
        } => *c,
        m => panic!("{m:?}"),
    };
    assert!(approx(c(0), Vec3::splat(0.5), 1e-4), "{}", c(0));
    // a red spectrum
    assert!(c(1).x > 0.8 && c(1).z < 0.05, "{}", c(1));
}

#[test]
fn textures_and_envmap_load_images() {
    let d = tmp("images");
    let mut img = image::RgbImage::new(2, 2);
    img.put_pixel(0, 0, image::Rgb([255, 0, 0])); // top left
    img.put_pixel(1, 1, image::Rgb([128, 128, 128]));
    img.save(d.join("tex.png")).unwrap();
    let xml = r#"<scene version="3.0.0">
        <shape type="rectangle"><bsdf type="diffuse">
            <texture type="bitmap" name="reflectance"><string name="filename" value="tex.png"/></texture>
        </bsdf></shape>
        <emitter type="envmap"><string name="filename" value="tex.png"/><float name="scale" value="2"/></emitter>
    </scene>"#;
    let path = d.join("tex.xml");
    std::fs::write(&path, xml).unwrap();
    let s = scene::load(&path).unwrap_or_else(|e| panic!("{e}"));
    let Material::Diffuse {
        reflectance: Texture::Bitmap { image, .. },
    } = &s.materials[s.shapes[0].material as usize]
    else {
        panic!("no bitmap")
    };
    // sRGB 128 is linear 0.2158
    assert!((image.pixel(3).x - 0.2158).abs() < 1e-3);
    // Mitsuba's uv (0, 0) is the top-left pixel
    let t = &s.materials[s.shapes[0].material as usize];
    if let Material::Diffuse { reflectance } = t {
        let c = reflectance.eval(glam::Vec2::new(0.25, 0.25));
        assert!(approx(c, Vec3::X, 1e-4), "{c}");
    }
    assert!(matches!(s.emitters[0], EmitterDesc::EnvMap { scale, .. } if scale == 2.0));
}

// ---------------------------------------------------------------------------
// PLY and OBJ

const QUAD: [[f32; 8]; 4] = [
    // x y z nx ny nz u v
    [0.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0],
    [1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 1.0, 0.0],
    [1.0, 1.0, 0.0, 0.0, 0.0, 1.0, 1.0, 1.0],
    [0.0, 1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 1.0],
];

fn ply_header(format: &str) -> String {
    format!(
        "ply\nformat {format} 1.0\ncomment made by a test\n\
         element material 1\nproperty list uchar int junk\nproperty float shine\n\
         element vertex 4\nproperty float x\nproperty float y\nproperty float z\n\
         property float nx\nproperty float ny\nproperty float nz\n\
         property float u\nproperty float v\nproperty uchar red\n\
         element face 1\nproperty uchar flags\nproperty list uchar int vertex_indices\n\
         end_header\n"
    )
}

fn binary_ply(le: bool) -> Vec<u8> {
    let mut b = ply_header(if le {
        "binary_little_endian"
    } else {
        "binary_big_endian"
    })
    .into_bytes();
    let i32b = |v: i32| if le { v.to_le_bytes() } else { v.to_be_bytes() };
    let f32b = |v: f32| if le { v.to_le_bytes() } else { v.to_be_bytes() };
    // material: a list of two ints and a float
    b.push(2);
    b.extend(i32b(7));
    b.extend(i32b(8));
    b.extend(f32b(0.5));
    for v in QUAD {
        for x in v {
            b.extend(f32b(x));
        }
        b.push(200);
    }
    b.push(0);
    b.push(4);
    for i in 0..4 {
        b.extend(i32b(i));
    }
    b
}

fn check_quad(m: &kalos::scene::MeshData) {
    assert_eq!(m.positions.len(), 4);
    assert_eq!(m.indices, vec![[0, 1, 2], [0, 2, 3]]);
    for (p, q) in m.positions.iter().zip(QUAD) {
        assert_eq!(*p, Vec3::new(q[0], q[1], q[2]));
    }
    assert_eq!(m.normals.as_ref().map(|n| n[2]), Some(Vec3::Z));
    assert_eq!(m.uvs.as_ref().map(|t| t[2]), Some(glam::Vec2::ONE));
    assert!((m.area() - 1.0).abs() < 1e-6);
}

#[test]
fn ply_ascii_and_binary_round_trip() {
    let d = tmp("ply");
    let mut ascii = ply_header("ascii");
    ascii += "2 7 8 0.5\n";
    for v in QUAD {
        let s: Vec<String> = v.iter().map(|x| x.to_string()).collect();
        ascii += &format!("{} 200\n", s.join(" "));
    }
    ascii += "0 4 0 1 2 3\n";
    std::fs::write(d.join("a.ply"), &ascii).unwrap();
    std::fs::write(d.join("le.ply"), binary_ply(true)).unwrap();
    std::fs::write(d.join("be.ply"), binary_ply(false)).unwrap();
    let access = scene::FileAccess::for_dir(&d, &Default::default()).unwrap();
    for f in ["a.ply", "le.ply", "be.ply"] {
        let m =
            kalos::scene::ply::load_ply(&d.join(f), &access).unwrap_or_else(|e| panic!("{f}: {e}"));
        check_quad(&m);
    }

    // in a scene, with a transform
    let xml = r#"<scene version="3.0.0"><shape type="ply">
        <string name="filename" value="le.ply"/>
        <transform name="to_world"><scale value="2"/></transform>
    </shape></scene>"#;
    std::fs::write(d.join("ply.xml"), xml).unwrap();
    let s = scene::load(&d.join("ply.xml")).unwrap_or_else(|e| panic!("{e}"));
    assert!((total_area(&s) - 4.0).abs() < 1e-5);
    assert!(s.shapes[0].smooth);
    // a standalone PLY is a scene too
    let s = scene::load(&d.join("be.ply")).unwrap_or_else(|e| panic!("{e}"));
    assert_eq!(s.triangles.len(), 2);

    // truncated files are errors naming the file
    let full = binary_ply(true);
    for cut in [full.len() - 3, full.len() - 20, 200] {
        let p = d.join("cut.ply");
        std::fs::write(&p, &full[..cut]).unwrap();
        let e = kalos::scene::ply::load_ply(&p, &access).unwrap_err();
        assert!(e.to_string().contains("cut.ply"), "{e}");
    }
    let p = d.join("cut.ply");
    std::fs::write(&p, &ascii[..ascii.len() - 4]).unwrap();
    assert!(kalos::scene::ply::load_ply(&p, &access).is_err());
}

#[test]
fn obj_as_scene_with_mtl() {
    let d = tmp("obj");
    std::fs::write(
        d.join("m.mtl"),
        "newmtl white\nKd 0.8 0.8 0.8\nnewmtl lamp\nKd 0 0 0\nKe 5 5 5\n",
    )
    .unwrap();
    std::fs::write(
        d.join("m.obj"),
        "mtllib m.mtl\no floor\nv -1 0 -1\nv 1 0 -1\nv 1 0 1\nv -1 0 1\nusemtl white\nf 1 4 3 2\n\
         o lamp\nv -0.1 1 -0.1\nv 0.1 1 -0.1\nv 0.1 1 0.1\nv -0.1 1 0.1\nusemtl lamp\nf 5 6 7 8\n",
    )
    .unwrap();
    let s = scene::load(&d.join("m.obj")).unwrap_or_else(|e| panic!("{e}"));
    assert_eq!(s.shapes.len(), 2);
    assert_eq!(s.triangles.len(), 4);
    assert_eq!(s.emitters.len(), 1);
    assert!(
        matches!(s.emitters[0], EmitterDesc::Area { radiance, .. } if radiance == Vec3::splat(5.0))
    );
    assert!(s.warnings.iter().any(|w| w.contains("camera")));
    // the synthesised camera sees the centre of the bounds
    let c = s.camera.to_world;
    let dir = c.z_axis.truncate();
    let to_center = (Vec3::new(0.0, 0.5, 0.0) - c.w_axis.truncate()).normalize();
    assert!(dir.dot(to_center) > 0.999);
}

// ---------------------------------------------------------------------------
// Errors: file, line, no panic

/// Writes `xml` to `<dir>/<name>` and loads it, expecting an error at `line`.
fn expect_error(name: &str, xml: &str, line: u32, needle: &str) {
    let d = tmp(&name.replace('.', "_"));
    let p = d.join(name);
    std::fs::write(&p, xml).unwrap();
    let e = match scene::load(&p) {
        Ok(_) => panic!("{name}: loaded without error"),
        Err(e) => e.to_string(),
    };
    assert!(
        e.contains(&format!("{name}:{line}:")),
        "{name}: wrong file or line: {e}"
    );
    assert!(
        e.to_lowercase().contains(&needle.to_lowercase()),
        "{name}: `{needle}` not in: {e}"
    );
}

#[test]
fn malformed_xml_names_file_and_line() {
    expect_error(
        "malformed.xml",
        "<scene version=\"3.0.0\">\n  <shape type=\"cube\">\n  </shap>\n</scene>\n",
        3,
        "malformed XML",
    );
}

#[test]
fn missing_mesh_names_the_file_and_line() {
    expect_error(
        "missing.xml",
        "<scene version=\"3.0.0\">\n\n  <shape type=\"obj\">\n    <string name=\"filename\" value=\"meshes/nothere.obj\"/>\n  </shape>\n</scene>\n",
        3,
        "nothere.obj",
    );
}

#[test]
fn unknown_plugin_is_an_error() {
    expect_error(
        "plugin.xml",
        "<scene version=\"3.0.0\">\n  <shape type=\"cube\"/>\n  <bsdf type=\"velvet\" id=\"v\"/>\n</scene>\n",
        3,
        "velvet",
    );
    expect_error(
        "point.xml",
        "<scene version=\"3.0.0\">\n  <emitter type=\"point\"/>\n</scene>\n",
        2,
        "point",
    );
    expect_error(
        "element.xml",
        "<scene version=\"3.0.0\">\n\n\n  <medium type=\"homogeneous\"/>\n</scene>\n",
        4,
        "medium",
    );
}

#[test]
fn bad_number_names_what_was_expected() {
    expect_error(
        "number.xml",
        "<scene version=\"3.0.0\">\n  <shape type=\"sphere\">\n    <float name=\"radius\" value=\"1.0x\"/>\n  </shape>\n</scene>\n",
        3,
        "expected a number",
    );
    expect_error(
        "rgb.xml",
        "<scene version=\"3.0.0\">\n  <bsdf type=\"diffuse\">\n\n    <rgb name=\"reflectance\" value=\"0.5, zero, 0.5\"/>\n  </bsdf>\n</scene>\n",
        4,
        "zero",
    );
}

#[test]
fn misspelt_parameter_is_an_error() {
    expect_error(
        "misspelt.xml",
        "<scene version=\"3.0.0\">\n  <bsdf type=\"diffuse\" id=\"a\">\n    <rgb name=\"reflectance\" value=\"0.5\"/>\n    <rgb name=\"reflectence\" value=\"0.5\"/>\n  </bsdf>\n</scene>\n",
        4,
        "reflectence",
    );
    expect_error(
        "sensor.xml",
        "<scene version=\"3.0.0\">\n  <sensor type=\"perspective\">\n    <float name=\"fox\" value=\"30\"/>\n  </sensor>\n</scene>\n",
        3,
        "fox",
    );
}

#[test]
fn references_and_includes_are_checked() {
    expect_error(
        "dangling.xml",
        "<scene version=\"3.0.0\">\n  <shape type=\"cube\">\n    <ref id=\"nobody\"/>\n  </shape>\n</scene>\n",
        3,
        "nobody",
    );
    let d = tmp("cycle");
    std::fs::write(
        d.join("a.xml"),
        "<scene version=\"3.0.0\">\n  <include filename=\"b.xml\"/>\n</scene>\n",
    )
    .unwrap();
    std::fs::write(
        d.join("b.xml"),
        "<scene version=\"3.0.0\">\n\n  <include filename=\"a.xml\"/>\n</scene>\n",
    )
    .unwrap();
    let e = scene::load(&d.join("a.xml")).unwrap_err().to_string();
    assert!(e.contains("b.xml:3:") && e.contains("cycle"), "{e}");
    // a self-referencing twosided
    expect_error(
        "selfref.xml",
        "<scene version=\"3.0.0\">\n  <bsdf type=\"twosided\" id=\"t\">\n    <ref id=\"t\"/>\n  </bsdf>\n</scene>\n",
        2,
        "cycle",
    );
}

#[test]
fn standard_parameters_are_accepted_silently() {
    let s = scene_of(
        r#"<sensor type="perspective">
             <float name="fov" value="45"/>
             <float name="far_clip" value="100"/>
             <float name="focus_distance" value="3"/>
             <sampler type="independent"><integer name="sample_count" value="16"/></sampler>
             <film type="hdrfilm">
               <integer name="width" value="64"/><integer name="height" value="32"/>
               <string name="pixel_format" value="rgb"/>
               <string name="component_format" value="float32"/>
               <string name="file_format" value="openexr"/>
               <rfilter type="gaussian"/>
             </film>
           </sensor>
           <shape type="rectangle"/>"#,
    );
    assert_eq!((s.camera.width, s.camera.height), (64, 32));
    assert!((s.camera.fov_x_deg - 45.0).abs() < 1e-4);
    assert!(s.warnings.iter().any(|w| w.contains("gaussian")));
}

// ---------------------------------------------------------------------------
// Garbage never panics

const PIECES: &[&str] = &[
    "<scene version=\"3.0.0\">",
    "</scene>",
    "<shape type=\"cube\">",
    "<shape type=\"sphere\">",
    "<shape type=\"obj\">",
    "</shape>",
    "<bsdf type=\"twosided\" id=\"a\">",
    "<bsdf type=\"diffuse\">",
    "</bsdf>",
    "<ref id=\"a\"/>",
    "<emitter type=\"area\"><rgb name=\"radiance\" value=\"1\"/></emitter>",
    "<transform name=\"to_world\">",
    "</transform>",
    "<matrix value=\"1 2 3\"/>",
    "<lookat origin=\"0,0,0\" target=\"0,0,0\"/>",
    "<rotate angle=\"90\"/>",
    "<scale value=\"0\"/>",
    "<float name=\"radius\" value=\"nan\"/>",
    "<string name=\"filename\" value=\"$x\"/>",
    "<default name=\"x\" value=\"$x$x\"/>",
    "<include filename=\"nothere.xml\"/>",
    "<sensor type=\"perspective\">",
    "</sensor>",
    "<film type=\"hdrfilm\"><integer name=\"width\" value=\"0\"/></film>",
    "<spectrum name=\"reflectance\" value=\"500:1, 400:2\"/>",
    "<texture type=\"checkerboard\" name=\"reflectance\"/>",
    "&amp;",
    "<!-- c -->",
    "<",
    ">",
    "\"",
];

fn load_garbage(xml: &str) {
    // only the result matters: Ok or Err, never a panic
    let _ = scene::load_str(xml, Path::new("/nonexistent-kalos-dir"), "garbage.xml");
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 200, ..ProptestConfig::default() })]

    #[test]
    fn random_bytes_never_panic(bytes in proptest::collection::vec(any::<u8>(), 0..400)) {
        load_garbage(&String::from_utf8_lossy(&bytes));
    }

    #[test]
    fn xml_like_garbage_never_panics(idx in proptest::collection::vec(0..PIECES.len(), 0..40)) {
        let s: String = idx.iter().map(|&i| PIECES[i]).collect();
        load_garbage(&s);
        load_garbage(&format!("<scene version=\"3.0.0\">{s}</scene>"));
    }

    #[test]
    fn ply_garbage_never_panics(bytes in proptest::collection::vec(any::<u8>(), 0..300), ascii in any::<bool>()) {
        let mut b = ply_header(if ascii { "ascii" } else { "binary_big_endian" }).into_bytes();
        b.extend(bytes);
        let _ = kalos::scene::ply::parse_ply(&b, Path::new("g.ply"));
    }
}
