//! BSDFs, evaluated in the local shading frame (normal on +z).
//!
//! # Conventions
//!
//! - `wo` and `wi` are unit vectors pointing away from the surface. With
//!   [`Mode::Radiance`] (camera paths) `wo` points toward the camera side of
//!   the path; with [`Mode::Importance`] (light paths) `wo` points toward the
//!   light side and `wi` is where the particle goes next.
//! - The reflective models (everything but the three dielectrics)
//!   are one-sided, as in Mitsuba: they are zero (and `sample` returns `None`)
//!   when `wo.z <= 0` or `wi.z <= 0`. For `twosided` materials the integrator
//!   flips the frame before calling ([`crate::scene::Material::is_two_sided`]).
//! - Dielectrics work from both sides: `eta` is interior over exterior, and
//!   from inside (`wo.z < 0`) the relative index inverts.
//! - `eval` returns f(wo, wi) **without** the cosine, and zero for delta lobes;
//!   `pdf` is per unit solid angle, and zero for delta lobes.
//! - Delta lobes in [`BsdfSample`]: `delta = true`, `pdf` is the probability of
//!   having chosen that lobe, and `f` is the lobe's weight divided by
//!   |cos θi| (|wi.z|), so that the path throughput update
//!   `f · |cos θi| / pdf` is the same expression for delta and non-delta
//!   samples.
//! - Refraction is adjoint-correct (Veach 1997, §5.2; pbrt's `TransportMode`):
//!   in radiance mode transmitted `f` carries 1/η², η being the relative index
//!   of the side entered by the path over the side it leaves (radiance is
//!   compressed into the denser medium); in importance mode it does not. The
//!   shading-normal correction of importance transport
//!   ([`shading_normal_correction`]) is applied where light paths scatter
//!   and meet the camera ([`crate::transport::scatter`],
//!   [`crate::transport::connect_to_camera`]).
//!
//! The models reproduce Mitsuba 3's plugins of the same names (same
//! parameters, same Fresnel and microfacet terms, same lobe-selection
//! probabilities) so that images agree with Mitsuba references; `phong` is
//! kalos's own.

pub mod coat;
pub mod fresnel;
mod material;
pub mod microfacet;
mod roughdielectric;

use glam::{Vec2, Vec3};
use std::f32::consts::{FRAC_1_PI, PI};

use crate::geometry::{reflect_local, Frame};
use crate::sampling::{cosine_hemisphere, cosine_hemisphere_pdf};
use crate::scene::{luminance, Rgb};

use coat::CoatTable;
use fresnel::{
    fresnel_conductor, fresnel_dielectric, fresnel_diffuse_reflectance, reflect, refract,
    thin_reflectance,
};
use microfacet::Microfacet;
use roughdielectric::{eval_rough_dielectric, pdf_rough_dielectric};

/// Which quantity a path carries: radiance (camera paths) or importance
/// (light paths, the adjoint). The two differ for refraction (the η² factor)
/// and for shading normals (handled by the integrator).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Mode {
    /// Camera paths: `wo` points toward the camera side of the path.
    Radiance,
    /// Light paths: `wo` points toward the light side of the path.
    Importance,
}

/// A sampled direction.
///
/// For a delta lobe (`delta == true`), `pdf` is the discrete probability of
/// the lobe and `f` is its weight over |cos θi|, so that `f·|wi.z|/pdf` is the
/// throughput factor in every case (see the module docs).
#[derive(Clone, Copy, Debug)]
pub struct BsdfSample {
    /// Sampled direction (local frame).
    pub wi: Vec3,
    /// BSDF value f(wo, wi) (no cosine); for a delta lobe, weight / |cos θi|.
    pub f: Rgb,
    /// Solid-angle pdf; for a delta lobe, the probability of choosing that lobe.
    pub pdf: f32,
    /// True when the sampled lobe is a Dirac delta.
    pub delta: bool,
    /// Relative index of refraction crossed: the side entered over the side
    /// left (1 for reflection).
    pub eta: f32,
}

