//! The iteration of §3 (`Iterate`): one step selects the lights or a hit,
//! shoots or reflects a ray with the listing's power weights, scales the
//! population by (1 − 1/m) through the lane's σ, and appends the new hit.
//! A [`Lane`] is one population with its films.

use glam::Vec2;

use std::sync::Arc;

use super::guide::{emit_guided, scatter_guided, DirGuide, DirRecord};
use super::importance::{ImportanceGrid, LIGHT_SLOT};
use super::purge::{end_phase, Scratch};
use super::{Measure, Settings, Variant};
use crate::film::Film;
use crate::geometry::{offset_point, Ray};
use crate::methods::World;
use crate::sampling::Pcg32;
use crate::scene::{luminance, Rgb};
use crate::simd::dispatched;
use crate::transport::{
    connect_emission_sample, connect_then, follow_delta_chain, Landing, Vertex,
};

/// No parent: the hit was shot from a light.
pub(super) const NO_PARENT: u32 = u32::MAX;

/// A photon hit, the record of §5: what every form reads. Powers are
/// stored in units of the lane's σ (actual power = σ · `phi`), and so are
/// `out_lum` and `s`.
///
/// 64 bytes, one cache line: the surface point is not kept (76 bytes) but
/// rebuilt from the triangle and barycentrics when the hit spawns, by the
/// function that built it at the landing ([`World::surface_point`]), so to
/// the same bits; and what only the paper's importance and the phase
/// images read is kept apart, in [`Measured`], by the forms that read it.
#[derive(Clone, Copy, Debug)]
pub(super) struct Hit {
    /// Triangle of the landing.
    pub(super) tri: u32,
    /// Barycentrics of the landing on `tri`.
    pub(super) b1: f32,
    pub(super) b2: f32,
    /// Incoming direction, reversed (toward where the power came from).
    pub(super) wo: glam::Vec3,
    /// Incoming power, RGB.
    pub(super) phi: Rgb,
    /// Output luminance: Lum(Φ · a(ω_in)).
    pub(super) out_lum: f32,
    /// Importance (unnormalised hit-selection weight).
    pub(super) s: f64,
    /// Segments from the light to this hit.
    pub(super) depth: u32,
    /// Cell of the pooled-importance grid (0 without one).
    pub(super) cell: u32,
    /// May spawn a ray (non-zero output, below the depth limit).
    pub(super) spawn: bool,
}

/// The part of a hit's record that only the paper's `ComputeImportance`
/// (eqs. (8), (9)) and the phase images (`--measure phase`) read, kept
/// beside the population ([`Lane::measured`], same order) by the forms that
/// read it ([`Form::measured`]). `contrib` is in units of σ, as the powers.
#[derive(Clone, Copy, Debug)]
pub(super) struct Measured {
    /// Image contribution Φ f cos θ g(x) (eq. (8)), zero when hidden.
    pub(super) contrib: Rgb,
    /// Film position of the contribution.
    pub(super) pix: Vec2,
    /// g*(x) of eq. (9): f² / (|x − eye|² 4π S_p).
    pub(super) g_star: f32,
    /// Index of the parent hit, or [`NO_PARENT`].
    pub(super) parent: u32,
    /// Number of children in the population.
    pub(super) nchild: u32,
}

const _: () = assert!(std::mem::size_of::<Hit>() == 64);
const _: () = assert!(std::mem::size_of::<Measured>() == 32);

/// One independent population with its films.
#[derive(Clone, Debug)]
pub(super) struct Lane {
    pub(super) hits: Vec<Hit>,
    /// The hits' [`Measured`] parts, in the same order, when the form
    /// reads them (else empty).
    pub(super) measured: Vec<Measured>,
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
    /// Steps whose new hits were measured at birth (`--measure birth`):
    /// the hits' image is averaged over them.
    pub(super) born: u64,
    /// The lights' image, Σ over steps of the emission-vertex splats.
    pub(super) le_film: Film,
    /// Σ over the counted phases of the hits' image.
    pub(super) hit_film: Film,
    /// The pooled-importance grid (`--variant pooled` and `guided`).
    pub(super) grid: Option<ImportanceGrid>,
    /// This lane's directional records since the last merge (guided only).
    pub(super) dirs: Option<Vec<DirRecord>>,
    /// The directional densities of this pass (guided, after the first).
    pub(super) guide: Option<Arc<DirGuide>>,
    /// The purge's buffers.
    pub(super) scratch: Scratch,
}

