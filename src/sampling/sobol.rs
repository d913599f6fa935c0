//! Owen-scrambled Sobol points: the low-discrepancy sampler of `path`
//! (`--sampler sobol`).
//!
//! A camera path asks for its numbers one dimension at a time, in a fixed
//! layout: the camera jitter takes dimensions 0 and 1, and the vertex at
//! depth k (the k-th segment's end) takes the seven from 2 + 7 (k − 1):
//! the light choice (1D), the point on the light (2D), the BSDF lobe (1D),
//! its direction (2D) and Russian roulette (1D), whatever branch the vertex
//! takes ([`Sampler::start_vertex`] puts the counter there).
//!
//! The points are the Sobol sequence (Sobol 1967) with the direction
//! numbers of Joe and Kuo (2008), randomised as Burley (2020, "Practical
//! Hash-based Owen Scrambling", JCGT 9(4)) does:
//!
//! - each dimension's value is Owen-scrambled (a nested uniform scramble
//!   in base 2, drawn from a hash of the pixel, the seed and the
//!   dimension instead of a stored tree), which keeps every elementary
//!   interval of the net and makes every pixel's points an independent
//!   randomisation, so the estimate stays unbiased;
//! - the sample index is shuffled by the same kind of scramble applied
//!   to the index's bits (high bits choosing the flips of low bits), so
//!   that the first 2^m indices of a pixel are one aligned block of 2^m
//!   Sobol points, in another order: a render of 2^m passes is a net
//!   whatever the shuffle, and the progressive passes in between are
//!   prefixes of it.
//!
//! All the dimensions of a sample are coordinates of one Sobol point (the
//! shuffle is per pixel, the scramble per pixel and dimension), so the
//! camera jitter, the light point and the BSDF direction of the first
//! vertices are stratified jointly, as in pbrt-v4's `SobolSampler` with
//! Owen scrambling. Joe and Kuo chose their numbers for the quality of
//! the two-dimensional projections, which are what a 2D draw sees.
//! Dimensions past the table ([`SOBOL_DIMENSIONS`]: the ninth vertex's
//! last draw and deeper) are padded with hashed independent numbers.
//! (Padding every draw with its own shuffled (0,2)-sequence, Burley's §4
//! and pbrt-v4's `PaddedSobolSampler`, stratifies each 2D draw alone but
//! not the draws together; on cbox it gave less error per sample at 16
//! spp but more at 64 and 256.)
//!
//! The first vertex's draws take the Sobol dimensions in another order
//! than they are drawn ([`CAMERA_ROWS`]): its BSDF direction, which
//! decides all the indirect light, takes dimensions 3 and 4, next to the
//! camera's and the light choice's, where the sequence stratifies best
//! with them; its point on the light takes 5 and 6 and its lobe 7. Against
//! the order of the draws, on cbox at 128², error per sample 0.87 at 16
//! spp, 0.915 at 64 and 0.935 at 256, and 0.966 on a textured room of many
//! lights at 64 (docs/notebook/sampling.md, "The first vertex's direction
//! next to the camera's"). Light walks keep the table's order
//! ([`SobolWalkSampler`]).
//!
//! Everything is keyed by (seed, pixel, pass) and nothing else, so an image
//! does not depend on the thread count, shards own whole pixels' sequences
//! and a checkpoint resumes at the next pass.

use glam::Vec2;

use super::{mix64, Sampler};

/// Dimensions of the direction-number table: dimension 0 (van der Corput,
/// no numbers needed) and the first 63 rows of Joe and Kuo's table.
pub const SOBOL_DIMENSIONS: usize = 64;

