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
use crate::sampling::{power_heuristic, Sampler};
use crate::scene::{Rgb, SurfacePoint};
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

impl Default for DepthLimits {
    /// `path`'s defaults: unlimited depth, Russian roulette from depth 5
    /// (Mitsuba's), lights chosen spatially (the light tree).
    fn default() -> Self {
        DepthLimits {
            max_depth: None,
            rr_depth: 5,
            light_selection: LightSelection::Spatial,
        }
    }
}

/// Radiance arriving along `ray`, which is the `depth`-th segment of a camera
/// path whose previous scattering (if any) was a delta lobe, so that emission
/// found by `ray` takes full weight; and the number of rays traced. Used for
/// primary rays (`depth` 1) and by the camera pass after a delta chain.
#[inline(always)]
pub fn radiance_from<S: Sampler>(
    world: &World,
    limits: &DepthLimits,
    ray: Ray,
    rng: &mut S,
    depth: u32,
) -> (Rgb, u64) {
    radiance_from_hit(world, limits, ray, None, rng, depth)
}

/// [`radiance_from`] with `ray`'s closest hit already found, when `first`
/// holds it (`Some(None)` for a miss): the camera rays of neighbouring
/// pixels are traced together ([`crate::accel::Accel::intersect_packet`]),
/// which answers as [`crate::accel::Accel::intersect`] would.
#[inline(always)]
pub fn radiance_from_hit<S: Sampler>(
    world: &World,
    limits: &DepthLimits,
    ray: Ray,
    mut first: Option<Option<Hit>>,
    rng: &mut S,
    depth: u32,
) -> (Rgb, u64) {
    let mut path = CameraPath::new(ray, depth);
    loop {
        path.rays += 1;
        let found = match first.take() {
            Some(h) => h,
            None => world.accel.intersect(&path.ray),
        };
        let alive = match found {
            Some(hit) => path.scatter(world, limits, &world.surface_point(&hit), rng),
            None => path.escape(world),
        };
        if !alive {
            break;
        }
    }
    (path.l, path.rays)
}

/// A camera path between two of its vertices: the ray it continues along
/// and what the estimator of [`radiance_from`] carries from one vertex to
/// the next. [`radiance_from_hit`] advances one path at a time; `path`
/// advances eight together, bounce by bounce, through the same steps.
#[derive(Clone, Copy, Debug)]
pub struct CameraPath {
    /// The segment the path continues along.
    pub ray: Ray,
    /// Radiance gathered so far, L.
    pub l: Rgb,
    /// Throughput β of the path up to `ray`.
    pub beta: Rgb,
    /// Rays traced so far.
    pub rays: u64,
    /// pdf of the direction that led here.
    pub(super) prev_pdf: f32,
    /// Whether that direction came from a delta lobe.
    pub(super) specular: bool,
    /// The previous vertex, where `ray` starts.
    pub(super) prev_p: Vec3,
    /// The previous vertex's geometric normal, for the light selection's pdf.
    pub(super) prev_n: Vec3,
    /// Product of η² over the refractions so far, for Russian roulette.
    pub(super) eta_scale: f32,
    /// Segments of the path so far, `ray` included.
    pub depth: u32,
}

impl CameraPath {
    /// A path whose `depth`-th segment is `ray`, after a delta lobe (or the
    /// eye), so that emission found by `ray` takes full weight.
    #[inline(always)]
    pub fn new(ray: Ray, depth: u32) -> Self {
        CameraPath {
            ray,
            l: Rgb::ZERO,
            beta: Rgb::ONE,
            rays: 0,
            prev_pdf: 0.0,
            specular: true,
            prev_p: ray.o,
            prev_n: Vec3::ZERO,
            eta_scale: 1.0,
            depth,
        }
    }

    /// A path whose `depth`-th segment is `ray`, leaving a point whose
    /// direct light the caller took by light sampling alone (a lightmap's
    /// final gather): the emission `ray` meets, or the environment if it
    /// escapes, takes no weight; the vertices after it weigh theirs as
    /// usual.
    #[inline(always)]
    pub fn after_light_sampling(ray: Ray, depth: u32) -> Self {
        CameraPath {
            specular: false,
            prev_pdf: 0.0,
            ..Self::new(ray, depth)
        }
    }

