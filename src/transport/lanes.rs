//! `path`'s camera paths eight at a time, bounce by bounce, with the
//! common case shaded in eight AVX lanes (issue #15, item 4).
//!
//! Each round traces the closest hit of every live path (one ray at a
//! time), computes the surface points of all of them in lanes, and then
//! takes one vertex of each path. A vertex is shaded in lanes when it is
//! the common case: a diffuse BSDF on a surface that does not emit, below
//! the depth limit, in a scene whose lights are all triangles
//! (`Lights::triangles_only`; the light is chosen lane by
//! lane, by power or down the light tree). Every other vertex goes through
//! [`super::CameraPath::scatter`], the step [`radiance_from_hit`] runs,
//! lane by lane. A lane runs the scalar operations in their order (Rust
//! never contracts to FMA), draws its numbers from its own pixel's sampler
//! in the scalar order and at the scalar dimensions ([`LaneSampler`]: the
//! eight PCG32 generators advance together where all the lanes draw; a
//! Sobol lane's numbers are its pixel's point's coordinates at its own
//! vertex's dimensions), and computes the concentric map's sine and cosine
//! with the scalar polynomial's operations, so a pixel's radiance is the
//! same bits as [`radiance_from_hit`]'s. The camera rays of 64 pixels at a time are
//! traced first, in packets of eight neighbours; a lane whose path ends
//! takes the next of those pixels, so that the lanes stay full until the
//! row runs out. The entry, [`radiance_camera_row`], also draws the
//! jitters and makes those camera rays eight at a time in lanes, with the
//! operations of `Camera::ray` in their order: in a closure called pixel
//! by pixel they took 7.9 % of a cbox run, compiled for the baseline CPU.
//!
//! [`radiance_continued`] runs the same lanes from paths begun elsewhere
//! (the camera pass's, after their first vertex), whose first segments the
//! lanes trace.
//!
//! [`light_walks`] does the same for `light --sampler sobol`'s walks: eight
//! at a time, the emission from triangle lights and the common vertex (a
//! diffuse BSDF below the depth limit: its camera connection, roulette and
//! scatter) in lanes, every other vertex by [`super::LightWalk::step`]; a
//! walk's splats are added in walk order, so the film's sums are the bits
//! of the walks run one by one.

use glam::DVec3;

use crate::film::Film;
use crate::geometry::Ray;
use crate::sampling::{Pcg32, Sampler, SamplerKind, SobolSampler, SobolWalkSampler};
use crate::scene::Rgb;
use crate::simd::dispatched;
use crate::world::World;

use super::{light_tracing_walk, radiance_from_hit, DepthLimits, WalkKind};

/// Paths advanced together.
pub const LANES: usize = 8;

/// A sampler whose numbers the AVX lanes draw for eight paths at a time,
/// each lane its own pixel's: PCG32 (`--sampler independent`) and the
/// Owen-scrambled Sobol points (`--sampler sobol`).
pub trait LaneSampler: Sampler + Clone {
    /// How eight lanes hold their samplers and draw a vertex's numbers.
    #[cfg(target_arch = "x86_64")]
    #[doc(hidden)]
    type Lanes: avx::Lanes<Self>;
}

impl LaneSampler for Pcg32 {
    #[cfg(target_arch = "x86_64")]
    type Lanes = avx::Rngs;
}

impl LaneSampler for SobolSampler {
    #[cfg(target_arch = "x86_64")]
    type Lanes = avx::SobolLanes;
}

/// Runs one camera path per pixel x of the camera's row `y`, `path`'s
/// loop: pixel x's sampler is `sampler(x)`, whose first 2D draw (u, v)
/// jitters the camera ray through (x + u, y + v)
/// ([`crate::camera::Camera::ray`]); `finish(x, L, rays)` takes the path's
/// radiance and the rays it traced, [`radiance_from_hit`]'s answer at
/// depth 1. Where the CPU has AVX2, eight paths run at a time in lanes, a
/// lane whose path ends takes the next pixel, and the jitters and camera
/// rays of eight pixels are made in lanes too, with the bits of the scalar
/// ones; elsewhere the camera rays of eight neighbouring pixels are traced
/// together and each path then runs alone.
#[inline(always)]
pub fn radiance_camera_row<S: LaneSampler>(
    world: &World,
    limits: &DepthLimits,
    y: usize,
    mut sampler: impl FnMut(usize) -> S,
    finish: impl FnMut(usize, Rgb, u64),
) {
    let camera = &world.camera;
    let w = camera.width as usize;
    #[cfg(target_arch = "x86_64")]
    if crate::simd::has_v3() && world.lights.triangles_only() {
        let start = avx::CameraRow { camera, y, sampler };
        // SAFETY: the CPU has AVX2 (checked by has_v3)
        unsafe { avx::radiance_row(world, limits, start, finish) };
        return;
    }
    let start = |x: usize| {
        let mut s = sampler(x);
        let j = s.next_2d();
        (s, camera.ray(x as f32 + j.x, y as f32 + j.y))
    };
    radiance_row_packets(world, limits, w, start, finish);
}

