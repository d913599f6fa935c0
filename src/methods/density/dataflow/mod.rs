//! The bake as a timely dataflow, across worker threads or processes
//! (`kalos bake --workers N`, `--process I --processes N --hostfile FILE`).
//!
//! The paper's pipeline (§4: trace, "sort by surface id", estimate,
//! decimate) with the sort done by the exchange, and work split below the
//! surface:
//!
//! 0. every worker traces the same small pilot (the bake's first chunks)
//!    and deals the tiles of the large planar surfaces by its hits
//!    ([`Tiling`], module `tiles`); every other surface is owned whole
//!    ([`owner`]);
//! 1. every worker traces its share of each batch of particle chunks and
//!    sends each hit to the worker that owns its tile, or its surface; the
//!    owner writes them to its own hit file, in its own scratch directory
//!    (bounded memory: [`super::hitfile`]);
//! 2. every worker estimates its own surfaces
//!    ([`pipeline::estimate_owned`]), then its tiles: with every tiled
//!    surface's hit count known, the hits within a kernel width of another
//!    worker's tile go to it as a halo, each worker estimates its tiles'
//!    over-mesh vertices, and sends them to the surface's owner, which
//!    assembles the surface's over-mesh;
//! 3. the white point is a percentile over all over-mesh vertices: worker 0
//!    gathers the vertex luminances and sends the white point back;
//! 4. every worker decimates its own surfaces (a tiled surface whole, at
//!    its owner: decimation is not split), and worker 0 gathers the meshes
//!    and assembles the [`Bake`], which the caller writes.
//!
//! Same bytes as [`super::bake`]. A planar estimate sums kernel terms in
//! exact fixed point ([`super::kernel::FIXED_BITS`]), so a vertex's value
//! does not depend on the order of its hits, nor on which worker holds
//! them: a tile's worker, holding every hit within a kernel width of its
//! vertices, computes them bit for bit as one process does. The owner of a
//! curved shape restores the order of the single-process bake (its 3D
//! estimate sums in f32): the batches are timely's timestamps, and once a
//! batch is complete at a worker its hit packets are written in (channel
//! run, chunk) order, which is the order in which one process pushes them.
//! Each chunk's particles come from the chunk's own stream whoever traces
//! it. Everything after depends on a surface's hits alone, or (the white
//! point, the statistics) on sets, gathered and sorted by surface before
//! use.
//!
//! Failures. Every worker takes part in every round, so that a failure
//! never leaves a peer waiting: a worker that fails or is cancelled while
//! tracing sends an abort to all; after that, each round carries every
//! worker's status, and all stop together with the first failure's reason.
//! A process that dies ends the connections to it: the others stop with
//! [`DataflowError::Lost`], naming it and its address.

use std::cell::RefCell;
use std::collections::BTreeMap;
use std::rc::Rc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{mpsc, Arc, Mutex};
use std::time::{Duration, Instant};

use timely::container::CapacityContainerBuilder;
use timely::dataflow::channels::pact::Exchange;
use timely::dataflow::operators::{Operator, Probe};
use timely::dataflow::{InputHandleVec, ProbeHandle};
use timely::worker::Worker;
use timely::WorkerConfig;

mod gather;
mod layout;
mod tiles;

pub use layout::{read_hostfile, DataflowError, Workers};
pub use tiles::{Tiling, TILES_PER_WORKER};

use super::control::{Control, Limits, Phase, Tick};
use super::decimate::Report;
use super::hits::{Hit, HitSink, HIT_BYTES};
use super::mesh::PlanarMesh;
use super::particles;
use super::pipeline;
use super::scratch::ScratchDir;
use super::surfaces::{Kind, SurfaceId, Surfaces};
use super::{Bake, DensityError, MethodError, Settings, World};

/// What a dataflow bake made: the bake at the process of worker 0, and
/// what this process sent to other workers.
#[derive(Debug)]
pub struct DataflowBake {
    /// The bake (at the process hosting worker 0; None elsewhere).
    pub bake: Option<Bake>,
    /// Hit records this process's workers sent to other workers.
    pub hits_sent: u64,
    /// Their bytes as serialized for the exchange (records and packet
    /// headers).
    pub bytes_sent: u64,
}

/// The worker that owns a surface side: a planar side by its surface, a
/// curved one by its shape (the 3D kernel is estimated over the whole shape
/// and side).
pub fn owner(surfaces: &Surfaces, id: SurfaceId, peers: usize) -> usize {
    let key = match surfaces.get(id) {
        Some(s) if s.kind == Kind::Curved => s.shape as u64,
        _ => id.index as u64,
    };
    (key % peers.max(1) as u64) as usize
}

