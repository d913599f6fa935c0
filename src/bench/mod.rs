//! Ray-core measurements for `kalos bench`: incoherent closest-hit
//! throughput (the default scene is [`crate::scenegen::bench_scene`]), and
//! recorded ray sets ([`rayset`]) replayed through kalos's ray core and, with
//! the `embree` feature, through Embree on the same rays ([`replay`]).
//! Benchmarks measure; no test asserts a time.

#[cfg(feature = "embree")]
pub mod embree;
pub mod rayset;
pub mod replay;

use std::time::Instant;

use glam::Vec3;
use rayon::prelude::*;

use crate::geometry::Ray;
use crate::methods::World;
use crate::sampling::{uniform_sphere, Pcg32};

/// Throughput of one measurement.
#[derive(Clone, Copy, Debug)]
pub struct RayThroughput {
    /// Rays traced.
    pub rays: u64,
    /// Rays that hit something.
    pub hits: u64,
    /// Million rays per second.
    pub mrays_per_s: f64,
}

/// Traces `rays` incoherent rays (uniform origins in the scene bounds,
/// uniform directions) for their closest hits on `threads` threads.
pub fn incoherent_closest_hits(world: &World, rays: u64, threads: usize) -> RayThroughput {
    let (lo, hi) = world.scene.bounds();
    let chunks = 256u64;
    let per = rays.div_ceil(chunks);
    // pre-generate so that only traversal is timed
    let batches: Vec<Vec<Ray>> = (0..chunks)
        .map(|c| {
            let mut rng = Pcg32::keyed(&[99, c]);
            (0..per)
                .map(|_| {
                    let o =
                        lo + (hi - lo) * Vec3::new(rng.next_f32(), rng.next_f32(), rng.next_f32());
                    Ray::new(o, uniform_sphere(rng.next_2d()))
                })
                .collect()
        })
        .collect();
    let pool = match rayon::ThreadPoolBuilder::new()
        .num_threads(threads.max(1))
        .build()
    {
        Ok(p) => p,
        Err(_) => {
            return RayThroughput {
                rays: 0,
                hits: 0,
                mrays_per_s: 0.0,
            }
        }
    };
    let t = Instant::now();
    let hits: u64 = pool.install(|| {
        batches
            .par_iter()
            .map(|b| {
                b.iter()
                    .filter(|r| world.accel.intersect(r).is_some())
                    .count() as u64
            })
            .sum()
    });
    let secs = t.elapsed().as_secs_f64();
    let n = per * chunks;
    RayThroughput {
        rays: n,
        hits,
        mrays_per_s: n as f64 / secs / 1e6,
    }
}
