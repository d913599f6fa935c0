//! The camera pass of the light-based methods (`light`, `plb`): the part of
//! path space that light paths cannot reach.
//!
//! A light-path vertex reaches the camera by an explicit connection, which
//! evaluates the BSDF at the first camera vertex x₁; a delta lobe evaluates
//! to zero there, so every path whose first camera vertex scatters through a
//! delta lobe (mirror, smooth conductor, smooth glass, thin glass, the coat
//! of smooth plastic) has zero probability in the light-based estimator, and
//! so has the environment seen directly. The path space is therefore
//! partitioned by the lobe used at x₁:
//!
//! - non-delta lobe at x₁ (and emission at x₁): the light-based method, as
//!   before: its connection evaluates exactly the non-delta part of the BSDF;
//! - delta lobe at x₁, or no x₁ (the primary ray escapes to the
//!   environment): this camera pass. It samples the BSDF at x₁ and keeps
//!   only delta samples (a non-delta sample contributes nothing here: that
//!   part belongs to the light-based method), follows the ray onward with the
//!   path tracer's estimator (delta chains, then next-event estimation with
//!   MIS and further bounces), [`super::radiance_from`].
//!
//! The two parts are disjoint and cover everything, so nothing is counted
//! twice: the light-based method never splats a path whose x₁ scatters
//! through a delta lobe (its connection weight is zero there), and the camera
//! pass drops every path whose x₁ scatters through a non-delta lobe and never
//! adds emission at x₁.
//!
//! **Glossy first vertices** (`CameraPass::new` with `glossy`, used by
//! `plb --variant guided`). A light path reaches the camera through a
//! glossy lobe at x₁ only when its last segment happens to fall inside the
//! lobe, so glossy surfaces seen by the camera are noisy in every
//! light-based method, while a camera-side BSDF sample at x₁ finds the lobe
//! at once. Both strategies can make every path whose x₁ scatters through a
//! glossy BSDF's non-delta lobes, so they are combined by multiple
//! importance sampling: the camera pass weights its non-delta sample by
//! w_C and the light-based connection weights its splat by 1 − w_C
//! ([`camera_share`]). w_C is a function of the path alone (the BSDF at x₁,
//! the direction to the eye and the direction to x₂), computed identically
//! by both sides, so the two weights sum to one on every such path: nothing
//! is counted twice and nothing is lost, whatever the weight. It is the
//! balance heuristic (power 2) between the BSDF's sampling density at x₁,
//! p, and a constant κ standing for the light side's density of arrivals:
//! w_C = p² / (p² + κ²). Where the lobe is sharp (p ≫ κ) the camera side
//! takes the path; over a diffuse base (p ≤ 1/π) the light side keeps most
//! of it. BSDFs without a glossy lobe ([`Bsdf::has_glossy`]), or whose
//! lobe is not sharp ([`is_sharp`]: its peak density below κ, where the
//! camera side would take less than half of even the peak's paths), stay
//! entirely with the light side: the camera pass would pay a path-traced
//! sample per pixel and pass for a small share of the image.
//!
//! Budget. Scenes with neither delta lobes nor an environment (nor, glossy,
//! sharp lobes) need no camera pass at all, and get none (cbox and
//! two-rooms-baffle cost nothing). Otherwise a pre-pass
//! ([`CameraPass::prepare`], run by the methods' `prepare`, so inside the
//! driver's clock and with its rays counted) of up to 4×4 stratified primary
//! rays per pixel marks the pixels whose first hit has a delta lobe or that
//! see the environment; marked pixels get one camera sample per pass, and
//! the others, so that a sliver the pre-pass missed still converges, one
//! with probability 1/16 (weighted by 16). The effort thus follows the
//! fraction of pixels whose first hit is delta, as the light-based method
//! gives about one light path per pixel per pass.
//!
//! Numbers (`--sampler` of `light` and `plb`). A pixel's sample of pass
//! p draws from PCG32 keyed by (seed, pass, pixel), or with
//! [`SamplerKind::Sobol`] is Owen-scrambled Sobol point p of the pixel's
//! sequence ([`SobolSampler`], keyed by (seed, pixel, pass) as `path`'s),
//! with its own layout: dimensions 0–1 the camera jitter, 2 the lobe and
//! 3–4 the direction at x₁, then from the vertex at depth 2 on `path`'s
//! seven per vertex ([`super::radiance_from`] moves there). An unmarked pixel's
//! coin is drawn from the PCG32 stream either way, so both samplers visit
//! the same pixels, and an unmarked pixel's samples are the points of the
//! passes that drew it (unbiased, not stratified).

