//! A final gather from the texels: each texel's irradiance re-estimated
//! from its point, its direct light by light sampling and its indirect
//! light by rays that read the density atlas where they land.
//!
//! Density estimation (§3.2 of the density-estimation paper,
//! [`super::estimate`]) blurs the lighting by the kernel's width and is
//! noisiest where the light changes fastest: the direct light's shadows
//! and the falloff near a lamp. A final gather (Jensen's photon-map final
//! gather, with the texels in the photon map's place) keeps the density
//! estimate only one bounce away, where it is smooth:
//!
//! Ĥ(p) = Ĥ_direct(p) + Ĥ_indirect(p), on the side of the surface the
//! texel holds ([`super::estimate::Estimator::side_of`]), with the coat's
//! transmittance T of the texel's material as in
//! [`crate::bsdf::DiffusePart`] (T = 1 without a coat):
//! - **direct**: `lights` samples of the emitters from p
//!   ([`crate::emitter::Lights::sample_li_from`]), each w T(cos θ) cos θ
//!   L_e / pdf when its shadow ray is clear, and the emission the
//!   indirect rays meet first, each w' π T(cos θ) L_e: multiple importance
//!   sampling, w and w' the power heuristic over the two techniques'
//!   sample counts times their pdfs (solid angle: the light sampling's,
//!   and cos θ / π). Light samples alone have no useful bound where p is
//!   near an emitter: their pdf falls as d², and on the acceptance
//!   interior a wall 1 cm from the sky panel took single samples of
//!   2.9·10⁶ (pdf 4·10⁻⁵), texels of 10⁵ times the median; there the
//!   cosine rays, which meet the emitter with most of their pdf, take
//!   over;
//! - **indirect**: `rays` cosine-weighted directions ω, each
//!   π T(cos θ) L(ω), where L is the radiance leaving the point the ray
//!   meets toward p, emission excluded (weighted into the direct part):
//!   - on a surface with a diffuse part, k T'(cos θ') Ĥ_atlas(q), Ĥ_atlas
//!     read bilinearly from the density atlas at q's lightmap coordinate,
//!     or, when the ray meets the side of the surface the atlas does not
//!     hold, from the atlas of the other sides ([`DensityAtlas::other`],
//!     estimated alike for surfaces lit on both sides; 0 on a side with
//!     no hits);
//!   - on one without (a mirror, glass, metal), the path tracer's radiance
//!     from there on ([`crate::transport::CameraPath`]), with the emission
//!     it meets first weighted out.
//!
//! What it leaves out: the glossy or specular lobe of a surface that also
//! has a diffuse part (a plastic's coat) is not followed at the point a
//! gather ray meets: that surface returns its diffuse part alone.
//!
//! The standard error is the sample variance of each part over its sample
//! count, plus the atlas's own error carried through the indirect part as
//! if the texels the rays read were independent.
//!
//! The atlas written is the gather combined with the density estimate,
//! texel by texel, by inverse variance, the variances taken from each
//! texel's neighbours ([`combine_with_density`]): where the gather's rays
//! find the light through a gap (its speckle) the density estimate takes
//! over, where the light arrives directly the gather keeps its shadows
//! sharp.

use std::f32::consts::PI;
use std::sync::atomic::{AtomicBool, Ordering};

use glam::{Vec2, Vec3};
use rayon::prelude::*;

use super::estimate::Estimator;
use super::raster::{self, Corners};
use super::{DensityAtlas, Lightmap, LightmapUv, Texel};
use crate::accel::Hit;
use crate::color::{luminance, Rgb};
use crate::emitter::LightSelection;
use crate::geometry::{offset_point, Frame, Ray};
use crate::sampling::{cosine_hemisphere, power_heuristic, Pcg32};
use crate::scene::SurfacePoint;
use crate::transport::{shadow_clear, CameraPath, DepthLimits, Shading};
use crate::world::World;

