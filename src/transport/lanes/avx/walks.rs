//! `light --variant walk`'s Sobol walks eight at a time ([`light_walks`]):
//! the emission from triangle lights and its camera connection, and the
//! common vertex (a diffuse BSDF below the depth limit), joined to the
//! camera and scattered, run in lanes, with the scalar operations in their
//! order (`Lights::sample_emission`, `emission_to_camera`,
//! [`crate::camera::Camera::project`], `connect_then`, `scatter` of Diffuse
//! in importance mode and the albedo's roulette of `LightWalk::step`), so a
//! walk's splats and rays are the same bits as [`light_tracing_walk`]'s.
//! Every other vertex takes `LightWalk::step` itself. No `unsafe` here:
//! the intrinsics are in the helpers of the parent module, whose contract
//! this entry keeps (compiled for AVX2, called where the CPU has it).
//!
//! Each walk's splats are held until the walks begun before it have ended,
//! then added in walk order: the film's sums are those of the walks run one
//! after another.
//!
//! [`light_tracing_walk`]: crate::transport::light_tracing_walk

use std::collections::VecDeque;
use std::ops::{ControlFlow, Range};

use glam::Vec2;

use super::{
    axis, cosine_sample, frame, gather_lights, lane_hits, lanes, lerp, offset, put, shade,
    surface_points, tangents, Frame8, Lanes, Shaded, SobolLanes, Surface, NO_LIGHT, V, V3,
};
use crate::accel::Hit;
use crate::camera::Camera;
use crate::emitter::TriLight;
use crate::film::Film;
use crate::geometry::Ray;
use crate::sampling::{Sampler, SobolWalkSampler};
use crate::scene::Rgb;
use crate::transport::lanes::LANES;
use crate::transport::{
    connect_to_camera, emission_sample_to_camera, LightWalk, Roulette, Spectrum, WalkKind,
};
use crate::world::World;

/// A splat held back: the film position and the contribution.
type Splat = (Vec2, Rgb);

/// The splats of the walks begun and not yet added to the film, in walk
/// order.
struct Pending {
    /// Walk `first`'s splats at the front; None while a walk runs.
    walks: VecDeque<Option<Vec<Splat>>>,
    /// The oldest walk not yet added.
    first: u64,
    /// Emptied buffers, for the walks to come.
    spare: Vec<Vec<Splat>>,
}

impl Pending {
    /// Walk `k`, the next in order, begins; an empty buffer for its splats.
    fn begin(&mut self, k: u64) -> Vec<Splat> {
        debug_assert_eq!(k, self.first + self.walks.len() as u64);
        self.walks.push_back(None);
        self.spare.pop().unwrap_or_default()
    }

    /// Walk `k` ended with `splats`; adds to `film` those of every ended
    /// walk that no running walk precedes.
    fn end(&mut self, k: u64, splats: Vec<Splat>, film: &mut Film) {
        self.walks[(k - self.first) as usize] = Some(splats);
        while let Some(Some(_)) = self.walks.front() {
            let Some(Some(mut s)) = self.walks.pop_front() else {
                unreachable!()
            };
            for &(pix, c) in &s {
                film.splat_soon(pix.x, pix.y, c);
            }
            s.clear();
            self.spare.push(s);
            self.first += 1;
        }
    }
}

/// The state of eight walks ([`LightWalk`]), by field.
struct Walks {
    o: [[f32; LANES]; 3],
    d: [[f32; LANES]; 3],
    beta: [[f32; LANES]; 3],
    /// The power each walk was emitted with (for [`Roulette::Throughput`]).
    emitted: [[f32; LANES]; 3],
    depth: [u32; LANES],
    /// Each lane's walk index.
    k: [u64; LANES],
    /// Each lane's walk's [`SobolWalkSampler`].
    rngs: SobolLanes,
    splats: [Vec<Splat>; LANES],
}

impl Walks {
    /// Walk `i` as a [`LightWalk`] with `roulette`.
    #[inline(always)]
    fn get(&self, i: usize, max_depth: u32, roulette: Roulette) -> LightWalk {
        let ray = Ray::new(V3::lane(&self.o, i), V3::lane(&self.d, i));
        let beta = V3::lane(&self.beta, i);
        let mut w = LightWalk::new(ray, beta, Spectrum::Rgb, roulette, None);
        w.emitted = V3::lane(&self.emitted, i);
        (w.depth, w.max_depth) = (self.depth[i], max_depth);
        w
    }