/// A BSDF with its parameters resolved at one surface point.
#[derive(Clone, Copy, Debug)]
pub enum Bsdf {
    /// Lambertian: f = r/π.
    Diffuse {
        /// Albedo.
        r: Rgb,
    },
    /// Energy-conserving modified Phong (Lafortune and Willems 1994):
    /// f = kd/π + ks (n+2)/(2π) cosⁿα, α the angle between wi and the mirror
    /// direction of wo. Reciprocal; albedo ≤ kd + ks.
    Phong {
        /// Diffuse albedo.
        kd: Rgb,
        /// Specular albedo.
        ks: Rgb,
        /// Phong exponent.
        n: f32,
    },
    /// Smooth conductor: a Fresnel mirror (delta).
    Conductor {
        /// Real part of the relative index of refraction.
        eta: Rgb,
        /// Imaginary part (absorption).
        k: Rgb,
        /// Multiplier.
        s: Rgb,
    },
    /// Rough conductor: Torrance–Sparrow microfacet reflection,
    /// f = s F(wo·h) D(h) G(wo, wi, h) / (4 cos θo cos θi).
    RoughConductor {
        /// Normal distribution.
        dist: Microfacet,
        /// Real part of the relative index of refraction.
        eta: Rgb,
        /// Imaginary part.
        k: Rgb,
        /// Multiplier.
        s: Rgb,
    },
    /// Smooth plastic: a Fresnel delta coat over a diffuse base with internal
    /// scattering (Mitsuba's `plastic`).
    Plastic {
        /// Base albedo ρ.
        rho: Rgb,
        /// Multiplier on the specular coat.
        s: Rgb,
        /// Relative index of the coat (interior / exterior).
        eta: f32,
        /// Diffuse Fresnel reflectance of the coat seen from inside, F_dr(1/η).
        fdr_int: f32,
        /// Mitsuba's `nonlinear`: internal scattering tints by ρ.
        nonlinear: bool,
        /// Weight steering lobe selection toward the coat, s̄/(ρ̄ + s̄).
        spec_weight: f32,
    },
    /// Rough plastic: a microfacet coat over a diffuse base (Mitsuba's
    /// `roughplastic`).
    RoughPlastic {
        /// Base albedo ρ.
        rho: Rgb,
        /// Multiplier on the specular coat.
        s: Rgb,
        /// Normal distribution of the coat.
        dist: Microfacet,
        /// Relative index of the coat (interior / exterior).
        eta: f32,
        /// Mitsuba's `nonlinear`.
        nonlinear: bool,
        /// Weight steering lobe selection toward the coat, s̄/(ρ̄ + s̄).
        spec_weight: f32,
        /// Precomputed coat transmittance t(μ) and internal reflectance.
        table: &'static CoatTable,
    },
    /// Smooth glass: Fresnel reflection and refraction (both delta).
    Dielectric {
        /// Relative index (interior / exterior).
        eta: f32,
        /// Multiplier on reflection.
        r: Rgb,
        /// Multiplier on transmission.
        t: Rgb,
    },
    /// Rough glass (Mitsuba's `roughdielectric`): microfacet reflection
    /// f_r = r F D G / (4 |cos θo cos θi|) and refraction (Walter et al.
    /// 2007, eq. 21) f_t = t (1 − F) D G η² |wo·m| |wi·m| / (|cos θo cos θi|
    /// (wo·m + η wi·m)²), η the index entered over the index left, times
    /// 1/η² in radiance mode; m the generalised half vector. A sample draws
    /// m (visible normals for GGX) and reflects with probability F(wo·m),
    /// else refracts. Single scattering: energy between microfacets is lost.
    RoughDielectric {
        /// Normal distribution.
        dist: Microfacet,
        /// Relative index (interior / exterior).
        eta: f32,
        /// Multiplier on reflection.
        r: Rgb,
        /// Multiplier on transmission.
        t: Rgb,
    },
    /// Thin glass pane: reflection with the interreflections of both faces
    /// summed, R' = R + T²R/(1 − R²), and straight-through transmission 1 − R'.
    ThinDielectric {
        /// Relative index of the pane.
        eta: f32,
        /// Multiplier on reflection.
        r: Rgb,
        /// Multiplier on transmission.
        t: Rgb,
    },
}

/// Multiplies a throughput by the ratio that makes shading normals
/// adjoint-correct in importance transport (Veach 1997, eq. 5.17):
/// |wo·ns| |wi·ng| / (|wo·ng| |wi·ns|), world-space vectors. Returns 0 when
/// the denominator vanishes (a grazing direction the path cannot continue).
#[inline]
pub fn shading_normal_correction(wo_world: Vec3, wi_world: Vec3, ng: Vec3, ns: Vec3) -> f32 {
    shading_normal_correction_over(wo_world, wi_world, ng, ns, wi_world.dot(ns).abs())
}

