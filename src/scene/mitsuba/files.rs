//! Reading the files a scene names through its [`FileAccess`], and the
//! messages for a file that is refused or missing. Shared by the Mitsuba
//! and pbrt-v4 loaders.

use std::path::Path;

use crate::scene::access::{AccessError, FileAccess, FileKind};

/// Reads the scene file the user named (`kind` [`FileKind::Scene`]'s
/// checks: a regular file within the size limit). [`FileAccess::for_scene`]
/// admits that file even when it is a symbolic link to another folder; the
/// files it names are still held to `access`'s folders.
pub(crate) fn read_main(path: &Path, access: &FileAccess) -> Result<Vec<u8>, AccessError> {
    access.read(path, FileKind::Scene)
}

/// [`read_main`] as UTF-8 text.
pub(crate) fn read_main_text(path: &Path, access: &FileAccess) -> Result<String, AccessError> {
    let bytes = read_main(path, access)?;
    String::from_utf8(bytes).map_err(|e| AccessError::Io {
        named: path.to_path_buf(),
        source: std::io::Error::new(std::io::ErrorKind::InvalidData, e),
    })
}

/// The message for the scene file the user named that could not be read.
pub(crate) fn main_message(e: &AccessError) -> String {
    match e {
        AccessError::Io { source, .. } => format!("cannot read scene file: {source}"),
        _ => e.to_string(),
    }
}

/// True when `e` says the file does not exist.
pub(crate) fn not_found(e: &AccessError) -> bool {
    matches!(e, AccessError::Io { source, .. } if source.kind() == std::io::ErrorKind::NotFound)
}

/// The message for a file a scene names (`what`: "mesh file", ...; `name`
/// as the scene spells it) that `access` refused or could not read: a
/// missing file says where it was looked for, any other error names the
/// file and how to allow it.
pub(crate) fn message(what: &str, name: &str, e: &AccessError) -> String {
    match e {
        AccessError::Io { named, .. } if not_found(e) => {
            format!("{what} `{name}` not found (looked for {})", named.display())
        }
        _ => format!("cannot read {what} `{name}`: {e}"),
    }
}

/// The memory an image of `width` × `height` pixels takes once decoded
/// (linear RGB, `f32` per channel), for [`FileAccess::reserve`].
pub(crate) fn image_bytes(width: u32, height: u32) -> u64 {
    width as u64 * height as u64 * std::mem::size_of::<crate::scene::Rgb>() as u64
}

/// The dimensions an image file's header claims, read without decoding
/// its pixels (PFM by hand, other formats through the `image` crate); None
/// when the header cannot be read (decoding then reports why).
pub(crate) fn image_dimensions(bytes: &[u8], path: &Path) -> Option<(u32, u32)> {
    let ext = path.extension()?.to_str()?.to_ascii_lowercase();
    if ext == "pfm" {
        let head = &bytes[..bytes.len().min(256)];
        let text = String::from_utf8_lossy(head);
        let mut tokens = text.split_ascii_whitespace();
        let _magic = tokens.next()?;
        let w = tokens.next()?.parse().ok()?;
        let h = tokens.next()?.parse().ok()?;
        return Some((w, h));
    }
    let format = image::ImageFormat::from_extension(&ext)?;
    image::ImageReader::with_format(std::io::Cursor::new(bytes), format)
        .into_dimensions()
        .ok()
}

/// Reserves the memory of the decoded image `bytes` read from `path`
/// before it is decoded, naming it by `name` (as the scene spells it).
pub(crate) fn reserve_image(
    access: &FileAccess,
    bytes: &[u8],
    path: &Path,
    name: &str,
) -> Result<(), AccessError> {
    match image_dimensions(bytes, path) {
        Some((w, h)) => access.reserve(format!("image `{name}` ({w}×{h})"), image_bytes(w, h)),
        None => Ok(()),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn dimensions_come_from_the_header() -> Result<(), Box<dyn std::error::Error>> {
        let pfm = b"PF\n3 2\n-1.0\n";
        assert_eq!(image_dimensions(pfm, Path::new("a.pfm")), Some((3, 2)));
        let mut png = Vec::new();
        image::RgbImage::new(5, 4)
            .write_to(&mut std::io::Cursor::new(&mut png), image::ImageFormat::Png)?;
        assert_eq!(image_dimensions(&png, Path::new("a.png")), Some((5, 4)));
        assert_eq!(image_dimensions(b"junk", Path::new("a.png")), None);
        assert_eq!(image_bytes(5, 4), 5 * 4 * 12);
        Ok(())
    }
}
