//! The bake, phase by phase (§3 of the paper; §4 for the implementation):
//!
//! 1. [`trace`]: particle tracing into a [`HitSink`] (§3.1, §4.1);
//! 2. [`group`]: the hits grouped by surface side (§4.2: "begins by sorting
//!    all hit points by surface id");
//! 3. [`estimate`]: per surface, the irradiance H by kernel density
//!    estimation on an over-mesh, streamed from a [`HitSource`] in chunks
//!    (§3.2, §4.2);
//! 4. [`decimate`]: the over-mesh decimated in (u, v, brightness) space
//!    against the white point of [`white_point`] (§3.3, §4.3).
//!
//! [`super::bake`] runs them in order; each is public so that a test, a
//! benchmark or a distributed runner can run one phase on its own.

use std::collections::HashMap;
use std::f32::consts::PI;
use std::time::Instant;

use glam::Vec3;
use rayon::prelude::*;

use super::control::{Control, Phase};
use super::decimate::{self as decimation, Report};
use super::hitfile::HitWriter;
use super::hits::{decode_rgb9e5, from_fixed, HitSink, HitSource, Run, HIT_BYTES};
use super::kernel::{self, Params, PlanarEstimator};
use super::mesh::{CurvedMesh, PlanarMesh};
use super::particles::{self, Channel};
use super::scratch::ScratchDir;
use super::surfaces::{Kind, SurfaceId, Surfaces};
use super::{DensityError, Settings, World};
use crate::scene::{luminance, Scene};

/// What phase 1 traced (its hits are in the sink).
#[derive(Clone, Copy, Debug, Default)]
pub struct Traced {
    /// Particles emitted (all channel runs).
    pub particles: u64,
    /// Hits recorded.
    pub hits: u64,
    /// Rays traced.
    pub rays: u64,
    /// φ = Φ/n, the power unit of the hit records (W).
    pub phi: f64,
}

/// The disk sink of a bake: bucket files in `scratch`, the hit file at
/// [`ScratchDir::hit_file`], buckets of about 32 MB of records, the bucket
/// sort in chunks of [`Settings::chunk_hits`].
pub fn file_sink(
    surfaces: &Surfaces,
    s: &Settings,
    scratch: &ScratchDir,
) -> Result<HitWriter, DensityError> {
    let n_expected_hits = s.particles.saturating_mul(4) * if s.per_channel { 3 } else { 1 };
    let buckets = (n_expected_hits * HIT_BYTES as u64 / (32 << 20)).clamp(1, 1024) as u32;
    let mut w = HitWriter::new(
        scratch.path(),
        scratch.hit_file(),
        surfaces.list.len() as u32,
        buckets,
    )?;
    w.sort_chunk = s.chunk_hits.max(1);
    Ok(w)
}

/// Phase 1 (§3.1, §4.1): traces n particles from the luminaires (three runs
/// of n, one per channel, with [`Settings::per_channel`]) and writes their
/// hits to `sink` in particle order.
pub fn trace(
    world: &World,
    surfaces: &Surfaces,
    s: &Settings,
    sink: &mut impl HitSink,
) -> Result<Traced, DensityError> {
    trace_within(world, surfaces, s, sink, &mut Control::none())
}

/// The particle tracers of a bake: one RGB run, or one per channel
/// (`--per-channel`); a channel whose luminaires emit nothing has none.
pub(super) fn tracers<'a>(
    world: &'a World,
    surfaces: &'a Surfaces,
    lums: &'a [particles::Luminaire],
    s: &Settings,
) -> Vec<particles::Tracer<'a>> {
    let channels: Vec<Channel> = if s.per_channel {
        (0..3).map(Channel::Single).collect()
    } else {
        vec![Channel::Rgb]
    };
    channels
        .into_iter()
        .filter_map(|ch| {
            particles::Tracer::new(world, surfaces, lums, s.particles, ch, s.seed, s.max_depth)
        })
        .collect()
}

