//! The iteration of §3 (`Iterate`): one step selects the lights or a hit,
//! shoots or reflects a ray with the listing's power weights, scales the
//! population by (1 − 1/m) through the lane's σ, and appends the new hit.
//! A [`Lane`] is one population with its films.

use glam::Vec2;

use super::importance::ImportanceGrid;
use super::purge::end_phase;
use super::Settings;
use crate::film::Film;
use crate::geometry::{offset_point, Ray};
use crate::methods::World;
use crate::sampling::Pcg32;
use crate::scene::{luminance, Rgb, SurfacePoint};
use crate::transport::{
    connect_emission, connect_to_camera, follow_delta_chain, scatter, Landing, Vertex,
};

/// No parent: the hit was shot from a light.
pub(super) const NO_PARENT: u32 = u32::MAX;

/// A photon hit, the record of §5. Powers are stored in units of the lane's
/// σ (actual power = σ · `phi`), and so are `out_lum`, `contrib` and `s`.
#[derive(Clone, Debug)]
pub(super) struct Hit {
    /// Location, surface (triangle, shape → BSDF) and normals.
    pub(super) sp: SurfacePoint,
    /// Incoming direction, reversed (toward where the power came from).
    pub(super) wo: glam::Vec3,
    /// Incoming power, RGB.
    pub(super) phi: Rgb,
    /// Output luminance: Lum(Φ · a(ω_in)).
    pub(super) out_lum: f32,
    /// g*(x) of eq. (9): f² / (|x − eye|² 4π S_p).
    pub(super) g_star: f32,
    /// Image contribution Φ f cos θ g(x) (eq. (8)), zero when hidden.
    pub(super) contrib: Rgb,
    /// Film position of the contribution.
    pub(super) pix: Vec2,
    /// Number of children in the population.
    pub(super) nchild: u32,
    /// Importance (unnormalised hit-selection weight).
    pub(super) s: f64,
    /// Index of the parent hit, or [`NO_PARENT`].
    pub(super) parent: u32,
    /// Segments from the light to this hit.
    pub(super) depth: u32,
    /// May spawn a ray (non-zero output, below the depth limit).
    pub(super) spawn: bool,
    /// Cell of the pooled-importance grid (0 without one).
    pub(super) cell: u32,
}

/// One independent population with its films.
#[derive(Clone, Debug)]
pub(super) struct Lane {
    pub(super) hits: Vec<Hit>,
    /// Prefix sums of the hits' selection weights (zero for hits that cannot
    /// spawn), for selection by binary search.
    pub(super) cum: Vec<f64>,
    /// Σ out_lum over the hits that can spawn, in stored units.
    pub(super) reflected: f64,
    /// The lazy power factor: actual power = σ · stored power.
    pub(super) sigma: f64,
    /// Iteration index m of the last step.
    pub(super) m: u64,
    /// Steps taken in the current phase.
    pub(super) in_phase: u32,
    /// Phases completed, and those averaged into `hit_film`.
    pub(super) phases: u64,
    pub(super) counted: u64,
    /// Steps taken (the lights' image is averaged over them).
    pub(super) steps: u64,
    /// The lights' image, Σ over steps of the emission-vertex splats.
    pub(super) le_film: Film,
    /// Σ over the counted phases of the hits' image.
    pub(super) hit_film: Film,
    /// The pooled-importance grid (`--variant pooled` only).
    pub(super) grid: Option<ImportanceGrid>,
}

impl Lane {
    pub(super) fn new(w: u32, h: u32, grid: Option<ImportanceGrid>) -> Self {
        Lane {
            grid,
            hits: Vec::new(),
            cum: Vec::new(),
            reflected: 0.0,
            sigma: 1.0,
            m: 0,
            in_phase: 0,
            phases: 0,
            counted: 0,
            steps: 0,
            le_film: Film::new(w, h),
            hit_film: Film::new(w, h),
        }
    }

    fn push(&mut self, hit: Hit) {
        let w = if hit.spawn { hit.s } else { 0.0 };
        if hit.spawn {
            self.reflected += hit.out_lum as f64;
        }
        self.cum.push(self.cum.last().copied().unwrap_or(0.0) + w);
        self.hits.push(hit);
    }

    /// Rebuilds the prefix sums and Σ out_lum after the purge.
    pub(super) fn rebuild(&mut self) {
        self.cum.clear();
        self.reflected = 0.0;
        let mut acc = 0.0;
        for h in &self.hits {
            if h.spawn {
                acc += h.s;
                self.reflected += h.out_lum as f64;
            }
            self.cum.push(acc);
        }
    }
}

