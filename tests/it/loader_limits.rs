//! Scene files whose few bytes describe something huge or endless: glTF node
//! cycles and multiplying instances, lying header lengths, include fan-out.
//! Each must end in a clear error naming the file, never an abort or a hang.
//! The inputs are small equivalents of the reproducers of issue 18, built
//! here in a temporary folder.

use std::path::{Path, PathBuf};

use kalos::scene;

/// A fresh temporary folder, removed when dropped.
fn tmp() -> tempfile::TempDir {
    tempfile::Builder::new()
        .prefix("kalos-limits-")
        .tempdir()
        .unwrap()
}

/// Loads `path`, expecting an error that names the file and holds every
/// needle (case-insensitive).
fn expect_error(path: &Path, needles: &[&str]) -> String {
    let e = match scene::load(path) {
        Ok(s) => panic!(
            "{}: loaded without error ({} triangles)",
            path.display(),
            s.triangles.len()
        ),
        Err(e) => e.to_string(),
    };
    let name = path.file_name().unwrap().to_str().unwrap();
    assert!(e.contains(name), "the error does not name `{name}`: {e}");
    for n in needles {
        assert!(
            e.to_lowercase().contains(&n.to_lowercase()),
            "`{n}` not in: {e}"
        );
    }
    e
}

// ---------------------------------------------------------------------------
// glTF node graphs

/// Writes a glTF file with one one-triangle mesh (in `tri.bin`) and the given
/// nodes (JSON objects), the scene's roots being `roots`.
fn gltf_with_nodes(dir: &Path, name: &str, nodes: &[String], roots: &[usize]) -> PathBuf {
    let mut bin = Vec::new();
    for v in [0.0f32, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0, 0.0] {
        bin.extend(v.to_le_bytes());
    }
    std::fs::write(dir.join("tri.bin"), &bin).unwrap();
    let json = format!(
        r#"{{"asset":{{"version":"2.0"}},"scene":0,"scenes":[{{"nodes":{roots:?}}}],
        "nodes":[{}],
        "meshes":[{{"primitives":[{{"attributes":{{"POSITION":0}}}}]}}],
        "accessors":[{{"bufferView":0,"componentType":5126,"count":3,"type":"VEC3",
                       "min":[0,0,0],"max":[1,1,0]}}],
        "bufferViews":[{{"buffer":0,"byteOffset":0,"byteLength":36}}],
        "buffers":[{{"byteLength":36,"uri":"tri.bin"}}]}}"#,
        nodes.join(",")
    );
    let p = dir.join(name);
    std::fs::write(&p, json).unwrap();
    p
}

#[test]
fn gltf_node_cycles_are_errors() {
    let d = tmp();
    // a node that is its own child (reproducer r1)
    let p = gltf_with_nodes(
        d.path(),
        "self.gltf",
        &[r#"{"mesh":0,"children":[0]}"#.into()],
        &[0],
    );
    expect_error(&p, &["node 0", "own child"]);
    // a longer cycle below a root: 0 → 1 → 2 → 1
    let p = gltf_with_nodes(
        d.path(),
        "cycle.gltf",
        &[
            r#"{"children":[1]}"#.into(),
            r#"{"mesh":0,"children":[2]}"#.into(),
            r#"{"children":[1]}"#.into(),
        ],
        &[0],
    );
    expect_error(&p, &["node 1", "own ancestor"]);
}

#[test]
fn gltf_shared_nodes_load_until_they_multiply_too_far() {
    let d = tmp();
    // node k has node k+1 twice as a child: 2^levels instances of the mesh
    let chain = |levels: usize| -> Vec<String> {
        (0..levels)
            .map(|k| format!(r#"{{"children":[{},{}]}}"#, k + 1, k + 1))
            .chain([r#"{"mesh":0}"#.to_string()])
            .collect()
    };
    // a small DAG is fine: 2^4 instances of the triangle
    let p = gltf_with_nodes(d.path(), "dag.gltf", &chain(4), &[0]);
    let s = scene::load(&p).unwrap_or_else(|e| panic!("{e}"));
    assert_eq!(s.triangles.len(), 16);
    // 2^40 instances: refused before any is made, with the count
    let p = gltf_with_nodes(d.path(), "huge.gltf", &chain(40), &[0]);
    expect_error(&p, &[&(1u64 << 40).to_string(), "triangles"]);
}
