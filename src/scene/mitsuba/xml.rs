//! Reading: the XML documents to an owned tree of [`El`]s, with includes
//! spliced in and `$name`s substituted.

use std::collections::HashSet;
use std::path::{Path, PathBuf};

use crate::scene::access::{FileAccess, FileKind};
use crate::scene::SceneError;

use super::Result;

// ---------------------------------------------------------------------------
// Reading: XML to an owned tree

/// Deepest element nesting accepted (a guard against stack exhaustion on
/// hostile input; real scenes nest a handful of levels).
const MAX_DEPTH: usize = 64;

/// Deepest chain of `<include>`s (a file including a file including...).
const MAX_INCLUDE_DEPTH: usize = 16;

/// Most `<include>`s read for one scene, counting every time a file is
/// included: a file that includes the next one ten times, seven levels deep,
/// asks for a million files from a few hundred bytes.
pub(super) const MAX_INCLUDES: usize = 4096;

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
    /// `<default>` values, first declaration wins (as in Mitsuba); the
    /// `-D` overrides come first, so they win.
    pub(super) defaults: Vec<(String, String)>,
    /// The names given by `-D`.
    pub(super) overrides: HashSet<String>,
    /// Names that a `$name` or a `<default>` used.
    pub(super) used: HashSet<String>,
    /// Canonical paths of the files being read (include-cycle guard).
    pub(super) stack: Vec<PathBuf>,
    /// `<include>`s read so far.
    pub(super) includes: usize,
    /// What the included files are read through.
    pub(super) access: FileAccess,
}

/// The byte offsets of a text's line breaks, to find an element's line by
/// binary search: roxmltree's `text_pos_at` rescans the text from its start
/// on every call, which made a scene of 20,000 shapes take seconds to number.
struct LineTable(Vec<usize>);

impl LineTable {
    fn new(text: &str) -> Self {
        LineTable(text.match_indices('\n').map(|(i, _)| i).collect())
    }

    /// The 1-based line of byte `pos`.
    fn row(&self, pos: usize) -> u32 {
        (self.0.partition_point(|&nl| nl < pos) + 1) as u32
    }
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
        let lines = LineTable::new(text);
        self.convert_children(&lines, root, file, depth, out)
    }

    /// Replaces each `$name` in `v` by its value (a `-D` override, else the
    /// first `<default>`); a `$name` left without a value is an error at
    /// `path:line` naming it.
    fn substitute(&mut self, v: &str, path: &Path, line: u32) -> Result<String> {
        if !v.contains('$') {
            return Ok(v.to_string());
        }
        // longest names first, so that `$spp` is not read as `$sp` + "p"
        let mut names: Vec<&(String, String)> = self.defaults.iter().collect();
        names.sort_by_key(|(n, _)| std::cmp::Reverse(n.len()));
        let mut s = v.to_string();
        for (n, val) in names {
            let pattern = format!("${n}");
            if s.contains(&pattern) {
                s = s.replace(&pattern, val);
                self.used.insert(n.clone());
            }
        }
        if let Some(at) = s.find('$') {
            let name: String = s[at + 1..]
                .chars()
                .take_while(|c| c.is_ascii_alphanumeric() || *c == '_')
                .collect();
            if !name.is_empty() {
                return Err(SceneError::new(
                    path,
                    line,
                    format!(
                        "`${name}` has no value: declare <default name=\"{name}\" value=\"...\"/> \
                         or pass -D {name}=VALUE"
                    ),
                ));
            }
        }
        Ok(s)
    }

    fn convert_children(
        &mut self,
        lines: &LineTable,
        node: roxmltree::Node,
        file: usize,
        depth: usize,
        out: &mut Vec<El>,
    ) -> Result<()> {
        let path = self.files.get(file).cloned().unwrap_or_default();
        for child in node.children().filter(|n| n.is_element()) {
            let line = lines.row(child.range().start);
            if depth > MAX_DEPTH {
                return Err(SceneError::new(&path, line, "elements nested too deeply"));
            }
            let tag = child.tag_name().name().to_string();
            let attrs: Vec<(String, String)> = child
                .attributes()
                .map(|a| {
                    Ok((
                        a.name().to_string(),
                        self.substitute(a.value(), &path, line)?,
                    ))
                })
                .collect::<Result<_>>()?;
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
                    if self.overrides.contains(&name) {
                        self.used.insert(name.clone());
                    }
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
                    self.convert_children(lines, child, file, depth + 1, &mut el.children)?;
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
        let refused = |e| err(super::files::message("included file", filename, &e));
        // checked (inside the allowed folders, a regular file) before
        // anything else is done with it
        let (canon, _) = self.access.check(&path, FileKind::Scene).map_err(refused)?;
        if self.stack.contains(&canon) {
            return Err(err(format!("include cycle: `{filename}` includes itself")));
        }
        if self.stack.len() > MAX_INCLUDE_DEPTH {
            return Err(err(format!(
                "includes nested more than {MAX_INCLUDE_DEPTH} deep (at `{filename}`)"
            )));
        }
        self.includes += 1;
        if self.includes > MAX_INCLUDES {
            return Err(err(format!(
                "more than {MAX_INCLUDES} includes in one scene (at `{filename}`, {} files deep): \
                 the includes fan out, each file including others many times",
                self.stack.len()
            )));
        }
        let text = self
            .access
            .read_string(&path, FileKind::Scene)
            .map_err(refused)?;
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
