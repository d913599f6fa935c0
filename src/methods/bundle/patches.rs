//! Patches: the finite elements of §5 (eq. (23)). Every scene triangle is cut
//! into k² congruent sub-triangles (k chosen per triangle so that no edge is
//! longer than the target edge length), and each sub-triangle is a patch with
//! constant emission L_i^e(ω), BRDF f̃_i, area A_i and radiance L\[i\].
//!
//! The sub-triangles of triangle t are numbered row by row in the barycentric
//! grid (b1 = i/k, b2 = j/k): row j holds k − j "up" and k − j − 1 "down"
//! triangles, interleaved, so that a ray hit (t, b1, b2) finds its patch in
//! O(1) ([`Patches::locate`]).

use std::collections::HashMap;

use glam::{Vec2, Vec3};

use crate::bsdf::Bsdf;
use crate::emitter::Lights;
use crate::scene::{Rgb, Scene};

/// One patch.
#[derive(Clone, Copy, Debug)]
pub struct Patch {
    /// Corners, counter-clockwise around `ng`.
    pub v: [Vec3; 3],
    /// Geometric normal (unit); its side is the front.
    pub ng: Vec3,
    /// Shading normal at the centroid, on the side of `ng`.
    pub ns: Vec3,
    /// Area A_i.
    pub area: f32,
    /// Emitted radiance of the front side (zero when the patch does not emit).
    pub le: Rgb,
    /// The BRDF at the centroid.
    pub bsdf: Bsdf,
    /// True when the back side reflects too (Mitsuba `twosided`).
    pub two_sided: bool,
    /// True when the patch is glass that the transfer reflects and
    /// transmits through ([`super::transfer::eval_glass`]); false for other
    /// BSDFs, and for glass with `--glass off`.
    pub glass: bool,
}

impl Patch {
    /// The centroid.
    #[inline]
    pub fn centroid(&self) -> Vec3 {
        (self.v[0] + self.v[1] + self.v[2]) / 3.0
    }

    /// L_i^e(ω): emission toward `w` (unit), front side only.
    #[inline]
    pub fn le(&self, w: Vec3) -> Rgb {
        if self.ng.dot(w) > 0.0 {
            self.le
        } else {
            Rgb::ZERO
        }
    }
}

/// All patches with their bookkeeping.
pub struct Patches {
    /// The patches.
    pub p: Vec<Patch>,
    /// Shared vertex index of each patch corner (for Gouraud smoothing).
    pub vid: Vec<[u32; 3]>,
    /// Number of shared vertices.
    pub vertex_count: usize,
    /// First patch of each scene triangle.
    first: Vec<u32>,
    /// Subdivision k of each scene triangle.
    k: Vec<u16>,
    /// The edge length the tessellation aimed at.
    pub edge: f32,
}

/// Subdivision of a triangle with longest edge `longest` for target `edge`.
fn subdivision(longest: f32, edge: f32) -> u32 {
    if edge > 0.0 && edge.is_finite() {
        ((longest / edge).ceil() as u32).clamp(1, 256)
    } else {
        1
    }
}

/// The target edge length h for about `n` patches. Starts from equilateral
/// triangles (area √3/4 h², so h = √(4 A / (√3 n))), then rescales h a few
/// times by √(count / n), since rounding k up per triangle makes more patches.
pub fn edge_for_count(scene: &Scene, n: usize) -> f32 {
    let n = n.max(1) as f64;
    let longest: Vec<f32> = (0..scene.triangles.len() as u32)
        .map(|t| {
            let [a, b, c] = scene.tri_vertices(t);
            (b - a).length().max((c - b).length()).max((a - c).length())
        })
        .collect();
    let total: f64 = (0..scene.triangles.len() as u32)
        .map(|t| scene.tri_area(t) as f64)
        .sum();
    let mut h = (4.0 * total / (3f64.sqrt() * n)).sqrt() as f32;
    for _ in 0..6 {
        let count: f64 = longest
            .iter()
            .map(|&l| (subdivision(l, h) as f64).powi(2))
            .sum();
        if count <= 1.1 * n {
            break;
        }
        h *= (count / n).sqrt() as f32;
    }
    h
}

