//! Direct light by next-event estimation alone: one light sample, one
//! shadow ray, no MIS. For estimators that have no BSDF-sampled
//! counterpart for the same light (bundle's first shot, where the global
//! directions carry only the light of non-emitting surfaces), so the light
//! sample takes the whole weight and stays unbiased.

use glam::Vec3;

use super::Vertex;
use crate::bsdf::Mode;
use crate::emitter::LightSample;
use crate::geometry::{offset_point, Ray};
use crate::sampling::Pcg32;
use crate::scene::Rgb;
use crate::world::World;

/// True when nothing blocks the segment from `p` (on a surface with
/// geometric normal `ng`, either side) to the light sample `ls`.
#[inline]
pub fn shadow_clear(world: &World, p: Vec3, ng: Vec3, ls: &LightSample) -> bool {
    let origin = offset_point(p, ng, ls.wi);
    if ls.is_env {
        !world.accel.occluded_ray(&Ray::new(origin, ls.wi))
    } else {
        !world
            .accel
            .occluded(origin, offset_point(ls.p, ls.n, -ls.wi))
    }
}

/// Radiance reflected at `v` toward `v.wo` of the light arriving straight
/// from the emitters, estimated by one light sample:
/// f(wo, wi) |wi·ns| Le / pdf when the shadow ray is clear. Returns it and
/// the rays traced (0 or 1). Draws one 1D and one 2D number whatever
/// happens, so that streams stay aligned.
pub fn direct_light(world: &World, v: &Vertex, rng: &mut Pcg32) -> (Rgb, u64) {
    let u_sel = rng.next_f32();
    let u = rng.next_2d();
    if !v.bsdf.has_smooth() {
        return (Rgb::ZERO, 0);
    }
    let Some(ls) = world.lights.sample_li(v.sp.p, u_sel, u) else {
        return (Rgb::ZERO, 0);
    };
    if ls.pdf.is_nan() || ls.pdf <= 0.0 {
        return (Rgb::ZERO, 0);
    }
    let wi = v.frame.to_local(ls.wi);
    // The light must be on the side the BSDF says it is
    if ls.wi.dot(v.ng) * wi.z <= 0.0 {
        return (Rgb::ZERO, 0);
    }
    let f = v.bsdf.eval(v.wo_local, wi, Mode::Radiance) * wi.z.abs();
    if f == Rgb::ZERO {
        return (Rgb::ZERO, 0);
    }
    if !shadow_clear(world, v.sp.p, v.ng, &ls) {
        return (Rgb::ZERO, 1);
    }
    let l = f * ls.le / ls.pdf;
    if l.is_finite() {
        (l, 1)
    } else {
        (Rgb::ZERO, 1)
    }
}
