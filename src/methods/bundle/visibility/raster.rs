//! A patch's projection onto the map and its scan conversion.
//!
//! The set-up of a triangle's scan (orientation, bounding box, tie rules,
//! 1/area) is done once per patch when it is projected ([`Proj::new`]), not
//! once per tile it is scanned in. The scan evaluates the three edge
//! functions for four pixel centres of a row at once (SSE2 through glam's
//! `Vec4`): most patches cover a handful of pixels, so the scalar loop spent
//! its time on the set-up and on one compare-and-branch chain per pixel.
//! The lanes compute exactly the scalar expressions, in the same order, so
//! the fragments and their depths are bit for bit those of a scalar scan.
//! The rows of a wide box are first narrowed to a span that provably holds
//! every pixel the edge tests pass ([`RowClip`]), so that the scan skips
//! most of the box's empty groups without changing a fragment.

use glam::{BVec4A, Vec2, Vec3, Vec3A, Vec4};

use crate::geometry::Frame;

use crate::sampling::{uniform_triangle, Pcg32};

/// Twice the signed area of (a, b, p): positive when p is left of a → b.
#[inline]
pub(super) fn edge(a: Vec2, b: Vec2, p: Vec2) -> f32 {
    (b.x - a.x) * (p.y - a.y) - (b.y - a.y) * (p.x - a.x)
}

/// Top-left style tie rule: of two triangles sharing an edge (traversed in
/// opposite directions) exactly one owns pixel centres on it.
#[inline]
fn owns(a: Vec2, b: Vec2) -> bool {
    let d = b - a;
    d.y > 0.0 || (d.y == 0.0 && d.x > 0.0)
}

/// ⌊v⌋ as i32 (saturating, NaN → 0), like `v.floor() as i32`, without the
/// libm call that `floor` compiles to on baseline x86-64.
#[cfg(any(test, not(target_arch = "x86_64")))]
#[inline]
pub(super) fn floor_i32(v: f32) -> i32 {
    let i = v as i32;
    if (i as f32) > v {
        i.saturating_sub(1)
    } else {
        i
    }
}

/// ⌈v⌉ as i32 (saturating, NaN → 0), like `v.ceil() as i32`.
#[cfg(any(test, not(target_arch = "x86_64")))]
#[inline]
pub(super) fn ceil_i32(v: f32) -> i32 {
    let i = v as i32;
    if (i as f32) < v {
        i.saturating_add(1)
    } else {
        i
    }
}

/// Bound of the lanes of [`box_bounds`]: its values, and any larger,
/// lie beyond every map's last pixel, so they clip the same.
pub(super) const BOX_LIMIT: f32 = (1 << 30) as f32;

/// The box of pixel centres of a box `lo`..`hi` on the map, before
/// clipping: [⌈lo.x − ½⌉, ⌈lo.y − ½⌉, ⌊hi.x − ½⌋, ⌊hi.y − ½⌋]. For finite
/// values this clips to the map like `ceil_i32` and `floor_i32` (the
/// lanes are first clamped to ±[`BOX_LIMIT`], where the scalar forms
/// saturate, and both clip to the same pixels); [`Proj::new`] never
/// passes NaN. Four lanes at once, where the scalar forms need a
/// saturating cast and a correction each.
#[inline(always)]
pub(super) fn box_bounds(lo: Vec2, hi: Vec2) -> [i32; 4] {
    let v = Vec4::new(lo.x, lo.y, hi.x, hi.y) - Vec4::splat(0.5);
    let v = v.max(Vec4::splat(-BOX_LIMIT)).min(Vec4::splat(BOX_LIMIT));
    #[cfg(target_arch = "x86_64")]
    {
        use std::arch::x86_64::{
            _mm_add_epi32, _mm_and_si128, _mm_castps_si128, _mm_cmpgt_ps, _mm_cmplt_ps,
            _mm_cvtepi32_ps, _mm_cvtsi128_si32, _mm_cvttps_epi32, _mm_set_epi32, _mm_shuffle_epi32,
            _mm_sub_epi32,
        };
        // SAFETY: SSE2 is part of the x86_64 baseline, and these
        // intrinsics only compute on registers.
        unsafe {
            // Truncation is exact here (|v| ≤ 2^30), and so is the way back.
            let v = v.into();
            let i = _mm_cvttps_epi32(v);
            let f = _mm_cvtepi32_ps(i);
            // masks are −1 where true: ceil lanes add 1 when truncation fell
            // below v, floor lanes subtract 1 when it rose above
            let up = _mm_and_si128(
                _mm_castps_si128(_mm_cmplt_ps(f, v)),
                _mm_set_epi32(0, 0, -1, -1),
            );
            let down = _mm_and_si128(
                _mm_castps_si128(_mm_cmpgt_ps(f, v)),
                _mm_set_epi32(-1, -1, 0, 0),
            );
            let r = _mm_add_epi32(_mm_sub_epi32(i, up), down);
            [
                _mm_cvtsi128_si32(r),
                _mm_cvtsi128_si32(_mm_shuffle_epi32::<0b01>(r)),
                _mm_cvtsi128_si32(_mm_shuffle_epi32::<0b10>(r)),
                _mm_cvtsi128_si32(_mm_shuffle_epi32::<0b11>(r)),
            ]
        }
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        [ceil_i32(v.x), ceil_i32(v.y), floor_i32(v.z), floor_i32(v.w)]
    }
}

