//! Per texel, the irradiance E and its standard error, by the paper's
//! density estimation (§3.2, eq. 2) evaluated at the texel's point.
//!
//! The particles are phase 1 of the density bake, as is
//! ([`crate::methods::density::pipeline::trace_within`]): every hit on a
//! surface with a diffuse part, grouped by surface side. Here the hits of
//! each group (a planar surface side, or one side of a curved shape) are
//! put in a 3D kd-tree, and at a texel's point p with normal n:
//!
//! - **bandwidth**: h is the distance from p to its k-th nearest hit of the
//!   same group (found by a pilot of [`PILOT`] neighbours), so that about k
//!   hits fall in the kernel's support whatever the local density of hits.
//!   Eq. (2) with n_i hits of equal power c in a disk of radius h gives a
//!   relative error of √(E[K²]/E[K]²/k) = √(9/5 / k) for Silverman's K2
//!   (∫K2² = 9/(5π) over the unit disk, uniform hits). k grows with the
//!   local density of hits, k = c·m^(2/3) with m the hits per texel area
//!   the pilot sees ([`grown_k`], c = [`Options::growth`]), the rule that
//!   balances the kernel's bias (∝ h²) against its variance (∝ 1/k): the
//!   error falls as particles are added, and the blur shrinks. A fixed k
//!   ([`Options::neighbours`], `--neighbours`) keeps the error near
//!   √(1.8/k) whatever the particle count (the paper's fixed h = C1·√(A/n)
//!   instead keeps the blur even and lets the error grow where few
//!   particles land).
//! - **estimate**: Ê(p) = φ/(h² m) Σ_j c_j K2(|p − x_j|²/h²), c_j the hit's
//!   power in units of φ = Φ/n, m the kernel mass inside the region the
//!   hits may come from (below), as the polygon renormalisation of
//!   [`crate::methods::density::kernel`].
//! - **variance**: eq. (2) is a sum over the n particles of independent
//!   terms X_i (each the kernel-weighted power of particle i's hits near p,
//!   nearly always 0 or one hit), so Var Ê = n Var X ≈ n E[X²] (E[X]² is
//!   k/n² times smaller), whose unbiased estimate from the same sum is
//!   (φ/(h² m))² Σ_j c_j² K2(…)², per channel. Its square root is the
//!   standard error of the texel. It is the error about E[Ê], which is E
//!   blurred by the kernel: the kernel's bias is not in it (it shrinks as
//!   h does, with more particles).
//! - **no leaks**: a hit counts only if it lies on the same side of the
//!   same surface (a planar group of coplanar connected triangles, or a
//!   curved shape with the normal test of [`NORMAL_COS`]), and if it is
//!   reachable from p along the surface: [`Options::sectors`] rays leave
//!   p (lifted by δ along n) in the tangent plane, one per angular
//!   sector, up to h. Where none met anything (most texels) every hit
//!   counts; otherwise a hit counts at once if it is nearer than what the
//!   rays of its sector and its two neighbours met, and else only if a
//!   ray from p to it (both lifted by δ) is unoccluded. A wall standing on
//!   a floor thus cuts the floor's kernel. A texel whose sector rays meet
//!   no front of a face and, half of them or more, the back of one is
//!   inside a closed solid (under a
//!   wall standing on the floor) and takes no light: the hits at the
//!   wall's foot, whose 16-bit chart coordinates may put them a hair
//!   inside its footprint, would reach it otherwise. The kernel mass m is then that of
//!   the star-shaped free region (and, for a planar surface, of the part
//!   of it inside the surface's polygon: an 8×8 quadrature as the density
//!   bake's renormalisation), so that a texel by a wall is not darkened.

use std::f32::consts::PI;
use std::num::NonZeroUsize;
use std::sync::atomic::{AtomicBool, Ordering};

use glam::{Vec2, Vec3};
use kiddo::SquaredEuclidean;
use rayon::prelude::*;

use super::index::Group;
pub use super::index::HitIndex;
use super::{DensityAtlas, Lightmap, Texel};
use crate::color::Rgb;
use crate::geometry::{offset_point, Frame, Ray};
use crate::methods::density::hits::decode_rgb9e5;
use crate::methods::density::kernel::{k2, TriGrid, NORMAL_COS};
use crate::methods::density::surfaces::{Kind, Surface, Surfaces};
use crate::world::World;

/// The pilot's neighbour count k₀ (see [`Estimator::gather`]).
pub const PILOT: usize = 32;

/// Most sectors of the visibility test.
pub const MAX_SECTORS: usize = 32;

