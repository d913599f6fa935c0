//! Untrusted glTF, OBJ and PLY files (issue 36): a file may read only
//! regular files under its own folder and the `--allow-read` folders, and
//! its meshes and images may take only the memory the limit gives. Each
//! crafted case ends in a clear error within a second, naming the file and
//! the fix; the same scene with its files inside the folder (or the folder
//! allowed) loads.

use crate::common::kalos;
use std::path::{Path, PathBuf};
use std::sync::mpsc;
use std::time::{Duration, Instant};

use kalos::scene::{self, FileAccess, LoadOptions, Material, ReadPolicy, Scene, Texture};

/// A fresh temporary folder, removed when dropped.
fn tmp() -> tempfile::TempDir {
    tempfile::Builder::new()
        .prefix("kalos-untrusted-")
        .tempdir()
        .unwrap()
}

/// Loads `path`, the folders `allow` readable too, with an optional memory
/// limit (bytes), on another thread: a load that blocks fails the test
/// after 10 s instead of hanging it, and one that answers later than a
/// second fails it too.
fn load(path: &Path, allow: &[&Path], memory: Option<u64>) -> Result<Scene, String> {
    let opts = LoadOptions {
        read: ReadPolicy {
            allow_read: allow.iter().map(|p| p.to_path_buf()).collect(),
            memory_limit: memory.map(|m| (m, "--max-memory".to_string())),
        },
        ..Default::default()
    };
    let path = path.to_path_buf();
    let (tx, rx) = mpsc::channel();
    let start = Instant::now();
    std::thread::spawn(move || {
        let _ = tx.send(scene::load_opts(&path, &opts).map_err(|e| e.to_string()));
    });
    let r = rx
        .recv_timeout(Duration::from_secs(10))
        .expect("the load blocked: no answer in 10 s");
    let took = start.elapsed();
    assert!(took < Duration::from_secs(1), "the load took {took:?}");
    r
}

/// The error of loading `path` (which must fail), checked to hold every
/// needle.
fn refused(path: &Path, allow: &[&Path], memory: Option<u64>, needles: &[&str]) -> String {
    let e = match load(path, allow, memory) {
        Ok(s) => panic!(
            "{}: loaded ({} triangles), expected an error",
            path.display(),
            s.triangles.len()
        ),
        Err(e) => e,
    };
    for n in needles {
        assert!(e.contains(n), "`{n}` not in: {e}");
    }
    e
}

/// A one-triangle glTF mesh: positions then uvs, 60 bytes.
fn triangle_bin() -> Vec<u8> {
    let mut bin = Vec::new();
    for v in [0.0f32, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0, 0.0] {
        bin.extend(v.to_le_bytes());
    }
    for v in [0.0f32, 0.0, 1.0, 0.0, 0.0, 1.0] {
        bin.extend(v.to_le_bytes());
    }
    bin
}

/// A glTF file `name` in `dir` holding one triangle from buffer `buffer`
/// (a URI), textured by the image `image` (a JSON object) when given, and
/// listing the images `extra` (JSON objects) besides.
fn gltf(dir: &Path, name: &str, buffer: &str, image: Option<&str>, extra: &[&str]) -> PathBuf {
    let (material, textures) = match image {
        Some(_) => (
            r#"[{"pbrMetallicRoughness":{"metallicFactor":0,"baseColorTexture":{"index":0}}}]"#,
            r#"[{"source":0}]"#,
        ),
        None => ("[{}]", "[]"),
    };
    let images: Vec<&str> = image.into_iter().chain(extra.iter().copied()).collect();
    let json = format!(
        r#"{{"asset":{{"version":"2.0"}},"scene":0,"scenes":[{{"nodes":[0]}}],
"nodes":[{{"mesh":0}}],
"meshes":[{{"primitives":[{{"attributes":{{"POSITION":0,"TEXCOORD_0":1}},"material":0}}]}}],
"materials":{material},
"textures":{textures},
"images":[{}],
"accessors":[{{"bufferView":0,"componentType":5126,"count":3,"type":"VEC3",
               "min":[0,0,0],"max":[1,1,0]}},
             {{"bufferView":1,"componentType":5126,"count":3,"type":"VEC2"}}],
"bufferViews":[{{"buffer":0,"byteOffset":0,"byteLength":36}},
               {{"buffer":0,"byteOffset":36,"byteLength":24}}],
"buffers":[{{"byteLength":60,
  "uri":"{buffer}"}}]}}"#,
        images.join(",")
    );
    let p = dir.join(name);
    std::fs::write(&p, json).unwrap();
    p
}

