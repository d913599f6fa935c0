//! The samplers of the AVX lanes ([`super::radiance_row`],
//! [`super::light_walks`]): eight [`Pcg32`] streams or eight
//! [`SobolSampler`]s, each lane drawing what the scalar step would draw, in
//! registers. Every `unsafe` block calls an intrinsic on register values or
//! on arrays it names; the functions run only inlined into `radiance_row`
//! or `light_walks`, which are compiled for AVX2 and called where the CPU
//! has it.

use std::arch::x86_64::*;

use super::super::LANES;
use super::{lanes, V};
use crate::sampling::sobol::{nibbles_by_dimension_table, padding, SOBOL_DIMENSIONS};
use crate::sampling::{Pcg32, Sampler, SobolSampler, PCG_MULT};

/// The samplers of eight lanes: a lane that takes the scalar step takes
/// its sampler out ([`Lanes::get`]) and puts it back ([`Lanes::set`]); the
/// lanes shaded together draw their vertex's numbers together. Each lane
/// draws what the scalar step would draw ([`crate::transport::CameraPath::scatter`]),
/// in its order and at its dimensions, so that lanes and scalar steps give
/// the same bits.
pub trait Lanes<S: Sampler> {
    /// Eight lanes holding placeholder samplers.
    fn new() -> Self;
    /// A placeholder sampler, for slots not yet given a pixel's.
    fn blank() -> S;
    /// Lane `i`'s sampler.
    fn get(&self, i: usize) -> S;
    /// Sets lane `i`'s sampler to `s`.
    fn set(&mut self, i: usize, s: &S);
    /// The numbers of the vertex at `depth[i]` of each lane `i` of `mask`,
    /// as `scatter` draws them after [`Sampler::start_vertex`]: the light's
    /// choice and point, the BSDF's lobe and direction (lanes outside
    /// `mask` hold meaningless numbers and keep their samplers), in
    /// registers of eight lanes.
    fn vertex(&mut self, mask: u32, depth: &[u32; LANES]) -> [__m256; 6];
    /// Russian roulette's number of each lane of `mask`, the draw after
    /// [`Lanes::vertex`]'s.
    fn roulette(&mut self, mask: u32) -> __m256;
    /// The first 2D draw of each lane of `mask` (`Sampler::next_2d` of a
    /// fresh sampler): the camera ray's jitter.
    fn jitter(&mut self, mask: u32) -> [__m256; 2];
}

/// The [`Pcg32`] of each lane, by field, so that the lanes that all draw
/// advance together ([`Rngs::draw`]).
#[repr(C, align(32))]
pub struct Rngs {
    state: [u64; LANES],
    inc: [u64; LANES],
}

impl Lanes<Pcg32> for Rngs {
    #[inline(always)]
    fn new() -> Self {
        Rngs {
            state: [0; LANES],
            inc: [0; LANES],
        }
    }

    #[inline(always)]
    fn blank() -> Pcg32 {
        Pcg32::new(0, 0)
    }

    #[inline(always)]
    fn get(&self, i: usize) -> Pcg32 {
        Pcg32::from_parts(self.state[i], self.inc[i])
    }

    #[inline(always)]
    fn set(&mut self, i: usize, r: &Pcg32) {
        (self.state[i], self.inc[i]) = r.parts();
    }

    /// Independent numbers ignore the depth: the eight generators advance
    /// together.
    #[inline(always)]
    fn vertex(&mut self, mask: u32, _depth: &[u32; LANES]) -> [__m256; 6] {
        self.draw::<6>(mask).map(|u| u.0)
    }

    #[inline(always)]
    fn roulette(&mut self, mask: u32) -> __m256 {
        let [u] = self.draw::<1>(mask);
        u.0
    }

    #[inline(always)]
    fn jitter(&mut self, mask: u32) -> [__m256; 2] {
        self.draw::<2>(mask).map(|u| u.0)
    }
}

