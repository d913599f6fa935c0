//! The lightmap bake on a timely dataflow (`kalos bake --lightmap
//! --workers N`, or `--process I --processes N --hostfile FILE`): the same
//! bytes as one process ([`super::bake::bake_lightmap`]), the work split
//! below the surface.
//!
//! 0. every process makes the uv set and the texels (they depend on the
//!    geometry alone: every process makes the same);
//! 1. the particles are traced and their hits exchanged as for the display
//!    mesh ([`dataflow::trace_and_group`]): a large planar surface is cut
//!    into tiles, each owned by a worker, and each hit goes to the owner
//!    of its tile, or of its whole surface. The tiles are dealt by the
//!    texels they hold (the display mesh deals them by a pilot's hits):
//!    a texel's estimate and gather are the work;
//! 2. every worker tells every other its hit count of each surface side
//!    (a texel's side is the side with more hits, over the whole bake);
//! 3. a texel belongs to the owner of the tile its point lies in, or of
//!    its surface. The estimate at a texel depends on the hits within its
//!    pilot's farthest neighbour and its bandwidth h of it
//!    ([`super::estimate::TexelEstimate::reach`]), and that reach is not
//!    known before the estimate. So the halo grows by rounds: each worker
//!    asks, for each tiled surface, for the hits within a width W of its
//!    tiles (at first twice the bandwidth that the surface's mean density
//!    of hits gives), the owners of those hits send them, and the worker
//!    estimates its texels. A texel whose reach is under W (with 2 % to
//!    spare) had every hit it depends on; the others ask again, for the
//!    widest reach among them times 1.5 (twice W when the worker holds too
//!    few hits to tell), up to the whole surface;
//! 4. the density atlases (held sides and other sides) go to every worker,
//!    which pads them as one process does;
//! 5. with the final gather on, each worker gathers its own texels (each
//!    texel's random numbers are keyed by its index), and worker 0 puts
//!    them together, combines them with the density estimate and pads.
//!
//! Why the bytes are the same: a texel's kernel sums are exact
//! (fixed point, [`super::estimate`]), so they do not depend on which of
//! the hits a worker holds beyond the texel's reach, nor on the order of
//! its kd-tree; the k-nearest distances are those of the whole set once
//! every hit within them is held; the visibility rays read the geometry
//! alone; the gather's random numbers are keyed by texel. Everything after
//! is the single-process code on the same atlases.
//!
//! Failures: as the display-mesh dataflow, every round carries every
//! worker's status and all stop together at the first failure.

use std::sync::atomic::Ordering;
use std::sync::Arc;
use std::time::Instant;

use glam::Vec2;
use timely::worker::Worker;

use super::bake::{
    self as lm_bake, LightmapBake, LightmapError, LightmapSettings, LightmapStats, LightmapWorker,
};
use super::estimate::{self, grown_k, Estimator, HitIndex, Sides, TexelEstimate, K_MAX, K_MIN};
use super::gather::{self, TexelGather};
use super::{DensityAtlas, LightmapUv, Texel};
use crate::color::Rgb;
use crate::methods::density::control::{Control, Phase};
use crate::methods::density::dataflow::{
    self, first_failure, round, status_of, DataflowError, Grouped, Part, Phase1, Status, Tiling,
    Workers, OK,
};
use crate::methods::density::hits::{Hit, HitSource, HIT_BYTES};
use crate::methods::density::surfaces::{SurfaceId, Surfaces};
use crate::methods::density::{DensityError, Settings};
use crate::world::World;

/// Spare room between a texel's reach and the halo's width: the chart
/// coordinates of hits and texels are each rounded once.
const SPARE: f32 = 1.02;

/// The first halo: this many bandwidths (at the surface's mean density).
const FIRST_HALO: f32 = 2.0;