impl Lane {
    pub(super) fn new(
        w: u32,
        h: u32,
        grid: Option<ImportanceGrid>,
        dirs: Option<Vec<DirRecord>>,
    ) -> Self {
        Lane {
            measured: Vec::new(),
            grid,
            dirs,
            guide: None,
            scratch: Scratch::default(),
            born: 0,
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

    #[inline(always)]
    fn push(&mut self, hit: Hit) {
        let w = if hit.spawn { hit.s } else { 0.0 };
        if hit.spawn {
            self.reflected += hit.out_lum as f64;
        }
        self.cum.push(self.cum.last().copied().unwrap_or(0.0) + w);
        self.hits.push(hit);
    }
}

/// The switches of one plb run, read once from its settings.
#[derive(Clone, Copy, Debug)]
pub(super) struct Form {
    /// `--variant guided`: landing values that count what the landing
    /// point passes on, guided directions, lights chosen by importance.
    pub(super) guided: bool,
    /// Hits measured at birth (else at every phase end).
    pub(super) birth: bool,
    /// The lane keeps the hits' [`Measured`] parts: the paper's importance
    /// or the phase images read them.
    pub(super) measured: bool,
    /// Camera connections carry the light side's MIS weight of the glossy
    /// camera pass (guided with the camera pass on).
    pub(super) glossy_split: bool,
    /// The longest path in segments (u32::MAX: unlimited).
    pub(super) max_depth: u32,
}

impl Form {
    pub(super) fn of(s: &Settings) -> Self {
        let birth = s.measure.unwrap_or(s.variant.default_measure()) == Measure::Birth;
        Form {
            guided: s.variant == Variant::Guided,
            birth,
            measured: !birth || s.variant == Variant::Paper,
            glossy_split: s.variant == Variant::Guided && s.camera_pass,
            max_depth: s.max_depth.unwrap_or(u32::MAX),
        }
    }
}

/// The lights' least share of the steps under `--variant guided`, as a
/// fraction of their share by power: importance may move the work to the
/// hits, but light keeps entering the population.
const LIGHT_FLOOR: f64 = 0.1;

/// Where a spawned or emitted ray came from, for the learnt statistics.
struct Source {
    /// Slot of the importance grid (the parent's cell, or the lights').
    slot: u32,
    /// Cell, direction and, when already computed, the direction's bin,
    /// for the directional histograms (guided only).
    dir: Option<(u32, glam::Vec3, Option<u32>)>,
}

dispatched! {
    /// `steps` steps of one lane ([`iterate`]); returns the rays traced. The
    /// per-pass loop that runtime dispatch compiles for x86-64-v3
    /// ([`crate::simd::dispatch`]), as light tracing's: the step, its trace
    /// and the phase end are inlined into it.
    pub(super) fn run_lane(
        world: &World,
        s: &Settings,
        rng: Pcg32,
        steps: u64,
        lane: &mut Lane,
    ) -> u64 {
        // A plain loop: an iterator adaptor would be a function of its own,
        // compiled for the baseline only
        let mut rng = rng;
        let mut rays = 0;
        for _ in 0..steps {
            rays += iterate(world, s, &mut rng, lane);
        }
        rays
    }
}

/// One step of `Iterate` (§3), ending the phase when it is full. Returns the
/// rays traced.
#[inline(always)]
pub(super) fn iterate(world: &World, s: &Settings, rng: &mut Pcg32, lane: &mut Lane) -> u64 {
    let form = Form::of(s);
    let mut rays = 0;
    let m = lane.m + 1;
    lane.m = m;
    lane.steps += 1;
    let counting = lane.phases >= s.discard;
    if form.birth && counting {
        lane.born += 1;
    }

    // Select the lights or hit i: the lights by their share of the power of
    // L_{m−1} (§3), the hits in proportion to their importance (§3.1).
    // Guided: the lights by their share of the importance, Φ_e W_e against
    // Σ s_i (W_e the value of the lights' own rays), floored
    let phi_e = world.lights.total_power();
    let w_hits = lane.cum.last().copied().unwrap_or(0.0);
    let refl = lane.sigma * lane.reflected;
    let p_light = if w_hits > 0.0 && refl > 0.0 {
        let by_power = phi_e / (phi_e + refl);
        match lane.grid.as_ref().filter(|_| form.guided) {
            Some(g) => {
                let le = phi_e * g.value(LIGHT_SLOT);
                let by_importance = le / (le + lane.sigma * w_hits);
                if by_importance.is_finite() {
                    by_importance.max(LIGHT_FLOOR * by_power)
                } else {
                    by_power
                }
            }
            None => by_power,
        }
    } else {
        1.0
    };
    let u = rng.next_f64();
    let mut shot: Option<(Ray, Rgb, u32, u32)> = None; // ray, Φ, parent, depth
    let mut source: Option<Source> = None;
    if u < p_light {
        // Sample the light source: Φ = Le cos θ / p_e / (1 − Σs_i)
        let (u_sel, u_pos, u_dir) = (rng.next_f32(), rng.next_2d(), rng.next_2d());
        if let Some(es) = world.lights.sample_emission(u_sel, u_pos, u_dir) {
            let inv_p = (1.0 / p_light) as f32;
            rays += connect_emission_sample(world, &es, inv_p, &mut lane.le_film);
            // Guided emission replaces an area light's cosine lobe; punctual
            // lights keep their own directions
            let area = !es.is_env && es.punctual == u32::MAX;
            match (form.guided, lane.grid.as_ref(), lane.guide.as_deref()) {
                (true, Some(grid), Some(guide)) if area => {
                    // A guided direction: Φ = Le cos θ / (p_pos p(ω))
                    let cell = grid.cell(es.p);
                    let (d, k, bin) = emit_guided(es.n, es.d, guide, cell, rng);
                    source = Some(Source {
                        slot: LIGHT_SLOT,
                        dir: Some((cell, d, bin)),
                    });
                    if k > 0.0 {
                        let ray = Ray::new(offset_point(es.p, es.n, d), d);
                        shot = Some((ray, es.phi_pos * (k * inv_p), NO_PARENT, 1));
                    }
                }
                _ => {
                    if form.guided {
                        source = Some(Source {
                            slot: LIGHT_SLOT,
                            dir: lane
                                .grid
                                .as_ref()
                                .filter(|_| area)
                                .map(|g| (g.cell(es.p), es.d, None)),
                        });
                    }
                    shot = Some((es.ray(), es.phi * inv_p, NO_PARENT, 1));
                }
            }
        }
    } else {
        // Select hit i with s_i = (1 − P(light)) w_i / Σw, then sample a
        // direction from its cosine-weighted BSDF (guided: from the
        // mixture of `guide`): Φ = Φ_i f cos θ / p / s_i
        let t = rng.next_f64() * w_hits;
        let i = lane
            .cum
            .partition_point(|&c| c <= t)
            .min(lane.hits.len() - 1);
        let h = &lane.hits[i];
        let s_i = (1.0 - p_light) * h.s / w_hits;
        if s_i > 0.0 {
            let guide = lane.guide.as_deref().filter(|_| form.guided);
            if let Some(g) = guide {
                g.prefetch(h.cell);
            }
            let sp = world.tris.surface_point(&world.scene, h.tri, h.b1, h.b2);
            let v = Vertex::new(world, sp, h.wo);
            if let Some(g) = scatter_guided(&v, guide, h.cell, rng) {
                if lane.grid.is_some() {
                    source = Some(Source {
                        slot: h.cell,
                        dir: form.guided.then_some((h.cell, g.wi, g.bin)),
                    });
                }
                if g.w != Rgb::ZERO {
                    let phi = h.phi * g.w * (lane.sigma / s_i) as f32;
                    let ray = Ray::new(offset_point(sp.p, sp.ng, g.wi), g.wi);
                    shot = Some((ray, phi, i as u32, h.depth + 1));
                }
            }
        }
    }

    // Multiply every stored power by (1 − 1/m), lazily through σ
    if m == 1 {
        lane.hits.clear();
        lane.measured.clear();
        lane.cum.clear();
        lane.reflected = 0.0;
        lane.sigma = 1.0;
    } else {
        lane.sigma *= 1.0 - 1.0 / m as f64;
    }

    // Trace, and append the new hit with power Φ/m
    let mut born = None;
    if let Some((ray, phi, parent, depth)) = shot {
        let stored = phi * (1.0 / (m as f64 * lane.sigma)) as f32;
        // At birth the hit's power is Φ = stored · m σ
        let birth = (form.birth && counting).then_some((m as f64 * lane.sigma) as f32);
        born = trace(
            world, ray, stored, parent, depth, form, birth, rng, lane, &mut rays,
        );
    }
    if let Some(src) = source {
        learn(lane, form, src, born);
    }

    lane.in_phase += 1;
    if lane.in_phase >= s.phase_len {
        end_phase(s, form, rng, lane);
    }
    rays
}

/// Records what the ray from `src` brought back, per unit power, in the
/// learnt statistics (0 when it escaped, landed hidden, or was never
/// traced: `born` None).
#[inline(always)]
fn learn(lane: &mut Lane, form: Form, src: Source, born: Option<Born>) {
    let r = born.map_or(0.0, |c| landing_value(&c, lane.grid.as_ref(), form.guided));
    // Pooled records only the hits' rays; guided also the lights'
    if src.slot != LIGHT_SLOT || form.guided {
        if let Some(g) = lane.grid.as_mut() {
            g.record(src.slot, r);
        }
    }
    if let (Some((cell, d, bin)), Some(dirs)) = (src.dir, lane.dirs.as_mut()) {
        if let Some(rec) = DirRecord::new(cell, d, bin, r) {
            dirs.push(rec);
        }
    }
}

/// What [`landing_value`] reads of the hit a step appended (its
/// contribution is not in the population's record under every form).
#[derive(Clone, Copy, Debug)]
struct Born {
    phi: Rgb,
    contrib: Rgb,
    out_lum: f32,
    spawn: bool,
    cell: u32,
}

/// The value r of a landing hit `c`, per unit of the power that reached it:
/// the image impact of its camera connection (`--variant pooled`), plus,
/// guided, what its own spawned rays are expected to bring, its output
/// luminance times its cell's value W (so that a landing hidden from the
/// camera, behind the baffle say, is worth what it passes on).
fn landing_value(c: &Born, grid: Option<&ImportanceGrid>, guided: bool) -> f64 {
    let l = luminance(c.phi) as f64;
    if l <= 0.0 {
        return 0.0;
    }
    let mut v = luminance(c.contrib).max(0.0) as f64;
    if let Some(g) = grid.filter(|_| guided && c.spawn) {
        v += c.out_lum as f64 * g.value(c.cell);
    }
    v / l
}

/// Sends stored power `phi` along `ray`, through delta chains
/// ([`follow_delta_chain`]), and appends the first non-delta hit with its
/// camera connection; `birth` (the factor from stored to actual power) when
/// the hit is measured at birth. Adds the rays to `rays`; returns what
/// [`landing_value`] reads of the new hit, if one was appended.
#[allow(clippy::too_many_arguments)]
#[inline(always)]
fn trace(
    world: &World,
    ray: Ray,
    phi: Rgb,
    parent: u32,
    depth: u32,
    form: Form,
    birth: Option<f32>,
    rng: &mut Pcg32,
    lane: &mut Lane,
    rays: &mut u64,
) -> Option<Born> {
    let max_depth = form.max_depth;
    let landing = follow_delta_chain(world, ray, phi, depth, rng, rays)?;
    let Landing {
        vertex: ref v,
        hit,
        phi,
        depth,
    } = landing;

    // The hit's image contribution, eq. (8), made once (deterministic)
    let mut contrib = Rgb::ZERO;
    let mut pix = Vec2::ZERO;
    if depth < max_depth && v.bsdf.has_smooth() {
        // the film is splatted at birth only (the guided default)
        let film = &lane.hit_film;
        let seen = |p: Vec2| {
            if birth.is_some() {
                film.prefetch(p.x, p.y);
            }
        };
        if let Some((p, c)) = connect_then(world, v, phi, form.glossy_split, rays, seen) {
            contrib = c;
            pix = p;
        }
    }
    // The potential impact, eq. (9): Φ a g*(x), g* = f²/(|x − eye|² 4π S_p)
    let sp = &v.sp;
    let a = v.bsdf.albedo(v.wo_local);
    let out_lum = luminance(phi * a).max(0.0);
    let r2 = (sp.p - world.camera.position()).length_squared().max(1e-12);
    let g_star = world.camera.pixels_per_area() / (r2 * 4.0 * std::f32::consts::PI);
    let spawn = out_lum > 0.0 && depth.saturating_add(1) < max_depth && out_lum.is_finite();
    if !(phi.is_finite() && out_lum.is_finite()) {
        return None;
    }
    if let Some(k) = birth {
        if contrib != Rgb::ZERO {
            lane.hit_film.splat(pix.x, pix.y, contrib * k);
        }
    }
    let (cell, s) = match &lane.grid {
        Some(g) => {
            let cell = g.cell(sp.p);
            (cell, out_lum as f64 * g.weight(cell))
        }
        None => (0, (out_lum * g_star) as f64),
    };
    if form.measured {
        lane.measured.push(Measured {
            contrib,
            pix,
            g_star,
            parent,
            nchild: 0,
        });
    }
    lane.push(Hit {
        tri: hit.tri,
        b1: hit.b1,
        b2: hit.b2,
        wo: v.wo,
        phi,
        out_lum,
        s,
        depth,
        spawn,
        cell,
    });
    Some(Born {
        phi,
        contrib,
        out_lum,
        spawn,
        cell,
    })
}