/// The map coordinates of a point: (x − c)·s and (x − c)·t scaled to
/// pixels, with the map's offset, and the depth (x − c)·d.
pub(super) struct ToMap {
    /// Centre of the scene's bounding sphere.
    pub center: Vec3,
    /// The plane's frame (n = d).
    pub frame: Frame,
    /// The flow direction.
    pub d: Vec3,
    /// Radius of the bounding sphere.
    pub radius: f32,
    /// Pixel size.
    pub delta: f32,
    /// The map's sub-pixel offset this iteration.
    pub jitter: Vec2,
}

impl ToMap {
    /// One point, as the sweep computes it.
    #[cfg(test)]
    fn point(&self, x: Vec3) -> (Vec2, f32) {
        let r = x - self.center;
        (
            Vec2::new(
                (r.dot(self.frame.s) + self.radius) / self.delta + self.jitter.x,
                (r.dot(self.frame.t) + self.radius) / self.delta + self.jitter.y,
            ),
            r.dot(self.d),
        )
    }

    /// The three corners on the map, their depths, and the depth of the
    /// centroid along d (from the origin, the sort key): [`ToMap::point`]
    /// and `centroid().dot(d)`, four lanes at once (the corners and the
    /// centroid) with the same operations in the same order, so the bits
    /// are the same.
    #[inline(always)]
    pub fn patch(&self, v: &[Vec3; 3]) -> ([Vec2; 3], [f32; 3], f32) {
        // in 4 lanes (the same per-component operations, so the same bits)
        let m = (Vec3A::from(v[0]) + Vec3A::from(v[1]) + Vec3A::from(v[2])) / 3.0;
        let c = self.center;
        // the centroid lane subtracts 0, which leaves it as it is
        let x = Vec4::new(v[0].x, v[1].x, v[2].x, m.x) - Vec4::new(c.x, c.x, c.x, 0.0);
        let y = Vec4::new(v[0].y, v[1].y, v[2].y, m.y) - Vec4::new(c.y, c.y, c.y, 0.0);
        let z = Vec4::new(v[0].z, v[1].z, v[2].z, m.z) - Vec4::new(c.z, c.z, c.z, 0.0);
        let dot = |w: Vec3| x * Vec4::splat(w.x) + y * Vec4::splat(w.y) + z * Vec4::splat(w.z);
        let (r, delta) = (Vec4::splat(self.radius), Vec4::splat(self.delta));
        let u = (dot(self.frame.s) + r) / delta + Vec4::splat(self.jitter.x);
        let w = (dot(self.frame.t) + r) / delta + Vec4::splat(self.jitter.y);
        let depth = dot(self.d);
        (
            [
                Vec2::new(u.x, w.x),
                Vec2::new(u.y, w.y),
                Vec2::new(u.z, w.z),
            ],
            [depth.x, depth.y, depth.z],
            depth.w,
        )
    }
}

/// What a patch covers on the map.
#[derive(Clone, Copy, PartialEq, Eq, Debug)]
#[repr(u8)]
pub(super) enum Cover {
    /// Scan-convert the triangle.
    Raster = 0,
    /// The one pixel (x0, y0) at depth `z[0]`: a sub-pixel patch kept by
    /// single-pixel Russian roulette, or a patch whose box holds one pixel
    /// centre, found covered when projected.
    One = 1,
}

/// One patch projected onto the map, ready to scan: corners counter-clockwise
/// on the map, their depths along d, and the pixel rows and columns it can
/// cover, clipped to the map. In C layout: eighteen 4-byte fields in this
/// order (the cover in the last one's first byte), which the eight-lane
/// projection writes as such (`lanes::project_avx2`).
#[derive(Clone, Copy, Debug)]
#[repr(C)]
pub(super) struct Proj {
    /// Corners on the map, counter-clockwise.
    pub t: [Vec2; 3],
    /// Their depths along d.
    pub z: [f32; 3],
    /// 1 / (twice the projected area), for the depth interpolation.
    pub inv: f32,
    /// Patch id.
    pub id: u32,
    /// Sort key: the order-preserving bits of the centroid's depth.
    pub key: u32,
    /// Columns and rows of pixel centres the bounding box holds, inclusive,
    /// inside the map.
    pub x0: i32,
    /// Last column.
    pub x1: i32,
    /// First row.
    pub y0: i32,
    /// Last row.
    pub y1: i32,
    /// Tie rules of the edges b→c, c→a, a→b (bits 0, 1, 2).
    pub owns: u32,
    /// Triangle or single pixel.
    pub cover: Cover,
}

