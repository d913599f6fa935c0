//! Scenes and statistics shared by the integration tests.
#![allow(dead_code)]

use glam::Vec3;
use kalos::film::Image;
use kalos::geometry::look_at;
use kalos::methods::{bundle, density, light, path, plb, Budget, Common, MethodConfig, World};
use kalos::render::Render;
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

/// Renders `scene` with `method` and master seed `seed` for `passes` passes.
pub fn render(scene: &Scene, method: &MethodConfig, seed: u64, passes: u64) -> (Image, u64) {
    render_budget(
        scene,
        method,
        &Common {
            seed,
            max_depth: None,
        },
        Budget {
            passes: Some(passes),
            ..Default::default()
        },
    )
}

/// Renders `scene` with `method` and the shared settings `common` until
/// `budget` is spent.
pub fn render_budget(
    scene: &Scene,
    method: &MethodConfig,
    common: &Common,
    budget: Budget,
) -> (Image, u64) {
    let world = World::new(scene.clone());
    let r = Render::new(&world)
        .method(method.clone())
        .common(common.clone())
        .budget(budget)
        .run(|_| {})
        .expect("render");
    (r.image, r.rays)
}

/// `path` with its defaults.
pub fn path() -> MethodConfig {
    MethodConfig::Path(path::Settings::default())
}

/// `light` with `s`.
pub fn light(s: light::Settings) -> MethodConfig {
    MethodConfig::Light(s)
}

/// `plb` with `s`.
pub fn plb(s: plb::Settings) -> MethodConfig {
    MethodConfig::Plb(s)
}

/// `bundle` with `s`.
pub fn bundle(s: bundle::Settings) -> MethodConfig {
    MethodConfig::Bundle(s)
}

/// `density` with `s`.
pub fn density(s: density::Settings) -> MethodConfig {
    MethodConfig::Density(s)
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

/// Block means of an estimate made of two independent renders, and the
/// variance of each block mean: per pixel, var((x₁+x₂)/2) is estimated by
/// (x₁−x₂)²/4 (E[(x₁−x₂)²] = 2σ²), and a block mean's variance is the sum
/// over its pixels divided by n². Blocks are `b`×`b` pixels; pixels where
/// `keep` is false are left out, and blocks with fewer than b²/2 kept pixels
/// are dropped (None).
pub fn block_stats(
    x1: &Image,
    x2: &Image,
    b: u32,
    keep: &dyn Fn(u32, u32) -> bool,
) -> Vec<Option<([f64; 3], [f64; 3])>> {
    let (bw, bh) = (x1.width / b, x1.height / b);
    let mut out = Vec::new();
    for by in 0..bh {
        for bx in 0..bw {
            let mut sum = [0.0; 3];
            let mut var = [0.0; 3];
            let mut n = 0.0;
            for y in by * b..(by + 1) * b {
                for x in bx * b..(bx + 1) * b {
                    if !keep(x, y) {
                        continue;
                    }
                    let (p, q) = (x1.get(x, y), x2.get(x, y));
                    for c in 0..3 {
                        sum[c] += (p[c] + q[c]) as f64 / 2.0;
                        var[c] += ((p[c] - q[c]) as f64).powi(2) / 4.0;
                    }
                    n += 1.0;
                }
            }
            if n < (b * b) as f64 / 2.0 {
                out.push(None);
            } else {
                out.push(Some((sum.map(|s| s / n), var.map(|v| v / (n * n)))));
            }
        }
    }
    out
}

/// The largest |z| over blocks and channels between two block statistics,
/// z = (m_a − m_b) / √(var_a + var_b + floor²), where `floor` is a small
/// absolute allowance for blocks whose both estimates are (near) noise-free.
pub fn max_block_z(
    a: &[Option<([f64; 3], [f64; 3])>],
    b: &[Option<([f64; 3], [f64; 3])>],
    floor: f64,
) -> (f64, usize) {
    let mut worst = (0.0f64, 0usize);
    for (i, (p, q)) in a.iter().zip(b).enumerate() {
        if let (Some((ma, va)), Some((mb, vb))) = (p, q) {
            for c in 0..3 {
                let z = (ma[c] - mb[c]).abs() / (va[c] + vb[c] + floor * floor).sqrt();
                if z > worst.0 {
                    worst = (z, i);
                }
            }
        }
    }
    worst
}

/// Runs the kalos binary with `args` and returns what it did.
pub fn kalos(args: &[&str]) -> std::process::Output {
    std::process::Command::new(env!("CARGO_BIN_EXE_kalos"))
        .args(args)
        .output()
        .expect("kalos runs")
}

/// A command's stderr as text.
pub fn stderr(o: &std::process::Output) -> String {
    String::from_utf8_lossy(&o.stderr).into_owned()
}
