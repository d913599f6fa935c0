//! Random numbers and the warps from the unit square to directions and shapes.
//!
//! The generator is PCG32 (O'Neill 2014), written here by hand: it is twelve
//! lines, and streams keyed by (seed, pass, task) make every render
//! reproducible whatever the thread count. A camera path or a light walk
//! draws through the [`Sampler`] trait, which PCG32 (`--sampler
//! independent`) and the Owen-scrambled Sobol points of [`sobol`]
//! (`--sampler sobol`) implement.

use glam::{Vec2, Vec3};
use std::f32::consts::PI;

pub mod sobol;

pub use sobol::{SobolSampler, SobolWalkSampler};

/// Where a path's numbers come from: uniform numbers in [0, 1),
/// one or two at a time. [`Pcg32`] gives independent ones; a
/// low-discrepancy sampler gives each draw its own dimension of a point
/// set and is told where each vertex's dimensions start.
pub trait Sampler {
    /// A uniform float in [0, 1).
    fn next_f32(&mut self) -> f32;
    /// A uniform point in [0, 1)².
    fn next_2d(&mut self) -> Vec2;
    /// The path (a camera path, or a light walk for [`SobolWalkSampler`])
    /// reaches its vertex at `depth` (the end of its `depth`-th segment): a
    /// sampler with a dimension layout moves to that vertex's dimensions,
    /// so that each vertex draws from its own whatever the earlier ones
    /// drew. Independent numbers ignore it.
    #[inline(always)]
    fn start_vertex(&mut self, depth: u32) {
        let _ = depth;
    }
}

impl Sampler for Pcg32 {
    #[inline(always)]
    fn next_f32(&mut self) -> f32 {
        Pcg32::next_f32(self)
    }

    #[inline(always)]
    fn next_2d(&mut self) -> Vec2 {
        Pcg32::next_2d(self)
    }
}

/// Which numbers a method draws (`--sampler`): `path`'s camera paths,
/// `light`'s walks and the camera pass of `light` and `plb`.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "kebab-case")]
#[cfg_attr(feature = "cli", derive(clap::ValueEnum))]
pub enum SamplerKind {
    /// Independent numbers from PCG32, one stream per (seed, pass, pixel)
    /// (per (seed, pass, lane) for `light`'s walks).
    #[default]
    Independent,
    /// Owen-scrambled Sobol points, one randomisation per (seed, pixel), the
    /// pass as the sample index ([`sobol`]); for `light`'s walks, one per
    /// (seed, pass), the walk as the index ([`SobolWalkSampler`]).
    Sobol,
}

impl SamplerKind {
    /// True for [`SamplerKind::Independent`] (serde leaves the default out
    /// of a partial result's header, which then reads as before).
    pub fn is_independent(&self) -> bool {
        *self == SamplerKind::Independent
    }
}

/// PCG32 (XSH RR): 64-bit state, 32-bit output, selectable stream.
#[derive(Clone, Debug)]
pub struct Pcg32 {
    state: u64,
    inc: u64,
}

/// PCG32's LCG multiplier.
pub(crate) const PCG_MULT: u64 = 6364136223846793005;

impl Pcg32 {
    /// A generator for the given seed and stream.
    pub fn new(seed: u64, stream: u64) -> Self {
        let mut r = Pcg32 {
            state: 0,
            inc: (stream << 1) | 1,
        };
        r.next_u32();
        r.state = r.state.wrapping_add(seed);
        r.next_u32();
        r
    }

    /// A generator for a task identified by several keys (seed, pass, pixel...),
    /// hashed together so that nearby keys give unrelated streams.
    pub fn keyed(keys: &[u64]) -> Self {
        let mut h = 0x9E37_79B9_7F4A_7C15u64;
        for &k in keys {
            h = mix64(h ^ mix64(k.wrapping_add(0x632B_E59B_D9B4_E019)));
        }
        Pcg32::new(h, mix64(h ^ 0xD1B5_4A32_D192_ED03))
    }

    /// The next 32 random bits.
    #[inline]
    pub fn next_u32(&mut self) -> u32 {
        let old = self.state;
        self.state = old.wrapping_mul(PCG_MULT).wrapping_add(self.inc);
        let xorshifted = (((old >> 18) ^ old) >> 27) as u32;
        let rot = (old >> 59) as u32;
        xorshifted.rotate_right(rot)
    }

    /// A uniform float in [0, 1).
    #[inline]
    pub fn next_f32(&mut self) -> f32 {
        // 24 random mantissa bits: never rounds up to 1.0.
        (self.next_u32() >> 8) as f32 * (1.0 / 16_777_216.0)
    }