    /// Sets walk `i` to `w`.
    #[inline(always)]
    fn set(&mut self, i: usize, w: &LightWalk) {
        V3::set(&mut self.o, i, w.ray.o);
        V3::set(&mut self.d, i, w.ray.d);
        V3::set(&mut self.beta, i, w.beta);
        V3::set(&mut self.emitted, i, w.emitted);
        self.depth[i] = w.depth;
    }
}

/// [`crate::transport::lanes::light_walks`] in AVX lanes.
#[target_feature(enable = "avx2")]
pub(in crate::transport::lanes) fn light_walks(
    world: &World,
    walk: &WalkKind,
    seed: u64,
    pass: u64,
    walks: Range<u64>,
    film: &mut Film,
) -> u64 {
    let mut w = Walks {
        o: [[0.0; LANES]; 3],
        d: [[0.0; LANES]; 3],
        beta: [[0.0; LANES]; 3],
        emitted: [[0.0; LANES]; 3],
        depth: [0; LANES],
        k: [0; LANES],
        rngs: SobolLanes::walks(),
        splats: std::array::from_fn(|_| Vec::new()),
    };
    let mut pending = Pending {
        walks: VecDeque::new(),
        first: walks.start,
        spare: Vec::new(),
    };
    let mut rays = 0u64;
    let mut next = walks.start;
    let mut alive = 0u32;
    let mut found = [None; LANES];
    loop {
        // The free lanes begin the next walks
        let mut fresh = 0u32;
        for i in lanes(!alive & ((1 << LANES) - 1)) {
            if next == walks.end {
                break;
            }
            w.k[i] = next;
            w.splats[i] = pending.begin(next);
            w.rngs
                .set(i, SobolWalkSampler::new(seed, pass, next).sampler());
            fresh |= 1 << i;
            next += 1;
        }
        if fresh != 0 {
            let left = begin(world, &mut w, fresh, &mut rays);
            for i in lanes(fresh & !left) {
                pending.end(w.k[i], std::mem::take(&mut w.splats[i]), film);
            }
            alive |= left;
        }
        if alive == 0 {
            if next == walks.end {
                return rays;
            }
            continue;
        }
        rays += u64::from(alive.count_ones());
        world.accel.intersect_lanes(&w.o, &w.d, alive, &mut found);
        let mut hit = 0u32;
        for i in lanes(alive) {
            hit |= u32::from(found[i].is_some()) << i;
        }
        let goes_on = if alive & hit != 0 {
            vertices(world, walk, &mut w, &found, alive & hit, &mut rays)
        } else {
            0
        };
        for i in lanes(alive & !goes_on) {
            pending.end(w.k[i], std::mem::take(&mut w.splats[i]), film);
        }
        alive = goes_on;
    }
}

