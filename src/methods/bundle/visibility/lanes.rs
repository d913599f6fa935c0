//! The projection of eight patches at once (AVX2), from the corners kept by
//! coordinate ([`Corners`]).
//!
//! [`project_avx2`] does what the scalar loop of [`super::project`] does
//! for each patch, [`ToMap::patch`] then [`Proj::new`] with pixel-centre
//! roulette, in eight lanes: the map coordinates and depths, the centroid's
//! sort key, the orientation and the area's tests, the box of pixel centres
//! and its clipping, the tie rules, and the test of a one-pixel box. Each
//! lane runs the scalar code's IEEE operations in the same order (Rust
//! never contracts a·b + c into a fused multiply-add), and the box's
//! ceiling and floor are exact in both, so every projection is bit for bit
//! the scalar one; only the patches that cover a pixel centre come out, in
//! patch order. The test `lanes_match_scalar` checks this.

use std::arch::x86_64::*;
use std::ops::Range;

use super::raster::{Proj, Projector, ToMap, BOX_LIMIT};
use crate::methods::bundle::patches::Corners;
use crate::simd::transpose8;

// The write-out stores each projection as eighteen 4-byte rows in the
// order of `Proj`'s fields (C layout); these pin that layout.
const _: () = {
    use std::mem::{offset_of, size_of};
    assert!(size_of::<Proj>() == 72);
    assert!(offset_of!(Proj, z) == 24 && offset_of!(Proj, inv) == 36);
    assert!(offset_of!(Proj, id) == 40 && offset_of!(Proj, key) == 44);
    assert!(offset_of!(Proj, x0) == 48 && offset_of!(Proj, x1) == 52);
    assert!(offset_of!(Proj, y0) == 56 && offset_of!(Proj, y1) == 60);
    assert!(offset_of!(Proj, owns) == 64 && offset_of!(Proj, cover) == 68);
};

/// Whether [`project_avx2`] may run: the CPU has AVX2, and
/// `KALOS_DISPATCH=baseline` does not ask for the baseline copies.
pub(super) fn available() -> bool {
    crate::simd::has_v3()
}

/// Twice the signed area of (a, b, p), as `raster::edge`, in lanes.
#[inline]
#[target_feature(enable = "avx2")]
fn edge(ax: __m256, ay: __m256, bx: __m256, by: __m256, px: __m256, py: __m256) -> __m256 {
    _mm256_sub_ps(
        _mm256_mul_ps(_mm256_sub_ps(bx, ax), _mm256_sub_ps(py, ay)),
        _mm256_mul_ps(_mm256_sub_ps(by, ay), _mm256_sub_ps(px, ax)),
    )
}

/// The tie rule `raster::owns` of edge a → b, as a lane mask.
#[inline]
#[target_feature(enable = "avx2")]
fn owns(ax: __m256, ay: __m256, bx: __m256, by: __m256) -> __m256 {
    let (dx, dy) = (_mm256_sub_ps(bx, ax), _mm256_sub_ps(by, ay));
    let zero = _mm256_setzero_ps();
    _mm256_or_ps(
        _mm256_cmp_ps::<_CMP_GT_OQ>(dy, zero),
        _mm256_and_ps(
            _mm256_cmp_ps::<_CMP_EQ_OQ>(dy, zero),
            _mm256_cmp_ps::<_CMP_GT_OQ>(dx, zero),
        ),
    )
}

/// (x·w.x + y·w.y) + z·w.z, as glam's `Vec4` sums in `ToMap::patch`.
#[inline]
#[target_feature(enable = "avx2")]
fn dot(x: __m256, y: __m256, z: __m256, w: [__m256; 3]) -> __m256 {
    _mm256_add_ps(
        _mm256_add_ps(_mm256_mul_ps(x, w[0]), _mm256_mul_ps(y, w[1])),
        _mm256_mul_ps(z, w[2]),
    )
}

/// A pixel-centre edge function's test with its tie rule: w > 0, or w = 0
/// on an owned edge.
#[inline]
#[target_feature(enable = "avx2")]
fn covers(w: __m256, own: __m256) -> __m256 {
    let zero = _mm256_setzero_ps();
    _mm256_or_ps(
        _mm256_cmp_ps::<_CMP_GT_OQ>(w, zero),
        _mm256_and_ps(_mm256_cmp_ps::<_CMP_EQ_OQ>(w, zero), own),
    )
}

