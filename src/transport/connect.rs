//! Camera connections of light paths: a surface vertex, or an emission
//! vertex, joined to the pinhole by one visibility ray and splatted with the
//! pixel weight g(x) of §2 of the light-path-building paper
//! ([`crate::camera::Camera::project`]).

use std::ops::ControlFlow;

use glam::{Vec2, Vec3};

use super::camera_pass::camera_share;
use super::{light_walk, Spectrum, Vertex, WalkKind};
use crate::bsdf::{shading_normal_correction_over, Mode};
use crate::emitter::EmissionSample;
use crate::film::Film;
use crate::geometry::offset_point;
use crate::sampling::Sampler;
use crate::scene::Rgb;
use crate::simd::dispatched;
use crate::world::World;

/// Connects the surface vertex `v` of a light path carrying power `phi` to
/// the camera, in importance mode: returns the film position and
/// Φ · f(wo → wc) · |wc·ns| · g(x) with the shading-normal correction
/// |wo·ns||wc·ng| / (|wo·ng||wc·ns|) (Veach 1997, eq. 5.17). Adds to `rays`
/// the visibility ray it traces (none when the point is off the film or the
/// BSDF gives nothing, as for a purely delta BSDF). With `glossy_split`
/// (the glossy camera pass is on) the splat carries the light side's MIS
/// weight 1 − [`camera_share`].
#[inline(always)]
pub fn connect_to_camera(
    world: &World,
    v: &Vertex,
    phi: Rgb,
    glossy_split: bool,
    rays: &mut u64,
) -> Option<(Vec2, Rgb)> {
    connect_then(world, v, phi, glossy_split, rays, |_| {})
}

/// [`connect_to_camera`], calling `seen` with the film position just
/// before the visibility ray is traced (for [`Film::prefetch`]).
#[inline(always)]
pub fn connect_then(
    world: &World,
    v: &Vertex,
    phi: Rgb,
    glossy_split: bool,
    rays: &mut u64,
    seen: impl FnOnce(Vec2),
) -> Option<(Vec2, Rgb)> {
    let cam = world.camera.position();
    let p = v.sp.p;
    let (pix, g) = world.camera.project(p)?;
    let d = cam - p;
    let dist = d.length();
    let wc = d / dist;
    let wi = v.frame.to_local(wc);
    // The connection must leave on the side the BSDF says it does
    if wc.dot(v.ng) * wi.z <= 0.0 {
        return None;
    }
    let f = v.bsdf.eval(v.wo_local, wi, Mode::Importance);
    if f == Rgb::ZERO {
        return None;
    }
    // f |wc·ns| times the correction: f |wo·ns||wc·ng| / |wo·ng|
    let mut k = shading_normal_correction_over(v.wo, wc, v.ng, v.frame.n, 1.0);
    if glossy_split {
        // The camera side samples x₁ → x₂ from wi (toward the eye)
        k *= 1.0 - camera_share(&v.bsdf, wi, v.wo_local);
    }
    let c = phi * f * (k * g);
    if !c.is_finite() || c == Rgb::ZERO {
        return None;
    }
    *rays += 1;
    seen(pix);
    if world.accel.occluded(offset_point(p, v.ng, wc), cam) {
        return None;
    }
    Some((pix, c))
}

dispatched! {
    /// [`connect_to_camera`] and the splat of its contribution into `film`
    /// ([`Film::splat_soon`]: held back while the film queues); returns the
    /// rays traced. Dispatched on its own, so that the light
    /// walk's per-vertex hook that calls it stays small enough to be inlined
    /// into the dispatched walk, and the connection runs in the x86-64-v3
    /// copy whatever walk calls it.
    pub fn splat_to_camera(
        world: &World,
        v: &Vertex,
        phi: Rgb,
        glossy_split: bool,
        film: &mut Film,
    ) -> u64 {
        let mut rays = 0;
        let seen = |pix: Vec2| film.prefetch(pix.x, pix.y);
        if let Some((pix, c)) = connect_then(world, v, phi, glossy_split, &mut rays, seen) {
            film.splat_soon(pix.x, pix.y, c);
        }
        rays
    }
}

