//! The image estimate of §5, both kinds, from the incoming radiance of one
//! sweep (the field that arrived from ±ω_m):
//!
//! - **Phong**: per pixel, the visible point's own normal, view direction and
//!   BRDF reflect the incoming radiance: L = Le + 2π Σ_± f(±ω_m → wo) E_±/A.
//!   The visible point, normal and direction are found once, in a
//!   preprocessing pass, and stored ("stored in a map", §5). Glossy
//!   highlights follow the per-pixel BRDF.
//! - **Gouraud**: the BRDF is evaluated once per patch toward the eye
//!   (L^eye\[i\] of §5), the values are averaged onto the shared vertices
//!   (area-weighted) and interpolated over each patch.
//!
//! Both take emission at the visible point exactly. Delta surfaces seen by
//! the camera (mirrors, glass) are followed in the preprocessing pass with
//! one sampled chain per pixel sample, so a mirror shows a sharp reflection
//! of the patch radiance field.
//!
//! Sub-pixel positions ([`Positions`]): by default every iteration draws a
//! fresh position in each pixel (jittered in the 2×2 stratum m mod 4, so
//! that four iterations cover the pixel evenly) and traces its camera ray,
//! delta chain included, from the seeded stream of (pixel, iteration); the
//! average over iterations then converges to the pixel's box-filtered
//! value, and the delta chains are re-sampled every iteration. `fixed` is
//! the paper's preprocessing ("stored in a map"): [`SAMPLES`] stratified
//! positions traced once, iteration m using position m mod [`SAMPLES`], so
//! the image keeps the error of those four points.
//!
//! Pixels whose visible point is glossy take their reflected term from a
//! final gather instead (`View::gather`; the argument is in the docs of
//! [`super`]).

use glam::{DVec3, Vec2, Vec3};
use rayon::prelude::*;

use super::patches::Patches;
use super::transfer;
use crate::bsdf::Mode;
use crate::geometry::{offset_point, Ray};
use crate::methods::World;
use crate::sampling::Pcg32;
use crate::scene::Rgb;
use crate::transport::{direct_light, orient, Vertex};

/// Sub-pixel positions per pixel.
pub const SAMPLES: usize = 4;
const NO_PATCH: u32 = u32::MAX;
/// A sample that sees nothing yet, with unit throughput.
const NO_SAMPLE: PixelSample = PixelSample {
    patch: NO_PATCH,
    w: Vec3::ZERO,
    thr: Rgb::ONE,
    le: Rgb::ZERO,
    wo: Vec3::Z,
    ns: Vec3::Z,
    tri: 0,
    b: Vec2::ZERO,
};
/// Longest chain of delta bounces followed from the camera.
const MAX_DELTA: u32 = 8;

/// Where the sub-pixel positions come from.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "kebab-case")]
#[cfg_attr(feature = "cli", derive(clap::ValueEnum))]
pub enum Positions {
    /// A fresh jittered position per pixel and iteration (the default).
    Jittered,
    /// Four stratified positions per pixel (`SAMPLES`), traced once at setup
    /// (the paper's preprocessing).
    Fixed,
}

/// Which image estimate.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "kebab-case")]
#[cfg_attr(feature = "cli", derive(clap::ValueEnum))]
pub enum ImageMode {
    /// Per-pixel BRDF (the default).
    Phong,
    /// Per-patch radiance interpolated over the vertices.
    Gouraud,
}

/// What a pixel sample sees, found once.
#[derive(Clone, Copy, Debug)]
pub struct PixelSample {
    /// The patch seen (after delta bounces), or none.
    pub patch: u32,
    /// Barycentric weights on the patch corners.
    pub w: Vec3,
    /// Throughput of the delta chain.
    pub thr: Rgb,
    /// Emission seen along the chain (already weighted).
    pub le: Rgb,
    /// Direction toward the viewer at the visible point.
    pub wo: Vec3,
    /// Shading normal at the visible point (front side).
    pub ns: Vec3,
    /// Scene triangle of the visible point, for the first shot's light
    /// sample.
    pub tri: u32,
    /// Barycentrics (b1, b2) of the visible point on `tri`.
    pub b: Vec2,
}

/// What the paper's form reads of a stored sample every iteration: its
/// patch, and the pixel's value when that patch received nothing along
/// ±ω_m. Most patches receive nothing in an iteration, so most pixels need
/// no more than these 16 bytes of their 80-byte sample.
#[derive(Clone, Copy, Debug)]
struct Quiet {
    /// `le` + 0 (the zero direct light of this form), or NaN when the
    /// zero reflection `thr` · 0 · 2π/A is not finite, since the general
    /// path then drops the pixel.
    l: Rgb,
    /// The sample's patch, or [`NO_PATCH`].
    patch: u32,
}

