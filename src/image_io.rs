//! Reading and writing images: OpenEXR and PFM for linear radiance, PNG for
//! display (tone mapped, 8-bit sRGB).
//!
//! Every write is atomic: the file is written under a temporary name in the
//! destination's directory and renamed over the destination only once it is
//! complete, so a crash or an error never leaves a half-written image, nor
//! destroys the file that was there before.
//!
//! PFM is read and written by hand (the `image` crate does not know it). The
//! layout follows `refs/README.md`: header `PF\n<w> <h>\n-1.0\n`, float32
//! little-endian, RGB interleaved, **rows bottom to top**.

use std::fs::File;
use std::io::{BufWriter, Write};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};

use glam::Vec3;
use image::{DynamicImage, ImageBuffer, ImageFormat, Rgb, RgbImage};

use crate::film::Image;

/// An error while reading or writing an image; every variant names the file.
#[derive(Debug, thiserror::Error)]
pub enum ImageIoError {
    /// The file name's extension names no format this module handles.
    #[error("{path}: unknown image format (expected {expected})", path = .path.display())]
    UnknownFormat {
        /// The file.
        path: PathBuf,
        /// The extensions that would have worked.
        expected: &'static str,
    },
    /// An operating-system error (open, write, rename).
    #[error("{path}: {source}", path = .path.display())]
    Io {
        /// The file.
        path: PathBuf,
        /// The underlying error.
        #[source]
        source: std::io::Error,
    },
    /// The `image` crate failed to encode or decode.
    #[error("{path}: {source}", path = .path.display())]
    Codec {
        /// The file.
        path: PathBuf,
        /// The underlying error.
        #[source]
        source: image::ImageError,
    },
    /// A PFM file that does not follow the format.
    #[error("{path}: malformed PFM: {reason}", path = .path.display())]
    Pfm {
        /// The file.
        path: PathBuf,
        /// What was wrong.
        reason: String,
    },
    /// An output that cannot be written where it is asked for: its folder
    /// is missing or not writable, or an existing file there is read-only.
    /// Found by [`check_writable`] before any work, and again before the
    /// rename that would replace an existing file.
    #[error("cannot write '{path}': {reason}", path = .path.display())]
    Unwritable {
        /// The user's path (never the temporary file beside it).
        path: PathBuf,
        /// What stands in the way.
        reason: String,
    },
    /// The image to write is inconsistent (pixel count differs from
    /// width × height) or empty.
    #[error("{path}: cannot write image: {reason}", path = .path.display())]
    BadImage {
        /// The file.
        path: PathBuf,
        /// What was wrong.
        reason: String,
    },
}

impl ImageIoError {
    fn io(path: &Path, source: std::io::Error) -> Self {
        ImageIoError::Io {
            path: path.to_path_buf(),
            source,
        }
    }

    fn codec(path: &Path, source: image::ImageError) -> Self {
        ImageIoError::Codec {
            path: path.to_path_buf(),
            source,
        }
    }

    fn unwritable(path: &Path, reason: impl Into<String>) -> Self {
        ImageIoError::Unwritable {
            path: path.to_path_buf(),
            reason: reason.into(),
        }
    }

    fn pfm(path: &Path, reason: impl Into<String>) -> Self {
        ImageIoError::Pfm {
            path: path.to_path_buf(),
            reason: reason.into(),
        }
    }
}

/// The curve that maps exposed linear radiance to display values in [0, 1].
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum Tonemap {
    /// Clamp each channel to [0, 1]: what the image holds, unaltered below 1.
    #[default]
    Clamp,
    /// Reinhard's x / (1 + x), per channel (Reinhard et al. 2002, eq. 3).
    Reinhard,
    /// Narkowicz's fit of the ACES filmic curve,
    /// x(2.51x + 0.03) / (x(2.43x + 0.59) + 0.14), per channel. Applied to the
    /// exposed value as is: Narkowicz suggests pre-scaling by 0.6 to match
    /// ACES's exposure, which is an exposure of −0.74 stops here.
    Aces,
}