/// Joe and Kuo's direction numbers (`new-joe-kuo-6.21201`, dimensions 2 to
/// 64), one row per dimension as (s, a, m_1 … m_s): s is the degree of the
/// primitive polynomial, the bits of a are its inner coefficients, and the
/// m_k are the initial direction numbers.
///
/// From S. Joe and F. Y. Kuo, "Constructing Sobol sequences with better
/// two-dimensional projections", SIAM J. Sci. Comput. 30 (2008) 2635–2654,
/// <https://web.maths.unsw.edu.au/~fkuo/sobol/>. Licence of the data:
///
/// Copyright (c) 2008, Frances Y. Kuo and Stephen Joe. All rights reserved.
/// Redistribution and use in source and binary forms, with or without
/// modification, are permitted provided that the following conditions are
/// met: redistributions of source code must retain the above copyright
/// notice, this list of conditions and the following disclaimer;
/// redistributions in binary form must reproduce the above copyright
/// notice, this list of conditions and the following disclaimer in the
/// documentation and/or other materials provided with the distribution;
/// neither the names of the copyright holders nor the names of the
/// University of New South Wales and the University of Waikato and its
/// contributors may be used to endorse or promote products derived from
/// this software without specific prior written permission. THIS SOFTWARE
/// IS PROVIDED BY THE COPYRIGHT HOLDERS "AS IS" AND ANY EXPRESS OR IMPLIED
/// WARRANTIES, INCLUDING, BUT NOT LIMITED TO, THE IMPLIED WARRANTIES OF
/// MERCHANTABILITY AND FITNESS FOR A PARTICULAR PURPOSE ARE DISCLAIMED. IN
/// NO EVENT SHALL THE COPYRIGHT HOLDERS BE LIABLE FOR ANY DIRECT, INDIRECT,
/// INCIDENTAL, SPECIAL, EXEMPLARY, OR CONSEQUENTIAL DAMAGES (INCLUDING, BUT
/// NOT LIMITED TO, PROCUREMENT OF SUBSTITUTE GOODS OR SERVICES; LOSS OF
/// USE, DATA, OR PROFITS; OR BUSINESS INTERRUPTION) HOWEVER CAUSED AND ON
/// ANY THEORY OF LIABILITY, WHETHER IN CONTRACT, STRICT LIABILITY, OR TORT
/// (INCLUDING NEGLIGENCE OR OTHERWISE) ARISING IN ANY WAY OUT OF THE USE OF
/// THIS SOFTWARE, EVEN IF ADVISED OF THE POSSIBILITY OF SUCH DAMAGE.
#[rustfmt::skip]
const JOE_KUO: [(u32, u32, &[u32]); SOBOL_DIMENSIONS - 1] = [
    (1, 0, &[1]),
    (2, 1, &[1, 3]),
    (3, 1, &[1, 3, 1]),
    (3, 2, &[1, 1, 1]),
    (4, 1, &[1, 1, 3, 3]),
    (4, 4, &[1, 3, 5, 13]),
    (5, 2, &[1, 1, 5, 5, 17]),
    (5, 4, &[1, 1, 5, 5, 5]),
    (5, 7, &[1, 1, 7, 11, 19]),
    (5, 11, &[1, 1, 5, 1, 1]),
    (5, 13, &[1, 1, 1, 3, 11]),
    (5, 14, &[1, 3, 5, 5, 31]),
    (6, 1, &[1, 3, 3, 9, 7, 49]),
    (6, 13, &[1, 1, 1, 15, 21, 21]),
    (6, 16, &[1, 3, 1, 13, 27, 49]),
    (6, 19, &[1, 1, 1, 15, 7, 5]),
    (6, 22, &[1, 3, 1, 15, 13, 25]),
    (6, 25, &[1, 1, 5, 5, 19, 61]),
    (7, 1, &[1, 3, 7, 11, 23, 15, 103]),
    (7, 4, &[1, 3, 7, 13, 13, 15, 69]),
    (7, 7, &[1, 1, 3, 13, 7, 35, 63]),
    (7, 8, &[1, 3, 5, 9, 1, 25, 53]),
    (7, 14, &[1, 3, 1, 13, 9, 35, 107]),
    (7, 19, &[1, 3, 1, 5, 27, 61, 31]),
    (7, 21, &[1, 1, 5, 11, 19, 41, 61]),
    (7, 28, &[1, 3, 5, 3, 3, 13, 69]),
    (7, 31, &[1, 1, 7, 13, 1, 19, 1]),
    (7, 32, &[1, 3, 7, 5, 13, 19, 59]),
    (7, 37, &[1, 1, 3, 9, 25, 29, 41]),
    (7, 41, &[1, 3, 5, 13, 23, 1, 55]),
    (7, 42, &[1, 3, 7, 3, 13, 59, 17]),
    (7, 50, &[1, 3, 1, 3, 5, 53, 69]),
    (7, 55, &[1, 1, 5, 5, 23, 33, 13]),
    (7, 56, &[1, 1, 7, 7, 1, 61, 123]),
    (7, 59, &[1, 1, 7, 9, 13, 61, 49]),
    (7, 62, &[1, 3, 3, 5, 3, 55, 33]),
    (8, 14, &[1, 3, 1, 15, 31, 13, 49, 245]),
    (8, 21, &[1, 3, 5, 15, 31, 59, 63, 97]),
    (8, 22, &[1, 3, 1, 11, 11, 11, 77, 249]),
    (8, 38, &[1, 3, 1, 11, 27, 43, 71, 9]),
    (8, 47, &[1, 1, 7, 15, 21, 11, 81, 45]),
    (8, 49, &[1, 3, 7, 3, 25, 31, 65, 79]),
    (8, 50, &[1, 3, 1, 1, 19, 11, 3, 205]),
    (8, 52, &[1, 1, 5, 9, 19, 21, 29, 157]),
    (8, 56, &[1, 3, 7, 11, 1, 33, 89, 185]),
    (8, 67, &[1, 3, 3, 3, 15, 9, 79, 71]),
    (8, 70, &[1, 3, 7, 11, 15, 39, 119, 27]),
    (8, 84, &[1, 1, 3, 1, 11, 31, 97, 225]),
    (8, 97, &[1, 1, 1, 3, 23, 43, 57, 177]),
    (8, 103, &[1, 3, 7, 7, 17, 17, 37, 71]),
    (8, 115, &[1, 3, 1, 5, 27, 63, 123, 213]),
    (8, 122, &[1, 1, 3, 5, 11, 43, 53, 133]),
    (9, 8, &[1, 3, 5, 5, 29, 17, 47, 173, 479]),
    (9, 13, &[1, 3, 3, 11, 3, 1, 109, 9, 69]),
    (9, 16, &[1, 1, 1, 5, 17, 39, 23, 5, 343]),
    (9, 22, &[1, 3, 1, 5, 25, 15, 31, 103, 499]),
    (9, 25, &[1, 1, 1, 11, 11, 17, 63, 105, 183]),
    (9, 44, &[1, 1, 5, 11, 9, 29, 97, 231, 363]),
    (9, 47, &[1, 1, 5, 15, 19, 45, 41, 7, 383]),
    (9, 52, &[1, 3, 7, 7, 31, 19, 83, 137, 221]),
    (9, 55, &[1, 1, 1, 3, 23, 15, 111, 223, 83]),
    (9, 59, &[1, 1, 5, 13, 31, 15, 55, 25, 161]),
    (9, 62, &[1, 1, 3, 13, 25, 47, 39, 87, 257]),
];