/// Bytes a hit takes in memory while the lightmap is estimated: its point
/// (12), its normal for curved shapes (12 at most), its power (4) and its
/// kd-tree entry (16).
pub const HIT_MEMORY: u64 = 44;

/// Settings of the estimator.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Options {
    /// A fixed k (`--neighbours K`): the bandwidth at a texel is the
    /// distance to its k-th nearest hit of the same surface side, and the
    /// relative error per texel stays about √(1.8/k) whatever the particle
    /// count (the blur grows with k). None: k grows with the local density
    /// of hits ([`Options::growth`]), so that the error falls as particles
    /// are added.
    pub neighbours: Option<usize>,
    /// c of the rule k = c·m^(2/3) (without a fixed k), m the hits per
    /// texel area at the texel (the local density of hits, from the pilot,
    /// times [`Options::texel_area`]); k is kept within [[`K_MIN`],
    /// [`K_MAX`]]. See [`grown_k`].
    pub growth: f32,
    /// The world area of one texel (m²), the unit the rule counts hits
    /// in; None: the scene's area over that of a 512² atlas 60 % used.
    pub texel_area: Option<f32>,
    /// A fixed bandwidth h (world units) for every texel instead of any k
    /// (for references: many bakes with a small h, averaged).
    pub bandwidth: Option<f32>,
    /// Visibility rays per texel, one per angular sector of the tangent
    /// plane (0: no visibility test; at most [`MAX_SECTORS`]).
    pub sectors: usize,
    /// The smallest kernel mass a texel's estimate is divided by.
    pub min_mass: f32,
}

/// The default c of [`Options::growth`]: of c = 10 to 160, the least
/// per-texel relative RMS at equal CPU time against a Cycles bake of the
/// Cornell box at 512² (docs/notebook/lightmap-estimator.md).
pub const GROWTH: f32 = 80.0;

/// The k a texel whose grown kernel is cut by an edge takes instead, when
/// narrower (see [`Estimator::texel`]): the fixed k of the first lightmap
/// bake, whose inside corners match the path tracer's.
pub const EDGE_K: usize = 256;

/// The fewest hits a grown kernel holds (the pilot's).
pub const K_MIN: usize = PILOT;

/// The most hits a grown kernel holds (a texel's cost is linear in k).
pub const K_MAX: usize = 1 << 16;

impl Default for Options {
    fn default() -> Self {
        Options {
            neighbours: None,
            growth: GROWTH,
            texel_area: None,
            bandwidth: None,
            sectors: 12,
            min_mass: 0.1,
        }
    }
}

/// The k of the adaptive rule at a texel whose pilot found `k0` hits
/// within a distance² `r2`: the local density of hits is ρ = k0/(π r2),
/// m = ρ·`texel_area` hits per texel, and k = `growth`·m^(2/3), within
/// [[`K_MIN`], [`K_MAX`]].
///
/// Why m^(2/3): for a second-order kernel in 2D the relative bias grows as
/// h² (the curvature of E times h²) and the relative variance is 1.8/k
/// with k = ρπh² hits in the kernel; the sum of the bias² and the variance
/// is least for h ∝ ρ^(−1/6), i.e. k ∝ ρ^(2/3). The error then falls as
/// ρ^(−1/3) once the bias matters, and as ρ^(−1/2) while it does not.
pub fn grown_k(k0: usize, r2: f32, texel_area: f32, growth: f32) -> usize {
    let rho = k0 as f32 / (PI * r2.max(1e-30));
    let m = rho * texel_area;
    let k = growth * m.max(0.0).powf(2.0 / 3.0);
    if !k.is_finite() {
        return K_MAX;
    }
    (k as usize).clamp(K_MIN, K_MAX)
}

/// atan2(y, x) to about 0.01 rad (a rational approximation on each
/// octant), enough to pick a sector: libm's is a tenth of a texel's time.
#[inline]
fn fast_atan2(y: f32, x: f32) -> f32 {
    let (ax, ay) = (x.abs(), y.abs());
    let (a, swap) = if ay > ax {
        (ax / ay.max(1e-30), true)
    } else {
        (ay / ax.max(1e-30), false)
    };
    // atan(a) on [0, 1]: a·(π/4 + 0.273·(1 − a)) (Rajan et al. 2006)
    let mut r = a * (std::f32::consts::FRAC_PI_4 + 0.273 * (1.0 - a));
    if swap {
        r = std::f32::consts::FRAC_PI_2 - r;
    }
    if x < 0.0 {
        r = PI - r;
    }
    if y < 0.0 {
        -r
    } else {
        r
    }
}

