//! Work below the surface: large planar surfaces cut into tiles, each
//! owned by a worker.
//!
//! A surface owned whole by one worker bounds the bake's scaling by its
//! share of the hits (26 % for the largest surface of the generated big
//! room). So a planar surface larger than a tile's area (the planar area
//! over `workers` × [`TILES_PER_WORKER`]) is cut into a grid of tiles over
//! its chart ([`Tiling`]):
//!
//! 0. every worker traces the same pilot ([`pilot_hits`], the bake's first
//!    [`PILOT_CHUNKS`] chunks) and deals the tiles by the pilot's hits,
//!    the most loaded first to the least loaded worker, so that all agree
//!    on the deal without a word and a bright spot's tiles spread;
//! 1. while tracing, a hit of a tiled surface goes to the owner of the
//!    tile it falls in ([`Tiling::owner_of_hit`]);
//! 2. once traced, every worker tells every other its hit counts of each
//!    tiled surface side: the bandwidth h = C1·√(A/n) needs the total n;
//! 3. the halo: each hit whose kernel footprint (a disk of radius h) reaches
//!    another worker's tile is sent to that worker;
//! 4. each worker estimates the over-mesh vertices of its own tiles from
//!    its hits and its halo, and sends them to the surface's home worker
//!    ([`super::owner`]), which assembles the over-mesh and decimates it
//!    (decimation stays per surface).
//!
//! A vertex's estimate is a sum of kernel terms over the hits within h of
//! it, in exact fixed point ([`crate::methods::density::kernel::FIXED_BITS`]),
//! so whatever subset of the hits a worker holds and in whatever order, a
//! vertex whose disk it holds whole gets the single-process value bit for
//! bit. The halo test is conservative (h widened by 1 %): a hit sent too
//! many adds nothing. The halo is held in memory; its share of the hits
//! falls as 1/√n (h shrinks with the hits, the tiles do not).

use std::collections::HashMap;

use glam::{Vec2, Vec3};
use timely::worker::Worker;

use super::{first_failure, round, status_of, DataflowError, Status};
use crate::methods::density::control::Control;
use crate::methods::density::hits::{from_fixed, Hit, HitSource, HIT_BYTES};
use crate::methods::density::kernel::{Params, PlanarEstimator};
use crate::methods::density::mesh::PlanarMesh;
use crate::methods::density::surfaces::{Kind, SurfaceId, Surfaces};
use crate::methods::density::{particles, pipeline, DensityError, Settings, World};
use crate::scene::Scene;

/// Tiles a worker should own, about: a surface larger than the planar area
/// over `peers × TILES_PER_WORKER` is cut into tiles of that area.
pub const TILES_PER_WORKER: usize = 16;

/// Chunks of the first channel run traced as the pilot
/// ([`pilot_hits`]).
pub const PILOT_CHUNKS: u64 = 2;

/// The pilot's hits: the first [`PILOT_CHUNKS`] chunks of the bake's first
/// channel run, traced alike by every worker (its streams are the chunks'
/// own), so that every worker deals the same tiles without a word.
pub fn pilot_hits(world: &World, surfaces: &Surfaces, s: &Settings) -> Vec<Hit> {
    let lums = particles::luminaires(world);
    let tracers = pipeline::tracers(world, surfaces, &lums, s);
    let Some(t) = tracers.first() else {
        return Vec::new();
    };
    let c1 = PILOT_CHUNKS.min(t.chunks());
    t.trace_chunks(0, c1, None)
        .into_iter()
        .flat_map(|(hits, _)| hits)
        .collect()
}

/// Most tiles along a chart axis.
const MAX_TILES_PER_AXIS: u32 = 64;

