//! Phase 1, particle tracing (§3.1, §4.1).
//!
//! The total power Φ of the luminaires is summed; luminaire i sends an
//! expected N_i = nΦ_i/Φ particles (stratified chunk by chunk, see
//! [`Tracer`]), from uniform points with cosine-distributed directions (the
//! pdf ∝ L_e cos θ of a diffuse luminaire). The environment (constant or
//! map) is one more luminaire, of power π R² ∫ L dω: its particles enter
//! the scene as parallel rays from a disk of the bounding radius R, as in
//! light tracing. Every particle starts with the
//! power φ = Φ/n (its colour that of the luminaire). At each surface it is
//! reflected, transmitted or absorbed by the BSDF (sampled in importance
//! mode, Russian roulette on the largest channel of the albedo, so that a
//! particle keeps its power while it lives); glass and metal are traced
//! through. Every hit on a surface with a diffuse part is recorded before
//! scattering.
//!
//! Parallelism and determinism: particles are numbered globally and cut in
//! chunks of [`CHUNK`]; chunk c draws from the stream keyed (seed, c), chunks
//! of a batch run in parallel and are appended to the hit file in chunk
//! order. The file depends on the seed only, not on the thread count nor
//! on the batch size. A [`Tracer`] may stop after any chunk (the render's
//! budget): each chunk samples the luminaires in proportion to their power
//! on its own, so the particles traced so far are always a fair run.

use std::f32::consts::PI;

use std::ops::ControlFlow;
use std::sync::atomic::{AtomicBool, Ordering};

use rayon::prelude::*;

use super::hitfile::HitFileError;
use super::hits::{encode_rgb9e5, to_fixed, Hit, HitSink};
use super::surfaces::{Kind, SurfaceId, Surfaces};

use crate::geometry::{offset_point, Frame, Ray};
use crate::methods::World;
use crate::sampling::{cosine_hemisphere, uniform_triangle, Distribution1D, Pcg32};
use crate::scene::{luminance, EmitterDesc, Rgb};
use crate::transport::{light_walk, Roulette, Spectrum};

/// Particles per chunk (one random stream each).
pub const CHUNK: u64 = 1 << 14;
/// Chunks traced in parallel before their hits are appended.
pub const BATCH: u64 = 64;
/// Chunks per batch when a budget may stop the tracing between batches
/// ([`super::pipeline::trace_within`]).
pub const BUDGET_BATCH: u64 = 16;

/// One luminaire of §3.1.
#[derive(Clone, Debug)]
pub struct Luminaire {
    /// Where its particles start.
    pub kind: LuminaireKind,
    /// Power per channel: π A L_e for an area light, π R² ∫ L dω for the
    /// environment (through the disk its particles start from).
    pub phi: Rgb,
}

/// How a luminaire emits.
#[derive(Clone, Debug)]
pub enum LuminaireKind {
    /// An area light: uniform points on its triangles, cosine-distributed
    /// directions (the pdf ∝ L_e cos θ of a diffuse luminaire).
    Area {
        /// Triangles.
        tris: Vec<u32>,
        /// Area distribution over `tris`.
        dist: Distribution1D,
        /// Emitted radiance.
        le: Rgb,
    },
    /// The environment (constant or map): parallel rays from a disk of the
    /// scene's bounding radius, directions by the environment's own
    /// sampling ([`crate::emitter::Lights::sample_env_emission`], shared
    /// with light tracing).
    Environment,
    /// Punctual light k of [`crate::emitter::Lights::punctual`]: particles
    /// from its point (uniform directions, or the spot's cone) or, for a
    /// directional light, parallel rays from the disk the environment uses
    /// ([`crate::emitter::Lights::sample_punctual_emission`]).
    Punctual(u32),
}

