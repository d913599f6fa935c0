//! glTF 2.0 scenes (`.gltf` with its buffers and images, or `.glb`), through
//! the `gltf` crate.
//!
//! What is read, and how the metallic–roughness model maps onto kalos's
//! materials (a choice: glTF's BRDF is not one of Mitsuba's plugins):
//!
//! - every triangle primitive of every mesh node of the default scene, with
//!   the node's world transform (a negative determinant reverses the winding,
//!   as the glTF specification says), normals and the first uv set; the
//!   second uv set is kept in [`Scene::uv1`], and each shape records the
//!   node, mesh and primitive it came from ([`super::ShapeSource`]);
//! - `baseColorFactor` × `baseColorTexture` (sRGB) is the base colour.
//!   glTF mixes a metal and a dielectric BRDF by `metallic`; kalos takes one
//!   of the two, the metal where `metallicFactor` ≥ 0.5. Metals become a
//!   mirror-Fresnel `conductor` (roughness 0) or a GGX `roughconductor`
//!   with α = roughness² tinted by the base colour (glTF's F0 of a metal).
//!   Dielectrics become Mitsuba's `roughplastic` (`plastic` at roughness 0):
//!   a GGX coat with α = roughness² (at least 10⁻³, as the metals) and
//!   η = 1.5 over a Lambertian base of the base colour, `nonlinear` off.
//!   η = 1.5 is glTF's F0 = ((η − 1)/(η + 1))² = 0.04 exactly;
//!   `KHR_materials_ior` replaces it (see below). How this
//!   departs from the specification's `fresnel_mix(ior = 1.5, base =
//!   diffuse_brdf, layer = specular_brdf(α))` (Appendix B), which is
//!   (1 − F(v·h)) c/π + F(v·h) D V with Schlick's F:
//!   - the coat's Fresnel is the exact dielectric one for η = 1.5, not
//!     Schlick's: equal at normal incidence (0.04), they part most near
//!     85° (0.57 against Schlick's 0.61 at cos θ = 0.1; 0.036 at most);
//!   - D and G are the same (GGX, the separable Smith G);
//!   - the base is Mitsuba's separable ρ/(π η² (1 − R_int)) t(cos θo)
//!     t(cos θi), where glTF weights c/π by 1 − F(v·h), with glTF's coat
//!     ([`Coat::Gltf`]) in place of Mitsuba's: Mitsuba's rough coat
//!     transmits its single-scattering t(μ), which loses the light the
//!     rough interface shadows (at glTF's default roughness 1, α = 1,
//!     t(1) = 0.88 and t(0.5) = 0.65, so a white base looked 30 % dark);
//!     glTF's coat transmits all it does not reflect, t(μ) = 1 − r(μ)
//!     with r(μ) the coat's directional reflectance, and the base colour
//!     is scaled (in [`crate::bsdf`], per hit) by η² (1 − R_int)/T̄ (T̄ =
//!     2∫ t(μ) μ dμ), so that the diffuse albedo seen from cos θo = μ is
//!     c t(μ) = c (1 − r(μ)): a white dielectric reflects 1 (furnace
//!     test), and the hue is the base colour's (`nonlinear` off). glTF's
//!     (1 − F(v·h)) c/π reflects c (1 − r(μ)) too, up to how F(v·h)
//!     averages over the lobe's half vectors;
//!   - `KHR_materials_specular`: `specularFactor` w weights the specular
//!     layer (the coat's lobe is scaled by w × `specularColorFactor`, and
//!     t(μ) = 1 − w r(μ)); w = 0 is a plain `diffuse`, exactly the
//!     specification's. The tint colours the whole lobe, where the
//!     specification tints F0 only (F90 stays w), and the diffuse part
//!     loses the untinted r(μ); the extension's textures are not read
//!     (a warning says so).
//!
//!   Mapping onto `roughplastic` keeps the Mitsuba model's sampling, its
//!   chi-square and furnace tests, and its diffuse part
//!   ([`crate::bsdf::Bsdf::diffuse_part`]), which the density method and
//!   the lightmap bake store;
//! - a `metallicRoughnessTexture` (linear: blue the metalness, green the
//!   roughness, times their factors) is read per texel, at each hit
//!   ([`super::material::MetallicRoughness`]): a texel is the metal or the
//!   dielectric above by the same 0.5 threshold, with α = roughness² (at
//!   least 10⁻³, so a smooth texel is a very sharp GGX lobe rather than a
//!   mirror); the dielectric's coat tables (and so its base's gain) are
//!   taken at the roughness rounded to 1/32, its D and G at the exact α;
//! - `KHR_texture_transform` on the textures read (base colour,
//!   metallic–roughness, emissive): scale, rotation and offset, applied to
//!   the uvs before the lookup, as the extension's matrix; its `texCoord`
//!   overrides the texture's;
//! - `KHR_materials_ior`: the dielectric's coat takes η = `ior`, so F0 =
//!   ((η − 1)/(η + 1))², and the base's gain is computed for that η (the
//!   coat tables are made per η), per texel too. `ior` = 0, the
//!   extension's special value (F = 1 at every angle: all light goes to
//!   the specular layer), is a white mirror (`conductor`, or
//!   `roughconductor` with α = roughness²; the base colour is not seen).
//!   An `ior` the extension does not allow (below 1 other than 0, not
//!   finite) is read as 1.5, with a warning. See `gltf/transmission.rs`;
//! - `KHR_materials_transmission` on a non-metal (`metallicFactor` < 0.5)
//!   is glass, of index η = `KHR_materials_ior` (1.5 without it),
//!   reflecting white and transmitting the base colour (factor × texture),
//!   as the extension's `specular_btdf` × `baseColor`: Mitsuba's
//!   `dielectric` when `KHR_materials_volume` has `thicknessFactor` > 0 (a
//!   solid: light refracts in and out; rough, `roughdielectric` with GGX
//!   α = roughness², at least 10⁻³), `thindielectric` otherwise (thin
//!   walls, as the extension says without a volume: straight through, the
//!   two faces' inter-reflections summed). Approximations, each named in
//!   a warning once per material: glTF mixes the glass and the opaque
//!   dielectric by the transmission t, kalos has no mix of two BSDFs, so t
//!   is thresholded at 0.5 (glass at or above, the opaque dielectric
//!   below), and a `transmissionTexture` is averaged over its image (red
//!   channel) into t first; thin-walled rough glass (roughness > 0, no
//!   volume) is the smooth pane (sharp where glTF's is frosted: the same
//!   Fresnel split of reflection and transmission, the blur lost), as
//!   Mitsuba has no rough `thindielectric`;
//!   the volume's attenuation (`attenuationDistance`, `attenuationColor`)
//!   is not read (clear glass); a `metallicRoughnessTexture` is not read
//!   on glass; `ior` = 0 makes it the white mirror above;
//! - `normalTexture` in tangent space, with the primitive's `TANGENT` or
//!   MikkTSpace tangents, tilts the shading normal at each hit, for every
//!   method (see `gltf/normalmap.rs`). Approximations: the density
//!   method and the lightmap bake store irradiance per area of the
//!   triangle, so the light their diffuse part receives ignores the map
//!   (the diffuse part's view-dependent factor, the glossy part and the
//!   other methods use the tilted normal); a normal tilted below the
//!   triangle is bent back to just above it;
//! - `doubleSided` → `twosided`;
//! - a non-zero `emissiveFactor` × `KHR_materials_emissive_strength` → an
//!   area emitter with that radiance (glTF's emission is unitless: it is
//!   read as W/(m²·sr), with a warning); negative emission is an error.
//!   An `emissiveTexture` (sRGB) multiplies it; kalos's area lights are
//!   uniform over their shape, so the texture is averaged over each
//!   primitive (area-weighted, four lookups per triangle), with a warning:
//!   the primitive's power is right, its pattern is lost;
//! - `KHR_lights_punctual` point, spot and directional lights on nodes,
//!   placed by the node's world transform, their candela and lux divided
//!   by 683 lm/W into W/sr and W/m² (Blender's exporter's convention;
//!   `range` ignored): see `gltf/lights.rs`;
//! - the first perspective camera (glTF cameras look along −z with +x to the
//!   right; kalos's along +z with +x to the left, so the camera's world
//!   transform is composed with diag(−1, 1, −1)). Without one, a camera is
//!   synthesised, with a warning.
//!
//! Skipped with a warning: non-triangle primitives, texture coordinate
//! sets other than the first, and every extension the file uses that is
//! not in [`READ_EXTENSIONS`] (named once). Ignored: samplers (every
//! texture wraps and is filtered bilinearly) and occlusion textures.
//!
//! Refused before anything is allocated: GLB lengths beyond the file, node
//! cycles, and node DAGs that instance more than [`super::MAX_TRIANGLES`]
//! triangles. A file with no emissive material and no punctual light is lit by a constant white
//! environment, with a note in [`Scene::notes`].
//!
//! The file, its buffers and its images are read through the scene's
//! [`FileAccess`], not by the `gltf` crate: a URI is a `data:` URI (decoded
//! in memory), or a relative path (percent-decoded, against the file's
//! folder) or a `file:` URI, read only if the access allows it. Every file the glTF names is checked before any is
//! read; the memory of its instanced meshes, its buffers and the images its
//! materials read (their sizes from the image headers) is declared
//! ([`FileAccess::reserve`]) before it is allocated. Images that no
//! material reads are checked, not read.