/// [`trace`] in batches of whole chunks while `ctl` allows (the render's
/// budget, the cancel flag), reporting progress after each. At least one
/// batch is traced, so that there is an estimate to make; the channel runs
/// of [`Settings::per_channel`] are traced batch by batch together, so
/// that every channel has the same particles. φ = Φ/(particles traced).
pub fn trace_within(
    world: &World,
    surfaces: &Surfaces,
    s: &Settings,
    sink: &mut impl HitSink,
    ctl: &mut Control,
) -> Result<Traced, DensityError> {
    let lums = particles::luminaires(world);
    let tracers = tracers(world, surfaces, &lums, s);
    let mut traced = Traced::default();
    let Some(first) = tracers.first() else {
        traced.phi = particles::phi_unit(&lums, s.particles);
        return Ok(traced);
    };
    // Batches small enough to stop near a deadline; a fixed number of
    // chunks, so that a ray limit stops at the same particle whatever the
    // thread count (the chunks, not the batches, key the streams)
    let batch = particles::BUDGET_BATCH;
    let chunks = first.chunks();
    let mut per_run = 0u64;
    let (mut batch_rays, mut batch_secs) = (0u64, 0.0f64);
    let mut c0 = 0;
    ctl.start_tracing();
    ctl.tick(Phase::Trace, 0, s.particles);
    while c0 < chunks {
        if c0 > 0 && !ctl.may_trace(traced.rays, batch_rays, batch_secs) {
            break;
        }
        let t = Instant::now();
        let c1 = (c0 + batch).min(chunks);
        let before = traced.rays;
        for tr in &tracers {
            let results = tr.trace_chunks(c0, c1, ctl.cancel_flag());
            if ctl.cancelled() {
                // the batch is dropped, but its rays were traced
                let rays = traced.rays + results.iter().map(|r| r.1).sum::<u64>();
                return Err(DensityError::Cancelled { rays });
            }
            for (hits, rays) in results {
                traced.hits += hits.len() as u64;
                traced.rays += rays;
                sink.push(&hits)?;
            }
            traced.particles += tr.particles_in(c0, c1);
        }
        per_run += first.particles_in(c0, c1);
        (batch_rays, batch_secs) = (traced.rays - before, t.elapsed().as_secs_f64());
        ctl.set_rays(traced.rays);
        ctl.tick(Phase::Trace, per_run, s.particles);
        c0 = c1;
    }
    traced.phi = particles::phi_unit(&lums, per_run);
    Ok(traced)
}

/// Phase 1, end (§4.2: the hit points sorted by surface id): every surface
/// side's records together, each side's in the order they were traced.
pub fn group<S: HitSink>(sink: S) -> Result<S::Source, DensityError> {
    Ok(sink.finish()?)
}

/// What phase 2 estimated.
#[derive(Clone, Debug, Default)]
pub struct Estimated {
    /// Over-meshes of the planar surface sides, by [`SurfaceId`]; every
    /// diffuse planar surface's front side has one, black without hits.
    pub planar: Vec<PlanarMesh>,
    /// Curved shapes, one mesh per shape and side, by (shape, side).
    pub curved: Vec<CurvedMesh>,
    /// Largest number of hit records held in memory at once.
    pub max_hits_in_memory: u64,
}

/// Phase 2 (§3.2, §4.2): the irradiance of every surface side that
/// received hits, eq. (2) with Silverman's K2 (eq. 3) and h = C1·√(A/n),
/// sampled on an over-mesh of spacing C2·√(A/n); hits read from `hits` at
/// most [`Settings::chunk_hits`] at a time.
pub fn estimate(
    scene: &Scene,
    surfaces: &Surfaces,
    s: &Settings,
    hits: &impl HitSource,
    phi: f64,
) -> Result<Estimated, DensityError> {
    estimate_within(scene, surfaces, s, hits, phi, &mut Control::none())
}