/// What a scan does with each fragment. A trait with an always-inlined
/// method rather than a closure, so that the painter's per-pixel update is
/// compiled into the scan loop instead of being called per fragment with
/// the loop's state spilled around the call.
pub(super) trait Visit {
    /// Pixel (x, y) is covered at depth `z`.
    fn visit(&mut self, x: i32, y: i32, z: f32);
}

impl<F: FnMut(i32, i32, f32)> Visit for F {
    #[inline(always)]
    fn visit(&mut self, x: i32, y: i32, z: f32) {
        self(x, y, z)
    }
}

/// Bits of an f32 that sort as the value does (negative values reversed).
#[inline]
pub(super) fn order_bits(v: f32) -> u32 {
    let k = v.to_bits();
    if k >> 31 == 1 {
        !k
    } else {
        k | 0x8000_0000
    }
}

/// The pieces of [`Proj::new`] that do not change from patch to patch.
pub(super) struct Projector {
    /// Map size in pixels.
    pub w: i32,
    /// Map height in pixels.
    pub h: i32,
    /// Sub-pixel patches by pixel-centre roulette (true) or single-pixel
    /// roulette (false).
    pub centre_rr: bool,
    /// The random stream keys of the single-pixel roulette.
    pub keys: [u64; 2],
}

impl Proj {
    /// Projects patch `id` with map corners `t` and depths `z`, sort key
    /// `key`; None when it covers no pixel centre of the map (a degenerate
    /// projection, off the map, or dropped by single-pixel roulette).
    #[inline]
    pub fn new(pj: &Projector, id: u32, t: [Vec2; 3], z: [f32; 3], key: u32) -> Option<Proj> {
        let [a, mut b, mut c] = t;
        let [za, mut zb, mut zc] = z;
        let signed = edge(a, b, c);
        let parea = 0.5 * signed.abs();
        if !(parea >= 1.0 || pj.centre_rr) {
            // Single-pixel roulette: keep with probability = the area in
            // pixels, at the pixel under a uniform point of the patch
            let mut rng = Pcg32::keyed(&[pj.keys[0], pj.keys[1], id as u64, 0x5B]);
            let keep = rng.next_f32() < parea;
            if !keep {
                return None;
            }
            let bc = uniform_triangle(rng.next_2d());
            let q = a * (1.0 - bc.x - bc.y) + b * bc.x + c * bc.y;
            let zq = za * (1.0 - bc.x - bc.y) + zb * bc.x + zc * bc.y;
            let (x, y) = (q.x.floor() as i32, q.y.floor() as i32);
            if !((0..pj.w).contains(&x) && (0..pj.h).contains(&y)) {
                return None;
            }
            return Some(Proj {
                t,
                z: [zq, zq, zq],
                inv: 0.0,
                id,
                key,
                x0: x,
                x1: x,
                y0: y,
                y1: y,
                owns: 0,
                cover: Cover::One,
            });
        }
        // Orient counter-clockwise; clip the box of pixel centres to the map
        let mut area = signed;
        if area == 0.0 || !area.is_finite() {
            return None;
        }
        if area < 0.0 {
            std::mem::swap(&mut b, &mut c);
            std::mem::swap(&mut zb, &mut zc);
            area = -area;
        }
        let lo = a.min(b).min(c);
        let hi = a.max(b).max(c);
        let [x0, y0, x1, y1] = box_bounds(lo, hi);
        let (x0, x1) = (x0.max(0), x1.min(pj.w - 1));
        let (y0, y1) = (y0.max(0), y1.min(pj.h - 1));
        if x0 > x1 || y0 > y1 {
            return None;
        }
        let owns = owns(b, c) as u32 | (owns(c, a) as u32) << 1 | (owns(a, b) as u32) << 2;
        let pr = Proj {
            t: [a, b, c],
            z: [za, zb, zc],
            inv: 1.0 / area,
            id,
            key,
            x0,
            x1,
            y0,
            y1,
            owns,
            cover: Cover::Raster,
        };
        if x0 == x1 && y0 == y1 {
            // One pixel centre in the box (most sub-pixel patches of a fine
            // mesh): test it here, once, with the scan's own expression, so
            // that a patch missing it costs no tile entry and one covering
            // it is a single fragment at the same depth bits
            let z = pr.centre(x0, y0)?;
            return Some(Proj {
                z: [z; 3],
                cover: Cover::One,
                ..pr
            });
        }
        Some(pr)
    }