use crate::scene::access::{FileAccess, FileKind};
use std::path::{Path, PathBuf};
use std::sync::Arc;

use glam::{Mat3, Mat4, Vec2, Vec3};

use super::material::MetallicRoughness;
use super::shapes::MeshData;
use super::{
    CameraDesc, Coat, Material, MicrofacetKind, Rgb, Scene, SceneError, ShapeSource, TexImage,
    Texture,
};

/// Largest number of node instances visited: a node referenced from many
/// parents is walked once per path to it, so a small file can describe an
/// exponentially large tree.
mod checks;
mod lights;
pub mod normalmap;
mod read;
mod transmission;

use checks::*;
use read::*;
pub(crate) use read::{locate, Located};

const MAX_NODES: u64 = 1 << 20;

/// The extensions kalos reads; a file that uses any other gets a warning
/// naming it, once. `MOZ_lightmap` (kalos's own bake output) is read as the
/// asset it lights: kalos computes the lighting anew.
const READ_EXTENSIONS: &[&str] = &[
    "KHR_lights_punctual",
    "KHR_materials_emissive_strength",
    "KHR_materials_ior",
    "KHR_materials_specular",
    "KHR_materials_transmission",
    "KHR_materials_volume",
    "KHR_texture_transform",
    "MOZ_lightmap",
];

