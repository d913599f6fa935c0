//! `KHR_lights_punctual`: the point, spot and directional lights of glTF
//! nodes, in radiometric units.
//!
//! The extension gives point and spot intensities in candela (lm/sr) and
//! directional ones in lux (lm/m²). kalos renders radiometric RGB, so a
//! light's `color` × `intensity` is divided by 683 lm/W (the luminous
//! efficacy at 555 nm, the extension's "physically based" reading): candela
//! become W/sr and lux W/m². This is also the convention of Blender's
//! exporter (its default "Standard" lighting mode writes a point or spot
//! lamp of P watts as P/(4π) · 683 cd, and a sun of S W/m² as S · 683 lx),
//! and Cycles renders a point lamp of P watts with intensity P/(4π) W/sr and
//! a sun of strength S with irradiance S W/m²: a Blender lamp comes back
//! with the power Blender renders it with.
//!
//! Approximations: `range` is ignored (the light falls off as 1/d² without
//! a cutoff, as the extension's physically based reading has it), with a
//! warning; Blender's spot blend (a smoothstep over its own parameter) is
//! read as the extension's falloff between the exported cone angles, so a
//! Blender spot's edge differs slightly in shape; Blender's lamp radius
//! (soft shadows) is not exported and lights are points.

use std::path::Path;

use glam::{Mat4, Vec3};
use gltf::json::extensions::scene::khr_lights_punctual::{Light, Type};
use gltf::json::validation::Checked;

use super::warn;
use crate::scene::{EmitterDesc, PunctualKind, PunctualLight, Rgb, Scene, SceneError};

/// Luminous efficacy used to turn photometric into radiometric units (lm/W).
pub const LUMENS_PER_WATT: f32 = 683.0;

/// Adds the punctual light of glTF node `node` (if it has one), placed by
/// the node's world transform `world`: its origin is the light's position
/// and its −z axis the direction a spot or directional light points to.
/// Lights of zero intensity add nothing. Malformed lights are errors.
pub(super) fn node_light(
    root: &gltf::json::Root,
    node: usize,
    world: Mat4,
    scene: &mut Scene,
    path: &Path,
) -> Result<(), SceneError> {
    let Some(ext) = root
        .nodes
        .get(node)
        .and_then(|n| n.extensions.as_ref())
        .and_then(|e| e.khr_lights_punctual.as_ref())
    else {
        return Ok(());
    };
    let err = |msg: String| SceneError::new(path, 0, format!("node {node}: {msg}"));
    let index = ext.light.value();
    let light = root
        .extensions
        .as_ref()
        .and_then(|e| e.khr_lights_punctual.as_ref())
        .and_then(|l| l.lights.get(index))
        .ok_or_else(|| {
            err(format!(
                "KHR_lights_punctual light {index} does not exist (the file's \
                 extensions.KHR_lights_punctual.lights has no such entry)"
            ))
        })?;
    let name = light
        .name
        .clone()
        .unwrap_or_else(|| format!("light {index}"));
    let Some(desc) = describe(light, &name, world, scene, path).map_err(err)? else {
        return Ok(());
    };
    scene.emitters.push(EmitterDesc::Punctual(desc));
    Ok(())
}

/// The light `light` placed by `world`, in watts; None when it emits
/// nothing. Errors say what is wrong with the light.
fn describe(
    light: &Light,
    name: &str,
    world: Mat4,
    scene: &mut Scene,
    path: &Path,
) -> Result<Option<PunctualLight>, String> {
    let ty = match &light.type_ {
        Checked::Valid(t) => *t,
        Checked::Invalid => {
            return Err(format!(
                "light `{name}`: type must be \"point\", \"spot\" or \"directional\""
            ))
        }
    };
    let color = Rgb::from(light.color);
    if !(color.is_finite() && color.min_element() >= 0.0) {
        return Err(format!(
            "light `{name}`: color must be finite and non-negative, found ({}, {}, {})",
            color.x, color.y, color.z
        ));
    }
    if !(light.intensity.is_finite() && light.intensity >= 0.0) {
        return Err(format!(
            "light `{name}`: intensity must be finite and non-negative, found {}",
            light.intensity
        ));
    }
    let intensity = color * (light.intensity / LUMENS_PER_WATT);
    if intensity.max_element() <= 0.0 {
        return Ok(None);
    }
    if light.range.is_some() {
        warn(
            scene,
            path,
            format!("light `{name}`: range ignored (the light falls off as 1/d² without a cutoff)"),
        );
    }
    let position = world.transform_point3(Vec3::ZERO);
    let direction = world.transform_vector3(Vec3::NEG_Z).normalize_or_zero();
    if !position.is_finite() || direction == Vec3::ZERO || !direction.is_finite() {
        return Err(format!(
            "light `{name}`: the node's world transform is degenerate (no position or -z axis)"
        ));
    }
    let kind = match ty {
        Type::Point => PunctualKind::Point,
        Type::Directional => PunctualKind::Directional,
        Type::Spot => {
            let (inner, outer) = light
                .spot
                .as_ref()
                .map_or((0.0, std::f32::consts::FRAC_PI_4), |s| {
                    (s.inner_cone_angle, s.outer_cone_angle)
                });
            if !(inner.is_finite() && outer.is_finite()) {
                return Err(format!("light `{name}`: spot cone angles must be finite"));
            }
            // The specification: 0 ≤ inner < outer ≤ π/2
            let outer_c = outer.clamp(0.0, std::f32::consts::FRAC_PI_2);
            let inner_c = inner.clamp(0.0, outer_c);
            if (outer_c, inner_c) != (outer, inner) {
                warn(
                    scene,
                    path,
                    format!(
                        "light `{name}`: spot cone angles ({inner}, {outer}) clamped to \
                         0 ≤ inner ≤ outer ≤ π/2"
                    ),
                );
            }
            PunctualKind::Spot {
                cos_inner: inner_c.cos(),
                cos_outer: outer_c.cos(),
            }
        }
    };
    Ok(Some(PunctualLight {
        kind,
        position,
        direction,
        intensity,
        name: name.to_string(),
    }))
}
