//! Scenes and statistics shared by the integration tests.
#![allow(dead_code)]

use glam::Vec3;
use kalos::film::Image;
use kalos::geometry::look_at;
use kalos::methods::{self, Budget, Driver, Options, World};
use kalos::scene::{CameraDesc, Material, Scene, Texture};

/// The white furnace: the inside of a closed cube, every face diffuse with
/// albedo `a` and emitting `le` toward the inside, seen by a camera at the
/// centre. Every pixel must converge to le / (1 − a).
pub fn furnace(a: f32, le: f32, res: u32) -> Scene {
    let mut s = Scene::empty("furnace");
    let m = s.add_material(Material::Diffuse {
        reflectance: Texture::Constant(Vec3::splat(a)),
    });
    // cube [-1,1]^3, triangles wound so that the normals point inward
    let p = [
        Vec3::new(-1.0, -1.0, -1.0),
        Vec3::new(1.0, -1.0, -1.0),
        Vec3::new(1.0, 1.0, -1.0),
        Vec3::new(-1.0, 1.0, -1.0),
        Vec3::new(-1.0, -1.0, 1.0),
        Vec3::new(1.0, -1.0, 1.0),
        Vec3::new(1.0, 1.0, 1.0),
        Vec3::new(-1.0, 1.0, 1.0),
    ];
    let quads = [
        [0, 1, 2, 3], // z = -1
        [4, 7, 6, 5], // z = +1
        [0, 4, 5, 1], // y = -1
        [3, 2, 6, 7], // y = +1
        [0, 3, 7, 4], // x = -1
        [1, 5, 6, 2], // x = +1
    ];
    let mut tris = Vec::new();
    for q in quads {
        tris.push([q[0], q[1], q[2]]);
        tris.push([q[0], q[2], q[3]]);
    }
    // orient inward: flip any triangle whose normal points away from the centre
    let tris: Vec<[u32; 3]> = tris
        .into_iter()
        .map(|t: [u32; 3]| {
            let (a0, b0, c0) = (p[t[0] as usize], p[t[1] as usize], p[t[2] as usize]);
            let n = (b0 - a0).cross(c0 - a0);
            if n.dot((a0 + b0 + c0) / 3.0) > 0.0 {
                [t[0], t[2], t[1]]
            } else {
                t
            }
        })
        .collect();
    s.add_mesh("box", &p, None, None, &tris, m, Some(Vec3::splat(le)));
    s.camera = CameraDesc {
        to_world: look_at(Vec3::new(0.1, 0.05, 0.0), Vec3::new(0.3, 0.1, 1.0), Vec3::Y),
        fov_x_deg: 70.0,
        width: res,
        height: res,
        near_clip: 1e-3,
    };
    s
}

/// Renders `scene` with `method` for `passes` passes.
pub fn render(scene: &Scene, method: &str, opts: &Options, passes: u64) -> (Image, u64) {
    let world = World::new(scene.clone());
    let mut m = methods::create(method, &world, opts).expect("method");
    let driver = Driver {
        budget: Budget {
            passes: Some(passes),
            ..Default::default()
        },
        cancel: None,
        reference: None,
        log_every: 0.0,
    };
    let r = driver.run(m.as_mut(), &world, |_| {});
    (r.image, r.rays)
}

/// Mean and standard error of the mean of one channel over all pixels
/// (pixels are independent estimates, so the spread of the pixel values
/// measures the noise of their mean).
pub fn mean_and_se(img: &Image, ch: usize) -> (f64, f64) {
    let v: Vec<f64> = img.data.iter().map(|p| p[ch] as f64).collect();
    let n = v.len() as f64;
    let mean = v.iter().sum::<f64>() / n;
    let var = v.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / (n - 1.0);
    (mean, (var / n).sqrt())
}
