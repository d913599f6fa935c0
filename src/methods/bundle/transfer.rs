//! The random transport operator of eq. (27) and the loop of §5:
//!
//! L_new\[i\] = L_i^e(ω_{m+1}) + 4π Σ_j f̃_i(ω_m, ω_{m+1}) A(i, j, ω_m)/A_i · L\[j\].
//!
//! With the bi-directional transfer both ω_m and −ω_m carry radiance in one
//! sweep, so each patch keeps two values, L[i](+ω) and L[i](−ω), and the
//! operator averages the two antithetic directions: 4π → 2π per direction,
//! still unbiased (E over uniform ω of ½(g(ω) + g(−ω)) = E g).
//!
//! f̃_i is the patch's BRDF evaluated in the frame of the side that faces
//! both the incoming flow and ω_{m+1} (zero when they are on different
//! sides; zero on the back of one-sided materials), except for glass, which
//! also transmits (below).
//!
//! Mirror-like conductors: a Dirac BRDF can never map ω_m onto a random
//! ω_{m+1}, so in the transfer a smooth conductor is replaced by a lobe
//! cos^n α of exponent [`MIRROR_EXPONENT`] around the mirror direction,
//! scaled by the conductor's Fresnel reflectance and divided by cos θ_i as
//! the mirror's δ is, so that its albedo is F at every angle (the paper's
//! "mirror-like" patches are glossy in the same sense). The camera side still sees a perfect mirror
//! (see `image.rs`).
//!
//! Glass (`--glass lobes`, the default) is widened the same way: a smooth
//! dielectric reflects into a lobe around the mirror direction with weight
//! F and transmits into a lobe around the refracted direction with weight
//! (1 − F) η_o²/η_i² (radiance is scaled by the squared ratio of indices as
//! it crosses, as in the path tracer's BSDF), both divided by cos θ_i, so
//! that the albedos are those of the smooth interface. A thin pane
//! transmits straight through with 1 − R' and reflects R'. Light then
//! travels through a glass object patch to patch (in at the front, across
//! the inside, out at the back), as it does through the patches of any
//! other surface. `--glass off` is the code before it: glass neither
//! reflects nor transmits in the transfer.

use std::f32::consts::PI;

use glam::Vec3;

use super::patches::Patch;
use crate::bsdf::fresnel::{fresnel_conductor, fresnel_dielectric, thin_reflectance};
use crate::bsdf::{Bsdf, Mode};
use crate::geometry::Frame;
use crate::sampling::{uniform_triangle, Pcg32};
use crate::scene::Rgb;
use crate::transport::shadow_clear;
use crate::world::World;

/// Phong exponent standing in for a smooth conductor in the transfer.
pub const MIRROR_EXPONENT: f32 = 400.0;

/// f(wo, wi) of `bsdf` in a local frame, with smooth conductors replaced by
/// a narrow Phong lobe.
#[inline]
pub fn eval_local(bsdf: &Bsdf, wo: Vec3, wi: Vec3) -> Rgb {
    match *bsdf {
        Bsdf::Conductor { eta, k, s } => {
            if wo.z <= 0.0 || wi.z <= 0.0 {
                return Rgb::ZERO;
            }
            // F δ(wi − r) / cos θ_i with the δ widened to the lobe
            // (n + 1)/(2π) cos^n α, which integrates to 1 over the sphere
            // of wi around r: the albedo ∫ f cos θ_i dω_i is then F, as for
            // the mirror, while the lobe stays above the horizon.
            s * fresnel_conductor(wo.z, eta, k) * widened(Vec3::new(-wo.x, -wo.y, wo.z), wi)
        }
        _ => bsdf.eval(wo, wi, Mode::Radiance),
    }
}

/// The widened δ around direction `c` (unit): (n + 1)/(2π) cos^n α / |cos
/// θ_i|, with α the angle between `wi` and `c`; ∫ of it times |cos θ_i|
/// over the sphere of `wi` is 1, so a smooth lobe of weight w keeps albedo
/// w.
#[inline]
fn widened(c: Vec3, wi: Vec3) -> f32 {
    let cos_a = c.dot(wi).max(0.0);
    if cos_a == 0.0 || wi.z == 0.0 {
        return 0.0;
    }
    let n = MIRROR_EXPONENT;
    (n + 1.0) / (2.0 * PI) * cos_a.powf(n) / wi.z.abs()
}

