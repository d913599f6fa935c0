//! Phase 1, particle tracing (§3.1, §4.1).
//!
//! The total power Φ of the luminaires is summed; luminaire i sends an
//! expected N_i = nΦ_i/Φ particles, ⌊N_i⌋ plus one with probability
//! N_i − ⌊N_i⌋, from uniform points with cosine-distributed directions (the
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
//! order. The file depends on the seed only, not on the thread count.

use std::f32::consts::PI;

use std::ops::ControlFlow;

use rayon::prelude::*;

use super::hitfile::HitFileError;
use super::hits::{encode_rgb9e5, to_fixed, Hit, HitSink};
use super::surfaces::{Kind, SurfaceId, Surfaces};

use crate::geometry::{offset_point, Frame, Ray};
use crate::methods::World;
use crate::sampling::{cosine_hemisphere, uniform_triangle, Distribution1D, Pcg32};
use crate::scene::{luminance, EmitterDesc, Rgb};
use crate::transport::{light_walk, Spectrum};

/// Particles per chunk (one random stream each).
pub const CHUNK: u64 = 1 << 14;
/// Chunks traced in parallel before their hits are appended.
pub const BATCH: u64 = 64;

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
}

/// The luminaires of a scene: its area lights, and the environment if it
/// has one.
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

/// Traces `n` particles (per channel run) and streams their hits to `out`,
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
    let weight = |c: Rgb| match channel {
        Channel::Rgb => luminance(c) as f64,
        Channel::Single(k) => c[k] as f64,
    };
    let phi_total: f64 = lums.iter().map(|l| weight(l.phi)).sum();
    let phi_ref = phi_unit(lums, n);
    if phi_total <= 0.0 || n == 0 {
        return Ok(TraceStats::default());
    }
    let salt = match channel {
        Channel::Rgb => 0xD0,
        Channel::Single(k) => 0xD1 + k as u64,
    };

    // N_i = nΦ_i/Φ: ⌊N_i⌋ and one more with probability N_i − ⌊N_i⌋
    let mut counts = Vec::with_capacity(lums.len());
    for (i, l) in lums.iter().enumerate() {
        let ni = n as f64 * weight(l.phi) / phi_total;
        let mut rng = Pcg32::keyed(&[seed, i as u64, salt, 0x4e]);
        let extra = u64::from(rng.next_f64() < ni - ni.floor());
        counts.push(ni.floor() as u64 + extra);
    }
    let total: u64 = counts.iter().sum();
    let starts: Vec<u64> = counts
        .iter()
        .scan(0u64, |s, &c| {
            let v = *s;
            *s += c;
            Some(v)
        })
        .collect();

    // Every particle starts with φ = Φ/n, coloured as its luminaire (for
    // the environment, the factor that turns the power of one emission
    // sample, whose luminance is Φ_env, into that of one of N_env particles)
    let power: Vec<Rgb> = lums
        .iter()
        .map(|l| {
            let LuminaireKind::Area { le, .. } = &l.kind else {
                return Rgb::splat((phi_total / n as f64 / phi_ref / weight(l.phi)) as f32);
            };
            let le = *le;
            let w = weight(le) as f32;
            let c = match channel {
                Channel::Rgb => le / w.max(1e-30),
                Channel::Single(k) => {
                    let mut v = Rgb::ZERO;
                    v[k] = 1.0;
                    v
                }
            };
            c * (phi_total / n as f64 / phi_ref) as f32
        })
        .collect();

    let chunks = total.div_ceil(CHUNK);
    let mut stats = TraceStats {
        particles: total,
        ..Default::default()
    };
    let mut c0 = 0;
    while c0 < chunks {
        let c1 = (c0 + BATCH).min(chunks);
        let results: Vec<(Vec<Hit>, u64)> = (c0..c1)
            .into_par_iter()
            .map(|c| {
                let mut rng = Pcg32::keyed(&[seed, c, salt]);
                let mut hits = Vec::new();
                let mut rays = 0;
                let (a, b) = (c * CHUNK, ((c + 1) * CHUNK).min(total));
                let mut li = starts.partition_point(|&s| s <= a).saturating_sub(1);
                for k in a..b {
                    while li + 1 < lums.len() && k >= starts[li + 1] {
                        li += 1;
                    }
                    if counts[li] == 0 {
                        continue;
                    }
                    rays += trace_one(
                        world, surfaces, &lums[li], power[li], channel, max_depth, &mut rng,
                        &mut hits,
                    );
                }
                (hits, rays)
            })
            .collect();
        for (hits, rays) in results {
            stats.hits += hits.len() as u64;
            stats.rays += rays;
            out.push(&hits)?;
        }
        c0 = c1;
    }
    Ok(stats)
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
        LuminaireKind::Environment => {
            let (u_pos, u_dir) = (rng.next_2d(), rng.next_2d());
            let Some(es) = world.lights.sample_env_emission(u_pos, u_dir) else {
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
    light_walk(world, ray, beta, spectrum, max_depth, rng, |e| {
        // Record the hit on a surface with a diffuse part (the side the
        // particle came from), its power times the coat's transmittance
        // T(cos θ) for a coated model (1 otherwise), so that the estimate is
        // the Ĥ of [`crate::bsdf::DiffusePart`]
        let (v, hit) = (e.vertex, e.hit);
        let sid = surfaces.tri_surface[hit.tri as usize];
        let s = &surfaces.list[sid as usize];
        let wo = v.wo_local;
        if s.diffuse && wo.z > 0.0 {
            let t = v.bsdf.diffuse_part().map_or(1.0, |d| d.t(wo.z));
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
    })
}