/// The generator matrices, column by column: `DIRECTIONS[d][j]` is the
/// 32-bit fraction that bit j of the index adds (XOR) to dimension d.
/// Built at compile time from [`JOE_KUO`] by the recurrence of Bratley and
/// Fox (ACM TOMS 14, 1988) in the form Joe and Kuo state it.
const DIRECTIONS: [[u32; 32]; SOBOL_DIMENSIONS] = directions();

/// The same matrices four index bits at a time, all bit-reversed:
/// `NIBBLES[d][k][n]` is the XOR of the columns 4k..4k+4 that the bits of
/// n, read from bit 3 down (n is a nibble of the bit-reversed index), select,
/// its bits reversed. So a coordinate is one lookup per nibble of the index
/// (32 KB in all) instead of a loop over the index's bits, its index and
/// its value both in the order the Owen scramble works in
/// ([`owen_scramble`], [`sobol_reversed`]).
static NIBBLES: Nibbles = nibbles(&identity());

/// [`NIBBLES`] in the camera path's order: `CAMERA_NIBBLES[d]` is
/// `NIBBLES[CAMERA_ROWS[d]]`.
static CAMERA_NIBBLES: Nibbles = nibbles(&CAMERA_ROWS);

/// The generator matrices four index bits at a time, per dimension.
type Nibbles = [[[u32; 16]; 8]; SOBOL_DIMENSIONS];

