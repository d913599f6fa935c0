//! The built-in default scene: Benedikt Bitterli's Cornell box (CC0, see
//! `scenes/cornell-box/LICENSE.txt`), embedded in the binary so that
//! `kalos render` works without any file.

use std::path::Path;

use super::{Scene, SceneError};

/// The Mitsuba XML of the built-in scene.
pub const CORNELL_BOX_XML: &str = include_str!("../../scenes/cornell-box/scene.xml");

/// Loads the built-in Cornell box.
pub fn cornell_box() -> Result<Scene, SceneError> {
    cornell_box_with(&[])
}

/// Loads the built-in Cornell box with `-D name=value` parameters (it has
/// `$spp`).
pub fn cornell_box_with(defines: &[(String, String)]) -> Result<Scene, SceneError> {
    super::mitsuba::load_str_with(
        CORNELL_BOX_XML,
        Path::new("."),
        "builtin:cornell-box",
        defines,
        &super::access::FileAccess::nothing(),
    )
}
