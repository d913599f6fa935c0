//! Untrusted Mitsuba and pbrt-v4 scenes (issue #36): every file a scene
//! names is read through the scene's file access. A file outside the
//! scene's folder (an `<include>`, an `Include`, a mesh through a symbolic
//! link, an image or spectrum by absolute path), a device or a FIFO ends
//! in an error within a second that names the file, the scene file and
//! line that named it, and the fix (`--allow-read DIR`); the same scene
//! with the file inside its folder loads, and `--allow-read` (`allow_read`
//! of [`ReadPolicy`]) admits the outside folder. The scene's memory is
//! declared before it is taken: images from their headers, pbrt meshes
//! and instance copies before the scene's copy is made.

use std::path::{Path, PathBuf};
use std::sync::mpsc;
use std::time::Duration;

use kalos::scene::{self, LoadOptions, ReadPolicy, Scene, SceneError};

use crate::common::{kalos, stderr};

/// A scene folder `scene/` and a folder beside it, `outside/`, holding a
/// file the scene must not read unless allowed.
struct Dirs {
    _root: tempfile::TempDir,
    scene: PathBuf,
    outside: PathBuf,
}

fn dirs() -> Dirs {
    let root = tempfile::Builder::new()
        .prefix("kalos-untrusted-mp-")
        .tempdir()
        .unwrap();
    let scene = root.path().join("scene");
    let outside = root.path().join("outside");
    std::fs::create_dir_all(&scene).unwrap();
    std::fs::create_dir_all(&outside).unwrap();
    Dirs {
        _root: root,
        scene,
        outside,
    }
}

/// Loads `path` with `allow` as the extra readable folders, on a thread,
/// and fails the test (rather than hang it) when the load takes more than
/// a second: a FIFO opened for reading would block for ever.
fn load_within_a_second(path: &Path, allow: &[&Path]) -> Result<Scene, SceneError> {
    let path = path.to_path_buf();
    let opts = LoadOptions {
        read: ReadPolicy {
            allow_read: allow.iter().map(|p| p.to_path_buf()).collect(),
            ..Default::default()
        },
        ..Default::default()
    };
    let (tx, rx) = mpsc::channel();
    std::thread::spawn(move || {
        let _ = tx.send(scene::load_opts(&path, &opts));
    });
    rx.recv_timeout(Duration::from_secs(1))
        .expect("the load ends within a second")
}

fn load_with_memory(path: &Path, limit: u64) -> Result<Scene, SceneError> {
    let opts = LoadOptions {
        read: ReadPolicy {
            memory_limit: Some((limit, "--max-memory".into())),
            ..Default::default()
        },
        ..Default::default()
    };
    scene::load_opts(path, &opts)
}

/// The error of a load that must fail.
fn refused(path: &Path, allow: &[&Path]) -> SceneError {
    match load_within_a_second(path, allow) {
        Ok(_) => panic!("{} loaded, but should be refused", path.display()),
        Err(e) => e,
    }
}

/// Asserts that `e` is at `file:line` and names every one of `words`.
fn assert_names(e: &SceneError, file: &Path, line: u32, words: &[&str]) {
    let msg = e.to_string();
    assert!(
        e.file == file && e.line == line,
        "expected {}:{line}, got {msg}",
        file.display()
    );
    for w in words {
        assert!(msg.contains(w), "`{w}` missing from: {msg}");
    }
}

fn write(path: &Path, text: impl AsRef<[u8]>) {
    std::fs::write(path, text).unwrap();
}

fn mkfifo(path: &Path) -> bool {
    std::process::Command::new("mkfifo")
        .arg(path)
        .status()
        .is_ok_and(|s| s.success())
}

/// A Mitsuba scene with a camera-less body.
fn xml(body: &str) -> String {
    format!("<scene version=\"3.0.0\">\n{body}\n</scene>\n")
}

const MITSUBA_PART: &str = r#"<scene version="3.0.0">
    <shape type="rectangle"><emitter type="area"><rgb name="radiance" value="1"/></emitter></shape>
</scene>"#;

const PLY: &str = "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\n\
                   property float z\nelement face 1\nproperty list uchar int vertex_indices\n\
                   end_header\n0 0 0\n2 0 0\n0 2 0\n3 0 1 2\n";

/// A 16×16 PNG.
fn png() -> Vec<u8> {
    let mut bytes = Vec::new();
    image::RgbImage::from_pixel(16, 16, image::Rgb([200, 100, 50]))
        .write_to(
            &mut std::io::Cursor::new(&mut bytes),
            image::ImageFormat::Png,
        )
        .unwrap();
    bytes
}

