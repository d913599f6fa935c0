//! Accumulation of pixel estimates in f64, and the image type that the
//! writers in [`crate::image_io`] take.

use glam::{DVec3, Vec3};

use crate::color::Rgb;
use crate::simd::prefetch;

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
    /// Splats on their way in ([`Film::splat_soon`]).
    queue: Queue,
}

/// The splats a film holds back while queueing ([`Film::begin_queue`]).
const QUEUE: usize = 8;

/// The smallest film that queues its splats: 1 MiB of sums (43,691
/// pixels), about a core's second-level cache today.
pub const QUEUE_FROM_BYTES: usize = 1 << 20;

/// Splats held back, as (pixel index, value), oldest at `head`; whether
/// [`Film::splat_soon`] queues at all.
#[derive(Clone, Debug, Default)]
struct Queue {
    on: bool,
    slots: [(usize, Rgb); QUEUE],
    head: usize,
    len: usize,
}

impl Film {
    /// An empty film.
    pub fn new(width: u32, height: u32) -> Self {
        Film {
            width,
            height,
            sum: vec![DVec3::ZERO; width as usize * height as usize],
            queue: Queue::default(),
        }
    }

    /// Adds `v` to pixel index `i`, after any splats still queued (so that
    /// every pixel receives its additions in the order they were made).
    /// Non-finite values are dropped, so that a numerical accident can never
    /// poison a pixel with NaN.
    #[inline]
    pub fn add_index(&mut self, i: usize, v: Rgb) {
        if self.queue.len != 0 {
            self.drain();
        }
        self.add_now(i, v);
    }

    #[inline(always)]
    fn add_now(&mut self, i: usize, v: Rgb) {
        if v.is_finite() {
            self.sum[i] += v.as_dvec3();
        }
    }

    /// From now until [`Film::settle`], [`Film::splat_soon`] holds splats
    /// back: each pixel is prefetched when its splat is queued and added
    /// `QUEUE` (8) splats later, so that the wait for a pixel outside the
    /// caches overlaps the work of the next few splats (a light tracer's
    /// film is read at random pixels). Every pixel receives the same
    /// additions in the same order, so the sums are the same bits; the
    /// film must be settled before it is read. A film smaller than
    /// [`QUEUE_FROM_BYTES`] does not queue: its pixels stay near the core,
    /// and the queue's own work only costs (light on two-rooms' 160 × 120
    /// films ran 3–10 % slower with it, cbox's 256 × 256 faster).
    pub fn begin_queue(&mut self) {
        self.queue.on = std::mem::size_of_val(&self.sum[..]) >= QUEUE_FROM_BYTES;
    }

    /// Adds the splats still queued, oldest first, and stops queueing.
    pub fn settle(&mut self) {
        self.drain();
        self.queue.on = false;
    }

    /// Adds the splats still queued, oldest first.
    fn drain(&mut self) {
        while self.queue.len != 0 {
            self.add_oldest();
        }
    }

    /// Adds the oldest splat queued (the queue holds one).
    #[inline(always)]
    fn add_oldest(&mut self) {
        let q = &mut self.queue;
        let (i, v) = q.slots[q.head];
        q.head = (q.head + 1) % QUEUE;
        q.len -= 1;
        self.add_now(i, v);
    }

    /// The index of the pixel at film position `(px, py)`, None off the
    /// film. For px ≥ 0 the cast truncates to floor(px) (and saturates past
    /// u32::MAX), so no `floor` is needed: on baseline x86-64 that is a
    /// libm call. NaN fails the comparison.
    #[inline(always)]
    fn index(&self, px: f32, py: f32) -> Option<usize> {
        if px >= 0.0 && py >= 0.0 {
            let (x, y) = (px as u32, py as u32);
            if x < self.width && y < self.height {
                return Some(y as usize * self.width as usize + x as usize);
            }
        }
        None
    }

    /// [`Film::splat`], held back while the film queues
    /// ([`Film::begin_queue`]).
    #[inline(always)]
    pub fn splat_soon(&mut self, px: f32, py: f32, v: Rgb) {
        if !self.queue.on {
            self.splat(px, py, v);
            return;
        }
        if let Some(i) = self.index(px, py) {
            self.prefetch_index(i);
            if self.queue.len == QUEUE {
                self.add_oldest();
            }
            let q = &mut self.queue;
            q.slots[(q.head + q.len) % QUEUE] = (i, v);
            q.len += 1;
        }
    }

