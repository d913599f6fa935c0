//! Phase 2, density estimation (§3.2, §4.2): Silverman's K2 kernel, eq. (3),
//! the bandwidth h = C1·√(A/n) and grid spacing C2·√(A/n), boundary
//! treatment, and the over-mesh with the irradiance at its vertices.
//!
//! Boundaries. Rectangles use the paper's reflection method: hits within h of
//! an edge are mirrored across it (and across both edges at corners), so
//! that the kernel mass lost outside comes back, which removes the zeroth-
//! order boundary bias for a density that is flat across the edge. General
//! polygons (L shapes, triangles, faces with holes) use renormalisation
//! instead: the estimate at x is divided by the kernel mass inside the
//! polygon, m(x) = ∫_P K_h(x − y) dy (computed by an 8×8 midpoint quadrature
//! of the kernel's support with exact point-in-polygon tests). Both are
//! consistent: E[Ĥ(x)] = ∫_P K_h(x−y) H(y) dy / m(x) → H(x) as h → 0, and
//! both are exact for a locally constant H; reflection is unusable for
//! polygons because mirrored points across one edge can land inside the
//! polygon across a re-entrant corner.
//!
//! Curved and finely tessellated shapes (too few hits per triangle for a
//! per-triangle estimate) use the 3D form: all hits of the shape in a kd-tree
//! (kiddo), and at each vertex x with normal n the sum over hits within h
//! whose normal is compatible (n·n_j ≥ [`NORMAL_COS`]), the kernel taken of
//! the 3D distance and normalised as a 2D kernel (the surface is locally
//! planar at the scale h).

use std::collections::HashMap;
use std::f32::consts::PI;

use glam::{Vec2, Vec3};
use kiddo::{ImmutableKdTree, SquaredEuclidean};
use rayon::prelude::*;

use super::hits::{decode_rgb9e5, from_fixed, Hit};

/// Normal compatibility of the 3D kernel: cos of the largest angle between
/// the normal at the estimate point and at a hit that may contribute.
pub const NORMAL_COS: f32 = 0.9;

/// Silverman's K2 of eq. (3) as a function of r² = |x − x_j|²/h²:
/// (3/π)(1 − r²)² inside the unit disk. Unit volume in 2D.
#[inline]
pub fn k2(r2: f32) -> f32 {
    if r2 < 1.0 {
        let t = 1.0 - r2;
        3.0 / PI * t * t
    } else {
        0.0
    }
}

/// An over-meshed planar estimate: chart vertices, triangles (counter-
/// clockwise in the chart) and the irradiance (W/m², RGB) at each vertex.
#[derive(Clone, Debug, Default)]
pub struct Estimate {
    /// Vertices in chart coordinates.
    pub verts: Vec<Vec2>,
    /// Triangles.
    pub tris: Vec<[u32; 3]>,
    /// Irradiance at each vertex.
    pub h: Vec<Vec3>,
    /// Kernel bandwidth used (chart units).
    pub bandwidth: f32,
}

/// A uniform bin grid over chart triangles, for point location.
#[derive(Clone, Debug, Default)]
pub struct TriGrid {
    lo: Vec2,
    cell: Vec2,
    nx: usize,
    ny: usize,
    start: Vec<u32>,
    items: Vec<u32>,
}

