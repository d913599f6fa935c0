//! The ray core: a BVH over every triangle of the scene, with closest-hit and
//! occlusion queries. This is the only module that knows how rays meet
//! geometry; it wraps obvhs (pinned to an exact version in Cargo.toml), whose
//! compressed wide BVH (CWBVH, Ylitie et al. 2017) is built in parallel by
//! PLOC with rayon.
//!
//! PLOC merges only pairs of clusters that are each other's nearest
//! neighbour, and some inputs have almost no such pairs: many copies of one
//! triangle (every candidate ties), or a fan of thin triangles around one
//! vertex (every box holds the shared vertex). Each of its passes then merges
//! a handful of clusters while searching all of them, and the build takes
//! time quadratic in the triangle count. [`Accel::build_reporting`] tries
//! PLOC on a sample of the triangles first and, when the sample shows that
//! behaviour, builds the tree top-down instead (`accel/sah.rs`), which takes
//! O(n log n) time whatever the input.

mod sah;

use std::time::Duration;

use glam::{Vec3, Vec3A};
use obvhs::cwbvh::builder::build_cwbvh_from_tris;
use obvhs::cwbvh::bvh2_to_cwbvh::bvh2_to_cwbvh;
use obvhs::cwbvh::CwBvh;
use obvhs::ploc::PlocBuilder;
use obvhs::ray::{Ray as ORay, RayHit};
use obvhs::rt_triangle::RtTriangle;
use obvhs::triangle::Triangle;
use obvhs::BvhBuildParams;

use crate::geometry::Ray;
use crate::scene::Scene;

/// A closest hit.
#[derive(Clone, Copy, Debug)]
pub struct Hit {
    /// Distance along the ray (in units of the ray direction's length).
    pub t: f32,
    /// Triangle index in the scene.
    pub tri: u32,
    /// Barycentric weight of the triangle's second vertex.
    pub b1: f32,
    /// Barycentric weight of the triangle's third vertex.
    pub b2: f32,
}

/// The acceleration structure.
pub struct Accel {
    bvh: CwBvh,
    /// Triangles in BVH leaf order (duplicated where spatial splits put one
    /// triangle in several leaves), so that traversal reads them in sequence;
    /// stored with precomputed edges and normal for the intersection test.
    tris: Vec<RtTriangle>,
    /// Scene triangle index of each entry of `tris`.
    ids: Vec<u32>,
}

impl Accel {
    /// Builds the BVH over all triangles of `scene` (in parallel).
    pub fn build(scene: &Scene) -> Self {
        Self::build_reporting(scene, &mut |_| {})
    }

    /// [`Accel::build`], telling `on_phase` which builder it runs (a line
    /// for a progress display: building a BVH over millions of triangles
    /// takes seconds).
    pub fn build_reporting(scene: &Scene, on_phase: &mut dyn FnMut(String)) -> Self {
        let tris: Vec<Triangle> = (0..scene.triangles.len() as u32)
            .map(|i| {
                let [a, b, c] = scene.tri_vertices(i);
                Triangle {
                    v0: a.into(),
                    v1: b.into(),
                    v2: c.into(),
                }
            })
            .collect();
        if tris.is_empty() {
            return Accel {
                bvh: CwBvh::default(),
                tris: Vec::new(),
                ids: Vec::new(),
            };
        }
        let params = BvhBuildParams::medium_build();
        let bvh = if ploc_is_safe(&tris, params) {
            on_phase(format!("building the BVH over {} triangles", tris.len()));
            build_cwbvh_from_tris(&tris, params, &mut Duration::default())
        } else {
            on_phase(format!(
                "building the BVH over {} triangles top-down (PLOC would take quadratic time on this input)",
                tris.len()
            ));
            let bvh2 = sah::build(&tris);
            bvh2_to_cwbvh(&bvh2, params.max_prims_per_leaf.clamp(1, 3), true, false)
        };
        let ids: Vec<u32> = bvh.primitive_indices.clone();
        let ordered = ids
            .iter()
            .map(|&i| RtTriangle::from(&tris[i as usize]))
            .collect();
        Accel {
            bvh,
            tris: ordered,
            ids,
        }
    }