/// Loads a glTF 2.0 file as a scene.
pub fn load_gltf(path: &Path, access: &FileAccess) -> Result<Scene, SceneError> {
    let err = |msg: String| SceneError::new(path, 0, msg);
    let (doc, buffers, images) = import(path, access)?;
    let mut scene = Scene::empty(path.display().to_string());
    for ext in doc.extensions_used() {
        if !READ_EXTENSIONS.contains(&ext) {
            warn(
                &mut scene,
                path,
                format!("extension {ext} is not read: what it adds to the asset is ignored"),
            );
        }
    }

    // Materials, each with its emission
    let mut mats = Vec::new();
    let mut textures: Vec<[Option<Arc<TexImage>>; 2]> = vec![[None, None]; images.len()];
    let mut normal_maps = Vec::new();
    for m in doc.materials() {
        mats.push(material(&m, &images, &mut textures, &mut scene, path)?);
        normal_maps.push(normalmap::normal_texture(
            &m,
            &images,
            &mut textures,
            &mut scene,
            path,
        ));
    }

    // Walk the node tree of the default scene
    let gscene = doc
        .default_scene()
        .or_else(|| doc.scenes().next())
        .ok_or_else(|| err("glTF file has no scene".into()))?;
    check_instancing(&doc, &gscene, path)?;
    let mut walk = Walk {
        path,
        root: doc.as_json(),
        buffers: &buffers,
        mats: &mats,
        normal_maps: &normal_maps,
        default_mat: None,
        scene,
        camera_seen: false,
    };
    walk.nodes(&gscene)?;
    let Walk {
        mut scene,
        camera_seen,
        ..
    } = walk;
    if scene.triangles.is_empty() {
        return Err(err("glTF file has no triangles".into()));
    }
    if !scene.uv1.is_empty() {
        scene.uv1.resize(scene.positions.len(), Vec2::ZERO);
    }
    if !camera_seen {
        super::obj::synthesise_camera(&mut scene, path);
    }
    scene.light_if_dark(path);
    Ok(scene)
}

/// Adds a warning about the file to the scene.
fn warn(scene: &mut Scene, path: &Path, msg: String) {
    scene.warnings.push(format!("{}: {msg}", path.display()));
}

