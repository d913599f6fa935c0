//! Fresnel reflectance of dielectric and conducting interfaces, and the
//! reflect / refract helpers of the local shading frame.

use glam::Vec3;

use crate::scene::Rgb;

/// Unpolarized Fresnel reflectance of a dielectric interface.
///
/// `cos_i` is the cosine between the incident direction and the normal (+z);
/// it is negative when the direction lies inside (below the surface), in
/// which case the relative index `eta` (= n_inside / n_outside) is inverted.
///
/// Returns `(F, cos_t, eta_it, eta_ti)`: the reflectance, the signed cosine of
/// the transmitted direction (on the side opposite to the incident one), the
/// relative index of the side entered over the side left (`eta_it`), and its
/// reciprocal. Under total internal reflection F = 1 and `cos_t` = 0.
#[inline]
pub fn fresnel_dielectric(cos_i: f32, eta: f32) -> (f32, f32, f32, f32) {
    // Orient the interface: from inside, the ratio of indices flips
    let (eta_it, eta_ti) = if cos_i >= 0.0 {
        (eta, 1.0 / eta)
    } else {
        (1.0 / eta, eta)
    };
    let ci = cos_i.abs().min(1.0);

    // Snell's law in cosines; a negative square means total internal reflection
    let cos_t_sqr = 1.0 - eta_ti * eta_ti * (1.0 - ci * ci);
    if cos_t_sqr <= 0.0 {
        return (1.0, 0.0, eta_it, eta_ti);
    }
    let ct = cos_t_sqr.sqrt();

    // Amplitude coefficients for s and p polarisation (Born and Wolf §1.5)
    let r_s = (ci - eta_it * ct) / (ci + eta_it * ct);
    let r_p = (eta_it * ci - ct) / (eta_it * ci + ct);
    let f = if eta == 1.0 {
        0.0
    } else if ci == 0.0 {
        1.0
    } else {
        0.5 * (r_s * r_s + r_p * r_p)
    };
    let cos_t = if cos_i >= 0.0 { -ct } else { ct };
    (f.clamp(0.0, 1.0), cos_t, eta_it, eta_ti)
}

/// Unpolarized Fresnel reflectance of a conductor with complex index
/// `eta + i k` (per channel), for incidence cosine `cos_i` ≥ 0.
///
/// The exact expression for a complex index, written in the real quantities
/// a² + b² (see e.g. Lagarde, "Memo on Fresnel equations", 2013). At normal
/// incidence it reduces to ((η−1)² + k²) / ((η+1)² + k²).
#[inline]
pub fn fresnel_conductor(cos_i: f32, eta: Rgb, k: Rgb) -> Rgb {
    let c = cos_i.clamp(0.0, 1.0);
    Rgb::new(
        fresnel_conductor_1(c, eta.x, k.x),
        fresnel_conductor_1(c, eta.y, k.y),
        fresnel_conductor_1(c, eta.z, k.z),
    )
}

fn fresnel_conductor_1(c: f32, eta: f32, k: f32) -> f32 {
    let c2 = c * c;
    let s2 = 1.0 - c2;
    let t0 = eta * eta - k * k - s2;
    let a2b2 = (t0 * t0 + 4.0 * eta * eta * k * k).max(0.0).sqrt();
    let a = (0.5 * (a2b2 + t0)).max(0.0).sqrt();
    let t1 = a2b2 + c2;
    let t2 = 2.0 * c * a;
    let r_s = (t1 - t2) / (t1 + t2);
    let t3 = c2 * a2b2 + s2 * s2;
    let t4 = t2 * s2;
    let r_p = r_s * (t3 - t4) / (t3 + t4);
    let f = 0.5 * (r_s + r_p);
    if f.is_finite() {
        f.clamp(0.0, 1.0)
    } else {
        1.0
    }
}

/// Diffuse Fresnel reflectance F_dr(η): the fraction of uniformly diffuse
/// (cosine-weighted) light reflected by a dielectric interface of relative
/// index η, i.e. 2∫₀¹ F(μ, η) μ dμ.
///
/// The same two fits as Mitsuba (so that `plastic` agrees with it): Egan and
/// Hilgeman (1973) for η < 1 and d'Eon and Irving (2011) for η ≥ 1, accurate
/// to ≈0.1 % for ordinary indices.
pub fn fresnel_diffuse_reflectance(eta: f32) -> f32 {
    let inv = 1.0 / eta;
    if eta < 1.0 {
        -1.4399 * eta * eta + 0.7099 * eta + 0.6681 + 0.0636 * inv
    } else {
        // Polynomial in 1/η, Horner form
        let c = [0.919317, -3.4793, 6.75335, -7.80989, 4.98554, -1.36881];
        let mut acc = c[5];
        for &ci in c[..5].iter().rev() {
            acc = acc * inv + ci;
        }
        acc
    }
}

/// Mirror reflection of `v` about a unit normal `m` (both pointing away from
/// the surface).
#[inline]
pub fn reflect(v: Vec3, m: Vec3) -> Vec3 {
    2.0 * v.dot(m) * m - v
}

/// Refraction of `v` through the microfacet (or surface) normal `m`, given
/// `cos_t` and `eta_ti` as returned by [`fresnel_dielectric`] for
/// `cos_i = v·m`. The result points away from the surface on the other side.
#[inline]
pub fn refract(v: Vec3, m: Vec3, cos_t: f32, eta_ti: f32) -> Vec3 {
    m * (v.dot(m) * eta_ti + cos_t) - v * eta_ti
}

/// Reflectance of a thin pane with both faces' interreflections summed
/// (Mitsuba's `thindielectric`): R' = R + T²R / (1 − R²), T = 1 − R.
#[inline]
pub fn thin_reflectance(cos: f32, eta: f32) -> f32 {
    let r = fresnel_dielectric(cos, eta).0;
    if r < 1.0 {
        let t = 1.0 - r;
        r + t * t * r / (1.0 - r * r)
    } else {
        1.0
    }
}