    /// The depth at pixel centre (x, y) of column `x`, when the patch
    /// covers it: the scan's test of one pixel, without its 4-lane set-up.
    #[inline(always)]
    fn centre(&self, x: i32, y: i32) -> Option<f32> {
        let [a, b, c] = self.t;
        let [za, zb, zc] = self.z;
        let own = |bit: u32| self.owns >> bit & 1 == 1;
        let (px, py) = (x as f32 + 0.5, y as f32 + 0.5);
        let wa = (c.x - b.x) * (py - b.y) - (c.y - b.y) * (px - b.x);
        let wb = (a.x - c.x) * (py - c.y) - (a.y - c.y) * (px - c.x);
        let wc = (b.x - a.x) * (py - a.y) - (b.y - a.y) * (px - a.x);
        let inside = (wa > 0.0 || (wa == 0.0 && own(0)))
            && (wb > 0.0 || (wb == 0.0 && own(1)))
            && (wc > 0.0 || (wc == 0.0 && own(2)));
        if inside {
            Some((wa * za + wb * zb + wc * zc) * self.inv)
        } else {
            None
        }
    }

    /// The edges' column bounds, when clipping `rows` rows of the box saves
    /// more than it costs. A row of a triangle covers about half of its
    /// box's columns, so clipping it saves about `cols / 8` groups of the
    /// scan, less about one group's work to evaluate its span; the bounds'
    /// set-up costs about [`CLIP_SETUP_GROUPS`] groups. Narrow or short
    /// boxes are scanned whole. Either way the fragments are the same.
    #[inline(always)]
    fn clip(&self, rows: i32) -> Option<RowClip> {
        let cols = self.x1 - self.x0 + 1;
        (cols > CLIP_WIDTH && rows * (cols - CLIP_WIDTH) > 8 * CLIP_SETUP_GROUPS)
            .then(|| RowClip::new(self.t, self.x0, self.x1, self.y1))
    }

    /// Row `y`'s products (c.x − b.x)(py − b.y) and its turns, the first
    /// term of each edge function, and the columns to scan: the box's, or
    /// those `clip` leaves.
    #[inline(always)]
    fn row(&self, y: i32, clip: &Option<RowClip>) -> ([f32; 3], i32, i32) {
        let [a, b, c] = self.t;
        let py = y as f32 + 0.5;
        let r = [
            (c.x - b.x) * (py - b.y),
            (a.x - c.x) * (py - c.y),
            (b.x - a.x) * (py - a.y),
        ];
        let (xs, xe) = match clip {
            Some(clip) => clip.span(py, self.x0, self.x1),
            None => (self.x0, self.x1),
        };
        (r, xs, xe)
    }

    /// Calls `v.visit(x, y, depth)` for every pixel centre the patch covers
    /// in rows `y0..y1`, row by row, left to right.
    #[inline(always)]
    pub fn scan<V: Visit>(&self, y0: i32, y1: i32, v: &mut V) {
        let ys = self.y0.max(y0);
        let ye = self.y1.min(y1 - 1);
        if ys > ye {
            return;
        }
        if self.cover == Cover::One {
            v.visit(self.x0, self.y0, self.z[0]);
            return;
        }
        if self.x0 == self.x1 {
            // One column (half the patches of a fine mesh): lane 0 of the
            // loop below, without its 4-lane set-up. The same operations in
            // the same order give the same bits.
            for y in ys..=ye {
                if let Some(z) = self.centre(self.x0, y) {
                    v.visit(self.x0, y, z);
                }
            }
            return;
        }
        let [a, b, c] = self.t;
        let [za, zb, zc] = self.z;
        let lane = |bit: u32| BVec4A::splat(self.owns >> bit & 1 == 1);
        let (oa, ob, oc) = (lane(0), lane(1), lane(2));
        // edge(u, v, p) = (v.x − u.x)(p.y − u.y) − (v.y − u.y)(p.x − u.x),
        // the row's first product once per row, as in `edge`
        let (dya, dyb, dyc) = (
            Vec4::splat(c.y - b.y),
            Vec4::splat(a.y - c.y),
            Vec4::splat(b.y - a.y),
        );
        let (bx, cx, ax) = (Vec4::splat(b.x), Vec4::splat(c.x), Vec4::splat(a.x));
        let (vza, vzb, vzc, vinv) = (
            Vec4::splat(za),
            Vec4::splat(zb),
            Vec4::splat(zc),
            Vec4::splat(self.inv),
        );
        const HALF: Vec4 = Vec4::new(0.5, 1.5, 2.5, 3.5);
        let clip = self.clip(ye - ys + 1);
        for y in ys..=ye {
            let (r, xs, xe) = self.row(y, &clip);
            let (ra, rb, rc) = (Vec4::splat(r[0]), Vec4::splat(r[1]), Vec4::splat(r[2]));
            let mut x = xs;
            while x <= xe {
                // x + k + 0.5 is exact in f32 on any map that fits in memory
                let px = Vec4::splat(x as f32) + HALF;
                let wa = ra - dya * (px - bx);
                let wb = rb - dyb * (px - cx);
                let wc = rc - dyc * (px - ax);
                let zero = Vec4::ZERO;
                let inside = (wa.cmpgt(zero) | (wa.cmpeq(zero) & oa))
                    & (wb.cmpgt(zero) | (wb.cmpeq(zero) & ob))
                    & (wc.cmpgt(zero) | (wc.cmpeq(zero) & oc));
                let cols = (xe - x + 1).min(4);
                let mut mask = inside.bitmask() & ((1u32 << cols) - 1);
                if mask != 0 {
                    let depth = (wa * vza + wb * vzb + wc * vzc) * vinv;
                    while mask != 0 {
                        let k = mask.trailing_zeros();
                        v.visit(x + k as i32, y, depth[k as usize]);
                        mask &= mask - 1;
                    }
                }
                x += 4;
            }
        }
    }
}

