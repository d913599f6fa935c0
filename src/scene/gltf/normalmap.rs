//! glTF normal maps (`normalTexture`) in tangent space.
//!
//! A material's `normalTexture` is read as a linear texture (its
//! `KHR_texture_transform` and `texCoord` as for the other textures) with
//! its `scale`. Each primitive with such a material gets a tangent frame
//! per triangle corner, kept on its shape ([`NormalMap`]): shapes without a
//! normal map store nothing.
//!
//! - **Tangents.** The primitive's `TANGENT` (xyz the tangent, w = ±1 the
//!   bitangent's sign) when it has one and also has `NORMAL` (without
//!   normals the specification says that tangents are ignored); otherwise
//!   MikkTSpace tangents, as the specification asks, from the primitive's
//!   positions, normals (the faces' own where it has none) and uvs. Both in
//!   object space, then taken to world space by the node's transform (the
//!   tangent as a direction, M t; w times the sign of det M, since the
//!   normals go by the inverse transpose and the bitangent must follow
//!   M b). MikkTSpace is given the uvs as (u, 1 − v): glTF's v points down
//!   the image, and the convention its normal maps are baked in (Blender's,
//!   whose exporter writes `TANGENT` from MikkTSpace on its own v-up uvs;
//!   three.js and the Khronos sample models agree) is a bitangent toward
//!   the image's top, where +Y (green) points.
//! - **The MikkTSpace crate** is `bevy_mikktspace` (1.x): a safe Rust
//!   translation of Mikkelsen's reference C code that gives the same
//!   tangents as the C code, with no dependency and no unsafe code,
//!   released with the Bevy engine, which generates its glTF tangents with
//!   it. The older `mikktspace` crate of the `gltf` project has not been
//!   released since 2021 and brings nalgebra or an old glam.
//! - **At a hit** ([`NormalMap::perturb`]): the corners' tangents are
//!   interpolated, made orthogonal to the shading normal N (the
//!   interpolated vertex normal, or the face's), B = w N × T, and the
//!   texel c (linear, [0, 1]) gives n' = normalize(T x s + B y s + N z) with
//!   (x, y, z) = 2c − 1 and s = `normalTexture.scale`, as the
//!   specification writes it. A normal map that tilts n' below the
//!   triangle's plane is bent back to just above it (its tilt's azimuth
//!   kept), so that the shading normal stays on the geometric normal's
//!   side, as the loaders' interpolated normals do.

use std::path::Path;
use std::sync::Arc;

use glam::{Mat3, Mat4, Vec2, Vec3, Vec4};

use super::{name_of, texture_transform, to_tex_image, warn};
use crate::scene::shapes::MeshData;
use crate::scene::{Scene, Texture};

/// A tangent-space normal map on one shape: glTF's `normalTexture` and
/// the tangent frame of each of the shape's triangle corners.
#[derive(Clone, Debug)]
pub struct NormalMap {
    /// The normal texture, linear values in [0, 1] (its uv transform
    /// included).
    pub texture: Texture,
    /// `normalTexture.scale`, on the texel's x and y.
    pub scale: f32,
    /// For each of the shape's triangles, in order from its first, the
    /// world-space tangent (xyz, unit; zero where none could be made) and
    /// the bitangent's sign (w, ±1) at its three corners.
    pub tangents: Vec<[Vec4; 3]>,
}

/// Cosine with the geometric normal under which a perturbed normal is
/// bent back (see the module doc).
const MIN_COS: f32 = 1e-3;

impl NormalMap {
    /// The shading normal at barycentrics `b` (b0, b1, b2) of the shape's
    /// triangle `k` (counted from its first), at uv `uv`, from the
    /// unperturbed shading normal `n` and the geometric normal `ng` (both
    /// unit, on the same side): see the module doc. `n` itself where the
    /// triangle has no tangent.
    pub fn perturb(&self, k: u32, b: [f32; 3], uv: Vec2, n: Vec3, ng: Vec3) -> Vec3 {
        let Some(c) = self.tangents.get(k as usize) else {
            return n;
        };
        let t4 = c[0] * b[0] + c[1] * b[1] + c[2] * b[2];
        let t = t4.truncate();
        let Some(t) = (t - n * n.dot(t)).try_normalize() else {
            return n;
        };
        let w = if t4.w < 0.0 { -1.0 } else { 1.0 };
        let bt = n.cross(t) * w;
        let x = self.texture.eval(uv) * 2.0 - Vec3::ONE;
        let m = (t * (x.x * self.scale) + bt * (x.y * self.scale) + n * x.z).normalize_or(n);
        let d = m.dot(ng);
        if d >= MIN_COS {
            m
        } else {
            (m + ng * (MIN_COS - d)).normalize_or(n)
        }
    }
}

