//! Where the lanes' paths start ([`Starts`]): each path's sampler, first
//! segment and, when already traced, that segment's closest hit.
//! [`CameraRow`] starts `path`'s paths, one per pixel of a row: it makes
//! the jitter and the camera rays of eight pixels at a time in lanes, with
//! the operations of [`Camera::ray`] in their order, so the rays are the
//! same bits as the scalar ones, and traces them in packets.
//! [`Continued`] starts paths already begun elsewhere (the camera pass's,
//! after their first vertex). Every `unsafe` block calls an intrinsic on
//! register values; the functions run only inlined into
//! [`super::radiance_row`], which is compiled for AVX2 and called where
//! the CPU has it.

use std::arch::x86_64::*;

use super::super::{LaneSampler, LANES};
use super::{axis, Lanes, V, V3};
use crate::accel::Hit;
use crate::camera::Camera;
use crate::geometry::Ray;
use crate::world::World;

/// The paths [`super::radiance_row`] runs, numbered 0 … `count() − 1`.
pub(in crate::transport) trait Starts<S> {
    /// How many paths there are.
    fn count(&self) -> usize;
    /// The depth of every path's first segment (1 for a camera ray).
    fn depth(&self) -> u32;
    /// Paths `k0 …`, as many as `out` holds, into `out`.
    fn starts(&mut self, world: &World, k0: usize, out: Chunk<'_, S>);
}

/// Where [`Starts::starts`] puts paths k0 + k: each one's sampler (after
/// what it drew to make its first segment) in `rngs[k]`, its first segment
/// in `rays[k]` and, if traced there, that segment's closest hit in
/// `hits[k]` (`None`: the lanes trace it as `Ray::new(o, d)`, so `rays[k]`
/// must be such a ray). The slices have one length.
pub(in crate::transport) struct Chunk<'a, S> {
    pub rngs: &'a mut [S],
    pub rays: &'a mut [Ray],
    pub hits: &'a mut [Option<Option<Hit>>],
}

/// The camera's row `y`: pixel x's sampler is `sampler(x)`, whose first
/// 2D draw (u, v) jitters the camera ray through (x + u, y + v).
pub(in crate::transport) struct CameraRow<'a, F> {
    /// The camera whose rays these are.
    pub camera: &'a Camera,
    /// The row.
    pub y: usize,
    /// Pixel x's fresh sampler, `x ↦ S`.
    pub sampler: F,
}

/// Path k is pixel k's: the row's camera rays, traced in packets of eight
/// neighbours ([`crate::accel::Accel::intersect_packet`]).
impl<S: LaneSampler, F: FnMut(usize) -> S> Starts<S> for CameraRow<'_, F> {
    #[inline(always)]
    fn count(&self) -> usize {
        self.camera.width as usize
    }

    #[inline(always)]
    fn depth(&self) -> u32 {
        1
    }

    #[inline(always)]
    fn starts(&mut self, world: &World, k0: usize, out: Chunk<'_, S>) {
        self.camera_rays(k0, out.rngs, out.rays);
        let mut found = [None; LANES];
        for (rs, hs) in out.rays.chunks(LANES).zip(out.hits.chunks_mut(LANES)) {
            let found = &mut found[..rs.len()];
            world.accel.intersect_packet(rs, found);
            for (h, f) in hs.iter_mut().zip(found.iter()) {
                *h = Some(*f);
            }
        }
    }
}