/// [`shading_normal_correction`] with its |wi·ns| replaced by `d`:
/// |wo·ns| |wi·ng| / (|wo·ng| d), and the same guard (0 when the
/// denominator vanishes). This is the one place where the correction is
/// written. A light path multiplies the correction by the cosine |wi·ns| of
/// the adjoint BSDF, which cancels the denominator's: scattering passes
/// d = pdf (the weight f |wi·ns| / pdf, corrected, is f times this), and a
/// camera connection d = 1, so that the cosine is never multiplied in and
/// divided out again.
#[inline(always)]
pub fn shading_normal_correction_over(
    wo_world: Vec3,
    wi_world: Vec3,
    ng: Vec3,
    ns: Vec3,
    d: f32,
) -> f32 {
    let num = wo_world.dot(ns).abs() * wi_world.dot(ng).abs();
    let den = wo_world.dot(ng).abs() * d;
    if den > 0.0 && num.is_finite() {
        num / den
    } else {
        0.0
    }
}

impl Bsdf {
    /// f(wo, wi), without the cosine. Zero for delta lobes.
    #[inline(always)]
    pub fn eval(&self, wo: Vec3, wi: Vec3, mode: Mode) -> Rgb {
        match *self {
            Bsdf::Diffuse { r } => {
                if wo.z <= 0.0 || wi.z <= 0.0 {
                    Rgb::ZERO
                } else {
                    r * FRAC_1_PI
                }
            }
            Bsdf::Phong { kd, ks, n } => {
                if wo.z <= 0.0 || wi.z <= 0.0 {
                    return Rgb::ZERO;
                }
                let c = wi.dot(reflect_local(wo)).max(0.0);
                kd * FRAC_1_PI + ks * ((n + 2.0) * 0.5 * FRAC_1_PI * c.powf(n))
            }
            Bsdf::RoughConductor { dist, eta, k, s } => {
                if wo.z <= 0.0 || wi.z <= 0.0 {
                    return Rgb::ZERO;
                }
                let Some(h) = half_vector(wo, wi) else {
                    return Rgb::ZERO;
                };
                let dg = dist.d(h) * dist.g(wo, wi, h);
                if dg <= 0.0 {
                    return Rgb::ZERO;
                }
                s * fresnel_conductor(wo.dot(h), eta, k) * (dg / (4.0 * wo.z * wi.z))
            }
            Bsdf::Plastic {
                rho,
                eta,
                fdr_int,
                nonlinear,
                ..
            } => {
                if wo.z <= 0.0 || wi.z <= 0.0 {
                    return Rgb::ZERO;
                }
                // Diffuse base seen through the smooth coat (Mitsuba's plastic):
                // in through (1 − F(θo)), out through (1 − F(θi)), radiance
                // expanded by 1/η² on the way out, and the geometric series of
                // internal reflections summed into 1/(1 − ρ F_dr,int)
                let f_o = fresnel_dielectric(wo.z, eta).0;
                let f_i = fresnel_dielectric(wi.z, eta).0;
                internal_scattering(rho, fdr_int, nonlinear)
                    * (FRAC_1_PI / (eta * eta) * (1.0 - f_o) * (1.0 - f_i))
            }
            Bsdf::RoughPlastic {
                rho,
                s,
                dist,
                eta,
                nonlinear,
                table,
                ..
            } => {
                if wo.z <= 0.0 || wi.z <= 0.0 {
                    return Rgb::ZERO;
                }
                // Microfacet coat
                let mut f = Rgb::ZERO;
                if let Some(h) = half_vector(wo, wi) {
                    let dg = dist.d(h) * dist.g(wo, wi, h);
                    if dg > 0.0 {
                        let fr = fresnel_dielectric(wo.dot(h), eta).0;
                        f += s * (fr * dg / (4.0 * wo.z * wi.z));
                    }
                }
                // Diffuse base through the rough coat, same form as plastic
                let t = table.t(wo.z) * table.t(wi.z);
                f + internal_scattering(rho, table.internal_reflectance, nonlinear)
                    * (FRAC_1_PI / (eta * eta) * t)
            }
            Bsdf::RoughDielectric { dist, eta, r, t } => {
                eval_rough_dielectric(dist, eta, r, t, wo, wi, mode)
            }
            Bsdf::Conductor { .. } | Bsdf::Dielectric { .. } | Bsdf::ThinDielectric { .. } => {
                Rgb::ZERO
            }
        }
    }