impl TriGrid {
    /// Bins `tris` (indices into `verts`).
    pub fn new(verts: &[Vec2], tris: &[[u32; 3]]) -> Self {
        let mut lo = Vec2::splat(f32::INFINITY);
        let mut hi = Vec2::splat(f32::NEG_INFINITY);
        for v in verts {
            lo = lo.min(*v);
            hi = hi.max(*v);
        }
        if tris.is_empty() || lo.x > hi.x {
            return TriGrid::default();
        }
        let n = (tris.len() as f32).sqrt().ceil().clamp(1.0, 1024.0) as usize;
        let ext = (hi - lo).max(Vec2::splat(1e-12));
        let (nx, ny) = (n, n);
        let cell = ext / Vec2::new(nx as f32, ny as f32);
        let range = |t: &[u32; 3]| {
            let mut a = Vec2::splat(f32::INFINITY);
            let mut b = Vec2::splat(f32::NEG_INFINITY);
            for &i in t {
                a = a.min(verts[i as usize]);
                b = b.max(verts[i as usize]);
            }
            let ia = ((a - lo) / cell).floor();
            let ib = ((b - lo) / cell).floor();
            (
                (ia.x.max(0.0) as usize).min(nx - 1),
                (ia.y.max(0.0) as usize).min(ny - 1),
                (ib.x.max(0.0) as usize).min(nx - 1),
                (ib.y.max(0.0) as usize).min(ny - 1),
            )
        };
        let mut count = vec![0u32; nx * ny + 1];
        for t in tris {
            let (x0, y0, x1, y1) = range(t);
            for y in y0..=y1 {
                for x in x0..=x1 {
                    count[y * nx + x + 1] += 1;
                }
            }
        }
        for i in 1..count.len() {
            count[i] += count[i - 1];
        }
        let mut fill = count.clone();
        let mut items = vec![0u32; count[nx * ny] as usize];
        for (ti, t) in tris.iter().enumerate() {
            let (x0, y0, x1, y1) = range(t);
            for y in y0..=y1 {
                for x in x0..=x1 {
                    let c = y * nx + x;
                    items[fill[c] as usize] = ti as u32;
                    fill[c] += 1;
                }
            }
        }
        TriGrid {
            lo,
            cell,
            nx,
            ny,
            start: count,
            items,
        }
    }

    /// The triangle containing `p` and its barycentrics (b0, b1, b2); when
    /// `p` is just outside every triangle (rounding at an edge), the
    /// triangle of the cell it is least outside of, with clamped weights.
    pub fn locate(&self, verts: &[Vec2], tris: &[[u32; 3]], p: Vec2) -> Option<(u32, Vec3)> {
        if self.nx == 0 {
            return None;
        }
        let c = ((p - self.lo) / self.cell).floor();
        let cx = (c.x.max(0.0) as usize).min(self.nx - 1);
        let cy = (c.y.max(0.0) as usize).min(self.ny - 1);
        let cell = cy * self.nx + cx;
        let mut best: Option<(f32, u32, Vec3)> = None;
        for &ti in &self.items[self.start[cell] as usize..self.start[cell + 1] as usize] {
            let t = tris[ti as usize];
            let b = barycentric(
                verts[t[0] as usize],
                verts[t[1] as usize],
                verts[t[2] as usize],
                p,
            );
            let m = b.min_element();
            if m >= -1e-6 {
                return Some((ti, b));
            }
            if best.is_none_or(|x| m > x.0) {
                best = Some((m, ti, b));
            }
        }
        best.map(|(_, ti, b)| {
            let b = b.max(Vec3::ZERO);
            (ti, b / b.element_sum().max(1e-12))
        })
    }

    /// True when the grid holds nothing (never built, or no triangles).
    pub fn is_empty(&self) -> bool {
        self.nx == 0
    }

    /// True when `p` lies in one of the triangles.
    pub fn inside(&self, verts: &[Vec2], tris: &[[u32; 3]], p: Vec2) -> bool {
        if self.nx == 0 {
            return false;
        }
        let c = ((p - self.lo) / self.cell).floor();
        if c.x < 0.0 || c.y < 0.0 || c.x >= self.nx as f32 || c.y >= self.ny as f32 {
            return false;
        }
        let cell = c.y as usize * self.nx + c.x as usize;
        self.items[self.start[cell] as usize..self.start[cell + 1] as usize]
            .iter()
            .any(|&ti| {
                let t = tris[ti as usize];
                barycentric(
                    verts[t[0] as usize],
                    verts[t[1] as usize],
                    verts[t[2] as usize],
                    p,
                )
                .min_element()
                    >= 0.0
            })
    }
}

/// Barycentrics of `p` in triangle (a, b, c).
#[inline]
pub fn barycentric(a: Vec2, b: Vec2, c: Vec2, p: Vec2) -> Vec3 {
    let d = (b - a).perp_dot(c - a);
    if d == 0.0 {
        return Vec3::splat(-1.0);
    }
    let b1 = (p - a).perp_dot(c - a) / d;
    let b2 = (b - a).perp_dot(p - a) / d;
    Vec3::new(1.0 - b1 - b2, b1, b2)
}