    /// A uniform point in [0, 1)².
    #[inline]
    pub fn next_2d(&mut self) -> Vec2 {
        Vec2::new(self.next_f32(), self.next_f32())
    }

    /// The state and the increment (the stream), for generators advanced
    /// together in lanes (`transport::lanes`).
    #[inline(always)]
    pub(crate) fn parts(&self) -> (u64, u64) {
        (self.state, self.inc)
    }

    /// The generator of [`Pcg32::parts`] `(state, inc)`.
    #[inline(always)]
    pub(crate) fn from_parts(state: u64, inc: u64) -> Self {
        Pcg32 { state, inc }
    }

    /// A uniform f64 in [0, 1).
    #[inline]
    pub fn next_f64(&mut self) -> f64 {
        let hi = (self.next_u32() as u64) << 21;
        let lo = (self.next_u32() >> 11) as u64;
        (hi | lo) as f64 * (1.0 / 9_007_199_254_740_992.0)
    }
}

/// SplitMix64 finaliser: a bijective 64-bit mixer.
#[inline]
pub fn mix64(mut z: u64) -> u64 {
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^ (z >> 31)
}

/// Cosine-weighted direction on the +z hemisphere (Malley's method).
#[inline]
pub fn cosine_hemisphere(u: Vec2) -> Vec3 {
    let d = concentric_disk(u);
    let z = (1.0 - d.length_squared()).max(0.0).sqrt();
    Vec3::new(d.x, d.y, z)
}

/// The pdf of [`cosine_hemisphere`] (per solid angle).
#[inline]
pub fn cosine_hemisphere_pdf(cos_theta: f32) -> f32 {
    cos_theta.max(0.0) / PI
}

/// Shirley–Chiu concentric map of the square onto the unit disk.
///
/// The angle is θ = φ = π/4 · (o_y / o_x) where |o_x| > |o_y|, and
/// θ = π/2 − φ with φ = π/4 · (o_x / o_y) elsewhere, so |φ| ≤ π/4 and the
/// point is r (cos φ, sin φ) or r (sin φ, cos φ): one polynomial pair
/// (`sin_cos_quarter`) serves the whole map, and `path`'s lanes compute
/// it eight at a time with the same operations.
#[inline]
pub fn concentric_disk(u: Vec2) -> Vec2 {
    let o = 2.0 * u - Vec2::ONE;
    if o.x == 0.0 && o.y == 0.0 {
        return Vec2::ZERO;
    }
    if o.x.abs() > o.y.abs() {
        let (sin, cos) = sin_cos_quarter(PI / 4.0 * (o.y / o.x), |c| c);
        o.x * Vec2::new(cos, sin)
    } else {
        let (sin, cos) = sin_cos_quarter(PI / 4.0 * (o.x / o.y), |c| c);
        o.y * Vec2::new(sin, cos)
    }
}

/// (sin φ, cos φ) for |φ| ≤ π/4, by the Taylor polynomials to φ⁹ and φ¹⁰
/// in Horner form (the first terms left out, φ¹¹/11! and φ¹²/12!, are
/// below 2 · 10⁻⁹ there, under f32's rounding). Generic over the number
/// type (`k` makes a constant of it), so that a lane type computes the
/// same bits as f32 does, operation for operation.
#[inline(always)]
pub(crate) fn sin_cos_quarter<T>(phi: T, k: impl Fn(f32) -> T) -> (T, T)
where
    T: Copy + std::ops::Add<Output = T> + std::ops::Mul<Output = T>,
{
    let z = phi * phi;
    let sin = phi
        + phi
            * z
            * (k(-1.0 / 6.0)
                + z * (k(1.0 / 120.0) + z * (k(-1.0 / 5040.0) + z * k(1.0 / 362_880.0))));
    let cos = k(1.0)
        + z * (k(-0.5)
            + z * (k(1.0 / 24.0)
                + z * (k(-1.0 / 720.0) + z * (k(1.0 / 40_320.0) + z * k(-1.0 / 3_628_800.0)))));
    (sin, cos)
}

/// Uniform direction on the unit sphere.
#[inline]
pub fn uniform_sphere(u: Vec2) -> Vec3 {
    let z = 1.0 - 2.0 * u.x;
    let r = (1.0 - z * z).max(0.0).sqrt();
    let phi = 2.0 * PI * u.y;
    Vec3::new(r * phi.cos(), r * phi.sin(), z)
}

/// Uniform barycentric coordinates (b1, b2) on a triangle (the square-root warp).
#[inline]
pub fn uniform_triangle(u: Vec2) -> Vec2 {
    let su = u.x.sqrt();
    Vec2::new(1.0 - su, u.y * su)
}

