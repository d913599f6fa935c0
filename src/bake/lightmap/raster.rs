//! The texels of a lightmap atlas: which triangle each covers and the point
//! of the surface it stands for, and the dilation that pads charts.
//!
//! Rasterisation is conservative: a triangle touches every texel whose
//! square it overlaps, not only those whose centre it contains, so that the
//! texels bilinear filtering reads at a chart's border hold the chart's own
//! lighting. Each texel belongs to exactly one triangle: the one containing
//! its centre, else the one nearest to it (ties to the lower index). Its
//! point is the surface point under the centre, or for an edge texel the
//! triangle's point nearest the centre, so that kernels are evaluated on the
//! surface and never beside it.

use glam::{Vec2, Vec3};
use rayon::prelude::*;

use super::{LightmapUv, Texel};
use crate::color::Rgb;
use crate::scene::Scene;

/// Rows per band: triangles are binned into bands of rows, and bands are
/// rasterised in parallel, each writing only its own rows.
const BAND: u32 = 8;

/// The depth, in texels, by which a triangle must enter a texel's square to
/// touch it (a chart edge that lies on a texel border does not touch the
/// texel beyond it).
const TOUCH: f32 = 1e-4;

/// Every texel of the atlas that a triangle touches, each once, in
/// row-major order (row 0 at the top), with its owning triangle, its point
/// on that triangle and the triangle's geometric normal. Triangles with no
/// area on the surface or in uv are skipped. Deterministic, whatever the
/// thread count.
pub fn texels(scene: &Scene, uv: &LightmapUv) -> Vec<Texel> {
    let (w, h) = (uv.width, uv.height);
    if w == 0 || h == 0 {
        return Vec::new();
    }
    let corners = uv_corners(scene, uv);
    // Bin triangles into bands of rows by their bounding boxes.
    let bands = h.div_ceil(BAND) as usize;
    let mut binned: Vec<Vec<u32>> = vec![Vec::new(); bands];
    for (t, c) in corners.iter().enumerate() {
        let Some(c) = c else { continue };
        let (_, (y0, y1)) = texel_box(c, w, h);
        for b in y0 / BAND..y1.div_ceil(BAND) {
            binned[b as usize].push(t as u32);
        }
    }
    // Per texel the best (distance², triangle), band by band.
    let mut best = vec![(f32::INFINITY, u32::MAX); w as usize * h as usize];
    best.par_chunks_mut((BAND * w) as usize)
        .zip(&binned)
        .enumerate()
        .for_each(|(b, (rows, tris))| {
            let row0 = b as u32 * BAND;
            for &t in tris {
                let Some(c) = &corners[t as usize] else {
                    continue;
                };
                let (_, (y0, y1)) = texel_box(c, w, h);
                for y in y0.max(row0)..y1.min(row0 + BAND) {
                    let Some((x0, x1)) = row_span(c, y, w) else {
                        continue;
                    };
                    for x in x0..x1 {
                        let centre = Vec2::new(x as f32 + 0.5, y as f32 + 0.5);
                        let d = centre.distance_squared(closest_point(c, centre));
                        let slot = &mut rows[((y - row0) * w + x) as usize];
                        if (d, t) < *slot {
                            *slot = (d, t);
                        }
                    }
                }
            }
        });
    best.par_chunks(w as usize)
        .enumerate()
        .flat_map_iter(|(y, row)| {
            let corners = &corners;
            row.iter().enumerate().filter_map(move |(x, &(_, t))| {
                let c = corners.get(t as usize)?.as_ref()?;
                Some(texel(scene, c, t, x as u32, y as u32))
            })
        })
        .collect()
}

/// Per atlas texel, whether a triangle touches it (from [`texels`]).
pub fn covered(uv: &LightmapUv, texels: &[Texel]) -> Vec<bool> {
    let mut out = vec![false; uv.width as usize * uv.height as usize];
    for t in texels {
        out[(t.y * uv.width + t.x) as usize] = true;
    }
    out
}