/// The sector of direction (x, y) in the tangent plane, of `sectors`
/// (sector s spans the angles −π + [s, s + 1)·2π/sectors).
#[inline]
fn sector(x: f32, y: f32, sectors: usize) -> usize {
    if sectors == 0 {
        return 0;
    }
    let a = fast_atan2(y, x);
    let s = ((a + PI) / (2.0 * PI) * sectors as f32) as usize;
    s.min(sectors - 1)
}

/// A planar surface's polygon in its chart, for the kernel mass.
struct Polygon {
    verts: Vec<Vec2>,
    tris: Vec<[u32; 3]>,
    grid: TriGrid,
}

impl Polygon {
    fn new(scene: &crate::scene::Scene, surf: &Surface) -> Polygon {
        let ct = surf.chart_tris(scene);
        let mut verts = Vec::with_capacity(ct.len() * 3);
        let mut tris = Vec::with_capacity(ct.len());
        for t in &ct {
            let b = verts.len() as u32;
            verts.extend_from_slice(t);
            tris.push([b, b + 1, b + 2]);
        }
        let grid = TriGrid::new(&verts, &tris);
        Polygon { verts, tris, grid }
    }

    fn inside(&self, surf: &Surface, c: Vec2) -> bool {
        if surf.rectangle {
            // a hair of slack: a point on the edge is inside
            let e = 1e-5 * surf.size.max_element();
            return c.x >= -e && c.y >= -e && c.x <= surf.size.x + e && c.y <= surf.size.y + e;
        }
        self.grid.inside(&self.verts, &self.tris, c)
    }
}

/// The estimate of one texel: irradiance and standard error (W/m², RGB).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct TexelEstimate {
    /// Irradiance Ê.
    pub e: Rgb,
    /// Standard error of Ê.
    pub se: Rgb,
    /// The bandwidth h (world units; 0 without hits).
    pub h: f32,
    /// Hits that counted (inside the kernel and reachable).
    pub used: u32,
    /// The texel's point is inside a closed solid (under a wall or a box
    /// standing on the floor, or lifted behind a wall that meets its
    /// surface at an acute edge): its sector rays met no front of a face
    /// and either half of them met the back of one, or some did and no
    /// hit was reachable. It holds no estimate of its own, and the atlas
    /// fills it from its neighbours as it pads a chart
    /// ([`estimate_texels`]).
    pub hidden: bool,
    /// The kernel was cut: by a face some sector ray met within h, or by
    /// the border of the surface (its mass inside the free region < 1).
    pub cut: bool,
    /// How far from the texel's point the hits the estimate depends on
    /// lie: the pilot's farthest neighbour and the bandwidth h. 0 when the
    /// index holds the texel's group whole; infinite when it holds too
    /// little of it to tell (a dataflow worker's part of the hits: the
    /// estimate is exact when the worker holds every hit within `reach`,
    /// see [`super::dataflow`]).
    pub reach: f32,
}

/// A texel's h², its hits within h (index, squared distance), and its
/// reach ([`TexelEstimate::reach`]).
type Gathered = (f32, Vec<(u32, f32)>, f32);

/// The sums of eq. (2) over a texel's hits, in the fixed point of
/// [`FIXED_BITS`] fractional bits: exact, so that the estimate does not
/// depend on the order the kd-tree returns its hits in (a dataflow
/// worker's tree holds some of them, in another order).
#[derive(Default)]
struct FixedSums {
    sum: [i128; 3],
    sum2: [i128; 3],
}

/// Fractional bits of [`FixedSums`]' sum of c·K2 (a term is at most
/// 65408·3/π < 2^16, so it fits an i64 with 40 bits, and an `i128` sum
/// holds 2^71 of them).
pub const FIXED_BITS: i32 = 40;

/// Fractional bits of the sum of c²·K2², for the standard error (a term
/// is below 2^32: an i64 holds it with 30 bits).
const FIXED_BITS2: i32 = 30;

impl FixedSums {
    /// `x` in a fixed point of `bits` fractional bits (truncated; the
    /// terms are never negative). Times a power of two is exact in f32
    /// (no term comes near its range), and the conversion to i64 is the
    /// processor's (to i128 it is a library call, which took most of a
    /// texel's time).
    #[inline]
    fn fixed(x: f32, bits: i32) -> i128 {
        (x * (1u64 << bits) as f32) as i64 as i128
    }

    #[inline]
    fn add(&mut self, c: Vec3, w: f32) {
        let (a, b) = (c * w, c * c * (w * w));
        for i in 0..3 {
            self.sum[i] += Self::fixed(a[i], FIXED_BITS);
            self.sum2[i] += Self::fixed(b[i], FIXED_BITS2);
        }
    }

