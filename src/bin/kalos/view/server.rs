//! The viewer's HTTP server: `tiny_http` on 127.0.0.1 only, one thread
//! answering the page, the vendored three.js files, the content (a .glb or
//! an image) and, for a live render or lightmap bake, its progress.
//!
//! Routes:
//! - `/`: the page; `/view/*`: its scripts; `/three/*`: three.js.
//! - `/info`: what is shown
//!   (`{"kind":"mesh"|"image"|"live"|"bake","name":…}`).
//! - `/scene.glb`: the mesh's bytes, as read; for a live bake, the asset
//!   once its uv set is made (404 before).
//! - `/image`: the image as `KIMG`, width and height (u32 LE), then
//!   RGB f32 LE per pixel, top row first; the page tone-maps it. For a
//!   live bake, the latest atlas (`KLM1`, see [`super::bake`]).
//! - `/status`: a live render's progress and convergence curve, or a live
//!   bake's progress (JSON).

use std::sync::{Arc, Mutex};
use std::thread::JoinHandle;

use anyhow::{anyhow, Result};
use tiny_http::{Header, Response, Server};

use kalos::film::Image;

/// The files the server answers from the binary: no network at view time.
const FILES: &[(&str, &str, &str)] = &[
    (
        "/",
        include_str!("../../../../assets/view/index.html"),
        HTML,
    ),
    (
        "/view/mesh.js",
        include_str!("../../../../assets/view/mesh.js"),
        JS,
    ),
    (
        "/view/lightmap.js",
        include_str!("../../../../assets/view/lightmap.js"),
        JS,
    ),
    (
        "/view/image.js",
        include_str!("../../../../assets/view/image.js"),
        JS,
    ),
    (
        "/three/three.module.min.js",
        include_str!("../../../../assets/three/three.module.min.js"),
        JS,
    ),
    (
        "/three/addons/controls/OrbitControls.js",
        include_str!("../../../../assets/three/addons/controls/OrbitControls.js"),
        JS,
    ),
    (
        "/three/addons/loaders/GLTFLoader.js",
        include_str!("../../../../assets/three/addons/loaders/GLTFLoader.js"),
        JS,
    ),
    (
        "/three/addons/utils/BufferGeometryUtils.js",
        include_str!("../../../../assets/three/addons/utils/BufferGeometryUtils.js"),
        JS,
    ),
    (
        "/three/LICENSE",
        include_str!("../../../../assets/three/LICENSE"),
        TEXT,
    ),
];

const HTML: &str = "text/html; charset=utf-8";
const JS: &str = "text/javascript; charset=utf-8";
const TEXT: &str = "text/plain; charset=utf-8";
const JSON: &str = "application/json";
const BINARY: &str = "application/octet-stream";

/// What the page shows.
pub enum Content {
    /// A baked display mesh: the .glb's bytes.
    Mesh(Vec<u8>),
    /// A still image.
    Image(Image),
    /// A render in progress: its latest estimate and progress.
    Live,
    /// A lightmap bake in progress: its asset, its latest atlas and
    /// progress.
    Bake,
}

/// A live render's state, as the page polls it.
#[derive(Default)]
pub struct LiveState {
    /// The latest estimate, encoded for `/image`.
    pub image: Option<Arc<Vec<u8>>>,
    /// Bumped with every new image, so that the page fetches only new ones.
    pub version: u64,
    /// Passes done.
    pub passes: u64,
    /// Rays traced.
    pub rays: u64,
    /// Seconds of render time.
    pub elapsed: f64,
    /// Fraction of the budget spent.
    pub fraction: f64,
    /// What a method's setup is doing, while it runs.
    pub phase: Option<&'static str>,
    /// (seconds, relMSE) against `--ref`, one point per image.
    pub curve: Vec<(f64, f64)>,
    /// True once the render has ended.
    pub done: bool,
    /// A live bake's asset (.glb), once its uv set is made.
    pub glb: Option<Arc<Vec<u8>>>,
    /// A live bake's progress.
    pub bake: Option<BakeStatus>,
}

/// A live lightmap bake's progress, as `/status` gives it under `bake`.
#[derive(Clone, Debug, Default)]
pub struct BakeStatus {
    /// Particles traced so far.
    pub particles: u64,
    /// Particles asked for.
    pub particles_total: u64,
    /// Work done and in all in the current phase.
    pub done: u64,
    /// Work of the current phase in all.
    pub total: u64,
    /// Particles the atlas shown was estimated from (0: none yet).
    pub atlas_particles: u64,
    /// Previews estimated so far, and their seconds in all.
    pub previews: u64,
    /// Seconds the previews took.
    pub preview_seconds: f64,
}

impl BakeStatus {
    fn json(&self) -> String {
        format!(
            "{{\"particles\":{},\"particles_total\":{},\"done\":{},\"total\":{},\"atlas_particles\":{},\"previews\":{},\"preview_seconds\":{}}}",
            self.particles,
            self.particles_total,
            self.done,
            self.total,
            self.atlas_particles,
            self.previews,
            finite(self.preview_seconds)
        )
    }
}