/// A worker's status in a round: 0 ok, 1 cancelled, 2 failed (with the
/// reason).
pub(crate) type Status = (u8, String);

pub(crate) const OK: u8 = 0;
pub(crate) const CANCELLED: u8 = 1;
const FAILED: u8 = 2;

pub(crate) fn status_of<T, E: std::error::Error + 'static>(r: &Result<T, E>) -> Status {
    let Err(e) = r else {
        return (OK, String::new());
    };
    let e: &(dyn std::error::Error + 'static) = e;
    let cancelled = matches!(
        e.downcast_ref::<DensityError>(),
        Some(DensityError::Cancelled { .. })
    ) || matches!(
        e.downcast_ref::<DataflowError>(),
        Some(DataflowError::Density(DensityError::Cancelled { .. }))
    );
    if cancelled {
        (CANCELLED, String::new())
    } else {
        (FAILED, super::error_chain(e))
    }
}

/// After a round that carried every worker's status: this worker's own
/// error, else the first peer's (a cancel before a failure), else `local`.
pub(crate) fn first_failure<'a, T, E: Into<DataflowError>>(
    statuses: impl Iterator<Item = (usize, &'a Status)>,
    local: Result<T, E>,
) -> Result<T, DataflowError> {
    let local = local.map_err(Into::into)?;
    let mut worst: Option<(usize, &Status)> = None;
    for (w, st) in statuses {
        if st.0 != OK && worst.is_none_or(|(_, b)| st.0 < b.0) {
            worst = Some((w, st));
        }
    }
    match worst {
        None => Ok(local),
        Some((_, st)) if st.0 == CANCELLED => Err(DensityError::Cancelled { rays: 0 }.into()),
        Some((worker, st)) => Err(DataflowError::Peer {
            worker,
            reason: st.1.clone(),
        }),
    }
}

/// Bakes on the dataflow laid out by `workers`. `ctl` sees the progress
/// of this process's first worker, and its cancel flag stops every local
/// worker (and, through them, every peer). Returns the bake at the process
/// of worker 0.
///
/// The world is shared with timely's worker threads, which outlive any
/// borrow, hence the [`Arc`].
pub fn bake_dataflow(
    world: Arc<World>,
    s: &Settings,
    workers: &Workers,
    ctl: &mut Control,
) -> Result<DataflowBake, DataflowError> {
    let done = run_dataflow(world, s, workers, ctl, run_worker)?;
    Ok(DataflowBake {
        bake: done.out,
        hits_sent: done.hits_sent,
        bytes_sent: done.bytes_sent,
    })
}

/// A job every worker of a dataflow runs ([`run_dataflow`]): given its
/// worker, the world, its surfaces, the settings and its control, it
/// returns its [`Part`].
pub trait WorkerJob<P>:
    Fn(&mut Worker, &World, &Surfaces, &Settings, &mut Control) -> Result<Part<P>, DataflowError>
    + Send
    + Sync
    + 'static
{
}

impl<P, F> WorkerJob<P> for F where
    F: Fn(
            &mut Worker,
            &World,
            &Surfaces,
            &Settings,
            &mut Control,
        ) -> Result<Part<P>, DataflowError>
        + Send
        + Sync
        + 'static
{
}