    fn get(s: &[i128; 3], bits: i32) -> Vec3 {
        let f = |x: i128| (x as f64 / (1u64 << bits) as f64) as f32;
        Vec3::new(f(s[0]), f(s[1]), f(s[2]))
    }
}

/// What every texel's estimate reads.
pub struct Estimator<'a> {
    world: &'a World,
    surfaces: &'a Surfaces,
    index: &'a HitIndex,
    phi: f32,
    opts: Options,
    polygons: Vec<Option<Polygon>>,
    /// The largest lift δ off the surface for the visibility rays.
    lift: f32,
    /// The world area of a texel for the adaptive k ([`Options::texel_area`]).
    texel_area: f32,
}

impl<'a> Estimator<'a> {
    /// An estimator over `index`'s hits, φ = Φ/n in W per unit of hit
    /// power.
    pub fn new(
        world: &'a World,
        surfaces: &'a Surfaces,
        index: &'a HitIndex,
        phi: f64,
        opts: Options,
    ) -> Self {
        let scene = &world.scene;
        let polygons = surfaces
            .list
            .par_iter()
            .map(|s| {
                (s.kind == Kind::Planar && s.diffuse && !s.rectangle)
                    .then(|| Polygon::new(scene, s))
            })
            .collect();
        let (lo, hi) = scene.bounds();
        let diag = (hi - lo).length();
        let lift = if diag.is_finite() { 1e-3 * diag } else { 1e-3 };
        let texel_area = opts.texel_area.unwrap_or_else(|| {
            let area: f32 = (0..scene.triangles.len() as u32)
                .map(|t| {
                    let [a, b, c] = scene.tri_vertices(t);
                    0.5 * (b - a).cross(c - a).length()
                })
                .sum();
            area / (0.6 * 512.0 * 512.0)
        });
        Estimator {
            world,
            surfaces,
            index,
            phi: phi as f32,
            opts: Options {
                sectors: opts.sectors.min(MAX_SECTORS),
                neighbours: opts.neighbours.map(|k| k.max(1)),
                ..opts
            },
            polygons,
            lift,
            texel_area,
        }
    }

    /// The side of its surface a texel on triangle `tri` holds: true for
    /// the back (the side with more hits, see [`Estimator::texel`]); None
    /// when the triangle has no diffuse surface or its surface took no hit.
    pub fn side_of(&self, tri: u32) -> Option<bool> {
        let &sid = self.surfaces.tri_surface.get(tri as usize)?;
        let surf = &self.surfaces.list[sid as usize];
        if !surf.diffuse {
            return None;
        }
        self.index.group_of(surf, sid).map(|(_, back)| back)
    }

    /// The estimates of a texel on both sides of its surface: the side
    /// its atlas holds ([`Estimator::texel`]), and the other side when
    /// that is lit too (a final gather's ray may meet it there:
    /// [`super::gather`] reads it from a second atlas).
    pub fn texel_sides(&self, t: &Texel) -> (TexelEstimate, Option<TexelEstimate>) {
        let held = self.texel(t);
        let Some(&sid) = self.surfaces.tri_surface.get(t.tri as usize) else {
            return (held, None);
        };
        let surf = &self.surfaces.list[sid as usize];
        let Some((_, back)) = self.index.group_of(surf, sid).filter(|_| surf.diffuse) else {
            return (held, None);
        };
        if self.index.group_on(surf, sid, !back).is_none() {
            return (held, None);
        }
        (held, Some(self.texel_on(t, Some(!back))))
    }

    /// The estimate at a texel's point.
    pub fn texel(&self, t: &Texel) -> TexelEstimate {
        self.texel_on(t, None)
    }

    /// [`Estimator::texel`] on the given side of the texel's surface (true:
    /// the back) instead of the side with more hits: a final gather's ray
    /// that meets a surface on its other side reads this one
    /// ([`super::gather`]).
    pub fn texel_on(&self, t: &Texel, side: Option<bool>) -> TexelEstimate {
        let e = self.texel_with(t, self.opts.neighbours, side);
        // A grown kernel cut by an edge (a wall standing on the floor, the
        // polygon's border) is one-sided: on the lighting's gradient there
        // its bias grows with h faster than its variance falls, and inside
        // corners came out 3–8 % dark (tests/it/lightmap_seams.rs). Such a
        // texel takes the fixed k of [`EDGE_K`] when that kernel is the
        // narrower.
        if self.opts.neighbours.is_none() && self.opts.bandwidth.is_none() && e.cut {
            let edge = self.texel_with(t, Some(EDGE_K), side);
            let reach = e.reach.max(edge.reach);
            let pick = if edge.h < e.h { edge } else { e };
            return TexelEstimate { reach, ..pick };
        }
        e
    }

