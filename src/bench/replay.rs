//! Replaying recorded ray sets through ray cores, timed, and comparing their
//! answers. Only the tracing is timed: the rays are in memory before the
//! clock starts, and the answers go to a buffer allocated before it.
//!
//! Every core replays every set on each thread count in turn, repetition by
//! repetition (kalos, then the next core, then kalos again), so that the load
//! of a shared machine falls on all of them alike; the figures are medians
//! and their ratios.

use std::time::Instant;

use glam::DVec3;
use rayon::prelude::*;

use super::rayset::{RaySets, SetKind};
use crate::accel::Accel;
use crate::geometry::Ray;
use crate::scene::Scene;

/// Rays handed to a core at once (one rayon task).
const CHUNK: usize = 1024;

/// A closest-hit answer: the scene triangle and the distance, or
/// [`Answer::MISS`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Answer {
    /// Scene triangle index (`u32::MAX`: no hit).
    pub tri: u32,
    /// Distance along the ray.
    pub t: f32,
}

impl Answer {
    /// No hit.
    pub const MISS: Answer = Answer {
        tri: u32::MAX,
        t: f32::INFINITY,
    };

    /// True when something was hit.
    pub fn is_hit(&self) -> bool {
        self.tri != u32::MAX
    }
}

/// A ray core that answers batches of rays. A batch may be traced one ray at
/// a time or as a stream, as the core prefers.
pub trait Tracer: Sync {
    /// Name as printed.
    fn name(&self) -> &str;
    /// The closest hit of each ray of `rays` into `out` (same length).
    fn closest(&self, rays: &[Ray], out: &mut [Answer]);
    /// Whether each ray of `rays` is blocked within `[tmin, tmax)`.
    fn occluded(&self, rays: &[Ray], out: &mut [bool]);
    /// True when this core is measured on `kind` (a packet or stream form
    /// may apply to coherent rays only).
    fn traces(&self, kind: SetKind) -> bool {
        let _ = kind;
        true
    }
}

/// kalos's own ray core, through [`Accel`]'s public queries.
pub struct KalosTracer<'a>(pub &'a Accel);

impl Tracer for KalosTracer<'_> {
    fn name(&self) -> &str {
        "kalos"
    }

    fn closest(&self, rays: &[Ray], out: &mut [Answer]) {
        for (r, o) in rays.iter().zip(out) {
            *o = match self.0.intersect(r) {
                Some(h) => Answer { tri: h.tri, t: h.t },
                None => Answer::MISS,
            };
        }
    }

    fn occluded(&self, rays: &[Ray], out: &mut [bool]) {
        for (r, o) in rays.iter().zip(out) {
            *o = self.0.occluded_ray(r);
        }
    }
}

/// kalos's own ray core answering closest-hit rays in packets of eight
/// neighbours ([`Accel::intersect_packet`]), as Embree's stream does; it is
/// measured on the coherent camera rays only, as the stream is.
pub struct KalosPacketTracer<'a>(pub &'a Accel);

impl Tracer for KalosPacketTracer<'_> {
    fn name(&self) -> &str {
        "kalos packets"
    }

    fn closest(&self, rays: &[Ray], out: &mut [Answer]) {
        // Eight at a time through a buffer on the stack: nothing is
        // allocated while the clock runs
        for (rs, os) in rays.chunks(8).zip(out.chunks_mut(8)) {
            let mut hits = [None; 8];
            self.0.intersect_packet(rs, &mut hits[..rs.len()]);
            for (h, o) in hits.iter().zip(os) {
                *o = match h {
                    Some(h) => Answer { tri: h.tri, t: h.t },
                    None => Answer::MISS,
                };
            }
        }
    }

    fn occluded(&self, rays: &[Ray], out: &mut [bool]) {
        KalosTracer(self.0).occluded(rays, out);
    }

    fn traces(&self, kind: SetKind) -> bool {
        kind == SetKind::Camera
    }
}

/// The answers of one core to one set.
#[derive(Clone, Debug, PartialEq)]
pub enum Answers {
    /// Closest hits.
    Closest(Vec<Answer>),
    /// Occlusion flags.
    Occluded(Vec<bool>),
}

impl Answers {
    /// A buffer for `n` answers of the query `kind` asks.
    fn new(kind: SetKind, n: usize) -> Self {
        if kind.closest_hit() {
            Answers::Closest(vec![Answer::MISS; n])
        } else {
            Answers::Occluded(vec![false; n])
        }
    }

    /// Rays that hit something (closest) or were blocked (occlusion).
    pub fn hits(&self) -> usize {
        match self {
            Answers::Closest(a) => a.iter().filter(|a| a.is_hit()).count(),
            Answers::Occluded(a) => a.iter().filter(|&&b| b).count(),
        }
    }
}

/// Traces `rays` with `tracer` on the current rayon pool into `out`.
fn trace(tracer: &dyn Tracer, rays: &[Ray], out: &mut Answers) {
    match out {
        Answers::Closest(a) => rays
            .par_chunks(CHUNK)
            .zip(a.par_chunks_mut(CHUNK))
            .for_each(|(r, o)| tracer.closest(r, o)),
        Answers::Occluded(a) => rays
            .par_chunks(CHUNK)
            .zip(a.par_chunks_mut(CHUNK))
            .for_each(|(r, o)| tracer.occluded(r, o)),
    }
}

