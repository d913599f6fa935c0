//! Error against a reference, and variance across seeds.
//!
//! All sums are in f64. The relative MSE is the one `refs/README.md` defines
//! for the Mitsuba references: the mean over pixels and channels of
//! (a − r)² / (r² + 0.01), the 0.01 keeping dark pixels from dominating.

use glam::{DVec3, Vec3};

use crate::film::Image;

/// The ε in the denominators of [`rel_mse`] (r² + ε) and [`rel_l1`]
/// (|r| + ε), as in `refs/README.md`.
pub const EPSILON: f64 = 0.01;

/// An error from comparing images.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum MetricsError {
    /// The two images differ in size.
    #[error("image sizes differ: {a_width}×{a_height} against {b_width}×{b_height}")]
    SizeMismatch {
        /// Width of the first image.
        a_width: u32,
        /// Height of the first image.
        a_height: u32,
        /// Width of the second image.
        b_width: u32,
        /// Height of the second image.
        b_height: u32,
    },
    /// An image has no pixels, or its pixel count is not width × height.
    #[error("image {width}×{height} has {len} pixels")]
    BadImage {
        /// Width.
        width: u32,
        /// Height.
        height: u32,
        /// Number of pixels held.
        len: usize,
    },
    /// A statistic that needs data had none (e.g. a variance from fewer than
    /// two images, or a relative error where every reference value is 0).
    #[error("not enough data: {0}")]
    NotEnoughData(&'static str),
    /// A figure came out NaN or infinite (an image holds a NaN or
    /// infinite pixel: the f64 sums cannot overflow from f32 values): it is
    /// refused rather than reported.
    #[error("{0} is not a finite number (an image holds NaN or infinite pixels)")]
    NotFinite(&'static str),
}

/// The number of pixels of `img` with a NaN or infinite channel: an image
/// that holds any cannot be compared (every mean over it is NaN).
pub fn non_finite_pixels(img: &Image) -> usize {
    img.data.iter().filter(|p| !p.is_finite()).count()
}

fn check_one(img: &Image) -> Result<(), MetricsError> {
    let n = img.width as usize * img.height as usize;
    if n == 0 || img.data.len() != n {
        return Err(MetricsError::BadImage {
            width: img.width,
            height: img.height,
            len: img.data.len(),
        });
    }
    Ok(())
}

fn check_pair(a: &Image, b: &Image) -> Result<(), MetricsError> {
    check_one(a)?;
    check_one(b)?;
    if a.width != b.width || a.height != b.height {
        return Err(MetricsError::SizeMismatch {
            a_width: a.width,
            a_height: a.height,
            b_width: b.width,
            b_height: b.height,
        });
    }
    Ok(())
}

/// The mean over all pixels and channels of `f(a, b)`, in f64.
fn mean_over_channels(a: &Image, b: &Image, f: impl Fn(f64, f64) -> f64) -> f64 {
    let sum: f64 = a
        .data
        .iter()
        .zip(&b.data)
        .map(|(pa, pb)| {
            let (pa, pb) = (pa.as_dvec3(), pb.as_dvec3());
            f(pa.x, pb.x) + f(pa.y, pb.y) + f(pa.z, pb.z)
        })
        .sum();
    sum / (3 * a.data.len()) as f64
}

/// Relative MSE of `img` against `reference`: the mean over pixels and
/// channels of (a − r)² / (r² + 0.01) (`refs/README.md`). A non-finite pixel
/// in `img` makes the result non-finite, on purpose.
pub fn rel_mse(img: &Image, reference: &Image) -> Result<f64, MetricsError> {
    check_pair(img, reference)?;
    Ok(mean_over_channels(img, reference, |a, r| {
        (a - r) * (a - r) / (r * r + EPSILON)
    }))
}

/// Half-versus-half relative MSE of two independent estimates: the mean of
/// (a − b)² / (m² + 0.01) with m = (a + b)/2, as `refs/README.md` computes
/// it for the references. The error of m itself is about a quarter of this.
pub fn rel_mse_pair(a: &Image, b: &Image) -> Result<f64, MetricsError> {
    check_pair(a, b)?;
    Ok(mean_over_channels(a, b, |a, b| {
        let m = 0.5 * (a + b);
        (a - b) * (a - b) / (m * m + EPSILON)
    }))
}

/// Root-mean-square error over pixels and channels.
pub fn rmse(img: &Image, reference: &Image) -> Result<f64, MetricsError> {
    check_pair(img, reference)?;
    Ok(mean_over_channels(img, reference, |a, r| (a - r) * (a - r)).sqrt())
}

/// Relative L1 error: the mean over pixels and channels of
/// |a − r| / (|r| + 0.01).
pub fn rel_l1(img: &Image, reference: &Image) -> Result<f64, MetricsError> {
    check_pair(img, reference)?;
    Ok(mean_over_channels(img, reference, |a, r| {
        (a - r).abs() / (r.abs() + EPSILON)
    }))
}

/// Plain mean absolute relative error, |a − r| / |r| with no ε, averaged
/// over the pixel channels whose reference is not zero (where the ratio is
/// undefined). Dark pixels weigh heavily: prefer [`rel_l1`] for ranking.
pub fn mean_abs_rel_error(img: &Image, reference: &Image) -> Result<f64, MetricsError> {
    check_pair(img, reference)?;
    let (mut sum, mut n) = (0.0f64, 0u64);
    for (pa, pr) in img.data.iter().zip(&reference.data) {
        for (a, r) in pa
            .as_dvec3()
            .to_array()
            .into_iter()
            .zip(pr.as_dvec3().to_array())
        {
            if r != 0.0 {
                sum += (a - r).abs() / r.abs();
                n += 1;
            }
        }
    }
    if n == 0 {
        return Err(MetricsError::NotEnoughData("every reference value is zero"));
    }
    Ok(sum / n as f64)
}

/// The mean over all pixels of each channel, in f64 (the "channel means" of
/// `refs/README.md`). Zero for an image with no pixels.
pub fn channel_means(img: &Image) -> DVec3 {
    if img.data.is_empty() {
        return DVec3::ZERO;
    }
    let sum: DVec3 = img.data.iter().map(|v| v.as_dvec3()).sum();
    sum / img.data.len() as f64
}

/// Stops of the viridis colour map (matplotlib's, sampled at 0, ¼, ½, ¾, 1),
/// as display sRGB values.
const VIRIDIS: [[f32; 3]; 5] = [
    [0.267_004, 0.004_874, 0.329_415],
    [0.229_739, 0.322_361, 0.545_706],
    [0.127_568, 0.566_949, 0.550_556],
    [0.369_214, 0.788_888, 0.382_914],
    [0.993_248, 0.906_157, 0.143_936],
];

/// The viridis-like ramp at `t` in [0, 1], as a *linear* colour, so that the
/// sRGB PNG writer shows the intended display colour.
fn ramp(t: f32) -> Vec3 {
    let s = t.clamp(0.0, 1.0) * (VIRIDIS.len() - 1) as f32;
    let i = (s.floor() as usize).min(VIRIDIS.len() - 2);
    let f = s - i as f32;
    let (a, b) = (Vec3::from(VIRIDIS[i]), Vec3::from(VIRIDIS[i + 1]));
    let srgb = a + (b - a) * f;
    Vec3::new(
        crate::image_io::srgb_to_linear(srgb.x),
        crate::image_io::srgb_to_linear(srgb.y),
        crate::image_io::srgb_to_linear(srgb.z),
    )
}

/// A false-colour map of the per-pixel relative squared error (the mean over
/// the three channels of (a − r)² / (r² + 0.01), i.e. each pixel's share of
/// [`rel_mse`]), on a viridis-like ramp with a log scale: 1e-4 or less is
/// dark blue-violet, 1 or more is yellow, each decade a quarter of the
/// ramp. Pixels whose error is NaN or infinite are magenta, a colour the ramp
/// never takes.
pub fn false_color_error(img: &Image, reference: &Image) -> Result<Image, MetricsError> {
    check_pair(img, reference)?;
    const LOG_MIN: f64 = -4.0;
    const LOG_MAX: f64 = 0.0;
    let data = img
        .data
        .iter()
        .zip(&reference.data)
        .map(|(pa, pr)| {
            let (a, r) = (pa.as_dvec3(), pr.as_dvec3());
            let d = a - r;
            let e = (d * d / (r * r + EPSILON)).element_sum() / 3.0;
            if !e.is_finite() {
                return Vec3::new(1.0, 0.0, 1.0);
            }
            let t = if e > 0.0 {
                (e.log10() - LOG_MIN) / (LOG_MAX - LOG_MIN)
            } else {
                0.0
            };
            ramp(t as f32)
        })
        .collect();
    Ok(Image {
        width: img.width,
        height: img.height,
        data,
    })
}

/// Per-pixel mean and variance across independent renders (seeds), by
/// Welford's online update in f64, for variance and variance-ratio
/// experiments.
#[derive(Clone, Debug)]
pub struct PixelStats {
    width: u32,
    height: u32,
    n: u64,
    mean: Vec<DVec3>,
    /// Sum of squared deviations from the running mean (Welford's M2).
    m2: Vec<DVec3>,
}

impl PixelStats {
    /// Empty statistics for images of the given size.
    pub fn new(width: u32, height: u32) -> Self {
        let n = width as usize * height as usize;
        PixelStats {
            width,
            height,
            n: 0,
            mean: vec![DVec3::ZERO; n],
            m2: vec![DVec3::ZERO; n],
        }
    }

    /// Adds one image (one independent render). Values are taken as they are:
    /// a non-finite pixel poisons that pixel's statistics.
    pub fn add(&mut self, img: &Image) -> Result<(), MetricsError> {
        check_one(img)?;
        if img.width != self.width || img.height != self.height {
            return Err(MetricsError::SizeMismatch {
                a_width: img.width,
                a_height: img.height,
                b_width: self.width,
                b_height: self.height,
            });
        }
        self.n += 1;
        let inv_n = 1.0 / self.n as f64;
        for ((mean, m2), v) in self.mean.iter_mut().zip(&mut self.m2).zip(&img.data) {
            // Welford: delta against the old mean, times delta against the new.
            let x = v.as_dvec3();
            let delta = x - *mean;
            *mean += delta * inv_n;
            *m2 += delta * (x - *mean);
        }
        Ok(())
    }

    /// How many images have been added.
    pub fn count(&self) -> u64 {
        self.n
    }

    /// The per-pixel mean of the images added (black before any).
    pub fn mean(&self) -> Image {
        self.to_image(self.mean.iter().copied())
    }

    /// The per-pixel unbiased sample variance, M2 / (n − 1), per channel.
    pub fn variance(&self) -> Result<Image, MetricsError> {
        let k = self.unbiased_factor()?;
        Ok(self.to_image(self.m2.iter().map(|m2| *m2 * k)))
    }

    /// The unbiased variance averaged over pixels and channels: one number
    /// per method and budget, whose ratios between methods are the variance
    /// ratios of the papers' comparisons.
    pub fn mean_variance(&self) -> Result<f64, MetricsError> {
        let k = self.unbiased_factor()?;
        let sum: f64 = self.m2.iter().map(|m2| m2.element_sum()).sum();
        Ok(sum * k / (3 * self.m2.len().max(1)) as f64)
    }

    fn unbiased_factor(&self) -> Result<f64, MetricsError> {
        if self.n < 2 {
            return Err(MetricsError::NotEnoughData(
                "a variance needs at least two images",
            ));
        }
        Ok(1.0 / (self.n - 1) as f64)
    }

    fn to_image(&self, values: impl Iterator<Item = DVec3>) -> Image {
        Image {
            width: self.width,
            height: self.height,
            data: values.map(|v| v.as_vec3()).collect(),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ramp_ends_and_false_colour() {
        let lo = ramp(0.0);
        let hi = ramp(1.0);
        assert!(lo.z > lo.x && lo.z > lo.y, "low end is violet-blue: {lo}");
        assert!(hi.x > hi.z && hi.y > hi.z, "high end is yellow: {hi}");
        let r = Image {
            width: 3,
            height: 1,
            data: vec![Vec3::ONE; 3],
        };
        let a = Image {
            width: 3,
            height: 1,
            data: vec![Vec3::ONE, Vec3::splat(3.0), Vec3::splat(f32::NAN)],
        };
        let fc = false_color_error(&a, &r).unwrap();
        assert_eq!(fc.data[0], ramp(0.0));
        assert_eq!(fc.data[1], ramp(1.0));
        assert_eq!(fc.data[2], Vec3::new(1.0, 0.0, 1.0));
    }
}

/// The figures `kalos compare` reports for an image against a reference.
#[derive(Clone, Copy, Debug)]
pub struct Comparison {
    /// relMSE, as defined in `refs/README.md`.
    pub rel_mse: f64,
    /// Root mean squared error.
    pub rmse: f64,
    /// Relative L1 error.
    pub rel_l1: f64,
    /// Channel means of the image.
    pub means: DVec3,
    /// Channel means of the reference.
    pub reference_means: DVec3,
}

impl Comparison {
    /// Compares `img` with `reference` (same size). A figure that is not
    /// finite (from a NaN or infinite pixel, or an overflow) is an error,
    /// never a NaN to report.
    pub fn new(img: &Image, reference: &Image) -> Result<Self, MetricsError> {
        let c = Comparison {
            rel_mse: rel_mse(img, reference)?,
            rmse: rmse(img, reference)?,
            rel_l1: rel_l1(img, reference)?,
            means: channel_means(img),
            reference_means: channel_means(reference),
        };
        for (name, v) in [
            ("relMSE", c.rel_mse),
            ("RMSE", c.rmse),
            ("relL1", c.rel_l1),
            ("the image's mean", c.means.element_sum()),
            ("the reference's mean", c.reference_means.element_sum()),
        ] {
            if !v.is_finite() {
                return Err(MetricsError::NotFinite(name));
            }
        }
        Ok(c)
    }
}

impl std::fmt::Display for Comparison {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let (mi, mr) = (self.means, self.reference_means);
        writeln!(f, "relMSE  {:.6e}", self.rel_mse)?;
        writeln!(f, "RMSE    {:.6e}", self.rmse)?;
        writeln!(f, "relL1   {:.6e}", self.rel_l1)?;
        write!(
            f,
            "means   image ({:.6}, {:.6}, {:.6})  reference ({:.6}, {:.6}, {:.6})",
            mi.x, mi.y, mi.z, mr.x, mr.y, mr.z
        )
    }
}