/// Bounds on the pixel columns of each row of a triangle, so that the
/// scan of a wide row starts and ends near its edges instead of at its box.
///
/// The scan's test for edge (u → v) at pixel centre px of row py is, in
/// f32, W = fl(R − fl(D · fl(px − u.x))) ≥ 0 (or > 0), with D = v.y − u.y,
/// A = v.x − u.x and R = fl(A · fl(py − u.y)), all as the scan computes
/// them. Rounding is monotonic and fl(R − M) ≥ 0 exactly when R ≥ M, so a
/// pixel passes only if fl(D · P) ≤ R with P = fl(px − u.x). With u = 2⁻²⁴
/// the unit roundoff (|fl(z) − z| ≤ u|z|, plus 2⁻¹⁵⁰ below the normal
/// range), s = A/D and T a bound on |px − u.x| over the box:
///
/// - D > 0: D·P ≤ R + u D|P|, so P ≤ R/D + u|P|; px − u.x ≤ P + u|px − u.x|;
///   and R/D ≤ s (py − u.y) + 2.0001 u |s| (|py| + |u.y|). Hence
///   px ≤ u.x + s (py − u.y) + E, E = 3uT + 2.0001 u |s| (|py| + |u.y|).
/// - D < 0: the same with the inequalities turned, px ≥ u.x + s (py − u.y) − E.
///
/// The bound is evaluated per row in f32 as fl(fl(s' · py) + b'), with
/// s' = fl(A/D) and b' = u.x − s' u.y ± m rounded once to f32. Its own
/// roundings are below 5.01 u |s| (|py| + |u.y|) + 2.01 u (|u.x| + m), so
/// the widening m = 3uT + 8u (|s| (Y + |u.y|) + |u.x|) + 10⁻³ pixel (Y the
/// largest py of the box) covers E and them, with room to spare for the
/// sub-normal terms (at most 2⁻¹³⁰ pixel once |D| ≥ 2⁻²⁰). The columns are
/// then taken by truncation toward zero of the bound minus ½, which is at
/// least the floor (last column) or at most the ceiling (first column), and
/// f32 rounding of bound − ½ cannot cross an integer.
///
/// So every pixel of the box that passes the three tests lies in the
/// clipped span: the per-pixel test is unchanged, and the fragments, their
/// order and their depths are those of the scan over the whole box. An
/// edge with |D| < 2⁻²⁰ or |s| > 2²⁴ (nearly horizontal, where s says
/// nothing useful) does not clip.
#[derive(Clone, Copy, Debug)]
pub(super) struct RowClip {
    /// Per edge (lanes 0–2), the last column's bound b' + s' py, for the
    /// edges with D > 0; +∞ with slope 0 for the others and lane 3.
    hi_base: Vec4,
    hi_slope: Vec4,
    /// The first column's bound, for the edges with D < 0; −∞ otherwise.
    lo_base: Vec4,
    lo_slope: Vec4,
}

/// Boxes no wider than this many columns are never clipped ([`Proj::clip`]):
/// a clipped row saves about one group of the scan per this many columns
/// beyond it.
const CLIP_WIDTH: i32 = 8;
/// The set-up of the row bounds ([`RowClip::new`], in f64 for its error
/// bound), in groups of the scan that it costs as much as.
const CLIP_SETUP_GROUPS: i32 = 14;

/// Unit roundoff of f32.
const U32: f64 = 1.0 / (1u64 << 24) as f64;
/// Edges with |D| below this, or a slope |A/D| above [`MAX_SLOPE`], do not
/// clip: nearly horizontal, their bound says little, and these limits keep
/// every term of the bound finite and the sub-normal terms negligible.
const MIN_DY: f32 = 1.0 / (1u32 << 20) as f32;
/// See [`MIN_DY`].
const MAX_SLOPE: f32 = (1u32 << 24) as f32;