/// Runs `job` on every worker of the dataflow laid out by `workers`, the
/// progress of this process's first worker relayed to `ctl` and its
/// cancel flag to every worker; returns what this process's workers
/// made: the output at the process of worker 0 (the display-mesh bake,
/// [`bake_dataflow`]; the lightmap bake,
/// [`crate::bake::lightmap::dataflow`]).
pub fn run_dataflow<P: Send + 'static>(
    world: Arc<World>,
    s: &Settings,
    workers: &Workers,
    ctl: &mut Control,
    job: impl WorkerJob<P>,
) -> Result<Part<P>, DataflowError> {
    s.check().map_err(DensityError::from)?;
    if let Some(p) = &s.keep_hits {
        return Err(DensityError::from(MethodError(format!(
            "cannot keep the hits at {}: a dataflow bake has one hit file per worker",
            p.display()
        )))
        .into());
    }
    let config = workers.config()?;
    if matches!(workers, Workers::Cluster { .. }) {
        layout::watch_network();
    }
    let first_local = match workers {
        Workers::Threads(_) => 0,
        Workers::Cluster {
            threads, process, ..
        } => threads * process,
    };
    let surfaces = Arc::new(super::surfaces::build(&world.scene));
    let settings = s.clone();
    let cancel = Arc::new(AtomicBool::new(false));
    let (tx, rx) = mpsc::channel::<Tick>();
    let (builders, others) = config.try_build().map_err(DataflowError::Network)?;
    let flag = Arc::clone(&cancel);
    let local_workers = builders.len();
    // The workers' results go through this rather than their threads'
    // return values: when a peer process dies, timely's network threads
    // panic and the join of the workers panics with them
    let finished = Arc::new(Mutex::new(Vec::new()));
    let sink = Arc::clone(&finished);
    let guards =
        timely::execute::execute_from(builders, others, WorkerConfig::default(), move |worker| {
            let tx = tx.clone();
            let mut forward = |t: &Tick| {
                let _ = tx.send(*t);
            };
            let mut c = Control::new(Instant::now(), Limits::default(), Some(&*flag));
            if worker.index() == first_local {
                c = c.on_tick(&mut forward);
            }
            let r = job(worker, &world, &surfaces, &settings, &mut c);
            sink.lock().unwrap_or_else(|e| e.into_inner()).push(r);
        })
        .map_err(DataflowError::Network)?;

    // Progress and the cancel flag, relayed until every local worker ends
    loop {
        match rx.recv_timeout(Duration::from_millis(50)) {
            Ok(t) => {
                ctl.set_rays(t.rays);
                ctl.tick(t.phase, t.done, t.total);
            }
            Err(mpsc::RecvTimeoutError::Timeout) => {}
            Err(mpsc::RecvTimeoutError::Disconnected) => break,
        }
        if ctl.cancelled() {
            cancel.store(true, Ordering::Relaxed);
        }
    }
    let joined = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| guards.join()));
    let mut results = std::mem::take(&mut *finished.lock().unwrap_or_else(|e| e.into_inner()));
    let panicked = joined.map_or(true, |j| j.iter().any(|r| r.is_err()));
    if panicked || results.len() < local_workers {
        let lost = layout::lost_peer().map(|(process, cause)| DataflowError::Lost {
            process,
            address: workers.address(process).unwrap_or("?").to_string(),
            cause,
        });
        results.insert(
            0,
            Err(lost.unwrap_or(DataflowError::Worker(
                "the connection to another process was lost, or the worker panicked".into(),
            ))),
        );
    }

    // This process's outcome: its own failures first, then a bake
    let mut done = Part {
        out: None,
        hits_sent: 0,
        bytes_sent: 0,
    };
    let mut first_err = None;
    for r in results {
        match r {
            Ok(p) => {
                done.hits_sent += p.hits_sent;
                done.bytes_sent += p.bytes_sent;
                if p.out.is_some() {
                    done.out = p.out;
                }
            }
            Err(e) => {
                let own = !matches!(e, DataflowError::Peer { .. });
                let have_peer = matches!(first_err, Some(DataflowError::Peer { .. }));
                if first_err.is_none() || own && have_peer {
                    first_err = Some(e);
                }
            }
        }
    }
    match first_err {
        Some(e) => Err(e),
        None => Ok(done),
    }
}

/// What one worker returns: its output (at worker 0), and the hit
/// records it sent to other workers with their bytes.
pub struct Part<P> {
    /// The output (worker 0's; None elsewhere).
    pub out: Option<P>,
    /// Hit records sent to other workers.
    pub hits_sent: u64,
    /// Their bytes as serialized.
    pub bytes_sent: u64,
}

/// A packet of hits for one owner: (owner, channel run, chunk, the records
/// as bytes). A channel run of `u32::MAX` is an abort: the sender stopped
/// (its status is in the bytes: the code, then the reason).
type Packet = (u32, u32, u64, Vec<u8>);

const ABORT: u32 = u32::MAX;

/// Per-worker figures sent to worker 0: hits received, rays traced,
/// over-mesh triangles, most records sorted at once, most hits in memory,
/// and its estimate work: hits (with the halo), over-mesh vertices, and
/// the halo's hits.
type Figures = (u64, u64, u64, u64, u64, u64, u64, u64);

