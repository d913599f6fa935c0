//! Punctual lights in the light distribution: points, spots and
//! directional lights ([`crate::scene::PunctualLight`]).
//!
//! They are delta lights: a point has no area and a directional light no
//! solid angle, so no BSDF-sampled ray can find them. Next-event estimation
//! is their only estimator on the camera side: [`super::LightSample::delta`]
//! marks their samples, whose `pdf` is the probability of choosing the
//! light alone (no density), and MIS gives them full weight. A surface seen
//! only through delta lobes (a mirror) cannot show a point light's
//! reflection, as in every renderer.
//!
//! Selection: a punctual light is an entry of the power distribution,
//! weighted by its luminance power: 4π lum(I) for a point, 2π lum(I)
//! ((1 − cos θ_i) + (cos θ_i − cos θ_o)/3) for a spot (its smooth falloff
//! integrated over the cone), π R² lum(E⊥) for a directional light (the
//! power through the disk of the scene's bounding sphere, as the
//! environment's). Under [`super::LightSelection::Spatial`] the light tree
//! keeps to the emitting triangles; punctual lights and the environment
//! take their power share before the tree is consulted.
//!
//! The camera never sees a punctual light directly (no camera ray can hit
//! a point or a direction): light-based methods do not join their
//! emission vertex to the eye, so that they agree with `path`.
//!
//! Emission (light particles): a point emits from its position in uniform
//! directions, a spot uniformly inside its outer cone (weighted by the
//! falloff), a directional light parallel rays from the disk of the scene's
//! bounding radius perpendicular to its direction, as the environment does.

use std::f32::consts::PI;

use glam::{Vec2, Vec3};

use super::{EmissionSample, LightSample};
use crate::geometry::Frame;
use crate::sampling::{concentric_disk, uniform_sphere};
use crate::scene::{luminance, PunctualKind, PunctualLight, Rgb};

/// The solid-angle integral of the spot falloff over the sphere, per unit
/// intensity: 2π ((1 − cos θ_i) + (cos θ_i − cos θ_o)/3).
fn spot_solid_angle(cos_inner: f32, cos_outer: f32) -> f32 {
    let span = (cos_inner - cos_outer).max(0.0);
    2.0 * PI * ((1.0 - cos_inner) + span / 3.0)
}

/// Power of `l` per channel (W): through the disk of radius `radius` for a
/// directional light.
pub(super) fn power(l: &PunctualLight, radius: f32) -> Rgb {
    match l.kind {
        PunctualKind::Point => l.intensity * (4.0 * PI),
        PunctualKind::Spot {
            cos_inner,
            cos_outer,
        } => l.intensity * spot_solid_angle(cos_inner, cos_outer),
        PunctualKind::Directional => l.intensity * (PI * radius * radius),
    }
}

/// The weight of `l` in the power distribution (luminance power).
pub(super) fn weight(l: &PunctualLight, radius: f32) -> f64 {
    luminance(power(l, radius)) as f64
}

/// Next-event estimation toward `l`, chosen with probability `pmf`, from
/// `p`: a delta sample (`pdf` = `pmf`) whose `le` is the irradiance the
/// light gives at `p` on a plane facing it (I·falloff/d², or E⊥). `center`
/// and `radius` bound the scene, for the directional light's far point.
#[inline]
pub(super) fn sample_li(
    l: &PunctualLight,
    pmf: f32,
    p: Vec3,
    center: Vec3,
    radius: f32,
) -> Option<LightSample> {
    if l.kind == PunctualKind::Directional {
        let wi = -l.direction;
        return Some(LightSample {
            wi,
            p: p + wi * (2.0 * radius + (p - center).length()),
            n: Vec3::ZERO,
            le: l.intensity,
            pdf: pmf,
            is_env: true,
            delta: true,
        });
    }
    let d = l.position - p;
    let dist2 = d.length_squared();
    if dist2 <= 0.0 {
        return None;
    }
    let wi = d / dist2.sqrt();
    let le = l.intensity * (l.profile(-wi) / dist2);
    if le == Rgb::ZERO {
        return None;
    }
    Some(LightSample {
        wi,
        p: l.position,
        n: Vec3::ZERO,
        le,
        pdf: pmf,
        is_env: false,
        delta: true,
    })
}

