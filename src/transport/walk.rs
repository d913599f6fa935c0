//! Light paths: the delta-chain follower and the one light-path walk.

use std::ops::ControlFlow;

use super::{scatter, Vertex};
use crate::accel::Hit;
use crate::geometry::{offset_point, Ray};
use crate::sampling::{Pcg32, Sampler};
use crate::scene::Rgb;
use crate::world::World;

/// Path depth (segments from the light) beyond which
/// [`follow_delta_chain`] stops at the next surface even if it is purely
/// specular. The follower plays no Russian roulette, so without a limit a
/// ray trapped between delta surfaces (two facing mirrors, total internal
/// reflection in a glass body) would never end; a path this deep carries
/// nothing visible, and a delta vertex returned here measures nothing (its
/// camera connection evaluates to zero).
pub const DELTA_CHAIN_DEPTH_LIMIT: u32 = 1000;

/// Where [`follow_delta_chain`] put the power down.
#[derive(Clone, Copy, Debug)]
pub struct Landing {
    /// The first vertex with a non-delta lobe (or the vertex past
    /// [`DELTA_CHAIN_DEPTH_LIMIT`]).
    pub vertex: Vertex,
    /// The closest hit the vertex was built from (triangle and
    /// barycentrics: [`World::surface_point`] rebuilds the vertex's point
    /// from it, to the same bits).
    pub hit: Hit,
    /// The power arriving there.
    pub phi: Rgb,
    /// Segments of the light path up to and including the last ray.
    pub depth: u32,
}

/// Sends power `phi` along `ray`, the `depth`-th segment of a light path,
/// through delta surfaces (mirrors, smooth glass, which cannot be measured
/// nor hold a useful hit) to the first vertex with a non-delta lobe. The
/// operator over a delta chain is one transfer (§4 of the 1999
/// stochastic-iteration paper; `light --variant iteration` and `plb`).
/// Returns None when a ray escapes or a delta sample fails; adds the rays
/// traced to `rays`.
#[inline(always)]
pub fn follow_delta_chain(
    world: &World,
    mut ray: Ray,
    mut phi: Rgb,
    mut depth: u32,
    rng: &mut Pcg32,
    rays: &mut u64,
) -> Option<Landing> {
    loop {
        *rays += 1;
        let hit = world.accel.intersect(&ray)?;
        let vertex = world.vertex(&ray, &hit);
        if vertex.bsdf.has_smooth() || depth > DELTA_CHAIN_DEPTH_LIMIT {
            return Some(Landing {
                vertex,
                hit,
                phi,
                depth,
            });
        }
        // A purely specular surface: pass the power on
        let (wi, w) = scatter(&vertex, rng)?;
        phi *= w;
        ray = Ray::new(offset_point(vertex.sp.p, vertex.sp.ng, wi), wi);
        depth += 1;
    }
}

/// Which colour channels a light walk carries.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Spectrum {
    /// All three: Russian roulette reads the largest channel of the albedo.
    Rgb,
    /// One channel only (the density paper's per-channel runs): Russian
    /// roulette reads that channel's albedo, and the other channels of the
    /// power are kept at zero.
    Channel(usize),
}

/// How a light walk plays Russian roulette after each vertex.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Roulette {
    /// On the albedo, as the papers have it: the walk goes on with
    /// probability a, the largest channel of the vertex's albedo (the
    /// walk's channel under [`Spectrum::Channel`]) capped at 0.99, and its
    /// power is divided by a, so that a particle keeps its power while it
    /// lives.
    Albedo,
    /// On the throughput relative to the emitted power, channel by
    /// channel, after the direction is sampled: the walk goes on with
    /// probability q = min(max_c β_c w_c / β0_c, 0.95) (β the power, w the
    /// sample's weight, β0 the emitted power), and its power is divided by
    /// q. A walk whose power went into a channel it was not emitted in is
    /// ended sooner than by the albedo. Measured against [`Roulette::Albedo`]
    /// at equal rays (docs/notebook/light.md, "Russian roulette on the
    /// throughput"): 7–9 % less error on cbox, 5–12 % more on the baffle, lit
    /// through a gap; plb's mixture walks use it (`methods::plb::mix`).
    Throughput,
}

/// The form of a light-tracing walk ([`super::light_tracing_walk`], and
/// eight at a time [`super::lanes::light_walks`]): `light`'s, with the
/// albedo's roulette and no glossy split, or `plb`'s mixture walks, with
/// the throughput's roulette and the glossy split of its camera pass.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct WalkKind {
    /// The depth limit (None: unlimited).
    pub max_depth: Option<u32>,
    /// The roulette played after each vertex.
    pub roulette: Roulette,
    /// Camera connections carry the light side's MIS weight against the
    /// glossy camera pass ([`super::connect_to_camera`]).
    pub glossy_split: bool,
}

/// The largest channel of `beta` relative to the emitted power `emitted`,
/// over the channels the walk carries (those emitted with power).
#[inline(always)]
fn relative_throughput(beta: Rgb, emitted: Rgb, spectrum: Spectrum) -> f32 {
    let mut q = 0.0f32;
    for c in 0..3 {
        let carried = match spectrum {
            Spectrum::Rgb => true,
            Spectrum::Channel(k) => c == k,
        };
        if carried && emitted[c] > 0.0 {
            q = q.max(beta[c] / emitted[c]);
        }
    }
    q
}

/// What [`light_walk`] shows its hook at each surface vertex.
#[derive(Clone, Copy, Debug)]
pub struct LightVertex<'a> {
    /// The vertex.
    pub vertex: &'a Vertex,
    /// The hit it was built from (triangle and barycentrics).
    pub hit: &'a Hit,
    /// The power arriving at the vertex.
    pub beta: Rgb,
    /// Segments of the light path up to the vertex (1: the first hit).
    pub depth: u32,
}

