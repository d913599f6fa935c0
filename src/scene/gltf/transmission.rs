//! `KHR_materials_ior` (the index of refraction of a glTF dielectric) and
//! `KHR_materials_transmission` with `KHR_materials_volume` (glass): see
//! the module doc of [`super`] for how they map.

use std::path::Path;

use super::{name_of, warn, Textures, DIELECTRIC_IOR, MIN_ALPHA};
use crate::scene::{Material, MicrofacetKind, Rgb, Scene, Texture};

/// The index of refraction of material `m`: `KHR_materials_ior`'s `ior`,
/// [`DIELECTRIC_IOR`] (the extension's default, F0 = 0.04) without it.
/// 0 is kept: the extension's special value, F = 1 at every angle (the
/// callers make it a white mirror). Values the extension does not allow
/// (below 1 other than 0, or not finite) are read as the default, with a
/// warning.
pub(super) fn ior(m: &gltf::Material, scene: &mut Scene, path: &Path) -> f32 {
    let Some(ior) = m.ior() else {
        return DIELECTRIC_IOR;
    };
    if ior == 0.0 || (ior >= 1.0 && ior.is_finite()) {
        return ior;
    }
    warn(
        scene,
        path,
        format!(
            "material `{}`: KHR_materials_ior {ior} is outside the extension's range \
             (0, or at least 1): read as {DIELECTRIC_IOR}",
            name_of(m)
        ),
    );
    DIELECTRIC_IOR
}

/// The dielectric of `KHR_materials_ior` = 0, whose Fresnel term is 1 at
/// every angle: all light goes to the specular layer, so the surface is a
/// white mirror (a perfect-mirror `conductor`, or a GGX `roughconductor`
/// with α = roughness², at least [`MIN_ALPHA`]); the base colour is not
/// seen.
pub(crate) fn mirror(roughness: f32) -> Material {
    let (eta, k, specular_reflectance) = (Rgb::ZERO, Rgb::ONE, Texture::Constant(Rgb::ONE));
    if roughness <= 0.0 {
        Material::Conductor {
            eta,
            k,
            specular_reflectance,
        }
    } else {
        Material::RoughConductor {
            distribution: MicrofacetKind::Ggx,
            alpha: (roughness * roughness).max(MIN_ALPHA),
            eta,
            k,
            specular_reflectance,
        }
    }
}

/// Transmission at or above which a material is read as glass (below it,
/// as the opaque dielectric): kalos has no mix of two BSDFs, so a
/// fractional `transmissionFactor` is thresholded, as `metallic` is.
const GLASS_THRESHOLD: f32 = 0.5;

/// The glass of a non-metal material `m` with `KHR_materials_transmission`
/// (`None` when it has none, or its transmission is below
/// [`GLASS_THRESHOLD`]): a `dielectric` (solid: its `KHR_materials_volume`
/// has `thicknessFactor` > 0; a GGX `roughdielectric` of α = roughness²,
/// at least [`MIN_ALPHA`], when roughness > 0) or `thindielectric`
/// (thin-walled, as the extension says without a volume), of index `ior`
/// ([`ior`]), reflecting white and transmitting the base colour
/// (`factor` × `baseColorTexture`, sRGB). Approximations, each with a
/// warning once per material: a `transmissionTexture` is averaged over the
/// image (red channel) and thresholded with its factor; a fractional
/// transmission is thresholded; a rough thin-walled one is the smooth pane
/// (Mitsuba has no rough `thindielectric`, and a rough interface on each
/// face of a pane has no closed form); the volume's attenuation is dropped;
/// `ior` = 0 (F = 1) is the white mirror of [`mirror`].
pub(super) fn glass(
    m: &gltf::Material,
    factor: Rgb,
    roughness: f32,
    ior: f32,
    textures: &mut Textures,
) -> Option<Material> {
    let tr = m.transmission()?;
    let name = name_of(m);
    let mut t = tr.transmission_factor();
    if !t.is_finite() {
        t = 0.0;
    }
    let mut t = t.clamp(0.0, 1.0);
    let mut notes = Vec::new();
    if let Some(info) = tr.transmission_texture() {
        if let Some(tex) = textures.texture(&info, Rgb::ONE, false, "transmission") {
            t *= tex.mean().x.clamp(0.0, 1.0);
            notes.push(format!(
                "its transmissionTexture is averaged over the image (mean transmission {t:.3})"
            ));
        }
    }
    let glass = t >= GLASS_THRESHOLD;
    if t > 0.0 && t < 1.0 {
        notes.push(format!(
            "transmission {t:.3} is thresholded at {GLASS_THRESHOLD} (kalos has no mix of \
             glass and the opaque dielectric): read as {}",
            if glass { "glass" } else { "opaque" }
        ));
    }
    let volume = m.volume();
    let solid = volume.as_ref().is_some_and(|v| v.thickness_factor() > 0.0);
    if glass && roughness > 0.0 && ior != 0.0 && !solid {
        notes.push(format!(
            "rough thin-walled transmission (roughness {roughness}) is read as a smooth pane: \
             kalos has no rough thin dielectric"
        ));
    }
    if let (true, Some(v)) = (glass, &volume) {
        let d = v.attenuation_distance();
        if d.is_finite() && d > 0.0 {
            notes.push(format!(
                "the volume's attenuation (distance {d}) is not read: the glass is clear"
            ));
        }
    }
    if !notes.is_empty() {
        warn(
            textures.scene,
            textures.path,
            format!("material `{name}`: {}", notes.join("; ")),
        );
    }
    if !glass {
        return None;
    }
    if ior == 0.0 {
        return Some(mirror(roughness));
    }
    let tint = match m.pbr_metallic_roughness().base_color_texture() {
        Some(info) => textures
            .texture(&info, factor, true, "base colour")
            .unwrap_or(Texture::Constant(factor)),
        None => Texture::Constant(factor),
    };
    let white = Texture::Constant(Rgb::ONE);
    Some(if solid && roughness > 0.0 {
        Material::RoughDielectric {
            distribution: MicrofacetKind::Ggx,
            alpha: (roughness * roughness).max(MIN_ALPHA),
            eta: ior,
            specular_reflectance: white,
            specular_transmittance: tint,
        }
    } else if solid {
        Material::Dielectric {
            eta: ior,
            specular_reflectance: white,
            specular_transmittance: tint,
        }
    } else {
        Material::ThinDielectric {
            eta: ior,
            specular_reflectance: white,
            specular_transmittance: tint,
        }
    })
}
