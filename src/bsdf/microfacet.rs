//! Isotropic microfacet normal distributions (GGX and Beckmann) with Smith
//! shadowing, after Walter et al. 2007 ("Microfacet models for refraction
//! through rough surfaces") and Heitz 2014/2018.
//!
//! Sampling: GGX samples the distribution of visible normals (Heitz 2018, "Sampling
//! the GGX distribution of visible normals"), whose density D_wo(m) =
//! G1(wo) max(0, wo·m) D(m) / cos θo is exact because the GGX G1 is exact.
//! Beckmann samples the full distribution D(m) cos θm (Walter et al. 2007,
//! eq. 28): Mitsuba's Beckmann G1 is a rational approximation (< 0.35 % error,
//! Walter et al. eq. 27), so a visible-normal density built on it would not
//! integrate to exactly one; the full distribution keeps `pdf` equal to the
//! density of `sample` to rounding, at the cost of slightly more variance.
//! The images are the same in expectation.

use std::f32::consts::PI;

use glam::{Vec2, Vec3};

use crate::scene::MicrofacetKind;

/// A microfacet distribution with its roughness.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Microfacet {
    /// GGX or Beckmann.
    pub kind: MicrofacetKind,
    /// Roughness α (clamped to ≥ 1e-4, as Mitsuba does).
    pub alpha: f32,
}

impl Microfacet {
    /// A distribution, with α clamped away from zero.
    pub fn new(kind: MicrofacetKind, alpha: f32) -> Self {
        let alpha = if alpha.is_finite() {
            alpha.max(1e-4)
        } else {
            1e-4
        };
        Microfacet { kind, alpha }
    }

    /// D(m): microfacet normal density per unit projected area (∫ D cos θm dω = 1).
    pub fn d(&self, m: Vec3) -> f32 {
        let c = m.z;
        if c <= 0.0 {
            return 0.0;
        }
        let a2 = self.alpha * self.alpha;
        let c2 = c * c;
        let r = match self.kind {
            MicrofacetKind::Beckmann => {
                let tan2 = (m.x * m.x + m.y * m.y) / c2;
                (-tan2 / a2).exp() / (PI * a2 * c2 * c2)
            }
            MicrofacetKind::Ggx => {
                let t = (m.x * m.x + m.y * m.y) / a2 + c2;
                1.0 / (PI * a2 * t * t)
            }
        };
        // Same cut-off as Mitsuba, to keep tiny values out of later divisions
        if r * c > 1e-20 && r.is_finite() {
            r
        } else {
            0.0
        }
    }

    /// Smith's monostatic shadowing G1(v, m); zero when `v` sees the back of `m`.
    pub fn g1(&self, v: Vec3, m: Vec3) -> f32 {
        if v.dot(m) * v.z <= 0.0 {
            return 0.0;
        }
        let xy2 = v.x * v.x + v.y * v.y;
        if xy2 == 0.0 {
            return 1.0;
        }
        let tan2_a2 = self.alpha * self.alpha * xy2 / (v.z * v.z);
        match self.kind {
            MicrofacetKind::Beckmann => {
                // Walter et al. 2007, eq. 27 (the rational fit Mitsuba uses)
                let a = 1.0 / tan2_a2.sqrt();
                if a >= 1.6 {
                    1.0
                } else {
                    (3.535 * a + 2.181 * a * a) / (1.0 + 2.276 * a + 2.577 * a * a)
                }
            }
            MicrofacetKind::Ggx => 2.0 / (1.0 + (1.0 + tan2_a2).sqrt()),
        }
    }

    /// Separable Smith shadowing-masking G(wo, wi, m) = G1(wo, m) G1(wi, m).
    pub fn g(&self, wo: Vec3, wi: Vec3, m: Vec3) -> f32 {
        self.g1(wo, m) * self.g1(wi, m)
    }

    /// Samples a microfacet normal seen from `wo` (wo.z > 0); see the module
    /// docs for which density.
    pub fn sample_m(&self, wo: Vec3, u: Vec2) -> Vec3 {
        match self.kind {
            MicrofacetKind::Ggx => self.sample_ggx_vndf(wo, u),
            MicrofacetKind::Beckmann => {
                // Walter et al. 2007, eq. 28: tan²θm = −α² ln(1 − u)
                let tan2 = -self.alpha * self.alpha * (1.0 - u.x).ln();
                let cos_t = 1.0 / (1.0 + tan2).sqrt();
                let sin_t = (1.0 - cos_t * cos_t).max(0.0).sqrt();
                let phi = 2.0 * PI * u.y;
                Vec3::new(sin_t * phi.cos(), sin_t * phi.sin(), cos_t)
            }
        }
    }

    /// Density of [`Self::sample_m`] over microfacet normals (solid angle).
    pub fn pdf_m(&self, wo: Vec3, m: Vec3) -> f32 {
        match self.kind {
            MicrofacetKind::Ggx => {
                if wo.z <= 0.0 {
                    return 0.0;
                }
                self.g1(wo, m) * wo.dot(m).max(0.0) * self.d(m) / wo.z
            }
            MicrofacetKind::Beckmann => self.d(m) * m.z.max(0.0),
        }
    }

    /// Heitz 2018: stretch wo to the α = 1 configuration, sample the projected
    /// hemisphere seen from it, unstretch.
    fn sample_ggx_vndf(&self, wo: Vec3, u: Vec2) -> Vec3 {
        let a = self.alpha;
        let vh = Vec3::new(a * wo.x, a * wo.y, wo.z).normalize();
        // Orthonormal basis around vh (t1 horizontal)
        let lensq = vh.x * vh.x + vh.y * vh.y;
        let t1 = if lensq > 0.0 {
            Vec3::new(-vh.y, vh.x, 0.0) / lensq.sqrt()
        } else {
            Vec3::X
        };
        let t2 = vh.cross(t1);
        // A point on the disk, squeezed onto the visible half
        let r = u.x.sqrt();
        let phi = 2.0 * PI * u.y;
        let p1 = r * phi.cos();
        let p2 = r * phi.sin();
        let s = 0.5 * (1.0 + vh.z);
        let p2 = (1.0 - s) * (1.0 - p1 * p1).max(0.0).sqrt() + s * p2;
        // Reproject onto the hemisphere and unstretch
        let nh = p1 * t1 + p2 * t2 + (1.0 - p1 * p1 - p2 * p2).max(0.0).sqrt() * vh;
        Vec3::new(a * nh.x, a * nh.y, nh.z.max(1e-6)).normalize()
    }
}
