//! The bake as world-space triangles, ready for a writer (`crate::bake`
//! writes them as glTF and PLY): the display mesh of §3.3 with, at each
//! vertex, the outgoing radiance L = R·H/π of the diffuse surface (plus
//! L_e on the front of an emitter), R being the reflectance at that vertex
//! (textures looked up through the mesh uvs) and, for a material with a
//! diffuse part that is not Lambertian, R_d·Ĥ/π
//! ([`crate::bsdf::DiffusePart::rd`]). Surfaces without a diffuse part
//! (glass, metal...) carry no baked lighting: they come as a second, unlit
//! mesh, so that a viewer still shows the geometry.

use std::f32::consts::PI;

use glam::{Vec2, Vec3};

use super::Bake;
use crate::scene::{EmitterDesc, Scene};

/// Triangles with per-vertex attributes, ready to write.
#[derive(Clone, Debug, Default)]
pub struct BakedMesh {
    /// Positions (world).
    pub positions: Vec<Vec3>,
    /// Normals (the side the lighting is for).
    pub normals: Vec<Vec3>,
    /// Irradiance H, W/m².
    pub irradiance: Vec<Vec3>,
    /// Outgoing radiance R·H/π (+ L_e), W/(m²·sr).
    pub radiance: Vec<Vec3>,
    /// Triangles.
    pub indices: Vec<[u32; 3]>,
}

impl BakedMesh {
    fn push(&mut self, p: Vec3, n: Vec3, h: Vec3, l: Vec3) -> u32 {
        self.positions.push(p);
        self.normals.push(n);
        self.irradiance.push(h);
        self.radiance.push(l);
        (self.positions.len() - 1) as u32
    }
}

impl Bake {
    /// The lit mesh (diffuse surfaces, both sides where lit) and the unlit
    /// geometry of the other surfaces, in world space.
    pub fn baked_meshes(&self, scene: &Scene) -> (BakedMesh, BakedMesh) {
        (self.lit_mesh(scene), self.unlit_mesh(scene))
    }

    fn lit_mesh(&self, scene: &Scene) -> BakedMesh {
        let mut lit = BakedMesh::default();
        let emitted = |shape: u32| {
            let sh = &scene.shapes[shape as usize];
            match sh.emitter.and_then(|e| scene.emitters.get(e as usize)) {
                Some(EmitterDesc::Area { radiance, .. }) => *radiance,
                _ => Vec3::ZERO,
            }
        };
        // Planar surfaces: chart vertices to world, a back side wound the
        // other way round
        for m in &self.mesh.planar {
            let back = m.surface.back;
            let s = self.surfaces.of(m.surface);
            let n = if back { -s.normal } else { s.normal };
            let le = if back { Vec3::ZERO } else { emitted(s.shape) };
            let base = lit.positions.len() as u32;
            let r = s.reflectance_at(scene, &m.verts);
            for ((v, h), r) in m.verts.iter().zip(&m.h).zip(r) {
                lit.push(s.to_world(*v), n, *h, r * *h / PI + le);
            }
            for t in &m.tris {
                let t = t.map(|i| i + base);
                lit.indices.push(if back { [t[0], t[2], t[1]] } else { t });
            }
        }
        // Curved shapes: their own triangles, H at the corners
        for m in &self.mesh.curved {
            let le = if m.back { Vec3::ZERO } else { emitted(m.shape) };
            for (&t, h) in m.tris.iter().zip(&m.h) {
                let s = &self.surfaces.list[self.surfaces.tri_surface[t as usize] as usize];
                let corners = [(0.0, 0.0), (1.0, 0.0), (0.0, 1.0)];
                let r = s.reflectance_at(scene, &corners.map(|(b1, b2)| Vec2::new(b1, b2)));
                let mut idx = [0u32; 3];
                for (k, (b1, b2)) in corners.into_iter().enumerate() {
                    let sp = scene.surface_point(t, b1, b2);
                    let n = if m.back { -sp.frame.n } else { sp.frame.n };
                    idx[k] = lit.push(sp.p, n, h[k], r[k] * h[k] / PI + le);
                }
                lit.indices.push(if m.back {
                    [idx[0], idx[2], idx[1]]
                } else {
                    idx
                });
            }
        }
        lit
    }

    fn unlit_mesh(&self, scene: &Scene) -> BakedMesh {
        let mut other = BakedMesh::default();
        for s in &self.surfaces.list {
            if s.diffuse {
                continue;
            }
            for &t in &s.tris {
                let sp = scene.surface_point(t, 0.0, 0.0);
                let mut idx = [0u32; 3];
                for (k, p) in scene.tri_vertices(t).into_iter().enumerate() {
                    idx[k] = other.push(p, sp.ng, Vec3::ZERO, Vec3::ZERO);
                }
                other.indices.push(idx);
            }
        }
        other
    }
}