    /// The closest hit along `ray` in `[ray.tmin, ray.tmax)`.
    #[inline]
    pub fn intersect(&self, ray: &Ray) -> Option<Hit> {
        if self.tris.is_empty() {
            return None;
        }
        let oray = obvhs_ray(ray.o, ray.d, ray.tmin, ray.tmax);
        let mut hit = RayHit::none();
        let tris = &self.tris;
        if self
            .bvh
            .ray_traverse(oray, &mut hit, |r, id| tris[id].intersect(r))
        {
            let slot = hit.primitive_id as usize;
            let (b1, b2) = barycentric(&self.tris[slot], ray.o, ray.d);
            Some(Hit {
                t: hit.t,
                tri: self.ids[slot],
                b1,
                b2,
            })
        } else {
            None
        }
    }

    /// True when something blocks the open segment from `a` to `b`. Both
    /// ends are expected to be already offset from their surfaces
    /// ([`crate::geometry::offset_point`]); the segment stops just short of `b`.
    #[inline]
    pub fn occluded(&self, a: Vec3, b: Vec3) -> bool {
        if self.tris.is_empty() {
            return false;
        }
        let d = b - a;
        let oray = obvhs_ray(a, d, 0.0, 1.0 - 1e-4);
        let tris = &self.tris;
        !self
            .bvh
            .ray_traverse_miss(oray, |r, id| tris[id].intersect(r))
    }

    /// True when something blocks the ray within `[ray.tmin, ray.tmax)`.
    #[inline]
    pub fn occluded_ray(&self, ray: &Ray) -> bool {
        if self.tris.is_empty() {
            return false;
        }
        let oray = obvhs_ray(ray.o, ray.d, ray.tmin, ray.tmax);
        let tris = &self.tris;
        !self
            .bvh
            .ray_traverse_miss(oray, |r, id| tris[id].intersect(r))
    }
}

/// The obvhs ray for `o + t d`. A direction component of −0 becomes +0:
/// obvhs inverts a zero component to ±1/ε by its sign, and its wide-BVH
/// traversal then misses every node along a direction such as `-Vec3::Z`
/// (whose x and y are −0), while the same ray with +0 hits.
#[inline]
fn obvhs_ray(o: Vec3, d: Vec3, tmin: f32, tmax: f32) -> ORay {
    ORay::new(Vec3A::from(o), Vec3A::from(d) + Vec3A::ZERO, tmin, tmax)
}

/// Triangles of the sample that [`ploc_is_safe`] builds PLOC on. PLOC takes
/// at most O(k²) on k triangles (a fraction of a second for this k), and
/// when the whole input is smaller it is built directly.
const PLOC_PROBE: usize = 2048;

/// False when PLOC would take quadratic time on `tris`: PLOC on an evenly
/// strided sample of them needed as many passes as obvhs's default
/// traversal stack depth (96). A healthy input merges a fixed fraction of
/// its clusters per pass, so its passes grow as log k for k clusters; the
/// inputs of the module doc merge a few per pass, and their passes grow
/// with k. A sample keeps either shape: a strided sample of a fan is a
/// fan, of copies is copies. A fan that is a small part of a large scene is
/// a small part of the sample too and goes undetected; PLOC's extra work is
/// then quadratic in the fan's size only.
fn ploc_is_safe(tris: &[Triangle], params: BvhBuildParams) -> bool {
    if tris.len() <= PLOC_PROBE {
        return true;
    }
    let stride = tris.len() / PLOC_PROBE;
    let sample: Vec<Triangle> = tris
        .iter()
        .step_by(stride)
        .take(PLOC_PROBE)
        .copied()
        .collect();
    let bvh2 = PlocBuilder::with_capacity(sample.len()).build(
        params.ploc_search_distance,
        &sample,
        (0..sample.len() as u32).collect(),
        params.sort_precision,
        params.search_depth_threshold,
    );
    // max_depth is max(96, passes + 1)
    bvh2.max_depth <= obvhs::bvh2::DEFAULT_MAX_STACK_DEPTH
}