/// What every worker of a process shares: the uv set, the texels and the
/// settings, made once before the dataflow.
struct Shared {
    uv: LightmapUv,
    texels: Vec<Texel>,
    lm: LightmapSettings,
    /// Each texel's surface and chart position, which deal the tiles.
    deal: Vec<(SurfaceId, Vec2)>,
    /// Seconds making the uv set and the texels.
    t_uv: f64,
}

/// Bakes a lightmap on the dataflow laid out by `workers`; returns the
/// bake at the process of worker 0 (None elsewhere), and the hit records
/// (and bytes) this process sent. `ctl` sees the progress of this
/// process's first worker; its cancel flag stops every worker.
pub fn bake_lightmap_dataflow(
    world: Arc<World>,
    s: &Settings,
    lm: &LightmapSettings,
    workers: &Workers,
    ctl: &mut Control,
) -> Result<Part<LightmapBake>, LightmapError> {
    lm.check()?;
    s.check().map_err(DensityError::from)?;
    let t = Instant::now();
    let (uv, texels, lm) = lm_bake::prepare(&world.scene, lm)?;
    let t_uv = t.elapsed().as_secs_f64();
    let surfaces = crate::methods::density::surfaces::build(&world.scene);
    let deal = texels
        .iter()
        .filter_map(|t| {
            let &sid = surfaces.tri_surface.get(t.tri as usize)?;
            let surf = surfaces.list.get(sid as usize)?;
            Some((SurfaceId::front(sid), surf.to_chart(t.p)))
        })
        .collect();
    let shared = Arc::new(Shared {
        uv,
        texels,
        lm,
        deal,
        t_uv,
    });
    let job =
        move |w: &mut Worker,
              world: &World,
              surfaces: &Surfaces,
              s: &Settings,
              ctl: &mut Control| { run_worker(w, world, surfaces, s, ctl, &shared) };
    dataflow::run_dataflow(world, s, workers, ctl, job).map_err(LightmapError::from)
}

/// Step 2's item: sender, status, hits per surface side (encoded).
type Counts = (u32, Status, Vec<(u32, u64)>);
/// Step 3's request: sender, status, the halo width it asks for on each
/// tiled surface (in [`Tiling::tiled`]'s order).
type Request = (u32, Status, Vec<f32>);
/// Per surface side (encoded), hit records as bytes.
type SideBytes = Vec<(u32, Vec<u8>)>;
/// Step 3's halo: sender, status, per surface side hit records.
type HaloWire = (u32, Status, SideBytes);
/// Step 4's item: sender, status, texel indices, 12 numbers each (held
/// E and se, other side E and se), and flags (1: held hidden, 2: other
/// side estimated, 4: other hidden).
type DensityWire = (u32, Status, Vec<u32>, Vec<f32>, Vec<u8>);
/// Step 5's item: sender, status, figures (rays traced, hits received,
/// halo hits received, texels, halo rounds, texel estimates), gathered
/// texel indices, six numbers each (E, se), rays and hidden flags.
type GatherWire = (u32, Status, [u64; 6], Vec<u32>, Vec<f32>, Vec<u64>, Vec<u8>);

/// The halo of one worker, as every worker knows it: per worker and tiled
/// surface, the width already sent.
struct Halo {
    tiled: Vec<u32>,
    sent: Vec<Vec<f32>>,
    /// The hits received, per side.
    hits: Vec<(SurfaceId, Vec<Hit>)>,
    received: u64,
    rounds: u64,
    /// Texel estimates made.
    estimates: u64,
}

