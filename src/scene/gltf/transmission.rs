//! `KHR_materials_ior`: the index of refraction of a glTF dielectric
//! (see the module doc of [`super`] for how it maps).

use std::path::Path;

use super::{name_of, warn, DIELECTRIC_IOR, MIN_ALPHA};
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

/// Warns that a material whose dielectric is resolved per texel (a
/// `metallicRoughnessTexture`) keeps the fixed index [`DIELECTRIC_IOR`]
/// when its `KHR_materials_ior` says otherwise.
pub(super) fn warn_fixed_ior(m: &gltf::Material, ior: f32, scene: &mut Scene, path: &Path) {
    if ior != DIELECTRIC_IOR {
        warn(
            scene,
            path,
            format!(
                "material `{}`: KHR_materials_ior {ior} is not applied with a \
                 metallicRoughnessTexture: its dielectric texels keep index {DIELECTRIC_IOR}",
                name_of(m)
            ),
        );
    }
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