/// [`estimate`], reporting the hits read and stopping between reads once
/// `ctl` is cancelled.
pub fn estimate_within(
    scene: &Scene,
    surfaces: &Surfaces,
    s: &Settings,
    hits: &impl HitSource,
    phi: f64,
    ctl: &mut Control,
) -> Result<Estimated, DensityError> {
    estimate_owned(scene, surfaces, s, hits, phi, ctl, &|_| true)
}

/// [`estimate_within`] for a worker of the dataflow bake
/// ([`super::dataflow`]): the planar sides where `owns` says so (`hits`
/// may hold others: the tiles of a tiled surface, estimated apart), and
/// the black meshes of hitless front sides only where `owns` says so
/// (every surface is owned by exactly one worker).
pub fn estimate_owned(
    scene: &Scene,
    surfaces: &Surfaces,
    s: &Settings,
    hits: &impl HitSource,
    phi: f64,
    ctl: &mut Control,
    owns: &dyn Fn(SurfaceId) -> bool,
) -> Result<Estimated, DensityError> {
    let mut read = Reads {
        done: 0,
        total: hits.hit_count(),
        ctl,
    };
    read.ctl.tick(Phase::Estimate, 0, read.total);
    let params = Params {
        c1: s.c1,
        c2: s.c2,
        phi: phi as f32,
        max_verts: s.max_verts,
    };
    let cap = s.chunk_hits.max(1) as u64;
    let (mut planar, in_memory_planar) =
        estimate_planar(scene, surfaces, hits, &params, cap, &mut read, owns)?;
    let (curved, in_memory_curved) =
        estimate_curved(scene, surfaces, s.c1, hits, phi, cap, &mut read)?;
    add_black_fronts(scene, surfaces, &params, &mut planar, owns);
    planar.sort_by_key(|m| m.surface);
    Ok(Estimated {
        planar,
        curved,
        max_hits_in_memory: in_memory_planar.max(in_memory_curved),
    })
}

/// Phase 2's reads of the hits: how many so far, for the progress, and
/// the control to check before each.
struct Reads<'c, 'a> {
    done: u64,
    total: u64,
    ctl: &'c mut Control<'a>,
}

impl Reads<'_, '_> {
    /// Reads `count` records from `start`, once the control allows.
    fn read<'h, H: HitSource>(
        &mut self,
        hits: &'h H,
        start: u64,
        count: u64,
    ) -> Result<std::borrow::Cow<'h, [super::hits::Hit]>, DensityError> {
        self.ctl.check()?;
        let chunk = hits.read(start, count)?;
        self.done += count;
        Ok(chunk)
    }

    /// Reports the hits read, once their estimate is made.
    fn tick(&mut self) {
        self.ctl.tick(Phase::Estimate, self.done, self.total);
    }
}

