//! What the coverage-guided fuzzing of the loaders found (`fuzz/`, see
//! its README and BENCHMARKS.md), each input minimised by libFuzzer and kept
//! here as plain files. Every case must end in a clear error (or a scene),
//! never a panic; the fuzz targets build with overflow checks, so some of
//! these panicked only in debug builds.

use std::path::PathBuf;

use kalos::scene::{self, Scene, SceneError};

/// Writes `files` (name, bytes) into a fresh folder and loads the first.
fn load_files(files: &[(&str, &[u8])]) -> Result<Scene, SceneError> {
    let dir = tempfile::Builder::new()
        .prefix("kalos-fuzz-found-")
        .tempdir()
        .unwrap();
    for (name, bytes) in files {
        let p: PathBuf = dir.path().join(name);
        std::fs::create_dir_all(p.parent().unwrap()).unwrap();
        std::fs::write(p, bytes).unwrap();
    }
    scene::load(&dir.path().join(files[0].0))
}

/// The error of a scene that must be refused.
fn refused(files: &[(&str, &[u8])]) -> String {
    match load_files(files) {
        Ok(_) => panic!("the scene loaded, but should be refused"),
        Err(e) => e.to_string(),
    }
}

/// gltf target: a GLB whose header gives a total length under its own 12
/// bytes. The gltf crate (1.4.1) subtracts 12 from it unchecked, a panic
/// in debug builds ("attempt to subtract with overflow"); it is now
/// refused before the crate sees it.
#[test]
fn glb_shorter_than_its_header_is_refused() {
    let glb = b"glTF\0\0\0\0\0\0\0\0";
    let msg = refused(&[("scene.glb", glb)]);
    assert!(
        msg.contains("scene.glb") && msg.contains("claims 0 bytes, fewer than the 12"),
        "{msg}"
    );
}