/// Adds one glTF material to the scene (see the module doc for the
/// mapping) and returns its index with its emission: the emitted radiance,
/// if any, and the emissive texture it is multiplied by, if any.
/// `textures` caches the decoded images, by image index and encoding
/// (`images` holds those a material reads).
fn material(
    m: &gltf::Material,
    images: &[Option<gltf::image::Data>],
    textures: &mut [[Option<Arc<TexImage>>; 2]],
    scene: &mut Scene,
    path: &Path,
) -> Result<MaterialEntry, SceneError> {
    let pbr = m.pbr_metallic_roughness();
    let f = pbr.base_color_factor();
    let factor = Rgb::new(f[0], f[1], f[2]);
    if !(factor.is_finite() && factor.min_element() >= 0.0) {
        return Err(SceneError::new(
            path,
            0,
            format!(
                "material {} `{}`: baseColorFactor must be non-negative, found ({}, {}, {})",
                m.index().map_or("?".into(), |i| i.to_string()),
                name_of(m),
                factor.x,
                factor.y,
                factor.z
            ),
        ));
    }
    let mut textures = Textures {
        m,
        images,
        cache: textures,
        scene,
        path,
    };
    let roughness = pbr.roughness_factor().clamp(0.0, 1.0);
    let metallic = pbr.metallic_factor();
    let metal = metallic >= 0.5;
    let specular = specular(m, textures.scene, path)?;
    let ior = transmission::ior(m, textures.scene, path);
    let mr = pbr
        .metallic_roughness_texture()
        .and_then(|info| textures.texture(&info, Rgb::ONE, false, "metallic-roughness"));
    let glass = if metal {
        None
    } else {
        transmission::glass(m, factor, roughness, ior, &mut textures)
    };
    let material = if let Some(glass) = glass {
        glass
    } else if let Some(mr) = mr {
        // metalness and roughness per texel. A constant base colour is a
        // one-texel bitmap: the diffuse part varies over the surface with
        // the texels' metalness and roughness, and a bitmap says so to
        // those who ask whether it does (the density method's surfaces)
        let constant = || Texture::Bitmap {
            image: Arc::new(TexImage::new(1, 1, vec![factor])),
            to_uv: glam::Affine2::IDENTITY,
        };
        let base_color = match pbr.base_color_texture() {
            Some(info) => textures
                .texture(&info, factor, true, "base colour")
                .unwrap_or_else(constant),
            None => constant(),
        };
        Material::MetallicRoughness(Box::new(MetallicRoughness {
            base_color,
            metallic: if metallic.is_finite() { metallic } else { 0.0 },
            roughness,
            metallic_roughness: mr,
            specular: specular.weight,
            specular_tint: specular.tint,
            ior,
        }))
    } else {
        let base = match pbr.base_color_texture() {
            Some(info) => textures
                .texture(&info, factor, true, "base colour")
                .unwrap_or(Texture::Constant(factor)),
            None => Texture::Constant(factor),
        };
        if metal {
            // a perfect-mirror Fresnel (eta 0, k 1) scaled by the base colour
            let (eta, k) = (Rgb::ZERO, Rgb::ONE);
            if roughness <= 0.0 {
                Material::Conductor {
                    eta,
                    k,
                    specular_reflectance: base,
                }
            } else {
                Material::RoughConductor {
                    distribution: MicrofacetKind::Ggx,
                    alpha: (roughness * roughness).max(MIN_ALPHA),
                    eta,
                    k,
                    specular_reflectance: base,
                }
            }
        } else {
            dielectric(base, roughness, ior, specular)
        }
    };
    let emissive = m
        .emissive_texture()
        .and_then(|info| textures.texture(&info, Rgb::ONE, true, "emissive"));
    let material = if m.double_sided() {
        Material::TwoSided(Box::new(material))
    } else {
        material
    };
    let emission = emission(m, scene, path)?;
    let emissive = match (emission, emissive) {
        (Some(_), Some(t)) => {
            warn(
                scene,
                path,
                format!(
                    "material `{}`: kalos's area lights are uniform, so the emissive \
                     texture is averaged over each primitive it covers",
                    name_of(m)
                ),
            );
            Some(t)
        }
        _ => None,
    };
    Ok((scene.add_material(material), emission, emissive))
}

/// `KHR_texture_transform`'s map of glTF uvs: scale, then rotate by
/// `rotation` radians (u' = u cos r + v sin r, v' = −u sin r + v cos r:
/// counter-clockwise in glTF's uv space, whose v points down), then
/// offset, as the extension's `translation * rotation * scale`. Non-finite
/// values leave the uvs as they are.
fn texture_transform(offset: [f32; 2], rotation: f32, scale: [f32; 2]) -> glam::Affine2 {
    let (o, s) = (Vec2::from(offset), Vec2::from(scale));
    if !(o.is_finite() && s.is_finite() && rotation.is_finite()) {
        return glam::Affine2::IDENTITY;
    }
    let (sin, cos) = rotation.sin_cos();
    let r = glam::Mat2::from_cols(Vec2::new(cos, -sin), Vec2::new(sin, cos));
    glam::Affine2::from_mat2_translation(r * glam::Mat2::from_diagonal(s), o)
}

/// A glTF material's scene index, its emitted radiance (`emissiveFactor`
/// × strength) and its emissive texture.
type MaterialEntry = (u32, Option<Rgb>, Option<Texture>);

/// What reading one material's textures needs: the material (for
/// warnings), the decoded images and their cache, and the scene.
struct Textures<'a, 'm> {
    m: &'a gltf::Material<'m>,
    images: &'a [Option<gltf::image::Data>],
    /// Each image as a linear texture, by image index, then 0 for linear
    /// data and 1 for sRGB.
    cache: &'a mut [[Option<Arc<TexImage>>; 2]],
    scene: &'a mut Scene,
    path: &'a Path,
}