/// Bytes of a sample's quiet part, kept beside it in the paper's form (for
/// the memory estimate before a render).
pub const QUIET_BYTES: usize = std::mem::size_of::<Quiet>();

/// The view: with [`Positions::Fixed`], [`SAMPLES`] samples per pixel
/// traced once, sample-major; with [`Positions::Jittered`], none stored.
pub struct View {
    /// Samples, `SAMPLES` blocks of width × height (fixed positions only).
    pub samples: Vec<PixelSample>,
    /// The samples' [`Quiet`] parts, in the same order, for the paper's form
    /// (fixed positions, no first shot, no gather); empty otherwise.
    quiet: Vec<Quiet>,
    positions: Positions,
    /// Add one light sample per pixel at the visible point (the first shot).
    nee: bool,
    /// Final gather at glossy visible points ([`super::Gather::Glossy`]).
    gather: bool,
    seed: u64,
    /// Area-weighted patch lists per vertex (CSR) for Gouraud.
    vstart: Vec<u32>,
    vpatch: Vec<u32>,
    /// Rays traced by the preprocessing.
    pub rays: u64,
}

impl View {
    /// The view; traces the camera rays once for fixed positions.
    pub fn new(
        world: &World,
        patches: &Patches,
        seed: u64,
        positions: Positions,
        nee: bool,
        gather: bool,
    ) -> Self {
        let (w, h) = (world.camera.width as usize, world.camera.height as usize);
        let n = w * h;
        let fixed = if positions == Positions::Fixed {
            SAMPLES * n
        } else {
            0
        };
        let results: Vec<(PixelSample, u64)> = (0..fixed)
            .into_par_iter()
            .map(|k| {
                let (s, pix) = (k / n, k % n);
                let (x, y) = (pix % w, pix / w);
                let mut rng = Pcg32::keyed(&[seed, pix as u64, s as u64, 0x1A]);
                // 2×2 strata
                let j = rng.next_2d();
                let fx = ((s % 2) as f32 + j.x) * 0.5;
                let fy = ((s / 2 % 2) as f32 + j.y) * 0.5;
                trace(
                    world,
                    patches,
                    world.camera.ray(x as f32 + fx, y as f32 + fy),
                    &mut rng,
                )
            })
            .collect();
        let rays = results.iter().map(|r| r.1).sum();
        let samples: Vec<PixelSample> = results.into_iter().map(|r| r.0).collect();
        let quiet = if !nee && !gather {
            samples
                .par_iter()
                .map(|s| {
                    let mut l = s.le + Rgb::ZERO;
                    if s.patch != NO_PATCH {
                        // reflected()'s product when both E are zero
                        let k = 2.0 * std::f32::consts::PI / patches.p[s.patch as usize].area;
                        if !(s.thr * Rgb::ZERO * k).is_finite() {
                            l = Rgb::NAN;
                        }
                    }
                    Quiet { l, patch: s.patch }
                })
                .collect()
        } else {
            Vec::new()
        };
        // vertex → patches
        let mut count = vec![0u32; patches.vertex_count + 1];
        for v in &patches.vid {
            for &x in v {
                count[x as usize + 1] += 1;
            }
        }
        for i in 1..count.len() {
            count[i] += count[i - 1];
        }
        let vstart = count.clone();
        let mut fill = count;
        let mut vpatch = vec![0u32; *vstart.last().unwrap_or(&0) as usize];
        for (p, v) in patches.vid.iter().enumerate() {
            for &x in v {
                vpatch[fill[x as usize] as usize] = p as u32;
                fill[x as usize] += 1;
            }
        }
        View {
            samples,
            quiet,
            positions,
            nee,
            gather,
            seed,
            vstart,
            vpatch,
            rays,
        }
    }