/// Settings of the final gather. `Default` is no gather (the atlas is
/// the density estimate, the paper's method, as the estimator's own tests
/// use it); `kalos bake --lightmap` and Python's `kalos.bake` gather with
/// [`GatherOptions::RECOMMENDED`], which measured better than the density
/// estimate alone on the Cornell box and the gap-lit interior at equal
/// time (docs/lightmaps.md).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct GatherOptions {
    /// Indirect rays per texel (0 with `lights` 0: no gather; the atlas is
    /// the density estimate itself).
    pub rays: u32,
    /// Light samples per texel.
    pub lights: u32,
    /// The seed of the rays.
    pub seed: u64,
}

/// The gather measured best at equal time on the Cornell box (rays and
/// light samples per texel), which `--gather` without a count takes.
pub const DEFAULT_RAYS: u32 = 64;
/// Light samples per texel of [`GatherOptions::RECOMMENDED`].
pub const DEFAULT_LIGHTS: u32 = 64;

impl GatherOptions {
    /// The gather of [`DEFAULT_RAYS`] rays and [`DEFAULT_LIGHTS`] light
    /// samples per texel.
    pub const RECOMMENDED: GatherOptions = GatherOptions {
        rays: DEFAULT_RAYS,
        lights: DEFAULT_LIGHTS,
        seed: 0,
    };

    /// No gather: the atlas is the density estimate, as the paper's method
    /// gives it.
    pub const OFF: GatherOptions = GatherOptions {
        rays: 0,
        lights: 0,
        seed: 0,
    };

    /// Whether a gather is to be made.
    pub fn is_on(&self) -> bool {
        self.rays > 0 || self.lights > 0
    }

    /// Rays a texel's gather traces, about (each indirect ray and each
    /// light sample's shadow ray).
    pub fn rays_per_texel(&self) -> u64 {
        self.rays as u64 + self.lights as u64
    }
}

/// The density atlas a gather reads, and where each scene triangle lies on
/// it.
pub struct Atlas<'a> {
    lm: &'a Lightmap,
    /// The other sides of surfaces lit on both ([`DensityAtlas::other`]).
    other: Option<&'a Lightmap>,
    /// Per scene triangle, its corners on the atlas in texels (texel
    /// (x, y)'s centre is at (x + ½, y + ½)); None without area.
    corners: Vec<Corners>,
}

impl<'a> Atlas<'a> {
    /// The atlases `density`, laid out on `uv`, of `scene`'s triangles.
    pub fn new(density: &'a DensityAtlas, uv: &LightmapUv, scene: &crate::scene::Scene) -> Self {
        Atlas {
            lm: &density.held,
            other: density.other.as_ref(),
            corners: raster::uv_corners(scene, uv),
        }
    }

    /// Irradiance and standard error at barycentrics (b1, b2) of triangle
    /// `tri`, bilinearly between the four nearest texels (the padding
    /// filled the gutters, so a point by a chart's border reads its own
    /// chart's values).
    fn read(&self, tri: u32, b1: f32, b2: f32) -> (Rgb, Rgb) {
        Self::read_in(self.lm, &self.corners, tri, b1, b2)
    }

    /// [`Atlas::read`] of the other side of a surface lit on both (0 where
    /// the other side took no hit).
    fn read_other(&self, tri: u32, b1: f32, b2: f32) -> (Rgb, Rgb) {
        match self.other {
            Some(lm) => Self::read_in(lm, &self.corners, tri, b1, b2),
            None => (Rgb::ZERO, Rgb::ZERO),
        }
    }

