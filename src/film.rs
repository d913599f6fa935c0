//! Accumulation of pixel estimates in f64, and the image type that the
//! writers in [`crate::image_io`] take.

use glam::{DVec3, Vec3};

use crate::color::Rgb;

/// A finished image: linear RGB, row 0 at the top.
#[derive(Clone, Debug, PartialEq)]
pub struct Image {
    /// Width in pixels.
    pub width: u32,
    /// Height in pixels.
    pub height: u32,
    /// Pixels, row-major, top row first.
    pub data: Vec<Vec3>,
}

impl Image {
    /// A black image.
    pub fn new(width: u32, height: u32) -> Self {
        Image {
            width,
            height,
            data: vec![Vec3::ZERO; width as usize * height as usize],
        }
    }

    /// The pixel at column x, row y (row 0 at the top).
    #[inline]
    pub fn get(&self, x: u32, y: u32) -> Vec3 {
        self.data[y as usize * self.width as usize + x as usize]
    }
}

/// A sum of samples per pixel, in f64 (box filter: a sample counts only
/// toward the pixel it falls in, as in the references).
#[derive(Clone, Debug)]
pub struct Film {
    /// Width in pixels.
    pub width: u32,
    /// Height in pixels.
    pub height: u32,
    /// Per-pixel sums.
    pub sum: Vec<DVec3>,
}

impl Film {
    /// An empty film.
    pub fn new(width: u32, height: u32) -> Self {
        Film {
            width,
            height,
            sum: vec![DVec3::ZERO; width as usize * height as usize],
        }
    }

    /// Adds `v` to pixel index `i`. Non-finite values are dropped, so that a
    /// numerical accident can never poison a pixel with NaN.
    #[inline]
    pub fn add_index(&mut self, i: usize, v: Rgb) {
        if v.is_finite() {
            self.sum[i] += v.as_dvec3();
        }
    }

    /// Asks the CPU to bring the pixel at film position `(px, py)` into its
    /// cache, as [`Film::splat`] would find it; nothing else. For a splat
    /// that waits on a visibility ray: the film of a light tracer is read
    /// at random pixels, most of them outside the caches near the core, and
    /// the ray's traversal hides the wait.
    #[inline(always)]
    pub fn prefetch(&self, px: f32, py: f32) {
        if px >= 0.0 && py >= 0.0 {
            let (x, y) = (px as u32, py as u32);
            if x < self.width && y < self.height {
                let i = y as usize * self.width as usize + x as usize;
                let p = self.sum[i..].as_ptr().cast::<i8>();
                #[cfg(target_arch = "x86_64")]
                // SAFETY: a prefetch has no effect on memory or on the
                // program's state; both addresses are inside pixel i's
                // 24 bytes (which may cross a cache line)
                unsafe {
                    use std::arch::x86_64::{_mm_prefetch, _MM_HINT_T0};
                    _mm_prefetch::<_MM_HINT_T0>(p);
                    _mm_prefetch::<_MM_HINT_T0>(p.add(23));
                }
                #[cfg(not(target_arch = "x86_64"))]
                let _ = p;
            }
        }
    }

    /// Adds `v` at continuous film position `(px, py)` in pixels (a splat).
    #[inline]
    pub fn splat(&mut self, px: f32, py: f32, v: Rgb) {
        // For px ≥ 0 the cast truncates to floor(px) (and saturates past
        // u32::MAX), so no `floor` is needed: on baseline x86-64 that is a
        // libm call. NaN fails the comparison.
        if px >= 0.0 && py >= 0.0 {
            let (x, y) = (px as u32, py as u32);
            if x < self.width && y < self.height {
                self.add_index(y as usize * self.width as usize + x as usize, v);
            }
        }
    }

    /// Adds another film, pixel by pixel.
    pub fn merge(&mut self, other: &Film) {
        for (a, b) in self.sum.iter_mut().zip(&other.sum) {
            *a += *b;
        }
    }

    /// The mean image `sum / n` of `n` samples (black when `n` is 0).
    pub fn mean(&self, n: u64) -> Image {
        self.to_image(if n == 0 { 0.0 } else { 1.0 / n as f64 })
    }

    /// The image `sum · scale`.
    pub fn to_image(&self, scale: f64) -> Image {
        Image {
            width: self.width,
            height: self.height,
            data: self.sum.iter().map(|v| (*v * scale).as_vec3()).collect(),
        }
    }
}