/// A discrete distribution sampled by its cumulative table.
#[derive(Clone, Debug, Default)]
pub struct Distribution1D {
    cdf: Vec<f64>,
    total: f64,
}

impl Distribution1D {
    /// Builds the table from non-negative weights. An all-zero table is allowed
    /// and samples nothing (`total() == 0`).
    pub fn new(weights: &[f64]) -> Self {
        let mut cdf = Vec::with_capacity(weights.len() + 1);
        let mut acc = 0.0;
        cdf.push(0.0);
        for &w in weights {
            acc += if w.is_finite() && w > 0.0 { w } else { 0.0 };
            cdf.push(acc);
        }
        Distribution1D { cdf, total: acc }
    }

    /// Sum of the weights.
    pub fn total(&self) -> f64 {
        self.total
    }

    /// Number of entries.
    pub fn len(&self) -> usize {
        self.cdf.len() - 1
    }

    /// True when there are no entries.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Probability of entry `i`.
    pub fn pmf(&self, i: usize) -> f64 {
        if self.total <= 0.0 {
            return 0.0;
        }
        (self.cdf[i + 1] - self.cdf[i]) / self.total
    }

    /// The probability [`Distribution1D::sample`] gives with each entry,
    /// as f32: the same division, made once (where the total is zero too,
    /// unlike [`Distribution1D::pmf`]'s guarded one).
    pub fn sample_pmfs_f32(&self) -> Vec<f32> {
        (0..self.len())
            .map(|i| ((self.cdf[i + 1] - self.cdf[i]) / self.total) as f32)
            .collect()
    }

    /// Picks an entry for `u` in [0,1); returns it, its probability, and `u`
    /// rescaled to [0,1) within the entry (for reuse).
    #[inline(always)]
    pub fn sample(&self, u: f64) -> (usize, f64, f64) {
        let target = u * self.total;
        // The last entry whose start is at most target: the first with
        // cdf[i+1] > target, which skips zero-width entries (the one kept
        // when target reaches the total is the last entry, as before).
        // partition_point searches without data-dependent branches.
        let lo = self
            .cdf
            .get(1..self.len())
            .map_or(0, |starts| starts.partition_point(|&c| c <= target));
        let w = self.cdf[lo + 1] - self.cdf[lo];
        let rem = if w > 0.0 {
            ((target - self.cdf[lo]) / w).clamp(0.0, 1.0 - 1e-12)
        } else {
            0.0
        };
        (lo, w / self.total, rem)
    }
}

/// The power heuristic with β = 2 (Veach), for MIS weights.
#[inline]
pub fn power_heuristic(pdf_a: f32, pdf_b: f32) -> f32 {
    let a = pdf_a * pdf_a;
    let b = pdf_b * pdf_b;
    if a + b == 0.0 {
        0.0
    } else if a.is_infinite() {
        1.0
    } else {
        a / (a + b)
    }
}

