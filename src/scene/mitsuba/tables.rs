//! Named materials (conductors, indices of refraction) and sampled spectra
//! to RGB.

use glam::{Mat3, Vec3};

use crate::scene::Rgb;

/// RGB (eta, k) of Mitsuba's named conductors, roughly integrated from their
/// spectra against the sRGB primaries (the values pbrt and Mitsuba's RGB
/// modes give). `none` is Mitsuba's default: a perfect mirror.
pub(super) const CONDUCTORS: &[(&str, [f32; 3], [f32; 3])] = &[
    ("none", [0.0, 0.0, 0.0], [1.0, 1.0, 1.0]),
    (
        "Ag",
        [0.155265, 0.116723, 0.138342],
        [4.82835, 3.12225, 2.14696],
    ),
    (
        "Al",
        [1.65746, 0.880369, 0.521229],
        [9.22387, 6.26952, 4.837],
    ),
    (
        "Au",
        [0.143119, 0.374957, 1.44248],
        [3.98316, 2.38572, 1.60322],
    ),
    ("Cr", [4.36968, 2.9167, 1.6547], [5.20643, 4.23136, 3.75495]),
    (
        "Cu",
        [0.200438, 0.924033, 1.10221],
        [3.91295, 2.45285, 2.14219],
    ),
];

pub(crate) fn conductor_table(name: &str) -> Option<(Rgb, Rgb)> {
    CONDUCTORS
        .iter()
        .find(|(n, _, _)| *n == name)
        .map(|(_, e, k)| (Rgb::from(*e), Rgb::from(*k)))
}

/// Mitsuba's named indices of refraction (`int_ior`, `ext_ior`).
pub(super) const IOR_TABLE: &[(&str, f32)] = &[
    ("vacuum", 1.0),
    ("helium", 1.000036),
    ("hydrogen", 1.000132),
    ("air", 1.000277),
    ("carbon dioxide", 1.00045),
    ("water", 1.333),
    ("acetone", 1.36),
    ("ethanol", 1.361),
    ("carbon tetrachloride", 1.461),
    ("glycerol", 1.4729),
    ("benzene", 1.501),
    ("silicone oil", 1.52045),
    ("bromine", 1.661),
    ("water ice", 1.31),
    ("fused quartz", 1.458),
    ("pyrex", 1.47),
    ("acrylic glass", 1.49),
    ("polypropylene", 1.49),
    ("bk7", 1.5046),
    ("sodium chloride", 1.544),
    ("amber", 1.55),
    ("pet", 1.575),
    ("diamond", 2.419),
];

pub(super) fn ior_table(name: &str) -> Option<f32> {
    let name = name.trim().to_ascii_lowercase();
    IOR_TABLE.iter().find(|(n, _)| *n == name).map(|(_, v)| *v)
}

/// A sampled spectrum (`(λ nm, value)` pairs, increasing λ, zero outside, as
/// Mitsuba's irregular spectrum) to linear sRGB, roughly: integrated against
/// the CIE 1931 matching functions in the multi-lobe Gaussian fit of Wyman,
/// Sloan and Shirley (2013), then normalised per channel so that a constant
/// spectrum of 1 gives RGB (1, 1, 1).
pub(crate) fn spectrum_to_rgb(pairs: &[(f32, f32)]) -> Rgb {
    fn g(l: f32, mu: f32, s1: f32, s2: f32) -> f32 {
        let t = (l - mu) / if l < mu { s1 } else { s2 };
        (-0.5 * t * t).exp()
    }
    fn xyz(l: f32) -> Vec3 {
        Vec3::new(
            1.056 * g(l, 599.8, 37.9, 31.0) + 0.362 * g(l, 442.0, 16.0, 26.7)
                - 0.065 * g(l, 501.1, 20.4, 26.2),
            0.821 * g(l, 568.8, 46.9, 40.5) + 0.286 * g(l, 530.9, 16.3, 31.1),
            1.217 * g(l, 437.0, 11.8, 36.0) + 0.681 * g(l, 459.0, 26.0, 13.8),
        )
    }
    let to_rgb = Mat3::from_cols_array(&[
        3.240454, -0.969266, 0.055643, -1.537139, 1.876011, -0.204026, -0.498531, 0.041556,
        1.057225,
    ]);
    let value = |l: f32| -> f32 {
        match pairs {
            [] => 0.0,
            [(l0, v0)] => {
                if (l - l0).abs() < 0.5 {
                    *v0
                } else {
                    0.0
                }
            }
            _ => {
                let (first, last) = (pairs[0].0, pairs[pairs.len() - 1].0);
                if l < first || l > last {
                    return 0.0;
                }
                let i = pairs
                    .partition_point(|(x, _)| *x <= l)
                    .clamp(1, pairs.len() - 1);
                let ((l0, v0), (l1, v1)) = (pairs[i - 1], pairs[i]);
                let t = ((l - l0) / (l1 - l0)).clamp(0.0, 1.0);
                v0 + t * (v1 - v0)
            }
        }
    };
    let (mut s, mut white) = (Vec3::ZERO, Vec3::ZERO);
    for l in 360..=830 {
        let l = l as f32;
        let c = xyz(l);
        s += c * value(l);
        white += c;
    }
    let (rgb, w) = (to_rgb * s, to_rgb * white);
    rgb / w
}
