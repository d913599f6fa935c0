//! `path`: the reference path tracer. Unidirectional, with next-event
//! estimation and multiple importance sampling (power heuristic) between
//! light sampling and BSDF sampling, Russian roulette on the throughput, and
//! unlimited depth unless `--max-depth` is given (Mitsuba's convention: depth
//! 1 shows only directly visible emitters, 2 adds direct lighting).
//!
//! ```text
//! kalos render scenes/cbox/cbox.xml --method path --spp 256 -o out.exr
//! ```

use glam::Vec3;
use rayon::prelude::*;

use super::{Method, MethodError, StepStats, World};
use crate::bsdf::Mode;
use crate::film::{Film, Image};
use crate::geometry::{offset_point, Frame, Ray};
use crate::sampling::{power_heuristic, Pcg32};
use crate::scene::Rgb;

/// Settings of the path tracer.
#[derive(Clone, Debug, PartialEq)]
#[cfg_attr(feature = "cli", derive(clap::Args))]
pub struct Settings {
    /// Master seed (set from [`super::Common`]).
    #[cfg_attr(feature = "cli", arg(skip))]
    pub seed: u64,
    /// Longest path in segments; None = unlimited (set from [`super::Common`]).
    #[cfg_attr(feature = "cli", arg(skip))]
    pub max_depth: Option<u32>,
    /// Depth from which Russian roulette may stop a path (Mitsuba's default
    /// 5, so that noise compares like for like).
    #[cfg_attr(feature = "cli", arg(long, default_value_t = 5))]
    pub rr_depth: u32,
}

impl Default for Settings {
    fn default() -> Self {
        Settings {
            seed: 0,
            max_depth: None,
            rr_depth: 5,
        }
    }
}

impl Settings {
    /// Rejects settings that cannot work.
    pub fn validate(&self) -> Result<(), MethodError> {
        if self.rr_depth == 0 {
            return Err(MethodError(
                "--rr-depth must be at least 1 (the depth from which Russian roulette may stop a path)"
                    .into(),
            ));
        }
        Ok(())
    }
}

/// The path tracer's progressive state: a sum per pixel and the pass count.
pub struct PathTracer {
    settings: Settings,
    film: Film,
    passes: u64,
}

impl PathTracer {
    /// A path tracer for `world`.
    pub fn new(world: &World, settings: Settings) -> Self {
        PathTracer {
            settings,
            film: Film::new(world.camera.width, world.camera.height),
            passes: 0,
        }
    }
}

impl Method for PathTracer {
    fn name(&self) -> &'static str {
        "path"
    }

    fn step(&mut self, world: &World, pass: u64) -> StepStats {
        let w = world.camera.width as usize;
        let seed = self.settings.seed;
        let settings = &self.settings;
        // One sample per pixel; rows in parallel, each pixel with its own
        // stream keyed by (seed, pass, pixel), so the image does not depend on
        // the thread count.
        let rays: u64 = self
            .film
            .sum
            .par_chunks_mut(w)
            .enumerate()
            .map(|(y, row)| {
                let mut rays = 0u64;
                for (x, acc) in row.iter_mut().enumerate() {
                    let pixel = (y * w + x) as u64;
                    let mut rng = Pcg32::keyed(&[seed, pass, pixel]);
                    let jitter = rng.next_2d();
                    let ray = world.camera.ray(x as f32 + jitter.x, y as f32 + jitter.y);
                    let (l, r) = radiance(world, settings, ray, &mut rng);
                    rays += r;
                    if l.is_finite() {
                        *acc += l.as_dvec3();
                    }
                }
                rays
            })
            .sum();
        self.passes += 1;
        StepStats { rays }
    }

    fn image(&self, _world: &World) -> Image {
        self.film.mean(self.passes)
    }

    fn spp(&self) -> f64 {
        self.passes as f64
    }
}

/// Radiance arriving along a primary `ray` and the number of rays traced for it.
pub fn radiance(world: &World, settings: &Settings, ray: Ray, rng: &mut Pcg32) -> (Rgb, u64) {
    radiance_from(world, settings, ray, rng, 1)
}

/// Radiance arriving along `ray`, which is the `depth`-th segment of a camera
/// path whose previous scattering (if any) was a delta lobe, so that emission
/// found by `ray` takes full weight. Used for primary rays (`depth` 1) and by
/// the camera pass after a delta chain.
pub fn radiance_from(
    world: &World,
    settings: &Settings,
    mut ray: Ray,
    rng: &mut Pcg32,
    depth: u32,
) -> (Rgb, u64) {
    let (scene, accel, lights) = (&world.scene, &world.accel, &world.lights);
    let max_depth = settings.max_depth.unwrap_or(u32::MAX);
    let mut l = Rgb::ZERO;
    let mut beta = Rgb::ONE;
    let mut rays = 0u64;
    // pdf of the direction that led here, and whether it was a delta lobe
    let mut prev_pdf = 0.0f32;
    let mut specular = true;
    let mut prev_p = ray.o;
    let mut eta_scale = 1.0f32;
    let mut depth = depth;
    loop {
        rays += 1;
        let Some(hit) = accel.intersect(&ray) else {
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
        let sp = scene.surface_point(hit.tri, hit.b1, hit.b2);
        let wo_world = -ray.d;

        // Emission of a hit light, weighted against light sampling
        if lights.is_emitter(hit.tri) {
            let le = lights.le_tri(hit.tri, sp.frame.n, wo_world);
            if le != Rgb::ZERO {
                let w = if specular {
                    1.0
                } else {
                    power_heuristic(
                        prev_pdf,
                        lights.pdf_li_tri(scene, prev_p, sp.p, sp.ng, hit.tri),
                    )
                };
                l += beta * le * w;
            }
        }
        if depth >= max_depth {
            break;
        }

        // The BSDF in the shading frame; two-sided materials face the viewer
        let material = scene.material_of(&sp);
        let bsdf = material.bsdf(sp.uv);
        let (frame, ng) = orient(sp.frame, sp.ng, wo_world, material.is_two_sided());
        let wo = frame.to_local(wo_world);

        // Next-event estimation with MIS
        if bsdf.has_smooth() && depth < max_depth {
            let u_sel = rng.next_f32();
            let u_l = rng.next_2d();
            if let Some(ls) = lights.sample_li(scene, sp.p, u_sel, u_l) {
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
        if s.eta != 1.0 {
            eta_scale *= s.eta * s.eta;
        }
        ray = Ray::new(offset_point(sp.p, sp.ng, wi_world), wi_world);
        depth += 1;

        // Terminate the walk with Russian roulette on the throughput
        if depth > settings.rr_depth {
            let q = (beta.max_element() * eta_scale).min(0.95);
            if rng.next_f32() >= q {
                break;
            }
            beta /= q;
        }
    }
    (l, rays)
}

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
