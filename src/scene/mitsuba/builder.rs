//! The [`Builder`]: the tree to a [`Scene`]. Its shared helpers (messages,
//! ids and references, the top-level dispatch) are here; the parameter
//! readers are in `props.rs`, and each plugin family has its own file.

use std::collections::{HashMap, HashSet};
use std::path::{Path, PathBuf};
use std::sync::Arc;

use crate::scene::access::FileAccess;
use crate::scene::{Scene, SceneError, TexImage, Texture};

use super::props::Props;
use super::xml::El;
use super::Result;

// ---------------------------------------------------------------------------
// Building: the tree to a Scene

pub(super) struct Builder<'t> {
    /// What the scene's files are read through.
    pub(super) access: &'t FileAccess,
    pub(super) files: &'t [PathBuf],
    pub(super) main_dir: &'t Path,
    pub(super) ids: HashMap<&'t str, &'t El>,
    pub(super) scene: Scene,
    /// Material index of each `<bsdf>` element built (by address).
    pub(super) materials: HashMap<usize, u32>,
    /// Each `<texture>` element built (by address).
    pub(super) textures: HashMap<usize, Texture>,
    pub(super) images: HashMap<(PathBuf, bool), Arc<TexImage>>,
    /// Elements being built (reference-cycle guard).
    pub(super) building: HashSet<usize>,
    pub(super) default_material: Option<u32>,
    pub(super) camera_seen: bool,
    /// Spheres waiting for the whole scene (see `shape.rs`).
    pub(super) spheres: Vec<super::shape::PendingSphere>,
}

pub(super) fn addr(el: &El) -> usize {
    std::ptr::from_ref(el) as usize
}

impl<'t> Builder<'t> {
    pub(super) fn file(&self, el: &El) -> PathBuf {
        self.files.get(el.file).cloned().unwrap_or_default()
    }

    pub(super) fn err(&self, el: &El, msg: impl Into<String>) -> SceneError {
        SceneError::new(self.file(el), el.line, msg)
    }

    pub(super) fn warn(&mut self, el: &El, msg: impl AsRef<str>) {
        let w = format!("{}:{}: {}", self.file(el).display(), el.line, msg.as_ref());
        self.scene.warnings.push(w);
    }

    pub(super) fn index_ids(&mut self, el: &'t El) -> Result<()> {
        if el.tag != "ref" {
            if let Some(id) = el.attr("id") {
                if let Some(prev) = self.ids.get(id) {
                    let msg = format!(
                        "id `{id}` is used twice (first at {}:{})",
                        self.file(prev).display(),
                        prev.line
                    );
                    return Err(self.err(el, msg));
                }
                self.ids.insert(id, el);
            }
        }
        for c in &el.children {
            self.index_ids(c)?;
        }
        Ok(())
    }

    pub(super) fn lookup(&self, r: &'t El) -> Result<&'t El> {
        let id = r
            .attr("id")
            .ok_or_else(|| self.err(r, "<ref> needs an `id` attribute"))?;
        self.ids
            .get(id)
            .copied()
            .ok_or_else(|| self.err(r, format!("<ref id=\"{id}\">: no object has this id")))
    }

    pub(super) fn plugin_type(&self, el: &'t El) -> Result<&'t str> {
        el.attr("type")
            .ok_or_else(|| self.err(el, format!("<{}> needs a `type` attribute", el.tag)))
    }

    /// Reports the first child the plugin did not read.
    pub(super) fn finish(&self, p: &Props<'t>) -> Result<()> {
        let el = p.el;
        for (c, used) in el.children.iter().zip(&p.used) {
            if *used {
                continue;
            }
            let msg = match c.attr("name") {
                Some(n) => format!(
                    "unknown parameter `{n}` of {} (misspelt, or not supported by kalos)",
                    el.describe()
                ),
                None => format!("unexpected {} inside {}", c.describe(), el.describe()),
            };
            return Err(self.err(c, msg));
        }
        Ok(())
    }

    pub(super) fn top_level(&mut self, el: &'t El) -> Result<()> {
        match el.tag.as_str() {
            "shape" => self.shape(el),
            "bsdf" => self.bsdf(el).map(|_| ()),
            "texture" => self.texture(el).map(|_| ()),
            "emitter" => self.emitter(el),
            "sensor" => {
                if self.camera_seen {
                    self.warn(el, "a second <sensor> is ignored: kalos uses the first");
                    Ok(())
                } else {
                    self.sensor(el)
                }
            }
            "integrator" => {
                let ty = el.attr("type").unwrap_or("?");
                self.warn(
                    el,
                    format!("<integrator type=\"{ty}\"> skipped: kalos chooses its method itself"),
                );
                Ok(())
            }
            _ => Err(self.err(
                el,
                format!("unsupported element {} in a scene", el.describe()),
            )),
        }
    }
}
