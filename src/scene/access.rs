//! The one way a scene's files are read: every loader opens the files a
//! scene names (Mitsuba includes, meshes, textures, spectra and
//! environment maps; glTF buffers and images; OBJ `mtllib`s; PLY meshes;
//! pbrt `Include`/`Import`s, meshes, textures and spectra; gzip members)
//! through a [`FileAccess`], never through `std::fs`.
//!
//! A scene file is untrusted input: it may come from a farm's queue, a web
//! service or a content repository. So a path it names is
//! 1. resolved against the folder of the file that names it and
//!    canonicalised (symlinks followed, `..` removed), then checked to lie
//!    under an allowed root: the folder of the scene file the user named,
//!    and any folder given by `--allow-read DIR` (`allow_read=` in Python);
//! 2. checked to be a regular file, from its metadata, before it is opened:
//!    a device (`/dev/zero`), a FIFO or a socket is refused, never read. It
//!    is then opened without blocking and checked again on the open handle,
//!    so a file swapped between the check and the open is refused too;
//! 3. checked against the size limit of its kind ([`FileKind::limit`])
//!    before it is read, and read through a reader bounded by the size it
//!    had when checked. Decompressed gzip members are bounded the same way.
//!
//! Loaders also declare what they will allocate before allocating it
//! ([`FileAccess::reserve`]: a mesh's triangles from a header's counts, an
//! image's pixels from its dimensions, an instance's copies), so that a
//! scene larger than the memory limit (`--max-memory`, else the machine's)
//! is refused before its memory is taken, with its largest item named.
//!
//! The errors ([`AccessError`]) name the file and say how to allow it; the
//! loaders wrap them into a [`super::SceneError`] that names the scene file
//! and line that named the file.

#![allow(clippy::disallowed_methods)]

use std::fmt;
use std::fs::File;
use std::io::Read;
use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex};

use crate::memory::format_bytes;

/// What a file is for, which sets its size limit and names it in messages.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum FileKind {
    /// A scene file, or one it includes (Mitsuba XML, pbrt-v4, OBJ, glTF
    /// JSON or GLB).
    Scene,
    /// A material library (OBJ's MTL).
    Material,
    /// A mesh (PLY, OBJ, Mitsuba `.serialized`, a glTF buffer).
    Mesh,
    /// A texture or environment image.
    Image,
    /// A spectrum or other small table.
    Spectrum,
}

impl FileKind {
    /// The largest file of this kind read, in bytes. Generous for real
    /// assets; what guards memory beyond it is [`FileAccess::reserve`].
    pub fn limit(self) -> u64 {
        const MIB: u64 = 1 << 20;
        match self {
            FileKind::Scene => 1024 * MIB,
            FileKind::Material => 64 * MIB,
            FileKind::Mesh => 8192 * MIB,
            FileKind::Image => 2048 * MIB,
            FileKind::Spectrum => 16 * MIB,
        }
    }

    /// The kind's name in messages.
    pub fn noun(self) -> &'static str {
        match self {
            FileKind::Scene => "scene file",
            FileKind::Material => "material library",
            FileKind::Mesh => "mesh file",
            FileKind::Image => "image",
            FileKind::Spectrum => "spectrum file",
        }
    }
}

/// What a scene's files may be read from, and how much memory the scene
/// may take: the options of the front ends (`--allow-read`,
/// `--max-memory`; `allow_read=`, `max_memory=` in Python).
#[derive(Clone, Debug, Default)]
pub struct ReadPolicy {
    /// Folders readable besides the scene file's own.
    pub allow_read: Vec<PathBuf>,
    /// The most memory the scene's data may take, in bytes, and where that
    /// limit comes from ("--max-memory", "this machine's memory"); None:
    /// no limit but [`super::MAX_TRIANGLES`].
    pub memory_limit: Option<(u64, String)>,
}

