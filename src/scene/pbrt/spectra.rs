//! Spectrum-valued parameters to RGB: `rgb`, `blackbody`, `spectrum`
//! (λ/value pairs, a named spectrum, or a file of pairs), and named
//! textures by `texture`.
//!
//! How a spectrum becomes RGB (kalos renders in linear sRGB):
//!
//! - `rgb` values are taken as they are.
//! - A reflectance or an index of refraction given as a spectrum (pairs,
//!   a file such as `spds/Au.eta.spd`) is integrated against the CIE 1931
//!   matching functions and mapped to sRGB with each channel normalised so
//!   that a constant spectrum gives that constant (the conversion the
//!   Mitsuba loader uses, `mitsuba::tables::spectrum_to_rgb`).
//! - An emission spectrum (pairs, a file, `blackbody`, `stdillum-A`) is
//!   converted to CIE XYZ and then to sRGB without white balance, and scaled
//!   to luminance 1, because pbrt-v4 divides every light's spectrum by its
//!   luminance before applying `scale` ("1 nit" per unit of scale). An `rgb`
//!   emission keeps its values: pbrt normalises only the illuminant under
//!   it, so `"rgb L" [1 1 1]` is radiance 1.
//! - Named spectra: `metal-{Ag,Al,Au,Cu}-{eta,k}` take the RGB values of
//!   the Mitsuba loader's conductor table; `glass-*` take their index at the
//!   sodium d line (kalos's dielectrics have one index, no dispersion);
//!   `stdillum-D65` is white and `stdillum-A` a 2856 K blackbody. Any other
//!   name is an error that lists these.

use std::path::Path;

use pbrt4::param::ParamType;

use super::lexer::{Param, Values};
use super::params::Params;
use super::Ctx;
use crate::scene::access::{AccessError, FileAccess, FileKind};
use crate::scene::mitsuba::tables::{conductor_table, spectrum_to_rgb};
use crate::scene::{luminance, Rgb, SceneError, Texture};

type Result<T> = std::result::Result<T, SceneError>;

/// What a spectrum stands for, which decides its conversion.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(super) enum Kind {
    /// An albedo in [0, 1].
    Reflectance,
    /// Indices of refraction, scales: any non-negative value.
    Unbounded,
    /// Emitted radiance, normalised to luminance 1 unless given as `rgb`.
    Illuminant,
}

/// Indices of refraction of pbrt-v4's named glasses at 587.6 nm.
const GLASSES: &[(&str, f32)] = &[
    ("glass-BK7", 1.5168),
    ("glass-BAF10", 1.6700),
    ("glass-FK51A", 1.4866),
    ("glass-LASF9", 1.8503),
    ("glass-F5", 1.6034),
    ("glass-F10", 1.6200),
    ("glass-F11", 1.6209),
];

/// The named spectra kalos knows, for messages.
const KNOWN: &str = "metal-Ag/Al/Au/Cu-eta/-k, glass-BK7/BAF10/FK51A/LASF9/F5/F10/F11, \
                     stdillum-D65, stdillum-A";

/// sRGB of the equal-energy spectrum without white balance (XYZ = 1, 1, 1
/// through the sRGB matrix): what undoes the per-channel normalisation of
/// `spectrum_to_rgb` for an emitter.
const EQUAL_ENERGY_SRGB: Rgb = Rgb::new(1.204_784, 0.948_301, 0.908_842);

/// A (λ, value) spectrum to RGB by its kind.
fn pairs_to_rgb(pairs: &[(f32, f32)], kind: Kind) -> Rgb {
    let rgb = spectrum_to_rgb(pairs);
    match kind {
        Kind::Illuminant => to_unit_luminance(rgb * EQUAL_ENERGY_SRGB),
        _ => rgb,
    }
}

fn to_unit_luminance(c: Rgb) -> Rgb {
    let y = luminance(c);
    if y > 0.0 && y.is_finite() {
        c / y
    } else {
        Rgb::ZERO
    }
}

/// A blackbody of temperature `t` kelvin as RGB of luminance 1.
pub(super) fn blackbody(t: f64) -> Rgb {
    let pairs: Vec<(f32, f32)> = (360..=830)
        .step_by(5)
        .map(|l| {
            let lm = l as f64 * 1e-9;
            let (c, h, kb) = (299_792_458.0f64, 6.626_069_57e-34f64, 1.380_648_8e-23f64);
            let le = 2.0 * h * c * c / (lm.powi(5) * (((h * c) / (lm * kb * t)).exp() - 1.0));
            (l as f32, le as f32)
        })
        .collect();
    let peak = pairs.iter().map(|p| p.1).fold(0.0f32, f32::max);
    let pairs: Vec<(f32, f32)> = pairs
        .iter()
        .map(|(l, v)| (*l, v / peak.max(f32::MIN_POSITIVE)))
        .collect();
    pairs_to_rgb(&pairs, Kind::Illuminant)
}