/// A glTF material's normal texture, as read for its primitives.
pub(super) struct NormalTexture {
    texture: Texture,
    scale: f32,
}

/// The normal texture of material `m`, if it has one that can be read:
/// its image decoded as linear values (cached in `cache` as the other
/// textures are), its uv transform (glTF's top-left origin, then
/// `KHR_texture_transform`) and its scale. A warning says why one is
/// skipped.
pub(super) fn normal_texture(
    m: &gltf::Material,
    images: &[Option<gltf::image::Data>],
    cache: &mut [[Option<Arc<crate::scene::TexImage>>; 2]],
    scene: &mut Scene,
    path: &Path,
) -> Option<NormalTexture> {
    let info = m.normal_texture()?;
    let scale = info.scale();
    if !scale.is_finite() {
        warn(
            scene,
            path,
            format!(
                "material `{}`: normalTexture.scale is not finite: the normal map is ignored",
                name_of(m)
            ),
        );
        return None;
    }
    // KHR_texture_transform, read from the JSON (the gltf crate reads it
    // only on the other textures)
    let tt = info.extension_value("KHR_texture_transform");
    let pair = |key: &str, default: [f32; 2]| -> [f32; 2] {
        tt.and_then(|t| t.get(key))
            .and_then(|v| v.as_array())
            .filter(|a| a.len() == 2)
            .and_then(|a| Some([a[0].as_f64()? as f32, a[1].as_f64()? as f32]))
            .unwrap_or(default)
    };
    let rotation = tt
        .and_then(|t| t.get("rotation"))
        .and_then(|v| v.as_f64())
        .unwrap_or(0.0) as f32;
    let tex_coord = tt
        .and_then(|t| t.get("texCoord"))
        .and_then(|v| v.as_u64())
        .unwrap_or(info.tex_coord() as u64);
    if tex_coord != 0 {
        warn(
            scene,
            path,
            format!("material `{}`: only uv set 0 is read", name_of(m)),
        );
    }
    let i = info.texture().source().index();
    let img = match cache.get_mut(i).map(|c| &mut c[0]) {
        Some(Some(img)) => Some(img.clone()),
        slot => {
            let img = images
                .get(i)
                .and_then(Option::as_ref)
                .and_then(|d| to_tex_image(d, false))
                .map(Arc::new);
            if let (Some(img), Some(slot)) = (&img, slot) {
                *slot = Some(img.clone());
            }
            img
        }
    };
    let Some(image) = img else {
        warn(
            scene,
            path,
            format!(
                "material `{}`: unsupported normal texture format (ignored)",
                name_of(m)
            ),
        );
        return None;
    };
    // glTF's uv (0, 0) is the image's top-left corner; TexImage puts v = 0
    // at the bottom
    let flip = glam::Affine2::from_mat2_translation(
        glam::Mat2::from_diagonal(Vec2::new(1.0, -1.0)),
        Vec2::new(0.0, 1.0),
    );
    let to_uv = match tt {
        Some(_) => {
            flip * texture_transform(pair("offset", [0.0; 2]), rotation, pair("scale", [1.0; 2]))
        }
        None => flip,
    };
    Some(NormalTexture {
        texture: Texture::Bitmap { image, to_uv },
        scale,
    })
}

/// The object-space tangent frames of a primitive's triangle corners
/// (`m` before its node's transform, its triangles in the file's
/// order): from `given` (its `TANGENT`, one per vertex) when the
/// primitive has normals and every given tangent is finite, else from
/// MikkTSpace. `None`, with a warning, when the primitive has no uvs (a
/// normal map needs them).
pub(super) fn primitive_tangents(
    m: &MeshData,
    given: Option<Vec<[f32; 4]>>,
    scene: &mut Scene,
    path: &Path,
    what: &str,
) -> Option<Vec<[Vec4; 3]>> {
    let Some(uvs) = m.uvs.as_deref() else {
        warn(
            scene,
            path,
            format!("{what}: its material has a normal texture but it has no uvs: no normal map"),
        );
        return None;
    };
    let n = m.positions.len();
    let given = given.filter(|t| {
        t.len() == n && m.normals.is_some() && t.iter().all(|v| v.iter().all(|c| c.is_finite()))
    });
    if let Some(t) = given {
        let at = |i: u32| {
            t.get(i as usize)
                .map_or(Vec4::ZERO, |&[x, y, z, w]| Vec4::new(x, y, z, w))
        };
        return Some(m.indices.iter().map(|c| c.map(at)).collect());
    }
    let mut g = Mikk {
        m,
        uvs,
        out: vec![[Vec4::ZERO; 3]; m.indices.len()],
    };
    if bevy_mikktspace::generate_tangents(&mut g).is_err() {
        return None;
    }
    Some(g.out)
}