/// A particle leaving `l` (light `index`), chosen with probability `pmf`.
/// Points and spots: `phi_pos` = I/pmf, the vertex's weight toward w
/// once multiplied by the falloff ([`PunctualLight::profile`]); `le` is I. Directional lights
/// start on the disk of radius `radius` around `center`, as the
/// environment does (`is_env`), and cannot be joined to a pinhole.
pub(super) fn emission(
    l: &PunctualLight,
    index: u32,
    pmf: f32,
    u_pos: Vec2,
    u_dir: Vec2,
    center: Vec3,
    radius: f32,
) -> Option<EmissionSample> {
    if pmf <= 0.0 {
        return None;
    }
    let (d, pdf_dir) = match l.kind {
        PunctualKind::Point => (uniform_sphere(u_dir), 1.0 / (4.0 * PI)),
        PunctualKind::Spot { cos_outer, .. } => {
            // Uniform in the outer cone
            let one_minus = 1.0 - cos_outer;
            if one_minus <= 0.0 {
                return None;
            }
            let ct = 1.0 - u_dir.x * one_minus;
            let st = (1.0 - ct * ct).max(0.0).sqrt();
            let phi = 2.0 * PI * u_dir.y;
            let local = Vec3::new(st * phi.cos(), st * phi.sin(), ct);
            (
                Frame::from_normal(l.direction).to_world(local),
                1.0 / (2.0 * PI * one_minus),
            )
        }
        PunctualKind::Directional => {
            let d = l.direction;
            let frame = Frame::from_normal(d);
            let disk = concentric_disk(u_pos) * radius;
            let p = center - d * radius + frame.s * disk.x + frame.t * disk.y;
            let pdf_pos = 1.0 / (PI * radius * radius);
            return Some(EmissionSample {
                p,
                n: d,
                d,
                phi: l.intensity / (pdf_pos * pmf),
                phi_pos: Rgb::ZERO,
                le: l.intensity,
                is_env: true,
                tri: u32::MAX,
                punctual: index,
            });
        }
    };
    let phi = l.intensity * (l.profile(d) / (pdf_dir * pmf));
    Some(EmissionSample {
        p: l.position,
        n: d,
        d,
        phi,
        phi_pos: l.intensity / pmf,
        le: l.intensity,
        is_env: false,
        tri: u32::MAX,
        punctual: index,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sampling::Pcg32;

    fn spot(ci: f32, co: f32) -> PunctualLight {
        PunctualLight {
            kind: PunctualKind::Spot {
                cos_inner: ci,
                cos_outer: co,
            },
            position: Vec3::ZERO,
            direction: Vec3::new(0.0, 0.6, -0.8),
            intensity: Rgb::new(1.0, 2.0, 3.0),
            name: "s".into(),
        }
    }

    /// The mean power of the spot's particles is its power (the falloff's
    /// closed-form integral): 4 standard errors of the mean, measured.
    #[test]
    fn spot_particles_carry_its_power() {
        let l = spot(0.9, 0.6);
        let want = power(&l, 1.0).y as f64;
        let mut rng = Pcg32::keyed(&[7]);
        let n = 100_000;
        let (mut s, mut s2) = (0.0f64, 0.0f64);
        for _ in 0..n {
            let es = emission(&l, 0, 1.0, rng.next_2d(), rng.next_2d(), Vec3::ZERO, 1.0)
                .expect("sample");
            assert!(l.direction.dot(es.d) >= 0.6 - 1e-5);
            let x = es.phi.y as f64;
            s += x;
            s2 += x * x;
        }
        let mean = s / n as f64;
        let se = ((s2 / n as f64 - mean * mean) / n as f64).sqrt();
        assert!((mean - want).abs() <= 4.0 * se, "{mean} vs {want} (σ {se})");
    }

    /// A point light's sample at distance 2 gives I/4 toward the light.
    #[test]
    fn point_sample_is_inverse_square() {
        let l = PunctualLight {
            kind: PunctualKind::Point,
            position: Vec3::new(0.0, 2.0, 0.0),
            direction: Vec3::NEG_Z,
            intensity: Rgb::splat(8.0),
            name: "p".into(),
        };
        let ls = sample_li(&l, 0.5, Vec3::ZERO, Vec3::ZERO, 1.0).expect("sample");
        assert!((ls.wi - Vec3::Y).length() < 1e-6);
        assert_eq!(ls.le, Rgb::splat(2.0));
        assert_eq!(ls.pdf, 0.5);
        assert!(ls.delta);
    }
}