/// Why a file was not read, or the scene's memory was refused.
#[derive(Debug)]
pub enum AccessError {
    /// The path resolves outside every allowed root.
    Outside {
        /// The path as the scene named it.
        named: PathBuf,
        /// Where it resolves.
        resolved: PathBuf,
        /// The allowed roots.
        roots: Vec<PathBuf>,
    },
    /// Not a regular file (a device, FIFO, socket or folder).
    NotRegular {
        /// The path as the scene named it.
        named: PathBuf,
        /// What it is instead ("a character device", ...).
        what: &'static str,
    },
    /// Larger than its kind's limit (or grew past it while being read).
    TooLarge {
        /// The path as the scene named it.
        named: PathBuf,
        /// Its kind.
        kind: FileKind,
        /// Its size in bytes (at least this much, for a decompressed
        /// member).
        size: u64,
    },
    /// The operating system's error (not found, permission denied, ...).
    Io {
        /// The path as the scene named it.
        named: PathBuf,
        /// The error.
        source: std::io::Error,
    },
    /// The scene's data would exceed the memory limit.
    Memory {
        /// The largest item declared so far, and its size.
        largest: (String, u64),
        /// The total declared, this item included.
        total: u64,
        /// The limit.
        limit: u64,
        /// Where the limit comes from.
        source: String,
    },
}

impl fmt::Display for AccessError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            AccessError::Outside {
                named,
                resolved,
                roots,
            } => {
                let roots: Vec<String> = roots.iter().map(|r| r.display().to_string()).collect();
                let dir = resolved.parent().unwrap_or(resolved);
                write!(
                    f,
                    "`{}` resolves to `{}`, outside the folders this scene may read ({}); \
                     to allow it, pass --allow-read {} (allow_read= in Python)",
                    named.display(),
                    resolved.display(),
                    roots.join(", "),
                    dir.display()
                )
            }
            AccessError::NotRegular { named, what } => write!(
                f,
                "`{}` is {what}, not a regular file: a scene may only name regular files",
                named.display()
            ),
            AccessError::TooLarge { named, kind, size } => write!(
                f,
                "`{}` is {} or more, larger than the {} limit of {} for a {}",
                named.display(),
                format_bytes(*size),
                kind.noun(),
                format_bytes(kind.limit()),
                kind.noun()
            ),
            AccessError::Io { named, source } => {
                write!(f, "cannot read `{}`: {source}", named.display())
            }
            AccessError::Memory {
                largest,
                total,
                limit,
                source,
            } => write!(
                f,
                "the scene needs at least {} of memory ({} alone takes {}), more than {source} \
                 ({}); raise --max-memory or lower the scene's size",
                format_bytes(*total),
                largest.0,
                format_bytes(largest.1),
                format_bytes(*limit)
            ),
        }
    }
}

impl std::error::Error for AccessError {}

/// What the scene's items have declared so far.
#[derive(Debug, Default)]
struct Budget {
    total: u64,
    largest: (String, u64),
}

/// The gate every loader reads a scene's files through (see the module
/// documentation). Cloning shares the memory budget.
#[derive(Clone, Debug)]
pub struct FileAccess {
    roots: Arc<Vec<PathBuf>>,
    memory_limit: Option<(u64, String)>,
    budget: Arc<Mutex<Budget>>,
}

impl FileAccess {
    /// The access of the scene file `scene`: its folder and the policy's
    /// folders are readable, and the scene file itself: the user named it,
    /// so when it is a symbolic link into another folder it is read all
    /// the same (with the regular-file and size checks), while the files
    /// it names are held to the folders. Fails when a folder of the policy
    /// does not exist.
    pub fn for_scene(scene: &Path, policy: &ReadPolicy) -> Result<Self, AccessError> {
        let dir = match scene.parent() {
            Some(d) if !d.as_os_str().is_empty() => d,
            _ => Path::new("."),
        };
        let mut access = Self::for_dir(dir, policy)?;
        if let Ok(file) = scene.canonicalize() {
            if !access.roots.iter().any(|r| file.starts_with(r)) {
                Arc::make_mut(&mut access.roots).push(file);
            }
        }
        Ok(access)
    }

    /// The access of a scene whose files resolve against `dir`: `dir` and
    /// the policy's folders are readable.
    pub fn for_dir(dir: &Path, policy: &ReadPolicy) -> Result<Self, AccessError> {
        let mut roots = Vec::new();
        for d in std::iter::once(dir).chain(policy.allow_read.iter().map(PathBuf::as_path)) {
            let canon = d.canonicalize().map_err(|source| AccessError::Io {
                named: d.to_path_buf(),
                source,
            })?;
            roots.push(canon);
        }
        Ok(FileAccess {
            roots: Arc::new(roots),
            memory_limit: policy.memory_limit.clone(),
            budget: Arc::default(),
        })
    }

