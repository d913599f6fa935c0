//! What the fuzz targets share: the container format that packs a scene's
//! files into one fuzz input, and the check run on each input.
//!
//! # Container format
//!
//! ```text
//! <bytes of the main file>
//! @@file <name>
//! <bytes of that file>
//! @@file <name>
//! ...
//! ```
//!
//! The input is split at each `"\n@@file "`; the part before the first one
//! is the main file (its name is fixed by the target, e.g. `scene.xml`),
//! and each later part is a name up to the next newline, then the file's
//! bytes. The marker's leading newline belongs to the marker, not to the
//! file before it. A name is one to three `/`-separated components of
//! `A-Z a-z 0-9 . _ -` (not `.` or `..`), at most 64 bytes; a part whose
//! name is not valid, or names the main file, is dropped. At most
//! [`MAX_FILES`] side files are written. Binary files may hold the marker
//! by chance; the seeds are checked not to (`seed.rs`).

use std::path::{Path, PathBuf};
use std::sync::OnceLock;

use kalos::scene::{self, Scene};
use kalos::world::World;

mod container;
pub use container::{join, split, Part, MARKER, MAX_FILES};

/// Writes the main file as `main_name` and the side files into a fresh
/// folder; returns the folder (deleted when dropped) and the main path.
pub fn write_scene(
    main_name: &str,
    main: &[u8],
    parts: &[Part<'_>],
) -> std::io::Result<(tempfile::TempDir, PathBuf)> {
    let dir = tempfile::Builder::new().prefix("kalos-fuzz-").tempdir()?;
    for p in parts {
        if p.name == main_name {
            continue;
        }
        let path = dir.path().join(&p.name);
        // a part whose name clashes with another's (`a` and `a/b`): the
        // later one is dropped
        if let Some(parent) = path.parent() {
            if std::fs::create_dir_all(parent).is_err() {
                continue;
            }
        }
        if path.is_dir() {
            continue;
        }
        std::fs::write(&path, p.bytes)?;
    }
    let main_path = dir.path().join(main_name);
    std::fs::write(&main_path, main)?;
    Ok((dir, main_path))
}

/// Loads the scene at `path`; when it loads, checks that its bounds are
/// finite and builds the world (BVH, lights, camera). A panic anywhere, or
/// non-finite bounds, is a finding.
/// With `KALOS_FUZZ_VERBOSE` set, each load error is printed (to see
/// which seeds load).
pub fn check(path: &Path) {
    static VERBOSE: OnceLock<bool> = OnceLock::new();
    match scene::load(path) {
        Ok(scene) => check_scene(scene),
        Err(e) => {
            if *VERBOSE.get_or_init(|| std::env::var_os("KALOS_FUZZ_VERBOSE").is_some()) {
                eprintln!("load error: {e}");
            }
        }
    }
}

/// The checks on a scene that loaded.
pub fn check_scene(scene: Scene) {
    let (lo, hi) = scene.bounds();
    assert!(
        lo.is_finite() && hi.is_finite(),
        "a loaded scene has non-finite bounds {lo} .. {hi}"
    );
    let world = World::new(scene);
    std::hint::black_box(&world);
}

/// One fuzz input: split it, write its files with the main one named
/// `main_name`, and [`check`] it.
pub fn run(main_name: &str, data: &[u8]) {
    let (main, parts) = split(data);
    let (_dir, path) = write_scene(main_name, main, &parts).expect("writing the scene files");
    check(&path);
}

/// Once per process: one rayon thread, since the machine's cores are
/// shared between several fuzzers.
pub fn init() {
    let _ = rayon::ThreadPoolBuilder::new()
        .num_threads(1)
        .build_global();
}