/// A primitive as MikkTSpace reads it, and the corner tangents it writes.
struct Mikk<'a> {
    m: &'a MeshData,
    uvs: &'a [Vec2],
    out: Vec<[Vec4; 3]>,
}

impl Mikk<'_> {
    /// The vertex index of corner `vert` of triangle `face` (out-of-range
    /// indices, which the scene drops with their triangle, read vertex 0's
    /// attributes or zeros).
    fn index(&self, face: usize, vert: usize) -> usize {
        self.m
            .indices
            .get(face)
            .map_or(0, |t| t[vert.min(2)] as usize)
    }

    fn p(&self, i: usize) -> Vec3 {
        self.m.positions.get(i).copied().unwrap_or(Vec3::ZERO)
    }
}

impl bevy_mikktspace::Geometry for Mikk<'_> {
    fn num_faces(&self) -> usize {
        self.m.indices.len()
    }

    fn num_vertices_of_face(&self, _face: usize) -> usize {
        3
    }

    fn position(&self, face: usize, vert: usize) -> [f32; 3] {
        self.p(self.index(face, vert)).to_array()
    }

    fn normal(&self, face: usize, vert: usize) -> [f32; 3] {
        match &self.m.normals {
            Some(ns) => ns
                .get(self.index(face, vert))
                .copied()
                .unwrap_or(Vec3::Z)
                .to_array(),
            None => {
                let [a, b, c] = [0, 1, 2].map(|v| self.p(self.index(face, v)));
                (b - a).cross(c - a).normalize_or(Vec3::Z).to_array()
            }
        }
    }

    fn tex_coord(&self, face: usize, vert: usize) -> [f32; 2] {
        let uv = self
            .uvs
            .get(self.index(face, vert))
            .copied()
            .unwrap_or(Vec2::ZERO);
        // glTF's v points down the image; MikkTSpace's bitangent is to
        // point up it (see the module doc)
        [uv.x, 1.0 - uv.y]
    }

    fn set_tangent(
        &mut self,
        tangent_space: Option<bevy_mikktspace::TangentSpace>,
        face: usize,
        vert: usize,
    ) {
        if let (Some(ts), Some(c)) = (tangent_space, self.out.get_mut(face)) {
            c[vert.min(2)] = Vec4::from(ts.tangent_encoded());
        }
    }
}