    /// The sample of pixel `pix` in iteration `iter`, and the rays traced
    /// for it: the stored one (fixed positions, by reference: it is read
    /// every iteration), or a fresh position in stratum `iter` mod 4, traced
    /// now into `fresh`.
    fn sample<'a>(
        &'a self,
        world: &World,
        patches: &Patches,
        pix: usize,
        iter: u64,
        fresh: &'a mut Option<PixelSample>,
    ) -> (&'a PixelSample, u64) {
        let n = world.camera.width as usize * world.camera.height as usize;
        match self.positions {
            Positions::Fixed => (&self.samples[(iter as usize % SAMPLES) * n + pix], 0),
            Positions::Jittered => {
                let w = world.camera.width as usize;
                let (x, y) = (pix % w, pix / w);
                let s = iter % 4;
                let mut rng = Pcg32::keyed(&[self.seed, pix as u64, iter, 0x1B]);
                let j = rng.next_2d();
                let fx = ((s % 2) as f32 + j.x) * 0.5;
                let fy = ((s / 2) as f32 + j.y) * 0.5;
                let (sample, rays) = trace(
                    world,
                    patches,
                    world.camera.ray(x as f32 + fx, y as f32 + fy),
                    &mut rng,
                );
                (fresh.insert(sample), rays)
            }
        }
    }

    /// With the first shot, the direct light that sample `s` of pixel `pix`
    /// sees in iteration `iter` (one light sample at its visible point,
    /// times the delta chain's throughput), and the rays traced.
    fn direct(&self, world: &World, s: &PixelSample, pix: usize, iter: u64) -> (Rgb, u64) {
        if !self.nee || s.patch == NO_PATCH {
            return (Rgb::ZERO, 0);
        }
        let sp = world.scene.surface_point(s.tri, s.b.x, s.b.y);
        let v = Vertex::new(world, sp, s.wo);
        let mut rng = Pcg32::keyed(&[self.seed, pix as u64, iter, 0x1D]);
        let (l, rays) = direct_light(world, &v, &mut rng);
        (s.thr * l, rays)
    }

    /// The final gather of sample `s` of pixel `pix` in iteration `iter`:
    /// None when it does not apply (gather off, nothing seen, or a visible
    /// point without a glossy lobe); otherwise the radiance that the visible
    /// point x reflects toward the eye of what the patch solution sends it
    /// (times the delta chain's throughput), and the rays traced.
    ///
    /// One direction wi is drawn from the BSDF at x (radiance mode) and
    /// traced to the first surface y, on patch j. What patch j sends back
    /// toward x, −wi, is the patch solution in the form the transfer builds
    /// it ([`transfer::reflect_onto`], eq. (27) for one direction): the
    /// start term plus 2π Σ_± f̃_j(±ω_m, −wi) E_±\[j\]/A_j, with E_± what j
    /// received in this iteration's sweep. The start term is what the
    /// bundles carry besides reflected light: j's emission (the paper's
    /// form), or with the first shot a fresh light sample from a uniform
    /// point of j ([`transfer::direct`]) and no emission, since light
    /// straight from the emitters to x is the pixel's own light sample.
    /// A gather ray that leaves the scene brings the sky in the paper's
    /// form and nothing with the first shot, for the same reason. The
    /// estimate is f(wo, wi) |cos θ_i| / pdf(wi) times that radiance; the
    /// module docs of [`super`] give the argument that nothing is counted
    /// twice.
    #[allow(clippy::too_many_arguments)]
    fn gather(
        &self,
        world: &World,
        patches: &Patches,
        s: &PixelSample,
        pix: usize,
        iter: u64,
        d: Vec3,
        e_plus: &[Rgb],
        e_minus: &[Rgb],
    ) -> Option<(Rgb, u64)> {
        if !self.gather || s.patch == NO_PATCH {
            return None;
        }
        let sp = world.scene.surface_point(s.tri, s.b.x, s.b.y);
        let v = Vertex::new(world, sp, s.wo);
        if !v.bsdf.has_glossy() {
            return None;
        }
        // Sample the BSDF at x; the glossy BSDFs have no delta lobe, and a
        // sample on the wrong side of the geometric surface carries nothing
        let mut rng = Pcg32::keyed(&[self.seed, pix as u64, iter, 0x1E]);
        let uc = rng.next_f32();
        let u = rng.next_2d();
        let Some(bs) = v.bsdf.sample(v.wo_local, uc, u, Mode::Radiance) else {
            return Some((Rgb::ZERO, 0));
        };
        let wi = v.frame.to_world(bs.wi);
        if bs.delta || bs.pdf <= 0.0 || wi.dot(v.ng) * bs.wi.z <= 0.0 {
            return Some((Rgb::ZERO, 0));
        }
        let weight = bs.f * (bs.wi.z.abs() / bs.pdf);

        // Trace to y and read what its patch sends back toward x
        let ray = Ray::new(offset_point(v.sp.p, v.ng, wi), wi);
        let Some(hit) = world.accel.intersect(&ray) else {
            let sky = if self.nee {
                Rgb::ZERO
            } else {
                world.lights.le_env(wi)
            };
            return Some((finite(s.thr * weight * sky), 1));
        };
        let (j, _) = patches.locate(hit.tri, hit.b1, hit.b2);
        let j = j as usize;
        let p = &patches.p[j];
        let w = -wi;
        let (start, shadow) = if self.nee {
            let (l, _, r) = transfer::direct(world, p, w, &mut rng);
            (l, r)
        } else {
            (p.le(w), 0)
        };
        let l = transfer::reflect_onto(start, p, d, e_plus[j], e_minus[j], w);
        Some((finite(s.thr * weight * l), 1 + shadow))
    }

    /// Adds one estimate to `sum` (one entry per pixel), using the
    /// samples of iteration `iter`; returns the rays traced.
    #[allow(clippy::too_many_arguments)]
    pub fn accumulate(
        &self,
        world: &World,
        patches: &Patches,
        mode: ImageMode,
        d: Vec3,
        e_plus: &[Rgb],
        e_minus: &[Rgb],
        iter: u64,
        sum: &mut [DVec3],
    ) -> u64 {
        // Gouraud: L^eye of §5 at the mesh vertices, reflected part only
        // (emission is exact per pixel)
        let vert = (mode == ImageMode::Gouraud)
            .then(|| self.eye_vertices(world, patches, d, e_plus, e_minus));
        let vert = vert.as_deref();
        if self.positions == Positions::Fixed && !self.nee && !self.gather {
            // The paper's form: each pixel only reflects what its stored
            // sample's patch received, and most patches received nothing
            // along ±ω_m. The general path's per-pixel calls (sample,
            // direct light, gather) cost more than that, so here the
            // iteration's block of samples is walked in chunks. The sums
            // are the general path's, operation for operation.
            let n = sum.len();
            let at = (iter as usize % SAMPLES) * n;
            let block = &self.samples[at..][..n];
            if vert.is_none() {
                // Phong: a pixel whose patch received nothing along ±ω_m
                // adds its Quiet value (the general line's l, as the zero
                // reflection leaves it unchanged: l is never −0 after the
                // + 0, and ±0 added keeps it); the others take that line
                let quiet = &self.quiet[at..][..n];
                sum.par_chunks_mut(PIXEL_CHUNK)
                    .zip(quiet.par_chunks(PIXEL_CHUNK))
                    .zip(block.par_chunks(PIXEL_CHUNK))
                    .for_each(|((acc, qs), ss)| {
                        for ((acc, q), s) in acc.iter_mut().zip(qs).zip(ss) {
                            let mut l = q.l;
                            if q.patch != NO_PATCH {
                                let i = q.patch as usize;
                                if e_plus[i] != Rgb::ZERO || e_minus[i] != Rgb::ZERO {
                                    l = s.le + Rgb::ZERO;
                                    l += reflected(patches, None, s, d, e_plus, e_minus);
                                }
                            }
                            if l.is_finite() {
                                *acc += l.as_dvec3();
                            }
                        }
                    });
                return 0;
            }
            sum.par_chunks_mut(PIXEL_CHUNK)
                .zip(block.par_chunks(PIXEL_CHUNK))
                .for_each(|(acc, ss)| {
                    for (acc, s) in acc.iter_mut().zip(ss) {
                        // no direct light in this form: its term is zero
                        let mut l = s.le + Rgb::ZERO;
                        if s.patch != NO_PATCH {
                            l += reflected(patches, vert, s, d, e_plus, e_minus);
                        }
                        if l.is_finite() {
                            *acc += l.as_dvec3();
                        }
                    }
                });
            return 0;
        }
        sum.par_iter_mut()
            .enumerate()
            .map(|(pix, acc)| {
                let mut fresh = None;
                let (s, rays) = self.sample(world, patches, pix, iter, &mut fresh);
                let (ld, shadow) = self.direct(world, s, pix, iter);
                let mut l = s.le + ld;
                let mut traced = rays + shadow;
                let gather = self.gather(world, patches, s, pix, iter, d, e_plus, e_minus);
                if let Some((lg, g_rays)) = gather {
                    l += lg;
                    traced += g_rays;
                } else if s.patch != NO_PATCH {
                    l += reflected(patches, vert, s, d, e_plus, e_minus);
                }
                if l.is_finite() {
                    *acc += l.as_dvec3();
                }
                traced
            })
            .sum()
    }

    /// L^eye\[i\] of §5 (the radiance each patch reflects toward the eye of
    /// the pair ±d, without emission), area-averaged at each mesh vertex.
    fn eye_vertices(
        &self,
        world: &World,
        patches: &Patches,
        d: Vec3,
        e_plus: &[Rgb],
        e_minus: &[Rgb],
    ) -> Vec<Rgb> {
        let eye = world.camera.position();
        let leye: Vec<Rgb> = patches
            .p
            .par_iter()
            .enumerate()
            .map(|(i, p)| {
                let w = (eye - p.centroid()).normalize_or(p.ng);
                (transfer::reflect(p, d, e_plus[i], e_minus[i], w) - p.le(w)) * p.area
            })
            .collect();
        (0..patches.vertex_count)
            .into_par_iter()
            .map(|v| {
                let (a, b) = (self.vstart[v] as usize, self.vstart[v + 1] as usize);
                let (mut s, mut wsum) = (Rgb::ZERO, 0.0f32);
                for &p in &self.vpatch[a..b] {
                    s += leye[p as usize];
                    wsum += patches.p[p as usize].area;
                }
                if wsum > 0.0 {
                    s / wsum
                } else {
                    Rgb::ZERO
                }
            })
            .collect()
    }
}

