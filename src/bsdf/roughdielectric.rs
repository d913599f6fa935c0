//! Mitsuba 3's `roughdielectric` (Walter et al. 2007, "Microfacet Models
//! for Refraction through Rough Surfaces"): the generalised half vector,
//! and the lobe's value and density; its sampling is in [`super::Bsdf::sample`].

use glam::Vec3;

use super::fresnel::fresnel_dielectric;
use super::microfacet::Microfacet;
use super::Mode;
use crate::scene::Rgb;

/// The generalised half vector of `roughdielectric` (Walter et al. 2007,
/// eq. 16), on the side of the macro-normal, with the relative index η
/// entered over left (1 for reflection): m ∝ wo + wi (reflection), wo + η wi
/// (refraction). `None` when degenerate or when wo or wi sees the back of m
/// (no microfacet joins them).
#[inline]
fn rough_dielectric_half(eta: f32, wo: Vec3, wi: Vec3) -> Option<(Vec3, bool, f32)> {
    if wo.z == 0.0 || wi.z == 0.0 {
        return None;
    }
    let reflected = wo.z * wi.z > 0.0;
    let eta_rel = match (reflected, wo.z > 0.0) {
        (true, _) => 1.0,
        (false, true) => eta,
        (false, false) => 1.0 / eta,
    };
    let m = wo + wi * eta_rel;
    let l2 = m.length_squared();
    if l2 <= 0.0 || !l2.is_finite() {
        return None;
    }
    let m = m / l2.sqrt();
    let m = if m.z < 0.0 { -m } else { m };
    if wo.dot(m) * wo.z <= 0.0 || wi.dot(m) * wi.z <= 0.0 {
        return None;
    }
    Some((m, reflected, eta_rel))
}

/// [`Bsdf::eval`] for `roughdielectric` (Mitsuba 3's form).
#[inline]
pub(super) fn eval_rough_dielectric(
    dist: Microfacet,
    eta: f32,
    r: Rgb,
    t: Rgb,
    wo: Vec3,
    wi: Vec3,
    mode: Mode,
) -> Rgb {
    let Some((m, reflected, eta_rel)) = rough_dielectric_half(eta, wo, wi) else {
        return Rgb::ZERO;
    };
    let dg = dist.d(m) * dist.g(wo, wi, m);
    if dg <= 0.0 || dg.is_nan() {
        return Rgb::ZERO;
    }
    let f = fresnel_dielectric(wo.dot(m), eta).0;
    let cc = (wo.z * wi.z).abs();
    if reflected {
        r * (f * dg / (4.0 * cc))
    } else {
        let (om, im) = (wo.dot(m), wi.dot(m));
        let den = om + eta_rel * im;
        // radiance is compressed by 1/η² into the denser side; importance is not
        let scale = match mode {
            Mode::Radiance => 1.0,
            Mode::Importance => eta_rel * eta_rel,
        };
        let v = ((1.0 - f) * dg * scale * om * im / (cc * den * den)).abs();
        if v.is_finite() {
            t * v
        } else {
            Rgb::ZERO
        }
    }
}

/// [`Bsdf::pdf`] for `roughdielectric`: the density of m times the lobe's
/// probability F or 1 − F times the Jacobian of the half-vector map,
/// 1/(4 |wi·m|) for reflection, η² |wi·m| / (wo·m + η wi·m)² for refraction.
#[inline]
pub(super) fn pdf_rough_dielectric(dist: Microfacet, eta: f32, wo: Vec3, wi: Vec3) -> f32 {
    let Some((m, reflected, eta_rel)) = rough_dielectric_half(eta, wo, wi) else {
        return 0.0;
    };
    let pm = dist.pdf_m(wo * wo.z.signum(), m);
    let f = fresnel_dielectric(wo.dot(m), eta).0;
    let im = wi.dot(m);
    let p = if reflected {
        pm * f / (4.0 * im.abs())
    } else {
        let den = wo.dot(m) + eta_rel * im;
        pm * (1.0 - f) * (eta_rel * eta_rel * im.abs() / (den * den))
    };
    if p.is_finite() {
        p
    } else {
        0.0
    }
}