#[test]
fn mitsuba_include_outside_the_folder_is_refused_until_allowed() {
    let d = dirs();
    write(&d.outside.join("part.xml"), MITSUBA_PART);
    write(&d.scene.join("part.xml"), MITSUBA_PART);
    let main = d.scene.join("main.xml");
    write(&main, xml(r#"<include filename="../outside/part.xml"/>"#));
    let e = refused(&main, &[]);
    assert_names(
        &e,
        &main,
        2,
        &["../outside/part.xml", "--allow-read", "outside"],
    );
    // an absolute path is held to the same folders
    let abs = format!(
        r#"<include filename="{}"/>"#,
        d.outside.join("part.xml").display()
    );
    write(&main, xml(&abs));
    let e = refused(&main, &[]);
    assert_names(&e, &main, 2, &["part.xml", "--allow-read"]);
    // --allow-read admits it
    let s = load_within_a_second(&main, &[&d.outside]).unwrap();
    assert_eq!(s.triangles.len(), 2);
    // the same scene with the file inside its folder loads
    write(&main, xml(r#"<include filename="part.xml"/>"#));
    let s = load_within_a_second(&main, &[]).unwrap();
    assert_eq!(s.triangles.len(), 2);
}

#[cfg(unix)]
#[test]
fn mitsuba_mesh_through_a_symlink_out_of_the_folder_is_refused_until_allowed() {
    let d = dirs();
    write(&d.outside.join("secret.ply"), PLY);
    std::os::unix::fs::symlink(d.outside.join("secret.ply"), d.scene.join("mesh.ply")).unwrap();
    let main = d.scene.join("main.xml");
    write(
        &main,
        xml(r#"<shape type="ply"><string name="filename" value="mesh.ply"/></shape>"#),
    );
    let e = refused(&main, &[]);
    assert_names(
        &e,
        &main,
        2,
        &["mesh file `mesh.ply`", "secret.ply", "--allow-read"],
    );
    let s = load_within_a_second(&main, &[&d.outside]).unwrap();
    assert_eq!(s.triangles.len(), 1);
    // the mesh itself inside the folder loads
    std::fs::remove_file(d.scene.join("mesh.ply")).unwrap();
    write(&d.scene.join("mesh.ply"), PLY);
    let s = load_within_a_second(&main, &[]).unwrap();
    assert_eq!(s.triangles.len(), 1);
}

#[test]
fn mitsuba_texture_by_absolute_path_outside_is_refused_until_allowed() {
    let d = dirs();
    write(&d.outside.join("secret.png"), png());
    let main = d.scene.join("main.xml");
    let body = |file: &str| {
        xml(&format!(
            r#"<shape type="rectangle">
    <bsdf type="diffuse"><texture type="bitmap" name="reflectance"><string name="filename" value="{file}"/></texture></bsdf>
</shape>
<emitter type="constant"/>"#
        ))
    };
    let secret = d.outside.join("secret.png");
    write(&main, body(&secret.display().to_string()));
    let e = refused(&main, &[]);
    assert_names(&e, &main, 3, &["image file", "secret.png", "--allow-read"]);
    assert!(load_within_a_second(&main, &[&d.outside]).is_ok());
    write(&d.scene.join("tex.png"), png());
    write(&main, body("tex.png"));
    let s = load_within_a_second(&main, &[]).unwrap();
    assert_eq!(s.triangles.len(), 2);
}

#[cfg(unix)]
#[test]
fn mitsuba_devices_and_fifos_are_refused_without_reading() {
    let d = dirs();
    let main = d.scene.join("main.xml");
    // /dev/zero: outside the folder, and not a regular file when allowed
    write(
        &main,
        xml(r#"<shape type="ply"><string name="filename" value="/dev/zero"/></shape>"#),
    );
    let e = refused(&main, &[]);
    assert_names(&e, &main, 2, &["/dev/zero", "--allow-read"]);
    let e = refused(&main, &[Path::new("/dev")]);
    assert_names(&e, &main, 2, &["/dev/zero", "character device"]);
    // a FIFO inside the folder, as an include and as an image
    if mkfifo(&d.scene.join("pipe.xml")) {
        write(&main, xml(r#"<include filename="pipe.xml"/>"#));
        let e = refused(&main, &[]);
        assert_names(&e, &main, 2, &["pipe.xml", "FIFO"]);
    }
    if mkfifo(&d.scene.join("pipe.png")) {
        write(
            &main,
            xml(r#"<emitter type="envmap"><string name="filename" value="pipe.png"/></emitter>"#),
        );
        let e = refused(&main, &[]);
        assert_names(&e, &main, 2, &["pipe.png", "FIFO"]);
    }
}

#[test]
fn mitsuba_missing_files_still_say_where_they_were_looked_for() {
    let d = dirs();
    let main = d.scene.join("main.xml");
    write(&main, xml(r#"<include filename="nowhere.xml"/>"#));
    let e = refused(&main, &[]);
    assert_names(
        &e,
        &main,
        2,
        &["included file `nowhere.xml` not found", "looked for"],
    );
    write(
        &main,
        xml(r#"<shape type="obj"><string name="filename" value="nowhere.obj"/></shape>"#),
    );
    let e = refused(&main, &[]);
    assert_names(&e, &main, 2, &["mesh file `nowhere.obj` not found"]);
}

#[test]
fn mitsuba_image_memory_is_declared_from_its_header() {
    let d = dirs();
    write(&d.scene.join("tex.png"), png());
    let main = d.scene.join("main.xml");
    write(
        &main,
        xml(r#"<emitter type="envmap"><string name="filename" value="tex.png"/></emitter>"#),
    );
    // 16 × 16 linear RGB texels of 12 bytes: 3 KiB
    let e = load_with_memory(&main, 1000).unwrap_err();
    assert_names(&e, &main, 2, &["image `tex.png` (16×16)", "--max-memory"]);
    assert!(load_with_memory(&main, 1 << 20).is_ok());
}

#[cfg(unix)]
#[test]
fn a_scene_file_that_is_a_symlink_is_read() {
    // the user named the file: it is read wherever it lies, and what it
    // names resolves against the link's folder
    let d = dirs();
    write(
        &d.outside.join("real.xml"),
        xml(r#"<include filename="part.xml"/>"#),
    );
    write(&d.scene.join("part.xml"), MITSUBA_PART);
    let link = d.scene.join("main.xml");
    std::os::unix::fs::symlink(d.outside.join("real.xml"), &link).unwrap();
    let s = load_within_a_second(&link, &[]).unwrap();
    assert_eq!(s.triangles.len(), 2);
}

/// A pbrt scene with an environment light; `body` follows `WorldBegin`.
fn world(body: &str) -> String {
    format!("WorldBegin\nLightSource \"infinite\" \"rgb L\" [1 1 1]\n{body}\n")
}

const TRIANGLE: &str =
    r#"Shape "trianglemesh" "point3 P" [0 0 0  1 0 0  0 1 0] "integer indices" [0 1 2]"#;

#[test]
fn pbrt_include_outside_the_folder_is_refused_until_allowed() {
    let d = dirs();
    write(&d.outside.join("geo.pbrt"), TRIANGLE);
    write(&d.scene.join("geo.pbrt"), TRIANGLE);
    let main = d.scene.join("main.pbrt");
    write(&main, world("Include \"../outside/geo.pbrt\""));
    let e = refused(&main, &[]);
    assert_names(
        &e,
        &main,
        3,
        &["../outside/geo.pbrt", "--allow-read", "outside"],
    );
    write(&main, world("Import \"../outside/geo.pbrt\""));
    let e = refused(&main, &[]);
    assert_names(&e, &main, 3, &["Import", "--allow-read"]);
    let s = load_within_a_second(&main, &[&d.outside]).unwrap();
    assert_eq!(s.triangles.len(), 1);
    write(&main, world("Include \"geo.pbrt\""));
    let s = load_within_a_second(&main, &[]).unwrap();
    assert_eq!(s.triangles.len(), 1);
}

#[cfg(unix)]
#[test]
fn pbrt_mesh_through_a_symlink_and_files_by_absolute_path_are_refused() {
    let d = dirs();
    write(&d.outside.join("secret.ply"), PLY);
    write(&d.outside.join("secret.png"), png());
    write(&d.outside.join("secret.spd"), "400 0.5 700 0.5\n");
    std::os::unix::fs::symlink(d.outside.join("secret.ply"), d.scene.join("mesh.ply")).unwrap();
    let main = d.scene.join("main.pbrt");
    let cases = [
        (
            "Shape \"plymesh\" \"string filename\" \"mesh.ply\"".to_string(),
            "PLY file `mesh.ply`",
        ),
        (
            format!(
                "Texture \"t\" \"spectrum\" \"imagemap\" \"string filename\" \"{}\"",
                d.outside.join("secret.png").display()
            ),
            "image file",
        ),
        (
            format!(
                "Material \"diffuse\" \"spectrum reflectance\" \"{}\"\n{TRIANGLE}",
                d.outside.join("secret.spd").display()
            ),
            "spectrum file",
        ),
    ];
    for (body, what) in &cases {
        write(&main, world(body));
        let e = refused(&main, &[]);
        assert_names(&e, &main, 3, &[what, "secret", "--allow-read"]);
        load_within_a_second(&main, &[&d.outside])
            .unwrap_or_else(|e| panic!("allowed, `{body}` gave {e}"));
    }
}

#[cfg(unix)]
#[test]
fn pbrt_devices_and_fifos_are_refused_without_reading() {
    let d = dirs();
    let main = d.scene.join("main.pbrt");
    write(
        &main,
        world("Shape \"plymesh\" \"string filename\" \"/dev/zero\""),
    );
    let e = refused(&main, &[Path::new("/dev")]);
    assert_names(&e, &main, 3, &["/dev/zero", "character device"]);
    if mkfifo(&d.scene.join("pipe.pbrt")) {
        write(&main, world("Include \"pipe.pbrt\""));
        let e = refused(&main, &[]);
        assert_names(&e, &main, 3, &["pipe.pbrt", "FIFO"]);
    }
    if mkfifo(&d.scene.join("pipe.spd")) {
        write(
            &main,
            world(&format!(
                "Material \"diffuse\" \"spectrum reflectance\" \"pipe.spd\"\n{TRIANGLE}"
            )),
        );
        let e = refused(&main, &[]);
        assert_names(&e, &main, 3, &["pipe.spd", "FIFO"]);
    }
}

#[test]
fn pbrt_instances_and_images_are_declared_before_they_are_made() {
    let d = dirs();
    let main = d.scene.join("main.pbrt");
    // an object of one triangle placed 1000 times: 1000 copies
    let mut body = format!("ObjectBegin \"tri\"\n{TRIANGLE}\nObjectEnd\n");
    for i in 0..1000 {
        body +=
            &format!("AttributeBegin\nTranslate {i} 0 0\nObjectInstance \"tri\"\nAttributeEnd\n");
    }
    write(&main, world(&body));
    let s = load_with_memory(&main, 1 << 20).unwrap();
    assert_eq!(s.triangles.len(), 1000);
    // each copy takes 3 vertices of 32 bytes and a triangle of 16: 112
    // bytes, so 20,000 bytes stop it near the 180th copy
    let e = load_with_memory(&main, 20_000).unwrap_err();
    assert!(e.file == main && e.msg.contains("--max-memory"), "{e}");
    assert!(e.msg.contains("triangles"), "{e}");

    write(&d.scene.join("sky.png"), png());
    write(
        &main,
        "WorldBegin\nLightSource \"infinite\" \"string filename\" \"sky.png\"\n",
    );
    let e = load_with_memory(&main, 1000).unwrap_err();
    assert_names(&e, &main, 2, &["image `sky.png` (16×16)", "--max-memory"]);
    assert!(load_with_memory(&main, 1 << 20).is_ok());
}

#[test]
fn cli_info_refuses_an_outside_include_and_allow_read_admits_it() {
    let d = dirs();
    write(&d.outside.join("part.xml"), MITSUBA_PART);
    let main = d.scene.join("main.xml");
    write(&main, xml(r#"<include filename="../outside/part.xml"/>"#));
    let scene = main.to_str().unwrap();
    let out = kalos(&["info", scene]);
    assert_eq!(out.status.code(), Some(1), "{}", stderr(&out));
    let err = stderr(&out);
    assert!(
        err.contains("main.xml:2") && err.contains("part.xml") && err.contains("--allow-read"),
        "{err}"
    );
    let out = kalos(&["info", scene, "--allow-read", d.outside.to_str().unwrap()]);
    assert!(out.status.success(), "{}", stderr(&out));

    write(&d.outside.join("geo.pbrt"), TRIANGLE);
    let main = d.scene.join("main.pbrt");
    write(&main, world("Include \"../outside/geo.pbrt\""));
    let scene = main.to_str().unwrap();
    let out = kalos(&["info", scene]);
    assert_eq!(out.status.code(), Some(1), "{}", stderr(&out));
    let err = stderr(&out);
    assert!(
        err.contains("main.pbrt:3") && err.contains("geo.pbrt") && err.contains("--allow-read"),
        "{err}"
    );
    let out = kalos(&["info", scene, "--allow-read", d.outside.to_str().unwrap()]);
    assert!(out.status.success(), "{}", stderr(&out));
}