/// Gives shape `shape`, just added from a primitive placed by `world`,
/// the normal map `tex` with the primitive's object-space corner tangents
/// `prim`: each of the shape's triangles takes its primitive triangle's
/// ([`crate::scene::ShapeSource`]), in world space, its second and third
/// corners swapped where the loader reversed the winding.
pub(super) fn attach(
    scene: &mut Scene,
    shape: u32,
    tex: &NormalTexture,
    prim: &[[Vec4; 3]],
    world: Mat4,
) {
    let Some(s) = scene.shapes.get(shape as usize) else {
        return;
    };
    let Some(src) = s.source.as_deref() else {
        return;
    };
    let m = Mat3::from_mat4(world);
    let sign = if m.determinant() < 0.0 { -1.0 } else { 1.0 };
    let to_world = |t: Vec4| {
        let d = (m * t.truncate()).normalize_or_zero();
        d.extend(if t.w < 0.0 { -sign } else { sign })
    };
    let tangents = (0..s.tri_count)
        .map(|k| {
            let c = prim
                .get(src.prim_triangle(k) as usize)
                .copied()
                .unwrap_or([Vec4::ZERO; 3]);
            if src.mirrored {
                [to_world(c[0]), to_world(c[2]), to_world(c[1])]
            } else {
                c.map(to_world)
            }
        })
        .collect();
    scene.shapes[shape as usize].normal_map = Some(Box::new(NormalMap {
        texture: tex.texture.clone(),
        scale: tex.scale,
        tangents,
    }));
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::scene::{Rgb, TexImage};

    fn flat_map(c: Rgb, scale: f32, tangents: Vec<[Vec4; 3]>) -> NormalMap {
        NormalMap {
            texture: Texture::Bitmap {
                image: Arc::new(TexImage::new(1, 1, vec![c])),
                to_uv: glam::Affine2::IDENTITY,
            },
            scale,
            tangents,
        }
    }

    /// A texel tilting the normal by 30° toward +x, then +y: n' follows T,
    /// then B = w N × T, and its scale; below the plane it is bent back to
    /// just above it.
    #[test]
    fn a_texel_tilts_the_normal_along_the_tangent_frame() {
        let a = 30f32.to_radians();
        let t = [Vec4::new(1.0, 0.0, 0.0, 1.0); 3];
        let b = [0.2, 0.3, 0.5];
        let enc = |v: Vec3| (v + Vec3::ONE) * 0.5;
        let nm = flat_map(enc(Vec3::new(a.sin(), 0.0, a.cos())), 1.0, vec![t]);
        let n = nm.perturb(0, b, Vec2::ZERO, Vec3::Z, Vec3::Z);
        assert!(
            (n - Vec3::new(a.sin(), 0.0, a.cos())).length() < 1e-5,
            "{n}"
        );
        // green: toward B = N × T = +y, or −y with w = −1
        let nm = flat_map(enc(Vec3::new(0.0, a.sin(), a.cos())), 1.0, vec![t]);
        let n = nm.perturb(0, b, Vec2::ZERO, Vec3::Z, Vec3::Z);
        assert!(
            (n - Vec3::new(0.0, a.sin(), a.cos())).length() < 1e-5,
            "{n}"
        );
        let nm = flat_map(
            enc(Vec3::new(0.0, a.sin(), a.cos())),
            1.0,
            vec![[Vec4::new(1.0, 0.0, 0.0, -1.0); 3]],
        );
        let n = nm.perturb(0, b, Vec2::ZERO, Vec3::Z, Vec3::Z);
        assert!(
            (n - Vec3::new(0.0, -a.sin(), a.cos())).length() < 1e-5,
            "{n}"
        );
        // the scale multiplies x and y
        let nm = flat_map(enc(Vec3::new(a.sin(), 0.0, a.cos())), 0.5, vec![t]);
        let n = nm.perturb(0, b, Vec2::ZERO, Vec3::Z, Vec3::Z);
        let want = Vec3::new(0.5 * a.sin(), 0.0, a.cos()).normalize();
        assert!((n - want).length() < 1e-5, "{n}");
        // a tangent off the normal's plane is made orthogonal to it first
        let nm = flat_map(
            enc(Vec3::new(a.sin(), 0.0, a.cos())),
            1.0,
            vec![[Vec4::new(1.0, 0.0, 0.7, 1.0); 3]],
        );
        let n = nm.perturb(0, b, Vec2::ZERO, Vec3::Z, Vec3::Z);
        assert!(
            (n - Vec3::new(a.sin(), 0.0, a.cos())).length() < 1e-5,
            "{n}"
        );
        // tilted past the plane: bent back above it, still toward +x
        let nm = flat_map(enc(Vec3::new(1.0, 0.0, -0.2)), 1.0, vec![t]);
        let n = nm.perturb(0, b, Vec2::ZERO, Vec3::Z, Vec3::Z);
        assert!(n.z > 0.0 && n.z < 2e-3 && n.x > 0.99, "{n}");
        // no tangent: the normal as it was
        let nm = flat_map(enc(Vec3::X), 1.0, vec![[Vec4::ZERO; 3]]);
        assert_eq!(nm.perturb(0, b, Vec2::ZERO, Vec3::Z, Vec3::Z), Vec3::Z);
        assert_eq!(nm.perturb(5, b, Vec2::ZERO, Vec3::Z, Vec3::Z), Vec3::Z);
    }

    /// MikkTSpace on a quad whose u runs along +x and whose glTF v runs
    /// down −y (the image upright on the quad) gives T = +x, w = +1
    /// (B = N × T = +y, the image's up); with u mirrored, T = −x and
    /// w = −1, so B is still +y.
    #[test]
    fn mikktspace_tangents_point_along_u_with_the_bitangent_up_the_image() {
        let positions = vec![
            Vec3::new(0.0, 0.0, 0.0),
            Vec3::new(1.0, 0.0, 0.0),
            Vec3::new(1.0, 1.0, 0.0),
            Vec3::new(0.0, 1.0, 0.0),
        ];
        for (mirror, t_want, w_want) in [(false, Vec3::X, 1.0), (true, Vec3::NEG_X, -1.0)] {
            let uvs = positions
                .iter()
                .map(|p| Vec2::new(if mirror { 1.0 - p.x } else { p.x }, 1.0 - p.y))
                .collect();
            let m = MeshData {
                positions: positions.clone(),
                normals: None,
                uvs: Some(uvs),
                indices: vec![[0, 1, 2], [0, 2, 3]],
            };
            let mut s = Scene::empty("t");
            let t = primitive_tangents(&m, None, &mut s, Path::new("t"), "t");
            assert!(t.is_some(), "no tangents for a quad with uvs");
            for c in t.iter().flatten().flatten() {
                assert!((c.truncate() - t_want).length() < 1e-5, "{c}");
                assert_eq!(c.w, w_want);
            }
        }
    }
}