/// The light-path walk: the particle of power `beta` leaves along `ray` (the
/// first segment; the emission vertex is the caller's), and at every surface
/// vertex `on_vertex` measures it; then the walk ends by Russian roulette
/// (`roulette`: on the albedo, the papers' form, so that a particle keeps
/// its power while it lives, §4 of the 1999 stochastic-iteration paper,
/// §3.1 of the density-estimation paper; or on the throughput), or
/// scatters in importance mode ([`scatter`]). Returns the rays traced by
/// the walk itself (the hook counts its own).
///
/// Depths follow Mitsuba's `max_depth` (see the [module docs](super)): the
/// hook sees only vertices at depth < `max_depth`, whose light path can
/// still be joined to the eye, and the walk stops before a segment whose end
/// could not be. The hook may end the walk with [`ControlFlow::Break`].
///
/// Random numbers, per vertex: one for the roulette, then those of
/// [`scatter`]; the hook draws none. Each vertex first calls
/// [`Sampler::start_vertex`] with its depth, so that a sampler with a
/// dimension layout ([`crate::sampling::SobolWalkSampler`]) draws the
/// vertex's own dimensions; PCG32 ignores it.
#[inline(always)]
#[allow(clippy::too_many_arguments)]
pub fn light_walk<S: Sampler>(
    world: &World,
    ray: Ray,
    beta: Rgb,
    spectrum: Spectrum,
    roulette: Roulette,
    max_depth: Option<u32>,
    rng: &mut S,
    mut on_vertex: impl FnMut(&LightVertex) -> ControlFlow<()>,
) -> u64 {
    let mut walk = LightWalk::new(ray, beta, spectrum, roulette, max_depth);
    let mut rays = 0;
    loop {
        rays += 1;
        let Some(hit) = world.accel.intersect(&walk.ray) else {
            break;
        };
        if !walk.step(world, &hit, rng, &mut on_vertex) {
            break;
        }
    }
    rays
}

/// The state of a [`light_walk`] between its vertices: the AVX lanes of
/// [`super::lanes::light_walks`] carry eight, and hand a vertex they do
/// not shade to [`LightWalk::step`].
#[derive(Clone, Copy, Debug)]
pub struct LightWalk {
    /// The segment being traced.
    pub ray: Ray,
    /// The power it carries.
    pub beta: Rgb,
    /// The power emitted (for [`Roulette::Throughput`]).
    pub emitted: Rgb,
    /// Segments of the light path up to and including `ray`.
    pub depth: u32,
    /// The channels carried.
    pub spectrum: Spectrum,
    /// The roulette played.
    pub roulette: Roulette,
    /// The depth limit (`u32::MAX`: none).
    pub max_depth: u32,
}

impl LightWalk {
    /// A walk whose first segment `ray` carries the emitted power `beta`.
    #[inline(always)]
    pub fn new(
        ray: Ray,
        beta: Rgb,
        spectrum: Spectrum,
        roulette: Roulette,
        max_depth: Option<u32>,
    ) -> Self {
        LightWalk {
            ray,
            beta,
            emitted: beta,
            depth: 1,
            spectrum,
            roulette,
            max_depth: max_depth.unwrap_or(u32::MAX),
        }
    }

    /// The vertex at `hit`, the closest hit of `self.ray`: measured by
    /// `on_vertex`, then Russian roulette and the next segment, as
    /// [`light_walk`] describes. Returns whether the walk goes on (along
    /// the new `self.ray`, which the caller traces and counts).
    #[inline(always)]
    pub fn step<S: Sampler>(
        &mut self,
        world: &World,
        hit: &Hit,
        rng: &mut S,
        mut on_vertex: impl FnMut(&LightVertex) -> ControlFlow<()>,
    ) -> bool {
        let (max_depth, depth) = (self.max_depth, self.depth);
        let vertex = world.vertex(&self.ray, hit);

        // Measure the vertex while its path can still reach the eye
        if depth < max_depth {
            let event = LightVertex {
                vertex: &vertex,
                hit,
                beta: self.beta,
                depth,
            };
            if on_vertex(&event).is_break() {
                return false;
            }
        }
        if depth + 1 >= max_depth {
            return false;
        }

        // Terminate the walk by Russian roulette (`roulette`), its
        // probability capped below 1 so that every walk ends
        rng.start_vertex(depth);
        let u_rr = rng.next_f32();
        let spectrum = self.spectrum;
        let (wi, w) = match self.roulette {
            Roulette::Albedo => {
                let albedo = vertex.bsdf.albedo(vertex.wo_local);
                let a = match spectrum {
                    Spectrum::Rgb => albedo.max_element(),
                    Spectrum::Channel(k) => albedo[k],
                }
                .clamp(0.0, 0.99);
                if u_rr >= a {
                    return false;
                }
                let Some((wi, w)) = scatter(&vertex, rng) else {
                    return false;
                };
                (wi, w / a)
            }
            Roulette::Throughput => {
                let Some((wi, w)) = scatter(&vertex, rng) else {
                    return false;
                };
                let q = relative_throughput(self.beta * w, self.emitted, spectrum).min(0.95);
                if u_rr >= q {
                    return false;
                }
                (wi, w / q)
            }
        };
        let mut beta = self.beta * w;
        if let Spectrum::Channel(k) = spectrum {
            let keep = beta[k];
            beta = Rgb::ZERO;
            beta[k] = keep;
        }
        if !(beta.max_element() > 0.0 && beta.is_finite()) {
            return false;
        }
        self.beta = beta;
        self.ray = Ray::new(offset_point(vertex.sp.p, vertex.sp.ng, wi), wi);
        self.depth = depth + 1;
        true
    }
}