impl Tonemap {
    /// Maps one exposed linear channel value to [0, 1].
    #[inline]
    pub fn apply(self, x: f32) -> f32 {
        let x = x.max(0.0);
        let y = match self {
            Tonemap::Clamp => x,
            Tonemap::Reinhard => x / (1.0 + x),
            Tonemap::Aces => (x * (2.51 * x + 0.03)) / (x * (2.43 * x + 0.59) + 0.14),
        };
        y.clamp(0.0, 1.0)
    }
}

/// How a linear image becomes 8-bit PNG values.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct PngOptions {
    /// Exposure in stops: the image is scaled by 2^exposure before tone
    /// mapping. Default 0.
    pub exposure: f32,
    /// The tone-mapping curve. Default [`Tonemap::Clamp`].
    pub tonemap: Tonemap,
}

/// The sRGB transfer function (IEC 61966-2-1), linear [0, 1] to encoded.
#[inline]
pub fn linear_to_srgb(c: f32) -> f32 {
    if c <= 0.003_130_8 {
        12.92 * c
    } else {
        1.055 * c.powf(1.0 / 2.4) - 0.055
    }
}

/// The inverse sRGB transfer function, encoded [0, 1] to linear.
#[inline]
pub fn srgb_to_linear(c: f32) -> f32 {
    if c <= 0.040_45 {
        c / 12.92
    } else {
        ((c + 0.055) / 1.055).powf(2.4)
    }
}

/// One linear pixel to 8-bit sRGB: exposure, tone mapping, the sRGB curve,
/// rounding. A pixel with any NaN or infinite channel becomes black, so that
/// a numerical accident shows as a dark speck rather than a white one.
#[inline]
pub fn to_srgb8(v: Vec3, opts: &PngOptions) -> [u8; 3] {
    if !v.is_finite() {
        return [0; 3];
    }
    let scale = opts.exposure.exp2();
    let q = |c: f32| (linear_to_srgb(opts.tonemap.apply(c * scale)) * 255.0).round() as u8;
    [q(v.x), q(v.y), q(v.z)]
}

/// The formats this module reads and writes, chosen by file extension.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Format {
    Exr,
    Pfm,
    Png,
    Jpeg,
    Hdr,
}

fn format_of(path: &Path) -> Option<Format> {
    let ext = path.extension()?.to_str()?.to_ascii_lowercase();
    Some(match ext.as_str() {
        "exr" => Format::Exr,
        "pfm" => Format::Pfm,
        "png" => Format::Png,
        "jpg" | "jpeg" => Format::Jpeg,
        "hdr" => Format::Hdr,
        _ => return None,
    })
}

/// Writes `img` to `path` in the format its extension names: `.exr` (32-bit
/// float RGB), `.pfm` (32-bit float RGB, little-endian, bottom row first) or
/// `.png` (8-bit sRGB through `opts`; ignored for the float formats). The
/// write is atomic (see the module docs).
pub fn write_image(path: &Path, img: &Image, opts: &PngOptions) -> Result<(), ImageIoError> {
    let format = match format_of(path) {
        Some(f @ (Format::Exr | Format::Pfm | Format::Png)) => f,
        _ => {
            return Err(ImageIoError::UnknownFormat {
                path: path.to_path_buf(),
                expected: ".exr, .pfm or .png",
            })
        }
    };
    check_image(path, img)?;
    match format {
        Format::Exr => write_exr(path, img),
        Format::Pfm => write_pfm(path, img),
        _ => write_png(path, img, opts),
    }
}

fn check_image(path: &Path, img: &Image) -> Result<(), ImageIoError> {
    let n = img.width as usize * img.height as usize;
    let reason = if n == 0 {
        format!("empty image ({}×{})", img.width, img.height)
    } else if img.data.len() != n {
        format!(
            "{} pixels for a {}×{} image",
            img.data.len(),
            img.width,
            img.height
        )
    } else {
        return Ok(());
    };
    Err(ImageIoError::BadImage {
        path: path.to_path_buf(),
        reason,
    })
}

