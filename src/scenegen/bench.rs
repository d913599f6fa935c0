//! The scene of `kalos bench`, built in memory.

use glam::Vec3;

use crate::sampling::Pcg32;
use crate::scene::shapes::{Diagonal, LatLong, Pole};
use crate::scene::{CameraDesc, Material, Scene, Texture};

/// A scene of about `triangles` triangles for ray-core measurements: finely
/// tessellated spheres (16 384 triangles each before the loader drops the
/// degenerate ones at the poles, like scanned or subdivided models) on a
/// jittered grid inside a closed room, lit by a quad under the ceiling.
/// Every ray from inside the room hits something, as in an interior.
pub fn bench_scene(triangles: u64) -> Scene {
    let mut scene = Scene::empty(format!("generated ({triangles} triangles)"));
    let m = scene.add_material(Material::Diffuse {
        reflectance: Texture::Constant(Vec3::splat(0.5)),
    });

    // Spheres on a jittered grid in [-1, 1]³. Each is the crate's
    // latitude–longitude sphere with all 2·rings·segments triangles, wound
    // inward (its normals point outward): the measured scene stays the one
    // of earlier measurements.
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

    // The room: a closed box around everything, normals inward
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

    // The light: a quad just under the ceiling, facing down
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
    // The camera stands inside the room, in front of the grid, so that
    // `kalos bench`'s recorded camera rays meet the spheres and their
    // bounces and shadow rays stay in the interior (from outside the room it
    // saw only the outer face of a wall).
    scene.camera = CameraDesc {
        to_world: crate::geometry::look_at(Vec3::new(0.0, 0.2, -1.55), Vec3::ZERO, Vec3::Y),
        fov_x_deg: 70.0,
        width: 256,
        height: 256,
        near_clip: 1e-2,
    };
    scene
}