/// Per atlas texel, the chart of the triangle that owns it
/// ([`LightmapUv::tri_chart`]), or `u32::MAX` where no triangle touches it
/// (or the uv set carries no charts): for filters that must not mix charts.
pub fn chart_map(uv: &LightmapUv, texels: &[Texel]) -> Vec<u32> {
    let mut out = vec![u32::MAX; uv.width as usize * uv.height as usize];
    for t in texels {
        if let Some(&c) = uv.tri_chart.get(t.tri as usize) {
            out[(t.y * uv.width + t.x) as usize] = c;
        }
    }
    out
}

/// Fills uncovered texels next to charts, `passes` rings deep: each pass
/// gives every still-empty texel with a filled neighbour (of its eight) the
/// average of those neighbours. So bilinear filtering and the first mip
/// level never read the black of empty texels at a chart's border. Texels
/// further than `passes` from every chart are left as they are.
/// Deterministic (each pass reads only the previous one).
///
/// Panics if `values` or `covered` is not `width × height` long.
pub fn dilate(values: &mut [Rgb], covered: &[bool], width: u32, height: u32, passes: u32) {
    let (w, h) = (width as usize, height as usize);
    assert!(values.len() == w * h && covered.len() == w * h);
    let mut filled = covered.to_vec();
    for _ in 0..passes {
        let (src, known) = (values.to_vec(), filled.clone());
        let changed: Vec<(usize, Rgb)> = (0..h)
            .into_par_iter()
            .flat_map_iter(|y| {
                let (src, known) = (&src, &known);
                (0..w).filter_map(move |x| {
                    if known[y * w + x] {
                        return None;
                    }
                    let mut sum = Rgb::ZERO;
                    let mut n = 0u32;
                    for ny in y.saturating_sub(1)..(y + 2).min(h) {
                        for nx in x.saturating_sub(1)..(x + 2).min(w) {
                            if known[ny * w + nx] {
                                sum += src[ny * w + nx];
                                n += 1;
                            }
                        }
                    }
                    (n > 0).then(|| (y * w + x, sum / n as f32))
                })
            })
            .collect();
        if changed.is_empty() {
            break;
        }
        for (i, v) in changed {
            values[i] = v;
            filled[i] = true;
        }
    }
}

/// A triangle's corners in texel units (uv × atlas size), or `None` for a
/// triangle without area on the surface or in uv.
pub(super) type Corners = Option<[Vec2; 3]>;

/// Per scene triangle, its corners on the atlas in texel units.
pub(super) fn uv_corners(scene: &Scene, uv: &LightmapUv) -> Vec<Corners> {
    let size = Vec2::new(uv.width as f32, uv.height as f32);
    let mut out = vec![None; scene.triangles.len()];
    for (shape, s) in scene.shapes.iter().zip(&uv.shapes) {
        for (k, t) in s.triangles.iter().enumerate() {
            let tri = shape.first_tri as usize + k;
            let Some(slot) = out.get_mut(tri) else {
                continue;
            };
            let c = t.map(|v| s.uv.get(v as usize).copied().unwrap_or(Vec2::NAN) * size);
            let [a, b, cc] = scene.triangles[tri].map(|v| scene.positions[v as usize]);
            let world = (b - a).cross(cc - a).length();
            let texel_area = (c[1] - c[0]).perp_dot(c[2] - c[0]).abs();
            if c.iter().all(|p| p.is_finite()) && world > 0.0 && texel_area > 1e-9 {
                *slot = Some(c);
            }
        }
    }
    out
}