/// The over-mesh of a planar surface: an n_u × n_v lattice with
/// 2(n_u − 1)(n_v − 1) triangles for a rectangle of `size` (§4.2), or, for a
/// general polygon, every triangle cut into k² by a barycentric lattice (one
/// k per surface so that shared edges match), vertices merged. At most about
/// `max_verts` vertices: the spacing grows if needed.
pub fn overmesh(
    rectangle: bool,
    size: Vec2,
    chart_tris: &[[Vec2; 3]],
    spacing: f32,
    max_verts: usize,
) -> (Vec<Vec2>, Vec<[u32; 3]>) {
    let max_verts = max_verts.max(4) as f32;
    if rectangle {
        let mut sp = spacing.max(1e-12);
        let area = size.x * size.y;
        if area / (sp * sp) > max_verts {
            sp = (area / max_verts).sqrt();
        }
        let nu = ((size.x / sp).ceil() as usize + 1).clamp(2, 1 << 14);
        let nv = ((size.y / sp).ceil() as usize + 1).clamp(2, 1 << 14);
        let mut verts = Vec::with_capacity(nu * nv);
        for j in 0..nv {
            for i in 0..nu {
                verts.push(Vec2::new(
                    size.x * i as f32 / (nu - 1) as f32,
                    size.y * j as f32 / (nv - 1) as f32,
                ));
            }
        }
        let mut tris = Vec::with_capacity(2 * (nu - 1) * (nv - 1));
        for j in 0..nv - 1 {
            for i in 0..nu - 1 {
                let a = (j * nu + i) as u32;
                let (b, c, d) = (a + 1, a + nu as u32 + 1, a + nu as u32);
                tris.push([a, b, c]);
                tris.push([a, c, d]);
            }
        }
        return (verts, tris);
    }
    let longest = chart_tris
        .iter()
        .flat_map(|t| {
            [
                (t[1] - t[0]).length(),
                (t[2] - t[1]).length(),
                (t[0] - t[2]).length(),
            ]
        })
        .fold(0.0f32, f32::max);
    let mut k = (longest / spacing.max(1e-12)).ceil().clamp(1.0, 256.0) as usize;
    while k > 1 && (chart_tris.len() * (k + 1) * (k + 2) / 2) as f32 > max_verts {
        k -= 1;
    }
    let quantum = longest.max(1e-12) * 1e-6;
    let mut index: HashMap<(i64, i64), u32> = HashMap::new();
    let mut verts = Vec::new();
    let mut tris = Vec::new();
    for t in chart_tris {
        let mut id = |i: usize, j: usize| {
            let p = t[0]
                + (t[1] - t[0]) * (i as f32 / k as f32)
                + (t[2] - t[0]) * (j as f32 / k as f32);
            let key = (
                (p.x / quantum).round() as i64,
                (p.y / quantum).round() as i64,
            );
            *index.entry(key).or_insert_with(|| {
                verts.push(p);
                (verts.len() - 1) as u32
            })
        };
        for j in 0..k {
            for i in 0..k - j {
                let (a, b, c) = (id(i, j), id(i + 1, j), id(i, j + 1));
                tris.push([a, b, c]);
                if i + j + 1 < k {
                    let d = id(i + 1, j + 1);
                    tris.push([b, d, c]);
                }
            }
        }
    }
    (verts, tris)
}

/// Parameters of one planar estimate.
#[derive(Clone, Copy, Debug)]
pub struct Params {
    /// C1 of h = C1·√(A/n).
    pub c1: f32,
    /// C2 of the grid spacing C2·√(A/n).
    pub c2: f32,
    /// φ = Φ/n in W (the unit of the hits' power).
    pub phi: f32,
    /// Cap on over-mesh vertices per surface.
    pub max_verts: usize,
}

/// Estimates the irradiance of a planar surface from its hit records
/// (chart position in fixed point, power in units of φ), eq. (2): H(x) = φ/h² Σ c_j K2((x − x_j)/h).
pub fn estimate_planar(
    rectangle: bool,
    size: Vec2,
    area: f32,
    chart_tris: &[[Vec2; 3]],
    hits: &[Hit],
    p: &Params,
) -> Estimate {
    let mut e = PlanarEstimator::new(rectangle, size, area, chart_tris, hits.len() as u64, p);
    e.add(hits);
    e.finish()
}