/// A decimated planar mesh on the wire: surface (encoded), vertices (x, y
/// pairs), triangles, irradiance (r, g, b triples), bandwidth, hits, and
/// its decimation report (max error, sum of errors, vertices removed).
type PlanarWire = (
    u32,
    Vec<f32>,
    Vec<[u32; 3]>,
    Vec<f32>,
    f32,
    u64,
    f32,
    f64,
    u64,
);

/// A worker's status and vertex luminances, for the white point.
type Luminances = (u32, Status, Vec<f32>);

/// A worker's part of the bake, to worker 0: its index, status, figures
/// and meshes.
type PartWire = (u32, Status, Figures, Vec<PlanarWire>, Vec<CurvedWire>);

/// A curved mesh on the wire: shape, back side, triangles, irradiance
/// (nine numbers a triangle).
type CurvedWire = (u32, bool, Vec<u32>, Vec<f32>);

/// What a worker estimated: its meshes and figures.
struct Local {
    est: pipeline::Estimated,
    figures: Figures,
    particles: u64,
    hits_sent: u64,
    bytes_sent: u64,
}

/// A worker's estimate with its tiles' meshes, and its figures.
fn local_of(
    mut est: pipeline::Estimated,
    t: tiles::TileOut,
    tr: &Traced,
    hits: &impl super::hits::HitSource,
) -> Local {
    let verts = est.planar.iter().map(|m| m.verts.len() as u64).sum::<u64>()
        + est
            .curved
            .iter()
            .map(|m| 3 * m.tris.len() as u64)
            .sum::<u64>()
        + t.verts;
    est.planar.extend(t.meshes);
    est.planar.sort_by_key(|m| m.surface);
    let tris = est.planar.iter().map(|m| m.tris.len() as u64).sum::<u64>()
        + est.curved.iter().map(|m| m.tris.len() as u64).sum::<u64>();
    let figures = (
        tr.hits_received,
        tr.rays,
        tris,
        hits.max_sort_records(),
        est.max_hits_in_memory,
        tr.hits_received + t.halo_received,
        verts,
        t.halo_received,
    );
    Local {
        est,
        figures,
        particles: tr.particles,
        hits_sent: tr.hits_sent + t.halo_sent,
        bytes_sent: tr.bytes_sent + t.halo_bytes,
    }
}

/// Runs one worker of the bake; returns the bake at worker 0.
fn run_worker(
    worker: &mut Worker,
    world: &World,
    surfaces: &Surfaces,
    s: &Settings,
    ctl: &mut Control,
) -> Result<Part<Bake>, DataflowError> {
    let me = worker.index();
    let peers = worker.peers();
    let scene = &world.scene;

    // Phase 1: the pilot deals the tiles; trace, exchange and group
    let t = Instant::now();
    let Phase1 {
        tiling,
        scratch,
        grouped,
    } = trace_and_group(worker, world, surfaces, s, None, ctl);
    let t_trace = t.elapsed().as_secs_f64();
    let t = Instant::now();

    // Phase 2: this worker's surfaces, then its tiles
    let owns = |id: SurfaceId| owner(surfaces, id, peers) == me && !tiling.is_split(id);
    let (grouped, est) = match grouped {
        Ok((tr, hits)) => {
            let est = pipeline::estimate_owned(scene, surfaces, s, &hits, tr.phi, ctl, &owns);
            (Some((tr, hits)), est.map_err(DataflowError::from))
        }
        Err(e) => (None, Err(e)),
    };
    let job = tiles::TileJob {
        scene,
        surfaces,
        tiling: &tiling,
        s,
        phi: grouped.as_ref().map_or(0.0, |g| g.0.phi),
    };
    let st = status_of(&est);
    let tiled = tiles::run(worker, &job, grouped.as_ref().map(|g| &g.1), st, ctl);
    let local: Result<Local, DataflowError> = est.and_then(|est| {
        let t = tiled?;
        let (tr, hits) = grouped.ok_or(DataflowError::Worker("no hit file".into()))?;
        Ok(local_of(est, t, &tr, &hits))
    });
    drop(scratch);
    let t_estimate = t.elapsed().as_secs_f64();

    // The white point: the vertex luminances to worker 0, its percentile back
    let lum = match &local {
        Ok(l) => pipeline::vertex_luminances(scene, surfaces, &l.est.planar),
        Err(_) => Vec::new(),
    };
    let st = status_of(&local);
    let mut items: Vec<(u64, Luminances)> = (1..peers)
        .map(|w| (w as u64, (me as u32, st.clone(), Vec::new())))
        .collect();
    items.push((0, (me as u32, st, lum)));
    let mut got = round(worker, items);
    got.sort_by_key(|g| g.0);
    let local = first_failure(got.iter().map(|g| (g.0 as usize, &g.1)), local)?;
    let w0 = if me == 0 {
        pipeline::white_point_of(got.into_iter().flat_map(|g| g.2).collect())
    } else {
        drop(got);
        0.0
    };
    let items = if me == 0 {
        (0..peers).map(|w| (w as u64, w0)).collect()
    } else {
        Vec::new()
    };
    let w0 = round(worker, items).first().copied().unwrap_or(1.0);

    // Phase 3: decimate this worker's surfaces, then gather at worker 0
    let t = Instant::now();
    let Local {
        est,
        figures,
        particles,
        hits_sent,
        bytes_sent,
    } = local;
    let decimated = decimate_owned(scene, surfaces, est.planar, w0, s, ctl);
    let st = status_of(&decimated);
    let (planar, reports) = decimated.unwrap_or_default();
    let t_decimate = t.elapsed().as_secs_f64();
    let mine = (
        me as u32,
        st.clone(),
        figures,
        gather::to_wire_planar(planar, reports),
        gather::to_wire_curved(est.curved),
    );
    let mut parts = round(worker, vec![(0, mine)]);
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
    let mut bake = gather::assemble(surfaces, s, w0, parts);
    bake.stats.particles = particles;
    bake.stats.t_trace = t_trace;
    bake.stats.t_estimate = t_estimate;
    bake.stats.t_decimate = t_decimate;
    Ok(Part {
        out: Some(bake),
        hits_sent,
        bytes_sent,
    })
}