/// The folder a file at `path` goes into ("." for a bare file name).
fn folder_of(path: &Path) -> &Path {
    match path.parent() {
        Some(d) if !d.as_os_str().is_empty() => d,
        _ => Path::new("."),
    }
}

/// The operating system's words for an error, without the path that some
/// wrappers (`tempfile`) add, so that a message names only the user's file.
fn os_words(e: &std::io::Error) -> String {
    std::io::Error::from(e.kind()).to_string()
}

/// Why an existing file at `path` must not be replaced, if it must not: it
/// is a folder, it is read-only (no write permission for anyone: the rename
/// would replace it all the same, since only the folder's permission
/// counts), or this user may not write it (a file of another user).
fn existing_refusal(path: &Path) -> Option<String> {
    let meta = std::fs::metadata(path).ok()?;
    if meta.is_dir() {
        return Some("it is a folder".into());
    }
    if meta.permissions().readonly() {
        return Some("the existing file is read-only, and kalos does not replace it".into());
    }
    // Opening for writing (without truncating) changes nothing in the file.
    match std::fs::OpenOptions::new().write(true).open(path) {
        Err(e) if e.kind() == std::io::ErrorKind::PermissionDenied => Some(format!(
            "the existing file is not writable by this user ({}), and kalos does not replace it",
            os_words(&e)
        )),
        _ => None,
    }
}

/// Checks, before any work, that a file can be written at `path`: it has a
/// file name, its folder exists and is a folder, a file can be created
/// there (a probe file is created and removed), and an existing file at
/// `path` is neither a folder, nor read-only, nor another user's. The error
/// names `path`, never the probe.
pub fn check_writable(path: &Path) -> Result<(), ImageIoError> {
    if path.file_name().is_none() {
        return Err(ImageIoError::unwritable(path, "the path has no file name"));
    }
    let dir = folder_of(path);
    match std::fs::metadata(dir) {
        Ok(m) if m.is_dir() => {}
        Ok(_) => {
            return Err(ImageIoError::unwritable(
                path,
                format!("'{}' is not a folder", dir.display()),
            ))
        }
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => {
            return Err(ImageIoError::unwritable(
                path,
                format!("the folder '{}' does not exist", dir.display()),
            ))
        }
        Err(e) => {
            return Err(ImageIoError::unwritable(
                path,
                format!(
                    "the folder '{}' cannot be read ({})",
                    dir.display(),
                    os_words(&e)
                ),
            ))
        }
    }
    if let Some(reason) = existing_refusal(path) {
        return Err(ImageIoError::unwritable(path, reason));
    }
    // The probe is removed when it is dropped.
    tempfile::Builder::new()
        .prefix(".kalos-probe-")
        .tempfile_in(dir)
        .map(drop)
        .map_err(|e| {
            ImageIoError::unwritable(
                path,
                format!(
                    "the folder '{}' is not writable ({})",
                    dir.display(),
                    os_words(&e)
                ),
            )
        })
}

/// Checks an image output before any work: a format [`write_image`]
/// writes (`.exr`, `.pfm`, `.png`), then [`check_writable`].
pub fn check_image_output(path: &Path) -> Result<(), ImageIoError> {
    match format_of(path) {
        Some(Format::Exr | Format::Pfm | Format::Png) => check_writable(path),
        _ => Err(ImageIoError::UnknownFormat {
            path: path.to_path_buf(),
            expected: ".exr, .pfm or .png",
        }),
    }
}