/// The Sobol dimension each dimension of a camera path's layout takes
/// (see the module's docs): the table's order except at the first vertex,
/// whose BSDF direction (drawn at 6 and 7) takes Sobol dimensions 3 and 4,
/// its point on the light (drawn at 3 and 4) 5 and 6, and its lobe
/// (drawn at 5) 7. The light choice (2) and the roulette (8) keep theirs.
pub const CAMERA_ROWS: [usize; SOBOL_DIMENSIONS] = {
    let mut r = identity();
    let first = vertex_dimension(1) as usize;
    // (drawn at, takes): light point, lobe, direction
    let moves = [(1, 3), (2, 4), (3, 5), (4, 1), (5, 2)];
    let mut k = 0;
    while k < moves.len() {
        r[first + moves[k].0] = first + moves[k].1;
        k += 1;
    }
    r
};

const fn identity() -> [usize; SOBOL_DIMENSIONS] {
    let mut r = [0; SOBOL_DIMENSIONS];
    let mut d = 0;
    while d < SOBOL_DIMENSIONS {
        r[d] = d;
        d += 1;
    }
    r
}

const fn nibbles(rows: &[usize; SOBOL_DIMENSIONS]) -> Nibbles {
    let mut t = [[[0u32; 16]; 8]; SOBOL_DIMENSIONS];
    let mut d = 0;
    while d < SOBOL_DIMENSIONS {
        let row = rows[d];
        let mut k = 0;
        while k < 8 {
            let mut n = 0;
            while n < 16 {
                let mut x = 0u32;
                let mut b = 0;
                while b < 4 {
                    if (n >> (3 - b)) & 1 == 1 {
                        x ^= DIRECTIONS[row][4 * k + b];
                    }
                    b += 1;
                }
                t[d][k][n] = x.reverse_bits();
                n += 1;
            }
            k += 1;
        }
        d += 1;
    }
    t
}

const fn directions() -> [[u32; 32]; SOBOL_DIMENSIONS] {
    let mut v = [[0u32; 32]; SOBOL_DIMENSIONS];
    let mut j = 0;
    while j < 32 {
        v[0][j] = 1 << (31 - j);
        j += 1;
    }
    let mut d = 1;
    while d < SOBOL_DIMENSIONS {
        let (s, a, m) = JOE_KUO[d - 1];
        let s = s as usize;
        let mut j = 0;
        while j < 32 {
            if j < s {
                v[d][j] = m[j] << (31 - j);
            } else {
                let mut x = v[d][j - s] ^ (v[d][j - s] >> s);
                let mut k = 1;
                while k < s {
                    if (a >> (s - 1 - k)) & 1 == 1 {
                        x ^= v[d][j - k];
                    }
                    k += 1;
                }
                v[d][j] = x;
            }
            j += 1;
        }
        d += 1;
    }
    v
}

/// Dimension `dim` (< [`SOBOL_DIMENSIONS`]) of Sobol point `index`, as a
/// 32-bit binary fraction (unscrambled, in natural order: the first 2^m
/// indices are the same set as in Gray-code order).
#[inline]
pub fn sobol(index: u32, dim: usize) -> u32 {
    sobol_reversed(index.reverse_bits(), dim).reverse_bits()
}