/// The [`SobolSampler`] of each lane, by field. A lane's numbers are
/// coordinates of its own pixel's Sobol point, at dimensions that depend
/// on its depth.
#[repr(C, align(32))]
pub struct SobolLanes {
    key32: [u32; LANES],
    shuffled: [u32; LANES],
    dim: [u32; LANES],
    index: [u32; LANES],
    key: [u64; LANES],
    /// The lanes hold light walks' samplers ([`SobolLanes::walks`]), whose
    /// dimensions are the table's own, not camera paths' (whose first
    /// vertex takes them in another order,
    /// [`crate::sampling::sobol::CAMERA_ROWS`]).
    walk: bool,
}

impl Lanes<SobolSampler> for SobolLanes {
    #[inline(always)]
    fn new() -> Self {
        SobolLanes {
            key32: [0; LANES],
            shuffled: [0; LANES],
            dim: [0; LANES],
            index: [0; LANES],
            key: [0; LANES],
            walk: false,
        }
    }

    #[inline(always)]
    fn blank() -> SobolSampler {
        SobolSampler::from_parts(0, 0, 0, 0, 0)
    }

    #[inline(always)]
    fn get(&self, i: usize) -> SobolSampler {
        SobolSampler::from_parts(
            self.key[i],
            self.key32[i],
            self.index[i],
            self.shuffled[i],
            self.dim[i],
        )
    }

    #[inline(always)]
    fn set(&mut self, i: usize, s: &SobolSampler) {
        (
            self.key[i],
            self.key32[i],
            self.index[i],
            self.shuffled[i],
            self.dim[i],
        ) = s.parts();
    }

    #[inline(always)]
    fn vertex(&mut self, mask: u32, depth: &[u32; LANES]) -> [__m256; 6] {
        // vertex_dimension
        self.start_vertices(mask, depth, 7, 2);
        let x = self.coordinates_run(mask);
        self.draw_from::<6>(mask, &x)
    }

    #[inline(always)]
    fn roulette(&mut self, mask: u32) -> __m256 {
        let x = self.coordinates_run(mask);
        let [u] = self.draw_from::<1>(mask, &x);
        u
    }

    #[inline(always)]
    fn jitter(&mut self, mask: u32) -> [__m256; 2] {
        let x = self.coordinates_run(mask);
        self.draw_from::<2>(mask, &x)
    }
}

impl SobolLanes {
    /// Lanes for light walks' samplers
    /// ([`crate::sampling::SobolWalkSampler`]).
    #[inline(always)]
    pub(super) fn walks() -> Self {
        SobolLanes {
            walk: true,
            ..<Self as Lanes<SobolSampler>>::new()
        }
    }

    /// The four numbers of the vertex at `depth` of each light walk of
    /// `mask` whose [`crate::sampling::SobolWalkSampler`] the lanes hold:
    /// dimensions from `walk_vertex_dimension(depth)`, that is
    /// 5 + 4 (min(max(depth, 1) − 1, u32::MAX / 8)), as its
    /// `start_vertex` sets them, then the roulette's, the lobe's and the
    /// direction's draws.
    #[inline(always)]
    pub(super) fn walk_vertex(&mut self, mask: u32, depth: &[u32; LANES]) -> [__m256; 4] {
        self.start_vertices(mask, depth, 4, 5);
        let x = self.coordinates_run(mask);
        self.draw_from::<4>(mask, &x)
    }

    /// Sets the dimension of each lane of `mask` to its vertex's first,
    /// `first + per · (min(max(depth, 1) − 1, u32::MAX / 8))`: a camera
    /// path's `vertex_dimension` (7, 2) or a light walk's
    /// `walk_vertex_dimension` (4, 5), as `start_vertex` sets them.
    #[inline(always)]
    fn start_vertices(&mut self, mask: u32, depth: &[u32; LANES], per: i32, first: i32) {
        // SAFETY: loads and stores of eight u32 from and to arrays of
        // eight, register operations; only inlined into `radiance_row` or
        // `light_walks`, which run where the CPU has AVX2
        unsafe {
            let d = _mm256_loadu_si256(depth.as_ptr().cast());
            let d = _mm256_sub_epi32(
                _mm256_max_epu32(d, _mm256_set1_epi32(1)),
                _mm256_set1_epi32(1),
            );
            let d = _mm256_min_epu32(d, _mm256_set1_epi32((u32::MAX / 8) as i32));
            let d = _mm256_add_epi32(
                _mm256_mullo_epi32(d, _mm256_set1_epi32(per)),
                _mm256_set1_epi32(first),
            );
            let dp = self.dim.as_mut_ptr().cast::<__m256i>();
            let old = _mm256_load_si256(dp);
            _mm256_store_si256(dp, _mm256_blendv_epi8(old, d, mask32(mask)));
        }
    }