/// Barycentric weights (of the second and third vertex) of the point where
/// the line `o + t d` meets the triangle's plane (Möller–Trumbore), clamped
/// into the triangle. obvhs's own helper divides by a normalised normal, so
/// its weights are scaled by twice the triangle's area; we compute our own.
#[inline]
fn barycentric(tri: &RtTriangle, o: Vec3, d: Vec3) -> (f32, f32) {
    // RtTriangle keeps e1 = v0 − v1 and e2 = v2 − v0
    let v0 = Vec3::from(tri.v0);
    let e1 = -Vec3::from(tri.e1);
    let e2 = Vec3::from(tri.e2);
    let pvec = d.cross(e2);
    let det = e1.dot(pvec);
    if det == 0.0 {
        return (0.0, 0.0);
    }
    let inv = 1.0 / det;
    let tvec = o - v0;
    let qvec = tvec.cross(e1);
    let b1 = (tvec.dot(pvec) * inv).clamp(0.0, 1.0);
    let b2 = (d.dot(qvec) * inv).clamp(0.0, 1.0 - b1);
    (b1, b2)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sampling::{uniform_sphere, Pcg32};
    use crate::scene::{Material, Texture};

    /// Random rays at a random triangle soup: the hit point rebuilt from the
    /// barycentrics equals o + t d, and a brute-force search finds the same
    /// closest triangle.
    #[test]
    fn closest_hit_matches_brute_force() {
        let mut rng = Pcg32::new(3, 3);
        let mut scene = Scene::empty("soup");
        let m = scene.add_material(Material::Diffuse {
            reflectance: Texture::Constant(Vec3::ONE),
        });
        let mut pos = Vec::new();
        let mut idx = Vec::new();
        for i in 0..300u32 {
            let c = Vec3::new(rng.next_f32(), rng.next_f32(), rng.next_f32()) * 4.0;
            for _ in 0..3 {
                pos.push(c + Vec3::new(rng.next_f32(), rng.next_f32(), rng.next_f32()) - 0.5);
            }
            idx.push([3 * i, 3 * i + 1, 3 * i + 2]);
        }
        scene.add_mesh("soup", &pos, None, None, &idx, m, None);
        let accel = Accel::build(&scene);
        let mut hits = 0;
        for _ in 0..2000 {
            let o = Vec3::new(rng.next_f32(), rng.next_f32(), rng.next_f32()) * 4.0;
            let ray = Ray::new(o, uniform_sphere(rng.next_2d()));
            let brute = (0..scene.triangles.len() as u32)
                .filter_map(|t| {
                    let [a, b, c] = scene.tri_vertices(t);
                    let tri = Triangle {
                        v0: a.into(),
                        v1: b.into(),
                        v2: c.into(),
                    };
                    let oray = ORay::new(o.into(), ray.d.into(), 0.0, f32::INFINITY);
                    let d = tri.intersect(&oray);
                    d.is_finite().then_some((d, t))
                })
                .min_by(|x, y| x.0.total_cmp(&y.0));
            let got = accel.intersect(&ray);
            assert_eq!(got.map(|h| h.tri), brute.map(|b| b.1));
            if let Some(h) = got {
                hits += 1;
                let sp = scene.surface_point(h.tri, h.b1, h.b2);
                assert!((sp.p - ray.at(h.t)).length() < 1e-4);
                assert!(accel.occluded(o, ray.at(h.t * 1.01)));
                assert!(!accel.occluded(o, ray.at(h.t * 0.99)));
            }
        }
        assert!(hits > 100);
    }
}