    /// Samples wi given wo; `uc` picks a lobe, `u` the direction. `None` when
    /// nothing is sampled (wo below a one-sided surface, or a direction that
    /// would leave the hemisphere: that probability mass is lost, and `pdf`
    /// integrates to less than one by the same amount).
    #[inline(always)]
    pub fn sample(&self, wo: Vec3, uc: f32, u: Vec2, mode: Mode) -> Option<BsdfSample> {
        match *self {
            Bsdf::Diffuse { r } => {
                if wo.z <= 0.0 {
                    return None;
                }
                let wi = cosine_hemisphere(u);
                let pdf = cosine_hemisphere_pdf(wi.z);
                if pdf <= 0.0 {
                    return None;
                }
                Some(BsdfSample {
                    wi,
                    f: r * FRAC_1_PI,
                    pdf,
                    delta: false,
                    eta: 1.0,
                })
            }
            Bsdf::Phong { kd, ks, n } => {
                if wo.z <= 0.0 {
                    return None;
                }
                // Choose the lobe by luminance, then warp u onto it
                let wi = if uc < phong_specular_probability(kd, ks) {
                    phong_lobe_sample(wo, n, u)
                } else {
                    cosine_hemisphere(u)
                };
                self.smooth_sample(wo, wi, mode)
            }
            Bsdf::Conductor { eta, k, s } => {
                if wo.z <= 0.0 {
                    return None;
                }
                Some(BsdfSample {
                    wi: reflect_local(wo),
                    f: s * fresnel_conductor(wo.z, eta, k) / wo.z,
                    pdf: 1.0,
                    delta: true,
                    eta: 1.0,
                })
            }
            Bsdf::RoughConductor { dist, .. } => {
                if wo.z <= 0.0 {
                    return None;
                }
                let m = dist.sample_m(wo, u);
                if wo.dot(m) <= 0.0 {
                    return None;
                }
                self.smooth_sample(wo, reflect(wo, m), mode)
            }
            Bsdf::Plastic { s, eta, .. } => {
                if wo.z <= 0.0 {
                    return None;
                }
                let p_spec = self.plastic_specular_probability(wo.z);
                if uc < p_spec {
                    // Delta coat: weight F(θo)·s, chosen with probability p_spec
                    let f_o = fresnel_dielectric(wo.z, eta).0;
                    return Some(BsdfSample {
                        wi: reflect_local(wo),
                        f: s * (f_o / wo.z),
                        pdf: p_spec,
                        delta: true,
                        eta: 1.0,
                    });
                }
                self.smooth_sample(wo, cosine_hemisphere(u), mode)
            }
            Bsdf::RoughPlastic { dist, .. } => {
                if wo.z <= 0.0 {
                    return None;
                }
                let wi = if uc < self.plastic_specular_probability(wo.z) {
                    let m = dist.sample_m(wo, u);
                    if wo.dot(m) <= 0.0 {
                        return None;
                    }
                    reflect(wo, m)
                } else {
                    cosine_hemisphere(u)
                };
                self.smooth_sample(wo, wi, mode)
            }
            Bsdf::Dielectric { eta, r, t } => sample_dielectric(wo, uc, eta, r, t, mode),
            Bsdf::RoughDielectric { dist, eta, .. } => {
                if wo.z == 0.0 {
                    return None;
                }
                // m from the side of wo; F at the microfacet picks the lobe
                let m = dist.sample_m(wo * wo.z.signum(), u);
                let (f, cos_t, eta_it, eta_ti) = fresnel_dielectric(wo.dot(m), eta);
                let reflected = uc < f;
                let wi = if reflected {
                    reflect(wo, m)
                } else {
                    refract(wo, m, cos_t, eta_ti)
                };
                // a reflection below or a refraction above the surface is lost
                if !wi.is_finite() || (wi.z * wo.z > 0.0) != reflected || wi.z == 0.0 {
                    return None;
                }
                self.sample_at(wo, wi, mode, if reflected { 1.0 } else { eta_it })
            }
            Bsdf::ThinDielectric { eta, r, t } => sample_thin_dielectric(wo, uc, eta, r, t),
        }
    }