/// [`sobol`] in bit-reversed form: the coordinate's bits reversed, of the
/// point whose index has its bits reversed in `rindex`. One lookup per
/// nibble of the index up to its highest set bit: a pixel's shuffled
/// indices stay below a power of two above its sample count
/// ([`SobolSampler`]), so a render of up to 256 samples per pixel takes
/// two.
#[inline]
pub fn sobol_reversed(rindex: u32, dim: usize) -> u32 {
    coordinate(&NIBBLES, rindex, dim)
}

/// [`sobol_reversed`] from `table`'s dimension `dim`.
#[inline(always)]
fn coordinate(table: &Nibbles, rindex: u32, dim: usize) -> u32 {
    let t = &table[dim];
    let (mut x, mut v, mut k) = (0, rindex, 0);
    while v != 0 {
        x ^= t[k][(v >> 28) as usize];
        v <<= 4;
        k += 1;
    }
    x
}

/// Dimensions in a row of [`NIBBLES_BY_DIMENSION`]: the table's, then
/// eight of zeros, so that eight consecutive dimensions can be read from
/// any dimension up to [`SOBOL_DIMENSIONS`].
pub(crate) const ROW_DIMENSIONS: usize = SOBOL_DIMENSIONS + 8;

/// A table with the dimension innermost ([`nibbles_by_dimension_table`]).
pub(crate) type ByDimension = [[[u32; ROW_DIMENSIONS]; 16]; 8];

/// [`NIBBLES`] with the dimension innermost: `NIBBLES_BY_DIMENSION[k][n][d]
/// = NIBBLES[d][k][n]` (zero past the last dimension). The AVX lanes draw a
/// vertex's consecutive dimensions from it, eight per load (36 KB).
static NIBBLES_BY_DIMENSION: ByDimension = nibbles_by_dimension(&NIBBLES);

/// [`CAMERA_NIBBLES`] with the dimension innermost, for camera paths.
static CAMERA_NIBBLES_BY_DIMENSION: ByDimension = nibbles_by_dimension(&CAMERA_NIBBLES);

const fn nibbles_by_dimension(nibbles: &Nibbles) -> ByDimension {
    let mut t = [[[0u32; ROW_DIMENSIONS]; 16]; 8];
    let mut k = 0;
    while k < 8 {
        let mut n = 0;
        while n < 16 {
            let mut d = 0;
            while d < SOBOL_DIMENSIONS {
                t[k][n][d] = nibbles[d][k][n];
                d += 1;
            }
            n += 1;
        }
        k += 1;
    }
    t
}

/// The table of the lanes' consecutive dimensions: in the camera path's
/// order ([`CAMERA_ROWS`]) for a [`SobolSampler`]'s draws, in the table's
/// for a [`SobolWalkSampler`]'s.
#[inline(always)]
pub(crate) fn nibbles_by_dimension_table(walk: bool) -> &'static ByDimension {
    if walk {
        &NIBBLES_BY_DIMENSION
    } else {
        &CAMERA_NIBBLES_BY_DIMENSION
    }
}

/// A nested uniform (Owen) scramble of the 32-bit binary fraction `x`,
/// drawn from `seed`: each digit is flipped or not by a hash of the digits
/// before it, so that every elementary interval maps onto one of the same
/// size and a net stays a net (Burley 2020, §3). Done as a permutation
/// whose bit k depends only on bits 0..=k (Laine and Karras 2011) of the
/// bit-reversed fraction. Each step keeps that and is a bijection: adding,
/// multiplying by an odd number, and x ^= x·c with c even (whose bit k
/// takes only bits below k). The constants are Vegdahl's (2021), chosen
/// for how evenly the flips come out.
#[inline]
pub fn owen_scramble(x: u32, seed: u32) -> u32 {
    laine_karras(x.reverse_bits(), seed).reverse_bits()
}