    /// An access that reads nothing, for scenes that name no files (the
    /// built-in ones).
    pub fn nothing() -> Self {
        FileAccess {
            roots: Arc::default(),
            memory_limit: None,
            budget: Arc::default(),
        }
    }

    /// The allowed roots, canonical.
    pub fn roots(&self) -> &[PathBuf] {
        &self.roots
    }

    /// Checks `path` (as resolved by the loader: relative paths against
    /// the naming file's folder) without opening it: that it exists, lies
    /// under an allowed root once canonical, is a regular file and is
    /// within `kind`'s limit. Returns the canonical path and the size.
    pub fn check(&self, path: &Path, kind: FileKind) -> Result<(PathBuf, u64), AccessError> {
        let io = |source| AccessError::Io {
            named: path.to_path_buf(),
            source,
        };
        let canon = path.canonicalize().map_err(io)?;
        if !self.roots.iter().any(|r| canon.starts_with(r)) {
            return Err(AccessError::Outside {
                named: path.to_path_buf(),
                resolved: canon,
                roots: self.roots.to_vec(),
            });
        }
        let meta = std::fs::metadata(&canon).map_err(io)?;
        check_regular(path, &meta)?;
        if meta.len() > kind.limit() {
            return Err(AccessError::TooLarge {
                named: path.to_path_buf(),
                kind,
                size: meta.len(),
            });
        }
        Ok((canon, meta.len()))
    }

    /// Opens `path` after [`FileAccess::check`], without blocking, and
    /// returns a reader bounded by the size checked (plus one byte, to see
    /// a file that grew), with that size.
    pub fn open(&self, path: &Path, kind: FileKind) -> Result<(BoundedFile, u64), AccessError> {
        let (canon, size) = self.check(path, kind)?;
        let io = |source| AccessError::Io {
            named: path.to_path_buf(),
            source,
        };
        let file = open_nonblocking(&canon).map_err(io)?;
        // the handle's own metadata: the file opened is the file checked
        let meta = file.metadata().map_err(io)?;
        check_regular(path, &meta)?;
        Ok((
            BoundedFile {
                inner: file.take(size + 1),
                named: path.to_path_buf(),
                kind,
                size,
            },
            size,
        ))
    }

    /// Reads all of `path` (see [`FileAccess::check`]).
    pub fn read(&self, path: &Path, kind: FileKind) -> Result<Vec<u8>, AccessError> {
        let (mut f, size) = self.open(path, kind)?;
        let mut bytes = Vec::with_capacity(size as usize);
        f.read_to_end(&mut bytes).map_err(|e| f.error(e))?;
        Ok(bytes)
    }

    /// Reads all of `path` as UTF-8 text (see [`FileAccess::check`]).
    pub fn read_string(&self, path: &Path, kind: FileKind) -> Result<String, AccessError> {
        let bytes = self.read(path, kind)?;
        String::from_utf8(bytes).map_err(|e| AccessError::Io {
            named: path.to_path_buf(),
            source: std::io::Error::new(std::io::ErrorKind::InvalidData, e),
        })
    }

    /// Decompresses the gzip member `bytes` read from `path`, refusing more
    /// than `kind`'s limit of output (a small member can expand a
    /// thousandfold).
    pub fn gunzip(
        &self,
        path: &Path,
        bytes: &[u8],
        kind: FileKind,
    ) -> Result<Vec<u8>, AccessError> {
        let mut out = Vec::new();
        flate2::read::MultiGzDecoder::new(bytes)
            .take(kind.limit() + 1)
            .read_to_end(&mut out)
            .map_err(|source| AccessError::Io {
                named: path.to_path_buf(),
                source,
            })?;
        if out.len() as u64 > kind.limit() {
            return Err(AccessError::TooLarge {
                named: path.to_path_buf(),
                kind,
                size: out.len() as u64,
            });
        }
        Ok(out)
    }

    /// Declares that the scene will allocate `bytes` for `item` (named in
    /// messages: "mesh `floor.ply`: 3 000 000 triangles"), before it does.
    /// Fails when the scene's declared total passes the memory limit,
    /// naming the largest item.
    pub fn reserve(&self, item: impl Into<String>, bytes: u64) -> Result<(), AccessError> {
        let mut b = self.budget.lock().unwrap_or_else(|p| p.into_inner());
        b.total = b.total.saturating_add(bytes);
        if bytes >= b.largest.1 {
            b.largest = (item.into(), bytes);
        }
        match &self.memory_limit {
            Some((limit, source)) if b.total > *limit => Err(AccessError::Memory {
                largest: b.largest.clone(),
                total: b.total,
                limit: *limit,
                source: source.clone(),
            }),
            _ => Ok(()),
        }
    }