/// Begins the walks of `fresh`, as `light_tracing_walk` does: the emission
/// samples and those points' camera connections; returns the lanes whose
/// walk leaves a light. Where every light is a triangle, in lanes
/// (`Lights::sample_emission`'s triangle branch and `emission_to_camera`,
/// their operations in order); otherwise lane by lane.
#[inline(always)]
fn begin(world: &World, w: &mut Walks, fresh: u32, rays: &mut u64) -> u32 {
    let lights = &world.lights;
    if !lights.triangles_only() {
        let mut left = 0;
        for i in lanes(fresh) {
            let mut rng = SobolWalkSampler::from_sampler(w.rngs.get(i));
            let (u_sel, u_pos, u_dir) = (rng.next_f32(), rng.next_2d(), rng.next_2d());
            w.rngs.set(i, rng.sampler());
            let Some(es) = lights.sample_emission(u_sel, u_pos, u_dir) else {
                continue;
            };
            if let Some(s) = emission_sample_to_camera(world, &es, rays) {
                w.splats[i].push(s);
            }
            let ray = es.ray();
            V3::set(&mut w.o, i, ray.o);
            V3::set(&mut w.d, i, ray.d);
            V3::set(&mut w.beta, i, es.phi);
            V3::set(&mut w.emitted, i, es.phi);
            w.depth[i] = 1;
            left |= 1 << i;
        }
        return left;
    }
    let [u_sel, ux, uy, dx, dy] = w.rngs.walk_emission(fresh);
    let u_sel = V(u_sel).store();
    let mut light: [&TriLight; LANES] = [&NO_LIGHT; LANES];
    let mut pmf = [0.0f32; LANES];
    let mut left = 0u32;
    for i in lanes(fresh) {
        if let Some((tl, pm)) = lights.emission_tri(u_sel[i]) {
            (light[i], pmf[i]) = (tl, pm);
            left |= 1 << i;
        }
    }
    if left == 0 {
        return 0;
    }
    let ls = gather_lights(&light, left, pmf);
    let (one, zero) = (V::splat(1.0), V::splat(0.0));
    // uniform_triangle, then the point
    let su = V(ux).sqrt();
    let (bx, by) = (one - su, V(uy) * su);
    let b0 = one - bx - by;
    let [qa, qb, qc] = ls.q;
    let p = V3::new(
        lerp(qa.x, qb.x, qc.x, b0, bx, by),
        lerp(qa.y, qb.y, qc.y, b0, bx, by),
        lerp(qa.z, qb.z, qc.z, b0, bx, by),
    );
    // Frame::from_normal(n).to_world(cosine_hemisphere(u_dir))
    let (fs, ft) = tangents(ls.n);
    let fr = Frame8 {
        fs,
        ft,
        fn_: ls.n,
        wo: ls.n,
        ng_o: ls.n,
    };
    let (_, _, d) = cosine_sample(&fr, [V(dx), V(dy)]);
    let pdf_pos = V::load(&ls.pmf) / ls.area;
    let k = V::splat(std::f32::consts::PI) / pdf_pos;
    let phi = V3::new(ls.le.x * k, ls.le.y * k, ls.le.z * k);
    let phi_pos = V3::new(ls.le.x / pdf_pos, ls.le.y / pdf_pos, ls.le.z / pdf_pos);
    // emission_to_camera: the point seen from the pinhole, facing it
    let cam = &world.camera;
    let (ok, px, py, g) = project(cam, p);
    let origin = V3::splat(cam.origin);
    let dc = V3::new(origin.x - p.x, origin.y - p.y, origin.z - p.z);
    let cos = dc.dot(ls.n) / dc.dot(dc).sqrt();
    let ok = (ok & cos.nle(zero)).bits() & left;
    if ok != 0 {
        *rays += u64::from(ok.count_ones());
        let from = offset(p, ls.n, dc).store();
        let clear = ok & !world.accel.occluded_lanes(&from, &origin.store(), ok);
        let kc = cos * g;
        let c = V3::new(phi_pos.x * kc, phi_pos.y * kc, phi_pos.z * kc).store();
        let (px, py) = (px.store(), py.store());
        for i in lanes(clear) {
            w.splats[i].push((Vec2::new(px[i], py[i]), V3::lane(&c, i)));
        }
    }
    // es.ray(): the point moved off the light, the direction
    let m = V::mask(left);
    put(&mut w.o, m, offset(p, ls.n, d));
    put(&mut w.d, m, d);
    put(&mut w.beta, m, phi);
    put(&mut w.emitted, m, phi);
    for i in lanes(left) {
        w.depth[i] = 1;
    }
    left
}

/// `Camera::project` of eight points: the lanes that land on the film,
/// their film position and their pixel weight g.
#[inline(always)]
fn project(cam: &Camera, p: V3) -> (V, V, V, V) {
    let (zero, one) = (V::splat(0.0), V::splat(1.0));
    // glam's transform_point3: x, then y added, then z, then w
    let m = &cam.to_camera;
    let (ax, ay, az, aw) = (
        axis(m.x_axis),
        axis(m.y_axis),
        axis(m.z_axis),
        axis(m.w_axis),
    );
    let pc = V3::new(
        aw.x + (az.x * p.z + (ay.x * p.y + ax.x * p.x)),
        aw.y + (az.y * p.z + (ay.y * p.y + ax.y * p.x)),
        aw.z + (az.z * p.z + (ay.z * p.y + ax.z * p.x)),
    );
    let mut ok = pc.z.nle(V::splat(cam.near)) & pc.z.nle(zero);
    let half = V::splat(0.5);
    let sx = half * (one - pc.x / (pc.z * V::splat(cam.tan_half.x)));
    let sy = half * (one - pc.y / (pc.z * V::splat(cam.tan_half.y)));
    ok = ok & sx.ge(zero) & sx.lt(one) & sy.ge(zero) & sy.lt(one);
    let origin = V3::splat(cam.origin);
    let d = V3::new(p.x - origin.x, p.y - origin.y, p.z - origin.z);
    let r2 = d.dot(d);
    let cos_c = d.dot(V3::splat(cam.forward)) / r2.sqrt();
    ok = ok & cos_c.nle(zero);
    let g = V::splat(cam.pixels_per_area()) / (cos_c * cos_c * cos_c * r2);
    let px = sx * V::splat(cam.width as f32);
    let py = sy * V::splat(cam.height as f32);
    (ok, px, py, g)
}