/// A worker's hits after phase 1, grouped by surface side.
pub type Grouped = <super::hitfile::HitWriter as HitSink>::Source;

/// What phase 1 leaves a worker ([`trace_and_group`]).
pub struct Phase1 {
    /// The tiles of the large planar surfaces, dealt.
    pub tiling: Tiling,
    /// The worker's scratch directory (its hit file is in it), unless it
    /// could not be made.
    pub scratch: Option<ScratchDir>,
    /// What it traced and its hits, or why it failed.
    pub grouped: Result<(Traced, Grouped), DataflowError>,
}

/// Phase 1 at one worker: the pilot (or `deal`'s points, see
/// [`Tiling::by_points`]) deals the tiles ([`Tiling`]); the
/// worker traces its share of the particles and exchanges them, each hit
/// to the owner of its tile or surface, into its own hit file; then
/// groups them. The exchange runs even when the scratch directory
/// failed, so that the peers hear of it.
pub fn trace_and_group(
    worker: &mut Worker,
    world: &World,
    surfaces: &Surfaces,
    s: &Settings,
    deal: Option<&[(SurfaceId, glam::Vec2)]>,
    ctl: &mut Control,
) -> Phase1 {
    let tiling = match deal {
        Some(points) => Tiling::by_points(surfaces, worker.peers(), points),
        None => Tiling::new(
            surfaces,
            worker.peers(),
            &tiles::pilot_hits(world, surfaces, s),
        ),
    };
    let made = ScratchDir::new(s).and_then(|dir| {
        let sink = pipeline::file_sink(surfaces, s, &dir)?;
        Ok((dir, sink))
    });
    let (scratch, traced) = match made {
        Ok((dir, sink)) => (
            Some(dir),
            trace_exchange(worker, world, (surfaces, &tiling), s, Some(sink), ctl),
        ),
        Err(e) => {
            let _ = trace_exchange(worker, world, (surfaces, &tiling), s, None, ctl);
            (None, Err(e.into()))
        }
    };
    let grouped = traced.and_then(|mut tr| {
        ctl.tick(Phase::Group, 0, 1);
        let sink = tr.sink.take();
        let sink = sink.ok_or(DataflowError::Worker("no hit sink".into()))?;
        let hits = pipeline::group(sink)?;
        Ok((tr, hits))
    });
    Phase1 {
        tiling,
        scratch,
        grouped,
    }
}

/// What a worker's phase 1 did.
pub struct Traced {
    /// Its hit file, unless it could not be made.
    sink: Option<super::hitfile::HitWriter>,
    /// φ = Φ/n.
    pub phi: f64,
    /// Particles of all channel runs (every worker counts them all).
    pub particles: u64,
    /// Rays this worker traced.
    pub rays: u64,
    /// Hit records it received (its surfaces' hits).
    pub hits_received: u64,
    /// Hit records it sent to other workers.
    pub hits_sent: u64,
    /// Their bytes.
    pub bytes_sent: u64,
}

