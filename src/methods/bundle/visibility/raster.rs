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

use glam::{BVec4A, Vec2, Vec3, Vec4};

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
#[inline]
pub(super) fn ceil_i32(v: f32) -> i32 {
    let i = v as i32;
    if (i as f32) < v {
        i.saturating_add(1)
    } else {
        i
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
        let m = (v[0] + v[1] + v[2]) / 3.0;
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
pub(super) enum Cover {
    /// Scan-convert the triangle.
    Raster,
    /// A sub-pixel patch kept by single-pixel Russian roulette: the one
    /// pixel (x0, y0) at depth `z[0]`.
    One,
}

/// One patch projected onto the map, ready to scan: corners counter-clockwise
/// on the map, their depths along d, and the pixel rows and columns it can
/// cover, clipped to the map.
#[derive(Clone, Copy, Debug)]
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
        let x0 = ceil_i32(lo.x - 0.5).max(0);
        let x1 = floor_i32(hi.x - 0.5).min(pj.w - 1);
        let y0 = ceil_i32(lo.y - 0.5).max(0);
        let y1 = floor_i32(hi.y - 0.5).min(pj.h - 1);
        if x0 > x1 || y0 > y1 {
            return None;
        }
        let owns = owns(b, c) as u32 | (owns(c, a) as u32) << 1 | (owns(a, b) as u32) << 2;
        Some(Proj {
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
        })
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
        for y in ys..=ye {
            let py = y as f32 + 0.5;
            let ra = Vec4::splat((c.x - b.x) * (py - b.y));
            let rb = Vec4::splat((a.x - c.x) * (py - c.y));
            let rc = Vec4::splat((b.x - a.x) * (py - a.y));
            let mut x = self.x0;
            while x <= self.x1 {
                // x + k + 0.5 is exact in f32 on any map that fits in memory
                let px = Vec4::splat(x as f32) + HALF;
                let wa = ra - dya * (px - bx);
                let wb = rb - dyb * (px - cx);
                let wc = rc - dyc * (px - ax);
                let zero = Vec4::ZERO;
                let inside = (wa.cmpgt(zero) | (wa.cmpeq(zero) & oa))
                    & (wb.cmpgt(zero) | (wb.cmpeq(zero) & ob))
                    & (wc.cmpgt(zero) | (wc.cmpeq(zero) & oc));
                let cols = (self.x1 - x + 1).min(4);
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
        let mut covered = 0;
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
                // in two bands of rows, as two tiles would scan it
                for (y0, y1) in [(0, 13), (13, h)] {
                    pr.scan(y0, y1, &mut |x, y, d: f32| got.push((x, y, d.to_bits())));
                }
            }
            covered += want.len();
            assert_eq!(got, want, "triangle {t:?}");
        }
        assert!(covered > 10_000, "the triangles covered {covered} pixels");
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
}