/// Writes `path` atomically: `write` fills a temporary file
/// `.<name>.tmp-<pid>-<n>` in the same directory, which is then renamed over
/// `path`. On any error the temporary file is removed and `path` is left as
/// it was. An existing `path` that is read-only or not writable by this
/// user is refused, not replaced (checked again just before the rename,
/// since the file may have changed while the render ran). Errors name
/// `path`, never the temporary file. (No fsync: this protects against
/// errors and interrupted runs, not against power loss.)
pub fn write_atomic<F>(path: &Path, write: F) -> Result<(), ImageIoError>
where
    F: FnOnce(&mut BufWriter<File>) -> Result<(), ImageIoError>,
{
    // A per-process counter keeps two threads writing the same name apart.
    static COUNTER: AtomicU64 = AtomicU64::new(0);

    let name = path.file_name().ok_or_else(|| {
        ImageIoError::io(
            path,
            std::io::Error::new(std::io::ErrorKind::InvalidInput, "path has no file name"),
        )
    })?;
    let dir = folder_of(path);
    let n = COUNTER.fetch_add(1, Ordering::Relaxed);
    let tmp = dir.join(format!(
        ".{}.tmp-{}-{}",
        name.to_string_lossy(),
        std::process::id(),
        n
    ));

    // Write, flush and close the temporary file, then rename it into place.
    let result = (|| {
        let file = File::create(&tmp).map_err(|e| ImageIoError::io(path, e))?;
        let mut w = BufWriter::new(file);
        write(&mut w)?;
        w.flush().map_err(|e| ImageIoError::io(path, e))?;
        drop(w);
        if let Some(reason) = existing_refusal(path) {
            return Err(ImageIoError::unwritable(path, reason));
        }
        std::fs::rename(&tmp, path).map_err(|e| ImageIoError::io(path, e))
    })();
    if result.is_err() {
        // Best effort: the temporary may not exist if creating it failed.
        let _ = std::fs::remove_file(&tmp);
    }
    result
}

fn write_exr(path: &Path, img: &Image) -> Result<(), ImageIoError> {
    let raw: Vec<f32> = img.data.iter().flat_map(|v| v.to_array()).collect();
    let buf: ImageBuffer<Rgb<f32>, Vec<f32>> = ImageBuffer::from_raw(img.width, img.height, raw)
        .ok_or_else(|| ImageIoError::BadImage {
            path: path.to_path_buf(),
            reason: "pixel count does not match the size".into(),
        })?;
    let dynamic = DynamicImage::ImageRgb32F(buf);
    write_atomic(path, |w| {
        dynamic
            .write_to(w, ImageFormat::OpenExr)
            .map_err(|e| ImageIoError::codec(path, e))
    })
}

/// The bytes of a PFM file holding `img` (3 channels, little-endian, bottom
/// row first).
pub fn encode_pfm(img: &Image) -> Vec<u8> {
    let header = format!("PF\n{} {}\n-1.0\n", img.width, img.height);
    let w = img.width as usize;
    let mut out = Vec::with_capacity(header.len() + img.data.len() * 12);
    out.extend_from_slice(header.as_bytes());
    // PFM stores the bottom row first: walk the rows from the last one up.
    for row in img.data.chunks_exact(w.max(1)).rev() {
        for v in row {
            for c in v.to_array() {
                out.extend_from_slice(&c.to_le_bytes());
            }
        }
    }
    out
}

fn write_pfm(path: &Path, img: &Image) -> Result<(), ImageIoError> {
    let bytes = encode_pfm(img);
    write_atomic(path, |w| {
        w.write_all(&bytes).map_err(|e| ImageIoError::io(path, e))
    })
}

fn write_png(path: &Path, img: &Image, opts: &PngOptions) -> Result<(), ImageIoError> {
    let raw: Vec<u8> = img.data.iter().flat_map(|&v| to_srgb8(v, opts)).collect();
    let buf =
        RgbImage::from_raw(img.width, img.height, raw).ok_or_else(|| ImageIoError::BadImage {
            path: path.to_path_buf(),
            reason: "pixel count does not match the size".into(),
        })?;
    write_rgb8_png(path, &buf)
}

/// Writes an 8-bit RGB buffer as PNG, atomically (used for plots as well).
pub fn write_rgb8_png(path: &Path, buf: &RgbImage) -> Result<(), ImageIoError> {
    write_atomic(path, |w| {
        buf.write_to(w, ImageFormat::Png)
            .map_err(|e| ImageIoError::codec(path, e))
    })
}