impl<F> CameraRow<'_, F> {
    /// Pixel `x0 + k`'s sampler (after the camera ray's draws) and camera
    /// ray, in `rngs[k]` and `rays[k]`, for every k of `rays`. Eight pixels
    /// at a time: their samplers made one by one, put in lanes for the
    /// jitter's draw and taken out again, then the eight camera rays in
    /// lanes.
    #[inline(always)]
    fn camera_rays<S: LaneSampler>(&mut self, x0: usize, rngs: &mut [S], rays: &mut [Ray])
    where
        F: FnMut(usize) -> S,
    {
        let n = rays.len().min(rngs.len());
        for g in (0..n).step_by(LANES) {
            let m = LANES.min(n - g);
            let mask = (1u32 << m) - 1;
            let mut lanes = S::Lanes::new();
            for i in 0..m {
                lanes.set(i, &(self.sampler)(x0 + g + i));
            }
            let [u, v] = lanes.jitter(mask);
            for (i, rng) in rngs[g..g + m].iter_mut().enumerate() {
                *rng = lanes.get(i);
            }
            // SAFETY: a register operation; only inlined into
            // `radiance_row`, which runs where the CPU has AVX2
            let px = V(unsafe {
                _mm256_cvtepi32_ps(_mm256_add_epi32(
                    _mm256_set1_epi32((x0 + g) as i32),
                    _mm256_setr_epi32(0, 1, 2, 3, 4, 5, 6, 7),
                ))
            });
            let py = V::splat(self.y as f32);
            let d = camera_directions(self.camera, px + V(u), py + V(v));
            let (d, tmin) = (d.0.store(), d.1.store());
            let o = self.camera.origin;
            for (i, ray) in rays[g..g + m].iter_mut().enumerate() {
                *ray = Ray {
                    o,
                    d: V3::lane(&d, i),
                    tmin: tmin[i],
                    tmax: f32::INFINITY,
                };
            }
        }
    }
}

/// Paths begun elsewhere, whose `depth`-th segment is `paths[k].1`, a
/// `Ray::new` ray not yet traced, with `paths[k].0` the sampler that drew
/// it: [`crate::transport::radiance_from`]'s paths, with its `depth`.
pub(in crate::transport) struct Continued<'a, S> {
    pub paths: &'a [(S, Ray)],
    pub depth: u32,
}

impl<S: LaneSampler> Starts<S> for Continued<'_, S> {
    #[inline(always)]
    fn count(&self) -> usize {
        self.paths.len()
    }

    #[inline(always)]
    fn depth(&self) -> u32 {
        self.depth
    }

    #[inline(always)]
    fn starts(&mut self, _: &World, k0: usize, out: Chunk<'_, S>) {
        let paths = &self.paths[k0..k0 + out.rays.len()];
        for (k, (s, ray)) in paths.iter().enumerate() {
            out.rngs[k] = s.clone();
            out.rays[k] = *ray;
            out.hits[k] = None;
        }
    }
}

/// [`Camera::ray`]'s direction and near distance through the film
/// positions (`px`, `py`) of eight lanes, with its operations in their
/// order: glam's `Mat4::transform_vector3` (x, then y added, then z
/// added), `normalize` as the product with 1 / √(d·d), and the clamped
/// cosine's `max` (`maxps` gives its second operand for NaN, as
/// `f32::max` gives the number).
#[inline(always)]
fn camera_directions(cam: &Camera, px: V, py: V) -> (V3, V) {
    let one = V::splat(1.0);
    let two = V::splat(2.0);
    let sx = px / V::splat(cam.width as f32);
    let sy = py / V::splat(cam.height as f32);
    let cx = (one - two * sx) * V::splat(cam.tan_half.x);
    let cy = (one - two * sy) * V::splat(cam.tan_half.y);
    let m = &cam.to_world;
    let (ax, ay, az) = (axis(m.x_axis), axis(m.y_axis), axis(m.z_axis));
    let d = V3::new(
        az.x * one + (ay.x * cy + ax.x * cx),
        az.y * one + (ay.y * cy + ax.y * cx),
        az.z * one + (ay.z * cy + ax.z * cx),
    );
    let d = d.scale(one / d.dot(d).sqrt());
    let cos = d.dot(V3::splat(cam.forward)).max(V::splat(1e-6));
    (d, V::splat(cam.near) / cos)
}
