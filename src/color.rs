//! Colour: the linear RGB type every layer passes around, and its
//! luminance. It sits on the ground floor, with `film`, `image_io`,
//! `geometry` and `sampling`, so that the film does not import the scene
//! (film → scene → pbrt loader → image_io → film was a circle); `scene`
//! re-exports both for its many users.

use glam::Vec3;

/// Linear RGB colour (radiance, reflectance, power...).
pub type Rgb = Vec3;

/// Rec. 709 luminance of a linear RGB colour.
#[inline]
pub fn luminance(c: Rgb) -> f32 {
    0.2126 * c.x + 0.7152 * c.y + 0.0722 * c.z
}
