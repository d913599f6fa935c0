//! The camera-side estimator: unidirectional path tracing with next-event
//! estimation and multiple importance sampling (power heuristic) between
//! light sampling and BSDF sampling, and Russian roulette on the
//! throughput. `path` is this estimator from the eye; the camera pass
//! continues it after a delta lobe.

use glam::Vec3;

use crate::accel::Hit;
use crate::bsdf::Mode;
use crate::emitter::LightSelection;
use crate::geometry::{offset_point, Ray};
use crate::sampling::{power_heuristic, Pcg32};
use crate::scene::Rgb;
use crate::world::World;

/// How deep a camera path may go, and how it chooses lights.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct DepthLimits {
    /// Longest path in segments (Mitsuba's `max_depth`); None = unlimited.
    pub max_depth: Option<u32>,
    /// Depth from which Russian roulette may stop a path (Mitsuba's
    /// `rr_depth`).
    pub rr_depth: u32,
    /// How next-event estimation chooses the light.
    pub light_selection: LightSelection,
}

/// Radiance arriving along `ray`, which is the `depth`-th segment of a camera
/// path whose previous scattering (if any) was a delta lobe, so that emission
/// found by `ray` takes full weight; and the number of rays traced. Used for
/// primary rays (`depth` 1) and by the camera pass after a delta chain.
#[inline(always)]
pub fn radiance_from(
    world: &World,
    limits: &DepthLimits,
    ray: Ray,
    rng: &mut Pcg32,
    depth: u32,
) -> (Rgb, u64) {
    radiance_from_hit(world, limits, ray, None, rng, depth)
}

/// [`radiance_from`] with `ray`'s closest hit already found, when `first`
/// holds it (`Some(None)` for a miss): the camera rays of neighbouring
/// pixels are traced together ([`crate::accel::Accel::intersect_packet`]),
/// which answers as [`crate::accel::Accel::intersect`] would.
#[inline(always)]
pub fn radiance_from_hit(
    world: &World,
    limits: &DepthLimits,
    mut ray: Ray,
    mut first: Option<Option<Hit>>,
    rng: &mut Pcg32,
    depth: u32,
) -> (Rgb, u64) {
    let (accel, lights) = (&world.accel, &world.lights);
    let selection = limits.light_selection;
    let max_depth = limits.max_depth.unwrap_or(u32::MAX);
    let mut l = Rgb::ZERO;
    let mut beta = Rgb::ONE;
    let mut rays = 0u64;
    // pdf of the direction that led here, and whether it was a delta lobe
    let mut prev_pdf = 0.0f32;
    let mut specular = true;
    let mut prev_p = ray.o;
    // the previous vertex's geometric normal, for the light selection's pdf
    let mut prev_n = Vec3::ZERO;
    let mut eta_scale = 1.0f32;
    let mut depth = depth;
    loop {
        rays += 1;
        let found = match first.take() {
            Some(h) => h,
            None => accel.intersect(&ray),
        };
        let Some(hit) = found else {
            // Escaped: the environment, weighted against light sampling.
            let le = lights.le_env(ray.d);
            if le != Rgb::ZERO {
                let w = if specular {
                    1.0
                } else {
                    power_heuristic(prev_pdf, lights.pdf_li_env(ray.d))
                };
                l += beta * le * w;
            }
            break;
        };
        let sp = world.surface_point(&hit);
        let wo_world = -ray.d;

        // Emission of a hit light, weighted against light sampling
        if lights.is_emitter_of(hit.tri, sp.shape) {
            let le = lights.le_tri(hit.tri, sp.frame.n, wo_world);
            if le != Rgb::ZERO {
                let w = if specular {
                    1.0
                } else {
                    power_heuristic(
                        prev_pdf,
                        lights.pdf_li_tri_from(selection, prev_p, prev_n, sp.p, sp.ng, hit.tri),
                    )
                };
                l += beta * le * w;
            }
        }
        if depth >= max_depth {
            break;
        }

        // The BSDF in the shading frame; two-sided materials face the viewer
        let v = super::Shading::at(world, &sp, wo_world);
        let (bsdf, frame, ng, wo) = (&v.bsdf, &v.frame, v.ng, v.wo_local);

        // Next-event estimation with MIS
        if bsdf.has_smooth() && depth < max_depth {
            let u_sel = rng.next_f32();
            let u_l = rng.next_2d();
            if let Some(ls) = lights.sample_li_from(selection, sp.p, ng, u_sel, u_l) {
                let wi = frame.to_local(ls.wi);
                let f = bsdf.eval(wo, wi, Mode::Radiance) * wi.z.abs();
                if f != Rgb::ZERO && ls.wi.dot(ng) * wi.z > 0.0 {
                    rays += 1;
                    let origin = offset_point(sp.p, ng, ls.wi);
                    let blocked = if ls.is_env {
                        accel.occluded_ray(&Ray::new(origin, ls.wi))
                    } else {
                        accel.occluded(origin, offset_point(ls.p, ls.n, -ls.wi))
                    };
                    if !blocked {
                        let w = power_heuristic(ls.pdf, bsdf.pdf(wo, wi));
                        l += beta * f * ls.le * (w / ls.pdf);
                    }
                }
            }
        } else {
            // keep the stream aligned whatever the branch
            rng.next_f32();
            rng.next_2d();
        }

        // Sample the BSDF for the next direction
        let uc = rng.next_f32();
        let u = rng.next_2d();
        let Some(s) = bsdf.sample(wo, uc, u, Mode::Radiance) else {
            break;
        };
        let wi_world = frame.to_world(s.wi);
        if wi_world.dot(ng) * s.wi.z <= 0.0 || s.pdf <= 0.0 {
            break;
        }
        beta *= s.f * (s.wi.z.abs() / s.pdf);
        if !beta.is_finite() || beta == Rgb::ZERO {
            break;
        }
        specular = s.delta;
        prev_pdf = s.pdf;
        prev_p = sp.p;
        prev_n = ng;
        if s.eta != 1.0 {
            eta_scale *= s.eta * s.eta;
        }
        ray = Ray::new(offset_point(sp.p, sp.ng, wi_world), wi_world);
        depth += 1;

        // Terminate the walk with Russian roulette on the throughput
        if depth > limits.rr_depth {
            let q = (beta.max_element() * eta_scale).min(0.95);
            if rng.next_f32() >= q {
                break;
            }
            beta /= q;
        }
    }
    (l, rays)
}