/// Eight values of `a` from `i`.
///
/// # Safety
///
/// `a` must hold at least `i + 8` values.
#[inline]
#[target_feature(enable = "avx2")]
unsafe fn load(a: &[f32], i: usize) -> __m256 {
    debug_assert!(a.len() >= i + 8);
    // SAFETY: the caller's promise
    unsafe { _mm256_loadu_ps(a.as_ptr().add(i)) }
}

/// `box_bounds`'s lower bound ⌈v − ½⌉ of a box's pixel centres: clamped to
/// ±[`BOX_LIMIT`] first, then an exact ceiling and conversion.
#[inline]
#[target_feature(enable = "avx2")]
fn ceil_centre(v: __m256) -> __m256i {
    _mm256_cvttps_epi32(_mm256_round_ps::<_MM_FROUND_TO_POS_INF>(clamp(v)))
}

/// `box_bounds`'s upper bound ⌊v − ½⌋.
#[inline]
#[target_feature(enable = "avx2")]
fn floor_centre(v: __m256) -> __m256i {
    _mm256_cvttps_epi32(_mm256_round_ps::<_MM_FROUND_TO_NEG_INF>(clamp(v)))
}

/// v − ½ clamped to ±[`BOX_LIMIT`], as `box_bounds` does (max, then min).
#[inline]
#[target_feature(enable = "avx2")]
fn clamp(v: __m256) -> __m256 {
    let v = _mm256_sub_ps(v, _mm256_set1_ps(0.5));
    _mm256_min_ps(
        _mm256_max_ps(v, _mm256_set1_ps(-BOX_LIMIT)),
        _mm256_set1_ps(BOX_LIMIT),
    )
}

/// [`ToMap`]'s values in every lane.
struct MapLanes {
    /// The map's centre.
    o: [__m256; 3],
    /// The map's frame: its two axes and its direction.
    s: [__m256; 3],
    t: [__m256; 3],
    d: [__m256; 3],
    radius: __m256,
    delta: __m256,
    jx: __m256,
    jy: __m256,
}

/// Eight patches on the map.
struct OnMap {
    /// The corners' map coordinates and depths.
    u: [__m256; 3],
    w: [__m256; 3],
    z: [__m256; 3],
    /// The centroid's depth.
    centroid: __m256,
}

/// Eight triangles on the map, counter-clockwise, and what `Proj::new`
/// finds of them.
struct Oriented {
    /// The corners a, b, c: map coordinates and depths.
    ax: __m256,
    ay: __m256,
    za: __m256,
    bx: __m256,
    by: __m256,
    zb: __m256,
    cx: __m256,
    cy: __m256,
    zc: __m256,
    /// Twice the area.
    area: __m256,
    /// The lanes that are neither degenerate nor non-finite.
    keep: __m256,
}

/// The boxes of pixel centres, clipped to the map.
struct PixelBox {
    x0: __m256i,
    y0: __m256i,
    x1: __m256i,
    y1: __m256i,
}

/// The tie rules and the test of a one-pixel box.
struct Centre {
    /// The tie rules of b→c, c→a, a→b, as bits 1, 2 and 4.
    bits: __m256i,
    /// 1 / (twice the area).
    inv: __m256,
    /// The lanes whose box holds one pixel centre.
    single: __m256,
    /// Those lanes' depth at the centre.
    z1: __m256,
    /// The lanes kept: boxes of one centre must cover it.
    keep: __m256,
}