    /// The five numbers of the emission of each light walk of `mask`
    /// whose sampler the lanes hold, from dimension 0: the light's choice,
    /// the point's two, the direction's two.
    #[inline(always)]
    pub(super) fn walk_emission(&mut self, mask: u32) -> [__m256; 5] {
        for i in lanes(mask) {
            self.dim[i] = 0;
        }
        let x = self.coordinates_run(mask);
        self.draw_from::<5>(mask, &x)
    }

    /// The highest shuffled index of the lanes of `mask`: how many nibbles
    /// their coordinates take.
    #[inline(always)]
    fn top(&self, mask: u32) -> u32 {
        let mut top = 0;
        for i in lanes(mask) {
            top |= self.shuffled[i];
        }
        top
    }

    /// The unscrambled Sobol coordinates (bit-reversed) of each lane at its
    /// dimension + k, for k in 0..8, from as many nibbles as the highest
    /// shuffled index of the lanes of `mask` has (the indices come
    /// bit-reversed): per nibble position, each lane's eight consecutive
    /// dimensions in one load from the table by dimension, the eight rows
    /// transposed into the eight dimensions. Past the table it reads zeros
    /// (the draw pads those dimensions). Eight loads and a transpose
    /// instead of a gather for each dimension (which was the hottest line
    /// of `radiance_row`).
    #[inline(always)]
    fn coordinates_run(&self, mask: u32) -> [__m256i; 8] {
        let table = nibbles_by_dimension_table(self.walk);
        let mut x = [V::splat(0.0).0; 8];
        let (mut t, mut pos) = (self.top(mask), 0);
        while t != 0 {
            // A loop, not `array::from_fn` (see `Rngs::draw`)
            let mut rows = [x[0]; LANES];
            for (i, r) in rows.iter_mut().enumerate() {
                let n = ((self.shuffled[i] << (4 * pos)) >> 28) as usize;
                let d = (self.dim[i] as usize).min(SOBOL_DIMENSIONS);
                let row = &table[pos][n][d..d + 8];
                // SAFETY: eight u32 of the row, read as f32 bits (no
                // alignment needed); only inlined into `radiance_row` or
                // `light_walks`, which run where the CPU has AVX2
                *r = unsafe { _mm256_loadu_ps(row.as_ptr().cast()) };
            }
            // SAFETY: as above
            let cols = unsafe { crate::simd::transpose8(rows) };
            for (xk, c) in x.iter_mut().zip(cols) {
                // SAFETY: a register operation, as above
                *xk = unsafe { _mm256_xor_ps(*xk, c) };
            }
            t <<= 4;
            pos += 1;
        }
        // SAFETY: register casts, as above
        x.map(|v| unsafe { _mm256_castps_si256(v) })
    }