/// Reads a linear RGB image (row 0 at the top) from `.pfm` (by hand), or
/// through the `image` crate from `.exr`, `.hdr` (linear as stored) and
/// `.png`, `.jpg`/`.jpeg` (taken as sRGB and converted to linear; alpha is
/// dropped).
pub fn read_image(path: &Path) -> Result<Image, ImageIoError> {
    format_of(path).ok_or_else(|| unknown_read_format(path))?;
    let bytes = std::fs::read(path).map_err(|e| ImageIoError::io(path, e))?;
    decode_image(&bytes, path)
}

fn unknown_read_format(path: &Path) -> ImageIoError {
    ImageIoError::UnknownFormat {
        path: path.to_path_buf(),
        expected: ".exr, .pfm, .hdr, .png, .jpg or .jpeg",
    }
}

/// Decodes the bytes of an image file as [`read_image`] reads it: the
/// format is the one `path`'s extension names, and `path` only names the
/// file in errors. For the scene loaders, which read a scene's files
/// through [`crate::scene::FileAccess`] and decode what they read.
pub fn decode_image(bytes: &[u8], path: &Path) -> Result<Image, ImageIoError> {
    let format = format_of(path).ok_or_else(|| unknown_read_format(path))?;
    let image_format = match format {
        Format::Pfm => {
            return decode_pfm(bytes).map_err(|reason| ImageIoError::pfm(path, reason));
        }
        Format::Exr => ImageFormat::OpenExr,
        Format::Png => ImageFormat::Png,
        Format::Jpeg => ImageFormat::Jpeg,
        Format::Hdr => ImageFormat::Hdr,
    };
    let decoded = image::ImageReader::with_format(std::io::Cursor::new(bytes), image_format)
        .decode()
        .map_err(|e| ImageIoError::codec(path, e))?;
    let rgb = decoded.to_rgb32f();
    let linear = matches!(format, Format::Exr | Format::Hdr);
    let data = rgb
        .pixels()
        .map(|p| {
            let v = Vec3::from_array(p.0);
            if linear {
                v
            } else {
                Vec3::new(
                    srgb_to_linear(v.x),
                    srgb_to_linear(v.y),
                    srgb_to_linear(v.z),
                )
            }
        })
        .collect();
    Ok(Image {
        width: rgb.width(),
        height: rgb.height(),
        data,
    })
}