/// Projects patches `range` with corners `corners`, as the scalar loop of
/// [`super::project`] does with pixel-centre roulette (`pj.centre_rr`),
/// and pushes each projection that covers a pixel centre onto `out`, in
/// patch order. The sort key is the centroid's order bits when `painter`,
/// else 0.
///
/// # Safety
///
/// The CPU must have AVX2 ([`available`]); `range` must lie within the
/// patches of `corners`.
#[target_feature(enable = "avx2")]
pub(super) unsafe fn project_avx2(
    corners: &Corners,
    range: Range<usize>,
    to_map: &ToMap,
    pj: &Projector,
    painter: bool,
    out: &mut Vec<Proj>,
) {
    debug_assert!(pj.centre_rr);
    let c = &corners.c;
    assert!(c.iter().all(|a| a.len() >= range.end + 7));
    let set = _mm256_set1_ps;
    let splat3 = |v: glam::Vec3| [set(v.x), set(v.y), set(v.z)];
    let map = MapLanes {
        o: splat3(to_map.center),
        s: splat3(to_map.frame.s),
        t: splat3(to_map.frame.t),
        d: splat3(to_map.d),
        radius: set(to_map.radius),
        delta: set(to_map.delta),
        jx: set(to_map.jitter.x),
        jy: set(to_map.jitter.y),
    };
    let mut i = range.start;
    while i < range.end {
        // SAFETY: every array holds at least `range.end + 7` values
        let v: [[__m256; 3]; 3] = unsafe {
            [
                [load(&c[0], i), load(&c[1], i), load(&c[2], i)],
                [load(&c[3], i), load(&c[4], i), load(&c[5], i)],
                [load(&c[6], i), load(&c[7], i), load(&c[8], i)],
            ]
        };
        let m = patch(&v, &map);
        let key = if painter {
            order_bits(m.centroid)
        } else {
            _mm256_setzero_si256()
        };
        let tri = orient(&m);
        let bx = pixel_box(&tri, pj);
        let ce = centre(&tri, &bx);

        // The projections of the kept lanes, in patch order
        let mut mask = _mm256_movemask_ps(ce.keep) as u32;
        let left = range.end - i;
        if left < 8 {
            mask &= (1 << left) - 1;
        }
        if mask != 0 {
            write_out(&tri, &bx, &ce, key, i, mask, out);
        }
        i += 8;
    }
}

/// `ToMap::patch` of eight patches with corners `v`: the centroid
/// ((v0 + v1) + v2) / 3, its depth (the scalar lane's subtraction of 0
/// leaves it as it is), the corners on the map.
#[inline]
#[target_feature(enable = "avx2")]
fn patch(v: &[[__m256; 3]; 3], map: &MapLanes) -> OnMap {
    let zero = _mm256_setzero_ps();
    let three = _mm256_set1_ps(3.0);
    let mut m = [zero; 3];
    for (a, m) in m.iter_mut().enumerate() {
        *m = _mm256_div_ps(
            _mm256_add_ps(_mm256_add_ps(v[0][a], v[1][a]), v[2][a]),
            three,
        );
    }
    let centroid = dot(m[0], m[1], m[2], map.d);
    let mut u = [zero; 3];
    let mut w = [zero; 3];
    let mut z = [zero; 3];
    for k in 0..3 {
        let x = _mm256_sub_ps(v[k][0], map.o[0]);
        let y = _mm256_sub_ps(v[k][1], map.o[1]);
        let zz = _mm256_sub_ps(v[k][2], map.o[2]);
        u[k] = _mm256_add_ps(
            _mm256_div_ps(_mm256_add_ps(dot(x, y, zz, map.s), map.radius), map.delta),
            map.jx,
        );
        w[k] = _mm256_add_ps(
            _mm256_div_ps(_mm256_add_ps(dot(x, y, zz, map.t), map.radius), map.delta),
            map.jy,
        );
        z[k] = dot(x, y, zz, map.d);
    }
    OnMap { u, w, z, centroid }
}

/// `order_bits`: negative values reversed, positive ones above them.
#[inline]
#[target_feature(enable = "avx2")]
fn order_bits(v: __m256) -> __m256i {
    let k = _mm256_castps_si256(v);
    let flip = _mm256_or_si256(_mm256_srai_epi32::<31>(k), _mm256_set1_epi32(i32::MIN));
    _mm256_xor_si256(k, flip)
}