/// One worker's bake.
fn run_worker(
    worker: &mut Worker,
    world: &World,
    surfaces: &Surfaces,
    s: &Settings,
    ctl: &mut Control,
    sh: &Shared,
) -> Result<Part<LightmapBake>, DataflowError> {
    let (me, peers) = (worker.index(), worker.peers());
    let t = Instant::now();
    let Phase1 {
        tiling,
        scratch,
        grouped,
    } = dataflow::trace_and_group(worker, world, surfaces, s, Some(&sh.deal), ctl);
    let t_trace = t.elapsed().as_secs_f64();
    let t = Instant::now();

    // Step 2: the counts
    let mine: Vec<(u32, u64)> = match &grouped {
        Ok((_, hits)) => hits
            .runs()
            .iter()
            .map(|r| (r.surface.encode(), r.count))
            .collect(),
        Err(_) => Vec::new(),
    };
    let st = status_of(&grouped);
    let items = (0..peers)
        .map(|w| (w as u64, (me as u32, st.clone(), mine.clone())))
        .collect();
    let mut got: Vec<Counts> = round(worker, items);
    got.sort_by_key(|g| g.0);
    let (traced, hits) = first_failure(got.iter().map(|g| (g.0 as usize, &g.1)), grouped)?;
    let mut totals: std::collections::BTreeMap<u32, u64> = Default::default();
    for (_, _, c) in &got {
        for &(side, n) in c {
            *totals.entry(side).or_default() += n;
        }
    }
    let totals: Vec<(SurfaceId, u64)> = totals
        .into_iter()
        .map(|(k, n)| (SurfaceId::decode(k), n))
        .collect();

    // Step 3: the texels, estimated as the halo grows
    let owned = owned_texels(&sh.texels, surfaces, &tiling, me, peers);
    let job = Job {
        world,
        surfaces,
        tiling: &tiling,
        s,
        sh,
        totals: &totals,
        phi: traced.phi,
    };
    let (index, sides, halo) = estimate_owned(worker, &job, &hits, &owned, ctl)?;
    let t_estimate = t.elapsed().as_secs_f64();

    // Step 4: the density atlases, to every worker (to worker 0 alone
    // without a gather)
    let t = Instant::now();
    let gather_on = sh.lm.gather.is_on();
    let wire = density_wire(me, &owned, &sides);
    let items = match gather_on {
        true => (0..peers).map(|w| (w as u64, wire.clone())).collect(),
        false => vec![(0, wire)],
    };
    let got: Vec<DensityWire> = round(worker, items);
    let mut density = DensityAtlas::empty(sh.uv.width, sh.uv.height);
    for (_, _, idx, vals, flags) in &got {
        put_density(&mut density, &sh.texels, idx, vals, flags);
    }
    drop(got);
    density.dilate(2);

    // Step 5: the gather of this worker's texels, all to worker 0
    let est = Estimator::new(world, surfaces, &index, traced.phi, sh.lm.estimator);
    let gathered = if gather_on {
        let g = lm_bake::gather_with(world, &est, &density, &sh.uv, s, &sh.lm);
        let cancel = ctl.cancel_flag();
        let mut progress = |done, total| ctl.tick(Phase::Gather, done, total);
        gather::gather_some(&g, &sh.texels, &owned, &density.held, cancel, &mut progress)
    } else {
        Vec::new()
    };
    let st: Status = if ctl.cancelled() {
        (dataflow::CANCELLED, String::new())
    } else {
        (OK, String::new())
    };
    let figures = [
        traced.rays,
        traced.hits_received,
        halo.received,
        owned.len() as u64,
        halo.rounds,
        halo.estimates,
    ];
    let mine = gather_wire(me, st.clone(), figures, &owned, &gathered);
    let mut parts: Vec<GatherWire> = round(worker, vec![(0, mine)]);
    drop(scratch);
    let (hits_sent, bytes_sent) = (traced.hits_sent, traced.bytes_sent);
    if me != 0 {
        first_failure(std::iter::once((me, &st)), Ok::<(), DataflowError>(()))?;
        return Ok(Part {
            out: None,
            hits_sent,
            bytes_sent,
        });
    }
    parts.sort_by_key(|p| p.0);
    first_failure(
        parts.iter().map(|p| (p.0 as usize, &p.1)),
        Ok::<(), DataflowError>(()),
    )?;
    let mut stats = LightmapStats {
        particles: traced.particles,
        texels: sh.texels.len() as u64,
        t_uv: sh.t_uv,
        t_trace,
        ..Default::default()
    };
    let lightmap = assemble(sh, density, &parts, &mut stats);
    stats.t_estimate = t_estimate + t.elapsed().as_secs_f64();
    Ok(Part {
        out: Some(LightmapBake {
            uv: sh.uv.clone(),
            lightmap,
            stats,
        }),
        hits_sent,
        bytes_sent: bytes_sent + halo.received * HIT_BYTES as u64,
    })
}