impl LiveState {
    /// The JSON `/status` answers.
    fn json(&self) -> String {
        let rays_per_s = if self.elapsed > 0.0 {
            self.rays as f64 / self.elapsed
        } else {
            0.0
        };
        // time left from the fraction spent, once there is a fraction to go by
        let left = if self.fraction > 0.0 && self.fraction < 1.0 && !self.done {
            format!("{}", self.elapsed * (1.0 - self.fraction) / self.fraction)
        } else {
            "null".into()
        };
        let curve: Vec<String> = self
            .curve
            .iter()
            .filter(|(t, e)| t.is_finite() && e.is_finite())
            .map(|(t, e)| format!("[{t},{e}]"))
            .collect();
        let phase = match self.phase {
            Some(p) => format!("\"{}\"", p.replace(['"', '\\'], "")),
            None => "null".into(),
        };
        let bake = match &self.bake {
            Some(b) => b.json(),
            None => "null".into(),
        };
        format!(
            "{{\"version\":{},\"passes\":{},\"rays\":{},\"elapsed\":{},\"fraction\":{},\"rays_per_s\":{},\"time_left\":{left},\"phase\":{phase},\"done\":{},\"asset\":{},\"bake\":{bake},\"curve\":[{}]}}",
            self.version,
            self.passes,
            self.rays,
            finite(self.elapsed),
            finite(self.fraction),
            finite(rays_per_s),
            self.done,
            self.glb.is_some(),
            curve.join(",")
        )
    }
}

/// JSON has no NaN or infinity.
fn finite(v: f64) -> f64 {
    if v.is_finite() {
        v
    } else {
        0.0
    }
}

/// `image` as `/image` sends it.
pub fn encode_image(image: &Image) -> Vec<u8> {
    let mut out = Vec::with_capacity(12 + image.data.len() * 12);
    out.extend_from_slice(b"KIMG");
    out.extend_from_slice(&image.width.to_le_bytes());
    out.extend_from_slice(&image.height.to_le_bytes());
    for p in &image.data {
        for c in p.to_array() {
            // the page must never see NaN: it would poison its statistics
            let c = if c.is_finite() { c } else { 0.0 };
            out.extend_from_slice(&c.to_le_bytes());
        }
    }
    out
}

/// A running server; it stops with the process.
pub struct Viewer {
    /// The page's address.
    pub url: String,
    /// The live state, for `render --view` to update.
    pub live: Arc<Mutex<LiveState>>,
    _thread: JoinHandle<()>,
}

/// Binds 127.0.0.1 at `port` (0: a free one) and serves `content` named
/// `name` from a thread of its own.
pub fn start(content: Content, name: &str, port: u16) -> Result<Viewer> {
    let server = Server::http(("127.0.0.1", port)).map_err(|e| {
        let in_use = e
            .downcast_ref::<std::io::Error>()
            .is_some_and(|e| e.kind() == std::io::ErrorKind::AddrInUse);
        match (port, in_use) {
            (0, _) => anyhow!("cannot open a port on 127.0.0.1 for the viewer: {e}"),
            (_, true) => anyhow!(
                "port {port} on 127.0.0.1 is in use: choose another with --port, or omit \
                 --port for a free one"
            ),
            _ => anyhow!("cannot serve the viewer on 127.0.0.1:{port}: {e}"),
        }
    })?;
    let port = server
        .server_addr()
        .to_ip()
        .map(|a| a.port())
        .ok_or_else(|| anyhow!("the viewer's server has no IP address"))?;
    let live = Arc::new(Mutex::new(LiveState::default()));
    let state = Arc::clone(&live);
    let kind = match content {
        Content::Mesh(_) => "mesh",
        Content::Image(_) => "image",
        Content::Live => "live",
        Content::Bake => "bake",
    };
    let info = format!("{{\"kind\":\"{kind}\",\"name\":\"{}\"}}", json_escape(name));
    let still = match &content {
        Content::Image(img) => Some(Arc::new(encode_image(img))),
        _ => None,
    };
    let glb = match content {
        Content::Mesh(bytes) => Some(Arc::new(bytes)),
        _ => None,
    };
    let thread = std::thread::spawn(move || {
        for req in server.incoming_requests() {
            let path = req.url().split('?').next().unwrap_or("/").to_string();
            let reply = |body: Vec<u8>, ctype: &str| {
                let mut r = Response::from_data(body);
                if let Ok(h) = Header::from_bytes("Content-Type", ctype) {
                    r.add_header(h);
                }
                // the live image changes under the same address
                if let Ok(h) = Header::from_bytes("Cache-Control", "no-store") {
                    r.add_header(h);
                }
                r
            };
            let response = if let Some((_, body, ctype)) = FILES.iter().find(|f| f.0 == path) {
                reply(body.as_bytes().to_vec(), ctype)
            } else {
                match path.as_str() {
                    "/info" => reply(info.clone().into_bytes(), JSON),
                    "/scene.glb" => {
                        let bytes = glb
                            .clone()
                            .or_else(|| state.lock().ok().and_then(|s| s.glb.clone()));
                        match bytes {
                            Some(b) => reply(b.to_vec(), BINARY),
                            None => reply(b"no asset yet".to_vec(), TEXT).with_status_code(404),
                        }
                    }
                    "/image" => {
                        let img = still
                            .clone()
                            .or_else(|| state.lock().ok().and_then(|s| s.image.clone()));
                        match img {
                            Some(bytes) => reply(bytes.to_vec(), BINARY),
                            None => reply(b"no image yet".to_vec(), TEXT).with_status_code(404),
                        }
                    }
                    "/status" => {
                        let text = state.lock().map(|s| s.json()).unwrap_or_default();
                        reply(text.into_bytes(), JSON)
                    }
                    _ => reply(b"not found".to_vec(), TEXT).with_status_code(404),
                }
            };
            // a page closed mid-answer is no concern of the render
            let _ = req.respond(response);
        }
    });
    Ok(Viewer {
        url: format!("http://127.0.0.1:{port}/"),
        live,
        _thread: thread,
    })
}

/// `s` inside a JSON string.
fn json_escape(s: &str) -> String {
    let mut out = String::new();
    for c in s.chars() {
        match c {
            '"' => out += "\\\"",
            '\\' => out += "\\\\",
            c if (c as u32) < 0x20 => out += &format!("\\u{:04x}", c as u32),
            c => out.push(c),
        }
    }
    out
}
