//! `kalos view` and `render --view` without a browser: what the server
//! answers over plain HTTP, the bad inputs (a file it cannot show, a
//! truncated .glb, a port in use) and the bake's camera. The page itself is
//! tested in Chromium by `tests/browser/test_view.py`.

use crate::common::{kalos, stderr};
use std::io::{BufRead, BufReader, Read, Write};
use std::net::{TcpListener, TcpStream};
use std::path::Path;
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use glam::{Mat4, Vec3};
use kalos::bake::BakedMesh;
use kalos::camera::Camera;
use kalos::scene::CameraDesc;

/// Two triangles of baked radiance, as `kalos bake` would write them.
fn quad() -> BakedMesh {
    let p = [
        Vec3::new(-1.0, -1.0, 0.0),
        Vec3::new(1.0, -1.0, 0.0),
        Vec3::new(1.0, 1.0, 0.0),
        Vec3::new(-1.0, 1.0, 0.0),
    ];
    BakedMesh {
        positions: p.to_vec(),
        normals: vec![Vec3::Z; 4],
        irradiance: vec![Vec3::ONE; 4],
        radiance: vec![Vec3::new(0.5, 0.25, 0.125); 4],
        indices: vec![[0, 1, 2], [0, 2, 3]],
    }
}

/// A camera that is not axis-aligned, with a scale in its transform (which
/// the glTF node must not carry).
fn camera() -> CameraDesc {
    // Mitsuba's lookat: +z toward the target, +x to the left
    let origin = Vec3::new(1.0, 2.0, -5.0);
    let dir = (Vec3::new(0.2, 0.1, 0.0) - origin).normalize();
    let left = Vec3::Y.cross(dir).normalize();
    let up = dir.cross(left);
    let look = Mat4::from_cols(
        left.extend(0.0),
        up.extend(0.0),
        dir.extend(0.0),
        origin.extend(1.0),
    );
    CameraDesc {
        to_world: look * Mat4::from_scale(Vec3::splat(2.0)),
        fov_x_deg: 50.0,
        width: 320,
        height: 200,
        near_clip: 0.01,
    }
}

fn glb(camera: Option<&CameraDesc>) -> Vec<u8> {
    kalos::bake::gltf::encode_glb(&quad(), &BakedMesh::default(), 1.0, camera)
}

/// Waits for the first line of `child`'s stdout or stderr that holds the
/// viewer's address, and returns it (`127.0.0.1:PORT`).
fn address(child: &mut Child, from_stderr: bool) -> String {
    let pipe: Box<dyn Read + Send> = if from_stderr {
        Box::new(child.stderr.take().expect("stderr piped"))
    } else {
        Box::new(child.stdout.take().expect("stdout piped"))
    };
    let mut lines = BufReader::new(pipe).lines();
    for line in lines.by_ref() {
        let line = line.expect("utf-8 output");
        if let Some(i) = line.find("http://127.0.0.1:") {
            let rest = &line[i + "http://".len()..];
            // read on, so that kalos never writes to a closed pipe
            std::thread::spawn(move || lines.for_each(drop));
            return rest[..rest.find('/').expect("a URL ending in /")].to_string();
        }
    }
    panic!("kalos printed no address");
}

/// `GET path` on `addr`: (status code, body).
fn get(addr: &str, path: &str) -> (u16, Vec<u8>) {
    let mut s = TcpStream::connect(addr).expect("the viewer accepts connections");
    s.set_read_timeout(Some(Duration::from_secs(30))).ok();
    write!(
        s,
        "GET {path} HTTP/1.1\r\nHost: {addr}\r\nConnection: close\r\n\r\n"
    )
    .expect("request sent");
    let mut raw = Vec::new();
    s.read_to_end(&mut raw).expect("response read");
    let split = raw
        .windows(4)
        .position(|w| w == b"\r\n\r\n")
        .expect("an HTTP response");
    let head = String::from_utf8_lossy(&raw[..split]).into_owned();
    let code = head
        .split_whitespace()
        .nth(1)
        .and_then(|c| c.parse().ok())
        .expect("a status code");
    (code, raw[split + 4..].to_vec())
}

/// Ends `child` (started by the test) and reaps it.
fn stop(mut child: Child) {
    let _ = child.kill();
    let _ = child.wait();
}