/// Worker 0's atlas from every worker's part: the gathers put into the
/// density atlas, combined and padded (the density atlas itself without
/// a gather), and the workers' figures into `stats`.
fn assemble(
    sh: &Shared,
    density: DensityAtlas,
    parts: &[GatherWire],
    stats: &mut LightmapStats,
) -> super::Lightmap {
    stats.workers = parts
        .iter()
        .map(|p| LightmapWorker {
            hits: p.2[1],
            halo: p.2[2],
            texels: p.2[3],
            rounds: p.2[4],
            estimates: p.2[5],
        })
        .collect();
    for (_, _, f, ..) in parts {
        stats.rays += f[0];
        stats.hits += f[1];
    }
    if !sh.lm.gather.is_on() {
        return density.held;
    }
    let mut lm = density.held.clone();
    for (_, _, _, idx, vals, rays, flags) in parts {
        let g = unwire_gathered(vals, rays, flags);
        let (r, h) = gather::put_gathered(&mut lm, &sh.texels, idx, &g);
        stats.gather_rays += r;
        stats.gather_hidden += h;
    }
    lm_bake::combined(lm, &density.held, &sh.texels, &sh.uv)
}

/// What step 3 reads.
struct Job<'a> {
    world: &'a World,
    surfaces: &'a Surfaces,
    tiling: &'a Tiling,
    s: &'a Settings,
    sh: &'a Shared,
    totals: &'a [(SurfaceId, u64)],
    phi: f64,
}

/// The texels this worker estimates: those whose point lies in one of its
/// tiles, or on a surface it owns whole.
fn owned_texels(
    texels: &[Texel],
    surfaces: &Surfaces,
    tiling: &Tiling,
    me: usize,
    peers: usize,
) -> Vec<u32> {
    (0..texels.len() as u32)
        .filter(|&i| texel_owner(&texels[i as usize], surfaces, tiling, peers) == me)
        .collect()
}

/// The worker a texel belongs to, and the tiled surface it lies on.
fn texel_owner(t: &Texel, surfaces: &Surfaces, tiling: &Tiling, peers: usize) -> usize {
    let Some(&sid) = surfaces.tri_surface.get(t.tri as usize) else {
        return 0;
    };
    let id = SurfaceId::front(sid);
    match (tiling.split(id), surfaces.get(id)) {
        (Some(sp), Some(surf)) => tiling.tile_owner(sp, sp.tile_of(surf.to_chart(t.p))),
        _ => dataflow::owner(surfaces, id, peers),
    }
}

/// The first halo width of each tiled surface: [`FIRST_HALO`] bandwidths
/// of a texel at the surface's mean density of hits (on its more lit
/// side), 0 for a surface without hits.
fn first_widths(job: &Job, tiled: &[u32]) -> Vec<f32> {
    let opts = &job.sh.lm.estimator;
    let texel_area = opts.texel_area.unwrap_or(0.0);
    tiled
        .iter()
        .map(|&i| {
            let n = job
                .totals
                .iter()
                .filter(|(id, _)| id.index == i)
                .map(|&(_, n)| n)
                .max()
                .unwrap_or(0);
            let area = job.surfaces.list.get(i as usize).map_or(0.0, |s| s.area);
            if n == 0 || area.partial_cmp(&0.0) != Some(std::cmp::Ordering::Greater) {
                return 0.0;
            }
            if let Some(h) = opts.bandwidth {
                return FIRST_HALO * h;
            }
            let rho = n as f32 / area;
            let k = match opts.neighbours {
                Some(k) => k.clamp(1, K_MAX),
                None => {
                    let r2 = K_MIN as f32 / (std::f32::consts::PI * rho);
                    grown_k(K_MIN, r2, texel_area, opts.growth)
                }
            };
            FIRST_HALO * (k as f32 / (std::f32::consts::PI * rho)).sqrt()
        })
        .collect()
}