    /// The next `N` (at most 8) draws of each lane of `mask`, all eight
    /// lanes at once, from their unscrambled coordinates `x[k]` at
    /// dimension + k ([`SobolLanes::coordinates_run`]): the
    /// scramble seeds hashed ([`owen_seed8`]), the Owen scramble
    /// ([`crate::sampling::sobol::owen_scramble`]); the rare draws past the
    /// table are padded lane by lane.
    #[inline(always)]
    fn draw_from<const N: usize>(&mut self, mask: u32, x: &[__m256i; 8]) -> [__m256; N] {
        let live = mask32(mask);
        // SAFETY: loads and stores of eight u32 from and to the struct's
        // 32-byte aligned arrays of eight, register operations; only
        // inlined into `radiance_row`, which runs where the CPU has AVX2
        unsafe {
            let dp = self.dim.as_mut_ptr().cast::<__m256i>();
            let dim = _mm256_load_si256(dp);
            let key = _mm256_load_si256(self.key32.as_ptr().cast());
            let last = _mm256_set1_epi32(SOBOL_DIMENSIONS as i32 - 1);
            let mut out = [_mm256_setzero_ps(); N];
            // A loop, not `array::from_fn` (see `Rngs::draw`)
            for (k, o) in out.iter_mut().enumerate() {
                let d = _mm256_add_epi32(dim, _mm256_set1_epi32(k as i32));
                let inside = _mm256_min_epu32(d, last);
                let mut y = owen_scramble8(x[k], owen_seed8(key, d));
                // unsigned d > last: d is not its own minimum with last
                let past = _mm256_andnot_si256(_mm256_cmpeq_epi32(inside, d), live);
                let past = _mm256_movemask_ps(_mm256_castsi256_ps(past)) as u32;
                if past != 0 {
                    let mut a = [0u32; LANES];
                    _mm256_storeu_si256(a.as_mut_ptr().cast(), y);
                    for i in lanes(past) {
                        a[i] = padding(self.key[i], self.index[i], self.dim[i] + k as u32);
                    }
                    y = _mm256_loadu_si256(a.as_ptr().cast());
                }
                // (x >> 8) as f32 * 2^-24, as the scalar `to_unit`
                *o = _mm256_mul_ps(
                    _mm256_cvtepi32_ps(_mm256_srli_epi32::<8>(y)),
                    _mm256_set1_ps(1.0 / 16_777_216.0),
                );
            }
            let next = _mm256_add_epi32(dim, _mm256_set1_epi32(N as i32));
            _mm256_store_si256(dp, _mm256_blendv_epi8(dim, next, live));
            out
        }
    }
}

/// The u32 lanes of `mask` as all-ones lanes.
#[inline(always)]
fn mask32(mask: u32) -> __m256i {
    // SAFETY: register operations only; only inlined into `radiance_row` or
    // `light_walks`, which run where the CPU has AVX2
    unsafe {
        let lane = _mm256_setr_epi32(1, 2, 4, 8, 16, 32, 64, 128);
        let set = _mm256_set1_epi32(mask as i32);
        _mm256_cmpeq_epi32(_mm256_and_si256(set, lane), lane)
    }
}

/// [`crate::sampling::sobol::dimension_seed`] of eight keys and
/// dimensions, the same operations on 32-bit lanes.
#[inline(always)]
fn owen_seed8(key: __m256i, d: __m256i) -> __m256i {
    // SAFETY: register operations only; only inlined into `radiance_row` or
    // `light_walks`, which run where the CPU has AVX2
    unsafe {
        let mut x = _mm256_xor_si256(
            key,
            _mm256_mullo_epi32(d, _mm256_set1_epi32(0x9E37_79B9u32 as i32)),
        );
        x = _mm256_xor_si256(x, _mm256_srli_epi32::<16>(x));
        x = _mm256_mullo_epi32(x, _mm256_set1_epi32(0x7feb_352d));
        x = _mm256_xor_si256(x, _mm256_srli_epi32::<15>(x));
        x = _mm256_mullo_epi32(x, _mm256_set1_epi32(0x846c_a68bu32 as i32));
        _mm256_xor_si256(x, _mm256_srli_epi32::<16>(x))
    }
}