#[test]
fn the_bake_records_the_scene_camera_and_the_loader_reads_it_back() {
    let dir = tempfile::tempdir().expect("tempdir");
    let path = dir.path().join("s.glb");
    std::fs::write(&path, glb(Some(&camera()))).expect("write");
    let scene = kalos::scene::load(&path).expect("the .glb loads");
    let (a, b) = (Camera::new(&camera()), Camera::new(&scene.camera));
    assert!(a.position().distance(b.position()) < 1e-4);
    // the same ray through the film's centre and through a corner (the
    // loader makes its own resolution from the aspect ratio)
    for (u, v) in [(0.5, 0.5), (0.0, 0.0), (1.0, 0.3)] {
        let ra = a.ray(u * a.width as f32, v * a.height as f32).d.normalize();
        let rb = b.ray(u * b.width as f32, v * b.height as f32).d.normalize();
        assert!(ra.distance(rb) < 1e-4, "({u}, {v}): {ra} against {rb}");
    }
    // without a camera, nothing is written and the loader makes one
    let bytes = glb(None);
    let (doc, _, _) = gltf::import_slice(&bytes).expect("valid glb");
    assert_eq!(doc.cameras().count(), 0);
}

#[test]
fn view_refuses_a_file_it_cannot_show() {
    let dir = tempfile::tempdir().expect("tempdir");
    let text = dir.path().join("notes.txt");
    std::fs::write(&text, "hello").expect("write");
    let o = kalos(&["view", text.to_str().expect("utf-8")]);
    assert!(!o.status.success());
    let e = stderr(&o);
    assert!(
        e.contains("notes.txt") && e.contains(".glb") && e.contains(".exr"),
        "{e}"
    );

    let missing = dir.path().join("missing.glb");
    let o = kalos(&["view", missing.to_str().expect("utf-8")]);
    assert!(!o.status.success());
    assert!(stderr(&o).contains("missing.glb"), "{}", stderr(&o));

    // an image that is not one: a .exr holding text
    let fake = dir.path().join("fake.exr");
    std::fs::write(&fake, "not an image").expect("write");
    let o = kalos(&["view", fake.to_str().expect("utf-8")]);
    assert!(!o.status.success());
    assert!(stderr(&o).contains("fake.exr"), "{}", stderr(&o));
}

#[test]
fn view_refuses_a_truncated_glb() {
    let dir = tempfile::tempdir().expect("tempdir");
    let bytes = glb(Some(&camera()));
    for keep in [bytes.len() - 8, bytes.len() / 2, 20, 0] {
        let path = dir.path().join("cut.glb");
        std::fs::write(&path, &bytes[..keep]).expect("write");
        let o = kalos(&["view", path.to_str().expect("utf-8")]);
        assert!(!o.status.success(), "{keep} bytes were accepted");
        let e = stderr(&o);
        assert!(
            e.contains("cut.glb") && e.contains("not a valid glTF binary"),
            "{keep} bytes: {e}"
        );
    }
}

#[test]
fn view_serves_the_page_three_js_and_the_file_on_loopback() {
    let dir = tempfile::tempdir().expect("tempdir");
    let path = dir.path().join("s.glb");
    let bytes = glb(Some(&camera()));
    std::fs::write(&path, &bytes).expect("write");
    let mut child = Command::new(env!("CARGO_BIN_EXE_kalos"))
        .arg("view")
        .arg(&path)
        .stdout(Stdio::piped())
        .stderr(Stdio::null())
        .spawn()
        .expect("kalos starts");
    let addr = address(&mut child, false);
    let (code, page) = get(&addr, "/");
    assert_eq!(code, 200);
    assert!(String::from_utf8_lossy(&page).contains("importmap"));
    let (code, info) = get(&addr, "/info");
    assert_eq!(code, 200);
    assert!(String::from_utf8_lossy(&info).contains("\"kind\":\"mesh\""));
    assert_eq!(get(&addr, "/scene.glb"), (200, bytes));
    let (code, three) = get(&addr, "/three/three.module.min.js");
    assert!(code == 200 && three.len() > 100_000);
    assert_eq!(get(&addr, "/no/such/file").0, 404);
    stop(child);
}