/// Step 3 at one worker: rounds of requests and halos until every
/// worker's texels had every hit within their reach; returns the last
/// index (its totals set), the estimates of `owned` in order, and the
/// halo.
fn estimate_owned(
    worker: &mut Worker,
    job: &Job,
    hits: &Grouped,
    owned: &[u32],
    ctl: &mut Control,
) -> Result<(HitIndex, Vec<Sides>, Halo), DataflowError> {
    let (me, peers) = (worker.index(), worker.peers());
    let tiled = job.tiling.tiled();
    let mut halo = Halo {
        sent: vec![vec![0.0; tiled.len()]; peers],
        tiled,
        hits: Vec::new(),
        received: 0,
        rounds: 0,
        estimates: 0,
    };
    let on_tiled: Vec<Option<usize>> = owned
        .iter()
        .map(|&i| tiled_of(&job.sh.texels[i as usize], job.surfaces, &halo.tiled))
        .collect();
    // ask first for the widths where this worker has texels
    let first = first_widths(job, &halo.tiled);
    let mut want = vec![0.0f32; halo.tiled.len()];
    for k in on_tiled.iter().flatten() {
        want[*k] = first[*k];
    }
    let mut sides: Vec<Sides> = vec![Default::default(); owned.len()];
    let mut pending: Vec<usize> = (0..owned.len()).collect();
    let mut index = None;
    let mut st: Status = (OK, String::new());
    loop {
        let items = (0..peers)
            .map(|w| (w as u64, (me as u32, st.clone(), want.clone())))
            .collect();
        let mut asks: Vec<Request> = round(worker, items);
        asks.sort_by_key(|a| a.0);
        first_failure(
            asks.iter().map(|a| (a.0 as usize, &a.1)),
            Ok::<(), DataflowError>(()),
        )?;
        let asked = |w: usize, k: usize| asks[w].2.get(k).copied().unwrap_or(0.0);
        let grows =
            (0..peers).any(|w| (0..halo.tiled.len()).any(|k| asked(w, k) > halo.sent[w][k]));
        if index.is_some() && !grows {
            break;
        }
        if grows {
            let out = halo_out(job, hits, &halo, &asks, me)
                .map_err(|e| DataflowError::from(DensityError::from(e)));
            let st = status_of(&out);
            let items = out
                .unwrap_or_default()
                .into_iter()
                .enumerate()
                .map(|(w, parts)| (w as u64, (me as u32, st.clone(), parts)))
                .collect();
            let mut got: Vec<HaloWire> = round(worker, items);
            got.sort_by_key(|g| g.0);
            first_failure(
                got.iter().map(|g| (g.0 as usize, &g.1)),
                Ok::<(), DataflowError>(()),
            )?;
            for (_, _, parts) in got {
                for (side, bytes) in parts {
                    let v: Vec<Hit> = bytes.chunks_exact(HIT_BYTES).map(Hit::from_bytes).collect();
                    halo.received += v.len() as u64;
                    halo.hits.push((SurfaceId::decode(side), v));
                }
            }
            for (w, a) in asks.iter().enumerate() {
                for (k, &x) in a.2.iter().enumerate().take(halo.tiled.len()) {
                    halo.sent[w][k] = halo.sent[w][k].max(x);
                }
            }
            halo.rounds += 1;
        }
        // The index of this worker's hits and halo, and its pending texels
        let chunk = job.s.chunk_hits as u64;
        let built = HitIndex::build_with(job.world, job.surfaces, hits, &halo.hits, chunk);
        let mut ix = built.map_err(|e| DataflowError::from(DensityError::from(e)))?;
        ix.set_totals(job.surfaces, job.totals);
        let est = Estimator::new(job.world, job.surfaces, &ix, job.phi, job.sh.lm.estimator);
        let which: Vec<u32> = pending.iter().map(|&j| owned[j]).collect();
        halo.estimates += which.len() as u64;
        let cancel = ctl.cancel_flag();
        let both = job.sh.lm.gather.is_on();
        let got = {
            let mut progress = |done, total| ctl.tick(Phase::Estimate, done, total);
            estimate::estimate_sides(&est, &job.sh.texels, &which, both, cancel, &mut progress)
        };
        drop(est);
        if got.len() < which.len() || cancel.is_some_and(|c| c.load(Ordering::Relaxed)) {
            st = (dataflow::CANCELLED, String::new());
        }
        want = vec![0.0; halo.tiled.len()];
        let mut still = Vec::new();
        for (&j, e) in pending.iter().zip(got) {
            let reach = reach_of(&e);
            sides[j] = e;
            let Some(k) = on_tiled[j] else { continue };
            let have = halo.sent[me][k];
            if reach == 0.0 || reach * SPARE < have {
                continue;
            }
            still.push(j);
            let next = if reach.is_finite() {
                (1.5 * reach).max(have * 1.25)
            } else {
                (2.0 * have).max(first[k])
            };
            want[k] = want[k].max(whole_if_past(next, job, halo.tiled[k]));
        }
        pending = still;
        index = Some(ix);
    }
    let index = index.ok_or(DataflowError::Worker("no estimate round".into()))?;
    Ok((index, sides, halo))
}