use glam::DVec3;
use rayon::prelude::*;

use glam::Vec3;

use super::lanes::{radiance_continued, LaneSampler};
use super::DepthLimits;
use crate::bsdf::{Bsdf, Mode};
use crate::emitter::LightSelection;
use crate::film::Image;
use crate::geometry::{offset_point, Ray};
use crate::sampling::{Pcg32, Sampler, SamplerKind, SobolSampler};
use crate::scene::Rgb;
use crate::simd::dispatched;
use crate::state::Shard;
use crate::world::World;

/// Probability with which an unmarked pixel is sampled in a pass.
const UNMARKED_PROB: f32 = 1.0 / 16.0;
/// Strata per pixel side of the pre-pass: at most 4×4 primary rays a pixel.
const PRE_PASS_SIDE: usize = 4;
/// Depth from which Russian roulette may stop a camera-pass path.
const RR_DEPTH: u32 = 3;
/// κ of [`camera_share`], per steradian: the BSDF density at which the
/// camera side and the light side share a glossy path equally.
const KAPPA: f32 = 1.0;
/// The least peak density, per steradian, of a glossy lobe the camera pass
/// takes a share of ([`is_sharp`]): κ, so that at the lobe's peak the
/// camera side would take at least half of the path. Below it the light
/// side keeps the whole lobe and the pass does not mark its pixels. The
/// rough plastics of two-rooms-baffle (α 0.15–0.3 over a bright base) peak
/// at 0.39–0.71; the polished floor of two-rooms/glossy-floor.xml (α 0.05)
/// at 2.91. On the baffle their share of the camera pass cost about a
/// quarter of plb's passes at equal time (1,776 against 2,378 in 20 s with
/// `--camera-pass off`) and brought little: without it, relMSE at equal
/// time, less the reference's noise, fell to 0.71× (docs/notebook/plb.md, "The camera pass in lanes, and for
/// sharp lobes only").
const SHARP_PEAK: f32 = KAPPA;

/// The camera side's MIS weight w_C = p² / (p² + κ²) of a path whose first
/// camera vertex x₁ has BSDF `bsdf` and scatters from `wo` (local, toward
/// the eye) to `wi` (local, toward x₂) through a non-delta lobe; p is the
/// BSDF's sampling density of `wi` given `wo`. Zero for BSDFs without a
/// sharp glossy lobe ([`is_sharp`]). The light-based method weights its
/// camera connection by 1 − w_C (see the module docs).
#[inline]
pub fn camera_share(bsdf: &Bsdf, wo: Vec3, wi: Vec3) -> f32 {
    if !is_sharp(bsdf) {
        return 0.0;
    }
    sharp_share(bsdf, wo, wi)
}

/// [`camera_share`] of a BSDF already known to be sharp ([`is_sharp`]),
/// without judging it again.
#[inline]
fn sharp_share(bsdf: &Bsdf, wo: Vec3, wi: Vec3) -> f32 {
    let p = bsdf.pdf(wo, wi);
    if p.is_nan() || p <= 0.0 {
        return 0.0;
    }
    let p2 = p * p;
    if p2.is_infinite() {
        return 1.0;
    }
    p2 / (p2 + KAPPA * KAPPA)
}