/// The complementary error function, |relative error| < 1.2e-7: the
/// Chebyshev-type fit in Press et al., Numerical Recipes, 2nd ed., §6.2.
/// (The Smith masking of Beckmann coats and the statistical tests' normal
/// tail use it.)
pub fn erfc(x: f64) -> f64 {
    let z = x.abs();
    let t = 1.0 / (1.0 + 0.5 * z);
    let poly = -z * z - 1.26551223
        + t * (1.00002368
            + t * (0.37409196
                + t * (0.09678418
                    + t * (-0.18628806
                        + t * (0.27886807
                            + t * (-1.13520398
                                + t * (1.48851587 + t * (-0.82215223 + t * 0.17087277))))))));
    let r = t * poly.exp();
    if x >= 0.0 {
        r
    } else {
        2.0 - r
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The table of f32 probabilities holds, bit for bit, what `sample`
    /// gives with each entry, zero-weight entries and a zero total too.
    #[test]
    fn sample_pmfs_are_the_probabilities_sample_gives() {
        let mut rng = Pcg32::new(5, 5);
        for weights in [vec![], vec![0.0, 0.0], vec![1.0, 0.0, 3.0, 1e-30, 7.5]] {
            let dist = Distribution1D::new(&weights);
            let table = dist.sample_pmfs_f32();
            assert_eq!(table.len(), dist.len());
            if dist.total() <= 0.0 {
                continue;
            }
            for _ in 0..1000 {
                let (i, pmf, _) = dist.sample(rng.next_f64());
                assert_eq!(table[i].to_bits(), (pmf as f32).to_bits());
            }
        }
    }

    #[test]
    fn pcg_floats_stay_below_one_and_keyed_streams_differ() {
        let mut a = Pcg32::keyed(&[1, 2, 3]);
        let mut b = Pcg32::keyed(&[1, 2, 4]);
        let mut same = 0;
        for _ in 0..1000 {
            let x = a.next_f32();
            assert!((0.0..1.0).contains(&x));
            if a.next_u32() == b.next_u32() {
                same += 1;
            }
        }
        assert!(same < 5);
    }

    /// [`concentric_disk`]'s polynomial against `f32::sin_cos` of the
    /// angle the map had before, θ = π/4 · t and θ = π/2 − π/4 · t, and
    /// against the exact (f64) sine and cosine of φ = π/4 · t, at 2²¹ + 1
    /// ratios t evenly over [−1, 1] (the whole θ range, (−π/4, 3π/4]).
    /// Measured: 1.79e-7 from `f32::sin_cos` (three ulps of [0.5, 1), 2⁻²⁴
    /// each; most of it is the old angle's own rounding: `f32::sin_cos` of
    /// the f32 π/2 − φ is up to 1.69e-7 from the exact value), and 6.57e-8
    /// from the exact value (1.1 ulps). Asserted: four ulps from
    /// `f32::sin_cos` (whose last bit depends on the platform's libm), and
    /// 1.25 ulps from the exact value (plain f32 arithmetic, the same bits
    /// everywhere). A dropped term fails it: without φ⁹/9!, 4.8e-7 from
    /// `f32::sin_cos` (checked); the φ¹⁰ term of the cosine, under half an
    /// ulp, is the one this test cannot see.
    #[test]
    fn concentric_polynomial_agrees_with_sin_cos() {
        let ulp = 1.0 / 16_777_216.0;
        let n = 1 << 20;
        let (mut from_f32, mut from_exact) = (0.0f32, 0.0f64);
        for k in -n..=n {
            let phi = PI / 4.0 * (k as f32 / n as f32);
            let (sin, cos) = sin_cos_quarter(phi, |c| c);
            for (theta, (s, c)) in [(phi, (sin, cos)), (PI / 2.0 - phi, (cos, sin))] {
                let (ts, tc) = theta.sin_cos();
                from_f32 = from_f32.max((s - ts).abs()).max((c - tc).abs());
            }
            let (es, ec) = f64::from(phi).sin_cos();
            from_exact = from_exact
                .max((f64::from(sin) - es).abs())
                .max((f64::from(cos) - ec).abs());
        }
        assert!(from_f32 <= 4.0 * ulp, "{from_f32:e} from f32::sin_cos");
        assert!(
            from_exact <= 1.25 * f64::from(ulp),
            "{from_exact:e} from the exact values"
        );
    }

    #[test]
    fn distribution_samples_in_proportion() {
        let d = Distribution1D::new(&[1.0, 0.0, 3.0]);
        assert_eq!(d.sample(0.1).0, 0);
        assert_eq!(d.sample(0.3).0, 2);
        assert!((d.pmf(2) - 0.75).abs() < 1e-12);
        assert_eq!(d.pmf(1), 0.0);
    }

    /// `sample` picks the entry the earlier search did (bisection, then a
    /// walk past zero-width entries), on tables with runs of zero weights,
    /// at every u including the ends and the cdf's own breakpoints, so that
    /// a seed gives the same image as before.
    #[test]
    fn sample_picks_the_same_entry_as_bisection() {
        fn bisect(cdf: &[f64], target: f64) -> usize {
            let len = cdf.len() - 1;
            let (mut lo, mut hi) = (0, len);
            while lo + 1 < hi {
                let mid = (lo + hi) / 2;
                if cdf[mid] <= target {
                    lo = mid;
                } else {
                    hi = mid;
                }
            }
            while lo + 1 < len && cdf[lo + 1] <= target {
                lo += 1;
            }
            lo
        }
        let tables: [&[f64]; 5] = [
            &[1.0],
            &[0.0, 1.0, 0.0, 0.0, 2.0, 0.0],
            &[3.0, 0.0, 0.0, 1.0],
            &[0.5, 0.25, 0.125, 0.0, 0.125, 7.0, 0.0, 0.0, 1e-9],
            &[0.0, 0.0, 5.0],
        ];
        let mut rng = Pcg32::keyed(&[11]);
        for w in tables {
            let d = Distribution1D::new(w);
            let mut us: Vec<f64> = d.cdf.iter().map(|c| c / d.total()).collect();
            us.extend([0.0, 1.0, 1.0 - 1e-16, f64::NAN, -0.5]);
            us.extend((0..10_000).map(|_| rng.next_f32() as f64));
            for u in us {
                assert_eq!(d.sample(u).0, bisect(&d.cdf, u * d.total()), "{w:?} u {u}");
            }
        }
    }
}
