//! One cache line per triangle for the hot path from a hit to its surface
//! point.
//!
//! [`Scene`] keeps its triangles as indices into shared vertex arrays, the
//! layout loaders and writers want. Building a surface point from that reads
//! the triangle's indices, then its three positions and three uvs (each
//! possibly on its own cache line, and only once the indices have arrived)
//! and its shape: on a large scene, several cache misses in a row per hit.
//! [`TriRecords`] copies what [`Scene::surface_point`] reads into one 64-byte,
//! 64-aligned record per triangle, so a hit costs one line, fetched without
//! an index first. The values are copies, and the arithmetic is shared with
//! [`Scene::surface_point`] (`interpolate`), so the surface point is the
//! same bit for bit. Smooth shapes still read their normals through the
//! indices (three more vectors would not fit in the line).

use glam::{Vec2, Vec3};

use super::{Scene, SurfacePoint};
use crate::geometry::Frame;

/// What a surface point needs of one triangle, in one cache line.
#[derive(Clone, Copy, Debug)]
#[repr(C, align(64))]
pub struct TriRecord {
    /// The three corners, as `Scene::positions` holds them.
    pub p: [Vec3; 3],
    /// The three corners' uvs, as `Scene::uvs` holds them.
    pub uv: [Vec2; 3],
    /// The triangle's shape (index into `Scene::shapes`).
    pub shape: u32,
}

/// The [`TriRecord`]s of every triangle of a scene, in triangle order.
#[derive(Clone, Debug, Default)]
pub struct TriRecords {
    recs: Vec<TriRecord>,
}

impl TriRecords {
    /// Copies each triangle's corners, uvs and shape out of `scene`. Must be
    /// rebuilt if the scene's triangles change.
    pub fn new(scene: &Scene) -> Self {
        let recs = scene
            .triangles
            .iter()
            .zip(&scene.tri_shape)
            .map(|(t, &shape)| TriRecord {
                p: t.map(|i| scene.positions[i as usize]),
                uv: t.map(|i| scene.uvs[i as usize]),
                shape,
            })
            .collect();
        TriRecords { recs }
    }

    /// The records, in triangle order.
    #[inline(always)]
    pub fn records(&self) -> &[TriRecord] {
        &self.recs
    }

    /// Bytes held.
    pub fn bytes(&self) -> usize {
        self.recs.len() * std::mem::size_of::<TriRecord>()
    }

    /// [`Scene::surface_point`] of the scene these records were built from,
    /// bit for bit, reading one record instead of five arrays.
    #[inline(always)]
    pub fn surface_point(&self, scene: &Scene, tri: u32, b1: f32, b2: f32) -> SurfacePoint {
        let r = &self.recs[tri as usize];
        interpolate(
            scene,
            tri,
            r.shape,
            r.p,
            r.uv,
            || scene.triangles[tri as usize],
            b1,
            b2,
        )
    }
}

/// The surface point at barycentrics (`b1`, `b2`) of triangle `tri` of
/// `shape`, from its corners `p` and uvs `uv`; `indices` gives the vertex
/// indices, read only for a smooth shape's normals. The one definition both
/// [`Scene::surface_point`] and [`TriRecords::surface_point`] use.
#[allow(clippy::too_many_arguments)]
#[inline(always)]
pub(super) fn interpolate(
    scene: &Scene,
    tri: u32,
    shape: u32,
    p: [Vec3; 3],
    uv: [Vec2; 3],
    indices: impl FnOnce() -> [u32; 3],
    b1: f32,
    b2: f32,
) -> SurfacePoint {
    let [a, b, c] = p;
    let b0 = 1.0 - b1 - b2;
    let p = a * b0 + b * b1 + c * b2;
    let ng = (b - a).cross(c - a).normalize_or(Vec3::Z);
    let sh = &scene.shapes[shape as usize];
    let ns = if sh.smooth {
        let [i0, i1, i2] = indices().map(|i| i as usize);
        let n = scene.normals[i0] * b0 + scene.normals[i1] * b1 + scene.normals[i2] * b2;
        // keep the shading normal on the geometric normal's side
        let n = n.normalize_or(ng);
        if n.dot(ng) < 0.0 {
            -n
        } else {
            n
        }
    } else {
        ng
    };
    let uv = uv[0] * b0 + uv[1] * b1 + uv[2] * b2;
    // a normal map tilts the shading normal (kept on ng's side)
    let ns = match &sh.normal_map {
        None => ns,
        Some(nm) => nm.perturb(tri - sh.first_tri, [b0, b1, b2], uv, ns, ng),
    };
    SurfacePoint {
        p,
        ng,
        frame: Frame::from_normal(ns),
        uv,
        tri,
        shape,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::scene::Material;

    fn bits(sp: &SurfacePoint) -> Vec<u32> {
        let f = &sp.frame;
        [sp.p, sp.ng, f.s, f.t, f.n]
            .iter()
            .flat_map(|v| v.to_array())
            .chain(sp.uv.to_array())
            .map(f32::to_bits)
            .chain([sp.tri, sp.shape])
            .collect()
    }

    #[test]
    fn records_give_the_scene_surface_point_bit_for_bit() {
        let mut scene = Scene::empty("test");
        let m = scene.add_material(Material::Diffuse {
            reflectance: crate::scene::Texture::Constant(glam::Vec3::splat(0.5)),
        });
        let pos = [
            Vec3::new(0.1, 0.2, 0.3),
            Vec3::new(1.7, -0.2, 0.4),
            Vec3::new(0.3, 2.1, -0.9),
            Vec3::new(-1.3, 0.5, 0.25),
        ];
        let uvs = [
            Vec2::new(0.0, 0.1),
            Vec2::new(0.9, 0.2),
            Vec2::new(0.3, 0.7),
            Vec2::new(0.4, 0.45),
        ];
        let normals = [
            Vec3::new(0.0, 0.3, 1.0),
            Vec3::new(0.2, -0.1, 1.0),
            Vec3::new(-0.4, 0.0, -1.0),
            Vec3::new(0.1, 0.9, 0.2),
        ];
        let idx = [[0, 1, 2], [0, 2, 3], [3, 1, 2]];
        // a flat shape with uvs, a smooth one (one normal facing away from
        // its triangle's winding) and one with neither
        scene.add_mesh("flat", &pos, None, Some(&uvs), &idx, m, None);
        scene.add_mesh("smooth", &pos, Some(&normals), Some(&uvs), &idx, m, None);
        scene.add_mesh("bare", &pos, None, None, &idx[..1], m, None);
        let recs = TriRecords::new(&scene);
        assert_eq!(recs.bytes(), 64 * scene.triangles.len());
        let bary = [(0.0, 0.0), (1.0, 0.0), (0.0, 1.0), (0.25, 0.6), (0.3, 0.3)];
        for tri in 0..scene.triangles.len() as u32 {
            for &(b1, b2) in &bary {
                let a = scene.surface_point(tri, b1, b2);
                let b = recs.surface_point(&scene, tri, b1, b2);
                assert_eq!(bits(&a), bits(&b), "triangle {tri} at ({b1}, {b2})");
            }
        }
    }
}