/// The kernel estimate of one planar surface, fed its hits chunk by chunk.
///
/// Eq. (2) is a sum over hits, so it is additive over any split of the
/// hits: the bandwidth and the over-mesh depend only on the total count
/// n_i, known before the first chunk; each chunk (and, for a rectangle, its
/// mirror images, made per hit on the fly) is binned and gathered at every
/// over-mesh vertex, and the partial sums are added.
///
/// The sums are exact: each kernel term c_j·K2 (an f32, as before) is
/// rounded to a fixed point of [`FIXED_BITS`] fractional bits and added
/// in an `i128`, so that a vertex's sum is the same whatever the order of
/// its terms and however the hits are cut into chunks, or into the tiles
/// of a dataflow bake, whose workers each see only the hits near their
/// vertices ([`PlanarEstimator::keep_only`]). The rounding (below 1e-12
/// of φ per term) is far under the f32 rounding of a term.
pub struct PlanarEstimator {
    rectangle: bool,
    size: Vec2,
    bw: f32,
    verts: Vec<Vec2>,
    tris: Vec<[u32; 3]>,
    sum: Vec<[i128; 3]>,
    keep: Option<Vec<bool>>,
    chart_tris: Vec<[Vec2; 3]>,
    phi: f32,
    empty: bool,
}

/// Fractional bits of the fixed-point kernel sums of [`PlanarEstimator`]:
/// a term (at most 65408·3/π, the largest RGB9E5 power times K2's peak) is
/// below 2^56, so an `i128` sum holds 2^71 of them.
pub const FIXED_BITS: i32 = 40;

/// A kernel term in the fixed point of [`FIXED_BITS`] (truncated; the
/// terms are never negative).
#[inline]
fn to_fixed(x: f32) -> i64 {
    // times a power of two: exact in f32 (no term comes near f32's range)
    (x * (1u64 << FIXED_BITS) as f32) as i64
}

/// A fixed-point sum back to f32.
#[inline]
fn from_fixed_sum(x: i128) -> f32 {
    (x as f64 / (1u64 << FIXED_BITS) as f64) as f32
}

impl PlanarEstimator {
    /// An estimator for a surface that will receive `n` hits in all.
    pub fn new(
        rectangle: bool,
        size: Vec2,
        area: f32,
        chart_tris: &[[Vec2; 3]],
        n: u64,
        p: &Params,
    ) -> Self {
        if n == 0 {
            let (verts, tris) = overmesh(rectangle, size, chart_tris, f32::INFINITY, 4);
            let sum = vec![[0; 3]; verts.len()];
            return PlanarEstimator {
                rectangle,
                size,
                bw: 0.0,
                verts,
                tris,
                sum,
                keep: None,
                chart_tris: Vec::new(),
                phi: p.phi,
                empty: true,
            };
        }
        let unit = (area / n as f32).sqrt();
        let bw = p.c1 * unit;
        let (verts, tris) = overmesh(rectangle, size, chart_tris, p.c2 * unit, p.max_verts);
        let sum = vec![[0; 3]; verts.len()];
        PlanarEstimator {
            rectangle,
            size,
            bw,
            verts,
            tris,
            sum,
            keep: None,
            chart_tris: chart_tris.to_vec(),
            phi: p.phi,
            empty: false,
        }
    }