/// Pixels per task of the image estimate's fast path.
const PIXEL_CHUNK: usize = 4096;

/// What sample `s` (on a patch) adds to its pixel from the sweep along
/// ±d: the patch's reflection of the pair (Phong), or the eye radiance
/// `vert` interpolated from its vertices (Gouraud); times the sample's
/// delta-chain throughput.
#[inline(always)]
fn reflected(
    patches: &Patches,
    vert: Option<&[Rgb]>,
    s: &PixelSample,
    d: Vec3,
    e_plus: &[Rgb],
    e_minus: &[Rgb],
) -> Rgb {
    let i = s.patch as usize;
    match vert {
        // Phong: the patch's reflection of the pair ±d
        None => {
            let p = &patches.p[i];
            let k = 2.0 * std::f32::consts::PI / p.area;
            let mut r = Rgb::ZERO;
            if e_plus[i] != Rgb::ZERO {
                r += transfer::brdf(p, s.ns, d, s.wo) * e_plus[i];
            }
            if e_minus[i] != Rgb::ZERO {
                r += transfer::brdf(p, s.ns, -d, s.wo) * e_minus[i];
            }
            s.thr * r * k
        }
        Some(vert) => {
            let vid = patches.vid[i];
            let r = vert[vid[0] as usize] * s.w.x
                + vert[vid[1] as usize] * s.w.y
                + vert[vid[2] as usize] * s.w.z;
            s.thr * r
        }
    }
}

