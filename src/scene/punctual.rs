//! Punctual lights: points, spots and directional lights, as glTF's
//! `KHR_lights_punctual` describes them, in kalos's radiometric units.
//!
//! A point or spot light is a point with a radiant intensity I (W/sr per
//! channel); a directional light is a direction with an irradiance E⊥
//! (W/m² per channel on a plane facing it). The spot's profile is the
//! extension's smooth falloff: I(θ) = I · s², s = clamp((cos θ − cos θ_o) /
//! (cos θ_i − cos θ_o), 0, 1), with θ measured from the spot's axis and θ_i,
//! θ_o the inner and outer cone angles.
//!
//! Their rendering is in [`crate::emitter`]: they are delta lights, reached
//! only by next-event estimation and emitted by light particles.

use glam::Vec3;

use super::Rgb;

/// The shape of a punctual light's emission.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum PunctualKind {
    /// A point radiating its intensity equally in every direction.
    Point,
    /// A point radiating inside a cone around `direction`, with the smooth
    /// falloff between the cosines of the inner and outer cone angles.
    Spot {
        /// cos θ_i: full intensity for cos θ ≥ this.
        cos_inner: f32,
        /// cos θ_o: nothing for cos θ ≤ this (cos_outer < cos_inner, or
        /// equal for a hard edge).
        cos_outer: f32,
    },
    /// Parallel light travelling along `direction` from infinitely far.
    Directional,
}

/// A punctual light in world space.
#[derive(Clone, Debug, PartialEq)]
pub struct PunctualLight {
    /// Point, spot or directional.
    pub kind: PunctualKind,
    /// Position (unused for a directional light).
    pub position: Vec3,
    /// Unit direction the light travels along: the spot's axis, the
    /// directional light's travel direction (unused for a point).
    pub direction: Vec3,
    /// Radiant intensity I in W/sr per channel (point and spot, on the
    /// spot's axis), or irradiance E⊥ in W/m² per channel (directional).
    pub intensity: Rgb,
    /// The light's name in the file, for messages.
    pub name: String,
}

impl PunctualLight {
    /// The spot falloff toward unit direction `w` (leaving the light): 1
    /// for a point light, 0 for a directional one (a pinhole or a point
    /// never sees it).
    #[inline]
    pub fn profile(&self, w: Vec3) -> f32 {
        match self.kind {
            PunctualKind::Point => 1.0,
            PunctualKind::Spot {
                cos_inner,
                cos_outer,
            } => spot_falloff(self.direction.dot(w), cos_inner, cos_outer),
            PunctualKind::Directional => 0.0,
        }
    }

    /// A short description, for the scene summary.
    pub fn describe(&self) -> String {
        let i = self.intensity;
        match self.kind {
            PunctualKind::Point => format!(
                "point '{}' at ({}, {}, {}), intensity ({}, {}, {}) W/sr",
                self.name, self.position.x, self.position.y, self.position.z, i.x, i.y, i.z
            ),
            PunctualKind::Spot {
                cos_inner,
                cos_outer,
            } => format!(
                "spot '{}' at ({}, {}, {}), intensity ({}, {}, {}) W/sr, cone {:.2}°..{:.2}°",
                self.name,
                self.position.x,
                self.position.y,
                self.position.z,
                i.x,
                i.y,
                i.z,
                cos_inner.clamp(-1.0, 1.0).acos().to_degrees(),
                cos_outer.clamp(-1.0, 1.0).acos().to_degrees()
            ),
            PunctualKind::Directional => format!(
                "directional '{}' along ({}, {}, {}), irradiance ({}, {}, {}) W/m²",
                self.name, self.direction.x, self.direction.y, self.direction.z, i.x, i.y, i.z
            ),
        }
    }
}

/// `KHR_lights_punctual`'s smooth spot falloff at cos θ = `c`:
/// clamp((c − cos θ_o)/(cos θ_i − cos θ_o), 0, 1)², a step at cos θ_o when
/// the two angles are equal.
#[inline]
pub fn spot_falloff(c: f32, cos_inner: f32, cos_outer: f32) -> f32 {
    let span = cos_inner - cos_outer;
    if span <= 1e-6 {
        return if c > cos_outer { 1.0 } else { 0.0 };
    }
    let s = ((c - cos_outer) / span).clamp(0.0, 1.0);
    s * s
}