    fn read_in(lm: &Lightmap, corners: &[Corners], tri: u32, b1: f32, b2: f32) -> (Rgb, Rgb) {
        let Some(Some(c)) = corners.get(tri as usize) else {
            return (Rgb::ZERO, Rgb::ZERO);
        };
        let q = c[0] * (1.0 - b1 - b2) + c[1] * b1 + c[2] * b2 - Vec2::splat(0.5);
        let (w, h) = (lm.width as i64, lm.height as i64);
        let (x0, y0) = (q.x.floor(), q.y.floor());
        let (fx, fy) = (q.x - x0, q.y - y0);
        let (mut e, mut se) = (Rgb::ZERO, Rgb::ZERO);
        for (dx, dy, wt) in [
            (0, 0, (1.0 - fx) * (1.0 - fy)),
            (1, 0, fx * (1.0 - fy)),
            (0, 1, (1.0 - fx) * fy),
            (1, 1, fx * fy),
        ] {
            let x = (x0 as i64 + dx).clamp(0, w - 1) as usize;
            let y = (y0 as i64 + dy).clamp(0, h - 1) as usize;
            let k = y * w as usize + x;
            e += lm.irradiance[k] * wt;
            se += lm.std_error[k] * wt;
        }
        (e, se)
    }
}

/// Jittered strata of the unit square for `n` samples: the first s² of
/// them one per cell of an s × s grid (s = ⌊√n⌋), the rest anywhere. A
/// gather's integrands (the light over the hemisphere, the light's area)
/// are smooth but for edges, where stratified samples' error falls faster
/// than independent ones'.
struct Strata {
    s: u32,
}

impl Strata {
    fn new(n: u32) -> Self {
        Strata {
            s: (n as f64).sqrt().floor() as u32,
        }
    }

    /// Sample `i`'s point, `u` the jitter in its cell.
    fn point(&self, i: u32, u: Vec2) -> Vec2 {
        let s = self.s;
        if i >= s * s {
            return u;
        }
        let cell = Vec2::new((i % s) as f32, (i / s) as f32);
        ((cell + u) / s as f32).min(Vec2::splat(1.0 - f32::EPSILON / 2.0))
    }
}

/// The share of a texel's indirect rays that may meet the back of a
/// one-sided face before the texel is taken for hidden (Unity's
/// "backface tolerance" is the same test).
pub const BACKFACE_SHARE: f32 = 0.25;

/// Sums of one part's stratified samples, for their mean and the variance
/// of that mean.
///
/// The variance is the collapsed-strata estimate (Cochran 1977, §5A.12):
/// strata 2j and 2j + 1 of [`Strata`], neighbours on the grid, are taken
/// as one stratum of two samples, so Var ≈ Σ_pairs (x_a − x_b)² / N², plus
/// the independent samples past the grid at the plain sample variance.
/// It errs high when the integrand changes between neighbouring strata,
/// far less than the independent-sample formula, which ignores the
/// strata altogether.
#[derive(Default)]
struct Moments {
    sum: Vec3,
    sum2: Vec3,
    pairs: Vec3,
    paired: u32,
    prev: Vec3,
}

impl Moments {
    /// Adds sample `i` (of strata `strata`).
    fn add(&mut self, i: u32, strata: &Strata, x: Rgb) {
        self.sum += x;
        self.sum2 += x * x;
        let grid = strata.s * strata.s / 2 * 2;
        if i < grid {
            if i % 2 == 1 {
                let d = x - self.prev;
                self.pairs += d * d;
                self.paired += 2;
            }
            self.prev = x;
        }
    }

    /// The mean of `n` samples and the variance of that mean.
    fn mean_var(&self, n: u32) -> (Vec3, Vec3) {
        if n == 0 {
            return (Vec3::ZERO, Vec3::ZERO);
        }
        let nf = n as f32;
        let mean = self.sum / nf;
        let s2 = if n > 1 {
            ((self.sum2 - self.sum * mean) / (nf - 1.0)).max(Vec3::ZERO)
        } else {
            Vec3::ZERO
        };
        let rest = (n - self.paired) as f32;
        (mean, (self.pairs + s2 * rest) / (nf * nf))
    }
}

/// The final gather of every texel.
pub struct Gather<'a> {
    world: &'a World,
    est: &'a Estimator<'a>,
    atlas: Atlas<'a>,
    opts: GatherOptions,
    limits: DepthLimits,
}