    /// Asks the CPU to bring the pixel at film position `(px, py)` into its
    /// cache, as [`Film::splat`] would find it; nothing else. For a splat
    /// that waits on a visibility ray: the film of a light tracer is read
    /// at random pixels, most of them outside the caches near the core, and
    /// the ray's traversal hides the wait.
    #[inline(always)]
    pub fn prefetch(&self, px: f32, py: f32) {
        if let Some(i) = self.index(px, py) {
            self.prefetch_index(i);
        }
    }

    /// [`Film::prefetch`] of pixel index `i`.
    #[inline(always)]
    fn prefetch_index(&self, i: usize) {
        // The first and the last byte of the pixel's 24 (which may cross a
        // cache line)
        let p = std::ptr::from_ref(&self.sum[i]).cast::<u8>();
        prefetch(p);
        prefetch(p.wrapping_add(23));
    }

    /// Adds `v` at continuous film position `(px, py)` in pixels (a splat).
    #[inline]
    pub fn splat(&mut self, px: f32, py: f32, v: Rgb) {
        if let Some(i) = self.index(px, py) {
            self.add_index(i, v);
        }
    }

    /// Adds another film, pixel by pixel.
    pub fn merge(&mut self, other: &Film) {
        debug_assert!(other.queue.len == 0, "a film read with splats queued");
        self.drain();
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
        debug_assert!(self.queue.len == 0, "a film read with splats queued");
        Image {
            width: self.width,
            height: self.height,
            data: self.sum.iter().map(|v| (*v * scale).as_vec3()).collect(),
        }
    }
}

/// Brings the sums of `row` toward the core, a cache line at a time:
/// `path` calls it as a row starts, whose pixels then receive their
/// samples out of order as the lanes' paths end, too sparsely in time for
/// the hardware's stream prefetcher (their loads missed the cache: 4.7 %
/// of the lanes' loop on cbox). No effect on what is computed.
#[inline(always)]
pub fn prefetch_row(row: &[DVec3]) {
    let p = row.as_ptr().cast::<u8>();
    for off in (0..std::mem::size_of_val(row)).step_by(64) {
        prefetch(p.wrapping_add(off));
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sampling::Pcg32;

    /// Splats held back by the queue end in the same sums, bit for bit, as
    /// splats made at once, in any mix with immediate splats (which add
    /// after the queued ones), off-film positions and non-finite values;
    /// a film not queueing splats at once, and a small film never queues.
    #[test]
    fn queued_splats_give_the_same_sums_as_immediate_ones() {
        let mut rng = Pcg32::new(9, 9);
        // a film large enough to queue, splatted in a corner of 8 × 6
        // pixels (many splats to each pixel) and off it
        let (mut now, mut soon) = (Film::new(256, 256), Film::new(256, 256));
        soon.begin_queue();
        let mut longest = 0;
        for k in 0..5000 {
            let (px, py) = match k % 31 {
                0 => (300.0, 2.0),
                _ => (rng.next_f32() * 8.0 - 0.5, rng.next_f32() * 6.0 - 0.5),
            };
            let v = match k % 97 {
                0 => Rgb::splat(f32::NAN),
                1 => Rgb::splat(f32::INFINITY),
                _ => Rgb::new(rng.next_f32(), rng.next_f32() * 1e-3, rng.next_f32() * 1e3),
            };
            now.splat(px, py, v);
            if k % 13 == 0 {
                soon.splat(px, py, v);
            } else {
                soon.splat_soon(px, py, v);
            }
            longest = longest.max(soon.queue.len);
        }
        assert_eq!(longest, QUEUE, "the queue held splats back");
        soon.settle();
        let bits = |f: &Film| {
            f.sum
                .iter()
                .map(|p| p.to_array().map(f64::to_bits))
                .collect::<Vec<_>>()
        };
        assert_eq!(bits(&now), bits(&soon));
        assert!(now.sum.iter().all(|p| p.is_finite()));
        // settled, the film adds at once again
        soon.splat_soon(3.5, 2.5, Rgb::ONE);
        assert_eq!(soon.queue.len, 0);
        let i = 2 * 256 + 3;
        assert_eq!(soon.sum[i], now.sum[i] + DVec3::ONE);
        // a film that fits a core's caches does not queue
        let mut small = Film::new(7, 5);
        small.begin_queue();
        small.splat_soon(3.5, 2.5, Rgb::ONE);
        assert_eq!(small.queue.len, 0);
        assert_eq!(small.sum[2 * 7 + 3], DVec3::ONE);
    }
}