/// The tile grids of a bake on `peers` workers: every planar surface
/// larger than the planar area over `peers` × [`TILES_PER_WORKER`] is cut
/// into tiles of about that area (in surface order; owners not yet dealt).
fn grids(surfaces: &Surfaces, peers: usize) -> Vec<(u32, Split)> {
    let planar = |s: &&crate::methods::density::surfaces::Surface| s.kind == Kind::Planar;
    let total: f64 = surfaces
        .list
        .iter()
        .filter(planar)
        .map(|s| s.area as f64)
        .sum();
    let tile_area = total / (peers * TILES_PER_WORKER) as f64;
    if tile_area <= 0.0 {
        return Vec::new();
    }
    let side = tile_area.sqrt() as f32;
    let mut out = Vec::new();
    for (i, s) in surfaces.list.iter().enumerate() {
        if !planar(&s) || (s.area as f64) <= tile_area {
            continue;
        }
        let n = |len: f32| ((len / side).ceil() as u32).clamp(1, MAX_TILES_PER_AXIS);
        let (tx, ty) = (n(s.size.x), n(s.size.y));
        if tx * ty < 2 || !(s.size.x > 0.0 && s.size.y > 0.0) {
            continue;
        }
        out.push((
            i as u32,
            Split {
                tx,
                ty,
                size: s.size,
                owner: Vec::new(),
            },
        ));
    }
    out
}

/// The tile grid of one tiled surface (both sides).
#[derive(Clone, Debug)]
pub struct Split {
    /// Tiles along the chart's u and v axes.
    pub tx: u32,
    /// Tiles along v.
    pub ty: u32,
    /// The chart's size.
    pub size: Vec2,
    /// Each tile's worker.
    owner: Vec<u32>,
}

impl Split {
    fn axis(x: f32, size: f32, n: u32) -> u32 {
        let t = (x / size * n as f32).floor();
        if t.is_nan() || t < 0.0 {
            0
        } else {
            (t as u32).min(n - 1)
        }
    }

    /// The tile of a chart point (clamped into the grid).
    pub fn tile_of(&self, x: Vec2) -> u32 {
        Self::axis(x.y, self.size.y, self.ty) * self.tx + Self::axis(x.x, self.size.x, self.tx)
    }

    /// The tiles whose rectangles meet the square of half-side `r` about `q`.
    pub(crate) fn tiles_near(&self, q: Vec2, r: f32) -> impl Iterator<Item = u32> + '_ {
        let (x0, x1) = (
            Self::axis(q.x - r, self.size.x, self.tx),
            Self::axis(q.x + r, self.size.x, self.tx),
        );
        let (y0, y1) = (
            Self::axis(q.y - r, self.size.y, self.ty),
            Self::axis(q.y + r, self.size.y, self.ty),
        );
        (y0..=y1).flat_map(move |y| (x0..=x1).map(move |x| y * self.tx + x))
    }

    /// A hit's chart position, as the estimator computes it.
    pub(crate) fn chart(&self, h: &Hit) -> Vec2 {
        Vec2::new(from_fixed(h.u), from_fixed(h.v)) * self.size
    }
}

/// Which surfaces are tiled, and who owns each tile.
#[derive(Clone, Debug, Default)]
pub struct Tiling {
    peers: usize,
    split: HashMap<u32, Split>,
}

impl Tiling {
    /// The tiles of a bake on `peers` workers (none on one worker), dealt
    /// by the hits of a pilot: `pilot`, the hits of the bake's first
    /// particles, which every worker traces alike, predicts each tile's and
    /// each whole surface's share of the hits. The tiles go, the most
    /// loaded first, to the least loaded worker (whole surfaces stay with
    /// [`super::owner`], and count in its load), so that a bright spot's
    /// tiles land on different workers.
    pub fn new(surfaces: &Surfaces, peers: usize, pilot: &[Hit]) -> Self {
        let points: Vec<(SurfaceId, Vec2)> = pilot
            .iter()
            .map(|h| match surfaces.get(h.surface) {
                Some(s) => (
                    h.surface,
                    Vec2::new(from_fixed(h.u), from_fixed(h.v)) * s.size,
                ),
                None => (h.surface, Vec2::ZERO),
            })
            .collect();
        Self::by_points(surfaces, peers, &points)
    }