impl RowClip {
    /// The bounds of the triangle `t` (counter-clockwise, as scanned) over
    /// columns `x0..=x1` and rows up to `y1`.
    #[inline]
    fn new(t: [Vec2; 3], x0: i32, x1: i32, y1: i32) -> RowClip {
        let [a, b, c] = t;
        let mut clip = RowClip {
            hi_base: Vec4::INFINITY,
            hi_slope: Vec4::ZERO,
            lo_base: Vec4::NEG_INFINITY,
            lo_slope: Vec4::ZERO,
        };
        let ymax = y1 as f64 + 0.5;
        // the edges as the scan takes them: (u, v) = (b, c), (c, a), (a, b)
        for (k, (u, v)) in [(b, c), (c, a), (a, b)].into_iter().enumerate() {
            let (dx, dy) = (v.x - u.x, v.y - u.y);
            let s = dx / dy;
            // nearly horizontal edges do not clip (nor could a non-finite one)
            if dy.abs() < MIN_DY || s.is_nan() || s.abs() > MAX_SLOPE {
                continue;
            }
            let (sd, ux, uy) = (s as f64, u.x as f64, u.y as f64);
            let t = (x0 as f64 + 0.5 - ux)
                .abs()
                .max((x1 as f64 + 0.5 - ux).abs());
            let m = 3.0 * U32 * t + 8.0 * U32 * (sd.abs() * (ymax + uy.abs()) + ux.abs()) + 1e-3;
            let (hi, lo) = ((ux - sd * uy + m) as f32, (ux - sd * uy - m) as f32);
            if !(hi.is_finite() && lo.is_finite()) {
                continue;
            }
            if dy > 0.0 {
                clip.hi_base[k] = hi;
                clip.hi_slope[k] = s;
            } else {
                clip.lo_base[k] = lo;
                clip.lo_slope[k] = s;
            }
        }
        clip
    }