impl Textures<'_, '_> {
    /// The texture `info` names (its `what`, for warnings): the image
    /// (decoded once, as sRGB when `srgb`, else as linear values) times
    /// `factor`; `None`, with a warning, when the image's format is not
    /// supported.
    fn texture(
        &mut self,
        info: &gltf::texture::Info,
        factor: Rgb,
        srgb: bool,
        what: &str,
    ) -> Option<Texture> {
        let i = info.texture().source().index();
        let transform = info.texture_transform();
        let tex_coord = transform
            .as_ref()
            .and_then(|t| t.tex_coord())
            .unwrap_or(info.tex_coord());
        if tex_coord != 0 {
            warn(
                self.scene,
                self.path,
                format!("material `{}`: only uv set 0 is read", name_of(self.m)),
            );
        }
        let slot = self.cache.get_mut(i).map(|c| &mut c[srgb as usize]);
        let img = match slot {
            Some(Some(img)) => Some(img.clone()),
            slot => {
                let img = self
                    .images
                    .get(i)
                    .and_then(Option::as_ref)
                    .and_then(|d| to_tex_image(d, srgb))
                    .map(Arc::new);
                if let (Some(img), Some(slot)) = (&img, slot) {
                    *slot = Some(img.clone());
                }
                img
            }
        };
        let Some(img) = img else {
            warn(
                self.scene,
                self.path,
                format!(
                    "material `{}`: unsupported {what} texture format (ignored)",
                    name_of(self.m)
                ),
            );
            return None;
        };
        let img = if factor == Rgb::ONE {
            img
        } else {
            Arc::new(img.map(|c| c * factor))
        };
        // glTF's uv (0, 0) is the image's top-left corner, as Mitsuba's;
        // TexImage puts v = 0 at the bottom
        let flip = glam::Affine2::from_mat2_translation(
            glam::Mat2::from_diagonal(Vec2::new(1.0, -1.0)),
            Vec2::new(0.0, 1.0),
        );
        let to_uv = match transform {
            Some(t) => flip * texture_transform(t.offset(), t.rotation(), t.scale()),
            None => flip,
        };
        Some(Texture::Bitmap { image: img, to_uv })
    }
}

/// Relative index of refraction of glTF's dielectric: F0 = ((η − 1)/(η + 1))²
/// = 0.04, as the specification's `fresnel_mix(ior = 1.5, …)`.
pub(crate) const DIELECTRIC_IOR: f32 = 1.5;

/// Smallest GGX α of a rough glTF surface (α = roughness²): below it the
/// lobe's peak outruns f32, and the surface is a mirror to the eye anyway.
pub(crate) const MIN_ALPHA: f32 = 1e-3;

/// glTF's dielectric (`metallic` = 0) with base colour `base`,
/// perceptual roughness `roughness` ∈ [0, 1] and index `eta`
/// (`KHR_materials_ior`, [`DIELECTRIC_IOR`] without it): a GGX coat of
/// index `eta` (α = roughness², at least [`MIN_ALPHA`]) over a Lambertian
/// base, as `roughplastic` (`plastic` when the roughness is 0) with glTF's
/// coat ([`Coat::Gltf`]); `eta` = 0 is the extension's F = 1, a white
/// mirror ([`transmission::mirror`]); a plain `diffuse` when
/// `KHR_materials_specular` gives the specular layer no weight. See the
/// module doc for how this differs from the specification's `fresnel_mix`.
pub(crate) fn dielectric(base: Texture, roughness: f32, eta: f32, specular: Specular) -> Material {
    if specular.weight <= 0.0 {
        // the specification's fresnel_mix with F0 = F90 = 0: c/π exactly
        return Material::Diffuse { reflectance: base };
    }
    if eta == 0.0 {
        return transmission::mirror(roughness);
    }
    let specular_reflectance = Texture::Constant(specular.tint * specular.weight);
    let coat = Coat::Gltf {
        specular: specular.weight,
    };
    if roughness <= 0.0 {
        Material::Plastic {
            diffuse_reflectance: base,
            specular_reflectance,
            eta,
            nonlinear: false,
            coat,
        }
    } else {
        Material::RoughPlastic {
            diffuse_reflectance: base,
            specular_reflectance,
            distribution: MicrofacetKind::Ggx,
            alpha: (roughness * roughness).max(MIN_ALPHA),
            eta,
            nonlinear: false,
            coat,
        }
    }
}

/// A dielectric's specular layer as `KHR_materials_specular` sets it: its
/// weight w (`specularFactor`, in [0, 1]) and its tint
/// (`specularColorFactor`, at most 1/F0 = 25 per channel, where the
/// specification clamps F0 × tint to 1). Without the extension, w = 1 and
/// a white tint.
#[derive(Clone, Copy, Debug)]
pub(crate) struct Specular {
    pub weight: f32,
    pub tint: Rgb,
}

/// The material's [`Specular`] layer. Its textures (`specularTexture`,
/// `specularColorTexture`) are not read: a warning says so, once per
/// material.
fn specular(m: &gltf::Material, scene: &mut Scene, path: &Path) -> Result<Specular, SceneError> {
    let Some(ext) = m.specular() else {
        return Ok(Specular {
            weight: 1.0,
            tint: Rgb::ONE,
        });
    };
    let (w, c) = (
        ext.specular_factor(),
        Rgb::from(ext.specular_color_factor()),
    );
    if !(w.is_finite() && w >= 0.0 && c.is_finite() && c.min_element() >= 0.0) {
        return Err(SceneError::new(
            path,
            0,
            format!(
                "material {} `{}`: KHR_materials_specular's specularFactor and \
                 specularColorFactor must be finite and non-negative, found {w} and ({}, {}, {})",
                m.index().map_or("?".into(), |i| i.to_string()),
                name_of(m),
                c.x,
                c.y,
                c.z
            ),
        ));
    }
    if ext.specular_texture().is_some() || ext.specular_color_texture().is_some() {
        warn(
            scene,
            path,
            format!(
                "material `{}`: KHR_materials_specular's textures are not read; its factors \
                 are used over the whole material",
                name_of(m)
            ),
        );
    }
    Ok(Specular {
        weight: w.min(1.0),
        tint: c.min(Rgb::splat(1.0 / 0.04)),
    })
}

