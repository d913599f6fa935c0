//! Reading: the XML documents to an owned tree of [`El`]s, with includes
//! spliced in and `$name`s substituted.

use std::path::{Path, PathBuf};

use crate::scene::SceneError;

use super::Result;

// ---------------------------------------------------------------------------
// Reading: XML to an owned tree

/// Deepest element nesting accepted (a guard against stack exhaustion on
/// hostile input; real scenes nest a handful of levels).
const MAX_DEPTH: usize = 64;

/// An element after includes are spliced in and `$name`s substituted.
#[derive(Debug)]
pub(super) struct El {
    pub(super) tag: String,
    pub(super) attrs: Vec<(String, String)>,
    pub(super) children: Vec<El>,
    /// Index into the list of files read.
    pub(super) file: usize,
    /// 1-based line of the element's start.
    pub(super) line: u32,
}

impl El {
    pub(super) fn attr(&self, k: &str) -> Option<&str> {
        self.attrs
            .iter()
            .find(|(n, _)| n == k)
            .map(|(_, v)| v.as_str())
    }

    /// `<tag name="..." type="...">` for messages.
    pub(super) fn describe(&self) -> String {
        let mut s = format!("<{}", self.tag);
        for k in ["type", "name", "id"] {
            if let Some(v) = self.attr(k) {
                s += &format!(" {k}=\"{v}\"");
            }
        }
        s + ">"
    }
}

pub(super) struct Reader {
    pub(super) main_dir: PathBuf,
    pub(super) files: Vec<PathBuf>,
    /// `<default>` values, first declaration wins (as in Mitsuba).
    pub(super) defaults: Vec<(String, String)>,
    /// Canonical paths of the files being read (include-cycle guard).
    pub(super) stack: Vec<PathBuf>,
}

impl Reader {
    pub(super) fn read_document(
        &mut self,
        text: &str,
        file: usize,
        depth: usize,
        out: &mut Vec<El>,
    ) -> Result<()> {
        let path = self.files.get(file).cloned().unwrap_or_default();
        let doc = roxmltree::Document::parse(text)
            .map_err(|e| SceneError::new(&path, e.pos().row, format!("malformed XML: {e}")))?;
        let root = doc.root_element();
        if root.tag_name().name() != "scene" {
            return Err(SceneError::new(
                &path,
                doc.text_pos_at(root.range().start).row,
                format!(
                    "expected <scene> as the root element, found <{}>",
                    root.tag_name().name()
                ),
            ));
        }
        self.convert_children(&doc, root, file, depth, out)
    }

    fn substitute(&self, v: &str) -> String {
        if !v.contains('$') {
            return v.to_string();
        }
        // longest names first, so that `$spp` is not read as `$sp` + "p"
        let mut names: Vec<&(String, String)> = self.defaults.iter().collect();
        names.sort_by_key(|(n, _)| std::cmp::Reverse(n.len()));
        let mut s = v.to_string();
        for (n, val) in names {
            s = s.replace(&format!("${n}"), val);
        }
        s
    }

    fn convert_children(
        &mut self,
        doc: &roxmltree::Document,
        node: roxmltree::Node,
        file: usize,
        depth: usize,
        out: &mut Vec<El>,
    ) -> Result<()> {
        let path = self.files.get(file).cloned().unwrap_or_default();
        for child in node.children().filter(|n| n.is_element()) {
            let line = doc.text_pos_at(child.range().start).row;
            if depth > MAX_DEPTH {
                return Err(SceneError::new(&path, line, "elements nested too deeply"));
            }
            let tag = child.tag_name().name().to_string();
            let attrs: Vec<(String, String)> = child
                .attributes()
                .map(|a| (a.name().to_string(), self.substitute(a.value())))
                .collect();
            let get = |k: &str| {
                attrs
                    .iter()
                    .find(|(n, _)| n == k)
                    .map(|(_, v)| v.clone())
                    .ok_or_else(|| {
                        SceneError::new(&path, line, format!("<{tag}> needs a `{k}` attribute"))
                    })
            };
            match tag.as_str() {
                "default" => {
                    let (name, value) = (get("name")?, get("value")?);
                    if !self.defaults.iter().any(|(n, _)| *n == name) {
                        self.defaults.push((name, value));
                    }
                }
                "include" => {
                    let filename = get("filename")?;
                    self.include(&filename, file, line, depth, out)?;
                }
                _ => {
                    let mut el = El {
                        tag,
                        attrs,
                        children: Vec::new(),
                        file,
                        line,
                    };
                    self.convert_children(doc, child, file, depth + 1, &mut el.children)?;
                    out.push(el);
                }
            }
        }
        Ok(())
    }

    fn include(
        &mut self,
        filename: &str,
        from: usize,
        line: u32,
        depth: usize,
        out: &mut Vec<El>,
    ) -> Result<()> {
        let from_path = self.files.get(from).cloned().unwrap_or_default();
        let path = resolve(&self.main_dir, &from_path, filename);
        let err = |msg: String| SceneError::new(&from_path, line, msg);
        if !path.is_file() {
            return Err(err(format!(
                "included file `{filename}` not found (looked for {})",
                path.display()
            )));
        }
        let canon = path.canonicalize().unwrap_or_else(|_| path.clone());
        if self.stack.contains(&canon) {
            return Err(err(format!("include cycle: `{filename}` includes itself")));
        }
        let text = std::fs::read_to_string(&path)
            .map_err(|e| err(format!("cannot read included file `{filename}`: {e}")))?;
        self.files.push(path);
        self.stack.push(canon);
        let idx = self.files.len() - 1;
        let r = self.read_document(&text, idx, depth + 1, out);
        self.stack.pop();
        r
    }
}

/// A file named in a scene: absolute as is; relative against the main scene
/// file's folder, else against the folder of the file that names it.
pub(super) fn resolve(main_dir: &Path, from_file: &Path, filename: &str) -> PathBuf {
    let f = Path::new(filename);
    if f.is_absolute() {
        return f.to_path_buf();
    }
    let main = main_dir.join(f);
    if main.exists() {
        return main;
    }
    if let Some(dir) = from_file.parent() {
        let local = dir.join(f);
        if local.exists() {
            return local;
        }
    }
    main
}