    /// The bytes declared so far through [`FileAccess::reserve`].
    pub fn reserved(&self) -> u64 {
        self.budget.lock().unwrap_or_else(|p| p.into_inner()).total
    }
}

/// A file opened by [`FileAccess::open`]: reads stop one byte past the
/// size it had when checked, and [`BoundedFile::error`] turns a file that
/// grew into [`AccessError::TooLarge`].
pub struct BoundedFile {
    inner: std::io::Take<File>,
    named: PathBuf,
    kind: FileKind,
    size: u64,
}

impl BoundedFile {
    /// The error for a failed read of this file.
    pub fn error(&self, source: std::io::Error) -> AccessError {
        AccessError::Io {
            named: self.named.clone(),
            source,
        }
    }
}

impl Read for BoundedFile {
    fn read(&mut self, buf: &mut [u8]) -> std::io::Result<usize> {
        let n = self.inner.read(buf)?;
        if n > 0 && self.inner.limit() == 0 {
            // the byte past the checked size: the file grew
            return Err(std::io::Error::other(format!(
                "it grew past the {} it had when checked (a {} may not change while it is read)",
                format_bytes(self.size),
                self.kind.noun()
            )));
        }
        Ok(n)
    }
}

/// Refuses anything but a regular file, naming what it is.
fn check_regular(named: &Path, meta: &std::fs::Metadata) -> Result<(), AccessError> {
    if meta.is_file() {
        return Ok(());
    }
    let ft = meta.file_type();
    let what = if ft.is_dir() {
        "a folder"
    } else {
        special_kind(&ft)
    };
    Err(AccessError::NotRegular {
        named: named.to_path_buf(),
        what,
    })
}

#[cfg(unix)]
fn special_kind(ft: &std::fs::FileType) -> &'static str {
    use std::os::unix::fs::FileTypeExt;
    if ft.is_char_device() {
        "a character device"
    } else if ft.is_block_device() {
        "a block device"
    } else if ft.is_fifo() {
        "a FIFO (named pipe)"
    } else if ft.is_socket() {
        "a socket"
    } else {
        "not a file"
    }
}

#[cfg(not(unix))]
fn special_kind(_: &std::fs::FileType) -> &'static str {
    "not a file"
}

/// Opens for reading without blocking: opening a FIFO for reading blocks
/// until a writer comes, so a FIFO swapped in after the check must not
/// stall the open (it is then refused by the handle's metadata).
#[cfg(unix)]
fn open_nonblocking(path: &Path) -> std::io::Result<File> {
    use std::os::unix::fs::OpenOptionsExt;
    const O_NONBLOCK: i32 = 0o4000; // Linux's value on every architecture kalos builds for
    std::fs::OpenOptions::new()
        .read(true)
        .custom_flags(O_NONBLOCK)
        .open(path)
}