/// Traces the set `kind` once with `tracer` on the current pool and returns
/// the answers (untimed; also warms the caches).
pub fn answers(tracer: &dyn Tracer, sets: &RaySets, kind: SetKind) -> Answers {
    let rays = sets.rays(kind);
    let mut out = Answers::new(kind, rays.len());
    trace(tracer, rays, &mut out);
    out
}

/// How far two closest-hit answers agree.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Agreement {
    /// Rays compared.
    pub rays: usize,
    /// Rays whose answers differ.
    pub differ: usize,
    /// Of those, closest hits on different triangles at the same distance
    /// (within 1e-4 relative): a shared edge or coincident triangles, where
    /// either answer is right.
    pub ties: usize,
    /// Of those, a hit in one core and a miss in the other.
    pub hit_vs_miss: usize,
}

/// Compares `other`'s answers with `reference`'s.
pub fn agreement(reference: &Answers, other: &Answers) -> Agreement {
    let mut g = Agreement::default();
    match (reference, other) {
        (Answers::Closest(a), Answers::Closest(b)) => {
            g.rays = a.len().min(b.len());
            for (x, y) in a.iter().zip(b) {
                if x.tri == y.tri {
                    continue;
                }
                g.differ += 1;
                if x.is_hit() != y.is_hit() {
                    g.hit_vs_miss += 1;
                } else if (x.t - y.t).abs() <= 1e-4 * x.t.abs().max(y.t.abs()).max(1e-3) {
                    g.ties += 1;
                }
            }
        }
        (Answers::Occluded(a), Answers::Occluded(b)) => {
            g.rays = a.len().min(b.len());
            g.differ = a.iter().zip(b).filter(|(x, y)| x != y).count();
            g.hit_vs_miss = g.differ;
        }
        _ => {}
    }
    g
}

/// A closest-hit ray on which the reference core (kalos) is wrong, for a
/// bug report: replay the set and look at ray `index`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Example {
    /// The ray's index in its set.
    pub index: usize,
    /// The reference core's answer.
    pub reference: Answer,
    /// The other core's answer.
    pub other: Answer,
    /// The search's distance and smallest barycentric weight, or None.
    pub search: Option<(f64, f64)>,
}

/// At most this many [`Example`]s are kept.
pub const EXAMPLES: usize = 3;

/// Who is right where two cores disagree, by a brute-force search of every
/// triangle in f64 (edges inclusive).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Verdict {
    /// Disagreeing rays judged (the first [`JUDGED`] at most).
    pub judged: usize,
    /// Rays where only the reference core (kalos) answers as the search.
    pub reference_right: usize,
    /// Rays where only the other core answers as the search.
    pub other_right: usize,
    /// Rays where both do (ties: another triangle at the search's distance).
    pub both_right: usize,
    /// Rays where neither does.
    pub neither_right: usize,
    /// Judged rays whose closest hit in the search lies within 1e-5
    /// (barycentric) of its triangle's edge: where a core that is not
    /// watertight may miss, or see the neighbour.
    pub on_edge: usize,
    /// The first closest-hit rays on which the reference core alone is
    /// wrong.
    pub examples: Vec<Example>,
}

/// At most this many disagreeing rays are judged: each costs a pass over
/// every triangle.
pub const JUDGED: usize = 200;

/// The closest hit of `r` over every triangle of `scene` by Möller–Trumbore
/// in f64, edges included, within `[tmin, tmax)`: the distance and the
/// smallest barycentric weight there (0 on an edge), or None.
fn brute_force(scene: &Scene, r: &Ray, any: bool) -> Option<(f64, f64)> {
    let v = |p: glam::Vec3| DVec3::new(p.x as f64, p.y as f64, p.z as f64);
    let (o, d) = (v(r.o), v(r.d));
    let (tmin, tmax) = (r.tmin as f64, r.tmax as f64);
    let mut best: Option<(f64, f64)> = None;
    for i in 0..scene.triangles.len() as u32 {
        let [a, b, c] = scene.tri_vertices(i).map(v);
        let (e1, e2) = (b - a, c - a);
        let p = d.cross(e2);
        let det = e1.dot(p);
        if det == 0.0 {
            continue;
        }
        let inv = 1.0 / det;
        let s = o - a;
        let u = s.dot(p) * inv;
        let q = s.cross(e1);
        let w = d.dot(q) * inv;
        if u < 0.0 || w < 0.0 || u + w > 1.0 {
            continue;
        }
        let t = e2.dot(q) * inv;
        if t >= tmin && t < tmax && best.is_none_or(|(bt, _)| t < bt) {
            best = Some((t, u.min(w).min(1.0 - u - w)));
            if any {
                break;
            }
        }
    }
    best
}