impl<'a> Gather<'a> {
    /// A gather reading `atlas` (the density estimate, padded), with
    /// `est` for the points the atlas does not hold; paths through
    /// surfaces without a diffuse part go at most `max_depth` segments.
    pub fn new(
        world: &'a World,
        est: &'a Estimator<'a>,
        atlas: Atlas<'a>,
        opts: GatherOptions,
        max_depth: Option<u32>,
    ) -> Self {
        Gather {
            world,
            est,
            atlas,
            opts,
            limits: DepthLimits {
                max_depth,
                rr_depth: 5,
                light_selection: LightSelection::Power,
            },
        }
    }

    /// The irradiance at texel `t` (`index` keys its random numbers).
    fn texel(&self, t: &Texel, index: u64) -> TexelGather {
        let world = self.world;
        let scene = &world.scene;
        let back = self.est.side_of(t.tri).unwrap_or(false);
        let n = if back { -t.n } else { t.n };
        // The texel's own material: its coat's transmittance T
        let Some(Some(corners)) = self.atlas.corners.get(t.tri as usize) else {
            return TexelGather::default();
        };
        let l = raster::texel_barycentrics(corners, t.x, t.y);
        let sp = scene.surface_point(t.tri, l.y, l.z);
        let Some(dp) = scene.material_of(&sp).bsdf(sp.uv).diffuse_part() else {
            return TexelGather::default();
        };
        let mut rng = Pcg32::keyed(&[self.opts.seed, index, 0x6761_7468_6572]);
        let mut rays = 0u64;

        // Direct: light samples, shadow rays, each weighted against the
        // indirect rays' chance of meeting the same light (the power
        // heuristic over the two techniques' sample counts)
        let (n_lights, n_rays) = (self.opts.lights as f32, self.opts.rays as f32);
        let mut direct = Moments::default();
        let strata = Strata::new(self.opts.lights);
        for i in 0..self.opts.lights {
            let (u_sel, u) = (rng.next_f32(), strata.point(i, rng.next_2d()));
            let mut x = Rgb::ZERO;
            if let Some(ls) = world
                .lights
                .sample_li_from(LightSelection::Power, t.p, n, u_sel, u)
            {
                let cos = ls.wi.dot(n);
                if cos > 0.0 && ls.pdf > 0.0 && ls.pdf.is_finite() {
                    rays += 1;
                    if shadow_clear(world, t.p, n, &ls) {
                        let w = if ls.delta {
                            1.0
                        } else {
                            power_heuristic(n_lights * ls.pdf, n_rays * cos / PI)
                        };
                        x = ls.le * (w * dp.t(cos) * cos / ls.pdf);
                    }
                }
            }
            direct.add(i, &strata, if x.is_finite() { x } else { Rgb::ZERO });
        }

        // Indirect: cosine-weighted rays reading the atlas where they land
        let frame = Frame::from_normal(n);
        let origin = offset_point(t.p, n, n);
        let mut indirect = Moments::default();
        let mut atlas_var = Vec3::ZERO;
        let mut backs = 0u32;
        let strata = Strata::new(self.opts.rays);
        for i in 0..self.opts.rays {
            let local = cosine_hemisphere(strata.point(i, rng.next_2d()));
            let wi = frame.to_world(local);
            let ray = Ray::new(origin, wi);
            rays += 1;
            // The emission the ray meets first, weighted against the light
            // samples' chance of choosing the same point
            let lights = &world.lights;
            let p_ray = n_rays * local.z / PI;
            let (l, l_se, le) = match world.accel.intersect(&ray) {
                Some(hit) => {
                    let sp = world.surface_point(&hit);
                    if ray.d.dot(sp.ng) > 0.0 && !scene.material_of(&sp).is_two_sided() {
                        backs += 1;
                    }
                    let mut le = Rgb::ZERO;
                    if lights.is_emitter_of(sp.tri, sp.shape) {
                        le = lights.le_tri(sp.tri, sp.frame.n, -ray.d);
                        if le != Rgb::ZERO {
                            let p_light = lights.pdf_li_tri_from(
                                LightSelection::Power,
                                t.p,
                                n,
                                sp.p,
                                sp.ng,
                                sp.tri,
                            );
                            le *= power_heuristic(p_ray, n_lights * p_light);
                        }
                    }
                    let (l, l_se) = self.leaving(&ray, &hit, &sp, &mut rng, &mut rays);
                    (l, l_se, le)
                }
                None => {
                    let le = lights.le_env(ray.d);
                    let p_light = lights.pdf_li_env(ray.d);
                    (
                        Rgb::ZERO,
                        Rgb::ZERO,
                        le * power_heuristic(p_ray, n_lights * p_light),
                    )
                }
            };
            let w = PI * dp.t(local.z);
            let x = (l + le) * w;
            indirect.add(i, &strata, if x.is_finite() { x } else { Rgb::ZERO });
            let s = l_se * w;
            atlas_var += s * s;
        }

        // A point that sees the back of one-sided faces is outside the
        // scene's closed spaces: a floor texel past a slanted wall that the
        // floor runs under, or under a box. Its value is not that of the
        // visible surface it borders; the padding fills it instead.
        if backs as f32 > BACKFACE_SHARE * self.opts.rays as f32 {
            return TexelGather {
                rays,
                hidden: true,
                ..Default::default()
            };
        }
        let (md, vd) = direct.mean_var(self.opts.lights);
        let (mi, vi) = indirect.mean_var(self.opts.rays);
        let g = self.opts.rays.max(1) as f32;
        let var = vd + vi + atlas_var / (g * g);
        TexelGather {
            e: md + mi,
            se: Vec3::new(var.x.sqrt(), var.y.sqrt(), var.z.sqrt()),
            rays,
            hidden: false,
        }
    }