/// Whether `bsdf` has a glossy lobe sharp enough for the camera side:
/// its sampling density toward the mirror direction at normal incidence,
/// the lobe's peak, is at least κ, the MIS constant of [`camera_share`]
/// (`SHARP_PEAK`).
#[inline]
pub fn is_sharp(bsdf: &Bsdf) -> bool {
    bsdf.has_glossy() && bsdf.pdf(Vec3::Z, Vec3::Z) >= SHARP_PEAK
}

/// The camera pass's state: the pixel mask and the per-pixel sums.
pub struct CameraPass {
    active: bool,
    /// Glossy first vertices too, with MIS (see the module docs).
    glossy: bool,
    /// The pre-pass has run (always true when inactive).
    prepared: bool,
    marked: Vec<bool>,
    sum: Vec<DVec3>,
    passes: u64,
    seed: u64,
    limits: DepthLimits,
    /// The rows this process samples, y ≡ K (mod N) for shard K/N.
    shard: Shard,
    /// Which numbers the samples draw (see the module docs).
    sampler: SamplerKind,
}

impl CameraPass {
    /// The camera pass of a light-based method, not yet prepared: it traces
    /// nothing until [`CameraPass::prepare`]. `enabled = false`
    /// (`--camera-pass off`) gives the raw light-based method; so does a
    /// scene with neither delta lobes nor an environment (nor, with
    /// `glossy`, sharp glossy lobes, [`is_sharp`], or glossy materials that
    /// vary over their surface and so may be sharp somewhere). With `glossy` the method's camera
    /// connections must be weighted by 1 − [`camera_share`]
    /// ([`CameraPass::splits_glossy`]). `sampler` chooses the numbers the
    /// samples draw (see the module docs).
    pub fn new(
        world: &World,
        enabled: bool,
        glossy: bool,
        seed: u64,
        max_depth: Option<u32>,
        sampler: SamplerKind,
    ) -> Self {
        // A glossy lobe is needed where it is sharp, or may be somewhere
        // (a material that varies over its surface)
        let needed = world.lights.env.is_some()
            || world.scene.materials.iter().any(|m| {
                let b = m.bsdf(glam::Vec2::ZERO);
                let sharp = is_sharp(&b) || (b.has_glossy() && !m.is_uniform());
                b.has_delta() || (glossy && sharp)
            });
        let active = enabled && needed;
        CameraPass {
            active,
            glossy: glossy && enabled,
            prepared: !active,
            marked: Vec::new(),
            sum: Vec::new(),
            passes: 0,
            seed,
            limits: DepthLimits {
                max_depth,
                rr_depth: RR_DEPTH,
                light_selection: LightSelection::Power,
            },
            shard: Shard::WHOLE,
            sampler,
        }
    }

    /// Restricts the pre-pass and the passes to the rows y ≡ K (mod N) of
    /// `shard`; each pixel's sum is then that of one run.
    pub fn set_shard(&mut self, shard: Shard) {
        self.shard = shard;
    }

    /// The per-pixel sums and the pass count, when the pass is active and
    /// prepared.
    pub fn state(&self) -> Option<(&[DVec3], u64)> {
        (self.active && self.prepared).then_some((self.sum.as_slice(), self.passes))
    }

    /// Continues from [`CameraPass::state`]'s sums and pass count, after
    /// [`CameraPass::prepare`].
    pub fn restore(&mut self, sum: &[DVec3], passes: u64) {
        self.sum.copy_from_slice(sum);
        self.passes = passes;
    }