/// The permutation of [`owen_scramble`] between its two bit reversals:
/// bit k of the result depends only on bits 0..=k of `x`.
#[inline(always)]
pub fn laine_karras(mut x: u32, seed: u32) -> u32 {
    x ^= x.wrapping_mul(0x3d20_adea);
    x = x.wrapping_add(seed);
    x = x.wrapping_mul((seed >> 16) | 1);
    x ^= x.wrapping_mul(0x0552_6c56);
    x ^ x.wrapping_mul(0x53a2_2864)
}

/// The first dimension of a camera path's vertex at `depth`: 0 and 1 are
/// the camera's, then seven per vertex (see the module's docs).
#[inline]
pub const fn vertex_dimension(depth: u32) -> u32 {
    let k = depth.saturating_sub(1);
    2 + 7 * if k < u32::MAX / 8 { k } else { u32::MAX / 8 }
}

/// A 32-bit fraction as a float in [0, 1) (24 bits: never rounds to 1).
#[inline]
fn to_unit(x: u32) -> f32 {
    (x >> 8) as f32 * (1.0 / 16_777_216.0)
}

/// A 32-bit seed from a key and a word (the shuffle's seed).
#[inline]
fn seed32(key: u64, word: u32) -> u32 {
    (mix64(key ^ (word as u64 + 1).wrapping_mul(0x9E37_79B9_7F4A_7C15)) >> 32) as u32
}

/// The seed of dimension `d`'s scramble from a pixel's 32-bit key: a
/// 32-bit hash (Wellons' `lowbias32`, 2018) of the key and the dimension,
/// cheap enough for every draw and computed eight lanes at a time in
/// `path`'s lanes (`owen_seed8` there, the same operations).
#[inline(always)]
pub fn dimension_seed(key: u32, d: u32) -> u32 {
    let mut x = key ^ d.wrapping_mul(0x9E37_79B9);
    x ^= x >> 16;
    x = x.wrapping_mul(0x7feb_352d);
    x ^= x >> 15;
    x = x.wrapping_mul(0x846c_a68b);
    x ^ (x >> 16)
}

/// The padding past the table: an independent 32-bit number from the
/// sample's key, its index and the dimension.
#[inline]
pub(crate) fn padding(key: u64, index: u32, d: u32) -> u32 {
    (mix64(key ^ mix64((index as u64) << 32 | d as u64)) >> 32) as u32
}

/// The Owen-scrambled Sobol numbers of one pixel's sample: a [`Sampler`]
/// keyed by (seed, pixel, sample index), whose draws take the dimensions
/// of the module's layout one after the other.
///
/// The index shuffle is a nested scramble whose flips of bit j depend on
/// the bits above j only; XORed with the shuffle of index 0, it maps every
/// block [0, 2^m) onto itself. So the sample takes the Sobol point whose
/// index is below 2^m, a few table lookups (see [`sobol`]), instead of one
/// at a full 32-bit index: that differs by a fixed point XORed into every
/// coordinate of the pixel (a digital shift), which the Owen scramble that
/// follows absorbs.
#[derive(Clone, Debug)]
pub struct SobolSampler {
    /// Hash of the seed, the pixel and the index's high word.
    key: u64,
    /// Its high 32 bits, the key of the dimensions' scramble seeds.
    key32: u32,
    /// The sample index within its block of 2^32 (the pass).
    index: u32,
    /// `index` after the pixel's shuffle, bit-reversed: the Sobol point
    /// this sample is, whose index is below the power of two above `index`.
    shuffled: u32,
    /// The next dimension to draw.
    dim: u32,
}

impl SobolSampler {
    /// The sampler of sample `index` (the pass) of `pixel` under `seed`.
    pub fn new(seed: u64, pixel: u64, index: u64) -> Self {
        Self::keyed(0x5851_F42D_4C95_7F2D, seed, pixel, index)
    }