    /// Solid-angle pdf of sampling wi given wo (zero for delta lobes; for
    /// plastic, the diffuse part only, which already includes the probability
    /// of not choosing the coat).
    #[inline(always)]
    pub fn pdf(&self, wo: Vec3, wi: Vec3) -> f32 {
        match *self {
            Bsdf::Diffuse { .. } => {
                if wo.z <= 0.0 {
                    0.0
                } else {
                    cosine_hemisphere_pdf(wi.z)
                }
            }
            Bsdf::Phong { kd, ks, n } => {
                if wo.z <= 0.0 || wi.z <= 0.0 {
                    return 0.0;
                }
                let ps = phong_specular_probability(kd, ks);
                let c = wi.dot(reflect_local(wo)).max(0.0);
                (1.0 - ps) * wi.z * FRAC_1_PI + ps * (n + 1.0) * 0.5 * FRAC_1_PI * c.powf(n)
            }
            Bsdf::RoughConductor { dist, .. } => {
                if wo.z <= 0.0 || wi.z <= 0.0 {
                    return 0.0;
                }
                match half_vector(wo, wi) {
                    Some(h) => microfacet_reflection_pdf(dist, wo, h),
                    None => 0.0,
                }
            }
            Bsdf::Plastic { .. } => {
                if wo.z <= 0.0 || wi.z <= 0.0 {
                    return 0.0;
                }
                (1.0 - self.plastic_specular_probability(wo.z)) * wi.z * FRAC_1_PI
            }
            Bsdf::RoughPlastic { dist, .. } => {
                if wo.z <= 0.0 || wi.z <= 0.0 {
                    return 0.0;
                }
                let ps = self.plastic_specular_probability(wo.z);
                let spec = match half_vector(wo, wi) {
                    Some(h) => microfacet_reflection_pdf(dist, wo, h),
                    None => 0.0,
                };
                ps * spec + (1.0 - ps) * wi.z * FRAC_1_PI
            }
            Bsdf::RoughDielectric { dist, eta, .. } => pdf_rough_dielectric(dist, eta, wo, wi),
            Bsdf::Conductor { .. } | Bsdf::Dielectric { .. } | Bsdf::ThinDielectric { .. } => 0.0,
        }
    }

    /// Directional albedo estimate ρ(wo) ∈ [0, 1] per channel, for Russian
    /// roulette: exact for `diffuse`, `conductor`, `dielectric`,
    /// `thindielectric` (and `plastic` up to the F_dr fits); for the rough
    /// models the Fresnel factor at the macro-normal without the shadowing
    /// loss (an upper estimate; `roughdielectric` as `dielectric`); for `phong` kd + ks (exact at normal incidence).
    #[inline(always)]
    pub fn albedo(&self, wo: Vec3) -> Rgb {
        let a = match *self {
            Bsdf::Diffuse { r } => r,
            Bsdf::Phong { kd, ks, .. } => kd + ks,
            Bsdf::Conductor { eta, k, s } | Bsdf::RoughConductor { eta, k, s, .. } => {
                s * fresnel_conductor(wo.z, eta, k)
            }
            Bsdf::Plastic {
                rho,
                s,
                eta,
                fdr_int,
                nonlinear,
                ..
            } => {
                // ∫ (1 − F(μ)) 2μ dμ over the exit = 1 − F_dr(η)
                let f_o = fresnel_dielectric(wo.z, eta).0;
                let t_out = (1.0 - fresnel_diffuse_reflectance(eta)) / (eta * eta);
                s * f_o + internal_scattering(rho, fdr_int, nonlinear) * ((1.0 - f_o) * t_out)
            }
            Bsdf::RoughPlastic {
                rho,
                s,
                eta,
                nonlinear,
                table,
                ..
            } => {
                let t_o = table.t(wo.z);
                let t_out = table.external_diffuse_transmittance / (eta * eta);
                s * (1.0 - t_o)
                    + internal_scattering(rho, table.internal_reflectance, nonlinear)
                        * (t_o * t_out)
            }
            Bsdf::Dielectric { eta, r, t } | Bsdf::RoughDielectric { eta, r, t, .. } => {
                let f = fresnel_dielectric(wo.z, eta).0;
                r * f + t * (1.0 - f)
            }
            Bsdf::ThinDielectric { eta, r, t } => {
                let rr = thin_reflectance(wo.z.abs(), eta);
                r * rr + t * (1.0 - rr)
            }
        };
        let one_sided = !self.is_transmissive();
        if one_sided && wo.z <= 0.0 {
            return Rgb::ZERO;
        }
        a.clamp(Rgb::ZERO, Rgb::ONE)
    }

    /// True when every lobe is a Dirac delta (mirror, smooth glass).
    pub fn is_delta(&self) -> bool {
        matches!(
            self,
            Bsdf::Conductor { .. } | Bsdf::Dielectric { .. } | Bsdf::ThinDielectric { .. }
        )
    }

    /// True when some lobe is a Dirac delta (so `sample` may return
    /// `delta = true`): the delta models and smooth `plastic`.
    pub fn has_delta(&self) -> bool {
        self.is_delta() || matches!(self, Bsdf::Plastic { .. })
    }

    /// True when some lobe is glossy: a non-delta lobe concentrated about a
    /// direction (Phong with a specular part, the rough conductor, the coat
    /// of rough plastic, rough glass). The glossy camera pass of `plb` estimates such
    /// lobes from the camera side too.
    pub fn has_glossy(&self) -> bool {
        match self {
            Bsdf::Phong { ks, .. } => ks.max_element() > 0.0,
            Bsdf::RoughConductor { .. }
            | Bsdf::RoughPlastic { .. }
            | Bsdf::RoughDielectric { .. } => true,
            _ => false,
        }
    }