/// f(wo, wi) of smooth glass in the transfer, in the frame of the front
/// side (+z = the shading normal, outside): reflection when wo and wi are
/// on the same side, transmission when not, each a widened δ (see the
/// module notes). Zero for any other BSDF.
#[inline]
pub fn eval_glass(bsdf: &Bsdf, wo: Vec3, wi: Vec3) -> Rgb {
    let same_side = wo.z * wi.z > 0.0;
    match *bsdf {
        Bsdf::Dielectric { eta, r, t } => {
            let (f, cos_t, _, eta_ti) = fresnel_dielectric(wo.z, eta);
            if same_side {
                r * (f * widened(Vec3::new(-wo.x, -wo.y, wo.z), wi))
            } else if cos_t != 0.0 && wo.z * wi.z < 0.0 {
                // the direction that refracts into wo
                let c = Vec3::new(-eta_ti * wo.x, -eta_ti * wo.y, cos_t);
                t * ((1.0 - f) * eta_ti * eta_ti * widened(c, wi))
            } else {
                Rgb::ZERO
            }
        }
        Bsdf::ThinDielectric { eta, r, t } => {
            let rr = thin_reflectance(wo.z.abs(), eta);
            if same_side {
                r * (rr * widened(Vec3::new(-wo.x, -wo.y, wo.z), wi))
            } else if wo.z * wi.z < 0.0 {
                t * ((1.0 - rr) * widened(-wo, wi))
            } else {
                Rgb::ZERO
            }
        }
        // rough glass is not a δ: its f is the transfer's as it is
        Bsdf::RoughDielectric { .. } => bsdf.eval(wo, wi, Mode::Radiance),
        _ => Rgb::ZERO,
    }
}

/// True for the BSDFs that [`eval_glass`] transfers.
#[inline]
pub fn is_glass(bsdf: &Bsdf) -> bool {
    matches!(
        bsdf,
        Bsdf::Dielectric { .. } | Bsdf::RoughDielectric { .. } | Bsdf::ThinDielectric { .. }
    )
}

/// f̃_i for radiance flowing along `d` into the patch and leaving toward `w`
/// (both unit, world space), with shading normal `ns` (on the front side),
/// times the shading-normal correction cos θ_s / cos θ_g of the incoming
/// direction (see [`shading_ratio`]). Glass patches transfer through
/// [`eval_glass`] unless `--glass off` ([`Patch::glass`]).
#[inline]
pub fn brdf(p: &Patch, ns: Vec3, d: Vec3, w: Vec3) -> Rgb {
    if p.glass {
        let frame = Frame::from_normal(ns);
        let wi = frame.to_local(-d);
        return eval_glass(&p.bsdf, frame.to_local(w), wi) * shading_ratio(wi.z, p.ng.dot(d));
    }
    let front_in = p.ng.dot(d) < 0.0;
    let front_out = p.ng.dot(w) > 0.0;
    if front_in != front_out || (!front_in && !p.two_sided) {
        return Rgb::ZERO;
    }
    let n = if front_in { ns } else { -ns };
    let frame = Frame::from_normal(n);
    let wi = frame.to_local(-d);
    eval_local(&p.bsdf, frame.to_local(w), wi) * shading_ratio(wi.z, p.ng.dot(d))
}

/// cos θ_s / cos θ_g for an incoming direction with local z `cos_s` in the
/// shading frame and `ng_dot_d` = n_g · d.
///
/// The map measures what arrives through the patch's projected area, A_i
/// |cos θ_g| (geometric normal), so E/A_i estimates L · |cos θ_g|. The
/// reflection integral that `path` (and Mitsuba) evaluate weights the
/// incoming radiance by the cosine to the *shading* normal, |cos θ_s|. With
/// flat shading the two agree; with interpolated normals they do not, and
/// leaving the ratio out darkens the image (measured in docs/notebook/bundle.md and
/// checked by `tests/bundle.rs`, `shading_normals_vs_path`). Where cos θ_g → 0
/// the ratio grows, but the pixel coverage that it multiplies falls in
/// proportion, so the product stays an unbiased estimate of L |cos θ_s|.
///
/// cos θ_g is floored at [`MIN_COS_G`], so that a patch seen exactly
/// edge-on (cos θ_g below ~3e-39 makes 1/cos θ_g infinite in f32) cannot
/// put an infinite radiance into the iteration, where the painter's
/// undone pairs would turn it into NaN. The floor changes the estimate
/// only for incoming directions with cos θ_g < 1e-6, a band of solid angle
/// 2π · 1e-6 on the patch's side, so it lowers ∫ L |cos θ_s| dω by at most
/// 2π · 1e-6 · max L.
#[inline]
pub fn shading_ratio(cos_s: f32, ng_dot_d: f32) -> f32 {
    let cg = ng_dot_d.abs();
    if cg > 0.0 {
        cos_s.abs() / cg.max(MIN_COS_G)
    } else {
        0.0
    }
}