impl Traced {
    /// Nothing traced yet by `tracers` (one per channel run, `chunks` chunks
    /// each) from the luminaires `lums`: φ and the particle count set.
    fn start(
        tracers: &[particles::Tracer],
        lums: &[particles::Luminaire],
        chunks: u64,
        s: &Settings,
    ) -> Self {
        let per_run = tracers
            .first()
            .map_or(s.particles, |t| t.particles_in(0, chunks));
        Traced {
            sink: None,
            phi: particles::phi_unit(lums, per_run),
            particles: tracers.iter().map(|t| t.particles_in(0, chunks)).sum(),
            rays: 0,
            hits_received: 0,
            hits_sent: 0,
            bytes_sent: 0,
        }
    }
}

/// What the receiving side of the exchange holds: the hit file, hits
/// written, the first write error, and an abort heard from a peer.
struct Receiver {
    sink: Option<super::hitfile::HitWriter>,
    hits: u64,
    error: Option<super::hitfile::HitFileError>,
    abort: Option<(usize, Status)>,
}

/// Bytes of a packet as serialized for the exchange (bincode: three
/// integers and a length-prefixed byte vector).
fn packet_bytes(p: &Packet) -> u64 {
    4 + 4 + 8 + 8 + p.3.len() as u64
}

/// Phase 1 at one worker: its share of every batch of chunks traced, the
/// hits exchanged by owner, and its own surfaces' hits written to `sink`
/// batch by batch in the single-process order.
fn trace_exchange(
    worker: &mut Worker,
    world: &World,
    (surfaces, tiling): (&Surfaces, &Tiling),
    s: &Settings,
    sink: Option<super::hitfile::HitWriter>,
    ctl: &mut Control,
) -> Result<Traced, DataflowError> {
    let route = Route {
        surfaces,
        tiling,
        me: worker.index(),
        peers: worker.peers(),
    };
    let recv = Rc::new(RefCell::new(Receiver {
        sink,
        hits: 0,
        error: None,
        abort: None,
    }));
    let failed_here = recv.borrow().sink.is_none();
    let (mut input, probe) = group_by_surface(worker, &recv);

    // The tracers, as in `pipeline::trace_within`
    let lums = particles::luminaires(world);
    let tracers = super::pipeline::tracers(world, surfaces, &lums, s);
    let chunks = tracers.first().map_or(0, |t| t.chunks());
    let mut tr = Traced::start(&tracers, &lums, chunks, s);

    // Batch by batch (the single-process batches: their order is the
    // order of the hits), this worker's slice of each
    let batch = particles::BUDGET_BATCH;
    let mut c0 = 0;
    ctl.start_tracing();
    ctl.tick(Phase::Trace, 0, s.particles);
    while c0 < chunks && !failed_here {
        let heard = recv.borrow().abort.is_some() || recv.borrow().error.is_some();
        if heard || ctl.cancelled() {
            break;
        }
        let c1 = (c0 + batch).min(chunks);
        let (a, b) = route.slice(c0, c1);
        for (run, t) in tracers.iter().enumerate() {
            if a == b {
                break;
            }
            let results = t.trace_chunks(a, b, ctl.cancel_flag());
            if ctl.cancelled() {
                break;
            }
            route.send(results, run as u32, a, &mut input, &mut tr);
        }
        if ctl.cancelled() {
            break;
        }
        ctl.set_rays(tr.rays);
        ctl.tick(Phase::Trace, tracers[0].particles_in(0, c1), s.particles);
        c0 = c1;
        let next = *input.time() + 1;
        input.advance_to(next);
        // One batch may be in flight while the next is traced: memory
        // stays at about two batches of hits per worker
        while probe.less_than(&(next - 1)) {
            worker.step_or_park(Some(Duration::from_millis(5)));
        }
    }

    // A stop here (cancelled, no hit file, a failed write) is told to
    // every peer before the input closes, so that they stop tracing too
    let write_error = recv.borrow_mut().error.take();
    let stop = stop_here(failed_here, write_error, ctl, tr.rays);
    if let Some(((code, reason), _)) = &stop {
        route.abort(*code, reason, &mut input);
    }
    drop(input);
    while !probe.done() {
        worker.step_or_park(Some(Duration::from_millis(5)));
    }
    if let Some((_, e)) = stop {
        return Err(e);
    }
    let mut r = recv.borrow_mut();
    if let Some(e) = r.error.take() {
        // a write failed after the last batch: the peers hear of it at
        // the white point round
        return Err(DensityError::from(e).into());
    }
    if let Some((worker, st)) = r.abort.take() {
        return Err(peer_error(worker, &st));
    }
    tr.sink = r.sink.take();
    tr.hits_received = r.hits;
    Ok(tr)
}