/// The luminaires of a scene: its area lights, its punctual lights, and the
/// environment if it has one.
pub fn luminaires(world: &World) -> Vec<Luminaire> {
    let scene = &world.scene;
    let mut out = Vec::new();
    for e in &scene.emitters {
        if let EmitterDesc::Area { shape, radiance } = e {
            let sh = &scene.shapes[*shape as usize];
            let tris: Vec<u32> = (sh.first_tri..sh.first_tri + sh.tri_count).collect();
            let areas: Vec<f64> = tris.iter().map(|&t| scene.tri_area(t) as f64).collect();
            let dist = Distribution1D::new(&areas);
            let a = dist.total() as f32;
            let phi = *radiance * (PI * a);
            if luminance(phi) > 0.0 {
                out.push(Luminaire {
                    kind: LuminaireKind::Area {
                        tris,
                        dist,
                        le: *radiance,
                    },
                    phi,
                });
            }
        }
    }
    for k in 0..world.lights.punctual().len() as u32 {
        let phi = world.lights.punctual_power(k);
        if luminance(phi) > 0.0 {
            out.push(Luminaire {
                kind: LuminaireKind::Punctual(k),
                phi,
            });
        }
    }
    let phi = world.lights.env_power();
    if world.lights.env.is_some() && luminance(phi) > 0.0 {
        out.push(Luminaire {
            kind: LuminaireKind::Environment,
            phi,
        });
    }
    out
}

/// Which power a run of particles carries.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Channel {
    /// One pass, RGB power on every particle (luminance picks the counts).
    Rgb,
    /// The paper's per-channel run: only channel 0, 1 or 2.
    Single(usize),
}

/// What the tracing phase produced.
#[derive(Clone, Copy, Debug, Default)]
pub struct TraceStats {
    /// Particles emitted.
    pub particles: u64,
    /// Hits recorded.
    pub hits: u64,
    /// Rays traced.
    pub rays: u64,
}

/// The power unit of the hit records: φ = Φ/n with Φ the luminance power.
pub fn phi_unit(lums: &[Luminaire], n: u64) -> f64 {
    lums.iter().map(|l| luminance(l.phi) as f64).sum::<f64>() / n.max(1) as f64
}

/// A run of `n` particles of one [`Channel`], traced chunk by chunk: any
/// prefix of whole chunks is a valid run of fewer particles (the budget
/// may stop tracing between batches, [`super::pipeline::trace`]).
///
/// The luminaire of each particle: within chunk c, particle j takes the
/// luminaire whose slice of the power CDF holds (j + ξ_c)/len, ξ_c one
/// number of the chunk's own stream. Every chunk is thus a stratified
/// sample of §3.1's allocation N_i = nΦ_i/Φ (its expected share of
/// luminaire i is exactly Φ_i/Φ), so that a run cut after any chunk still
/// covers every luminaire in proportion; the paper's allocation, all of
/// luminaire 0's particles then all of luminaire 1's, would be biased by a
/// cut. With one luminaire the two are the same particles.
pub struct Tracer<'a> {
    world: &'a World,
    surfaces: &'a Surfaces,
    lums: &'a [Luminaire],
    /// Cumulative weights of the luminaires, normalised to end at 1.
    cdf: Vec<f64>,
    /// Starting power of a particle of each luminaire, relative to φ.
    power: Vec<Rgb>,
    n: u64,
    channel: Channel,
    seed: u64,
    salt: u64,
    max_depth: Option<u32>,
}

impl<'a> Tracer<'a> {
    /// A run of `n` particles; None when the luminaires emit nothing in
    /// `channel` or `n` is 0.
    pub fn new(
        world: &'a World,
        surfaces: &'a Surfaces,
        lums: &'a [Luminaire],
        n: u64,
        channel: Channel,
        seed: u64,
        max_depth: Option<u32>,
    ) -> Option<Self> {
        let weight = |c: Rgb| match channel {
            Channel::Rgb => luminance(c) as f64,
            Channel::Single(k) => c[k] as f64,
        };
        let phi_total: f64 = lums.iter().map(|l| weight(l.phi)).sum();
        if phi_total.is_nan() || phi_total <= 0.0 || n == 0 {
            return None;
        }
        // The records are relative to φ = Φ/n with Φ the luminance power:
        // the factor Φ_channel/Φ does not depend on n, so a cut run's
        // records stay valid with φ = Φ/(particles traced)
        let rel = lums.iter().map(|l| luminance(l.phi) as f64).sum::<f64>();
        let scale = phi_total / rel;
        let cdf = lums
            .iter()
            .scan(0.0, |acc, l| {
                *acc += weight(l.phi) / phi_total;
                Some(*acc)
            })
            .collect();
        // Every particle starts with φ = Φ/n, coloured as its luminaire (for
        // the environment and punctual lights, the factor that turns the power of one emission
        // sample, whose weight is Φ_env, into that of one of N_env particles)
        let power = lums
            .iter()
            .map(|l| {
                let LuminaireKind::Area { le, .. } = &l.kind else {
                    return Rgb::splat((scale / weight(l.phi)) as f32);
                };
                let w = weight(*le) as f32;
                let c = match channel {
                    Channel::Rgb => *le / w.max(1e-30),
                    Channel::Single(k) => {
                        let mut v = Rgb::ZERO;
                        v[k] = 1.0;
                        v
                    }
                };
                c * scale as f32
            })
            .collect();
        let salt = match channel {
            Channel::Rgb => 0xD0,
            Channel::Single(k) => 0xD1 + k as u64,
        };
        Some(Tracer {
            world,
            surfaces,
            lums,
            cdf,
            power,
            n,
            channel,
            seed,
            salt,
            max_depth,
        })
    }