#[test]
fn a_port_in_use_is_an_error_naming_it() {
    let dir = tempfile::tempdir().expect("tempdir");
    let path = dir.path().join("s.glb");
    std::fs::write(&path, glb(None)).expect("write");
    let taken = TcpListener::bind("127.0.0.1:0").expect("a free port");
    let port = taken.local_addr().expect("address").port().to_string();
    let o = kalos(&["view", path.to_str().expect("utf-8"), "--port", &port]);
    assert!(!o.status.success());
    let e = stderr(&o);
    assert!(
        e.contains(&format!("port {port} on 127.0.0.1 is in use")),
        "{e}"
    );

    // render --view fails the same way, before it renders anything
    let out = dir.path().join("x.pfm");
    let o = kalos(&[
        "render",
        "--view",
        "--port",
        &port,
        "--res",
        "8x8",
        "--spp",
        "1",
        "-o",
        out.to_str().expect("utf-8"),
    ]);
    assert!(!o.status.success());
    assert!(stderr(&o).contains("in use"), "{}", stderr(&o));
    assert!(!out.exists());
}

/// A live render publishes its estimate and progress while it runs, and
/// Ctrl-C still saves the image (exit 130).
#[cfg(unix)]
#[test]
fn render_view_publishes_progress_and_ctrl_c_still_saves() {
    let dir = tempfile::tempdir().expect("tempdir");
    let out = dir.path().join("live.pfm");
    let mut child = Command::new(env!("CARGO_BIN_EXE_kalos"))
        .args([
            "render", "--view", "--res", "16x16", "--time", "600", "-q", "-o",
        ])
        .arg(&out)
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .expect("kalos starts");
    let addr = address(&mut child, true);
    let status = |addr: &str| String::from_utf8_lossy(&get(addr, "/status").1).into_owned();
    let number = |json: &str, key: &str| -> u64 {
        let at = json.find(&format!("\"{key}\":")).expect(key) + key.len() + 3;
        json[at..]
            .split([',', '}'])
            .next()
            .and_then(|v| v.parse().ok())
            .expect("a number")
    };
    // Generous bound, only so that a render that never publishes fails
    // instead of hanging
    let deadline = Instant::now() + Duration::from_secs(120);
    let mut first = None;
    loop {
        let s = status(&addr);
        let (passes, version) = (number(&s, "passes"), number(&s, "version"));
        match first {
            None if version >= 1 => first = Some((passes, version)),
            Some((p, v)) if passes > p && version > v => break,
            _ => {}
        }
        assert!(Instant::now() < deadline, "no progress published: {s}");
        std::thread::sleep(Duration::from_millis(200));
    }
    let (code, img) = get(&addr, "/image");
    assert_eq!(code, 200);
    assert_eq!(&img[..4], b"KIMG");
    assert_eq!(img.len(), 12 + 16 * 16 * 12);
    let sent = Command::new("kill")
        .args(["-INT", &child.id().to_string()])
        .status()
        .expect("kill runs");
    assert!(sent.success());
    let deadline = Instant::now() + Duration::from_secs(60);
    let code = loop {
        if let Some(s) = child.try_wait().expect("wait") {
            break s.code();
        }
        if Instant::now() > deadline {
            stop(child);
            panic!("kalos did not stop within 60 s of SIGINT");
        }
        std::thread::sleep(Duration::from_millis(50));
    };
    assert_eq!(code, Some(130));
    let saved = kalos::image_io::read_image(Path::new(&out)).expect("the image was saved");
    assert_eq!((saved.width, saved.height), (16, 16));
}

/// `Render::watch` sees every pass but the last (whose image the result
/// holds), at the film's size, and leaves the render as it would be
/// without it.
#[test]
fn the_watch_hook_sees_the_passes_and_changes_nothing() {
    let world = kalos::world::World::new(crate::common::furnace(0.5, 1.0, 12));
    let plain = kalos::render::Render::new(&world)
        .seed(3)
        .passes(5)
        .run(|_| {})
        .expect("render");
    let mut seen = Vec::new();
    let watched = kalos::render::Render::new(&world)
        .seed(3)
        .passes(5)
        .watch(0.0, |img, p| {
            seen.push((p.passes, img.width, img.height, img.data.len()))
        })
        .run(|_| {})
        .expect("render");
    let want: Vec<_> = (1..5).map(|p| (p, 12, 12, 144)).collect();
    assert_eq!(seen, want);
    assert_eq!(watched.image, plain.image);
}