impl Patches {
    /// Tessellates `scene` with edges no longer than `edge` (plus the
    /// triangles' own shape: a thin sliver keeps its aspect ratio).
    pub fn build(scene: &Scene, lights: &Lights, edge: f32) -> Self {
        let nt = scene.triangles.len();
        let mut p = Vec::new();
        let mut vid = Vec::new();
        let mut first = Vec::with_capacity(nt);
        let mut ks = Vec::with_capacity(nt);
        // corners are shared between patches of one shape when their positions
        // agree after quantisation to 1e-5 of the scene size
        let (lo, hi) = scene.bounds();
        let q = ((hi - lo).max_element() * 1e-5).max(1e-12);
        let mut vmap: HashMap<(u32, [i64; 3]), u32> = HashMap::new();
        let mut vkey = |shape: u32, x: Vec3| -> u32 {
            let key = (
                shape,
                [
                    (x.x / q).round() as i64,
                    (x.y / q).round() as i64,
                    (x.z / q).round() as i64,
                ],
            );
            let n = vmap.len() as u32;
            *vmap.entry(key).or_insert(n)
        };
        for t in 0..nt as u32 {
            let [a, b, c] = scene.tri_vertices(t);
            let longest = (b - a).length().max((c - b).length()).max((a - c).length());
            let k = subdivision(longest, edge);
            first.push(p.len() as u32);
            ks.push(k as u16);
            let shape = scene.tri_shape[t as usize];
            let material = &scene.materials[scene.shapes[shape as usize].material as usize];
            let two_sided = material.is_two_sided();
            let ng = (b - a).cross(c - a).normalize_or(Vec3::Z);
            let le = lights.le_tri(t, ng, ng);
            let kf = k as f32;
            let at = |i: u32, j: u32| a + (b - a) * (i as f32 / kf) + (c - a) * (j as f32 / kf);
            for j in 0..k {
                for i in 0..k - j {
                    // up triangle (i, j), then down triangle (i, j) when it exists
                    let mut corners = vec![[(i, j), (i + 1, j), (i, j + 1)]];
                    if i + j + 1 < k {
                        corners.push([(i + 1, j), (i + 1, j + 1), (i, j + 1)]);
                    }
                    for cs in corners {
                        let v = cs.map(|(ii, jj)| at(ii, jj));
                        let bary: Vec2 = cs
                            .iter()
                            .map(|&(ii, jj)| Vec2::new(ii as f32, jj as f32) / kf)
                            .sum::<Vec2>()
                            / 3.0;
                        let sp = scene.surface_point(t, bary.x, bary.y);
                        let area = 0.5 * (v[1] - v[0]).cross(v[2] - v[0]).length();
                        let bsdf = material.bsdf(sp.uv);
                        p.push(Patch {
                            v,
                            ng,
                            ns: sp.frame.n,
                            area: area.max(1e-30),
                            le,
                            glass: super::transfer::is_glass(&bsdf),
                            bsdf,
                            two_sided,
                        });
                        vid.push(v.map(|x| vkey(shape, x)));
                    }
                }
            }
        }
        let vertex_count = vmap.len();
        Patches {
            p,
            vid,
            vertex_count,
            first,
            k: ks,
            edge,
        }
    }

    /// Turns the glass transfer off (`--glass off`: glass neither reflects
    /// nor transmits in the transfer, as before it existed) or back on.
    pub fn set_glass(&mut self, on: bool) {
        for p in &mut self.p {
            p.glass = on && super::transfer::is_glass(&p.bsdf);
        }
    }

    /// Number of patches.
    pub fn len(&self) -> usize {
        self.p.len()
    }

    /// True when there are no patches.
    pub fn is_empty(&self) -> bool {
        self.p.is_empty()
    }

    /// The patch holding barycentrics (`b1`, `b2`) of scene triangle `tri`,
    /// and the point's barycentric weights on that patch's three corners.
    pub fn locate(&self, tri: u32, b1: f32, b2: f32) -> (u32, Vec3) {
        let k = self.k[tri as usize] as u32;
        let kf = k as f32;
        let (u, v) = ((b1 * kf).max(0.0), (b2 * kf).max(0.0));
        let j = (v.floor() as u32).min(k - 1);
        let i = (u.floor() as u32).min(k - 1 - j);
        let (fu, fv) = (u - i as f32, v - j as f32);
        let row = 2 * k * j - j * j;
        let down = fu + fv > 1.0 && i + j + 1 < k;
        let idx = self.first[tri as usize] + row + 2 * i + down as u32;
        let w = if down {
            // corners (1,0), (1,1), (0,1) of the cell
            let t = 1.0 - fu;
            let s = fv - t;
            Vec3::new(1.0 - s - t, s, t)
        } else {
            Vec3::new(1.0 - fu - fv, fu, fv)
        };
        (idx, w.clamp(Vec3::ZERO, Vec3::ONE))
    }
}