/// `Proj::new`'s first steps: a degenerate or non-finite projection
/// covers nothing, and the triangle turns counter-clockwise (b and c
/// swapped where the area is negative).
#[inline]
#[target_feature(enable = "avx2")]
fn orient(m: &OnMap) -> Oriented {
    let (u, w, z) = (&m.u, &m.w, &m.z);
    let zero = _mm256_setzero_ps();
    let inf = _mm256_set1_ps(f32::INFINITY);
    let abs_mask = _mm256_castsi256_ps(_mm256_set1_epi32(i32::MAX));
    let signed = edge(u[0], w[0], u[1], w[1], u[2], w[2]);
    let area = _mm256_and_ps(signed, abs_mask);
    let keep = _mm256_and_ps(
        _mm256_cmp_ps::<_CMP_LT_OQ>(area, inf),
        _mm256_cmp_ps::<_CMP_NEQ_OQ>(signed, zero),
    );
    let neg = _mm256_cmp_ps::<_CMP_LT_OQ>(signed, zero);
    Oriented {
        ax: u[0],
        ay: w[0],
        za: z[0],
        bx: _mm256_blendv_ps(u[1], u[2], neg),
        by: _mm256_blendv_ps(w[1], w[2], neg),
        zb: _mm256_blendv_ps(z[1], z[2], neg),
        cx: _mm256_blendv_ps(u[2], u[1], neg),
        cy: _mm256_blendv_ps(w[2], w[1], neg),
        zc: _mm256_blendv_ps(z[2], z[1], neg),
        area,
        keep,
    }
}

/// The box of pixel centres (`box_bounds`: clamped, then exact ceiling and
/// floor), clipped to the map.
#[inline]
#[target_feature(enable = "avx2")]
fn pixel_box(t: &Oriented, pj: &Projector) -> PixelBox {
    let izero = _mm256_setzero_si256();
    let (wmax, hmax) = (_mm256_set1_epi32(pj.w - 1), _mm256_set1_epi32(pj.h - 1));
    let lo_x = _mm256_min_ps(_mm256_min_ps(t.ax, t.bx), t.cx);
    let lo_y = _mm256_min_ps(_mm256_min_ps(t.ay, t.by), t.cy);
    let hi_x = _mm256_max_ps(_mm256_max_ps(t.ax, t.bx), t.cx);
    let hi_y = _mm256_max_ps(_mm256_max_ps(t.ay, t.by), t.cy);
    PixelBox {
        x0: _mm256_max_epi32(ceil_centre(lo_x), izero),
        y0: _mm256_max_epi32(ceil_centre(lo_y), izero),
        x1: _mm256_min_epi32(floor_centre(hi_x), wmax),
        y1: _mm256_min_epi32(floor_centre(hi_y), hmax),
    }
}

/// The tie rules of b→c, c→a, a→b, 1 / (twice the area), and for a box of
/// one pixel centre `Proj::centre`'s test and depth; an empty box, or a
/// one-centre box whose centre the triangle misses, drops the lane.
#[inline]
#[target_feature(enable = "avx2")]
fn centre(t: &Oriented, b: &PixelBox) -> Centre {
    let (ax, ay, bx, by, cx, cy) = (t.ax, t.ay, t.bx, t.by, t.cx, t.cy);
    let empty = _mm256_or_si256(
        _mm256_cmpgt_epi32(b.x0, b.x1),
        _mm256_cmpgt_epi32(b.y0, b.y1),
    );
    let keep = _mm256_andnot_ps(_mm256_castsi256_ps(empty), t.keep);
    let own = [
        owns(bx, by, cx, cy),
        owns(cx, cy, ax, ay),
        owns(ax, ay, bx, by),
    ];
    let bits = _mm256_or_si256(
        _mm256_and_si256(_mm256_castps_si256(own[0]), _mm256_set1_epi32(1)),
        _mm256_or_si256(
            _mm256_and_si256(_mm256_castps_si256(own[1]), _mm256_set1_epi32(2)),
            _mm256_and_si256(_mm256_castps_si256(own[2]), _mm256_set1_epi32(4)),
        ),
    );
    let inv = _mm256_div_ps(_mm256_set1_ps(1.0), t.area);
    let single = _mm256_castsi256_ps(_mm256_and_si256(
        _mm256_cmpeq_epi32(b.x0, b.x1),
        _mm256_cmpeq_epi32(b.y0, b.y1),
    ));
    let half = _mm256_set1_ps(0.5);
    let px = _mm256_add_ps(_mm256_cvtepi32_ps(b.x0), half);
    let py = _mm256_add_ps(_mm256_cvtepi32_ps(b.y0), half);
    let wa = edge(bx, by, cx, cy, px, py);
    let wb = edge(cx, cy, ax, ay, px, py);
    let wc = edge(ax, ay, bx, by, px, py);
    let inside = _mm256_and_ps(
        _mm256_and_ps(covers(wa, own[0]), covers(wb, own[1])),
        covers(wc, own[2]),
    );
    let z1 = _mm256_mul_ps(
        _mm256_add_ps(
            _mm256_add_ps(_mm256_mul_ps(wa, t.za), _mm256_mul_ps(wb, t.zb)),
            _mm256_mul_ps(wc, t.zc),
        ),
        inv,
    );
    Centre {
        bits,
        inv,
        single,
        z1,
        keep: _mm256_andnot_ps(_mm256_andnot_ps(inside, single), keep),
    }
}