/// `l`, or black when it is not finite.
#[inline]
fn finite(l: Rgb) -> Rgb {
    if l.is_finite() {
        l
    } else {
        Rgb::ZERO
    }
}

/// Follows a camera ray through delta surfaces to the first non-delta one.
fn trace(world: &World, patches: &Patches, mut ray: Ray, rng: &mut Pcg32) -> (PixelSample, u64) {
    let mut out = NO_SAMPLE;
    let mut rays = 0;
    for _ in 0..=MAX_DELTA {
        rays += 1;
        let Some(hit) = world.accel.intersect(&ray) else {
            out.le += out.thr * world.lights.le_env(ray.d);
            break;
        };
        let sp = world.scene.surface_point(hit.tri, hit.b1, hit.b2);
        let wo_world = -ray.d;
        out.le += out.thr * world.lights.le_tri(hit.tri, sp.ng, wo_world);
        let material = world.scene.material_of(&sp);
        let bsdf = material.bsdf(sp.uv);
        if !bsdf.is_delta() {
            let (patch, w) = patches.locate(hit.tri, hit.b1, hit.b2);
            out.patch = patch;
            out.w = w;
            out.wo = wo_world;
            out.ns = sp.frame.n;
            out.tri = hit.tri;
            out.b = Vec2::new(hit.b1, hit.b2);
            break;
        }
        let (frame, ng) = orient(sp.frame, sp.ng, wo_world, material.is_two_sided());
        let wo = frame.to_local(wo_world);
        let uc = rng.next_f32();
        let u = rng.next_2d();
        let Some(s) = bsdf.sample(wo, uc, u, Mode::Radiance) else {
            break;
        };
        if s.pdf <= 0.0 {
            break;
        }
        out.thr *= s.f * (s.wi.z.abs() / s.pdf);
        let wi = frame.to_world(s.wi);
        ray = Ray::new(offset_point(sp.p, ng, wi), wi);
    }
    (out, rays)
}