/// The bits of eight u32 reversed: the bytes of each swapped, then each
/// byte's nibbles looked up reversed and swapped.
#[inline(always)]
fn reverse_bits8(x: __m256i) -> __m256i {
    // SAFETY: register operations only; only inlined into `radiance_row` or
    // `light_walks`, which run where the CPU has AVX2
    unsafe {
        #[rustfmt::skip]
        let bswap = _mm256_setr_epi8(
            3, 2, 1, 0, 7, 6, 5, 4, 11, 10, 9, 8, 15, 14, 13, 12,
            3, 2, 1, 0, 7, 6, 5, 4, 11, 10, 9, 8, 15, 14, 13, 12,
        );
        // rev4[n] and rev4[n] << 4, for the low and the high nibble
        #[rustfmt::skip]
        let (lo_tbl, hi_tbl) = (
            _mm256_setr_epi8(
                0, 8, 4, 12, 2, 10, 6, 14, 1, 9, 5, 13, 3, 11, 7, 15,
                0, 8, 4, 12, 2, 10, 6, 14, 1, 9, 5, 13, 3, 11, 7, 15,
            ),
            _mm256_setr_epi8(
                0x00, -0x80, 0x40, -0x40, 0x20, -0x60, 0x60, -0x20,
                0x10, -0x70, 0x50, -0x30, 0x30, -0x50, 0x70, -0x10,
                0x00, -0x80, 0x40, -0x40, 0x20, -0x60, 0x60, -0x20,
                0x10, -0x70, 0x50, -0x30, 0x30, -0x50, 0x70, -0x10,
            ),
        );
        let x = _mm256_shuffle_epi8(x, bswap);
        let nib = _mm256_set1_epi8(0x0f);
        let lo = _mm256_and_si256(x, nib);
        let hi = _mm256_and_si256(_mm256_srli_epi16::<4>(x), nib);
        _mm256_or_si256(
            _mm256_shuffle_epi8(hi_tbl, lo),
            _mm256_shuffle_epi8(lo_tbl, hi),
        )
    }
}

/// [`crate::sampling::sobol::owen_scramble`] of eight u32 whose bits come
/// reversed in `x` (as the tables hold them) with their seeds: the same
/// operations on 32-bit lanes after the first reversal.
#[inline(always)]
fn owen_scramble8(x: __m256i, seed: __m256i) -> __m256i {
    // SAFETY: register operations only; only inlined into `radiance_row` or
    // `light_walks`, which run where the CPU has AVX2
    unsafe {
        let mut x = x;
        x = _mm256_xor_si256(x, _mm256_mullo_epi32(x, _mm256_set1_epi32(0x3d20_adea)));
        x = _mm256_add_epi32(x, seed);
        let odd = _mm256_or_si256(_mm256_srli_epi32::<16>(seed), _mm256_set1_epi32(1));
        x = _mm256_mullo_epi32(x, odd);
        x = _mm256_xor_si256(x, _mm256_mullo_epi32(x, _mm256_set1_epi32(0x0552_6c56)));
        x = _mm256_xor_si256(x, _mm256_mullo_epi32(x, _mm256_set1_epi32(0x53a2_2864)));
        reverse_bits8(x)
    }
}

impl Rngs {
    /// `N` numbers of each lane of `mask`, each drawn as
    /// [`Pcg32::next_f32`] draws it (in lanes outside `mask` the numbers
    /// are meaningless and the generators stay as they were).
    #[inline(always)]
    fn draw<const N: usize>(&mut self, mask: u32) -> [V; N] {
        // SAFETY: the arrays hold eight u64 each, 32-byte aligned (the
        // struct's repr), read and written as two 256-bit halves; only
        // inlined into `radiance_row`, which runs where the CPU has AVX2
        unsafe {
            let sp = self.state.as_mut_ptr().cast::<__m256i>();
            let ip = self.inc.as_ptr().cast::<__m256i>();
            let old = [_mm256_load_si256(sp), _mm256_load_si256(sp.add(1))];
            let inc = [_mm256_load_si256(ip), _mm256_load_si256(ip.add(1))];
            let mut s = old;
            // A loop, not `array::from_fn`: a closure does not inherit the
            // caller's AVX2, and out of line its intrinsics become calls
            // (as `main`'s binary had it, at twice the time per sample)
            let mut out = [V(_mm256_setzero_ps()); N];
            for o in &mut out {
                let x = pack32(xsh_rr(s[0]), xsh_rr(s[1]));
                s = [step(s[0], inc[0]), step(s[1], inc[1])];
                // (x >> 8) as f32 * 2^-24
                *o = V(_mm256_mul_ps(
                    _mm256_cvtepi32_ps(_mm256_srli_epi32::<8>(x)),
                    _mm256_set1_ps(1.0 / 16_777_216.0),
                ));
            }
            _mm256_store_si256(sp, _mm256_blendv_epi8(old[0], s[0], mask64(mask, 1)));
            _mm256_store_si256(
                sp.add(1),
                _mm256_blendv_epi8(old[1], s[1], mask64(mask, 16)),
            );
            out
        }
    }
}