/// A material's emitted radiance: `emissiveFactor` ×
/// `KHR_materials_emissive_strength`, `None` when black. Emission is
/// unitless in glTF, so a warning says how it is read.
fn emission(m: &gltf::Material, scene: &mut Scene, path: &Path) -> Result<Option<Rgb>, SceneError> {
    // KHR_materials_emissive_strength scales the [0, 1] factor (Blender
    // writes emission strengths above 1 this way)
    let e = Rgb::from(m.emissive_factor()) * m.emissive_strength().unwrap_or(1.0);
    if !(e.is_finite() && e.min_element() >= 0.0) {
        return Err(SceneError::new(
            path,
            0,
            format!(
                "material {} `{}`: emission (emissiveFactor × emissiveStrength) must be finite \
                 and non-negative, found ({}, {}, {})",
                m.index().map_or("?".into(), |i| i.to_string()),
                name_of(m),
                e.x,
                e.y,
                e.z
            ),
        ));
    }
    let emission = (e.max_element() > 0.0).then_some(e);
    if emission.is_some() {
        warn(
            scene,
            path,
            format!(
                "material `{}`: glTF emission is unitless; read as radiance ({}, {}, {}) \
                 W/(m²·sr){}",
                name_of(m),
                e.x,
                e.y,
                e.z,
                if m.emissive_strength().is_none() && e.max_element() <= 1.0 {
                    // an exporter's display white, not a lamp's output:
                    // Blender writes lamps as KHR_lights_punctual, and
                    // emission strengths above 1 as emissiveStrength
                    " (at most 1, as viewers show it: a dim light; the file has no \
                     KHR_materials_emissive_strength)"
                } else {
                    ""
                }
            ),
        );
    }
    Ok(emission)
}

/// The walk of a glTF scene's node tree: what it adds meshes with, and
/// the scene it adds them to.
struct Walk<'a> {
    path: &'a Path,
    /// The file's JSON, for the extensions the `gltf` crate does not check
    /// (`KHR_lights_punctual`).
    root: &'a gltf::json::Root,
    buffers: &'a [gltf::buffer::Data],
    /// Each glTF material's index in the scene, and its emission.
    mats: &'a [MaterialEntry],
    /// Each glTF material's normal texture, if it has one.
    normal_maps: &'a [Option<normalmap::NormalTexture>],
    /// The white diffuse material of primitives without one, once added.
    default_mat: Option<u32>,
    scene: Scene,
    /// Whether a camera was read (the first perspective one is used).
    camera_seen: bool,
}

