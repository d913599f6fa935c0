//! glTF 2.0: a JSON .gltf with its buffers and images as side files, or a
//! GLB (the main file is written as `scene.glb` when it starts with the
//! GLB magic `glTF`, else as `scene.gltf`). The input is in the container
//! format of `kalos_fuzz`.
#![no_main]

use libfuzzer_sys::fuzz_target;

fuzz_target!(init: kalos_fuzz::init(), |data: &[u8]| {
    let (main, parts) = kalos_fuzz::split(data);
    let name = if main.starts_with(b"glTF") {
        "scene.glb"
    } else {
        "scene.gltf"
    };
    let (_dir, path) =
        kalos_fuzz::write_scene(name, main, &parts).expect("writing the scene files");
    kalos_fuzz::check(&path);
});