    /// The columns of the row at `py`, within `x0..=x1`, that can hold a
    /// pixel passing all three edge tests (possibly none: start past end).
    #[inline(always)]
    fn span(&self, py: f32, x0: i32, x1: i32) -> (i32, i32) {
        let py = Vec4::splat(py);
        let hi = (self.hi_slope * py + self.hi_base).min_element();
        let lo = (self.lo_slope * py + self.lo_base).max_element();
        (x0.max((lo - 0.5) as i32), x1.min((hi - 0.5) as i32))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The scan of the code before this one: one pixel at a time, scalar,
    /// with its set-up per call. The 4-wide scan must give the same
    /// fragments with the same depth bits.
    fn scalar_scan(t: &[Vec2; 3], z: &[f32; 3], w: i32, h: i32) -> Vec<(i32, i32, u32)> {
        let (a, mut b, mut c) = (t[0], t[1], t[2]);
        let (za, mut zb, mut zc) = (z[0], z[1], z[2]);
        let mut area = edge(a, b, c);
        let mut out = Vec::new();
        if area == 0.0 || !area.is_finite() {
            return out;
        }
        if area < 0.0 {
            std::mem::swap(&mut b, &mut c);
            std::mem::swap(&mut zb, &mut zc);
            area = -area;
        }
        let lo = a.min(b).min(c);
        let hi = a.max(b).max(c);
        let xs = ceil_i32(lo.x - 0.5).max(0);
        let xe = floor_i32(hi.x - 0.5).min(w - 1);
        let ys = ceil_i32(lo.y - 0.5).max(0);
        let ye = floor_i32(hi.y - 0.5).min(h - 1);
        let (oa, ob, oc) = (owns(b, c), owns(c, a), owns(a, b));
        let inv = 1.0 / area;
        for y in ys..=ye {
            for x in xs..=xe {
                let p = Vec2::new(x as f32 + 0.5, y as f32 + 0.5);
                let (wa, wb, wc) = (edge(b, c, p), edge(c, a, p), edge(a, b, p));
                if (wa > 0.0 || (wa == 0.0 && oa))
                    && (wb > 0.0 || (wb == 0.0 && ob))
                    && (wc > 0.0 || (wc == 0.0 && oc))
                {
                    out.push((x, y, ((wa * za + wb * zb + wc * zc) * inv).to_bits()));
                }
            }
        }
        out
    }

    /// Random triangles from sub-pixel to 40 pixels wide, some on pixel
    /// centres (ties), some across the map's edges: the same fragments,
    /// order and depth bits as the scalar scan, whichever rows are asked.
    #[test]
    fn scan_matches_scalar() {
        let (w, h) = (37, 29);
        let pj = Projector {
            w,
            h,
            centre_rr: true,
            keys: [0, 0],
        };
        let mut rng = Pcg32::keyed(&[79]);
        let (mut covered, mut single) = (0, 0);
        for k in 0..20_000u32 {
            let size = [0.7, 2.0, 5.0, 40.0][k as usize % 4];
            let o = Vec2::new(rng.next_f32() * 45.0 - 4.0, rng.next_f32() * 37.0 - 4.0);
            let mut corner = || {
                let v = o + Vec2::new(rng.next_f32(), rng.next_f32()) * size;
                // every fifth triangle snapped to half pixels: edges through centres
                if k % 5 == 0 {
                    (v * 2.0).round() * 0.5
                } else {
                    v
                }
            };
            let t = [corner(), corner(), corner()];
            let z = [rng.next_f32(), rng.next_f32(), rng.next_f32()];
            let want = scalar_scan(&t, &z, w, h);
            let mut got = Vec::new();
            if let Some(pr) = Proj::new(&pj, k, t, z, 0) {
                single += (pr.cover == Cover::One) as usize;
                // in two bands of rows, as two tiles would scan it
                for (y0, y1) in [(0, 13), (13, h)] {
                    pr.scan(y0, y1, &mut |x, y, d: f32| got.push((x, y, d.to_bits())));
                }
            }
            covered += want.len();
            assert_eq!(got, want, "triangle {t:?}");
        }
        assert!(covered > 10_000, "the triangles covered {covered} pixels");
        // one-pixel boxes, resolved when projected, were among them
        assert!(single > 500, "{single} one-pixel projections");
    }

    /// Rows clipped to the edges give exactly the fragments of the scan
    /// over the whole box (the scalar scan above), on random triangles
    /// where the clip applies: thin slivers, nearly horizontal and nearly
    /// vertical edges, sub-pixel and small ones, with corners around 1000
    /// pixels as on a 1024² map (where f32 rounding is coarsest), some on
    /// the half-pixel grid or one ulp off it (edges through or next to
    /// pixel centres). The clip must also cut: the spans hold far fewer
    /// columns than the boxes.
    #[test]
    fn clipped_rows_match_full_box() {
        let (w, h) = (1025, 1025);
        let pj = Projector {
            w,
            h,
            centre_rr: true,
            keys: [0, 0],
        };
        let mut rng = Pcg32::keyed(&[81]);
        let (mut covered, mut span_cols, mut box_cols) = (0usize, 0i64, 0i64);
        for k in 0..40_000u32 {
            let o = Vec2::new(rng.next_f32() * 60.0 + 960.0, rng.next_f32() * 1040.0 - 8.0);
            let mut r = || rng.next_f32();
            let long = 4.0 + 60.0 * r();
            let (p, q) = (o, o + Vec2::new(long * (r() - 0.5), long * (r() - 0.5)));
            let mut t = match k % 6 {
                // a sliver: the third corner a fraction of a pixel off p → q
                0 => [p, q, (p + q) * 0.5 + Vec2::new(r() - 0.5, r() - 0.5) * 0.3],
                // a nearly horizontal edge, then a nearly vertical one
                1 => [
                    p,
                    p + Vec2::new(long, (r() - 0.5) * 1e-3),
                    p + Vec2::new(r(), 3.0 * r()),
                ],
                2 => [
                    p,
                    p + Vec2::new((r() - 0.5) * 1e-3, long),
                    p + Vec2::new(8.0 * r(), r()),
                ],
                // sub-pixel, and small
                3 => [p, p + Vec2::new(r(), r()), p + Vec2::new(r(), r())],
                4 => [
                    p,
                    p + Vec2::new(9.0 * r(), 9.0 * r()),
                    p + Vec2::new(9.0 * r(), 9.0 * r()),
                ],
                _ => [p, q, p + Vec2::new(long * (r() - 0.5), long * (r() - 0.5))],
            };
            match k % 5 {
                // on the half-pixel grid: edges through pixel centres
                0 => t = t.map(|v| (v * 2.0).round() * 0.5),
                // one ulp off it
                1 => {
                    t = t.map(|v| {
                        let g = (v * 2.0).round() * 0.5;
                        let nudge = |x: f32, up: bool| match (x == 0.0, up) {
                            (true, _) => x,
                            (_, true) => f32::from_bits(x.to_bits() + 1),
                            _ => f32::from_bits(x.to_bits() - 1),
                        };
                        Vec2::new(nudge(g.x, r() < 0.5), nudge(g.y, r() < 0.5))
                    })
                }
                _ => {}
            }
            let z = [r(), r(), r()];
            let want = scalar_scan(&t, &z, w, h);
            let mut got = Vec::new();
            if let Some(pr) = Proj::new(&pj, k, t, z, 0) {
                for (y0, y1) in [(0, 500), (500, h)] {
                    pr.scan(y0, y1, &mut |x, y, d: f32| got.push((x, y, d.to_bits())));
                }
                if let Some(clip) = pr.clip(pr.y1 - pr.y0 + 1) {
                    for y in pr.y0..=pr.y1 {
                        let (_, xs, xe) = pr.row(y, &Some(clip));
                        span_cols += (xe - xs + 1).max(0) as i64;
                        box_cols += (pr.x1 - pr.x0 + 1) as i64;
                    }
                }
            }
            covered += want.len();
            assert_eq!(got, want, "triangle {t:?}");
        }
        assert!(covered > 100_000, "the triangles covered {covered} pixels");
        assert!(
            2 * span_cols < box_cols,
            "the clip scanned {span_cols} columns of the boxes' {box_cols}"
        );
    }

    /// The 4-lane projection gives the bits of the scalar one, and the
    /// centroid's depth those of `centroid().dot(d)`.
    #[test]
    fn patch_projection_matches_scalar() {
        let mut rng = Pcg32::keyed(&[80]);
        let mut r3 = || Vec3::new(rng.next_f32(), rng.next_f32(), rng.next_f32()) * 20.0 - 10.0;
        for _ in 0..2000 {
            let d = r3().normalize();
            let m = ToMap {
                center: r3(),
                frame: Frame::from_normal(d),
                d,
                radius: 17.3,
                delta: 0.0337,
                jitter: Vec2::new(0.31, 0.77),
            };
            let v = [r3(), r3(), r3()];
            let (t, z, key) = m.patch(&v);
            for k in 0..3 {
                let (tk, zk) = m.point(v[k]);
                assert_eq!(
                    (t[k].x.to_bits(), t[k].y.to_bits(), z[k].to_bits()),
                    (tk.x.to_bits(), tk.y.to_bits(), zk.to_bits())
                );
            }
            assert_eq!(key.to_bits(), ((v[0] + v[1] + v[2]) / 3.0).dot(d).to_bits());
        }
    }

    /// The integer floor and ceiling agree with `floor`/`ceil` then `as
    /// i32`, including the saturating and NaN cases.
    #[test]
    fn floor_ceil_match_std() {
        let mut rng = Pcg32::keyed(&[77]);
        let mut vals = vec![
            0.0,
            -0.0,
            0.5,
            -0.5,
            1.0,
            -1.0,
            2.5e9,
            -2.5e9,
            f32::INFINITY,
            f32::NEG_INFINITY,
            f32::NAN,
            16777217.0,
            -0.49999997,
        ];
        vals.extend((0..100_000).map(|_| (rng.next_f32() - 0.5) * 5000.0));
        for v in vals {
            assert_eq!(floor_i32(v), v.floor() as i32, "floor {v}");
            assert_eq!(ceil_i32(v), v.ceil() as i32, "ceil {v}");
        }
    }

    /// The 4-lane box bounds clip to the same pixels as the scalar
    /// ceil/floor, for finite values from sub-pixel to saturating.
    #[test]
    fn box_bounds_match_scalar() {
        let mut rng = Pcg32::keyed(&[78]);
        let mut vals = vec![
            0.0,
            -0.0,
            0.5,
            -0.5,
            1.0,
            1.5,
            -1.5,
            2.5e9,
            -2.5e9,
            1.5e30,
            -1.5e30,
            16777217.0,
            -0.49999997,
            0.50000006,
            1023.5,
            1024.5,
            1e-30,
        ];
        vals.extend((0..100_000).map(|_| (rng.next_f32() - 0.5) * 3000.0));
        vals.extend((0..1000).map(|_| (rng.next_f32() - 0.5) * 1e12));
        let (w, h) = (1025, 1025);
        for (k, &x) in vals.iter().enumerate() {
            let y = vals[(k * 7 + 3) % vals.len()];
            // boxes from sub-pixel to many pixels wide
            let e = Vec2::new(rng.next_f32(), rng.next_f32()) * [1.0, 4.0, 40.0][k % 3];
            let (lo, hi) = (Vec2::new(x, y), Vec2::new(x, y) + e);
            let [x0, y0, x1, y1] = box_bounds(lo, hi);
            let want = [
                ceil_i32(lo.x - 0.5),
                ceil_i32(lo.y - 0.5),
                floor_i32(hi.x - 0.5),
                floor_i32(hi.y - 0.5),
            ];
            // below the clamp, the very same bounds
            if lo.abs().max(hi.abs()).max_element() < 1e9 {
                assert_eq!([x0, y0, x1, y1], want, "lo {lo} hi {hi}");
            }
            // the clipped box, or None when it holds no pixel (the value
            // of an empty bound does not matter)
            let clip = |[x0, y0, x1, y1]: [i32; 4]| {
                let b = (x0.max(0), y0.max(0), x1.min(w - 1), y1.min(h - 1));
                (b.0 <= b.2 && b.1 <= b.3).then_some(b)
            };
            assert_eq!(clip([x0, y0, x1, y1]), clip(want), "lo {lo} hi {hi}");
        }
    }
}
