//! The bake's scratch directory: where phase 1's bucket files go and, unless
//! the user keeps it elsewhere, the hit file itself (§4: the paper's three
//! programs "communicate using files").
//!
//! [`ScratchDir`] removes the directory and everything in it when dropped,
//! so that a bake leaves nothing behind whether it finishes, returns an
//! error or unwinds from a panic. A hit file the user asked to keep
//! ([`Settings::keep_hits`], `kalos bake --hits PATH`) is written at that
//! path instead, outside the directory, and survives.

use std::path::{Path, PathBuf};

use super::{DensityError, Settings};

/// A fresh directory for one bake, removed on drop (a `tempfile::TempDir`).
#[derive(Debug)]
pub struct ScratchDir {
    dir: tempfile::TempDir,
    hit_file: PathBuf,
    keep_hits: bool,
}

impl ScratchDir {
    /// Creates a fresh `kalos-density-*` directory in [`Settings::scratch`]
    /// (the system's temporary directory when unset). That directory must
    /// exist: only the fresh one is created, so only it is removed.
    pub fn new(s: &Settings) -> Result<Self, DensityError> {
        let base = s.scratch.clone().unwrap_or_else(std::env::temp_dir);
        let dir = tempfile::Builder::new()
            .prefix("kalos-density-")
            .tempdir_in(&base)
            .map_err(|source| DensityError::Scratch { base, source })?;
        let hit_file = s
            .keep_hits
            .clone()
            .unwrap_or_else(|| dir.path().join("hits.bin"));
        Ok(ScratchDir {
            dir,
            hit_file,
            keep_hits: s.keep_hits.is_some(),
        })
    }

    /// The directory.
    pub fn path(&self) -> &Path {
        self.dir.path()
    }

    /// Where the hit file goes: the kept path, or inside the directory.
    pub fn hit_file(&self) -> &Path {
        &self.hit_file
    }

    /// True when the hit file is kept (it is not in the directory).
    pub fn keeps_hits(&self) -> bool {
        self.keep_hits
    }
}