    /// The radiance leaving the point `ray` meets at `hit` back along the
    /// ray, emission excluded, and its standard error (the atlas's part).
    fn leaving(
        &self,
        ray: &Ray,
        hit: &Hit,
        sp: &SurfacePoint,
        rng: &mut Pcg32,
        rays: &mut u64,
    ) -> (Rgb, Rgb) {
        let world = self.world;
        let wo = -ray.d;
        let v = Shading::at(world, sp, wo);
        let Some(dp) = v.bsdf.diffuse_part() else {
            // No diffuse part: the path tracer from here on, the emission
            // met first weighted out (the light samples counted it)
            let mut path = CameraPath::after_light_sampling(*ray, 1);
            let mut alive = path.scatter(world, &self.limits, sp, rng);
            while alive {
                path.rays += 1;
                alive = match world.accel.intersect(&path.ray) {
                    Some(h) => path.scatter(world, &self.limits, &world.surface_point(&h), rng),
                    None => path.escape(world),
                };
            }
            *rays += path.rays;
            return (path.l, Rgb::ZERO);
        };
        let cos_o = v.wo_local.z;
        if cos_o <= 0.0 {
            return (Rgb::ZERO, Rgb::ZERO);
        }
        // The side the ray sees, against the side the atlas holds there
        let seen_back = wo.dot(sp.ng) < 0.0;
        let held_back = self.est.side_of(sp.tri).unwrap_or(false);
        let (e, se) = if seen_back == held_back {
            self.atlas.read(hit.tri, hit.b1, hit.b2)
        } else {
            self.atlas.read_other(hit.tri, hit.b1, hit.b2)
        };
        let k = dp.k * dp.t(cos_o);
        (k * e, k * se)
    }
}

/// One texel's gather: irradiance, its standard error, rays traced, and
/// whether its rays found it hidden.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct TexelGather {
    /// Irradiance.
    pub e: Rgb,
    /// Its standard error.
    pub se: Rgb,
    /// Rays traced.
    pub rays: u64,
    /// More than [`BACKFACE_SHARE`] of the rays met a back face.
    pub hidden: bool,
}