/// A 2×2 PNG, each texel a different colour.
fn png() -> Vec<u8> {
    let img = image::RgbImage::from_raw(2, 2, vec![255, 0, 0, 0, 255, 0, 0, 0, 255, 255, 255, 0])
        .unwrap();
    let mut out = std::io::Cursor::new(Vec::new());
    img.write_to(&mut out, image::ImageFormat::Png).unwrap();
    out.into_inner()
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

/// The texels of the scene's first material's base colour texture.
fn texels(s: &Scene) -> Vec<glam::Vec3> {
    match s.materials[0].diffuse_texture() {
        Some(Texture::Bitmap { image, .. }) => image.pixels().collect(),
        _ => panic!("not a textured material: {:?}", s.materials[0]),
    }
}

#[cfg(unix)]
fn mkfifo(p: &Path) -> bool {
    std::process::Command::new("mkfifo")
        .arg(p)
        .status()
        .is_ok_and(|s| s.success())
}

// ---------------------------------------------------------------------------
// glTF buffers

#[cfg(unix)]
#[test]
fn a_gltf_buffer_at_dev_zero_is_refused_at_once() {
    let d = tmp();
    std::fs::write(d.path().join("tri.bin"), triangle_bin()).unwrap();
    let p = gltf(d.path(), "zero.gltf", "/dev/zero", None, &[]);
    // outside the folder: refused, naming the scene file, its line, the
    // file and the fix
    let e = refused(
        &p,
        &[],
        None,
        &["zero.gltf:", "buffer 0", "/dev/zero", "--allow-read /dev"],
    );
    assert!(e.contains("zero.gltf:13:"), "not the uri's line: {e}");
    // allowed, it is still a device, refused without being read
    refused(
        &p,
        &[Path::new("/dev")],
        None,
        &["/dev/zero", "character device", "not a regular file"],
    );
    // the same scene with its buffer inside the folder loads
    let p = gltf(d.path(), "good.gltf", "tri.bin", None, &[]);
    assert_eq!(load(&p, &[], None).unwrap().triangles.len(), 1);
}

#[cfg(unix)]
#[test]
fn a_gltf_buffer_that_is_a_fifo_is_refused_without_blocking() {
    let d = tmp();
    let scene_dir = d.path().join("scene");
    let other = d.path().join("other");
    std::fs::create_dir_all(&scene_dir).unwrap();
    std::fs::create_dir_all(&other).unwrap();
    if !(mkfifo(&scene_dir.join("pipe.bin")) && mkfifo(&other.join("x"))) {
        eprintln!("skipped: no mkfifo");
        return;
    }
    // inside the folder
    let p = gltf(&scene_dir, "in.gltf", "pipe.bin", None, &[]);
    refused(&p, &[], None, &["in.gltf", "pipe.bin", "FIFO"]);
    // `../other/x`, outside until allowed, then refused as a FIFO
    let p = gltf(&scene_dir, "up.gltf", "../other/x", None, &[]);
    refused(&p, &[], None, &["up.gltf", "../other/x", "--allow-read"]);
    refused(
        &p,
        &[&other],
        None,
        &["up.gltf", "FIFO", "not a regular file"],
    );
    // a regular file in its place loads
    std::fs::remove_file(other.join("x")).unwrap();
    std::fs::write(other.join("x"), triangle_bin()).unwrap();
    assert_eq!(load(&p, &[&other], None).unwrap().triangles.len(), 1);
}

#[test]
fn gltf_uris_in_other_schemes_are_errors() {
    let d = tmp();
    let p = gltf(
        d.path(),
        "http.gltf",
        "http://example.com/tri.bin",
        None,
        &[],
    );
    refused(
        &p,
        &[],
        None,
        &["http.gltf", "buffer 0", "unsupported URI scheme"],
    );
    let p = gltf(d.path(), "bad64.gltf", "data:;base64,AA*A", None, &[]);
    refused(&p, &[], None, &["bad64.gltf", "not a base64 digit"]);
}

// ---------------------------------------------------------------------------
// glTF images

#[test]
fn gltf_images_outside_the_folder_are_refused_until_allowed() {
    let d = tmp();
    let scene_dir = d.path().join("scene");
    let outside = d.path().join("outside");
    std::fs::create_dir_all(&scene_dir).unwrap();
    std::fs::create_dir_all(&outside).unwrap();
    std::fs::write(scene_dir.join("tri.bin"), triangle_bin()).unwrap();
    std::fs::write(outside.join("secret.png"), png()).unwrap();
    std::fs::write(scene_dir.join("tex.png"), png()).unwrap();

    // the image inside the folder loads, as the texture
    let p = gltf(
        &scene_dir,
        "in.gltf",
        "tri.bin",
        Some(r#"{"uri":"tex.png"}"#),
        &[],
    );
    let inside = texels(&load(&p, &[], None).unwrap());
    assert_eq!(inside.len(), 4);

    // `../outside/secret.png`: refused, then read once its folder is allowed
    let p = gltf(
        &scene_dir,
        "rel.gltf",
        "tri.bin",
        Some(r#"{"uri":"../outside/secret.png"}"#),
        &[],
    );
    refused(
        &p,
        &[],
        None,
        &["rel.gltf", "image 0", "secret.png", "--allow-read"],
    );
    assert_eq!(texels(&load(&p, &[&outside], None).unwrap()), inside);

    // an absolute path, the same
    let abs = outside.join("secret.png");
    let image = format!(r#"{{"uri":"{}"}}"#, abs.display());
    let p = gltf(&scene_dir, "abs.gltf", "tri.bin", Some(&image), &[]);
    refused(&p, &[], None, &["abs.gltf", "secret.png", "--allow-read"]);
    assert_eq!(texels(&load(&p, &[&outside], None).unwrap()), inside);
    // and as a file: URI
    let image = format!(r#"{{"uri":"file://{}"}}"#, abs.display());
    let p = gltf(&scene_dir, "file.gltf", "tri.bin", Some(&image), &[]);
    refused(&p, &[], None, &["file.gltf", "secret.png", "--allow-read"]);

    // an image no material uses is not read, but still checked
    let p = gltf(
        &scene_dir,
        "unused.gltf",
        "tri.bin",
        None,
        &[r#"{"uri":"../outside/secret.png"}"#],
    );
    refused(&p, &[], None, &["unused.gltf", "image 0", "secret.png"]);
    assert_eq!(load(&p, &[&outside], None).unwrap().triangles.len(), 1);
}

#[test]
fn gltf_data_uris_buffer_views_and_escaped_names_load_the_same() {
    let d = tmp();
    let bin = triangle_bin();
    std::fs::write(d.path().join("tri.bin"), &bin).unwrap();
    std::fs::write(d.path().join("my tex.png"), png()).unwrap();
    let from_file = {
        let p = gltf(
            d.path(),
            "file.gltf",
            "tri.bin",
            Some(r#"{"uri":"my%20tex.png"}"#),
            &[],
        );
        texels(&load(&p, &[], None).unwrap())
    };
    // buffer and image as data: URIs
    let image = format!(r#"{{"uri":"data:image/png;base64,{}"}}"#, base64(&png()));
    let buffer = format!("data:application/octet-stream;base64,{}", base64(&bin));
    let p = gltf(d.path(), "data.gltf", &buffer, Some(&image), &[]);
    let s = load(&p, &[], None).unwrap();
    assert_eq!(s.triangles.len(), 1);
    assert_eq!(texels(&s), from_file);
    // the image in a buffer view of a second buffer
    let png = png();
    let json = std::fs::read_to_string(d.path().join("file.gltf")).unwrap();
    let json = json
        .replace(
            r#""images":[{"uri":"my%20tex.png"}]"#,
            r#""images":[{"bufferView":2,"mimeType":"image/png"}]"#,
        )
        .replace(
            r#"{"buffer":0,"byteOffset":36,"byteLength":24}]"#,
            &format!(
                r#"{{"buffer":0,"byteOffset":36,"byteLength":24}},
                   {{"buffer":1,"byteOffset":0,"byteLength":{}}}]"#,
                png.len()
            ),
        )
        .replace(
            r#""uri":"tri.bin"}]"#,
            &format!(
                r#""uri":"tri.bin"}},{{"byteLength":{},"uri":"tex%2Ebin"}}]"#,
                png.len()
            ),
        );
    std::fs::write(d.path().join("tex.bin"), &png).unwrap();
    let p = d.path().join("view.gltf");
    std::fs::write(&p, json).unwrap();
    assert_eq!(texels(&load(&p, &[], None).unwrap()), from_file);
}

// ---------------------------------------------------------------------------
// OBJ

#[cfg(unix)]
#[test]
fn an_obj_mtllib_at_dev_urandom_is_refused_at_once() {
    let d = tmp();
    let obj = |name: &str, mtllib: &str| {
        let p = d.path().join(name);
        std::fs::write(
            &p,
            format!(
                "# a triangle\nmtllib {mtllib}\nusemtl red\nv 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n"
            ),
        )
        .unwrap();
        p
    };
    let p = obj("urandom.obj", "/dev/urandom");
    refused(
        &p,
        &[],
        None,
        &["urandom.obj:2:", "mtllib", "/dev/urandom", "--allow-read"],
    );
    refused(
        &p,
        &[Path::new("/dev")],
        None,
        &["urandom.obj:2:", "character device"],
    );
    // the library inside the folder gives the material
    std::fs::write(d.path().join("red.mtl"), "newmtl red\nKd 0.8 0.1 0.1\n").unwrap();
    let s = load(&obj("good.obj", "red.mtl"), &[], None).unwrap();
    match &s.materials[0] {
        Material::Diffuse {
            reflectance: Texture::Constant(c),
        } => assert!((c.x - 0.8).abs() < 1e-6, "{c:?}"),
        m => panic!("{m:?}"),
    }
    // a missing one is a warning, as before
    let s = load(&obj("missing.obj", "none.mtl"), &[], None).unwrap();
    assert!(
        s.warnings.iter().any(|w| w.contains("MTL not loaded")),
        "{:?}",
        s.warnings
    );
}

#[cfg(unix)]
#[test]
fn obj_and_ply_meshes_through_a_symlink_out_of_the_folder_are_refused() {
    let d = tmp();
    let scene_dir = d.path().join("scene");
    let outside = d.path().join("outside");
    std::fs::create_dir_all(&scene_dir).unwrap();
    std::fs::create_dir_all(&outside).unwrap();
    std::fs::write(
        outside.join("t.obj"),
        "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n",
    )
    .unwrap();
    std::fs::write(
        outside.join("t.ply"),
        "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\n\
         property float z\nelement face 1\nproperty list uchar int vertex_indices\n\
         end_header\n0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n",
    )
    .unwrap();
    for f in ["t.obj", "t.ply"] {
        let link = scene_dir.join(f);
        std::os::unix::fs::symlink(outside.join(f), &link).unwrap();
        // named by the user as the scene file, the link is read (what it
        // names is held to the folders); named by a scene, it is refused
        assert_eq!(load(&link, &[], None).unwrap().triangles.len(), 1);
    }
    // the shared mesh readers, as the Mitsuba and pbrt loaders call them
    let access = FileAccess::for_dir(&scene_dir, &ReadPolicy::default()).unwrap();
    let e = scene::ply::load_ply(&scene_dir.join("t.ply"), &access).unwrap_err();
    assert!(e.to_string().contains("--allow-read"), "{e}");
    let e = scene::obj::load_obj(&scene_dir.join("t.obj"), true, &access).unwrap_err();
    assert!(e.to_string().contains("--allow-read"), "{e}");
}

// ---------------------------------------------------------------------------
// Memory

#[test]
fn meshes_and_images_past_the_memory_limit_are_refused_naming_the_largest() {
    let d = tmp();
    std::fs::write(d.path().join("tri.bin"), triangle_bin()).unwrap();
    // a PLY header's counts: 10^6 vertices and faces (the body holds them:
    // one byte a value, so 3 MB and 4 MB)
    let mut ply = b"ply\nformat binary_little_endian 1.0\nelement vertex 1000000\n\
        property uchar x\nproperty uchar y\nproperty uchar z\nelement face 1000000\n\
        property list uchar uchar vertex_indices\nend_header\n"
        .to_vec();
    ply.resize(ply.len() + 7_000_000, 0);
    let p = d.path().join("big.ply");
    std::fs::write(&p, &ply).unwrap();
    refused(
        &p,
        &[],
        Some(10_000_000),
        &["big.ply", "1000000 vertices", "--max-memory"],
    );

    // glTF: the mesh instanced 2^10 times by shared nodes
    let nodes: Vec<String> = (0..10)
        .map(|k| format!(r#"{{"children":[{},{}]}}"#, k + 1, k + 1))
        .chain([r#"{"mesh":0}"#.to_string()])
        .collect();
    let p = gltf(d.path(), "dag.gltf", "tri.bin", None, &[]);
    let json = std::fs::read_to_string(&p).unwrap().replace(
        r#""nodes":[{"mesh":0}]"#,
        &format!(r#""nodes":[{}]"#, nodes.join(",")),
    );
    std::fs::write(&p, json).unwrap();
    let s = load(&p, &[], None).unwrap();
    assert_eq!(s.triangles.len(), 1024);
    refused(
        &p,
        &[],
        Some(50_000),
        &["dag.gltf", "glTF mesh 0", "1024 instances", "--max-memory"],
    );

    // glTF: an image's pixels, from its header, before it is decoded
    let big = image::GrayImage::new(1024, 1024);
    big.save(d.path().join("big.png")).unwrap();
    let p = gltf(
        d.path(),
        "img.gltf",
        "tri.bin",
        Some(r#"{"uri":"big.png"}"#),
        &[],
    );
    refused(
        &p,
        &[],
        Some(4_000_000),
        &[
            "img.gltf",
            "image 0",
            "big.png",
            "1024×1024",
            "--max-memory",
        ],
    );
    assert!(load(&p, &[], Some(40_000_000)).is_ok());

    // OBJ: its v and f lines
    let mut obj = String::new();
    for i in 0..30_000 {
        obj += &format!(
            "v {i} 0 0\nv {i} 1 0\nv {i} 0 1\nf {} {} {}\n",
            3 * i + 1,
            3 * i + 2,
            3 * i + 3
        );
    }
    let p = d.path().join("many.obj");
    std::fs::write(&p, obj).unwrap();
    refused(
        &p,
        &[],
        Some(1_000_000),
        &["many.obj", "90000 vertices", "--max-memory"],
    );
    assert_eq!(load(&p, &[], None).unwrap().triangles.len(), 30_000);
}

// ---------------------------------------------------------------------------
// Through the binary

#[test]
fn kalos_info_refuses_then_loads_with_allow_read() {
    let d = tmp();
    let scene_dir = d.path().join("scene");
    let outside = d.path().join("outside");
    std::fs::create_dir_all(&scene_dir).unwrap();
    std::fs::create_dir_all(&outside).unwrap();
    std::fs::write(outside.join("tri.bin"), triangle_bin()).unwrap();
    std::fs::write(outside.join("secret.png"), png()).unwrap();
    let p = gltf(
        &scene_dir,
        "s.gltf",
        "../outside/tri.bin",
        Some(r#"{"uri":"../outside/secret.png"}"#),
        &[],
    );
    let p = p.to_str().unwrap();
    let start = Instant::now();
    let o = kalos(&["info", p]);
    let err = crate::common::stderr(&o);
    assert_eq!(o.status.code(), Some(1), "{err}");
    assert!(
        start.elapsed() < Duration::from_secs(2),
        "{:?}",
        start.elapsed()
    );
    for n in ["s.gltf", "tri.bin", "--allow-read"] {
        assert!(err.contains(n), "`{n}` not in: {err}");
    }
    let o = kalos(&["info", p, "--allow-read", outside.to_str().unwrap()]);
    assert!(o.status.success(), "{}", crate::common::stderr(&o));

    // an OBJ whose mtllib is /dev/urandom
    #[cfg(unix)]
    {
        let obj = scene_dir.join("u.obj");
        std::fs::write(
            &obj,
            "mtllib /dev/urandom\nv 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n",
        )
        .unwrap();
        let o = kalos(&["info", obj.to_str().unwrap()]);
        let err = crate::common::stderr(&o);
        assert_eq!(o.status.code(), Some(1), "{err}");
        assert!(
            err.contains("u.obj:1:") && err.contains("/dev/urandom"),
            "{err}"
        );
    }
}