/// One vertex of each walk of `mask`, whose rays hit at `hits`; returns
/// the walks that go on.
#[inline(always)]
fn vertices(
    world: &World,
    walk: &WalkKind,
    w: &mut Walks,
    hits: &[Option<Hit>; LANES],
    mask: u32,
    rays: &mut u64,
) -> u32 {
    let lh = lane_hits(hits, mask);
    let sp = surface_points(world.tris.records(), &lh);
    // The common case: measured and scattered (depth + 1 below the limit)
    let max_depth = walk.max_depth.unwrap_or(u32::MAX);
    let mut common = 0u32;
    for i in lanes(mask) {
        common |= u32::from(w.depth[i] + 1 < max_depth) << i;
    }
    let mut sh = shade(world, &lh, &sp, mask, common);
    // Every other vertex takes the scalar step
    for i in lanes(mask & !sh.vec) {
        let mut lw = w.get(i, max_depth, walk.roulette);
        let splats = &mut w.splats[i];
        let split = walk.glossy_split;
        let on_vertex = |e: &crate::transport::LightVertex| {
            if e.vertex.bsdf.has_smooth() {
                if let Some(s) = connect_to_camera(world, e.vertex, e.beta, split, rays) {
                    splats.push(s);
                }
            }
            ControlFlow::Continue(())
        };
        let mut rng = SobolWalkSampler::from_sampler(w.rngs.get(i));
        if lw.step(world, &lh[i], &mut rng, on_vertex) {
            w.set(i, &lw);
        } else {
            sh.alive &= !(1 << i);
        }
        w.rngs.set(i, rng.sampler());
    }
    if sh.vec == 0 {
        return sh.alive;
    }
    let fr = frame(&sh, sp.ng, V3::load(&w.d).neg());
    to_camera(world, w, &sp, &sh, &fr, rays);
    scatter(w, walk.roulette, &sp, &sh, &fr)
}

/// Joins the vertices of `sh.vec` to the camera (`connect_then` of a
/// Diffuse BSDF after `Camera::project`), traces the visibility rays of
/// those that give light, and holds the splats of the clear ones.
#[inline(always)]
fn to_camera(world: &World, w: &mut Walks, sp: &Surface, sh: &Shaded, fr: &Frame8, rays: &mut u64) {
    let cam: &Camera = &world.camera;
    let (zero, one) = (V::splat(0.0), V::splat(1.0));
    let p = sp.p;
    let (mut ok, px, py, g) = project(cam, p);
    let origin = V3::splat(cam.origin);
    // connect_then: the direction to the eye, on the side the BSDF says
    let dc = V3::new(origin.x - p.x, origin.y - p.y, origin.z - p.z);
    let dist = dc.dot(dc).sqrt();
    let wc = V3::new(dc.x / dist, dc.y / dist, dc.z / dist);
    let wi_z = wc.dot(fr.fn_);
    ok = ok & (wc.dot(fr.ng_o) * wi_z).nle(zero);
    // Diffuse's f in importance mode: r / π on the upper side
    let wol_z = fr.wo.dot(fr.fn_);
    let up = wol_z.nle(zero) & wi_z.nle(zero);
    let r = V3::load(&sh.r);
    let k_pi = V::splat(std::f32::consts::FRAC_1_PI);
    let f = V3::new(
        up.select(r.x * k_pi, zero),
        up.select(r.y * k_pi, zero),
        up.select(r.z * k_pi, zero),
    );
    ok = ok & !(f.x.eq(zero) & f.y.eq(zero) & f.z.eq(zero));
    // shading_normal_correction_over(wo, wc, ng, ns, 1)
    let num = fr.wo.dot(fr.fn_).abs() * wc.dot(fr.ng_o).abs();
    let den = fr.wo.dot(fr.ng_o).abs() * one;
    let k = (den.gt(zero) & num.finite()).select(num / den, zero);
    let kg = k * g;
    let phi = V3::load(&w.beta);
    let c = V3::new(phi.x * f.x * kg, phi.y * f.y * kg, phi.z * f.z * kg);
    let finite = c.x.finite() & c.y.finite() & c.z.finite();
    ok = ok & finite & !(c.x.eq(zero) & c.y.eq(zero) & c.z.eq(zero));
    let ok = ok.bits() & sh.vec;
    if ok == 0 {
        return;
    }
    *rays += u64::from(ok.count_ones());
    let from = offset(p, fr.ng_o, wc).store();
    let eye = origin.store();
    let clear = ok & !world.accel.occluded_lanes(&from, &eye, ok);
    let (px, py, c) = (px.store(), py.store(), c.store());
    for i in lanes(clear) {
        w.splats[i].push((Vec2::new(px[i], py[i]), V3::lane(&c, i)));
    }
}