/// The texel columns and rows (half-open) a triangle's bounding box
/// overlaps, inside the atlas.
fn texel_box(c: &[Vec2; 3], w: u32, h: u32) -> ((u32, u32), (u32, u32)) {
    let lo = c[0].min(c[1]).min(c[2]);
    let hi = c[0].max(c[1]).max(c[2]);
    let span = |lo: f32, hi: f32, n: u32| {
        let a = (lo + TOUCH).floor().clamp(0.0, n as f32) as u32;
        let b = (hi - TOUCH).ceil().clamp(0.0, n as f32) as u32;
        (a, b.max(a))
    };
    (span(lo.x, hi.x, w), span(lo.y, hi.y, h))
}

/// The texel columns (half-open) of row `y` whose squares the triangle
/// overlaps deeper than [`TOUCH`]: the triangle clipped to the row's slab
/// is convex and spans the slab's height at most, so it meets a texel's
/// square exactly when its extent in x meets the square's.
fn row_span(c: &[Vec2; 3], y: u32, w: u32) -> Option<(u32, u32)> {
    let (lo, hi) = (y as f32 + TOUCH, y as f32 + 1.0 - TOUCH);
    let (mut xmin, mut xmax) = (f32::INFINITY, f32::NEG_INFINITY);
    let mut take = |x: f32| {
        xmin = xmin.min(x);
        xmax = xmax.max(x);
    };
    for i in 0..3 {
        let (a, b) = (c[i], c[(i + 1) % 3]);
        if (lo..=hi).contains(&a.y) {
            take(a.x);
        }
        // Where the edge crosses the slab's two lines.
        for line in [lo, hi] {
            if (a.y.min(b.y)..=a.y.max(b.y)).contains(&line) && a.y != b.y {
                take(a.x + (b.x - a.x) * ((line - a.y) / (b.y - a.y)));
            }
        }
    }
    if xmin > xmax {
        return None;
    }
    let x0 = (xmin + TOUCH).floor().clamp(0.0, w as f32) as u32;
    let x1 = (xmax - TOUCH).ceil().clamp(0.0, w as f32) as u32;
    (x1 > x0).then_some((x0, x1))
}

/// The point of triangle `c` nearest to `p` (p itself when inside).
fn closest_point(c: &[Vec2; 3], p: Vec2) -> Vec2 {
    let sign = (c[1] - c[0]).perp_dot(c[2] - c[0]).signum();
    let inside = (0..3).all(|i| sign * (c[(i + 1) % 3] - c[i]).perp_dot(p - c[i]) >= 0.0);
    if inside {
        return p;
    }
    (0..3)
        .map(|i| {
            let (a, b) = (c[i], c[(i + 1) % 3]);
            let e = b - a;
            let t = ((p - a).dot(e) / e.length_squared().max(f32::MIN_POSITIVE)).clamp(0.0, 1.0);
            a + e * t
        })
        .min_by(|a, b| a.distance_squared(p).total_cmp(&b.distance_squared(p)))
        .unwrap_or(p)
}

/// Barycentric coordinates of `p` in triangle `c`, clamped into it.
fn barycentric(c: &[Vec2; 3], p: Vec2) -> Vec3 {
    let d = (c[1] - c[0]).perp_dot(c[2] - c[0]);
    let l1 = (p - c[0]).perp_dot(c[2] - c[0]) / d;
    let l2 = (c[1] - c[0]).perp_dot(p - c[0]) / d;
    let l = Vec3::new(1.0 - l1 - l2, l1, l2).max(Vec3::ZERO);
    let s = l.x + l.y + l.z;
    if s > 0.0 && s.is_finite() {
        l / s
    } else {
        Vec3::splat(1.0 / 3.0)
    }
}

/// The barycentrics of texel (x, y)'s point on the triangle with atlas
/// corners `c`: under the texel's centre, or the triangle's point nearest
/// it.
pub(super) fn texel_barycentrics(c: &[Vec2; 3], x: u32, y: u32) -> Vec3 {
    let centre = Vec2::new(x as f32 + 0.5, y as f32 + 0.5);
    barycentric(c, closest_point(c, centre))
}

