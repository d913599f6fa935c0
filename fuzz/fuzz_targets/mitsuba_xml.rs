//! Mitsuba 3 XML: the main scene plus included XML files, meshes (OBJ, PLY) and other side files.
//! The input is in the container format of `kalos_fuzz` (main file first).
#![no_main]

use libfuzzer_sys::fuzz_target;

fuzz_target!(init: kalos_fuzz::init(), |data: &[u8]| {
    kalos_fuzz::run("scene.xml", data);
});