/// Gathers the texels `which` (indices into `texels`, which also key their
/// random numbers) that `density` covers, in parallel, in `which`'s order
/// (None: not covered, left as the density estimate has it). Stops early
/// once `cancel` is set, with the gathers as far as they got; `progress`
/// hears the texels done.
pub fn gather_some(
    gather: &Gather,
    texels: &[Texel],
    which: &[u32],
    density: &Lightmap,
    cancel: Option<&AtomicBool>,
    progress: &mut dyn FnMut(u64, u64),
) -> Vec<Option<TexelGather>> {
    let (w, h) = (density.width, density.height);
    const SLICE: usize = 1 << 12;
    let total = which.len() as u64;
    let mut out = Vec::with_capacity(which.len());
    progress(0, total);
    for slice in which.chunks(SLICE) {
        if cancel.is_some_and(|c| c.load(Ordering::Relaxed)) {
            break;
        }
        out.par_extend(slice.par_iter().map(|&i| {
            let t = &texels[i as usize];
            let k = t.y as usize * w as usize + t.x as usize;
            (t.x < w && t.y < h && density.covered[k]).then(|| gather.texel(t, i as u64))
        }));
        progress(out.len() as u64, total);
    }
    out
}

/// Writes gathers into `lm` (a copy of the density atlas): texel
/// `which[i]` of `texels` takes `gathered[i]`. Returns the rays traced
/// and the texels found hidden (left uncovered, for the padding to fill).
pub fn put_gathered(
    lm: &mut Lightmap,
    texels: &[Texel],
    which: &[u32],
    gathered: &[Option<TexelGather>],
) -> (u64, u64) {
    let (mut rays, mut hidden) = (0, 0);
    for (&i, g) in which.iter().zip(gathered) {
        let (Some(g), Some(t)) = (g, texels.get(i as usize)) else {
            continue;
        };
        if t.x >= lm.width || t.y >= lm.height {
            continue;
        }
        let k = t.y as usize * lm.width as usize + t.x as usize;
        lm.irradiance[k] = g.e;
        lm.std_error[k] = g.se;
        lm.covered[k] = !g.hidden;
        hidden += g.hidden as u64;
        rays += g.rays;
    }
    (rays, hidden)
}

/// Gathers every covered texel of `density` (the atlas `gather` reads)
/// into a new atlas, in parallel (the same bytes whatever the thread
/// count). Texels the density estimate left uncovered (padding, hidden)
/// stay so. Stops early once `cancel` is set, with the density values in
/// the texels not reached; `progress` hears the texels done. Returns the
/// atlas, the rays traced, and how many texels were found hidden (their
/// rays met back faces: left uncovered, for the padding to fill).
pub fn gather_texels(
    gather: &Gather,
    texels: &[Texel],
    density: &Lightmap,
    cancel: Option<&AtomicBool>,
    progress: &mut dyn FnMut(u64, u64),
) -> (Lightmap, u64, u64) {
    let all: Vec<u32> = (0..texels.len() as u32).collect();
    let got = gather_some(gather, texels, &all, density, cancel, progress);
    let mut lm = density.clone();
    let (rays, hidden) = put_gathered(&mut lm, texels, &all[..got.len()], &got);
    (lm, rays, hidden)
}

/// The half-width of the neighbourhood whose variances weigh a texel's
/// two estimates in [`combine_with_density`] (5 × 5 texels).
const BLEND_REACH: i64 = 2;