    /// True when some lobe is non-delta, so that connections (NEE, camera) can
    /// reach it.
    pub fn has_smooth(&self) -> bool {
        !self.is_delta()
    }

    /// True when light can pass through the surface (the dielectrics); these
    /// are two-sided by construction and must not be frame-flipped.
    pub fn is_transmissive(&self) -> bool {
        matches!(
            self,
            Bsdf::Dielectric { .. } | Bsdf::RoughDielectric { .. } | Bsdf::ThinDielectric { .. }
        )
    }

    /// Completes a non-delta sample at `wi` from `eval` and `pdf`, so that the
    /// two always agree with `sample`.
    fn smooth_sample(&self, wo: Vec3, wi: Vec3, mode: Mode) -> Option<BsdfSample> {
        if wi.z <= 0.0 || !wi.is_finite() {
            return None;
        }
        self.sample_at(wo, wi, mode, 1.0)
    }

    /// The non-delta sample at `wi` (either side of the surface), its value
    /// and density from `eval` and `pdf`, with the relative index `eta` it
    /// crosses; `None` where the density is zero or not finite.
    fn sample_at(&self, wo: Vec3, wi: Vec3, mode: Mode, eta: f32) -> Option<BsdfSample> {
        let pdf = self.pdf(wo, wi);
        if !(pdf > 0.0 && pdf.is_finite()) {
            return None;
        }
        Some(BsdfSample {
            wi,
            f: self.eval(wo, wi, mode),
            pdf,
            delta: false,
            eta,
        })
    }

    /// Probability of sampling the coat of `plastic` / `roughplastic` for
    /// cos θo = `cos_o`: Mitsuba's F·w / (F·w + (1 − F)(1 − w)), with F the
    /// Fresnel reflectance of the smooth coat or 1 − t(μ) of the rough one.
    fn plastic_specular_probability(&self, cos_o: f32) -> f32 {
        let (f, w) = match *self {
            Bsdf::Plastic {
                eta, spec_weight, ..
            } => (fresnel_dielectric(cos_o, eta).0, spec_weight),
            Bsdf::RoughPlastic {
                table, spec_weight, ..
            } => (1.0 - table.t(cos_o), spec_weight),
            _ => return 0.0,
        };
        let ps = f * w;
        let pd = (1.0 - f) * (1.0 - w);
        if ps + pd > 0.0 {
            ps / (ps + pd)
        } else {
            0.0
        }
    }
}

/// The diffuse part of a BSDF: the term f_d(wo, wi) = k · T(cos θo) ·
/// T(cos θi) that is Lambertian up to a coat's transmittance T on each side
/// (T = 1 for `diffuse` and `phong`; 1 − F(θ) through the smooth coat of
/// `plastic`; the tabulated t(μ) through the rough coat of `roughplastic`).
///
/// It is what the density method stores view-independently (§3.2 of the
/// density-estimation paper, for the Lambertian part): the separable form
/// gives L_d(wo) = k T(cos θo) Ĥ with Ĥ = ∫ T(cos θi) L_i cos θi dωi, the
/// irradiance weighted by the coat's transmittance (Ĥ = H when T = 1).
#[derive(Clone, Copy, Debug)]
pub struct DiffusePart {
    /// k = R/π (`diffuse`), kd/π (`phong`), ρ_int/(π η²) (the plastics, ρ_int
    /// the base albedo after the coat's internal reflections).
    pub k: Rgb,
    coat: CoatLaw,
}

#[derive(Clone, Copy, Debug)]
enum CoatLaw {
    None,
    Smooth { eta: f32 },
    Rough { table: &'static CoatTable },
}

impl DiffusePart {
    /// The coat's transmittance T for a direction at cos θ = `cos` (1 for
    /// uncoated models).
    #[inline]
    pub fn t(&self, cos: f32) -> f32 {
        match self.coat {
            CoatLaw::None => 1.0,
            CoatLaw::Smooth { eta } => 1.0 - fresnel_dielectric(cos, eta).0,
            CoatLaw::Rough { table } => table.t(cos),
        }
    }

    /// f_d(wo, wi), local directions (zero below the surface).
    #[inline]
    pub fn f(&self, wo: Vec3, wi: Vec3) -> Rgb {
        if wo.z <= 0.0 || wi.z <= 0.0 {
            return Rgb::ZERO;
        }
        self.k * (self.t(wo.z) * self.t(wi.z))
    }