/// Connects an emission vertex (point `p`, normal `n`) to the camera for
/// diffuse emitters, whose directional profile is 1 on the front side:
/// splats `phi_pos` · cos θ · g(x) when the segment is clear
/// ([`Film::splat_soon`]). Returns the rays traced (0 or 1).
#[inline(always)]
pub fn connect_emission(world: &World, p: Vec3, n: Vec3, phi_pos: Rgb, film: &mut Film) -> u64 {
    let mut rays = 0;
    let seen = |pix: Vec2| film.prefetch(pix.x, pix.y);
    if let Some((pix, c)) = emission_to_camera(world, p, n, phi_pos, &mut rays, seen) {
        film.splat_soon(pix.x, pix.y, c);
    }
    rays
}

/// The film position and contribution of [`connect_emission`], None when
/// the point is off the film, faces away or is blocked; calls `seen` with
/// the film position just before the visibility ray is traced, and adds
/// that ray to `rays`.
#[inline(always)]
pub fn emission_to_camera(
    world: &World,
    p: Vec3,
    n: Vec3,
    phi_pos: Rgb,
    rays: &mut u64,
    seen: impl FnOnce(Vec2),
) -> Option<(Vec2, Rgb)> {
    let (pix, g) = world.camera.project(p)?;
    let d = world.camera.position() - p;
    let cos = d.dot(n) / d.length();
    if cos <= 0.0 {
        return None;
    }
    *rays += 1;
    seen(pix);
    if world
        .accel
        .occluded(offset_point(p, n, d), world.camera.position())
    {
        return None;
    }
    Some((pix, phi_pos * (cos * g)))
}

/// Connects the emission vertex of `es` to the camera, into `film`, as
/// [`connect_emission`] does, with `phi_pos` × `scale`: for area lights
/// only. The environment and directional lights cannot be joined to a
/// pinhole, and points and spots are not seen by the camera: no camera ray
/// can hit a point, so `path` never shows one, nor do Blender or glTF
/// viewers; joining their emission vertex would put a dot of light where
/// `path` has none. Their light reaches the image through the surfaces it
/// lights. Returns the rays traced (0 or 1).
#[inline(always)]
pub fn connect_emission_sample(
    world: &World,
    es: &EmissionSample,
    scale: f32,
    film: &mut Film,
) -> u64 {
    if !joins_the_camera(es) {
        return 0;
    }
    connect_emission(world, es.p, es.n, es.phi_pos * scale, film)
}

/// Whether the emission vertex of `es` is joined to the camera: an area
/// light's ([`connect_emission_sample`] says why the others are not).
#[inline(always)]
fn joins_the_camera(es: &EmissionSample) -> bool {
    !es.is_env && es.punctual == u32::MAX
}

/// [`connect_emission_sample`] with `scale` 1, answered as
/// [`emission_to_camera`] answers instead of splatted.
#[inline(always)]
pub fn emission_sample_to_camera(
    world: &World,
    es: &EmissionSample,
    rays: &mut u64,
) -> Option<(Vec2, Rgb)> {
    if !joins_the_camera(es) {
        return None;
    }
    emission_to_camera(world, es.p, es.n, es.phi_pos * 1.0, rays, |_| {})
}

/// One light-tracing walk of the form `kind`: an emission sample (one
/// number for the light, two for the point, two for the direction), joined
/// to the camera ([`connect_emission_sample`]), then a [`light_walk`],
/// joined to the camera at every non-delta vertex ([`splat_to_camera`]).
/// `light --variant walk`'s walk, and plb's mixture walk. Returns the rays
/// traced.
#[inline(always)]
pub fn light_tracing_walk<S: Sampler>(
    world: &World,
    kind: &WalkKind,
    rng: &mut S,
    film: &mut Film,
) -> u64 {
    let (u_sel, u_pos, u_dir) = (rng.next_f32(), rng.next_2d(), rng.next_2d());
    let Some(es) = world.lights.sample_emission(u_sel, u_pos, u_dir) else {
        return 0;
    };
    let mut rays = 0;
    // Emitter points connect to the camera directly
    rays += connect_emission_sample(world, &es, 1.0, film);
    let split = kind.glossy_split;
    let walk = light_walk(
        world,
        es.ray(),
        es.phi,
        Spectrum::Rgb,
        kind.roulette,
        kind.max_depth,
        rng,
        |e| {
            // Connect to the camera at every non-delta vertex
            if e.vertex.bsdf.has_smooth() {
                rays += splat_to_camera(world, e.vertex, e.beta, split, film);
            }
            ControlFlow::Continue(())
        },
    );
    rays + walk
}
