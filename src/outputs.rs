//! The files a render or a bake names: its outputs, checked before any work
//! ([`check_output`]), the HDR images it measures against ([`read_hdr`]),
//! and its convergence log ([`write_log`]). The command line, the Python
//! package and the jobs ([`crate::job`], [`crate::bake::job`]) all check
//! and write through these, so that a bad path fails the same way, with the
//! same words, before the scene is loaded.

use std::path::{Path, PathBuf};

use crate::film::Image;
use crate::image_io::{self, ImageIoError};
use crate::methods::LogRow;
use crate::metrics;

/// A file named as an output or an input of a render that cannot serve:
/// each variant names the file.
#[derive(Debug, thiserror::Error)]
pub enum OutputError {
    /// An output whose extension is not one the command writes there.
    #[error("output '{path}' must end in {expected}", path = .path.display())]
    Extension {
        /// The file.
        path: PathBuf,
        /// The extensions allowed, in words (".exr, .pfm or .png").
        expected: String,
    },
    /// A folder that is missing or not writable, a read-only file, or a
    /// file that cannot be read ([`image_io`]'s error).
    #[error(transparent)]
    Image(#[from] ImageIoError),
    /// An image to measure or to measure against that holds display values
    /// (PNG, JPEG) rather than linear radiance.
    #[error(
        "{path}: not a linear HDR image; comparisons need .exr, .pfm or .hdr (a .{ext} holds \
         tone-mapped display values, not radiance)",
        path = .path.display()
    )]
    NotHdr {
        /// The file.
        path: PathBuf,
        /// Its extension, lower case.
        ext: String,
    },
    /// An image with NaN or infinite pixels, whose every figure would be
    /// NaN.
    #[error(
        "{path}: {bad} of its {pixels} pixels are NaN or infinite, so every figure would be NaN",
        path = .path.display()
    )]
    NonFinite {
        /// The file.
        path: PathBuf,
        /// Pixels that are not finite.
        bad: usize,
        /// All its pixels.
        pixels: usize,
    },
}

/// The lower-case extension of `path` ("" when it has none).
pub fn extension(path: &Path) -> String {
    path.extension()
        .and_then(|e| e.to_str())
        .map(str::to_ascii_lowercase)
        .unwrap_or_default()
}

/// Checks an output file before any work: its extension is one of `exts`
/// (lower case, without the dot), and it can be written there
/// ([`image_io::check_writable`]: an existing folder where a file can be
/// created, and no read-only file or folder in the way).
pub fn check_output(path: &Path, exts: &[&str]) -> Result<(), OutputError> {
    if !exts.contains(&extension(path).as_str()) {
        let list: Vec<String> = exts.iter().map(|e| format!(".{e}")).collect();
        let expected = match list.split_last() {
            Some((last, rest)) if !rest.is_empty() => format!("{} or {last}", rest.join(", ")),
            _ => list.join(""),
        };
        return Err(OutputError::Extension {
            path: path.to_path_buf(),
            expected,
        });
    }
    image_io::check_writable(path)?;
    Ok(())
}

/// Reads an image to measure or to measure against: linear radiance only
/// (EXR, PFM, Radiance HDR; a PNG or JPEG holds tone-mapped display values,
/// whose error against radiance means nothing), every pixel finite.
pub fn read_hdr(path: &Path) -> Result<Image, OutputError> {
    let ext = extension(path);
    if !matches!(ext.as_str(), "exr" | "pfm" | "hdr") {
        return Err(OutputError::NotHdr {
            path: path.to_path_buf(),
            ext,
        });
    }
    let img = image_io::read_image(path)?;
    let bad = metrics::non_finite_pixels(&img);
    if bad > 0 {
        return Err(OutputError::NonFinite {
            path: path.to_path_buf(),
            bad,
            pixels: img.data.len(),
        });
    }
    Ok(img)
}

/// The text of a convergence log: a `time_s,rays,spp,rel_mse` header, then
/// one line a row (rel_mse empty without a reference).
pub fn log_text(rows: &[LogRow]) -> String {
    let mut text = String::from("time_s,rays,spp,rel_mse\n");
    for r in rows {
        text += &format!(
            "{:.4},{},{:.3},{}\n",
            r.time_s,
            r.rays,
            r.spp,
            r.rel_mse.map(|e| format!("{e:.6e}")).unwrap_or_default()
        );
    }
    text
}

/// Writes the convergence log [`log_text`] to `path` (CSV), atomically like
/// the images: a temporary file beside the target, then a rename.
pub fn write_log(path: &Path, rows: &[LogRow]) -> Result<(), ImageIoError> {
    let text = log_text(rows);
    image_io::write_atomic(path, |w| {
        use std::io::Write as _;
        w.write_all(text.as_bytes())
            .map_err(|source| ImageIoError::Io {
                path: path.to_path_buf(),
                source,
            })
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn an_unknown_extension_is_refused_with_the_list() {
        let e = check_output(Path::new("out.txt"), &["exr", "pfm", "png"]).unwrap_err();
        assert_eq!(
            e.to_string(),
            "output 'out.txt' must end in .exr, .pfm or .png"
        );
        let e = check_output(Path::new("out"), &["glb"]).unwrap_err();
        assert_eq!(e.to_string(), "output 'out' must end in .glb");
    }

    #[test]
    fn a_missing_folder_is_refused_naming_the_output() {
        let e = check_output(Path::new("no-such-folder-kalos/x.exr"), &["exr"]).unwrap_err();
        assert!(matches!(e, OutputError::Image(_)), "{e}");
        assert!(e.to_string().contains("x.exr"), "{e}");
    }

    #[test]
    fn a_display_image_is_not_hdr() {
        let e = read_hdr(Path::new("a.PNG")).unwrap_err();
        assert!(
            e.to_string().starts_with("a.PNG: not a linear HDR image"),
            "{e}"
        );
    }

    #[test]
    fn the_log_has_a_header_and_one_line_a_row() {
        let rows = [
            LogRow {
                time_s: 1.0,
                rays: 10,
                spp: 2.0,
                rel_mse: Some(0.5),
            },
            LogRow {
                time_s: 2.5,
                rays: 20,
                spp: 4.0,
                rel_mse: None,
            },
        ];
        assert_eq!(
            log_text(&rows),
            "time_s,rays,spp,rel_mse\n1.0000,10,2.000,5.000000e-1\n2.5000,20,4.000,\n"
        );
    }
}
