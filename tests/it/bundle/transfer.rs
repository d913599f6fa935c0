//! The transfer's stand-ins for Dirac BSDFs: a smooth conductor and smooth
//! or thin glass must keep the albedo of the interface they replace.

use glam::{DVec3, Vec3};
use kalos::bsdf::fresnel::{fresnel_conductor, fresnel_dielectric, thin_reflectance};
use kalos::bsdf::Bsdf;
use kalos::geometry::Frame;
use kalos::methods::bundle::transfer::{eval_glass, eval_local, MIRROR_EXPONENT};

/// ∫ f(wi) |cos θ_i| dω_i over the cap α ≤ 0.35 rad around the unit
/// direction `c`, on c's side of the surface, by the midpoint rule in
/// polar coordinates (α, φ) around `c` with `na` × `nphi` cells. (Near
/// grazing the cap reaches across the surface, where the other lobe of a
/// thin pane, 2 × 15° away at θ_o = 75°, would leak into it.)
///
/// The lobes cos^n α with n = [`MIRROR_EXPONENT`] = 400 are below e^{−24}
/// of their peak at the cap's rim, so for a lobe that stays clear of the
/// horizon the cap holds all of its albedo.
fn cap_albedo(f: impl Fn(Vec3) -> Vec3, c: Vec3, na: usize, nphi: usize) -> Vec3 {
    let frame = Frame::from_normal(c);
    let a_max = 0.35f64;
    let (da, dphi) = (a_max / na as f64, std::f64::consts::TAU / nphi as f64);
    let mut sum = DVec3::ZERO;
    for i in 0..na {
        let a = (i as f64 + 0.5) * da;
        for j in 0..nphi {
            let phi = (j as f64 + 0.5) * dphi;
            let l = Vec3::new(
                (a.sin() * phi.cos()) as f32,
                (a.sin() * phi.sin()) as f32,
                a.cos() as f32,
            );
            let wi = frame.to_world(l);
            if wi.z * c.z <= 0.0 {
                continue;
            }
            sum += f(wi).as_dvec3() * (wi.z.abs() as f64 * a.sin() * da * dphi);
        }
    }
    sum.as_vec3()
}

/// Checks that the lobe `f` around `c` has albedo `expected`, within the
/// midpoint rule's own error, measured as the difference between the grid
/// and one with half the steps per axis (the rule's error falls 4× when
/// the steps halve, so that difference is 3× the error of the finer grid),
/// plus the f32 rounding of the terms: cos α = c · wi carries a few ulp of
/// error (the frame's rotation and the dot product, taken as 4 ε = 4 ·
/// 2⁻²⁴), which cos^n α multiplies by n = 400, so each term and the sum
/// are within 400 · 4 ε ≈ 9.5e-5 of the albedo, relative.
fn check_albedo(what: &str, f: impl Fn(Vec3) -> Vec3, c: Vec3, expected: Vec3) {
    let fine = cap_albedo(&f, c, 800, 256);
    let coarse = cap_albedo(&f, c, 400, 128);
    let rounding = MIRROR_EXPONENT * 4.0 * f32::EPSILON / 2.0 * expected.max_element();
    let tol = (fine - coarse).abs().max_element() / 3.0 + rounding;
    let err = (fine - expected).abs().max_element();
    eprintln!(
        "{what}: albedo {fine:?}, expected {expected:?}, error {err:.2e}, tolerance {tol:.2e}"
    );
    assert!(
        err <= tol,
        "{what}: albedo {fine:?} vs {expected:?} (tolerance {tol:.2e})"
    );
}

/// The smooth-conductor stand-in of the transfer is a mirror: for every
/// outgoing direction wo its albedo ∫ f(wo, wi) cos θ_i dω_i must be the
/// Fresnel reflectance F(θ_o), as for the Dirac BRDF F δ(wi − r(wo)) / cos θ_i
/// that it replaces. (The stand-in without the 1/cos θ_i had albedo
/// F · cos θ_o, half of F at 60°.) Up to θ_o = 75° the lobe stays above the
/// horizon (75° + 0.35 rad < 90°), so the exact value is F.
#[test]
fn mirror_transfer_albedo_is_fresnel() {
    let (eta, k) = (Vec3::new(0.2, 0.4, 1.4), Vec3::new(3.6, 2.4, 1.8));
    let bsdf = Bsdf::Conductor {
        eta,
        k,
        s: Vec3::ONE,
    };
    for deg in [0.0f32, 30.0, 45.0, 60.0, 75.0] {
        let t = deg.to_radians();
        let wo = Vec3::new(t.sin(), 0.0, t.cos());
        let r = Vec3::new(-wo.x, -wo.y, wo.z);
        let f = fresnel_conductor(wo.z, eta, k);
        check_albedo(
            &format!("conductor, θ_o = {deg}°"),
            |wi| eval_local(&bsdf, wo, wi),
            r,
            f,
        );
    }
}

/// Glass in the transfer (`--glass lobes`): for an outgoing direction wo,
/// outside (θ_o < 90°) or inside (θ_o > 90°), the lobe around the mirror
/// direction must have albedo F and the lobe around the direction that
/// refracts into wo albedo (1 − F) (η_o/η_i)², the radiance that a smooth
/// interface passes (F = 1 and nothing transmitted past the critical
/// angle inside). A thin pane reflects R' and passes 1 − R' straight
/// through. The angles keep both lobes clear of the horizon (the refracted
/// direction of 40° inside is 74.6° outside), so the exact values hold.
/// Before glass was transferred, eval_local gave glass nothing.
#[test]
fn glass_transfer_albedo_is_fresnel() {
    let eta = 1.5f32;
    let (r, t) = (Vec3::ONE, Vec3::new(0.9, 0.8, 1.0));
    let glass = Bsdf::Dielectric { eta, r, t };
    for deg in [0.0f32, 30.0, 60.0, 75.0, 180.0, 150.0, 140.0, 130.0] {
        let th = deg.to_radians();
        let wo = Vec3::new(th.sin(), 0.0, th.cos());
        let (f, cos_t, _, eta_ti) = fresnel_dielectric(wo.z, eta);
        let refl = Vec3::new(-wo.x, -wo.y, wo.z);
        check_albedo(
            &format!("dielectric reflection, θ_o = {deg}°"),
            |wi| eval_glass(&glass, wo, wi),
            refl,
            r * f,
        );
        if cos_t != 0.0 {
            let c = Vec3::new(-eta_ti * wo.x, -eta_ti * wo.y, cos_t);
            check_albedo(
                &format!("dielectric transmission, θ_o = {deg}°"),
                |wi| eval_glass(&glass, wo, wi),
                c,
                t * ((1.0 - f) * eta_ti * eta_ti),
            );
        } else {
            assert_eq!(f, 1.0, "total internal reflection at θ_o = {deg}°");
        }
    }
    let pane = Bsdf::ThinDielectric { eta, r, t };
    for deg in [0.0f32, 45.0, 75.0, 150.0] {
        let th = deg.to_radians();
        let wo = Vec3::new(th.sin(), 0.0, th.cos());
        let rr = thin_reflectance(wo.z.abs(), eta);
        check_albedo(
            &format!("thin pane reflection, θ_o = {deg}°"),
            |wi| eval_glass(&pane, wo, wi),
            Vec3::new(-wo.x, -wo.y, wo.z),
            r * rr,
        );
        check_albedo(
            &format!("thin pane transmission, θ_o = {deg}°"),
            |wi| eval_glass(&pane, wo, wi),
            -wo,
            t * (1.0 - rr),
        );
    }
}