/// The planar surfaces of phase 2 that `owns` says so, in the order of
/// `hits`' runs; returns them and the largest hit buffer.
fn estimate_planar(
    scene: &Scene,
    surfaces: &Surfaces,
    hits: &impl HitSource,
    params: &Params,
    cap: u64,
    reads: &mut Reads,
    owns: &dyn Fn(SurfaceId) -> bool,
) -> Result<(Vec<PlanarMesh>, u64), DensityError> {
    let is_planar =
        |id: SurfaceId| owns(id) && surfaces.get(id).is_some_and(|s| s.kind == Kind::Planar);
    let new_estimator = |run: &Run| {
        let surf = surfaces.of(run.surface);
        let ct = surf.chart_tris(scene);
        PlanarEstimator::new(surf.rectangle, surf.size, surf.area, &ct, run.count, params)
    };
    let finish = |run: &Run, est: PlanarEstimator| {
        let e = est.finish();
        PlanarMesh::unindexed(run.surface, e.verts, e.tris, e.h, e.bandwidth, run.count)
    };
    let runs = hits.runs();
    let mut planar = Vec::new();
    let mut max_in_memory = 0u64;
    let mut i = 0;
    while i < runs.len() {
        if !is_planar(runs[i].surface) {
            i += 1;
            continue;
        }
        if runs[i].count > cap {
            // A large surface: its hits chunk by chunk into one estimate
            // (eq. (2) is a sum over hits, additive over chunks)
            let run = runs[i];
            let mut est = new_estimator(&run);
            let mut done = 0;
            while done < run.count {
                let m = (run.count - done).min(cap);
                let chunk = reads.read(hits, run.start + done, m)?;
                max_in_memory = max_in_memory.max(m);
                est.add(&chunk);
                reads.tick();
                done += m;
            }
            planar.push(finish(&run, est));
            i += 1;
            continue;
        }
        // Consecutive small planar surfaces: one read, estimated in parallel
        // (§3.4: "each surface can be processed independently")
        let mut j = i;
        let mut total = 0;
        while j < runs.len()
            && is_planar(runs[j].surface)
            && runs[j].count <= cap
            && total + runs[j].count <= cap
        {
            total += runs[j].count;
            j += 1;
        }
        let chunk = reads.read(hits, runs[i].start, total)?;
        max_in_memory = max_in_memory.max(total);
        let base = runs[i].start;
        let meshes: Vec<PlanarMesh> = runs[i..j]
            .par_iter()
            .map(|run| {
                let a = (run.start - base) as usize;
                let mut est = new_estimator(run);
                est.add(&chunk[a..a + run.count as usize]);
                finish(run, est)
            })
            .collect();
        planar.extend(meshes);
        reads.tick();
        i = j;
    }
    Ok((planar, max_in_memory))
}

/// The curved shapes of phase 2: the 3D kernel at their vertices, the hits
/// of a shape and side (many runs: one per triangle) streamed in chunks.
/// Eq. (2) is additive over chunks, so each chunk's kd-tree gives a partial
/// sum at every vertex. Returns the meshes by (shape, side) and the largest
/// hit buffer.
fn estimate_curved(
    scene: &Scene,
    surfaces: &Surfaces,
    c1: f32,
    hits: &impl HitSource,
    phi: f64,
    cap: u64,
    reads: &mut Reads,
) -> Result<(Vec<CurvedMesh>, u64), DensityError> {
    // The runs of every (shape, back side), in the order of `hits`
    let mut keys: Vec<((u32, bool), Vec<Run>)> = Vec::new();
    let mut index: HashMap<(u32, bool), usize> = HashMap::new();
    for run in hits.runs() {
        let Some(surf) = surfaces.get(run.surface) else {
            continue;
        };
        if surf.kind != Kind::Curved {
            continue;
        }
        let key = (surf.shape, run.surface.back);
        let k = *index.entry(key).or_insert_with(|| {
            keys.push((key, Vec::new()));
            keys.len() - 1
        });
        keys[k].1.push(*run);
    }
    keys.sort_by_key(|k| k.0);

    let mut curved = Vec::with_capacity(keys.len());
    let mut max_in_memory = 0u64;
    for ((shape, back), kruns) in keys {
        // h = C1·√(A/n) over the whole shape and side
        let sh = &scene.shapes[shape as usize];
        let tris: Vec<u32> = (sh.first_tri..sh.first_tri + sh.tri_count).collect();
        let area: f32 = tris.iter().map(|&t| scene.tri_area(t)).sum();
        let n_key: u64 = kruns.iter().map(|r| r.count).sum();
        let h = c1 * (area / n_key.max(1) as f32).sqrt();
        let side = |n: Vec3| if back { -n } else { n };
        let at: Vec<(Vec3, Vec3)> = tris
            .iter()
            .flat_map(|&t| {
                [(0.0, 0.0), (1.0, 0.0), (0.0, 1.0)].map(|(b1, b2)| {
                    let sp = scene.surface_point(t, b1, b2);
                    (sp.p, side(sp.frame.n))
                })
            })
            .collect();

        // Sum chunk by chunk: each hit as a world point, normal and power
        let mut sum = vec![Vec3::ZERO; at.len()];
        let mut buf: Vec<(Vec3, Vec3, Vec3)> = Vec::new();
        let flush = |buf: &mut Vec<(Vec3, Vec3, Vec3)>, sum: &mut Vec<Vec3>| {
            let part = kernel::estimate_3d(&at, buf, h, phi as f32);
            for (a, b) in sum.iter_mut().zip(part) {
                *a += b;
            }
            buf.clear();
        };
        for run in &kruns {
            let surf = surfaces.of(run.surface);
            let mut done = 0;
            while done < run.count {
                let m = (run.count - done).min(cap - buf.len() as u64);
                let chunk = reads.read(hits, run.start + done, m)?;
                for hh in chunk.iter() {
                    let sp = scene.surface_point(surf.tris[0], from_fixed(hh.u), from_fixed(hh.v));
                    buf.push((sp.p, side(sp.frame.n), decode_rgb9e5(hh.rgb)));
                }
                max_in_memory = max_in_memory.max(buf.len() as u64);
                done += m;
                if buf.len() as u64 >= cap {
                    flush(&mut buf, &mut sum);
                    reads.tick();
                }
            }
        }
        if !buf.is_empty() {
            flush(&mut buf, &mut sum);
            reads.tick();
        }
        curved.push(CurvedMesh {
            shape,
            back,
            h: sum.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect(),
            tris,
        });
    }
    Ok((curved, max_in_memory))
}

