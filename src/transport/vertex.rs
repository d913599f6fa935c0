//! The vertex built from a hit, and scattering in importance mode.

use glam::Vec3;

use crate::accel::Hit;
use crate::bsdf::{shading_normal_correction_over, Bsdf, Mode};
use crate::geometry::{Frame, Ray};
use crate::sampling::Sampler;
use crate::scene::{Rgb, SurfacePoint};
use crate::world::World;

/// The shading frame and geometric normal, flipped to the side of `wo` for
/// two-sided materials (Mitsuba's `twosided`). One-sided materials keep their
/// orientation: seen from behind they are black.
#[inline]
pub fn orient(frame: Frame, ng: Vec3, wo: Vec3, two_sided: bool) -> (Frame, Vec3) {
    if two_sided && ng.dot(wo) < 0.0 {
        (
            Frame {
                s: frame.s,
                t: -frame.t,
                n: -frame.n,
            },
            -ng,
        )
    } else {
        (frame, ng)
    }
}

/// A path vertex on a surface: the point, its BSDF, and the shading frame
/// and geometric normal oriented for the material ([`orient`]), seen from
/// `wo`. The same for camera paths and light paths; only the [`Mode`] the
/// BSDF is evaluated in differs.
#[derive(Clone, Copy, Debug)]
pub struct Vertex {
    /// The surface point (its `frame` and `ng` as the mesh gives them).
    pub sp: SurfacePoint,
    /// The BSDF at the point.
    pub bsdf: Bsdf,
    /// The shading frame, oriented: flipped toward `wo` for two-sided
    /// materials.
    pub frame: Frame,
    /// The geometric normal, oriented like `frame`.
    pub ng: Vec3,
    /// Unit direction back along the path (world): toward the camera on a
    /// camera path, toward the light on a light path.
    pub wo: Vec3,
    /// `wo` in the oriented shading frame.
    pub wo_local: Vec3,
}

impl Vertex {
    /// The vertex at `sp` seen from direction `wo` (world, pointing away from
    /// the surface).
    #[inline(always)]
    pub fn new(world: &World, sp: SurfacePoint, wo: Vec3) -> Self {
        let Shading {
            bsdf,
            frame,
            ng,
            wo_local,
        } = Shading::at(world, &sp, wo);
        Vertex {
            sp,
            bsdf,
            frame,
            ng,
            wo,
            wo_local,
        }
    }
}

/// What scattering at a surface point needs: a [`Vertex`] without the
/// point itself, for loops that keep the [`SurfacePoint`] beside it and
/// would otherwise copy it into every vertex.
#[derive(Clone, Copy, Debug)]
pub struct Shading {
    /// The BSDF at the point.
    pub bsdf: Bsdf,
    /// The shading frame, oriented as [`Vertex::frame`].
    pub frame: Frame,
    /// The geometric normal, oriented like `frame`.
    pub ng: Vec3,
    /// `wo` in the oriented shading frame.
    pub wo_local: Vec3,
}

impl Shading {
    /// The BSDF and oriented frame at `sp` seen from `wo` (world, pointing
    /// away from the surface), as [`Vertex::new`] builds them.
    #[inline(always)]
    pub fn at(world: &World, sp: &SurfacePoint, wo: Vec3) -> Self {
        let material = world.scene.material_of(sp);
        let bsdf = material.bsdf(sp.uv);
        let (frame, ng) = orient(sp.frame, sp.ng, wo, material.is_two_sided());
        Shading {
            bsdf,
            frame,
            ng,
            wo_local: frame.to_local(wo),
        }
    }
}

impl World {
    /// The surface point at `hit`: [`crate::scene::Scene::surface_point`],
    /// read from the per-triangle records.
    #[inline(always)]
    pub fn surface_point(&self, hit: &Hit) -> SurfacePoint {
        self.tris
            .surface_point(&self.scene, hit.tri, hit.b1, hit.b2)
    }

    /// The vertex where `ray` meets the scene at `hit`.
    #[inline(always)]
    pub fn vertex(&self, ray: &Ray, hit: &Hit) -> Vertex {
        let sp = self.surface_point(hit);
        Vertex::new(self, sp, -ray.d)
    }
}

/// Samples the next direction of a light path at `v`, in importance mode;
/// returns the world direction and the throughput factor f·|wi·ns|/pdf with
/// the shading-normal correction (Veach 1997, eq. 5.17), or None when the
/// BSDF gives no sample or the sample leaves on the wrong side of the
/// geometric surface. Draws one 1D and one 2D number.
#[inline(always)]
pub fn scatter<S: Sampler>(v: &Vertex, rng: &mut S) -> Option<(Vec3, Rgb)> {
    let wo = v.wo_local;
    let uc = rng.next_f32();
    let u = rng.next_2d();
    let s = v.bsdf.sample(wo, uc, u, Mode::Importance)?;
    let wi = v.frame.to_world(s.wi);
    if wi.dot(v.ng) * s.wi.z <= 0.0 || v.wo.dot(v.ng) * wo.z <= 0.0 || s.pdf <= 0.0 {
        return None;
    }
    // f |wi·ns| / pdf times the correction: the sample's own |wi·ns| cancels
    // the one in the correction's denominator
    let k = shading_normal_correction_over(v.wo, wi, v.ng, v.frame.n, s.pdf);
    let w = s.f * k;
    if k == 0.0 || !w.is_finite() {
        return None;
    }
    Some((wi, w))
}