/// The exchange's operator, "sort by surface id" (§4 of the paper): packets
/// exchanged by owner, stashed by batch, and written once the batch is
/// complete everywhere (the capability held until then keeps the probe
/// from passing it). Returns the input the tracers feed and the probe.
fn group_by_surface(
    worker: &mut Worker,
    recv: &Rc<RefCell<Receiver>>,
) -> (InputHandleVec<u64, Packet>, ProbeHandle<u64>) {
    let mut input = InputHandleVec::<u64, Packet>::new();
    let probe = ProbeHandle::new();
    worker.dataflow::<u64, _, _>(|scope| {
        let recv = Rc::clone(recv);
        input
            .to_stream(scope)
            .unary_frontier::<CapacityContainerBuilder<Vec<()>>, _, _, _>(
                Exchange::new(|p: &Packet| p.0 as u64),
                "GroupBySurface",
                move |_cap, _info| {
                    let mut stash: BTreeMap<u64, (_, Vec<Packet>)> = BTreeMap::new();
                    move |(input, frontier), output| {
                        input.for_each(|cap, data| {
                            for p in data.drain(..) {
                                if p.1 == ABORT {
                                    hear_abort(&mut recv.borrow_mut(), &p);
                                    continue;
                                }
                                let Some(&t) = cap.least() else {
                                    continue;
                                };
                                stash
                                    .entry(t)
                                    .or_insert_with(|| {
                                        (cap.delayed(&t, output.output_index()), Vec::new())
                                    })
                                    .1
                                    .push(p);
                            }
                        });
                        while let Some(entry) = stash.first_entry() {
                            if frontier.less_equal(entry.key()) {
                                break;
                            }
                            let (_cap, packets) = entry.remove();
                            write_batch(&mut recv.borrow_mut(), packets);
                        }
                    }
                },
            )
            .probe_with(&probe);
    });
    (input, probe)
}

/// An abort packet from a peer: its status is kept unless one with a
/// lower code was heard before.
fn hear_abort(r: &mut Receiver, p: &Packet) {
    let code = p.3.first().copied().unwrap_or(FAILED);
    let why = String::from_utf8_lossy(p.3.get(1..).unwrap_or(&[]));
    if r.abort.as_ref().is_none_or(|a| code < a.1 .0) {
        r.abort = Some((p.2 as usize, (code, why.into_owned())));
    }
}

/// A batch complete everywhere: its packets written to the hit file in
/// (channel run, chunk) order, the order of the single-process bake; after
/// a write error the hits are only counted.
fn write_batch(r: &mut Receiver, mut packets: Vec<Packet>) {
    packets.sort_unstable_by_key(|p| (p.1, p.2));
    for p in packets {
        let hits: Vec<Hit> = p.3.chunks_exact(HIT_BYTES).map(Hit::from_bytes).collect();
        r.hits += hits.len() as u64;
        if r.error.is_some() {
            continue;
        }
        if let Some(sink) = r.sink.as_mut() {
            if let Err(e) = sink.push(&hits) {
                r.error = Some(e);
            }
        }
    }
}

/// Where this worker's hits go: worker `me` of `peers`, the surfaces owned
/// by [`owner`], the tiles of tiled surfaces by their owners ([`Tiling`]).
struct Route<'a> {
    surfaces: &'a Surfaces,
    tiling: &'a Tiling,
    me: usize,
    peers: usize,
}

