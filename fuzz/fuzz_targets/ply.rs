//! PLY, ASCII and binary: the whole input is the one PLY file.
#![no_main]

use libfuzzer_sys::fuzz_target;

fuzz_target!(init: kalos_fuzz::init(), |data: &[u8]| {
    let (_dir, path) =
        kalos_fuzz::write_scene("scene.ply", data, &[]).expect("writing the scene file");
    kalos_fuzz::check(&path);
});
