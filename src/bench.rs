//! Ray-core measurements for `kalos bench`: a generated scene of a given
//! triangle count, and incoherent closest-hit throughput. Benchmarks measure;
//! nothing here is asserted by tests.

use std::time::Instant;

use glam::Vec3;
use rayon::prelude::*;

use crate::geometry::Ray;
use crate::methods::World;
use crate::sampling::{uniform_sphere, Pcg32};
use crate::scene::shapes::{Diagonal, LatLong, Pole};
use crate::scene::{CameraDesc, Material, Scene, Texture};

/// A generated scene of about `triangles` triangles: finely tessellated
/// spheres (16 384 triangles each, like scanned or subdivided models) on a
/// jittered grid inside a closed room, lit by a quad under the ceiling.
/// Every ray from inside the room hits something, as in an interior.
pub fn generated_scene(triangles: u64) -> Scene {
    let mut scene = Scene::empty(format!("generated ({triangles} triangles)"));
    let m = scene.add_material(Material::Diffuse {
        reflectance: Texture::Constant(Vec3::splat(0.5)),
    });
    // each sphere: all 2·rings·segments triangles of the crate's
    // latitude–longitude sphere, wound inward (normals outward), as in
    // earlier measurements
    let sphere = LatLong {
        rings: 64,
        pole: Pole::Y,
        diagonal: Diagonal::Anti,
        seam: true,
        pole_triangles: true,
    };
    let per = 2 * sphere.rings as u64 * 2 * sphere.rings as u64;
    let count = (triangles / per).max(1);
    let mut rng = Pcg32::new(7, 0);
    let side = (count as f32).cbrt().ceil().max(1.0);
    for i in 0..count {
        let g = Vec3::new(
            (i as f32 % side).floor(),
            ((i as f32 / side) % side).floor(),
            (i as f32 / (side * side)).floor(),
        );
        let jitter = Vec3::new(rng.next_f32(), rng.next_f32(), rng.next_f32()) - 0.5;
        let c = ((g + 0.5 + 0.3 * jitter) / side) * 2.0 - Vec3::ONE;
        let radius = (0.35 / side) * (0.6 + 0.4 * rng.next_f32());
        let mut mesh = sphere.mesh(c, radius);
        mesh.reverse_winding();
        let normals = mesh.normals.as_deref();
        scene.add_mesh(
            format!("sphere{i}"),
            &mesh.positions,
            normals,
            None,
            &mesh.indices,
            m,
            None,
        );
    }
    // the room: a closed box around everything, normals inward
    let r = 1.6f32;
    let room = [
        Vec3::new(-r, -r, -r),
        Vec3::new(r, -r, -r),
        Vec3::new(r, r, -r),
        Vec3::new(-r, r, -r),
        Vec3::new(-r, -r, r),
        Vec3::new(r, -r, r),
        Vec3::new(r, r, r),
        Vec3::new(-r, r, r),
    ];
    let faces = [
        [0, 1, 2],
        [0, 2, 3],
        [4, 6, 5],
        [4, 7, 6],
        [0, 4, 5],
        [0, 5, 1],
        [3, 2, 6],
        [3, 6, 7],
        [0, 3, 7],
        [0, 7, 4],
        [1, 5, 6],
        [1, 6, 2],
    ];
    scene.add_mesh("room", &room, None, None, &faces, m, None);
    let quad = [
        Vec3::new(-0.5, 1.5, -0.5),
        Vec3::new(0.5, 1.5, -0.5),
        Vec3::new(0.5, 1.5, 0.5),
        Vec3::new(-0.5, 1.5, 0.5),
    ];
    scene.add_mesh(
        "light",
        &quad,
        None,
        None,
        &[[0, 1, 2], [0, 2, 3]],
        m,
        Some(Vec3::splat(5.0)),
    );
    scene.camera = CameraDesc {
        to_world: crate::geometry::look_at(Vec3::new(0.0, 0.0, -4.0), Vec3::ZERO, Vec3::Y),
        fov_x_deg: 40.0,
        width: 256,
        height: 256,
        near_clip: 1e-2,
    };
    scene
}

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