/// Russian roulette (`roulette`) and the next segment by `scatter` of a
/// Diffuse BSDF in importance mode, for the vertices of `sh.vec`, as
/// `LightWalk::step` plays them; returns the walks that go on.
#[inline(always)]
fn scatter(w: &mut Walks, roulette: Roulette, sp: &Surface, sh: &Shaded, fr: &Frame8) -> u32 {
    let zero = V::splat(0.0);
    // The lanes' numbers: the roulette's, the lobe's, the direction's
    let [u_rr, _lobe, u0, u1] = w.rngs.walk_vertex(sh.vec, &w.depth).map(V);
    let r = V3::load(&sh.r);
    // Diffuse::sample, then scatter's checks and weight
    let wol_z = fr.wo.dot(fr.fn_);
    let (z, spdf, wiw) = cosine_sample(fr, [u0, u1]);
    let side = wol_z.nle(zero)
        & spdf.nle(zero)
        & (wiw.dot(fr.ng_o) * z).nle(zero)
        & (fr.wo.dot(fr.ng_o) * wol_z).nle(zero);
    let num = fr.wo.dot(fr.fn_).abs() * wiw.dot(fr.ng_o).abs();
    let den = fr.wo.dot(fr.ng_o).abs() * spdf;
    let k = (den.gt(zero) & num.finite()).select(num / den, zero);
    let k_pi = V::splat(std::f32::consts::FRAC_1_PI);
    let wt = V3::new(r.x * k_pi * k, r.y * k_pi * k, r.z * k_pi * k);
    let w_ok = k.ne(zero) & wt.x.finite() & wt.y.finite() & wt.z.finite();
    let beta = V3::load(&w.beta);
    // The roulette's probability of going on
    let q = match roulette {
        Roulette::Albedo => {
            // the albedo's largest channel, clamped to [0, 0.99]
            let m = r.y.gt(r.z).select(r.y, r.z);
            let m = r.x.gt(m).select(r.x, m);
            m.lt(zero)
                .select(zero, m.gt(V::splat(0.99)).select(V::splat(0.99), m))
        }
        Roulette::Throughput => {
            // relative_throughput(β w, β0), then min(·, 0.95)
            let e = V3::load(&w.emitted);
            let mut q = zero;
            for (b, w, e) in [
                (beta.x, wt.x, e.x),
                (beta.y, wt.y, e.y),
                (beta.z, wt.z, e.z),
            ] {
                q = e.gt(zero).select((b * w / e).max(q), q);
            }
            q.min(V::splat(0.95))
        }
    };
    let survive = !u_rr.ge(q);
    let nb = V3::new(
        beta.x * (wt.x / q),
        beta.y * (wt.y / q),
        beta.z * (wt.z / q),
    );
    let mb = nb.y.gt(nb.z).select(nb.y, nb.z);
    let mb = nb.x.gt(mb).select(nb.x, mb);
    let b_ok = mb.gt(zero) & nb.x.finite() & nb.y.finite() & nb.z.finite();
    let on = (survive & side & w_ok & b_ok).bits() & sh.vec;
    let m = V::mask(on);
    put(&mut w.o, m, offset(sp.p, sp.ng, wiw));
    put(&mut w.d, m, wiw);
    put(&mut w.beta, m, nb);
    for i in lanes(on) {
        w.depth[i] += 1;
    }
    (sh.alive & !sh.vec) | on
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Walks that end out of order are added in walk order: three splats
    /// into one pixel whose f64 sum depends on the order (1 − 1 + 10⁻¹⁷
    /// is 10⁻¹⁷; 10⁻¹⁷ − 1 + 1 is 0).
    #[test]
    fn pending_adds_the_walks_in_walk_order() {
        let mut film = Film::new(1, 1);
        let mut p = Pending {
            walks: VecDeque::new(),
            first: 7,
            spare: Vec::new(),
        };
        let mut bufs: Vec<Vec<Splat>> = (7..10).map(|k| p.begin(k)).collect();
        let at = Vec2::new(0.5, 0.5);
        for (b, v) in bufs.iter_mut().zip([1.0f32, -1.0, 1e-17]) {
            b.push((at, Rgb::splat(v)));
        }
        let mut bufs = bufs.into_iter();
        let (b7, b8, b9) = (bufs.next(), bufs.next(), bufs.next());
        p.end(9, b9.unwrap(), &mut film);
        p.end(8, b8.unwrap(), &mut film);
        assert_eq!(film.sum[0].x, 0.0, "a walk added before walk 7 ended");
        p.end(7, b7.unwrap(), &mut film);
        assert_eq!(film.sum[0].x, 1e-17f32 as f64);
        assert!(p.walks.is_empty() && p.first == 10);
    }
}