/// One step of `Iterate` (§3), ending the phase when it is full. Returns the
/// rays traced.
pub(super) fn iterate(world: &World, s: &Settings, rng: &mut Pcg32, lane: &mut Lane) -> u64 {
    let max_depth = s.max_depth.unwrap_or(u32::MAX);
    let mut rays = 0;
    let m = lane.m + 1;
    lane.m = m;
    lane.steps += 1;

    // Select the lights or hit i: the lights by their share of the power of
    // L_{m−1} (§3), the hits in proportion to their importance (§3.1)
    let phi_e = world.lights.total_power();
    let w_hits = lane.cum.last().copied().unwrap_or(0.0);
    let refl = lane.sigma * lane.reflected;
    let p_light = if w_hits > 0.0 && refl > 0.0 {
        phi_e / (phi_e + refl)
    } else {
        1.0
    };
    let u = rng.next_f64();
    let mut shot: Option<(Ray, Rgb, u32, u32)> = None; // ray, Φ, parent, depth
    if u < p_light {
        // Sample the light source: Φ = Le cos θ / p_e / (1 − Σs_i)
        let (u_sel, u_pos, u_dir) = (rng.next_f32(), rng.next_2d(), rng.next_2d());
        if let Some(es) = world
            .lights
            .sample_emission(&world.scene, u_sel, u_pos, u_dir)
        {
            let inv_p = (1.0 / p_light) as f32;
            if !es.is_env {
                rays += connect_emission(world, es.p, es.n, es.phi_pos * inv_p, &mut lane.le_film);
            }
            let ray = es.ray();
            shot = Some((ray, es.phi * inv_p, NO_PARENT, 1));
        }
    } else {
        // Select hit i with s_i = (1 − P(light)) w_i / Σw, then sample a
        // direction from its cosine-weighted BSDF:
        // Φ = Φ_i f cos θ / p / s_i
        let t = rng.next_f64() * w_hits;
        let i = lane
            .cum
            .partition_point(|&c| c <= t)
            .min(lane.hits.len() - 1);
        let h = &lane.hits[i];
        let s_i = (1.0 - p_light) * h.s / w_hits;
        if s_i > 0.0 {
            let v = Vertex::new(world, h.sp, h.wo);
            if let Some((wi, w)) = scatter(&v, rng) {
                let phi = h.phi * w * (lane.sigma / s_i) as f32;
                let ray = Ray::new(offset_point(h.sp.p, h.sp.ng, wi), wi);
                shot = Some((ray, phi, i as u32, h.depth + 1));
            }
        }
    }

    // Multiply every stored power by (1 − 1/m), lazily through σ
    if m == 1 {
        lane.hits.clear();
        lane.cum.clear();
        lane.reflected = 0.0;
        lane.sigma = 1.0;
    } else {
        lane.sigma *= 1.0 - 1.0 / m as f64;
    }

    // Trace, and append the new hit with power Φ/m
    if let Some((ray, phi, parent, depth)) = shot {
        let stored = phi * (1.0 / (m as f64 * lane.sigma)) as f32;
        let before = lane.hits.len();
        rays += trace(world, ray, stored, parent, depth, max_depth, rng, lane);
        // Pooled importance: the image impact per unit power of where the
        // ray from the parent's cell landed (0 if it added no visible hit)
        if let Some(g) = lane.grid.as_mut().filter(|_| parent != NO_PARENT) {
            let r = lane.hits.get(before).map_or(0.0, |c| {
                let l = luminance(c.phi) as f64;
                if l > 0.0 {
                    luminance(c.contrib).max(0.0) as f64 / l
                } else {
                    0.0
                }
            });
            g.record(lane.hits[parent as usize].cell, r);
        }
    }

    lane.in_phase += 1;
    if lane.in_phase >= s.phase_len {
        end_phase(s, rng, lane);
    }
    rays
}

/// Sends stored power `phi` along `ray`, through delta chains
/// ([`follow_delta_chain`]), and appends the first non-delta hit with its
/// camera connection. Returns the rays.
#[allow(clippy::too_many_arguments)]
fn trace(
    world: &World,
    ray: Ray,
    phi: Rgb,
    parent: u32,
    depth: u32,
    max_depth: u32,
    rng: &mut Pcg32,
    lane: &mut Lane,
) -> u64 {
    let mut rays = 0;
    let Some(Landing {
        vertex: v,
        phi,
        depth,
    }) = follow_delta_chain(world, ray, phi, depth, rng, &mut rays)
    else {
        return rays;
    };

    // The hit's image contribution, eq. (8), made once (deterministic)
    let mut contrib = Rgb::ZERO;
    let mut pix = Vec2::ZERO;
    if depth < max_depth && v.bsdf.has_smooth() {
        if let Some((p, c)) = connect_to_camera(world, &v, phi, &mut rays) {
            contrib = c;
            pix = p;
        }
    }
    // The potential impact, eq. (9): Φ a g*(x), g* = f²/(|x − eye|² 4π S_p)
    let sp = v.sp;
    let a = v.bsdf.albedo(v.wo_local);
    let out_lum = luminance(phi * a).max(0.0);
    let r2 = (sp.p - world.camera.position()).length_squared().max(1e-12);
    let g_star = world.camera.pixels_per_area() / (r2 * 4.0 * std::f32::consts::PI);
    let spawn = out_lum > 0.0 && depth.saturating_add(1) < max_depth && out_lum.is_finite();
    if !(phi.is_finite() && out_lum.is_finite()) {
        return rays;
    }
    let (cell, s) = match &lane.grid {
        Some(g) => {
            let cell = g.cell(sp.p);
            (cell, out_lum as f64 * g.weight(cell))
        }
        None => (0, (out_lum * g_star) as f64),
    };
    lane.push(Hit {
        sp,
        wo: v.wo,
        phi,
        out_lum,
        g_star,
        contrib,
        pix,
        nchild: 0,
        s,
        parent,
        depth,
        spawn,
        cell,
    });
    rays
}