    /// The pre-pass: marks the pixels whose first hit has a delta lobe or
    /// that see the environment, stopping at a pixel's first such ray.
    /// Returns the rays traced; runs once (later calls trace nothing).
    pub fn prepare(&mut self, world: &World) -> u64 {
        if self.prepared {
            return 0;
        }
        self.prepared = true;
        let (w, h) = (world.camera.width as usize, world.camera.height as usize);
        let side = PRE_PASS_SIDE;
        let glossy = self.glossy;
        let shard = self.shard;
        let marks: Vec<(bool, u64)> = (0..w * h)
            .into_par_iter()
            .map(|i| {
                if !shard.owns((i / w) as u64) {
                    return (false, 0);
                }
                let (x, y) = ((i % w) as f32, (i / w) as f32);
                let mut rays = 0;
                let marked = (0..side * side).any(|k| {
                    let sx = (k % side) as f32 + 0.5;
                    let sy = (k / side) as f32 + 0.5;
                    let ray = world.camera.ray(x + sx / side as f32, y + sy / side as f32);
                    rays += 1;
                    match world.accel.intersect(&ray) {
                        None => world.lights.env.is_some(),
                        Some(hit) => {
                            let sp = world.surface_point(&hit);
                            let b = world.scene.material_of(&sp).bsdf(sp.uv);
                            b.has_delta() || (glossy && is_sharp(&b))
                        }
                    }
                });
                (marked, rays)
            })
            .collect();
        self.marked = marks.iter().map(|m| m.0).collect();
        self.sum = vec![DVec3::ZERO; w * h];
        marks.iter().map(|m| m.1).sum()
    }

    /// True when this scene and setting use a camera pass.
    pub fn is_active(&self) -> bool {
        self.active
    }

    /// True when glossy first vertices are shared with the camera pass, so
    /// that the method's camera connections must carry 1 − [`camera_share`].
    pub fn splits_glossy(&self) -> bool {
        self.glossy
    }

    /// One pass; returns the rays traced. Runs the pre-pass first if the
    /// caller has not (its rays then count in this pass).
    pub fn step(&mut self, world: &World, pass: u64) -> u64 {
        if !self.active {
            return 0;
        }
        let pre = self.prepare(world);
        self.passes += 1;
        let w = world.camera.width as usize;
        let (seed, limits, glossy, sampler) = (self.seed, &self.limits, self.glossy, self.sampler);
        let marked = &self.marked;
        let shard = self.shard;
        let rays: u64 = self
            .sum
            .par_chunks_mut(w)
            .enumerate()
            .map(|(y, row)| {
                if !shard.owns(y as u64) {
                    return 0;
                }
                sample_row(world, limits, glossy, sampler, marked, seed, pass, y, row)
            })
            .sum();
        pre + rays
    }

    /// Adds the camera pass's estimate to `img`.
    pub fn add_to(&self, img: &mut Image) {
        if !self.active || self.passes == 0 {
            return;
        }
        let scale = 1.0 / self.passes as f64;
        for (p, s) in img.data.iter_mut().zip(&self.sum) {
            *p += (*s * scale).as_vec3();
        }
    }
}

dispatched! {
    /// One camera-pass sample for each pixel of row `y` (`row` holds its
    /// sums); returns the rays traced. The per-pass loop that runtime
    /// dispatch compiles for x86-64-v3 ([`super::dispatch`]).
    #[allow(clippy::too_many_arguments)]
    fn sample_row(
        world: &World,
        limits: &DepthLimits,
        glossy: bool,
        sampler: SamplerKind,
        marked: &[bool],
        seed: u64,
        pass: u64,
        y: usize,
        row: &mut [DVec3],
    ) -> u64 {
        let pixels = Pixels { world, glossy, marked, seed, pass, y };
        match sampler {
            SamplerKind::Independent => pixels.sample(limits, row, |_, rng| rng),
            SamplerKind::Sobol => {
                pixels.sample(limits, row, |i, _| SobolSampler::new(seed, i, pass))
            }
        }
    }
}

/// The pixels of one row of a pass.
struct Pixels<'a> {
    world: &'a World,
    glossy: bool,
    marked: &'a [bool],
    seed: u64,
    pass: u64,
    y: usize,
}