/// Combines each gathered texel with the density estimate at the same
/// texel, weighted by inverse variance: E = w E_gather + (1 − w) E_density,
/// w = V_density / (V_gather + V_density), its standard error
/// √(w² se_gather² + (1 − w)² se_density²).
///
/// The variances V are the means of the squared standard errors
/// (luminance) of the texel's neighbours in a 5 × 5 square of the same
/// chart, the texel itself left out, so that a texel's weight does not
/// depend on its own samples: weights from a texel's own variance would
/// lean away from exactly its bright outliers (a texel whose one ray
/// passed a gap has a large sample variance), a bias toward dark. Where
/// the gather's rays find the light through a gap its neighbours'
/// variances are large and the density estimate takes over; where light
/// arrives directly the gather's are small and it keeps the sharpness of
/// its shadows. One weight for the three channels, so that no colour
/// shifts.
///
/// Two things it leaves out: the density estimate's error bars do not
/// hold its kernel's bias (the blur of a shadow's edge), so there it
/// weighs more than its error warrants; and the two estimates are
/// correlated (the gather reads the density atlas one bounce away), which
/// the combined error bar ignores. Measured in docs/notebook/
/// lightmap-estimator.md: on the Cornell box against Cycles the combined
/// atlas is closer than the gather alone (3.94 % against 4.07 %), on the
/// gap-lit interior its two seeds agree better than either estimate's.
///
/// `chart[k]` is texel k's chart (`u32::MAX`: none); texels not covered in
/// both atlases keep the gathered value.
pub fn combine_with_density(gathered: &mut Lightmap, density: &Lightmap, chart: &[u32]) {
    let (w, h) = (gathered.width as i64, gathered.height as i64);
    let var = |se: Rgb| {
        let l = luminance(se) as f64;
        l * l
    };
    let both = |k: usize| gathered.covered[k] && density.covered[k] && chart[k] != u32::MAX;
    let weights: Vec<Option<f32>> = (0..w * h)
        .into_par_iter()
        .map(|i| {
            let (x, y, k) = (i % w, i / w, i as usize);
            if !both(k) {
                return None;
            }
            let (mut vg, mut vd) = (0.0f64, 0.0f64);
            for yy in (y - BLEND_REACH).max(0)..=(y + BLEND_REACH).min(h - 1) {
                for xx in (x - BLEND_REACH).max(0)..=(x + BLEND_REACH).min(w - 1) {
                    let j = (yy * w + xx) as usize;
                    if j != k && both(j) && chart[j] == chart[k] {
                        vg += var(gathered.std_error[j]);
                        vd += var(density.std_error[j]);
                    }
                }
            }
            (vg + vd > 0.0).then(|| (vd / (vg + vd)) as f32)
        })
        .collect();
    for (k, wg) in weights.into_iter().enumerate() {
        let Some(wg) = wg else { continue };
        let wd = 1.0 - wg;
        gathered.irradiance[k] = gathered.irradiance[k] * wg + density.irradiance[k] * wd;
        let (a, b) = (gathered.std_error[k] * wg, density.std_error[k] * wd);
        let v = a * a + b * b;
        gathered.std_error[k] = Vec3::new(v.x.sqrt(), v.y.sqrt(), v.z.sqrt());
    }
}

/// Per texel of `uv`'s atlas, the chart its texel of `texels` lies on
/// (`u32::MAX` where none does), for [`combine_with_density`].
pub fn texel_charts(texels: &[Texel], uv: &LightmapUv) -> Vec<u32> {
    let (w, h) = (uv.width as usize, uv.height as usize);
    let mut chart = vec![u32::MAX; w * h];
    for t in texels {
        if (t.x as usize) < w && (t.y as usize) < h {
            chart[t.y as usize * w + t.x as usize] = uv
                .tri_chart
                .get(t.tri as usize)
                .copied()
                .unwrap_or(u32::MAX);
        }
    }
    chart
}

#[cfg(test)]
mod tests {
    use super::*;

    fn flat(e: f32, se: f32) -> Lightmap {
        Lightmap {
            width: 5,
            height: 5,
            irradiance: vec![Rgb::splat(e); 25],
            std_error: vec![Rgb::splat(se); 25],
            covered: vec![true; 25],
        }
    }