    /// `ray` escaped the scene: adds the environment, weighted against light
    /// sampling. The path ends (returns false).
    #[inline(always)]
    pub fn escape(&mut self, world: &World) -> bool {
        let lights = &world.lights;
        let le = lights.le_env(self.ray.d);
        if le != Rgb::ZERO {
            let w = if self.specular {
                1.0
            } else {
                power_heuristic(self.prev_pdf, lights.pdf_li_env(self.ray.d))
            };
            self.l += self.beta * le * w;
        }
        false
    }

    /// `ray` met the surface at `sp` ([`World::surface_point`] of its closest
    /// hit): adds the emission found there and the light sampled from it,
    /// then samples the BSDF for the next segment. Returns whether the path
    /// continues (along the new `ray`; the caller traces it and counts it).
    #[inline(always)]
    pub fn scatter<S: Sampler>(
        &mut self,
        world: &World,
        limits: &DepthLimits,
        sp: &SurfacePoint,
        rng: &mut S,
    ) -> bool {
        let (accel, lights) = (&world.accel, &world.lights);
        let selection = limits.light_selection;
        let max_depth = limits.max_depth.unwrap_or(u32::MAX);
        let wo_world = -self.ray.d;
        rng.start_vertex(self.depth);

        // Emission of a hit light, weighted against light sampling
        if lights.is_emitter_of(sp.tri, sp.shape) {
            let le = lights.le_tri(sp.tri, sp.frame.n, wo_world);
            if le != Rgb::ZERO {
                let w = if self.specular {
                    1.0
                } else {
                    power_heuristic(
                        self.prev_pdf,
                        lights.pdf_li_tri_from(
                            selection,
                            self.prev_p,
                            self.prev_n,
                            sp.p,
                            sp.ng,
                            sp.tri,
                        ),
                    )
                };
                self.l += self.beta * le * w;
            }
        }
        if self.depth >= max_depth {
            return false;
        }

        // The BSDF in the shading frame; two-sided materials face the viewer
        let v = super::Shading::at(world, sp, wo_world);
        let (bsdf, frame, ng, wo) = (&v.bsdf, &v.frame, v.ng, v.wo_local);

        // Next-event estimation with MIS
        if bsdf.has_smooth() && self.depth < max_depth {
            let u_sel = rng.next_f32();
            let u_l = rng.next_2d();
            if let Some(ls) = lights.sample_li_from(selection, sp.p, ng, u_sel, u_l) {
                let wi = frame.to_local(ls.wi);
                let f = bsdf.eval(wo, wi, Mode::Radiance) * wi.z.abs();
                if f != Rgb::ZERO && ls.wi.dot(ng) * wi.z > 0.0 {
                    self.rays += 1;
                    let origin = offset_point(sp.p, ng, ls.wi);
                    let blocked = if ls.is_env {
                        accel.occluded_ray(&Ray::new(origin, ls.wi))
                    } else {
                        accel.occluded(origin, offset_point(ls.p, ls.n, -ls.wi))
                    };
                    if !blocked {
                        // A delta light cannot be found by BSDF sampling
                        let w = if ls.delta {
                            1.0
                        } else {
                            power_heuristic(ls.pdf, bsdf.pdf(wo, wi))
                        };
                        self.l += self.beta * f * ls.le * (w / ls.pdf);
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
            return false;
        };
        let wi_world = frame.to_world(s.wi);
        if wi_world.dot(ng) * s.wi.z <= 0.0 || s.pdf <= 0.0 {
            return false;
        }
        self.beta *= s.f * (s.wi.z.abs() / s.pdf);
        if !self.beta.is_finite() || self.beta == Rgb::ZERO {
            return false;
        }
        self.specular = s.delta;
        self.prev_pdf = s.pdf;
        self.prev_p = sp.p;
        self.prev_n = ng;
        if s.eta != 1.0 {
            self.eta_scale *= s.eta * s.eta;
        }
        self.ray = Ray::new(offset_point(sp.p, sp.ng, wi_world), wi_world);
        self.depth += 1;

        // Terminate the walk with Russian roulette on the throughput
        if self.depth > limits.rr_depth {
            let q = (self.beta.max_element() * self.eta_scale).min(0.95);
            if rng.next_f32() >= q {
                return false;
            }
            self.beta /= q;
        }
        true
    }
}