dispatched! {
    /// Adds one sample to each pixel of row `y` (`row` holds its sums, and
    /// `squares`, when given, the sums of their squares); returns the rays
    /// traced. Each pixel draws its own numbers, keyed by (seed, pass,
    /// pixel) and chosen by `sampler`, so that the row does not depend on
    /// the thread count. `path`'s pass loop, and the path estimate of
    /// plb's mixture (with the squares); compiled for x86-64-v3 by runtime
    /// dispatch ([`crate::transport::dispatch`]).
    #[allow(clippy::too_many_arguments)]
    pub fn camera_row(
        world: &World,
        limits: &DepthLimits,
        sampler: SamplerKind,
        seed: u64,
        pass: u64,
        y: usize,
        row: &mut [DVec3],
        squares: Option<&mut [DVec3]>,
    ) -> u64 {
        let mut squares = squares;
        let w = row.len();
        crate::film::prefetch_row(row);
        let mut rays = 0u64;
        let mut finish = |x: usize, l: Rgb, n: u64| {
            rays += n;
            if l.is_finite() {
                let v = l.as_dvec3();
                row[x] += v;
                if let Some(q) = squares.as_deref_mut() {
                    q[x] += v * v;
                }
            }
        };
        let pixel = |x: usize| (y * w + x) as u64;
        match sampler {
            SamplerKind::Independent => {
                let sampler = |x: usize| Pcg32::keyed(&[seed, pass, pixel(x)]);
                radiance_camera_row(world, limits, y, sampler, &mut finish);
            }
            SamplerKind::Sobol => {
                let sampler = |x: usize| SobolSampler::new(seed, pixel(x), pass);
                radiance_camera_row(world, limits, y, sampler, &mut finish);
            }
        }
        rays
    }
}

/// [`radiance_camera_row`] without lanes, for any [`Sampler`]: the camera rays of
/// eight neighbouring pixels are traced together, then each path runs
/// alone through [`radiance_from_hit`]. The loop of CPUs without AVX2 and
/// of scenes with lights other than triangles.
#[inline(always)]
pub fn radiance_row_packets<S: Sampler>(
    world: &World,
    limits: &DepthLimits,
    w: usize,
    mut start: impl FnMut(usize) -> (S, Ray),
    mut finish: impl FnMut(usize, Rgb, u64),
) {
    for x0 in (0..w).step_by(LANES) {
        let n = LANES.min(w - x0);
        let mut rngs: [Option<S>; LANES] = std::array::from_fn(|_| None);
        let mut cam = [Ray::new(glam::Vec3::ZERO, glam::Vec3::Z); LANES];
        for (i, (rng, r)) in rngs.iter_mut().zip(&mut cam).take(n).enumerate() {
            let (s, ray) = start(x0 + i);
            (*rng, *r) = (Some(s), ray);
        }
        let mut hits = [None; LANES];
        world.accel.intersect_packet(&cam[..n], &mut hits[..n]);
        for (i, (rng, h)) in rngs.iter_mut().zip(hits).take(n).enumerate() {
            let Some(rng) = rng else { continue };
            let (l, rays) = radiance_from_hit(world, limits, cam[i], Some(h), rng, 1);
            finish(x0 + i, l, rays);
        }
    }
}

/// [`super::radiance_from`] of each of `paths`, whose `depth`-th segments
/// are `paths[k].1` (a `Ray::new` ray, not yet traced) and whose samplers
/// drew them: `finish(k, L, rays)` takes path k's answer. Where the CPU
/// has AVX2 and the scene's lights are all triangles, eight paths run at a
/// time in the lanes of [`radiance_camera_row`], with the same bits;
/// elsewhere one by one. The camera pass continues its paths here after
/// their first vertex.
#[inline(always)]
pub fn radiance_continued<S: LaneSampler>(
    world: &World,
    limits: &DepthLimits,
    depth: u32,
    paths: &mut [(S, Ray)],
    mut finish: impl FnMut(usize, Rgb, u64),
) {
    #[cfg(target_arch = "x86_64")]
    if crate::simd::has_v3() && world.lights.triangles_only() {
        let start = avx::Continued { paths, depth };
        // SAFETY: the CPU has AVX2 (checked by has_v3)
        unsafe { avx::radiance_row(world, limits, start, finish) };
        return;
    }
    for (k, (rng, ray)) in paths.iter_mut().enumerate() {
        let (l, rays) = super::radiance_from(world, limits, *ray, rng, depth);
        finish(k, l, rays);
    }
}

/// The light-tracing walks `walks` of pass `pass` under `seed`, of the
/// form `kind` (`light --variant walk`'s, or plb's mixture walks), each
/// with its Sobol points ([`SobolWalkSampler`]), splatted into `film` as
/// [`light_tracing_walk`] splats them one walk after another: the same
/// splats in the same order, so the film's sums are the same bits. Returns
/// the rays traced. Where the CPU has AVX2, eight walks run at a time in
/// lanes, a vertex with a diffuse BSDF (below the depth limit) is shaded,
/// joined to the camera and scattered in lanes, every other vertex takes
/// [`super::LightWalk::step`], and a walk's splats wait until the walks
/// before it have ended.
#[inline(always)]
pub fn light_walks(
    world: &World,
    kind: &WalkKind,
    seed: u64,
    pass: u64,
    walks: std::ops::Range<u64>,
    film: &mut Film,
) -> u64 {
    #[cfg(target_arch = "x86_64")]
    if crate::simd::has_v3() {
        // SAFETY: the CPU has AVX2 (checked by has_v3)
        return unsafe { avx::light_walks(world, kind, seed, pass, walks, film) };
    }
    let mut rays = 0;
    for k in walks {
        let mut sobol = SobolWalkSampler::new(seed, pass, k);
        rays += light_tracing_walk(world, kind, &mut sobol, film);
    }
    rays
}

#[cfg(target_arch = "x86_64")]
mod avx;