impl Walk<'_> {
    /// Walks the nodes of `gscene` depth first, each with its world
    /// transform, adding their mesh primitives, their punctual lights and
    /// the first camera.
    fn nodes(&mut self, gscene: &gltf::Scene) -> Result<(), SceneError> {
        let mut stack: Vec<(gltf::Node, Mat4)> =
            gscene.nodes().map(|n| (n, Mat4::IDENTITY)).collect();
        while let Some((node, parent)) = stack.pop() {
            let world = parent * Mat4::from_cols_array_2d(&node.transform().matrix());
            if let Some(mesh) = node.mesh() {
                for (k, prim) in mesh.primitives().enumerate() {
                    self.primitive(&node, &mesh, k, &prim, world)?;
                }
            }
            lights::node_light(self.root, node.index(), world, &mut self.scene, self.path)?;
            if let (Some(cam), false) = (node.camera(), self.camera_seen) {
                if let Some(c) = camera(&cam, world) {
                    self.scene.camera = c;
                    self.camera_seen = true;
                }
            }
            for c in node.children() {
                stack.push((c, world));
            }
        }
        Ok(())
    }

    /// Adds primitive `k` of a node's mesh in world space, or skips it with
    /// a warning when it is not made of triangles or has no readable
    /// positions.
    fn primitive(
        &mut self,
        node: &gltf::Node,
        mesh: &gltf::Mesh,
        k: usize,
        prim: &gltf::Primitive,
        world: Mat4,
    ) -> Result<(), SceneError> {
        let (path, scene) = (self.path, &mut self.scene);
        let err = |msg: String| SceneError::new(path, 0, msg);
        if prim.mode() != gltf::mesh::Mode::Triangles {
            warn(
                scene,
                path,
                format!(
                    "mesh `{}`: non-triangle primitive skipped",
                    mesh.name().unwrap_or("?")
                ),
            );
            return Ok(());
        }
        check_accessor_types(prim)
            .map_err(|e| err(format!("mesh {} primitive {k}: {e}", mesh.index())))?;
        let buffers = self.buffers;
        let reader = prim.reader(|b| buffers.get(b.index()).map(|d| &d.0[..]));
        let Some(positions) = reader.read_positions() else {
            warn(
                scene,
                path,
                format!(
                    "mesh {} primitive {k}: no readable POSITION (missing, or outside \
                     its buffer): skipped",
                    mesh.index()
                ),
            );
            return Ok(());
        };
        let positions: Vec<Vec3> = positions.map(Vec3::from).collect();
        super::check_finite(
            path,
            &format!("mesh {} primitive {k}", mesh.index()),
            &positions,
        )?;
        let n = positions.len();
        let normals: Option<Vec<Vec3>> = reader
            .read_normals()
            .map(|it| it.map(Vec3::from).collect::<Vec<_>>())
            .filter(|v| v.len() == n);
        let uvs: Option<Vec<Vec2>> = reader
            .read_tex_coords(0)
            .map(|t| t.into_f32().map(Vec2::from).collect::<Vec<_>>())
            .filter(|v| v.len() == n);
        let uv1: Option<Vec<Vec2>> = reader
            .read_tex_coords(1)
            .map(|t| t.into_f32().map(Vec2::from).collect::<Vec<_>>())
            .filter(|v| v.len() == n);
        let flat: Vec<u32> = match reader.read_indices() {
            Some(ix) => ix.into_u32().collect(),
            None => (0..n as u32).collect(),
        };
        let indices = flat.chunks_exact(3).map(|t| [t[0], t[1], t[2]]).collect();
        let mut m = MeshData {
            positions,
            normals,
            uvs,
            indices,
        };
        // a normal map's tangents, in object space
        let normal_map = prim
            .material()
            .index()
            .and_then(|i| self.normal_maps.get(i)?.as_ref())
            .and_then(|tex| {
                let given = reader.read_tangents().map(|t| t.collect());
                let what = format!("mesh {} primitive {k}", mesh.index());
                Some((
                    tex,
                    normalmap::primitive_tangents(&m, given, scene, path, &what)?,
                ))
            });
        m.transform(&world);
        let mirrored = Mat3::from_mat4(world).determinant() < 0.0;
        if mirrored {
            m.reverse_winding();
        }
        let (material, emission) = match prim.material().index().and_then(|i| self.mats.get(i)) {
            Some((mat, Some(e), Some(tex))) => {
                let mean = surface_mean(tex, &m.positions, m.uvs.as_deref(), &m.indices);
                (*mat, Some(*e * mean).filter(|e| e.max_element() > 0.0))
            }
            Some(&(mat, e, _)) => (mat, e),
            None => {
                let d = *self.default_mat.get_or_insert_with(|| {
                    scene.add_material(Material::Diffuse {
                        reflectance: Texture::Constant(Rgb::ONE),
                    })
                });
                (d, None)
            }
        };
        let name = format!("{}.{k}", node.name().or(mesh.name()).unwrap_or("mesh"));
        let first_vertex = scene.positions.len() as u32;
        let shape = scene.add_mesh(
            name,
            &m.positions,
            m.normals.as_deref(),
            m.uvs.as_deref(),
            &m.indices,
            material,
            emission,
        );
        keep_uv1(scene, first_vertex, n, uv1.as_deref());
        let s = &scene.shapes[shape as usize];
        let kept = kept_triangles(
            &scene.triangles[s.first_tri as usize..][..s.tri_count as usize],
            &m.indices,
            first_vertex,
        );
        scene.shapes[shape as usize].source = Some(Box::new(ShapeSource {
            node: node.index() as u32,
            mesh: mesh.index() as u32,
            primitive: k as u32,
            first_vertex,
            vertex_count: n as u32,
            prim_triangles: m.indices.len() as u32,
            kept,
            mirrored,
        }));
        if let Some((tex, tangents)) = normal_map {
            normalmap::attach(scene, shape, tex, &tangents, world);
        }
        Ok(())
    }
}

/// Appends a primitive's TEXCOORD_1 (`n` vertices from `first_vertex`) to
/// [`Scene::uv1`], which stays empty until a primitive has one: then the
/// vertices before get zeros, as do later primitives without one.
fn keep_uv1(scene: &mut Scene, first_vertex: u32, n: usize, uv1: Option<&[Vec2]>) {
    if uv1.is_none() && scene.uv1.is_empty() {
        return;
    }
    scene.uv1.resize(first_vertex as usize, Vec2::ZERO);
    match uv1 {
        Some(t) => scene.uv1.extend_from_slice(t),
        None => scene.uv1.resize(first_vertex as usize + n, Vec2::ZERO),
    }
}