impl Pixels<'_> {
    /// One sample for each pixel of the row that draws one, into `row`;
    /// pixel i's numbers come from `sampler(i, rng)`, `rng` the PCG32
    /// stream that drew its coin. Every pixel's first vertex is taken
    /// first ([`first_vertex`]); the paths that go on then run together,
    /// eight at a time in AVX lanes where the CPU has them
    /// ([`radiance_continued`], the bits of [`super::radiance_from`]).
    /// Returns the rays traced.
    #[inline(always)]
    fn sample<S: LaneSampler>(
        &self,
        limits: &DepthLimits,
        row: &mut [DVec3],
        sampler: impl Fn(u64, Pcg32) -> S,
    ) -> u64 {
        let (world, w) = (self.world, row.len());
        let mut rays = 0;
        let mut go: Vec<(S, Ray)> = Vec::with_capacity(w);
        // Each path's pixel and the factor its radiance is multiplied by
        let mut scale: Vec<(usize, Rgb, f32)> = Vec::with_capacity(w);
        for (x, acc) in row.iter_mut().enumerate() {
            let i = self.y * w + x;
            let mut rng = Pcg32::keyed(&[self.seed, self.pass, i as u64, 0xCA]);
            let weight = if self.marked[i] {
                1.0
            } else if rng.next_f32() < UNMARKED_PROB {
                1.0 / UNMARKED_PROB
            } else {
                continue;
            };
            let mut s = sampler(i as u64, rng);
            match first_vertex(world, self.glossy, x, self.y, &mut s) {
                First::Done(l) => {
                    rays += 1;
                    add(acc, l * weight);
                }
                First::Next { beta, ray } => {
                    go.push((s, ray));
                    scale.push((x, beta, weight));
                }
            }
        }
        radiance_continued(world, limits, 2, &mut go, |k, l, r| {
            let (x, beta, weight) = scale[k];
            rays += 1 + r;
            add(&mut row[x], beta * l * weight);
        });
        rays
    }
}

/// Adds a sample `v` to a pixel's sum, unless it is not finite.
#[inline(always)]
fn add(acc: &mut DVec3, v: Rgb) {
    if v.is_finite() {
        *acc += v.as_dvec3();
    }
}

/// What a camera-pass sample's first vertex leaves.
enum First {
    /// The estimate, made (one ray traced).
    Done(Rgb),
    /// The path goes on along `ray` (untraced) with throughput `beta`.
    Next { beta: Rgb, ray: Ray },
}

/// The first vertex of a camera-pass sample of pixel (x, y): the
/// environment seen directly, nothing, or the throughput and the next
/// segment through a delta lobe at the first hit (and, with `glossy`,
/// through a glossy BSDF's other lobes, weighted by [`camera_share`]);
/// the estimate is then β times [`super::radiance_from`] that segment at
/// depth 2.
#[inline(always)]
fn first_vertex<S: Sampler>(world: &World, glossy: bool, x: usize, y: usize, rng: &mut S) -> First {
    let j = rng.next_2d();
    let ray = world.camera.ray(x as f32 + j.x, y as f32 + j.y);
    let Some(hit) = world.accel.intersect(&ray) else {
        return First::Done(world.lights.le_env(ray.d));
    };
    let v = world.vertex(&ray, &hit);
    let glossy = glossy && is_sharp(&v.bsdf);
    if !v.bsdf.has_delta() && !glossy {
        return First::Done(Rgb::ZERO);
    }
    let uc = rng.next_f32();
    let u = rng.next_2d();
    // Keep delta lobes, and glossy ones with their MIS weight: the rest
    // belongs to the light method
    let Some(s) = v.bsdf.sample(v.wo_local, uc, u, Mode::Radiance) else {
        return First::Done(Rgb::ZERO);
    };
    if s.pdf <= 0.0 {
        return First::Done(Rgb::ZERO);
    }
    let share = if s.delta {
        1.0
    } else if glossy {
        sharp_share(&v.bsdf, v.wo_local, s.wi)
    } else {
        0.0
    };
    if share <= 0.0 {
        return First::Done(Rgb::ZERO);
    }
    let wi = v.frame.to_world(s.wi);
    if wi.dot(v.ng) * s.wi.z <= 0.0 {
        return First::Done(Rgb::ZERO);
    }
    let beta = s.f * (s.wi.z.abs() / s.pdf * share);
    let ray = Ray::new(offset_point(v.sp.p, v.sp.ng, wi), wi);
    First::Next { beta, ray }
}