/// Pushes the projections of the lanes of `mask` (patches `i`..) onto
/// `out`, in patch order: the 18 fields of `Proj` (C layout) as rows of
/// eight lanes, transposed so that each lane's 72 bytes are three stores.
#[inline]
#[target_feature(enable = "avx2")]
fn write_out(
    t: &Oriented,
    b: &PixelBox,
    ce: &Centre,
    key: __m256i,
    i: usize,
    mut mask: u32,
    out: &mut Vec<Proj>,
) {
    let id = _mm256_add_epi32(
        _mm256_set1_epi32(i as i32),
        _mm256_setr_epi32(0, 1, 2, 3, 4, 5, 6, 7),
    );
    // a one-pixel projection's depths are all that of its centre;
    // its cover is Cover::One (1), else Cover::Raster (0)
    let single = ce.single;
    let cover = _mm256_and_si256(_mm256_castps_si256(single), _mm256_set1_epi32(1));
    let f = _mm256_castsi256_ps;
    let lo = transpose8([
        t.ax,
        t.ay,
        t.bx,
        t.by,
        t.cx,
        t.cy,
        _mm256_blendv_ps(t.za, ce.z1, single),
        _mm256_blendv_ps(t.zb, ce.z1, single),
    ]);
    let hi = transpose8([
        _mm256_blendv_ps(t.zc, ce.z1, single),
        ce.inv,
        f(id),
        f(key),
        f(b.x0),
        f(b.x1),
        f(b.y0),
        f(b.y1),
    ]);
    // owns and cover, pairs by lane: 0, 1, 4, 5 in `a`, 2, 3, 6, 7 in `b`
    let (pa, pb) = (
        _mm256_unpacklo_ps(f(ce.bits), f(cover)),
        _mm256_unpackhi_ps(f(ce.bits), f(cover)),
    );
    let mut tail = [0u64; 8];
    // SAFETY: `tail` holds eight u64 (unaligned stores)
    unsafe {
        _mm256_storeu_ps(
            tail.as_mut_ptr().cast(),
            _mm256_permute2f128_ps::<0x20>(pa, pb),
        );
        _mm256_storeu_ps(
            tail.as_mut_ptr().add(4).cast(),
            _mm256_permute2f128_ps::<0x31>(pa, pb),
        );
    }
    // tail now holds lanes 0, 1, 2, 3 and 4, 5, 6, 7 in order
    out.reserve(8);
    let mut len = out.len();
    let at = out.as_mut_ptr();
    while mask != 0 {
        let l = mask.trailing_zeros() as usize;
        mask &= mask - 1;
        // SAFETY: at most 8 lanes, and 8 places were reserved; Proj
        // is 72 bytes in C layout, its fields as the rows above
        unsafe {
            let p = at.add(len).cast::<f32>();
            _mm256_storeu_ps(p, lo[l]);
            _mm256_storeu_ps(p.add(8), hi[l]);
            p.add(16).cast::<u64>().write_unaligned(tail[l]);
        }
        len += 1;
    }
    // SAFETY: the places up to `len` were written just above
    unsafe { out.set_len(len) };
}

#[cfg(test)]
mod tests {
    use glam::{Vec2, Vec3};

    use super::*;
    use crate::geometry::Frame;
    use crate::methods::bundle::visibility::raster::order_bits;
    use crate::methods::bundle::visibility::raster::Cover;
    use crate::sampling::Pcg32;