/// Texel (x, y) owned by triangle `t` with atlas corners `c`.
fn texel(scene: &Scene, c: &[Vec2; 3], t: u32, x: u32, y: u32) -> Texel {
    let l = texel_barycentrics(c, x, y);
    let [a, b, cc] = scene.triangles[t as usize].map(|v| scene.positions[v as usize]);
    Texel {
        x,
        y,
        tri: t,
        p: a * l.x + b * l.y + cc * l.z,
        n: (b - a).cross(cc - a).normalize_or_zero(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Whether triangle `c` and the square of texel (x, y) overlap by more
    /// than `margin` (separating axes: the square's two and the triangle's
    /// three edge normals).
    fn overlaps(c: &[Vec2; 3], x: u32, y: u32, margin: f32) -> bool {
        let sq = [(0.0, 0.0), (1.0, 0.0), (0.0, 1.0), (1.0, 1.0)]
            .map(|(dx, dy)| Vec2::new(x as f32 + dx, y as f32 + dy));
        let sign = (c[1] - c[0]).perp_dot(c[2] - c[0]).signum();
        let lo = c[0].min(c[1]).min(c[2]);
        let hi = c[0].max(c[1]).max(c[2]);
        let axes = lo.x < x as f32 + 1.0 - margin
            && hi.x > x as f32 + margin
            && lo.y < y as f32 + 1.0 - margin
            && hi.y > y as f32 + margin;
        axes && (0..3).all(|i| {
            let (a, b) = (c[i], c[(i + 1) % 3]);
            let e = b - a;
            sq.iter()
                .any(|&p| sign * e.perp_dot(p - a) > margin * e.length())
        })
    }

    /// The row spans against a brute-force separating-axis test on random
    /// triangles: every texel overlapped by more than 1e-3 is in the span,
    /// and every texel in it is at least touched (−1e-3).
    #[test]
    fn row_spans_are_the_conservative_coverage() {
        let mut state = 12345u64;
        let mut rnd = || {
            state = state
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            (state >> 40) as f32 / (1u64 << 24) as f32
        };
        let w = 32;
        for _ in 0..2000 {
            let scale = if rnd() < 0.5 { 3.0 } else { 30.0 };
            let c = [(); 3].map(|_| Vec2::new(1.0 + rnd() * scale, 1.0 + rnd() * scale));
            if (c[1] - c[0]).perp_dot(c[2] - c[0]).abs() < 1e-3 {
                continue;
            }
            for y in 0..w {
                let span = row_span(&c, y, w).unwrap_or((0, 0));
                for x in 0..w {
                    let inside = (span.0..span.1).contains(&x);
                    if overlaps(&c, x, y, 1e-3) {
                        assert!(inside, "{c:?}: texel ({x}, {y}) missed");
                    }
                    if inside {
                        assert!(
                            overlaps(&c, x, y, -1e-3),
                            "{c:?}: texel ({x}, {y}) not touched"
                        );
                    }
                }
            }
        }
    }

    #[test]
    fn closest_point_is_on_the_triangle_and_nearest() {
        let c = [
            Vec2::new(0.0, 0.0),
            Vec2::new(4.0, 0.0),
            Vec2::new(0.0, 4.0),
        ];
        assert_eq!(closest_point(&c, Vec2::new(1.0, 1.0)), Vec2::new(1.0, 1.0));
        assert_eq!(closest_point(&c, Vec2::new(1.0, -2.0)), Vec2::new(1.0, 0.0));
        assert_eq!(closest_point(&c, Vec2::new(3.0, 3.0)), Vec2::new(2.0, 2.0));
        assert_eq!(closest_point(&c, Vec2::new(-1.0, -1.0)), Vec2::ZERO);
        let l = barycentric(&c, Vec2::new(1.0, 2.0));
        assert!((l - Vec3::new(0.25, 0.25, 0.5)).length() < 1e-6);
    }
}