    /// [`Estimator::texel`] with k fixed at `fixed` (None: the rule of
    /// [`Options::growth`]), on side `side` (None: the side with more hits).
    fn texel_with(&self, t: &Texel, fixed: Option<usize>, side: Option<bool>) -> TexelEstimate {
        let Some(&sid) = self.surfaces.tri_surface.get(t.tri as usize) else {
            return TexelEstimate::default();
        };
        let surf = &self.surfaces.list[sid as usize];
        if !surf.diffuse {
            return TexelEstimate::default();
        }
        let found = match side {
            None => self.index.group_of(surf, sid),
            Some(back) => self.index.group_on(surf, sid, back).map(|g| (g, back)),
        };
        let Some((held, back)) = found else {
            return TexelEstimate::default();
        };
        // lit, but none of its hits held here: the halo must grow
        let unknown = TexelEstimate {
            reach: f32::INFINITY,
            ..Default::default()
        };
        let Some(gi) = held else {
            return unknown;
        };
        let g = &self.index.groups[gi];
        let n = if back { -t.n } else { t.n };
        let p = t.p;
        let Some((h2, found, reach)) = self.gather(g, p, fixed) else {
            return TexelEstimate {
                reach: if g.whole() { 0.0 } else { f32::INFINITY },
                ..Default::default()
            };
        };
        let h = h2.sqrt();
        let reach = if g.whole() { 0.0 } else { reach };

        // What the sector rays met, in units of h (1: nothing within h)
        let frame = Frame::from_normal(n);
        let sectors = self.opts.sectors;
        let (free, backs, fronts) = self.sector_rays(p, n, h, surf, &frame);
        // No ray met the front of a face and most left through the back of
        // one: p is inside a closed solid (a texel under a wall standing on
        // the floor; the rays along the wall may meet nothing within h),
        // and takes no light whatever hits lie near it
        if sectors > 0 && fronts == 0 && 2 * backs >= sectors {
            return TexelEstimate {
                h,
                hidden: true,
                reach,
                ..Default::default()
            };
        }
        // Only a texel whose kernel some ray was cut in tests the sectors
        let open = free[..sectors].iter().all(|&f| f >= 1.0);
        let (mut sums, mut used) = (FixedSums::default(), 0u32);
        for &(j, d2) in &found {
            let j = j as usize;
            if !g.normal.is_empty() && g.normal[j].dot(n) < NORMAL_COS {
                continue;
            }
            let w = k2(d2 / h2);
            if w <= 0.0 {
                continue;
            }
            if !open && !self.reachable(p, n, g, j, d2.sqrt(), &free[..sectors], &frame, h) {
                continue;
            }
            sums.add(decode_rgb9e5(g.rgb[j]), w);
            used += 1;
        }

        // The kernel mass of the region the hits may come from
        let mass = self.kernel_mass(surf, sid, (p, h, &frame), &free, open);
        let scale = self.phi / (h2 * mass.max(self.opts.min_mass));
        let sum = FixedSums::get(&sums.sum, FIXED_BITS);
        let sum2 = FixedSums::get(&sums.sum2, FIXED_BITS2);
        TexelEstimate {
            e: sum * scale,
            se: Vec3::new(sum2.x.sqrt(), sum2.y.sqrt(), sum2.z.sqrt()) * scale,
            h,
            used,
            // No hit reachable, and the rays met the back of a face and no
            // front: inside a solid too, nearer one of its walls than the
            // test above can tell (a texel under a box, a texel from its
            // side: the rays away from that side meet nothing within h)
            hidden: used == 0 && backs > 0 && fronts == 0,
            cut: !open || mass < 1.0,
            reach,
        }
    }