/// The reach of a texel's estimates (both sides).
fn reach_of(e: &Sides) -> f32 {
    e.1.as_ref()
        .map_or(e.0.reach, |o: &TexelEstimate| e.0.reach.max(o.reach))
}

/// A halo width, or infinity (the whole surface) once it spans the
/// surface's chart.
fn whole_if_past(w: f32, job: &Job, surface: u32) -> f32 {
    let extent = job
        .tiling
        .split(SurfaceId::front(surface))
        .map_or(0.0, |sp| sp.size.max_element());
    if w < extent {
        w
    } else {
        f32::INFINITY
    }
}

/// The tiled surface (its position in `tiled`) a texel lies on.
fn tiled_of(t: &Texel, surfaces: &Surfaces, tiled: &[u32]) -> Option<usize> {
    let sid = *surfaces.tri_surface.get(t.tri as usize)?;
    tiled.binary_search(&sid).ok()
}

/// The halo this worker sends: to each worker that asks for a wider halo
/// on a tiled surface, the hits of this worker's tiles within the new
/// width of one of its tiles and not within the old.
fn halo_out(
    job: &Job,
    hits: &Grouped,
    halo: &Halo,
    asks: &[Request],
    me: usize,
) -> Result<Vec<SideBytes>, crate::methods::density::hitfile::HitFileError> {
    let peers = asks.len();
    let mut out: Vec<SideBytes> = vec![Vec::new(); peers];
    let cap = job.s.chunk_hits.max(1) as u64;
    for run in hits.runs() {
        let Some(k) = halo.tiled.iter().position(|&i| i == run.surface.index) else {
            continue;
        };
        let Some(sp) = job.tiling.split(run.surface) else {
            continue;
        };
        let grow: Vec<(usize, f32, f32)> = (0..peers)
            .filter(|&w| w != me)
            .filter_map(|w| {
                let new = asks[w].2.get(k).copied().unwrap_or(0.0);
                let old = halo.sent[w][k];
                (new > old).then_some((w, old, new))
            })
            .collect();
        if grow.is_empty() {
            continue;
        }
        let near = |x, r: f32, w: usize| {
            r > 0.0
                && sp
                    .tiles_near(x, r)
                    .any(|t| job.tiling.tile_owner(sp, t) == w)
        };
        let mut bufs: Vec<Vec<u8>> = vec![Vec::new(); peers];
        let mut done = 0;
        while done < run.count {
            let m = (run.count - done).min(cap);
            let chunk = hits.read(run.start + done, m)?;
            for h in chunk.iter() {
                let x = sp.chart(h);
                for &(w, old, new) in &grow {
                    if near(x, new, w) && !near(x, old, w) {
                        bufs[w].extend_from_slice(&h.to_bytes());
                    }
                }
            }
            done += m;
        }
        for (w, b) in bufs.into_iter().enumerate() {
            if !b.is_empty() {
                out[w].push((run.surface.encode(), b));
            }
        }
    }
    Ok(out)
}

