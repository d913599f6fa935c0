//! `kalos view FILE`, `kalos render --view` and `kalos bake --lightmap
//! --view`: a local web page, served on 127.0.0.1 only, that shows a baked
//! display mesh (.glb) in 3D with three.js, a linear HDR image (EXR, PFM,
//! HDR) with exposure, tone mapping, pixel values and false colour, a
//! render as it converges, or a lightmap as it is baked.

mod bake;
mod server;

use std::path::{Path, PathBuf};
use std::sync::Arc;

use anyhow::{bail, Context, Result};
use clap::Args;

use kalos::film::Image;
use kalos::methods::Progress;

pub use bake::LiveBake;
pub use server::Viewer;
use server::{Content, LiveState};

/// The flags of `kalos view`.
#[derive(Args)]
pub struct ViewArgs {
    /// A baked display mesh (.glb, from `kalos bake`) or a linear HDR image
    /// (.exr, .pfm, .hdr).
    file: PathBuf,
    /// Port on 127.0.0.1 (default: a free one).
    #[arg(long, default_value_t = 0)]
    port: u16,
}

/// Runs `kalos view`: checks the file, serves it, prints the address and
/// serves until the process is stopped (Ctrl-C).
pub fn run(a: ViewArgs) -> Result<()> {
    let content = read_content(&a.file)?;
    let name = a
        .file
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_default();
    let viewer = server::start(content, &name, a.port)?;
    crate::say!("{}: open {} (Ctrl-C stops)", a.file.display(), viewer.url);
    loop {
        std::thread::park();
    }
}

/// Reads and checks what `kalos view` will show, so that a bad file fails
/// here, with its name, and not in the browser.
fn read_content(path: &Path) -> Result<Content> {
    let ext = crate::extension(path);
    match ext.as_str() {
        "glb" => {
            let bytes =
                std::fs::read(path).with_context(|| format!("cannot read {}", path.display()))?;
            check_glb(&bytes)
                .with_context(|| format!("{}: not a valid glTF binary (.glb)", path.display()))?;
            Ok(Content::Mesh(bytes))
        }
        "exr" | "pfm" | "hdr" => {
            let img = kalos::image_io::read_image(path)?;
            if img.data.is_empty() {
                bail!("{}: the image has no pixels", path.display());
            }
            Ok(Content::Image(img))
        }
        _ => bail!(
            "{}: kalos view shows a baked mesh (.glb) or a linear HDR image (.exr, .pfm, .hdr), \
             not a '.{ext}' file",
            path.display()
        ),
    }
}

/// Parses a .glb in full (JSON, buffer lengths, accessors), as the browser
/// would, and asks for at least one mesh: a truncated file is refused here.
fn check_glb(bytes: &[u8]) -> Result<()> {
    let (doc, _, _) = gltf::import_slice(bytes)?;
    if doc.meshes().len() == 0 {
        bail!("it holds no mesh");
    }
    Ok(())
}

/// `render --view`: the server, and what the render's callbacks update.
pub struct Live {
    viewer: Viewer,
    reference: Option<Arc<Image>>,
}

impl Live {
    /// Starts the server for a live render (before the scene loads, so that
    /// a port in use fails at once) and prints its address.
    pub fn start(port: u16, name: &str) -> Result<Live> {
        let viewer = server::start(Content::Live, name, port)?;
        eprintln!("view the render at {}", viewer.url);
        Ok(Live {
            viewer,
            reference: None,
        })
    }

    /// The reference, for the page's convergence curve.
    pub fn set_reference(&mut self, reference: Option<Image>) {
        self.reference = reference.map(Arc::new);
    }

    /// Records progress after a pass (cheap: no image).
    pub fn progress(&self, p: &Progress) {
        self.update(|s| {
            s.passes = p.passes;
            s.rays = p.rays;
            s.elapsed = p.elapsed;
            s.fraction = p.fraction;
            s.phase = p.phase;
        });
    }

    /// Publishes a new estimate, with its error against the reference.
    pub fn image(&self, img: &Image, p: &Progress) {
        let bytes = Arc::new(server::encode_image(img));
        let err = self
            .reference
            .as_deref()
            .and_then(|r| kalos::metrics::rel_mse(img, r).ok());
        self.update(|s| {
            s.image = Some(bytes);
            s.version += 1;
            if let Some(e) = err {
                s.curve.push((p.elapsed, e));
            }
        });
        self.progress(p);
    }

    /// Marks the render ended, with its final image.
    pub fn finish(&self, img: &Image, p: &Progress) {
        self.image(img, p);
        self.update(|s| s.done = true);
    }

    fn update(&self, f: impl FnOnce(&mut LiveState)) {
        // a poisoned lock means the server thread panicked: the render goes on
        if let Ok(mut s) = self.viewer.live.lock() {
            f(&mut s);
        }
    }
}