/// For each triangle the scene kept of a primitive (`kept`, on scene
/// vertices), the index of the primitive triangle (`all`, on the
/// primitive's vertices, which start at scene vertex `base`) it is; empty
/// when every triangle was kept. The scene keeps them in order, so one pass
/// matches them.
fn kept_triangles(kept: &[[u32; 3]], all: &[[u32; 3]], base: u32) -> Vec<u32> {
    if kept.len() == all.len() {
        return Vec::new();
    }
    let mut out = Vec::with_capacity(kept.len());
    let mut j = 0;
    for t in kept {
        let local = t.map(|i| i - base);
        while j < all.len() && all[j] != local {
            j += 1;
        }
        out.push(j as u32);
        j += 1;
    }
    out
}

/// The area-weighted mean of texture `tex` over a mesh (world-space
/// `positions`, `uvs` or uv (0, 0) throughout, triangles `indices`): on
/// each triangle the mean of its centroid and three points halfway from
/// it to the corners, weighted by the triangle's area. The mean of the
/// texels when the mesh has no area.
fn surface_mean(
    tex: &Texture,
    positions: &[Vec3],
    uvs: Option<&[Vec2]>,
    indices: &[[u32; 3]],
) -> Rgb {
    let uv = |i: u32| {
        uvs.and_then(|t| t.get(i as usize))
            .copied()
            .unwrap_or(Vec2::ZERO)
    };
    let (mut sum, mut area) = (Rgb::ZERO, 0.0f64);
    for t in indices {
        let p = t.map(|i| positions.get(i as usize).copied().unwrap_or(Vec3::ZERO));
        let a = 0.5 * (p[1] - p[0]).cross(p[2] - p[0]).length();
        if !(a > 0.0 && a.is_finite()) {
            continue;
        }
        let [u0, u1, u2] = t.map(uv);
        let c = (u0 + u1 + u2) / 3.0;
        let m = (tex.eval(c)
            + tex.eval((c + u0) * 0.5)
            + tex.eval((c + u1) * 0.5)
            + tex.eval((c + u2) * 0.5))
            * 0.25;
        sum += m * a;
        area += a as f64;
    }
    if area > 0.0 {
        sum / area as f32
    } else {
        tex.mean()
    }
}

/// A perspective glTF camera placed by `world`, as kalos's camera (`None`
/// for an orthographic camera, or one kalos cannot build).
fn camera(cam: &gltf::Camera, world: Mat4) -> Option<CameraDesc> {
    let gltf::camera::Projection::Perspective(p) = cam.projection() else {
        return None;
    };
    let aspect = p.aspect_ratio().filter(|a| *a > 0.0).unwrap_or(1.0);
    let height = 512u32;
    let width = ((height as f32 * aspect).round() as u32).clamp(1, 1 << 16);
    let to_world = world * Mat4::from_scale(Vec3::new(-1.0, 1.0, -1.0));
    let mut c = CameraDesc::from_fov(to_world, p.yfov().to_degrees(), "y", width, height)?;
    c.near_clip = p.znear().max(1e-6);
    Some(c)
}

fn name_of(m: &gltf::Material) -> String {
    m.name().unwrap_or("(unnamed)").to_string()
}

/// A decoded glTF image as linear RGB: 8- and 16-bit data are decoded
/// from sRGB when `srgb` (base colour and emissive textures are sRGB by
/// the specification, metallic–roughness ones linear), float data are
/// linear.
fn to_tex_image(d: &gltf::image::Data, srgb: bool) -> Option<TexImage> {
    use gltf::image::Format as F;
    let (channels, bytes, float) = match d.format {
        F::R8 => (1, 1, false),
        F::R8G8 => (2, 1, false),
        F::R8G8B8 => (3, 1, false),
        F::R8G8B8A8 => (4, 1, false),
        F::R16 => (1, 2, false),
        F::R16G16 => (2, 2, false),
        F::R16G16B16 => (3, 2, false),
        F::R16G16B16A16 => (4, 2, false),
        F::R32G32B32FLOAT => (3, 4, true),
        F::R32G32B32A32FLOAT => (4, 4, true),
    };
    let px = channels * bytes;
    let count = (d.width as usize).checked_mul(d.height as usize)?;
    if d.pixels.len() < count.checked_mul(px)? || count == 0 {
        return None;
    }
    let read = |b: &[u8]| -> f32 {
        match (bytes, float) {
            (1, _) => b[0] as f32 / 255.0,
            (2, _) => u16::from_le_bytes([b[0], b[1]]) as f32 / 65535.0,
            _ => f32::from_le_bytes([b[0], b[1], b[2], b[3]]),
        }
    };
    let decode = |c: f32| {
        if float || !srgb {
            c
        } else if c <= 0.04045 {
            c / 12.92
        } else {
            ((c + 0.055) / 1.055).powf(2.4)
        }
    };
    let data = d.pixels[..count * px]
        .chunks_exact(px)
        .map(|p| {
            let ch = |i: usize| decode(read(&p[i * bytes..(i + 1) * bytes]));
            match channels {
                1 => Rgb::splat(ch(0)),
                2 => Rgb::new(ch(0), ch(1), 0.0),
                _ => Rgb::new(ch(0), ch(1), ch(2)),
            }
        })
        .collect();
    Some(TexImage::new(d.width, d.height, data))
}