/// Decodes PFM bytes: `PF` (RGB) or `Pf` (grey, copied to all three
/// channels); a negative scale means little-endian, a positive one
/// big-endian. The scale's magnitude is ignored, as Mitsuba and most readers
/// do. Rows are flipped so that row 0 is the top. The error is a reason
/// without the path.
pub fn decode_pfm(bytes: &[u8]) -> Result<Image, String> {
    // Parse the header: four whitespace-separated tokens, then exactly one
    // whitespace byte before the raster.
    let mut pos = 0;
    let mut token = || -> Result<&[u8], String> {
        while pos < bytes.len() && bytes[pos].is_ascii_whitespace() {
            pos += 1;
        }
        let start = pos;
        while pos < bytes.len() && !bytes[pos].is_ascii_whitespace() {
            pos += 1;
        }
        if start == pos {
            return Err("header ends early".into());
        }
        Ok(&bytes[start..pos])
    };
    let channels = match token()? {
        b"PF" => 3,
        b"Pf" => 1,
        other => {
            return Err(format!(
                "magic is {:?}, expected \"PF\" or \"Pf\"",
                String::from_utf8_lossy(&other[..other.len().min(8)])
            ))
        }
    };
    let mut number = |what: &str| -> Result<String, String> {
        let t = token()?;
        std::str::from_utf8(t)
            .map(str::to_owned)
            .map_err(|_| format!("{what} is not text"))
    };
    let width: u32 = number("width")?
        .parse()
        .map_err(|_| "width is not a whole number".to_string())?;
    let height: u32 = number("height")?
        .parse()
        .map_err(|_| "height is not a whole number".to_string())?;
    let scale: f64 = number("scale")?
        .parse()
        .map_err(|_| "scale is not a number".to_string())?;
    if width == 0 || height == 0 {
        return Err(format!("empty image ({width}×{height})"));
    }
    if scale == 0.0 || !scale.is_finite() {
        return Err(format!("scale {scale} gives no byte order"));
    }
    let little_endian = scale < 0.0;
    if pos >= bytes.len() || !bytes[pos].is_ascii_whitespace() {
        return Err("no whitespace after the scale".into());
    }
    let raster = &bytes[pos + 1..];

    // Read the raster, bottom row first, into a top-first image.
    let (w, h) = (width as usize, height as usize);
    let needed = w
        .checked_mul(h)
        .and_then(|n| n.checked_mul(channels * 4))
        .ok_or("size overflows")?;
    if raster.len() < needed {
        return Err(format!(
            "raster has {} bytes, {}×{}×{} floats need {}",
            raster.len(),
            width,
            height,
            channels,
            needed
        ));
    }
    let float = |i: usize| {
        let b: [u8; 4] = raster[4 * i..4 * i + 4].try_into().unwrap_or_default();
        if little_endian {
            f32::from_le_bytes(b)
        } else {
            f32::from_be_bytes(b)
        }
    };
    let mut data = vec![Vec3::ZERO; w * h];
    for file_row in 0..h {
        let y = h - 1 - file_row;
        for x in 0..w {
            let i = (file_row * w + x) * channels;
            data[y * w + x] = if channels == 3 {
                Vec3::new(float(i), float(i + 1), float(i + 2))
            } else {
                Vec3::splat(float(i))
            };
        }
    }
    Ok(Image {
        width,
        height,
        data,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn srgb_curve_round_trips_and_hits_known_values() {
        assert_eq!(linear_to_srgb(0.0), 0.0);
        assert!((linear_to_srgb(1.0) - 1.0).abs() < 1e-6);
        // 18 % grey encodes to 118/255 in sRGB.
        assert_eq!((linear_to_srgb(0.18) * 255.0).round() as u8, 118);
        for i in 0..=100 {
            let c = i as f32 / 100.0;
            assert!((srgb_to_linear(linear_to_srgb(c)) - c).abs() < 1e-5);
        }
    }

    #[test]
    fn tonemaps_are_monotone_and_bounded() {
        for t in [Tonemap::Clamp, Tonemap::Reinhard, Tonemap::Aces] {
            let mut prev = t.apply(0.0);
            assert!(prev.abs() < 1e-6, "{t:?}(0) = {prev}");
            for i in 1..1000 {
                let y = t.apply(i as f32 * 0.05);
                assert!(y >= prev && y <= 1.0, "{t:?}");
                prev = y;
            }
        }
        assert_eq!(Tonemap::Reinhard.apply(1.0), 0.5);
        assert_eq!(Tonemap::Clamp.apply(-3.0), 0.0);
    }

    #[test]
    fn non_finite_pixels_are_black() {
        let o = PngOptions::default();
        assert_eq!(to_srgb8(Vec3::new(f32::NAN, 1.0, 1.0), &o), [0; 3]);
        assert_eq!(to_srgb8(Vec3::new(1.0, f32::INFINITY, 1.0), &o), [0; 3]);
        assert_eq!(to_srgb8(Vec3::ONE, &o), [255; 3]);
        let half = PngOptions {
            exposure: -1.0,
            ..o
        };
        assert_eq!(to_srgb8(Vec3::ONE, &half), [188; 3]);
    }

    #[test]
    fn pfm_big_endian_and_grey() {
        // 2×1 grey, big-endian: file row 0 is the bottom row (only one here).
        let mut b = b"Pf\n2 1\n1.0\n".to_vec();
        b.extend_from_slice(&1.5f32.to_be_bytes());
        b.extend_from_slice(&(-2.0f32).to_be_bytes());
        let img = decode_pfm(&b).unwrap();
        assert_eq!((img.width, img.height), (2, 1));
        assert_eq!(img.data, vec![Vec3::splat(1.5), Vec3::splat(-2.0)]);

        assert!(decode_pfm(b"P6\n1 1\n-1.0\n").is_err());
        assert!(decode_pfm(b"PF\n1 1\n-1.0\n\0\0").is_err());
        assert!(decode_pfm(b"PF\n1 1\n0\n\0\0\0\0\0\0\0\0\0\0\0\0").is_err());
    }
}