/// The index of refraction of a named glass.
pub(super) fn glass_ior(name: &str) -> Option<f32> {
    GLASSES.iter().find(|(n, _)| *n == name).map(|(_, v)| *v)
}

/// A named spectrum as RGB.
fn named(name: &str, kind: Kind) -> Option<Rgb> {
    if let Some(rest) = name.strip_prefix("metal-") {
        let (metal, part) = rest.rsplit_once('-')?;
        let (eta, k) = conductor_table(metal).filter(|_| metal != "none")?;
        return match part {
            "eta" => Some(eta),
            "k" => Some(k),
            _ => None,
        };
    }
    if let Some(v) = glass_ior(name) {
        return Some(Rgb::splat(v));
    }
    match (name, kind) {
        ("stdillum-D65", _) => Some(Rgb::ONE),
        ("stdillum-A", _) => Some(blackbody(2856.0)),
        _ => None,
    }
}

/// Reads a spectrum file: whitespace-separated λ/value pairs, `#` comments.
fn read_spd(cx: &Ctx, line: u32, file: &str) -> Result<Vec<(f32, f32)>> {
    let path = cx.resolve(file);
    let bytes = read_file(&cx.access, &path, FileKind::Spectrum).map_err(|e| {
        if crate::scene::mitsuba::files::not_found(&e) {
            cx.err(
                line,
                format!(
                    "`{file}` is neither a named spectrum ({KNOWN}) nor a spectrum file (looked for {})",
                    path.display()
                ),
            )
        } else {
            cx.err(line, format!("cannot read spectrum file `{file}`: {e}"))
        }
    })?;
    let text = utf8(bytes).map_err(|m| {
        cx.err(
            line,
            format!("cannot read spectrum file `{}`: {m}", path.display()),
        )
    })?;
    let mut nums = Vec::new();
    for (i, l) in text.lines().enumerate() {
        let l = l.split('#').next().unwrap_or("");
        for w in l.split_whitespace() {
            match w.parse::<f32>() {
                Ok(v) if v.is_finite() => nums.push(v),
                _ => {
                    return Err(SceneError::new(
                        &path,
                        i as u32 + 1,
                        format!("expected a number in the spectrum file, found `{w}`"),
                    ))
                }
            }
        }
    }
    pairs_from(&nums).map_err(|m| SceneError::new(&path, 0, m))
}

/// λ/value pairs from a flat list: an even count, λ increasing.
fn pairs_from(nums: &[f32]) -> std::result::Result<Vec<(f32, f32)>, String> {
    if nums.len() < 2 || !nums.len().is_multiple_of(2) {
        return Err(format!(
            "a spectrum needs wavelength/value pairs, found {} numbers",
            nums.len()
        ));
    }
    let pairs: Vec<(f32, f32)> = nums.chunks_exact(2).map(|c| (c[0], c[1])).collect();
    if pairs.windows(2).any(|w| w[1].0 <= w[0].0) {
        return Err("the wavelengths of a spectrum must increase".into());
    }
    Ok(pairs)
}

/// Reads a file of `kind` through `access`, decompressing it when its name
/// ends in `.gz` (pbrt-v4 scenes ship gzip-compressed `.pbrt.gz` and
/// `.ply.gz` files); the decompressed bytes are held to `kind`'s limit.
pub(super) fn read_file(
    access: &FileAccess,
    path: &Path,
    kind: FileKind,
) -> std::result::Result<Vec<u8>, AccessError> {
    let bytes = access.read(path, kind)?;
    gunzip(access, path, bytes, kind)
}

/// `bytes` read from `path`, decompressed when its name ends in `.gz`.
pub(super) fn gunzip(
    access: &FileAccess,
    path: &Path,
    bytes: Vec<u8>,
    kind: FileKind,
) -> std::result::Result<Vec<u8>, AccessError> {
    if !path
        .extension()
        .is_some_and(|e| e.eq_ignore_ascii_case("gz"))
    {
        return Ok(bytes);
    }
    access.gunzip(path, &bytes, kind).map_err(|e| match e {
        AccessError::Io { named, source } => AccessError::Io {
            named,
            source: std::io::Error::new(source.kind(), format!("not a valid gzip file ({source})")),
        },
        e => e,
    })
}