    /// The sampler of sample `index` of the sequence keyed by `(a, b)`
    /// under the domain `h`: the hash of the keys and the index's high
    /// word chooses the index shuffle and the dimensions' scrambles.
    #[inline]
    fn keyed(mut h: u64, a: u64, b: u64, index: u64) -> Self {
        for k in [a, b, index >> 32] {
            h = mix64(h ^ mix64(k.wrapping_add(0x632B_E59B_D9B4_E019)));
        }
        let index = index as u32;
        let shuffle = seed32(h, u32::MAX);
        SobolSampler {
            key: h,
            key32: (h >> 32) as u32,
            index,
            // owen_scramble(index) ^ owen_scramble(0), bit-reversed
            shuffled: laine_karras(index.reverse_bits(), shuffle) ^ laine_karras(0, shuffle),
            dim: 0,
        }
    }

    /// The dimension the next draw takes.
    pub fn dimension(&self) -> u32 {
        self.dim
    }

    /// The 32-bit fraction of dimension `d` of `table`'s order: the Sobol
    /// point's coordinate, scrambled, inside the table; past it, a hash of
    /// the key, the index and `d` (independent numbers).
    #[inline]
    fn sample(&self, table: &Nibbles, d: u32) -> u32 {
        if (d as usize) < SOBOL_DIMENSIONS {
            // owen_scramble(sobol(..)), the table already reversed
            let x = coordinate(table, self.shuffled, d as usize);
            laine_karras(x, dimension_seed(self.key32, d)).reverse_bits()
        } else {
            padding(self.key, self.index, d)
        }
    }

    /// The next 1D draw, in `table`'s order.
    #[inline]
    fn draw_1d(&mut self, table: &Nibbles) -> f32 {
        let x = self.sample(table, self.dim);
        self.dim = self.dim.wrapping_add(1);
        to_unit(x)
    }

    /// The next 2D draw, in `table`'s order.
    #[inline]
    fn draw_2d(&mut self, table: &Nibbles) -> Vec2 {
        let (x, y) = (
            self.sample(table, self.dim),
            self.sample(table, self.dim.wrapping_add(1)),
        );
        self.dim = self.dim.wrapping_add(2);
        Vec2::new(to_unit(x), to_unit(y))
    }

    /// The sampler's fields, for `path`'s lanes, which hold them by field:
    /// (key, key32, index, shuffled, dimension).
    #[inline(always)]
    pub(crate) fn parts(&self) -> (u64, u32, u32, u32, u32) {
        (self.key, self.key32, self.index, self.shuffled, self.dim)
    }

    /// The sampler from [`SobolSampler::parts`].
    #[inline(always)]
    pub(crate) fn from_parts(key: u64, key32: u32, index: u32, shuffled: u32, dim: u32) -> Self {
        SobolSampler {
            key,
            key32,
            index,
            shuffled,
            dim,
        }
    }
}

/// The first dimension of a light walk's vertex at `depth` (1: the first
/// hit): 0 to 4 are the emission's (light choice, point, direction), then
/// four per vertex (see [`SobolWalkSampler`]).
#[inline]
pub fn walk_vertex_dimension(depth: u32) -> u32 {
    5 + 4 * depth.saturating_sub(1).min(u32::MAX / 8)
}

/// The Owen-scrambled Sobol numbers of one light-tracing walk (`light
/// --sampler sobol`): walk k of a pass is Sobol point k of a sequence
/// randomised by (seed, pass), since light paths belong to no pixel.
///
/// Layout: dimension 0 chooses the light, 1–2 the point on it, 3–4 the
/// direction of emission; the vertex at depth d (the d-th segment's end)
/// takes the four from 5 + 4 (d − 1), in the order the walk draws them:
/// Russian roulette (1D), then the BSDF's lobe (1D) and direction (2D).
/// Past the table ([`SOBOL_DIMENSIONS`]: from the 15th vertex's last
/// draw) the numbers are hashed independent ones, as in
/// [`SobolSampler`]. A pass's walks take the indices 0 … n − 1, split
/// among `light`'s lanes as contiguous ranges, so the points a pass draws
/// do not depend on the thread count, and a pass of n walks uses the
/// first n points of one shuffled sequence: every aligned block of 2^m of
/// them is a (t, m, s)-net.
#[derive(Clone, Debug)]
pub struct SobolWalkSampler(SobolSampler);