    /// Adds the kernels of a chunk of hits.
    pub fn add(&mut self, hits: &[Hit]) {
        if self.empty || hits.is_empty() {
            return;
        }
        let (rectangle, size, bw) = (self.rectangle, self.size, self.bw);
        // The points: every hit (chart position, power in units of φ) and,
        // for a rectangle, its mirror images across the edges within h (the
        // reflection method). Generated twice (count, then fill) so that
        // only one decoded copy of the chunk is ever held.
        let for_each_point = |f: &mut dyn FnMut(Vec2, Vec3)| {
            for h in hits {
                let x = Vec2::new(from_fixed(h.u), from_fixed(h.v)) * size;
                let c = decode_rgb9e5(h.rgb);
                f(x, c);
                if !rectangle {
                    continue;
                }
                let xs: [f32; 3] = [x.x, -x.x, 2.0 * size.x - x.x];
                let ys: [f32; 3] = [x.y, -x.y, 2.0 * size.y - x.y];
                for (i, &u) in xs.iter().enumerate() {
                    for (j, &v) in ys.iter().enumerate() {
                        if i == 0 && j == 0 {
                            continue;
                        }
                        let q = Vec2::new(u, v);
                        if q.x > -bw && q.y > -bw && q.x < size.x + bw && q.y < size.y + bw {
                            f(q, c);
                        }
                    }
                }
            }
        };

        // Bin the points in cells of side ≥ h (counting sort keeps their order)
        let lo = Vec2::splat(-bw);
        let ext = size + Vec2::splat(2.0 * bw);
        let ncell = |e: f32| ((e / bw).floor() as usize).clamp(1, 4096);
        let (nx, ny) = (ncell(ext.x), ncell(ext.y));
        let cell = ext / Vec2::new(nx as f32, ny as f32);
        let cell_of = |q: Vec2| {
            let c = ((q - lo) / cell).floor();
            let cx = (c.x.max(0.0) as usize).min(nx - 1);
            let cy = (c.y.max(0.0) as usize).min(ny - 1);
            cy * nx + cx
        };
        let mut start = vec![0u32; nx * ny + 1];
        for_each_point(&mut |q, _| start[cell_of(q) + 1] += 1);
        for i in 1..start.len() {
            start[i] += start[i - 1];
        }
        let mut fill = start.clone();
        let mut sorted = vec![(Vec2::ZERO, Vec3::ZERO); start[nx * ny] as usize];
        for_each_point(&mut |q, c| {
            let k = cell_of(q);
            sorted[fill[k] as usize] = (q, c);
            fill[k] += 1;
        });
        drop(fill);

        let inv_h2 = 1.0 / (bw * bw);
        let keep = self.keep.as_deref();
        self.sum
            .par_iter_mut()
            .zip(self.verts.par_iter())
            .enumerate()
            .for_each(|(i, (acc, &x))| {
                if keep.is_some_and(|k| !k[i]) {
                    return;
                }
                let c = ((x - lo) / cell).floor();
                let cx = c.x.max(0.0) as usize;
                let cy = c.y.max(0.0) as usize;
                // Terms are below 2^56: an i64 holds 64 of them, then
                // goes into the i128 sum
                let mut part = [0i64; 3];
                let mut terms = 0u32;
                for yy in cy.saturating_sub(1)..=(cy + 1).min(ny - 1) {
                    for xx in cx.saturating_sub(1)..=(cx + 1).min(nx - 1) {
                        let k = yy * nx + xx;
                        for &(q, col) in &sorted[start[k] as usize..start[k + 1] as usize] {
                            let w = k2((x - q).length_squared() * inv_h2);
                            if w > 0.0 {
                                let t = col * w;
                                part[0] += to_fixed(t.x);
                                part[1] += to_fixed(t.y);
                                part[2] += to_fixed(t.z);
                                terms += 1;
                                if terms == 64 {
                                    for (a, b) in acc.iter_mut().zip(part) {
                                        *a += b as i128;
                                    }
                                    (part, terms) = ([0; 3], 0);
                                }
                            }
                        }
                    }
                }
                for (a, b) in acc.iter_mut().zip(part) {
                    *a += b as i128;
                }
            });
    }

    /// Estimates only the vertices where `keep` is true (one flag a vertex,
    /// in the order of [`PlanarEstimator::verts`]); the others stay black.
    /// A dataflow worker estimates the vertices of its own tiles so.
    pub fn keep_only(&mut self, keep: Vec<bool>) {
        debug_assert_eq!(keep.len(), self.verts.len());
        self.keep = Some(keep);
    }

    /// The over-mesh's vertices, in chart coordinates.
    pub fn verts(&self) -> &[Vec2] {
        &self.verts
    }

    /// The kernel bandwidth h (0 without hits).
    pub fn bandwidth(&self) -> f32 {
        self.bw
    }