/// Front sides of diffuse planar surfaces without hits get a (black)
/// mesh, so that the display mesh covers every diffuse surface.
fn add_black_fronts(
    scene: &Scene,
    surfaces: &Surfaces,
    params: &Params,
    planar: &mut Vec<PlanarMesh>,
    owns: &dyn Fn(SurfaceId) -> bool,
) {
    let have: std::collections::HashSet<SurfaceId> = planar.iter().map(|m| m.surface).collect();
    for (sid, surf) in surfaces.list.iter().enumerate() {
        let front = SurfaceId::front(sid as u32);
        if surf.kind == Kind::Planar && surf.diffuse && !have.contains(&front) && owns(front) {
            let ct = surf.chart_tris(scene);
            let est =
                kernel::estimate_planar(surf.rectangle, surf.size, surf.area, &ct, &[], params);
            planar.push(PlanarMesh::unindexed(
                front, est.verts, est.tris, est.h, 0.0, 0,
            ));
        }
    }
}

/// R at the vertices of a planar mesh: one value for an untextured
/// surface, else the texture at each vertex (§3.2: L = R(u, v)·H(u, v)/π).
pub fn reflectance(scene: &Scene, surfaces: &Surfaces, m: &PlanarMesh) -> Vec<Vec3> {
    let surf = surfaces.of(m.surface);
    if surf.textured {
        surf.reflectance_at(scene, &m.verts)
    } else {
        vec![surf.reflectance]
    }
}

/// The white point w0 of the brightness axis (§4.3): the 99th percentile
/// of the vertex radiance R·H/π (luminance) over the planar over-meshes.
pub fn white_point(scene: &Scene, surfaces: &Surfaces, planar: &[PlanarMesh]) -> f32 {
    white_point_of(vertex_luminances(scene, surfaces, planar))
}

/// The positive vertex radiances R·H/π (luminance) of the planar
/// over-meshes, in no particular order: what [`white_point_of`] ranks.
pub fn vertex_luminances(scene: &Scene, surfaces: &Surfaces, planar: &[PlanarMesh]) -> Vec<f32> {
    planar
        .par_iter()
        .flat_map_iter(|m| {
            let r = reflectance(scene, surfaces, m);
            let r_at = move |i: usize| if r.len() == 1 { r[0] } else { r[i] };
            m.h.iter()
                .enumerate()
                .map(move |(i, h)| luminance(r_at(i) * *h / PI))
                .collect::<Vec<_>>()
        })
        .filter(|v| *v > 0.0)
        .collect()
}