    /// The cosine-weighted mean of T over the outgoing hemisphere,
    /// 2∫ T(μ) μ dμ: 1 uncoated, 1 − F_dr(η) for the smooth coat, the
    /// table's external diffuse transmittance for the rough one.
    pub fn t_mean(&self) -> f32 {
        match self.coat {
            CoatLaw::None => 1.0,
            CoatLaw::Smooth { eta } => 1.0 - fresnel_diffuse_reflectance(eta),
            CoatLaw::Rough { table } => table.external_diffuse_transmittance,
        }
    }

    /// The view-independent reflectance R_d = π k T̄ of the display mesh,
    /// whose vertices carry R_d Ĥ/π: exact for `diffuse` and `phong` (R and
    /// kd); for the plastics the outgoing T(cos θo) is replaced by its
    /// cosine-weighted mean T̄ (a view-dependent factor no vertex colour can
    /// hold; the view pass uses the exact one).
    pub fn rd(&self) -> Rgb {
        self.k * (PI * self.t_mean())
    }
}

impl Bsdf {
    /// The diffuse part of this BSDF (`diffuse`, `phong`, `plastic`,
    /// `roughplastic`; k may be zero), None for the models without one.
    pub fn diffuse_part(&self) -> Option<DiffusePart> {
        let (k, coat) = match *self {
            Bsdf::Diffuse { r } => (r * FRAC_1_PI, CoatLaw::None),
            Bsdf::Phong { kd, .. } => (kd * FRAC_1_PI, CoatLaw::None),
            Bsdf::Plastic {
                rho,
                eta,
                fdr_int,
                nonlinear,
                ..
            } => (
                internal_scattering(rho, fdr_int, nonlinear) * (FRAC_1_PI / (eta * eta)),
                CoatLaw::Smooth { eta },
            ),
            Bsdf::RoughPlastic {
                rho,
                eta,
                nonlinear,
                table,
                ..
            } => (
                internal_scattering(rho, table.internal_reflectance, nonlinear)
                    * (FRAC_1_PI / (eta * eta)),
                CoatLaw::Rough { table },
            ),
            _ => return None,
        };
        Some(DiffusePart { k, coat })
    }
}

/// The reflection half vector, `None` when wo = −wi.
#[inline]
fn half_vector(wo: Vec3, wi: Vec3) -> Option<Vec3> {
    let h = wo + wi;
    let l2 = h.length_squared();
    if l2 > 0.0 {
        Some(h / l2.sqrt())
    } else {
        None
    }
}

/// Solid-angle density of wi = reflect(wo, h) when h is drawn by
/// `Microfacet::sample_m`: the Jacobian of reflection is 1/(4 |wo·h|).
#[inline]
fn microfacet_reflection_pdf(dist: Microfacet, wo: Vec3, h: Vec3) -> f32 {
    let c = wo.dot(h);
    if c <= 0.0 {
        return 0.0;
    }
    dist.pdf_m(wo, h) / (4.0 * c)
}

/// ρ / (1 − x·F_int) with x = ρ when `nonlinear`, else 1: the base albedo
/// after the series of internal reflections under the coat (Mitsuba's
/// `plastic` model; `nonlinear = false` keeps the texture's hue).
#[inline]
fn internal_scattering(rho: Rgb, f_int: f32, nonlinear: bool) -> Rgb {
    if nonlinear {
        rho / (Rgb::ONE - rho * f_int)
    } else {
        rho / (1.0 - f_int)
    }
}

/// Samples the Phong lobe around the mirror direction of `wo`: cos α =
/// u.x^(1/(n+1)), φ = 2π u.y, the density ∝ cosⁿα (Lafortune and Willems
/// 1994).
#[inline(always)]
fn phong_lobe_sample(wo: Vec3, n: f32, u: Vec2) -> Vec3 {
    let r = reflect_local(wo);
    let cos_a = u.x.powf(1.0 / (n + 1.0));
    let sin_a = (1.0 - cos_a * cos_a).max(0.0).sqrt();
    let phi = 2.0 * PI * u.y;
    Frame::from_normal(r).to_world(Vec3::new(sin_a * phi.cos(), sin_a * phi.sin(), cos_a))
}

/// [`Bsdf::sample`] for `dielectric`: specular reflection with probability
/// F, else refraction, both delta (pbrt-v4's `DielectricBxDF::Sample_f`).
#[inline(always)]
fn sample_dielectric(
    wo: Vec3,
    uc: f32,
    eta: f32,
    r: Rgb,
    t: Rgb,
    mode: Mode,
) -> Option<BsdfSample> {
    if wo.z == 0.0 {
        return None;
    }
    let (f, cos_t, eta_it, eta_ti) = fresnel_dielectric(wo.z, eta);
    if uc < f {
        // Specular reflection, chosen with probability F
        Some(BsdfSample {
            wi: reflect_local(wo),
            f: r * (f / wo.z.abs()),
            pdf: f,
            delta: true,
            eta: 1.0,
        })
    } else {
        // Refraction, chosen with probability 1 − F; radiance is
        // scaled by (1/η)² = eta_ti², importance is not
        let wi = Vec3::new(-eta_ti * wo.x, -eta_ti * wo.y, cos_t);
        let scale = match mode {
            Mode::Radiance => eta_ti * eta_ti,
            Mode::Importance => 1.0,
        };
        if cos_t == 0.0 {
            return None;
        }
        Some(BsdfSample {
            wi,
            f: t * ((1.0 - f) * scale / cos_t.abs()),
            pdf: 1.0 - f,
            delta: true,
            eta: eta_it,
        })
    }
}

/// [`Bsdf::sample`] for `thindielectric`: reflection with probability R'
/// (both faces' interreflections summed), else straight through.
#[inline(always)]
fn sample_thin_dielectric(wo: Vec3, uc: f32, eta: f32, r: Rgb, t: Rgb) -> Option<BsdfSample> {
    if wo.z == 0.0 {
        return None;
    }
    let rr = thin_reflectance(wo.z.abs(), eta);
    let c = wo.z.abs();
    if uc < rr {
        Some(BsdfSample {
            wi: reflect_local(wo),
            f: r * (rr / c),
            pdf: rr,
            delta: true,
            eta: 1.0,
        })
    } else {
        // Straight through: the two refractions cancel
        Some(BsdfSample {
            wi: -wo,
            f: t * ((1.0 - rr) / c),
            pdf: 1.0 - rr,
            delta: true,
            eta: 1.0,
        })
    }
}

/// Probability of Phong's specular lobe: ks over kd + ks, in luminance.
#[inline]
fn phong_specular_probability(kd: Rgb, ks: Rgb) -> f32 {
    let (d, s) = (luminance(kd).max(0.0), luminance(ks).max(0.0));
    if d + s > 0.0 {
        s / (d + s)
    } else {
        0.0
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn shading_normal_correction_is_one_for_equal_normals_and_guarded() {
        let n = Vec3::Z;
        let wo = Vec3::new(0.3, 0.1, 0.9).normalize();
        let wi = Vec3::new(-0.5, 0.2, 0.4).normalize();
        assert!((shading_normal_correction(wo, wi, n, n) - 1.0).abs() < 1e-6);
        assert_eq!(shading_normal_correction(Vec3::X, wi, n, n), 0.0);
    }

    /// The forms the light paths use agree with the correction: times
    /// |wi·ns| / d, up to rounding, with shading normals that differ from
    /// the geometric one; and the guard holds for them too.
    #[test]
    fn shading_normal_correction_over_is_the_correction_times_cosine_over_d() {
        let ng = Vec3::Z;
        let ns = Vec3::new(0.2, -0.1, 0.95).normalize();
        let wo = Vec3::new(0.3, 0.1, 0.9).normalize();
        let wi = Vec3::new(-0.5, 0.2, 0.4).normalize();
        let c = shading_normal_correction(wo, wi, ng, ns);
        assert!((c - 1.0).abs() > 1e-3, "normals too close to test: {c}");
        let cos = wi.dot(ns).abs();
        for d in [1.0f32, 0.37, 2.5] {
            let over = shading_normal_correction_over(wo, wi, ng, ns, d);
            assert!((over - c * cos / d).abs() < 1e-6 * over, "d {d}: {over}");
        }
        assert_eq!(shading_normal_correction_over(wo, wi, ng, ns, cos), c);
        assert_eq!(
            shading_normal_correction_over(Vec3::X, wi, ng, ng, 1.0),
            0.0
        );
        assert_eq!(shading_normal_correction_over(wo, wi, ng, ns, 0.0), 0.0);
    }

    #[test]
    fn conductor_sample_weight_is_fresnel() {
        let b = Bsdf::Conductor {
            eta: Rgb::splat(0.2),
            k: Rgb::splat(3.0),
            s: Rgb::ONE,
        };
        let wo = Vec3::new(0.6, 0.0, 0.8);
        let s = b.sample(wo, 0.5, Vec2::splat(0.5), Mode::Radiance).unwrap();
        let w = s.f * s.wi.z.abs() / s.pdf;
        let f = fresnel_conductor(0.8, Rgb::splat(0.2), Rgb::splat(3.0));
        assert!((w - f).abs().max_element() < 1e-6);
    }
}