    /// [`Tiling::new`] with the loads predicted by `points` (surface side,
    /// chart position) instead of a pilot's hits: a lightmap bake deals
    /// the tiles by its texels, whose estimates and gathers are its work
    /// ([`crate::bake::lightmap::dataflow`]).
    pub fn by_points(surfaces: &Surfaces, peers: usize, pilot: &[(SurfaceId, Vec2)]) -> Self {
        let mut t = Tiling {
            peers: peers.max(1),
            split: HashMap::new(),
        };
        if peers < 2 {
            return t;
        }
        let grids = grids(surfaces, peers);
        if grids.is_empty() {
            return t;
        }
        // Predicted loads: the pilot's hits, tile by tile and by the owner
        // of each whole surface
        let mut load = vec![0.0f64; peers];
        let mut tiles: Vec<(f64, u32, u32)> = Vec::new();
        let mut at: HashMap<u32, (usize, &Split)> = HashMap::new();
        for (i, sp) in &grids {
            at.insert(*i, (tiles.len(), sp));
            tiles.extend((0..sp.tx * sp.ty).map(|k| (0.0, *i, k)));
        }
        for (id, c) in pilot {
            match at.get(&id.index) {
                Some((first, sp)) => tiles[first + sp.tile_of(*c) as usize].0 += 1.0,
                None => load[super::owner(surfaces, *id, peers)] += 1.0,
            }
        }
        drop(at);
        // A tile without pilot hits still costs its vertices: a small floor
        let floor = 0.05 * pilot.len().max(1) as f64 / tiles.len().max(1) as f64;
        tiles.sort_by(|a, b| {
            (b.0 + floor)
                .total_cmp(&(a.0 + floor))
                .then((a.1, a.2).cmp(&(b.1, b.2)))
        });
        let mut owners: HashMap<u32, Vec<u32>> = HashMap::new();
        for (i, sp) in &grids {
            owners.insert(*i, vec![0; (sp.tx * sp.ty) as usize]);
        }
        for (l, i, k) in tiles {
            let w = (0..peers)
                .min_by(|&a, &b| load[a].total_cmp(&load[b]).then(a.cmp(&b)))
                .unwrap_or(0);
            load[w] += l + floor;
            if let Some(o) = owners.get_mut(&i) {
                o[k as usize] = w as u32;
            }
        }
        for (i, mut sp) in grids {
            sp.owner = owners.remove(&i).unwrap_or_default();
            t.split.insert(i, sp);
        }
        t
    }

    /// The tile grid of a surface, if it is tiled.
    pub fn split(&self, id: SurfaceId) -> Option<&Split> {
        self.split.get(&id.index)
    }

    /// True when the surface side is tiled.
    pub fn is_split(&self, id: SurfaceId) -> bool {
        self.split.contains_key(&id.index)
    }

    /// The worker that owns tile `tile` of a tiled surface.
    pub(crate) fn tile_owner(&self, sp: &Split, tile: u32) -> usize {
        sp.owner.get(tile as usize).map_or(0, |&w| w as usize)
    }

    /// The worker a hit goes to while tracing: the owner of its tile, or
    /// of its whole surface.
    pub fn owner_of_hit(&self, surfaces: &Surfaces, h: &Hit) -> usize {
        match self.split(h.surface) {
            Some(sp) => self.tile_owner(sp, sp.tile_of(sp.chart(h))),
            None => super::owner(surfaces, h.surface, self.peers),
        }
    }

    /// Every tiled surface, in order.
    pub(crate) fn tiled(&self) -> Vec<u32> {
        let mut v: Vec<u32> = self.split.keys().copied().collect();
        v.sort_unstable();
        v
    }

    /// Every tiled surface side, in order (the sides a worker counts).
    fn sides(&self) -> Vec<SurfaceId> {
        let mut v: Vec<u32> = self.split.keys().copied().collect();
        v.sort_unstable();
        v.into_iter()
            .flat_map(|i| {
                [
                    SurfaceId::front(i),
                    SurfaceId {
                        index: i,
                        back: true,
                    },
                ]
            })
            .collect()
    }
}

/// What the tile phase did at one worker.
#[derive(Debug, Default)]
pub struct TileOut {
    /// The over-meshes of the tiled sides whose home this worker is.
    pub meshes: Vec<PlanarMesh>,
    /// Halo hits received and estimated.
    pub halo_received: u64,
    /// Over-mesh vertices of its tiles it estimated.
    pub verts: u64,
    /// Halo hits sent to other workers, and their bytes.
    pub halo_sent: u64,
    /// Bytes of the halo sent.
    pub halo_bytes: u64,
}