    /// Chunks in the whole run.
    pub fn chunks(&self) -> u64 {
        self.n.div_ceil(CHUNK)
    }

    /// Particles in chunks `c0..c1`.
    pub fn particles_in(&self, c0: u64, c1: u64) -> u64 {
        (c1 * CHUNK).min(self.n).saturating_sub(c0 * CHUNK)
    }

    /// Traces chunks `c0..c1` in parallel; returns each chunk's hits and
    /// rays, in chunk order. Once `cancel` is set, chunks not yet begun
    /// trace nothing (the caller discards the batch).
    pub fn trace_chunks(
        &self,
        c0: u64,
        c1: u64,
        cancel: Option<&AtomicBool>,
    ) -> Vec<(Vec<Hit>, u64)> {
        (c0..c1)
            .into_par_iter()
            .map(|c| {
                if cancel.is_some_and(|f| f.load(Ordering::Relaxed)) {
                    return (Vec::new(), 0);
                }
                let mut rng = Pcg32::keyed(&[self.seed, c, self.salt]);
                let (a, b) = (c * CHUNK, ((c + 1) * CHUNK).min(self.n));
                let xi = if self.lums.len() > 1 {
                    Pcg32::keyed(&[self.seed, c, self.salt, 0x4e]).next_f64()
                } else {
                    0.0
                };
                let mut hits = Vec::new();
                let mut rays = 0;
                for j in 0..b - a {
                    let u = (j as f64 + xi) / (b - a) as f64;
                    let li = self
                        .cdf
                        .partition_point(|&p| p <= u)
                        .min(self.lums.len() - 1);
                    rays += trace_one(
                        self.world,
                        self.surfaces,
                        &self.lums[li],
                        self.power[li],
                        self.channel,
                        self.max_depth,
                        &mut rng,
                        &mut hits,
                    );
                }
                (hits, rays)
            })
            .collect()
    }
}

/// Traces `n` particles (one channel run) and streams their hits to `out`,
/// in particle order.
#[allow(clippy::too_many_arguments)]
pub fn trace(
    world: &World,
    surfaces: &Surfaces,
    lums: &[Luminaire],
    n: u64,
    channel: Channel,
    seed: u64,
    max_depth: Option<u32>,
    out: &mut impl HitSink,
) -> Result<TraceStats, HitFileError> {
    let Some(t) = Tracer::new(world, surfaces, lums, n, channel, seed, max_depth) else {
        return Ok(TraceStats::default());
    };
    let mut stats = TraceStats {
        particles: n,
        ..Default::default()
    };
    let chunks = t.chunks();
    let mut c0 = 0;
    while c0 < chunks {
        let c1 = (c0 + BATCH).min(chunks);
        for (hits, rays) in t.trace_chunks(c0, c1, None) {
            stats.hits += hits.len() as u64;
            stats.rays += rays;
            out.push(&hits)?;
        }
        c0 = c1;
    }
    Ok(stats)
}