/// The 99th percentile of `lum` (1 when empty): a function of the set of
/// values alone, so that workers may gather them in any order.
pub fn white_point_of(mut lum: Vec<f32>) -> f32 {
    lum.sort_by(f32::total_cmp);
    lum.get(((lum.len() as f64 * 0.99) as usize).min(lum.len().saturating_sub(1)))
        .copied()
        .unwrap_or(1.0)
        .max(1e-12)
}

/// What phase 3 did, over all surfaces.
#[derive(Clone, Copy, Debug, Default)]
pub struct Decimated {
    /// Largest brightness error at a removed vertex (Stevens units, ≤ ε).
    pub max_error: f32,
    /// Mean brightness error over removed vertices.
    pub mean_error: f32,
}

/// Phase 3 (§3.3, §4.3): every planar over-mesh decimated in parallel as a
/// height field of Stevens brightness against white point `w0`, within
/// error bound `epsilon` (never fails: [`decimate_within`] without a
/// cancel flag or a limit).
pub fn decimate(
    scene: &Scene,
    surfaces: &Surfaces,
    planar: Vec<PlanarMesh>,
    w0: f32,
    epsilon: f32,
) -> Result<(Vec<PlanarMesh>, Decimated), DensityError> {
    decimate_within(scene, surfaces, planar, w0, epsilon, &mut Control::none())
}

/// [`decimate`] in slices of surfaces, reporting after each: stops once
/// `ctl` is cancelled, and leaves the surfaces of the slices after the
/// time limit's deadline over-meshed ([`Control::may_decimate`]).
pub fn decimate_within(
    scene: &Scene,
    surfaces: &Surfaces,
    planar: Vec<PlanarMesh>,
    w0: f32,
    epsilon: f32,
    ctl: &mut Control,
) -> Result<(Vec<PlanarMesh>, Decimated), DensityError> {
    let out = decimate_each(scene, surfaces, planar, w0, epsilon, ctl)?;
    let d = Decimated::of(out.iter().map(|(_, r)| r));
    Ok((out.into_iter().map(|(m, _)| m).collect(), d))
}

/// The loop of [`decimate_within`]: every mesh with its own report (the
/// dataflow bake sends them to the worker that assembles the bake).
pub fn decimate_each(
    scene: &Scene,
    surfaces: &Surfaces,
    planar: Vec<PlanarMesh>,
    w0: f32,
    epsilon: f32,
    ctl: &mut Control,
) -> Result<Vec<(PlanarMesh, Report)>, DensityError> {
    let total = planar.len() as u64;
    let slice = 4 * rayon::current_num_threads().max(1);
    let mut todo = planar.into_iter().peekable();
    let mut out: Vec<(PlanarMesh, Report)> = Vec::with_capacity(total as usize);
    ctl.tick(Phase::Decimate, 0, total);
    while todo.peek().is_some() {
        ctl.check()?;
        if !ctl.may_decimate() {
            out.extend(todo.by_ref().map(|m| (m, Report::default())));
            break;
        }
        let part: Vec<PlanarMesh> = todo.by_ref().take(slice).collect();
        out.par_extend(part.into_par_iter().map(|m| {
            let r = reflectance(scene, surfaces, &m);
            decimation::decimate_planar(m, &r, w0, epsilon)
        }));
        ctl.tick(Phase::Decimate, out.len() as u64, total);
    }
    Ok(out)
}

impl Decimated {
    /// The errors over all removed vertices, from each mesh's report.
    pub fn of<'a>(reports: impl IntoIterator<Item = &'a Report>) -> Self {
        let mut max_error = 0.0f32;
        let mut sum_error = 0.0f64;
        let mut removed = 0u64;
        for r in reports {
            max_error = max_error.max(r.max_error);
            sum_error += r.sum_error;
            removed += r.removed;
        }
        let mean_error = if removed > 0 {
            (sum_error / removed as f64) as f32
        } else {
            0.0
        };
        Decimated {
            max_error,
            mean_error,
        }
    }
}