impl Route<'_> {
    /// This worker's slice `a..b` of the batch of chunks `c0..c1`.
    fn slice(&self, c0: u64, c1: u64) -> (u64, u64) {
        let n = c1 - c0;
        let (me, peers) = (self.me as u64, self.peers as u64);
        (c0 + n * me / peers, c0 + n * (me + 1) / peers)
    }

    /// Sends the hits of channel run `run`'s chunks from `a` on (`results`,
    /// in chunk order) to their owners, one packet per owner and chunk, and
    /// counts the rays and what leaves this worker in `tr`.
    fn send(
        &self,
        results: Vec<(Vec<Hit>, u64)>,
        run: u32,
        a: u64,
        input: &mut InputHandleVec<u64, Packet>,
        tr: &mut Traced,
    ) {
        for (k, (hits, rays)) in results.into_iter().enumerate() {
            tr.rays += rays;
            let mut by_owner: Vec<Vec<u8>> = vec![Vec::new(); self.peers];
            for h in hits {
                by_owner[self.tiling.owner_of_hit(self.surfaces, &h)]
                    .extend_from_slice(&h.to_bytes());
            }
            for (w, bytes) in by_owner.into_iter().enumerate() {
                if bytes.is_empty() {
                    continue;
                }
                let p: Packet = (w as u32, run, a + k as u64, bytes);
                if w != self.me {
                    tr.hits_sent += (p.3.len() / HIT_BYTES) as u64;
                    tr.bytes_sent += packet_bytes(&p);
                }
                input.send(p);
            }
        }
    }

    /// Tells every peer (this worker too) that this worker stopped, with
    /// its status `code` and `reason`.
    fn abort(&self, code: u8, reason: &str, input: &mut InputHandleVec<u64, Packet>) {
        let mut why = vec![code];
        why.extend_from_slice(reason.as_bytes());
        for w in 0..self.peers {
            input.send((w as u32, ABORT, self.me as u64, why.clone()));
        }
    }
}

/// Why this worker stops after tracing, if it does: no hit file, a failed
/// write, or a cancel; the status told to the peers and the error returned.
fn stop_here(
    failed_here: bool,
    write_error: Option<super::hitfile::HitFileError>,
    ctl: &Control,
    rays: u64,
) -> Option<(Status, DataflowError)> {
    if failed_here {
        let st = (FAILED, "could not make its scratch directory".to_string());
        Some((st, DataflowError::Worker("no hit file".into())))
    } else if let Some(e) = write_error {
        let e = DataflowError::from(DensityError::from(e));
        Some(((FAILED, super::error_chain(&e)), e))
    } else if ctl.cancelled() {
        let e = DensityError::Cancelled { rays }.into();
        Some(((CANCELLED, String::new()), e))
    } else {
        None
    }
}

/// The error a worker returns once a peer aborted.
fn peer_error(worker: usize, st: &Status) -> DataflowError {
    if st.0 == CANCELLED {
        DensityError::Cancelled { rays: 0 }.into()
    } else {
        DataflowError::Peer {
            worker,
            reason: st.1.clone(),
        }
    }
}

/// One all-to-some round: each item goes to the worker it names; returns
/// what this worker received (in no particular order) once every worker's
/// items have arrived.
pub(crate) fn round<T>(worker: &mut Worker, items: Vec<(u64, T)>) -> Vec<T>
where
    T: timely::ExchangeData + Clone,
{
    let got = Rc::new(RefCell::new(Vec::new()));
    let mut input = InputHandleVec::<u64, (u64, T)>::new();
    let probe = ProbeHandle::new();
    worker.dataflow::<u64, _, _>(|scope| {
        let got = Rc::clone(&got);
        input
            .to_stream(scope)
            .unary_frontier::<CapacityContainerBuilder<Vec<()>>, _, _, _>(
                Exchange::new(|x: &(u64, T)| x.0),
                "Round",
                move |_cap, _info| {
                    move |(input, _frontier), _output| {
                        input.for_each(|_cap, data| {
                            got.borrow_mut().extend(data.drain(..).map(|x| x.1));
                        });
                    }
                },
            )
            .probe_with(&probe);
    });
    for it in items {
        input.send(it);
    }
    drop(input);
    while !probe.done() {
        worker.step_or_park(Some(Duration::from_millis(5)));
    }
    let out = std::mem::take(&mut *got.borrow_mut());
    out
}

/// Phase 3 at one worker: its planar over-meshes decimated (in slices, the
/// cancel flag read between them), with each mesh's report.
fn decimate_owned(
    scene: &crate::scene::Scene,
    surfaces: &Surfaces,
    planar: Vec<PlanarMesh>,
    w0: f32,
    s: &Settings,
    ctl: &mut Control,
) -> Result<(Vec<PlanarMesh>, Vec<Report>), DensityError> {
    if !s.decimate {
        let n = planar.len();
        return Ok((planar, vec![Report::default(); n]));
    }
    let out = pipeline::decimate_each(scene, surfaces, planar, w0, s.epsilon, ctl)?;
    Ok(out.into_iter().unzip())
}