/// A tiled side's vertices estimated by one worker: the side (encoded),
/// vertex indices, and r, g, b for each.
type SideH = (u32, Vec<u32>, Vec<f32>);
/// Per side (encoded), hit records as bytes.
type SideHits = Vec<(u32, Vec<u8>)>;
/// A worker's estimate of one side: vertex indices, r, g, b, and how many.
type Estimated = Option<(Vec<u32>, Vec<f32>, u64)>;

/// Round 1's item: sender, status, hit count of each tiled side.
type Counts = (u32, Status, Vec<u64>);
/// Round 2's item: sender, status, the halo (side, hit records as bytes).
type Halo = (u32, Status, SideHits);
/// Round 3's item: sender, status, per side its tile vertices (index and
/// r, g, b).
type TileH = (u32, Status, Vec<SideH>);

/// What the tile phase needs of a worker: the scene, its surfaces and
/// tiles, the settings and φ.
pub struct TileJob<'a> {
    /// The scene.
    pub scene: &'a Scene,
    /// Its surfaces.
    pub surfaces: &'a Surfaces,
    /// The tiles.
    pub tiling: &'a Tiling,
    /// The bake's settings.
    pub s: &'a Settings,
    /// φ.
    pub phi: f64,
}

/// The tile phase (steps 2 to 4 of the module doc) at one worker; every
/// worker takes part in its three rounds whatever its `status`, and all
/// stop together at the first round that carries a failure. `hits` is the
/// worker's hit file (None after a failure).
pub fn run<H: HitSource>(
    worker: &mut Worker,
    job: &TileJob,
    hits: Option<&H>,
    status: Status,
    ctl: &mut Control,
) -> Result<TileOut, DataflowError> {
    let (me, peers) = (worker.index(), worker.peers());
    let sides = job.tiling.sides();
    let mut out = TileOut::default();
    if sides.is_empty() {
        return Ok(out);
    }

    // Round 1: the hit counts, to everyone
    let mine: Vec<u64> = match hits {
        Some(h) if status.0 == super::OK => sides.iter().map(|&id| count(h, id)).collect(),
        _ => vec![0; sides.len()],
    };
    let items = (0..peers)
        .map(|w| (w as u64, (me as u32, status.clone(), mine.clone())))
        .collect();
    let mut got: Vec<Counts> = round(worker, items);
    got.sort_by_key(|g| g.0);
    first_failure(
        got.iter().map(|g| (g.0 as usize, &g.1)),
        Ok::<_, DataflowError>(()),
    )?;
    let mut n = vec![0u64; sides.len()];
    for g in &got {
        for (a, b) in n.iter_mut().zip(&g.2) {
            *a += b;
        }
    }
    let params = Params {
        c1: job.s.c1,
        c2: job.s.c2,
        phi: job.phi as f32,
        max_verts: job.s.max_verts,
    };
    let estimator = |k: usize| {
        let surf = job.surfaces.of(sides[k]);
        let ct = surf.chart_tris(job.scene);
        PlanarEstimator::new(surf.rectangle, surf.size, surf.area, &ct, n[k], &params)
    };

    // Round 2: the halo
    let no_file = || DataflowError::Worker("no hit file".into());
    let halo = hits
        .ok_or_else(no_file)
        .and_then(|h| halo_of(job, h, &sides, &n, me, peers, &estimator));
    let st = status_of(&halo);
    let halo = halo.unwrap_or_else(|_| vec![Vec::new(); peers]);
    let mut items = Vec::with_capacity(peers);
    for (w, parts) in halo.into_iter().enumerate() {
        if w != me {
            for (_, b) in &parts {
                out.halo_sent += (b.len() / HIT_BYTES) as u64;
                out.halo_bytes += b.len() as u64 + 12;
            }
        }
        items.push((w as u64, (me as u32, st.clone(), parts)));
    }
    let mut got: Vec<Halo> = round(worker, items);
    got.sort_by_key(|g| g.0);
    first_failure(
        got.iter().map(|g| (g.0 as usize, &g.1)),
        Ok::<_, DataflowError>(()),
    )?;
    let mut received: HashMap<u32, Vec<Hit>> = HashMap::new();
    for (_, _, parts) in got {
        for (side, bytes) in parts {
            let v = received.entry(side).or_default();
            v.extend(bytes.chunks_exact(HIT_BYTES).map(Hit::from_bytes));
        }
    }
    out.halo_received = received.values().map(|v| v.len() as u64).sum();

    // Estimate this worker's tiles; round 3: their vertices to each home
    let mut to_home: Vec<Vec<SideH>> = vec![Vec::new(); peers];
    let est = hits.ok_or_else(no_file).and_then(|h| {
        for (k, &id) in sides.iter().enumerate() {
            let Some((idx, rgb, verts)) =
                estimate_side(job, h, &received, id, me, ctl, || estimator(k))?
            else {
                continue;
            };
            out.verts += verts;
            let home = super::owner(job.surfaces, id, peers);
            to_home[home].push((id.encode(), idx, rgb));
        }
        Ok(())
    });
    drop(received);
    let st = status_of(&est);
    let items = to_home
        .into_iter()
        .enumerate()
        .map(|(w, parts)| (w as u64, (me as u32, st.clone(), parts)))
        .collect();
    let mut got: Vec<TileH> = round(worker, items);
    got.sort_by_key(|g| g.0);
    first_failure(got.iter().map(|g| (g.0 as usize, &g.1)), est)?;
    out.meshes = assemble_home(job, &sides, &n, me, peers, got, &estimator);
    Ok(out)
}