/// A worker's density estimates on the wire.
fn density_wire(me: usize, owned: &[u32], sides: &[Sides]) -> DensityWire {
    let mut vals = Vec::with_capacity(owned.len() * 12);
    let mut flags = Vec::with_capacity(owned.len());
    for (held, other) in sides {
        let o = other.unwrap_or_default();
        for v in [held.e, held.se, o.e, o.se] {
            vals.extend_from_slice(&v.to_array());
        }
        flags.push(
            u8::from(held.hidden) | (u8::from(other.is_some()) << 1) | (u8::from(o.hidden) << 2),
        );
    }
    (me as u32, (OK, String::new()), owned.to_vec(), vals, flags)
}

/// Puts a worker's density estimates into the atlases.
fn put_density(
    atlas: &mut DensityAtlas,
    texels: &[Texel],
    idx: &[u32],
    vals: &[f32],
    flags: &[u8],
) {
    let rgb = |v: &[f32]| Rgb::new(v[0], v[1], v[2]);
    for ((&i, v), &f) in idx.iter().zip(vals.chunks_exact(12)).zip(flags) {
        let Some(t) = texels.get(i as usize) else {
            continue;
        };
        let held = TexelEstimate {
            e: rgb(&v[0..3]),
            se: rgb(&v[3..6]),
            hidden: f & 1 != 0,
            ..Default::default()
        };
        let other = (f & 2 != 0).then(|| TexelEstimate {
            e: rgb(&v[6..9]),
            se: rgb(&v[9..12]),
            hidden: f & 4 != 0,
            ..Default::default()
        });
        atlas.set(t, &held, other.as_ref());
    }
}

/// A worker's gathers on the wire (the texels it did not gather, not
/// covered, are left out).
fn gather_wire(
    me: usize,
    st: Status,
    figures: [u64; 6],
    owned: &[u32],
    gathered: &[Option<TexelGather>],
) -> GatherWire {
    let (mut idx, mut vals, mut rays, mut flags) = (Vec::new(), Vec::new(), Vec::new(), Vec::new());
    for (&i, g) in owned.iter().zip(gathered) {
        let Some(g) = g else { continue };
        idx.push(i);
        vals.extend_from_slice(&g.e.to_array());
        vals.extend_from_slice(&g.se.to_array());
        rays.push(g.rays);
        flags.push(u8::from(g.hidden));
    }
    (me as u32, st, figures, idx, vals, rays, flags)
}

/// Gathers back from the wire.
fn unwire_gathered(vals: &[f32], rays: &[u64], flags: &[u8]) -> Vec<Option<TexelGather>> {
    vals.chunks_exact(6)
        .zip(rays)
        .zip(flags)
        .map(|((v, &r), &f)| {
            Some(TexelGather {
                e: Rgb::new(v[0], v[1], v[2]),
                se: Rgb::new(v[3], v[4], v[5]),
                rays: r,
                hidden: f != 0,
            })
        })
        .collect()
}