#[cfg(not(unix))]
fn open_nonblocking(path: &Path) -> std::io::Result<File> {
    File::open(path)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn access(dir: &Path) -> Result<FileAccess, AccessError> {
        FileAccess::for_dir(dir, &ReadPolicy::default())
    }

    #[test]
    fn reads_a_file_inside_and_refuses_one_outside_until_allowed(
    ) -> Result<(), Box<dyn std::error::Error>> {
        let root = tempfile::tempdir()?;
        let scene = root.path().join("scene");
        let outside = root.path().join("outside");
        std::fs::create_dir_all(&scene)?;
        std::fs::create_dir_all(&outside)?;
        std::fs::write(scene.join("a.txt"), "inside")?;
        std::fs::write(outside.join("secret.png"), "secret")?;
        let a = access(&scene)?;
        assert_eq!(a.read(&scene.join("a.txt"), FileKind::Scene)?, b"inside");
        let e = a
            .read(&scene.join("../outside/secret.png"), FileKind::Image)
            .err()
            .ok_or("expected an error")?;
        assert!(matches!(e, AccessError::Outside { .. }), "{e}");
        let msg = e.to_string();
        assert!(
            msg.contains("--allow-read") && msg.contains("secret.png"),
            "{msg}"
        );
        let policy = ReadPolicy {
            allow_read: vec![outside.clone()],
            ..Default::default()
        };
        let wide = FileAccess::for_dir(&scene, &policy)?;
        let bytes = wide.read(&scene.join("../outside/secret.png"), FileKind::Image);
        assert_eq!(bytes?, b"secret");
        Ok(())
    }

    #[cfg(unix)]
    #[test]
    fn a_symlink_out_of_the_folder_is_refused() -> Result<(), Box<dyn std::error::Error>> {
        let root = tempfile::tempdir()?;
        let scene = root.path().join("scene");
        std::fs::create_dir_all(&scene)?;
        std::fs::write(root.path().join("secret"), "x")?;
        std::os::unix::fs::symlink(root.path().join("secret"), scene.join("link"))?;
        let e = access(&scene)?
            .read(&scene.join("link"), FileKind::Mesh)
            .err()
            .ok_or("expected an error")?;
        assert!(matches!(e, AccessError::Outside { .. }), "{e}");
        Ok(())
    }

    #[cfg(unix)]
    #[test]
    fn devices_and_fifos_are_refused_without_reading() -> Result<(), Box<dyn std::error::Error>> {
        let a = FileAccess::for_dir(Path::new("/dev"), &ReadPolicy::default())?;
        let e = a
            .read(Path::new("/dev/zero"), FileKind::Mesh)
            .err()
            .ok_or("expected an error")?;
        assert!(
            matches!(
                e,
                AccessError::NotRegular {
                    what: "a character device",
                    ..
                }
            ),
            "{e}"
        );
        let dir = tempfile::tempdir()?;
        let fifo = dir.path().join("pipe");
        let made = std::process::Command::new("mkfifo").arg(&fifo).status();
        if made.is_ok_and(|s| s.success()) {
            let e = access(dir.path())?
                .read(&fifo, FileKind::Mesh)
                .err()
                .ok_or("expected an error")?;
            assert!(matches!(e, AccessError::NotRegular { .. }), "{e}");
            assert!(e.to_string().contains("FIFO"), "{e}");
        }
        let e = access(dir.path())?
            .read(dir.path(), FileKind::Mesh)
            .err()
            .ok_or("expected an error")?;
        assert!(
            matches!(
                e,
                AccessError::NotRegular {
                    what: "a folder",
                    ..
                }
            ),
            "{e}"
        );
        Ok(())
    }

    #[test]
    fn a_file_over_its_kinds_limit_is_refused_before_reading(
    ) -> Result<(), Box<dyn std::error::Error>> {
        let dir = tempfile::tempdir()?;
        let big = dir.path().join("big.spd");
        let f = File::create(&big)?;
        f.set_len(FileKind::Spectrum.limit() + 1)?; // sparse: no disk used
        let e = access(dir.path())?
            .read(&big, FileKind::Spectrum)
            .err()
            .ok_or("expected an error")?;
        assert!(matches!(e, AccessError::TooLarge { .. }), "{e}");
        Ok(())
    }

    #[test]
    fn a_gzip_bomb_is_bounded() -> Result<(), Box<dyn std::error::Error>> {
        use std::io::Write;
        let mut enc = flate2::write::GzEncoder::new(Vec::new(), flate2::Compression::best());
        let zeros = vec![0u8; 1 << 20];
        for _ in 0..17 {
            enc.write_all(&zeros)?;
        }
        let gz = enc.finish()?;
        let dir = tempfile::tempdir()?;
        let e = access(dir.path())?
            .gunzip(Path::new("bomb.spd.gz"), &gz, FileKind::Spectrum)
            .err()
            .ok_or("expected an error")?;
        assert!(matches!(e, AccessError::TooLarge { .. }), "{e}");
        Ok(())
    }

    #[test]
    fn memory_past_the_limit_names_the_largest_item() -> Result<(), Box<dyn std::error::Error>> {
        let dir = tempfile::tempdir()?;
        let policy = ReadPolicy {
            memory_limit: Some((1000, "--max-memory".into())),
            ..Default::default()
        };
        let a = FileAccess::for_dir(dir.path(), &policy)?;
        a.reserve("mesh a", 400)?;
        a.reserve("texture b", 500)?;
        let e = a.reserve("mesh c", 200).err().ok_or("expected an error")?;
        let msg = e.to_string();
        assert!(
            msg.contains("texture b") && msg.contains("--max-memory"),
            "{msg}"
        );
        assert_eq!(a.reserved(), 1100);
        Ok(())
    }
}