/// Records of side `id` in a hit file.
fn count<H: HitSource>(hits: &H, id: SurfaceId) -> u64 {
    hits.runs()
        .iter()
        .filter(|r| r.surface == id)
        .map(|r| r.count)
        .sum()
}

/// Calls `f` with this worker's hits of side `id`, at most
/// [`Settings::chunk_hits`] at a time.
fn each_chunk<H: HitSource>(
    hits: &H,
    id: SurfaceId,
    cap: u64,
    ctl: &mut Control,
    mut f: impl FnMut(&[Hit]),
) -> Result<(), DensityError> {
    for run in hits.runs().iter().filter(|r| r.surface == id) {
        let mut done = 0;
        while done < run.count {
            ctl.check()?;
            let m = (run.count - done).min(cap);
            let chunk = hits.read(run.start + done, m)?;
            f(&chunk);
            done += m;
        }
    }
    Ok(())
}

/// The halo this worker sends: for every worker, per tiled side, the hits
/// of this worker's tiles within h (widened by 1 %) of that worker's tiles.
fn halo_of<H: HitSource>(
    job: &TileJob,
    hits: &H,
    sides: &[SurfaceId],
    n: &[u64],
    me: usize,
    peers: usize,
    estimator: &dyn Fn(usize) -> PlanarEstimator,
) -> Result<Vec<SideHits>, DataflowError> {
    let mut out: Vec<SideHits> = vec![Vec::new(); peers];
    let cap = job.s.chunk_hits.max(1) as u64;
    let mut ctl = Control::none();
    for (k, &id) in sides.iter().enumerate() {
        if n[k] == 0 || count(hits, id) == 0 {
            continue;
        }
        let Some(sp) = job.tiling.split(id) else {
            continue;
        };
        let r = bandwidth(job, id, n[k], estimator, k) * 1.01;
        let mut bufs: Vec<Vec<u8>> = vec![Vec::new(); peers];
        let mut seen = vec![usize::MAX; peers];
        let mut i = 0usize;
        each_chunk(hits, id, cap, &mut ctl, |chunk| {
            for h in chunk {
                let x = sp.chart(h);
                for t in sp.tiles_near(x, r) {
                    let w = job.tiling.tile_owner(sp, t);
                    if w != me && seen[w] != i {
                        seen[w] = i;
                        bufs[w].extend_from_slice(&h.to_bytes());
                    }
                }
                i += 1;
            }
        })?;
        for (w, b) in bufs.into_iter().enumerate() {
            if !b.is_empty() {
                out[w].push((id.encode(), b));
            }
        }
    }
    Ok(out)
}

