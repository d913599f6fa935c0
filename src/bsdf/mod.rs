//! BSDFs, evaluated in the local shading frame (normal on +z).
//!
//! STUB: to be completed (all Mitsuba plugins, importance mode).

use glam::{Vec2, Vec3};
use std::f32::consts::FRAC_1_PI;

use crate::sampling::{cosine_hemisphere, cosine_hemisphere_pdf};
use crate::scene::{Material, Rgb};

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
#[derive(Clone, Copy, Debug)]
pub struct BsdfSample {
    /// Sampled direction (local frame).
    pub wi: Vec3,
    /// BSDF value f(wo, wi) (no cosine).
    pub f: Rgb,
    /// Solid-angle pdf; for a delta lobe, the probability of choosing that lobe.
    pub pdf: f32,
    /// True when the sampled lobe is a Dirac delta.
    pub delta: bool,
    /// Relative index of refraction crossed (1 for reflection).
    pub eta: f32,
}

/// A BSDF with its parameters resolved at one surface point.
#[derive(Clone, Copy, Debug)]
pub enum Bsdf {
    /// Lambertian.
    Diffuse {
        /// Albedo.
        r: Rgb,
    },
}

impl Bsdf {
    /// f(wo, wi), without the cosine. Zero for delta lobes.
    pub fn eval(&self, wo: Vec3, wi: Vec3, _mode: Mode) -> Rgb {
        match *self {
            Bsdf::Diffuse { r } => {
                if wo.z <= 0.0 || wi.z <= 0.0 {
                    Rgb::ZERO
                } else {
                    r * FRAC_1_PI
                }
            }
        }
    }

    /// Samples wi given wo; `uc` picks a lobe, `u` the direction.
    pub fn sample(&self, wo: Vec3, _uc: f32, u: Vec2, _mode: Mode) -> Option<BsdfSample> {
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
        }
    }

    /// Solid-angle pdf of sampling wi given wo (zero for delta lobes).
    pub fn pdf(&self, wo: Vec3, wi: Vec3) -> f32 {
        match *self {
            Bsdf::Diffuse { .. } => {
                if wo.z <= 0.0 {
                    0.0
                } else {
                    cosine_hemisphere_pdf(wi.z)
                }
            }
        }
    }

    /// Directional albedo estimate ρ(wo) (for Russian roulette).
    pub fn albedo(&self, _wo: Vec3) -> Rgb {
        match *self {
            Bsdf::Diffuse { r } => r,
        }
    }

    /// True when every lobe is a Dirac delta (mirror, smooth glass).
    pub fn is_delta(&self) -> bool {
        false
    }

    /// True when some lobe is non-delta, so that connections (NEE, camera) can
    /// reach it.
    pub fn has_smooth(&self) -> bool {
        !self.is_delta()
    }
}

impl Material {
    /// Resolves the textures at `uv`.
    pub fn bsdf(&self, uv: Vec2) -> Bsdf {
        match self {
            Material::Diffuse { reflectance } => Bsdf::Diffuse {
                r: reflectance.eval(uv),
            },
            Material::TwoSided(inner) => inner.bsdf(uv),
            _ => Bsdf::Diffuse { r: Rgb::splat(0.5) },
        }
    }

    /// True for `twosided` materials and for those that are meaningful on both
    /// sides anyway (glass).
    pub fn is_two_sided(&self) -> bool {
        matches!(self, Material::TwoSided(_))
    }
}