/// Judges the first [`JUDGED`] rays of `rays` on which `reference` and
/// `other` disagree against a brute-force f64 search over every triangle
/// (`brute_force`). An answer is right when it misses where the search
/// misses, or hits within 1e-4 (relative) of the search's distance (for occlusion: blocked where the search finds a hit).
pub fn judge(scene: &Scene, rays: &[Ray], reference: &Answers, other: &Answers) -> Verdict {
    let close = |a: &Answer, t: Option<f64>| match t {
        None => !a.is_hit(),
        Some(t) => a.is_hit() && (a.t as f64 - t).abs() <= 1e-4 * t.abs().max(1e-3),
    };
    let edge = |h: Option<(f64, f64)>| h.is_some_and(|(_, m)| m < 1e-5);
    let mut examples = Vec::new();
    let rights: Vec<(bool, bool, bool)> = match (reference, other) {
        (Answers::Closest(a), Answers::Closest(b)) => {
            let idx: Vec<usize> = (0..a.len().min(b.len()).min(rays.len()))
                .filter(|&i| a[i].tri != b[i].tri)
                .take(JUDGED)
                .collect();
            let judged: Vec<_> = idx
                .par_iter()
                .map(|&i| {
                    let h = brute_force(scene, &rays[i], false);
                    let t = h.map(|(t, _)| t);
                    (i, h, (close(&a[i], t), close(&b[i], t), edge(h)))
                })
                .collect();
            examples = judged
                .iter()
                .filter(|(_, _, (r, o, _))| !r && *o)
                .take(EXAMPLES)
                .map(|&(index, search, _)| Example {
                    index,
                    reference: a[index],
                    other: b[index],
                    search,
                })
                .collect();
            judged.into_iter().map(|(_, _, r)| r).collect()
        }
        (Answers::Occluded(a), Answers::Occluded(b)) => {
            let idx: Vec<usize> = (0..a.len().min(b.len()).min(rays.len()))
                .filter(|&i| a[i] != b[i])
                .take(JUDGED)
                .collect();
            idx.par_iter()
                .map(|&i| {
                    let h = brute_force(scene, &rays[i], true);
                    (a[i] == h.is_some(), b[i] == h.is_some(), edge(h))
                })
                .collect()
        }
        _ => Vec::new(),
    };
    let mut v = Verdict {
        judged: rights.len(),
        examples,
        ..Verdict::default()
    };
    for (r, o, e) in rights {
        v.on_edge += e as usize;
        match (r, o) {
            (true, true) => v.both_right += 1,
            (true, false) => v.reference_right += 1,
            (false, true) => v.other_right += 1,
            (false, false) => v.neither_right += 1,
        }
    }
    v
}

/// The timings of one core on one set at one thread count.
#[derive(Clone, Debug)]
pub struct Timing {
    /// The core's name.
    pub tracer: String,
    /// The set.
    pub kind: SetKind,
    /// Worker threads.
    pub threads: usize,
    /// Rays in the set.
    pub rays: usize,
    /// Seconds of each repetition.
    pub secs: Vec<f64>,
}

impl Timing {
    /// The median time of the repetitions.
    pub fn median_secs(&self) -> f64 {
        let mut s = self.secs.clone();
        s.sort_by(f64::total_cmp);
        match s.len() {
            0 => f64::NAN,
            n if n % 2 == 1 => s[n / 2],
            n => 0.5 * (s[n / 2 - 1] + s[n / 2]),
        }
    }

    /// Million rays per second at the median time.
    pub fn mrays_per_s(&self) -> f64 {
        self.rays as f64 / self.median_secs() / 1e6
    }
}

/// Replays each set of `sets` through each of `tracers` on each thread count
/// of `threads`, `repeat` times, the cores alternating within each
/// repetition. Returns one [`Timing`] per core, set and thread count (in
/// that nesting: set, threads, core). Errors only when a thread pool cannot
/// be made.
pub fn measure(
    sets: &RaySets,
    tracers: &[&dyn Tracer],
    threads: &[usize],
    repeat: usize,
) -> Result<Vec<Timing>, rayon::ThreadPoolBuildError> {
    let mut out = Vec::new();
    for kind in SetKind::ALL {
        let rays = sets.rays(kind);
        if rays.is_empty() {
            continue;
        }
        for &n in threads {
            let pool = rayon::ThreadPoolBuilder::new()
                .num_threads(n.max(1))
                .build()?;
            let active: Vec<&dyn Tracer> =
                tracers.iter().copied().filter(|t| t.traces(kind)).collect();
            let mut timings: Vec<Timing> = active
                .iter()
                .map(|t| Timing {
                    tracer: t.name().to_string(),
                    kind,
                    threads: n,
                    rays: rays.len(),
                    secs: Vec::with_capacity(repeat),
                })
                .collect();
            let mut buf = Answers::new(kind, rays.len());
            pool.install(|| {
                for _ in 0..repeat.max(1) {
                    for (t, timing) in active.iter().zip(&mut timings) {
                        let start = Instant::now();
                        trace(*t, rays, &mut buf);
                        timing.secs.push(start.elapsed().as_secs_f64());
                    }
                }
            });
            out.extend(timings);
        }
    }
    Ok(out)
}