/// The weight |wo·ns|/|wo·ng| of a hit arriving from `wo`, given its
/// cosines with the shading normal (`cos_s`, positive) and with the
/// geometric normal (`cos_g`); 0 for a particle grazing the geometry (as
/// [`crate::bsdf::shading_normal_correction_over`] gives).
#[inline]
fn shading_weight(cos_s: f32, cos_g: f32) -> f32 {
    let w = cos_s / cos_g.abs();
    if w.is_finite() {
        w
    } else {
        0.0
    }
}

/// One particle's walk ([`light_walk`]); returns the rays traced.
#[allow(clippy::too_many_arguments)]
fn trace_one(
    world: &World,
    surfaces: &Surfaces,
    lum: &Luminaire,
    power: Rgb,
    channel: Channel,
    max_depth: Option<u32>,
    rng: &mut Pcg32,
    hits: &mut Vec<Hit>,
) -> u64 {
    let scene = &world.scene;
    let (ray, beta) = match &lum.kind {
        LuminaireKind::Area { tris, dist, .. } => {
            // Emission: a triangle by area, a uniform point, a cosine direction
            let (i, _, _) = dist.sample(rng.next_f64());
            let tri = tris[i];
            let b = uniform_triangle(rng.next_2d());
            let sp = scene.surface_point(tri, b.x, b.y);
            let d = Frame::from_normal(sp.ng).to_world(cosine_hemisphere(rng.next_2d()));
            (Ray::new(offset_point(sp.p, sp.ng, d), d), power)
        }
        LuminaireKind::Environment | LuminaireKind::Punctual(_) => {
            let (u_pos, u_dir) = (rng.next_2d(), rng.next_2d());
            let es = match lum.kind {
                LuminaireKind::Punctual(k) => {
                    world.lights.sample_punctual_emission(k, u_pos, u_dir)
                }
                _ => world.lights.sample_env_emission(u_pos, u_dir),
            };
            let Some(es) = es else {
                return 0;
            };
            let mut beta = es.phi * power;
            if let Channel::Single(k) = channel {
                let keep = beta[k];
                beta = Rgb::ZERO;
                beta[k] = keep;
            }
            if !beta.is_finite() {
                return 0;
            }
            (es.ray(), beta)
        }
    };
    let spectrum = match channel {
        Channel::Rgb => Spectrum::Rgb,
        Channel::Single(k) => Spectrum::Channel(k),
    };
    // The walk records a hit only while its light path is shorter than
    // `max_depth`: the view pass adds the segment to the eye (Mitsuba's
    // convention, as in light tracing)
    light_walk(
        world,
        ray,
        beta,
        spectrum,
        Roulette::Albedo,
        max_depth,
        rng,
        |e| {
            // Record the hit on a surface with a diffuse part (the side the
            // particle came from), its power times the coat's transmittance
            // T(cos θ) for a coated model (1 otherwise), so that the estimate is
            // the Ĥ of [`crate::bsdf::DiffusePart`]
            let (v, hit) = (e.vertex, e.hit);
            let sid = surfaces.tri_surface[hit.tri as usize];
            let s = &surfaces.list[sid as usize];
            let wo = v.wo_local;
            if s.diffuse && wo.z > 0.0 {
                // and times |wo·ns|/|wo·ng|: a hit's power falls on the geometric
                // area, but the Lambertian lobe of a shading normal reflects
                // ∫ L_i |wi·ns| dω, so this is the irradiance L = R·H/π needs.
                // The light tracer's camera connection carries the same factor
                // (Veach 1997, eq. 5.17); it is exactly 1 where ns = ng
                let t = v.bsdf.diffuse_part().map_or(1.0, |d| d.t(wo.z))
                    * shading_weight(wo.z, v.wo.dot(v.ng));
                let back = v.wo.dot(v.sp.ng) < 0.0;
                let (u, v) = match s.kind {
                    Kind::Planar => {
                        let c = s.to_chart(v.sp.p) / s.size;
                        (c.x, c.y)
                    }
                    Kind::Curved => (hit.b1, hit.b2),
                };
                hits.push(Hit {
                    surface: SurfaceId { index: sid, back },
                    u: to_fixed(u),
                    v: to_fixed(v),
                    rgb: encode_rgb9e5(e.beta * t),
                });
            }
            ControlFlow::Continue(())
        },
    )
}