impl SobolWalkSampler {
    /// The sampler of walk `index` of pass `pass` under `seed`.
    #[inline]
    pub fn new(seed: u64, pass: u64, index: u64) -> Self {
        SobolWalkSampler(SobolSampler::keyed(
            0x1F83_D9AB_FB41_BD6B,
            seed,
            pass,
            index,
        ))
    }

    /// The dimension the next draw takes.
    pub fn dimension(&self) -> u32 {
        self.0.dim
    }

    /// The point's sampler, for the AVX lanes that hold eight walks'.
    #[inline(always)]
    pub(crate) fn sampler(&self) -> &SobolSampler {
        &self.0
    }

    /// The walk sampler of [`SobolWalkSampler::sampler`].
    #[inline(always)]
    pub(crate) fn from_sampler(s: SobolSampler) -> Self {
        SobolWalkSampler(s)
    }
}

impl Sampler for SobolWalkSampler {
    #[inline(always)]
    fn next_f32(&mut self) -> f32 {
        self.0.draw_1d(&NIBBLES)
    }

    #[inline(always)]
    fn next_2d(&mut self) -> Vec2 {
        self.0.draw_2d(&NIBBLES)
    }

    #[inline(always)]
    fn start_vertex(&mut self, depth: u32) {
        self.0.dim = walk_vertex_dimension(depth);
    }
}

impl Sampler for SobolSampler {
    #[inline]
    fn next_f32(&mut self) -> f32 {
        self.draw_1d(&CAMERA_NIBBLES)
    }

    #[inline]
    fn next_2d(&mut self) -> Vec2 {
        self.draw_2d(&CAMERA_NIBBLES)
    }

    #[inline]
    fn start_vertex(&mut self, depth: u32) {
        self.dim = vertex_dimension(depth);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The nibble tables give the XOR of the columns the index's bits
    /// select, as the definition says, at indices with every bit pattern.
    #[test]
    fn nibble_tables_agree_with_the_columns() {
        let mut i = 0x9E37_79B9u32;
        for step in 0..4000u32 {
            let index = if step < 1000 { step } else { i };
            for (d, columns) in DIRECTIONS.iter().enumerate() {
                let mut x = 0;
                for (j, v) in columns.iter().enumerate() {
                    if (index >> j) & 1 == 1 {
                        x ^= v;
                    }
                }
                assert_eq!(sobol(index, d), x, "index {index} dimension {d}");
            }
            i = i.wrapping_mul(0x2C9_277B5).wrapping_add(0xAC56_4B05);
        }
    }

    /// The table's rows are what Joe and Kuo's recurrence needs: m_k odd
    /// and below 2^k, a below 2^(s−1), and each polynomial primitive (the
    /// order of x modulo it is 2^s − 1) and different from the others.
    #[test]
    fn joe_kuo_rows_are_primitive_polynomials() {
        let mut seen = std::collections::HashSet::new();
        for (row, &(s, a, m)) in JOE_KUO.iter().enumerate() {
            assert_eq!(m.len(), s as usize, "row {row}");
            assert!(a < 1 << (s - 1), "row {row}");
            for (k, &mk) in m.iter().enumerate() {
                assert!(mk % 2 == 1 && mk < 2 << k, "row {row} m_{}", k + 1);
            }
            let poly = 1u32 << s | a << 1 | 1;
            let (mut p, mut order) = (1u32, 0u32);
            loop {
                p <<= 1;
                if p >> s & 1 == 1 {
                    p ^= poly;
                }
                order += 1;
                if p == 1 {
                    break;
                }
            }
            assert_eq!(order, (1 << s) - 1, "row {row}: polynomial not primitive");
            assert!(seen.insert(poly), "row {row}: polynomial repeated");
        }
    }
}