    /// Every field of a projection, as bits.
    fn bits(p: &Proj) -> Vec<u32> {
        let mut b: Vec<u32> =
            p.t.iter()
                .flat_map(|v| [v.x.to_bits(), v.y.to_bits()])
                .collect();
        b.extend(p.z.iter().map(|z| z.to_bits()));
        b.extend([p.inv.to_bits(), p.id, p.key, p.owns]);
        b.extend([p.x0, p.x1, p.y0, p.y1].map(|v| v as u32));
        b.push((p.cover == Cover::One) as u32);
        b
    }

    /// The eight-lane projection gives the scalar loop's projections bit
    /// for bit, in the same order: patches from sub-pixel to hundreds of
    /// pixels, degenerate ones, ones off or across the map's edges, corners
    /// on the half-pixel grid (ties on the edge functions), with and
    /// without the painter's keys, from ranges that start and end off the
    /// lanes' groups of eight.
    #[test]
    fn lanes_match_scalar() {
        if !available() {
            eprintln!("no AVX2: the eight-lane projection is not used here");
            return;
        }
        let mut rng = Pcg32::keyed(&[81]);
        let mut counts = [0usize; 3]; // one-pixel, raster, projected
        for case in 0..40 {
            // a random direction, or +z with a power-of-two pixel on a grid
            let grid = case % 4 == 0;
            let d = if grid {
                Vec3::Z
            } else {
                (Vec3::new(rng.next_f32(), rng.next_f32(), rng.next_f32()) - 0.5).normalize()
            };
            let (radius, res) = (16.0, [1024, 32][case % 2]);
            let delta = 2.0 * radius / res as f32;
            let to_map = ToMap {
                center: Vec3::ZERO,
                frame: Frame::from_normal(d),
                d,
                radius,
                delta,
                jitter: if grid {
                    Vec2::ZERO
                } else {
                    Vec2::new(rng.next_f32(), rng.next_f32())
                },
            };
            let pj = Projector {
                w: res + 1,
                h: res + 1,
                centre_rr: true,
                keys: [case as u64, 7],
            };
            // patches of sizes from a tenth of a pixel to hundreds
            let n = 3001;
            let v: Vec<[Vec3; 3]> = (0..n)
                .map(|i| {
                    let mut p = || Vec3::new(rng.next_f32(), rng.next_f32(), rng.next_f32());
                    let size = delta * [0.1, 0.7, 1.5, 4.0, 300.0][i % 5];
                    let at = (p() * 2.0 - 1.0) * radius * 1.1;
                    let mut v = [at, at + (p() - 0.5) * size, at + (p() - 0.5) * size];
                    if grid {
                        // corners on multiples of half a pixel
                        v = v.map(|x| (x / (0.5 * delta)).round() * (0.5 * delta));
                    }
                    match i % 23 {
                        0 => v[2] = v[1],                       // degenerate
                        1 => v[2] = v[0] + (v[1] - v[0]) * 2.0, // collinear
                        _ => {}
                    }
                    v
                })
                .collect();
            let corners = Corners::new(n, |i| v[i]);
            let painter = case % 3 != 0;
            let range = [0..n, 5..n - 3, 13..14][case % 3].clone();
            let mut want = Vec::new();
            for id in range.clone() {
                let (t, z, centroid) = to_map.patch(&v[id]);
                let key = if painter { order_bits(centroid) } else { 0 };
                want.extend(Proj::new(&pj, id as u32, t, z, key));
            }
            let mut got = Vec::new();
            // SAFETY: available() said the CPU has AVX2; range ≤ n
            unsafe { project_avx2(&corners, range, &to_map, &pj, painter, &mut got) };
            assert_eq!(got.len(), want.len(), "case {case}");
            for (g, w) in got.iter().zip(&want) {
                assert_eq!(bits(g), bits(w), "case {case}: {g:?} against {w:?}");
            }
            counts[0] += want.iter().filter(|p| p.cover == Cover::One).count();
            counts[1] += want.iter().filter(|p| p.cover == Cover::Raster).count();
            counts[2] += want.len();
        }
        // every kind of projection occurred (and patches were dropped)
        assert!(counts[0] > 1000 && counts[1] > 1000, "{counts:?}");
        assert!(counts[2] < 40 * 3001 * 9 / 10, "{counts:?}");
    }
}