/// The kernel bandwidth of side `id` with `n` hits in all: h = C1·√(A/n),
/// as the estimator computes it.
fn bandwidth(
    job: &TileJob,
    id: SurfaceId,
    n: u64,
    estimator: &dyn Fn(usize) -> PlanarEstimator,
    k: usize,
) -> f32 {
    let surf = job.surfaces.of(id);
    let unit = (surf.area / n as f32).sqrt();
    let bw = job.s.c1 * unit;
    debug_assert_eq!(bw, estimator(k).bandwidth());
    bw
}

/// This worker's vertices of side `id` (those in its tiles), estimated
/// from its hits and its halo: their indices and r, g, b, and how many;
/// None when it owns no tile of the side or the side has no hits.
fn estimate_side<H: HitSource>(
    job: &TileJob,
    hits: &H,
    halo: &HashMap<u32, Vec<Hit>>,
    id: SurfaceId,
    me: usize,
    ctl: &mut Control,
    make: impl FnOnce() -> PlanarEstimator,
) -> Result<Estimated, DensityError> {
    let Some(sp) = job.tiling.split(id) else {
        return Ok(None);
    };
    let own = count(hits, id);
    let extra = halo.get(&id.encode()).map_or(&[][..], |v| &v[..]);
    if own == 0 && extra.is_empty() {
        return Ok(None);
    }
    let mut est = make();
    let keep: Vec<bool> = est
        .verts()
        .iter()
        .map(|&v| job.tiling.tile_owner(sp, sp.tile_of(v)) == me)
        .collect();
    let verts = keep.iter().filter(|k| **k).count() as u64;
    if verts == 0 {
        return Ok(None);
    }
    let idx: Vec<u32> = (0..keep.len() as u32)
        .filter(|&i| keep[i as usize])
        .collect();
    est.keep_only(keep);
    let cap = job.s.chunk_hits.max(1) as u64;
    each_chunk(hits, id, cap, ctl, |chunk| est.add(chunk))?;
    for c in extra.chunks(cap as usize) {
        ctl.check()?;
        est.add(c);
    }
    let e = est.finish();
    let rgb = idx
        .iter()
        .flat_map(|&i| e.h[i as usize].to_array())
        .collect();
    Ok(Some((idx, rgb, verts)))
}

/// The home's over-meshes of its tiled sides, from every worker's tile
/// vertices: a side with hits, and the (black) front of a diffuse surface
/// without, as the single-process bake makes them.
fn assemble_home(
    job: &TileJob,
    sides: &[SurfaceId],
    n: &[u64],
    me: usize,
    peers: usize,
    parts: Vec<TileH>,
    estimator: &dyn Fn(usize) -> PlanarEstimator,
) -> Vec<PlanarMesh> {
    let mut by_side: HashMap<u32, Vec<SideH>> = HashMap::new();
    for (_, _, p) in parts {
        for part in p {
            by_side.entry(part.0).or_default().push(part);
        }
    }
    let mut out = Vec::new();
    for (k, &id) in sides.iter().enumerate() {
        if super::owner(job.surfaces, id, peers) != me {
            continue;
        }
        let surf = job.surfaces.of(id);
        if n[k] == 0 && (id.back || !surf.diffuse) {
            continue;
        }
        let mut est = estimator(k);
        let nv = est.verts().len();
        est.keep_only(vec![false; nv]);
        let mut e = est.finish();
        for (_, idx, rgb) in by_side.remove(&id.encode()).unwrap_or_default() {
            for (i, c) in idx.iter().zip(rgb.chunks_exact(3)) {
                if let Some(h) = e.h.get_mut(*i as usize) {
                    *h = Vec3::new(c[0], c[1], c[2]);
                }
            }
        }
        out.push(PlanarMesh::unindexed(
            id,
            e.verts,
            e.tris,
            e.h,
            e.bandwidth,
            n[k],
        ));
    }
    out
}