    #[test]
    fn the_density_estimate_weighs_by_the_neighbours_variances() {
        // gather: E 10, se 2; density: E 5, se 1; so w = 1 / (4 + 1)
        let density = flat(5.0, 1.0);
        let mut chart = vec![0u32; 25];
        let mut g = flat(10.0, 2.0);
        combine_with_density(&mut g, &density, &chart);
        let c = 12;
        assert!(
            (g.irradiance[c].x - 6.0).abs() < 1e-5,
            "{}",
            g.irradiance[c].x
        );
        let se = ((0.2f32 * 2.0).powi(2) + (0.8f32 * 1.0).powi(2)).sqrt();
        assert!((g.std_error[c].x - se).abs() < 1e-5);
        // The texel's own error bar does not move its weight; a neighbour
        // on another chart does not either
        let mut g = flat(10.0, 2.0);
        g.std_error[c] = Rgb::splat(100.0);
        g.std_error[13] = Rgb::splat(100.0);
        chart[13] = 1;
        combine_with_density(&mut g, &density, &chart);
        assert!(
            (g.irradiance[c].x - 6.0).abs() < 1e-5,
            "{}",
            g.irradiance[c].x
        );
        // A texel the density estimate does not cover keeps the gather's
        let mut d = density.clone();
        d.covered[c] = false;
        let mut g = flat(10.0, 2.0);
        combine_with_density(&mut g, &d, &[0; 25]);
        assert_eq!(g.irradiance[c].x, 10.0);
    }

    #[test]
    fn moments_give_the_variance_of_the_mean() {
        // Unstratified (one sample): the plain sample variance over n
        let none = Strata::new(3);
        assert_eq!(none.s, 1);
        let mut m = Moments::default();
        for (i, x) in [1.0f32, 2.0, 3.0].into_iter().enumerate() {
            m.add(i as u32, &none, Vec3::splat(x));
        }
        let (mean, var) = m.mean_var(3);
        assert!((mean.x - 2.0).abs() < 1e-6);
        assert!((var.x - 1.0 / 3.0).abs() < 1e-6, "{}", var.x);
        // Four strata: the pairs (1, 2) and (3, 5), (1 + 4) / 16
        let four = Strata::new(4);
        let mut m = Moments::default();
        for (i, x) in [1.0f32, 2.0, 3.0, 5.0].into_iter().enumerate() {
            m.add(i as u32, &four, Vec3::splat(x));
        }
        let (mean, var) = m.mean_var(4);
        assert!((mean.x - 2.75).abs() < 1e-6);
        assert!((var.x - 5.0 / 16.0).abs() < 1e-6, "{}", var.x);
    }

    #[test]
    fn collapsed_strata_track_the_spread_of_stratified_means() {
        // A smooth integrand over the square, 64 jittered samples: the
        // estimated variance of the mean must match the spread of the
        // means over many runs within a factor that the collapsed-strata
        // estimate allows (it errs high), and be far below the
        // independent-sample formula's.
        let f = |u: Vec2| 1.0 + u.x * u.x + 0.5 * (6.0 * u.y).sin();
        let strata = Strata::new(64);
        let (runs, n) = (2000, 64);
        let (mut means, mut est, mut iid) = (Vec::new(), 0.0f64, 0.0f64);
        for r in 0..runs {
            let mut rng = Pcg32::keyed(&[7, r]);
            let mut m = Moments::default();
            for i in 0..n {
                m.add(i, &strata, Vec3::splat(f(strata.point(i, rng.next_2d()))));
            }
            let (mean, var) = m.mean_var(n);
            means.push(mean.x as f64);
            est += var.x as f64 / runs as f64;
            let s2 = (m.sum2.x - m.sum.x * mean.x) / (n as f32 - 1.0);
            iid += (s2 / n as f32) as f64 / runs as f64;
        }
        let mu = means.iter().sum::<f64>() / runs as f64;
        let actual = means.iter().map(|x| (x - mu).powi(2)).sum::<f64>() / (runs - 1) as f64;
        // the ratio's own sampling error over 2000 runs is about 3 %
        assert!(
            est / actual > 0.9 && est / actual < 4.0,
            "estimated {est:e}, actual {actual:e}"
        );
        assert!(iid / actual > 10.0, "iid {iid:e} actual {actual:e}");
    }
}