    /// The kernel mass (in units of the whole kernel's) of the region a
    /// texel's hits may come from: the part of the disk of radius h about
    /// `p` that the sector rays left free (`free`, in units of h, one per
    /// sector; none met anything when `open`) and, for a planar surface, inside its
    /// polygon (an 8×8 quadrature, as the density bake's renormalisation).
    fn kernel_mass(
        &self,
        surf: &Surface,
        sid: u32,
        (p, h, frame): (Vec3, f32, &Frame),
        free: &[f32; MAX_SECTORS],
        open: bool,
    ) -> f32 {
        let sectors = self.opts.sectors;
        let sector_of = |x: f32, y: f32| sector(x, y, sectors);
        let inner = |c: Vec2| {
            surf.rectangle
                && c.x >= h
                && c.y >= h
                && c.x <= surf.size.x - h
                && c.y <= surf.size.y - h
        };
        match (surf.kind, &self.polygons[sid as usize]) {
            (Kind::Planar, _) if open && inner(surf.to_chart(p)) => 1.0,
            (Kind::Curved, _) if open => 1.0,
            (Kind::Planar, poly) => {
                const N: usize = 8;
                let step = 2.0 / N as f32;
                let (mut m, mut total) = (0.0, 0.0);
                for jy in 0..N {
                    for ix in 0..N {
                        let o = Vec2::new(
                            -1.0 + (ix as f32 + 0.5) * step,
                            -1.0 + (jy as f32 + 0.5) * step,
                        );
                        let w = k2(o.length_squared());
                        if w <= 0.0 {
                            continue;
                        }
                        total += w;
                        if !open && o.length() >= free[sector_of(o.x, o.y)] {
                            continue;
                        }
                        let y = p + (frame.s * o.x + frame.t * o.y) * h;
                        let c = surf.to_chart(y);
                        let inside = match poly {
                            Some(poly) => poly.inside(surf, c),
                            None => {
                                surf.rectangle
                                    && c.x >= 0.0
                                    && c.y >= 0.0
                                    && c.x <= surf.size.x
                                    && c.y <= surf.size.y
                            }
                        };
                        if inside {
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
            (Kind::Curved, _) => {
                // the star-shaped free region: ∫ K2 over a sector to radius
                // t (in units of h) is (1 − (1 − t²)³)/S
                let s = sectors.max(1);
                free[..s]
                    .iter()
                    .map(|&t| {
                        let t = t.min(1.0);
                        let u = 1.0 - t * t;
                        1.0 - u * u * u
                    })
                    .sum::<f32>()
                    / s as f32
            }
        }
    }

    /// The sector rays of a texel at `p` (normal `n`, bandwidth `h`), one
    /// per sector of the tangent plane, lifted off the surface: how far
    /// each went, in units of h (1: it met nothing within h), and how many
    /// met the back and the front of a face.
    fn sector_rays(
        &self,
        p: Vec3,
        n: Vec3,
        h: f32,
        surf: &Surface,
        frame: &Frame,
    ) -> ([f32; MAX_SECTORS], usize, usize) {
        let sectors = self.opts.sectors;
        let mut free = [1.0f32; MAX_SECTORS];
        let (mut backs, mut fronts) = (0, 0);
        if sectors == 0 {
            return (free, backs, fronts);
        }
        let lift = (0.02 * h).min(self.lift);
        let o = offset_point(p, n, n) + n * lift;
        for (s, f) in free.iter_mut().enumerate().take(sectors) {
            let a = -PI + (s as f32 + 0.5) * 2.0 * PI / sectors as f32;
            let d = frame.s * a.cos() + frame.t * a.sin();
            let (t, back) = self.reach(o, d, h, surf.shape, surf.kind);
            *f = t / h;
            if t < h {
                backs += usize::from(back);
                fronts += usize::from(!back);
            }
        }
        (free, backs, fronts)
    }

    /// The bandwidth² h² at `p` and the hits within h (index, squared
    /// distance). h is found from a pilot: the distance r to the k₀-th
    /// nearest hit (k₀ = min(k, 32)) holds k₀ hits, so for a density even
    /// at the scale of h, the disk of radius r·√(k/k₀) holds about k
    /// (a full k-nearest query keeps a heap of k and costs several times
    /// more). k is fixed, or grown from the density the pilot saw
    /// ([`grown_k`]). Groups of at most k hits use them all, h just past
    /// the farthest. A fixed [`Options::bandwidth`] skips the pilot.
    fn gather(&self, g: &Group, p: Vec3, fixed: Option<usize>) -> Option<Gathered> {
        let q = p.to_array();
        let (h2, pilot) = match self.opts.bandwidth {
            Some(h) => (h * h, 0.0),
            None => self.bandwidth2(g, &q, p, fixed)?,
        };
        if !(h2 > 0.0 && h2.is_finite()) {
            return None;
        }
        let found = g
            .tree
            .query(&q)
            .within::<SquaredEuclidean<f32>>(h2)
            .unsorted()
            .execute()
            .into_iter()
            .map(|r| (r.item, r.distance))
            .collect();
        Some((h2, found, pilot.max(h2.sqrt())))
    }

    /// h² at `p` (see [`Estimator::gather`]), and the distance to the
    /// pilot's farthest neighbour (infinite when the group's hits decide
    /// h as a whole and are not all held).
    fn bandwidth2(
        &self,
        g: &Group,
        q: &[f32; 3],
        p: Vec3,
        fixed: Option<usize>,
    ) -> Option<(f32, f32)> {
        let all = || {
            let far = g
                .pos
                .iter()
                .map(|x| x.distance_squared(p))
                .fold(0.0f32, f32::max);
            (far * 1.0001, if g.whole() { 0.0 } else { f32::INFINITY })
        };
        let k0 = fixed.map_or(PILOT, |k| k.min(PILOT));
        if g.total <= k0 as u64 {
            return Some(all());
        }
        let near = g
            .tree
            .query(q)
            .nearest_n::<SquaredEuclidean<f32>>(NonZeroUsize::new(k0)?)
            .execute();
        if near.len() < k0 {
            // a worker holding fewer than k0 of the group's hits
            return Some((near.last().map_or(0.0, |n| n.distance), f32::INFINITY));
        }
        let r2 = near.last()?.distance;
        let k = match fixed {
            Some(k) => k,
            None => grown_k(k0, r2, self.texel_area, self.opts.growth),
        };
        if g.total <= k as u64 {
            return Some(all());
        }
        Some((r2 * (k as f32 / k0 as f32), r2.sqrt()))
    }

    /// Whether hit `j` of `g`, at distance `d` from `p`, is reachable from
    /// `p` along the surface: at once when it is nearer than what the rays
    /// of its sector and of the two next to it met (a wall that cuts the
    /// kernel is met by them), otherwise by a ray between the two points,
    /// both lifted off the surface (a wall seen edge-on between two sector
    /// rays, such as the one a texel under a wall stands in, would
    /// otherwise let through hits beyond its end).
    #[allow(clippy::too_many_arguments)]
    fn reachable(
        &self,
        p: Vec3,
        n: Vec3,
        g: &Group,
        j: usize,
        d: f32,
        free: &[f32],
        frame: &Frame,
        h: f32,
    ) -> bool {
        let s = free.len();
        let q = g.pos[j];
        let v = q - p;
        let k = sector(v.dot(frame.s), v.dot(frame.t), s);
        let near = free[k].min(free[(k + 1) % s]).min(free[(k + s - 1) % s]);
        if d < near * h {
            return true;
        }
        let lift = (0.02 * h).min(self.lift);
        let nq = if g.normal.is_empty() { n } else { g.normal[j] };
        let a = offset_point(p, n, n) + n * lift;
        let b = offset_point(q, nq, nq) + nq * lift;
        !self.world.accel.occluded(a, b)
    }

    /// How far a ray from `o` along `d` goes, up to `tmax`, before it meets
    /// geometry other than its own curved shape (a planar surface's own
    /// plane it cannot meet: it runs parallel to it, lifted), and whether
    /// what it met was the back of a face (its winding's normal along `d`).
    fn reach(&self, o: Vec3, d: Vec3, tmax: f32, own_shape: u32, kind: Kind) -> (f32, bool) {
        let scene = &self.world.scene;
        let mut ray = Ray {
            o,
            d,
            tmin: 0.0,
            tmax,
        };
        for _ in 0..4 {
            let Some(hit) = self.world.accel.intersect(&ray) else {
                return (tmax, false);
            };
            let same = kind == Kind::Curved && scene.tri_shape[hit.tri as usize] == own_shape;
            if !same {
                let [a, b, c] = scene.tri_vertices(hit.tri);
                return (hit.t, (b - a).cross(c - a).dot(d) > 0.0);
            }
            ray.tmin = hit.t * (1.0 + 1e-5) + 1e-6 * tmax;
            if ray.tmin >= tmax {
                return (tmax, false);
            }
        }
        (tmax, false)
    }
}

/// Estimates every texel of `texels` into a `width` × `height` atlas (in
/// parallel; the same bytes whatever the thread count). A texel found
/// inside a closed solid ([`TexelEstimate::hidden`]) is left uncovered,
/// at 0, for the padding to fill ([`Lightmap::set`]). Stops early, with
/// the atlas as far as it got, once `cancel` is set; `progress` hears the
/// texels done, from the calling thread.
pub fn estimate_texels(
    est: &Estimator,
    texels: &[Texel],
    width: u32,
    height: u32,
    cancel: Option<&AtomicBool>,
    progress: &mut dyn FnMut(u64, u64),
) -> Lightmap {
    let mut lm = Lightmap::empty(width, height);
    const SLICE: usize = 1 << 14;
    let total = texels.len() as u64;
    progress(0, total);
    for (i, slice) in texels.chunks(SLICE).enumerate() {
        if cancel.is_some_and(|c| c.load(Ordering::Relaxed)) {
            break;
        }
        let out: Vec<TexelEstimate> = slice.par_iter().map(|t| est.texel(t)).collect();
        for (t, e) in slice.iter().zip(out) {
            lm.set(t, &e);
        }
        progress((i * SLICE + slice.len()) as u64, total);
    }
    lm
}

/// A texel's estimates on both sides ([`Estimator::texel_sides`]).
pub type Sides = (TexelEstimate, Option<TexelEstimate>);

/// The estimates of the texels `which` (indices into `texels`), on both
/// sides when `both` (else the held side alone), in parallel, in
/// `which`'s order. Stops early, with the
/// estimates as far as they got, once `cancel` is set; `progress` hears
/// the texels done.
pub fn estimate_sides(
    est: &Estimator,
    texels: &[Texel],
    which: &[u32],
    both: bool,
    cancel: Option<&AtomicBool>,
    progress: &mut dyn FnMut(u64, u64),
) -> Vec<Sides> {
    const SLICE: usize = 1 << 14;
    let total = which.len() as u64;
    let mut out = Vec::with_capacity(which.len());
    progress(0, total);
    for slice in which.chunks(SLICE) {
        if cancel.is_some_and(|c| c.load(Ordering::Relaxed)) {
            break;
        }
        out.par_extend(slice.par_iter().map(|&i| match both {
            true => est.texel_sides(&texels[i as usize]),
            false => (est.texel(&texels[i as usize]), None),
        }));
        progress(out.len() as u64, total);
    }
    out
}

/// The density atlases of every texel ([`DensityAtlas`], the other sides
/// when `both`), unpadded.
pub fn estimate_density(
    est: &Estimator,
    texels: &[Texel],
    (width, height): (u32, u32),
    both: bool,
    cancel: Option<&AtomicBool>,
    progress: &mut dyn FnMut(u64, u64),
) -> DensityAtlas {
    let all: Vec<u32> = (0..texels.len() as u32).collect();
    let sides = estimate_sides(est, texels, &all, both, cancel, progress);
    let mut atlas = DensityAtlas::empty(width, height);
    for (t, (held, other)) in texels.iter().zip(&sides) {
        atlas.set(t, held, other.as_ref());
    }
    atlas
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_fast_atan2_is_close() {
        for i in 0..1000 {
            let a = -PI + 2.0 * PI * (i as f32 + 0.5) / 1000.0;
            let (y, x) = (3.0 * a.sin(), 3.0 * a.cos());
            assert!(
                (fast_atan2(y, x) - a).abs() < 0.01,
                "{a}: {}",
                fast_atan2(y, x)
            );
        }
    }

    #[test]
    fn the_k2_sector_mass_is_the_integral_of_the_kernel() {
        // ∫_0^t 2π r K2(r) dr = 1 − (1 − t²)³, by a midpoint rule
        for t in [0.25f32, 0.5, 0.9, 1.0] {
            let n = 10_000;
            let dr = t / n as f32;
            let m: f32 = (0..n)
                .map(|i| {
                    let r = (i as f32 + 0.5) * dr;
                    2.0 * PI * r * k2(r * r) * dr
                })
                .sum();
            let exact = 1.0 - (1.0 - t * t).powi(3);
            assert!((m - exact).abs() < 1e-4, "t {t}: {m} against {exact}");
        }
    }

    #[test]
    fn the_grown_k_follows_the_density_to_the_two_thirds() {
        // 32 hits within r² = 1/π: ρ = 32 per unit area
        let r2 = 1.0 / PI;
        let k = |area: f32| grown_k(32, r2, area, 40.0);
        // m = 32·area hits per texel: k = 40·m^(2/3)
        assert_eq!(k(1.0), (40.0 * 32f32.powf(2.0 / 3.0)) as usize);
        // 8 times the density: 4 times the k
        let (a, b) = (k(1.0) as f32, k(8.0) as f32);
        assert!((b / a - 4.0).abs() < 0.01, "{a} {b}");
        // clamped at both ends, and finite for any pilot
        assert_eq!(k(1e-9), K_MIN);
        assert_eq!(k(1e9), K_MAX);
        assert_eq!(grown_k(32, 0.0, 1.0, 40.0), K_MAX);
        assert_eq!(grown_k(32, f32::INFINITY, 1.0, 40.0), K_MIN);
    }
}