/// Bytes read from a file as UTF-8 text; the error is a reason.
pub(super) fn utf8(bytes: Vec<u8>) -> std::result::Result<String, String> {
    String::from_utf8(bytes).map_err(|_| "not UTF-8 text".to_string())
}

/// A spectrum parameter's value as RGB (not a texture).
pub(super) fn spectrum_value(cx: &Ctx, p: &Param, what: &str, kind: Kind) -> Result<Rgb> {
    let rgb = match (&p.ty, &p.values) {
        (ParamType::Rgb, Values::Nums(v)) => match v.as_slice() {
            [r, g, b] => Rgb::new(*r as f32, *g as f32, *b as f32),
            _ => {
                return Err(cx.err(
                    p.line,
                    format!(
                        "`rgb {}` of {what} takes 3 numbers, found {}",
                        p.name,
                        v.len()
                    ),
                ))
            }
        },
        (ParamType::Blackbody, Values::Nums(v)) => match v.as_slice() {
            [t] if *t > 0.0 => blackbody(*t),
            _ => {
                return Err(cx.err(
                    p.line,
                    format!(
                        "`blackbody {}` of {what} takes one positive temperature in kelvin",
                        p.name
                    ),
                ))
            }
        },
        (ParamType::Spectrum, Values::Nums(v)) => {
            let v: Vec<f32> = v.iter().map(|x| *x as f32).collect();
            let pairs = pairs_from(&v)
                .map_err(|m| cx.err(p.line, format!("`spectrum {}` of {what}: {m}", p.name)))?;
            pairs_to_rgb(&pairs, kind)
        }
        (ParamType::Spectrum, Values::Strs(v)) if v.len() == 1 => match named(&v[0], kind) {
            Some(c) => c,
            None => pairs_to_rgb(&read_spd(cx, p.line, &v[0])?, kind),
        },
        (ParamType::Float, Values::Nums(v)) if v.len() == 1 && kind != Kind::Illuminant => {
            Rgb::splat(v[0] as f32)
        }
        _ => {
            return Err(cx.err(
                p.line,
                format!(
                    "parameter `{}` of {what} has type `{}`; expected rgb, spectrum or blackbody",
                    p.name, p.ty_name
                ),
            ))
        }
    };
    if !rgb.is_finite() || rgb.min_element() < 0.0 {
        return Err(cx.err(
            p.line,
            format!(
                "`{}` of {what} must be finite and non-negative, found {rgb}",
                p.name
            ),
        ));
    }
    if kind == Kind::Reflectance && rgb.max_element() > 1.0 {
        return Err(cx.err(
            p.line,
            format!(
                "reflectance `{}` of {what} must be at most 1, found {rgb}",
                p.name
            ),
        ));
    }
    Ok(rgb)
}

impl Ctx {
    /// A spectrum-or-texture parameter: `rgb`/`spectrum`/`blackbody` give
    /// a constant, `texture` names a texture defined earlier.
    pub(super) fn color(
        &self,
        ps: &mut Params<'_>,
        name: &str,
        kind: Kind,
        textures: &std::collections::HashMap<String, Texture>,
    ) -> Result<Option<Texture>> {
        let Some(p) = ps.take(name) else {
            return Ok(None);
        };
        if p.ty == ParamType::Texture {
            let Values::Strs(v) = &p.values else {
                return Err(self.err(p.line, format!("`texture {name}` takes a texture name")));
            };
            let [t] = v.as_slice() else {
                return Err(self.err(p.line, format!("`texture {name}` takes one texture name")));
            };
            return textures.get(t).cloned().map(Some).ok_or_else(|| {
                self.err(
                    p.line,
                    format!("no texture named \"{t}\" is defined before this line"),
                )
            });
        }
        spectrum_value(self, p, &ps.what, kind).map(|c| Some(Texture::Constant(c)))
    }

    /// A float-or-texture parameter (roughness, amount): a textured one is
    /// replaced by its mean, with a warning.
    pub(super) fn scalar(
        &self,
        ps: &mut Params<'_>,
        name: &str,
        default: f32,
        textures: &std::collections::HashMap<String, Texture>,
        warnings: &mut Vec<String>,
    ) -> Result<f32> {
        if ps
            .list
            .iter()
            .any(|p| p.name == name && p.ty == ParamType::Texture)
        {
            let line = ps.line;
            let t = self
                .color(ps, name, Kind::Unbounded, textures)?
                .unwrap_or(Texture::Constant(Rgb::ZERO));
            if let Texture::Constant(c) = t {
                return Ok(c.x);
            }
            warnings.push(self.at(
                line,
                format!("textured `{name}` of {} replaced by its mean", ps.what),
            ));
            return Ok(t.mean().x);
        }
        ps.float(self, name, default)
    }
}