    /// Over-mesh vertices so far (the memory the estimate holds).
    pub fn vertex_count(&self) -> usize {
        self.verts.len()
    }

    /// The estimate: φ/h² times the sums, renormalised at the boundary of a
    /// general polygon.
    pub fn finish(self) -> Estimate {
        let bw = self.bw;
        if self.empty {
            return Estimate {
                h: vec![Vec3::ZERO; self.verts.len()],
                verts: self.verts,
                tris: self.tris,
                bandwidth: 0.0,
            };
        }
        // Renormalisation for general polygons: kernel mass inside the polygon
        let poly = (!self.rectangle).then(|| {
            let mut pv = Vec::with_capacity(self.chart_tris.len() * 3);
            let mut pt = Vec::with_capacity(self.chart_tris.len());
            for t in &self.chart_tris {
                let b = pv.len() as u32;
                pv.extend_from_slice(t);
                pt.push([b, b + 1, b + 2]);
            }
            let g = TriGrid::new(&pv, &pt);
            (pv, pt, g)
        });
        let scale = self.phi / (bw * bw);
        let keep = self.keep.as_deref();
        let h: Vec<Vec3> = self
            .sum
            .par_iter()
            .zip(self.verts.par_iter())
            .enumerate()
            .map(|(i, (&sum, &x))| {
                if keep.is_some_and(|k| !k[i]) {
                    return Vec3::ZERO;
                }
                let sum = Vec3::new(
                    from_fixed_sum(sum[0]),
                    from_fixed_sum(sum[1]),
                    from_fixed_sum(sum[2]),
                );
                let mut est = sum * scale;
                if let Some((pv, pt, g)) = &poly {
                    let m = kernel_mass(x, bw, |y| g.inside(pv, pt, y));
                    if m > 0.05 {
                        est /= m;
                    }
                }
                est
            })
            .collect();
        Estimate {
            verts: self.verts,
            tris: self.tris,
            h,
            bandwidth: bw,
        }
    }
}

/// ∫ K_h(x − y) [y inside] dy by an 8×8 midpoint rule over the support.
fn kernel_mass(x: Vec2, h: f32, inside: impl Fn(Vec2) -> bool) -> f32 {
    const N: usize = 8;
    let d = 2.0 / N as f32;
    let mut m = 0.0;
    let mut total = 0.0;
    for j in 0..N {
        for i in 0..N {
            let o = Vec2::new(-1.0 + (i as f32 + 0.5) * d, -1.0 + (j as f32 + 0.5) * d);
            let w = k2(o.length_squared());
            total += w;
            if w > 0.0 && inside(x + o * h) {
                m += w;
            }
        }
    }
    if total > 0.0 {
        m / total
    } else {
        1.0
    }
}

/// 3D estimate on a curved shape: irradiance at each point `at` (with unit
/// normal) from hits (position, normal, power in units of φ), bandwidth `h`.
pub fn estimate_3d(
    at: &[(Vec3, Vec3)],
    hits: &[(Vec3, Vec3, Vec3)],
    h: f32,
    phi: f32,
) -> Vec<Vec3> {
    if hits.is_empty() || h <= 0.0 {
        return vec![Vec3::ZERO; at.len()];
    }
    let pts: Vec<[f32; 3]> = hits.iter().map(|(p, _, _)| p.to_array()).collect();
    let Ok(tree) = ImmutableKdTree::<f32, 3>::new_from_slice(&pts) else {
        return vec![Vec3::ZERO; at.len()];
    };
    let scale = phi / (h * h);
    at.par_iter()
        .map(|&(x, n)| {
            let mut found: Vec<(u32, f32)> = tree
                .query(&x.to_array())
                .within::<SquaredEuclidean<f32>>(h * h)
                .execute()
                .into_iter()
                .map(|r| (r.item, r.distance))
                .collect();
            found.sort_by_key(|r| r.0); // fixed summation order
            let mut sum = Vec3::ZERO;
            for (i, d2) in found {
                let (_, nj, c) = hits[i as usize];
                if n.dot(nj) >= NORMAL_COS {
                    sum += c * k2(d2 / (h * h));
                }
            }
            sum * scale
        })
        .collect()
}