/// The u64 lanes of `mask` whose bits start at `bits` (1 for lanes 0–3,
/// 16 for lanes 4–7), as all-ones lanes.
#[inline(always)]
fn mask64(mask: u32, bits: i64) -> __m256i {
    // SAFETY: register operations only; only inlined into `radiance_row` or
    // `light_walks`, which run where the CPU has AVX2
    unsafe {
        let lane = _mm256_setr_epi64x(bits, bits << 1, bits << 2, bits << 3);
        let set = _mm256_set1_epi64x(i64::from(mask));
        _mm256_cmpeq_epi64(_mm256_and_si256(set, lane), lane)
    }
}

/// PCG32's state transition, `state · PCG_MULT + inc` mod 2⁶⁴, in four u64
/// lanes: the product from three 32 × 32-bit ones (the high × high one
/// falls outside 64 bits).
#[inline(always)]
fn step(state: __m256i, inc: __m256i) -> __m256i {
    // SAFETY: register operations only; only inlined into `radiance_row` or
    // `light_walks`, which run where the CPU has AVX2
    unsafe {
        let lo = _mm256_set1_epi64x((PCG_MULT & 0xFFFF_FFFF) as i64);
        let hi = _mm256_set1_epi64x((PCG_MULT >> 32) as i64);
        let ll = _mm256_mul_epu32(state, lo);
        let hl = _mm256_mul_epu32(_mm256_srli_epi64::<32>(state), lo);
        let lh = _mm256_mul_epu32(state, hi);
        let cross = _mm256_slli_epi64::<32>(_mm256_add_epi64(hl, lh));
        _mm256_add_epi64(_mm256_add_epi64(ll, cross), inc)
    }
}

/// PCG32's output (XSH RR) of four u64 states, in the low 32 bits of each
/// lane.
#[inline(always)]
fn xsh_rr(old: __m256i) -> __m256i {
    // SAFETY: register operations only; only inlined into `radiance_row` or
    // `light_walks`, which run where the CPU has AVX2
    unsafe {
        let x = _mm256_srli_epi64::<27>(_mm256_xor_si256(_mm256_srli_epi64::<18>(old), old));
        let rot = _mm256_srli_epi64::<59>(old);
        // rotate right; a left shift by 32 gives 0, as rotate_right(0) needs
        let left = _mm256_sub_epi32(_mm256_set1_epi32(32), rot);
        _mm256_or_si256(_mm256_srlv_epi32(x, rot), _mm256_sllv_epi32(x, left))
    }
}

/// The low 32 bits of the u64 lanes of `a` (lanes 0–3) and `b` (lanes 4–7),
/// as eight u32 in lane order.
#[inline(always)]
fn pack32(a: __m256i, b: __m256i) -> __m256i {
    // SAFETY: register operations only; only inlined into `radiance_row` or
    // `light_walks`, which run where the CPU has AVX2
    unsafe {
        let a = _mm256_shuffle_epi32::<0b10_00_10_00>(a);
        let b = _mm256_shuffle_epi32::<0b10_00_10_00>(b);
        // per 128 bits: a's two, b's two; then the 64-bit pieces reordered
        let ab = _mm256_blend_epi32::<0b1100_1100>(a, b);
        _mm256_permute4x64_epi64::<0b11_01_10_00>(ab)
    }
}