/// Floor of cos θ_g in [`shading_ratio`].
pub const MIN_COS_G: f32 = 1e-6;

/// Radiance leaving patch `p` toward `w` after reflecting what it received
/// from the sweep along ±d: Le(w) + 2π Σ_{±} f̃(±d, w) E_±/A.
#[inline]
pub fn reflect(p: &Patch, d: Vec3, e_plus: Rgb, e_minus: Rgb, w: Vec3) -> Rgb {
    reflect_onto(p.le(w), p, d, e_plus, e_minus, w)
}

/// `start` + 2π Σ_{±} f̃(±d, w) E_±/A: what patch `p` reflects toward `w`
/// of the sweep along ±d, added to `start` (the emission for the paper's
/// operator, the first shot's direct light for [`super::Direct::Nee`]).
#[inline]
pub fn reflect_onto(start: Rgb, p: &Patch, d: Vec3, e_plus: Rgb, e_minus: Rgb, w: Vec3) -> Rgb {
    let mut l = start;
    let k = 2.0 * PI / p.area;
    if e_plus != Rgb::ZERO {
        l += brdf(p, p.ns, d, w) * e_plus * k;
    }
    if e_minus != Rgb::ZERO {
        l += brdf(p, p.ns, -d, w) * e_minus * k;
    }
    l
}

/// The first shot on the patch side: the radiance that patch `p` reflects
/// toward `w` and toward −`w` of the light arriving straight from the
/// emitters, estimated by one light sample from a uniform point of the
/// patch (so that it averages over the patch, as the patch's constant
/// radiance of eq. (23) does): f̃(−wi, ±w) |cos θ_s| Le / pdf when the
/// shadow ray is clear, with f̃ and the shading correction of [`brdf`].
/// Returns both and the rays traced (0 or 1).
pub fn direct(world: &World, p: &Patch, w: Vec3, rng: &mut Pcg32) -> (Rgb, Rgb, u64) {
    let b = uniform_triangle(rng.next_2d());
    let u_sel = rng.next_f32();
    let u = rng.next_2d();
    let q = p.v[0] * (1.0 - b.x - b.y) + p.v[1] * b.x + p.v[2] * b.y;
    let Some(ls) = world.lights.sample_li(q, u_sel, u) else {
        return (Rgb::ZERO, Rgb::ZERO, 0);
    };
    if ls.pdf.is_nan() || ls.pdf <= 0.0 {
        return (Rgb::ZERO, Rgb::ZERO, 0);
    }
    // brdf() gives f |cos θ_s| / |cos θ_g| of the flow direction −wi
    let cos_g = p.ng.dot(ls.wi);
    let g = ls.le * (cos_g.abs() / ls.pdf);
    let (f_plus, f_minus) = (brdf(p, p.ns, -ls.wi, w), brdf(p, p.ns, -ls.wi, -w));
    if f_plus == Rgb::ZERO && f_minus == Rgb::ZERO {
        return (Rgb::ZERO, Rgb::ZERO, 0);
    }
    let side = if cos_g > 0.0 { p.ng } else { -p.ng };
    if !shadow_clear(world, q, side, &ls) {
        return (Rgb::ZERO, Rgb::ZERO, 1);
    }
    let (l_plus, l_minus) = (f_plus * g, f_minus * g);
    if l_plus.is_finite() && l_minus.is_finite() {
        (l_plus, l_minus, 1)
    } else {
        (Rgb::ZERO, Rgb::ZERO, 1)
    }
}
