//! Generated scenes: `kalos gen NAME -o DIR` writes one as Mitsuba 3 XML
//! plus OBJ meshes (so that Mitsuba renders it too), and `kalos bench`
//! traces one built in memory.
//!
//! Written by [`generate`] (the names are [`NAMES`]):
//!
//! - `sphereflake`: a golden Phong sphere-flake of 91 spheres (about 57k
//!   triangles) on a grey floor, under two area lights (Fig. 9 of the
//!   stochastic-iteration paper);
//! - `teapot-room`: a room with a glossy metallic teapot (Fig. 8). The teapot
//!   is a procedural approximation (a lathed body and lid, a tapered tube
//!   spout and a half-torus handle), not the Utah Bezier data;
//! - `terrain`: a fractal terrain (value-noise octaves), wavy water, a
//!   glowing moon and a constant sky (Fig. 11);
//! - `big-room`: a furnished room of about 150k triangles (after Fig. 6 of
//!   the density-estimation paper: tables, chairs, shelves full of books, a
//!   lattice of ceiling lights); the only one whose layout depends on the
//!   seed;
//! - `big-room-textured`: the same room and layout, with bitmap textures
//!   that the generator writes as PNGs beside the meshes (wood planks on the
//!   floor, wallpaper on the walls, a strip of book spines on the books),
//!   and uvs on those meshes.
//!
//! Built in memory by [`bench_scene`]: finely tessellated spheres on a
//! jittered grid inside a closed room, for the ray-core throughput of
//! `kalos bench` ([`crate::bench`]).
//!
//! A scene to write is built in memory first, then written file by file, each
//! atomically (a temporary file beside the target, renamed over it), the
//! meshes before the `scene.xml` that names them.

mod bench;
mod big_room;
mod mesh;
mod sphereflake;
mod teapot_room;
mod terrain;
mod textures;
mod xml;

use std::io::Write as _;
use std::path::{Path, PathBuf};

use image::RgbImage;

use crate::image_io::{write_atomic, write_rgb8_png, ImageIoError};

pub use bench::bench_scene;
use mesh::Mesh;

/// The scenes [`generate`] writes.
pub const NAMES: &[&str] = &[
    "sphereflake",
    "teapot-room",
    "terrain",
    "big-room",
    "big-room-textured",
];

/// Why a scene could not be generated.
#[derive(Debug, thiserror::Error)]
pub enum GenError {
    /// The name is none of [`NAMES`].
    #[error("unknown scene '{name}' (known: {known})", known = NAMES.join(", "))]
    UnknownScene {
        /// The name asked for.
        name: String,
    },
    /// A directory of the output could not be created.
    #[error("{path}: cannot create the directory", path = .path.display())]
    CreateDir {
        /// The directory.
        path: PathBuf,
        /// The underlying error.
        #[source]
        source: std::io::Error,
    },
    /// A file could not be written; `path` keeps its previous content.
    #[error("{path}: cannot write the generated file", path = .path.display())]
    Write {
        /// The file.
        path: PathBuf,
        /// What failed: creating, writing or renaming the temporary file.
        #[source]
        source: ImageIoError,
    },
}

/// Writes scene `name` (one of [`NAMES`]) into `dir`: `scene.xml` and the
/// OBJ meshes (and PNG textures) it names, creating the directories it
/// needs. `seed` picks the random layout of a scene that has one
/// (`big-room`, `big-room-textured`); the others are fixed. Returns the path of the XML file.
pub fn generate(name: &str, dir: &Path, seed: u64) -> Result<PathBuf, GenError> {
    let files = match name {
        "sphereflake" => sphereflake::build(),
        "teapot-room" => teapot_room::build(),
        "terrain" => terrain::build(),
        "big-room" => big_room::build(seed, false),
        "big-room-textured" => big_room::build(seed, true),
        other => {
            return Err(GenError::UnknownScene {
                name: other.to_string(),
            })
        }
    };
    files.write(dir)
}

/// A generated scene in memory: its meshes and textures, each with the
/// path (relative to the scene's directory) of its file, and the XML that
/// names them.
struct SceneFiles {
    meshes: Vec<(String, Mesh)>,
    images: Vec<(String, RgbImage)>,
    xml: String,
}

impl SceneFiles {
    /// Writes the meshes and textures, then `scene.xml`; returns the path
    /// of the latter.
    fn write(&self, dir: &Path) -> Result<PathBuf, GenError> {
        for (file, mesh) in &self.meshes {
            write_file(&dir.join(file), &mesh.obj_text())?;
        }
        for (file, image) in &self.images {
            let path = dir.join(file);
            create_parent(&path)?;
            write_rgb8_png(&path, image).map_err(|source| GenError::Write { path, source })?;
        }
        let path = dir.join("scene.xml");
        write_file(&path, &self.xml)?;
        Ok(path)
    }
}

/// Creates the directory `path` goes in, if it is missing.
fn create_parent(path: &Path) -> Result<(), GenError> {
    if let Some(parent) = path.parent().filter(|p| !p.as_os_str().is_empty()) {
        std::fs::create_dir_all(parent).map_err(|source| GenError::CreateDir {
            path: parent.to_path_buf(),
            source,
        })?;
    }
    Ok(())
}

/// Writes `text` to `path` atomically, creating its directory first.
fn write_file(path: &Path, text: &str) -> Result<(), GenError> {
    create_parent(path)?;
    write_atomic(path, |w| {
        w.write_all(text.as_bytes())
            .map_err(|source| ImageIoError::Io {
                path: path.to_path_buf(),
                source,
            })
    })
    .map_err(|source| GenError::Write {
        path: path.to_path_buf(),
        source,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A fresh temporary directory (removed when dropped) and a path in it
    /// that does not exist yet, for `generate` to create.
    fn scratch(name: &str) -> (tempfile::TempDir, PathBuf) {
        let tmp = tempfile::Builder::new()
            .prefix("kalos-scenegen-")
            .tempdir()
            .unwrap();
        let dir = tmp.path().join(name);
        (tmp, dir)
    }

    #[test]
    fn unknown_name_is_an_error_and_writes_nothing() {
        let (_tmp, dir) = scratch("unknown");
        let e = generate("teapot", &dir, 1).unwrap_err();
        assert!(matches!(e, GenError::UnknownScene { .. }));
        assert!(e.to_string().contains("sphereflake"), "{e}");
        assert!(!dir.exists());
    }

    #[test]
    fn writes_the_meshes_and_the_xml_and_no_temporaries() {
        let (_tmp, dir) = scratch("sphereflake");
        let xml = generate("sphereflake", &dir, 1).unwrap();
        assert_eq!(xml, dir.join("scene.xml"));
        let mut names: Vec<String> = std::fs::read_dir(&dir)
            .unwrap()
            .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
            .collect();
        names.sort();
        assert_eq!(names, ["flake.obj", "floor.obj", "scene.xml"]);
    }

    /// The diffuse reflectance under a material's `twosided` wrapper.
    fn reflectance(m: &crate::scene::Material) -> Option<&crate::scene::Texture> {
        use crate::scene::Material;
        match m {
            Material::TwoSided(inner) => reflectance(inner),
            Material::Diffuse { reflectance } => Some(reflectance),
            _ => None,
        }
    }

    #[test]
    fn the_textured_room_has_the_plain_rooms_layout_and_three_bitmaps() {
        let (_tmp, dir) = scratch("rooms");
        let plain = generate("big-room", &dir.join("plain"), 3).unwrap();
        let textured = generate("big-room-textured", &dir.join("textured"), 3).unwrap();
        for png in ["wood", "wallpaper", "spines"] {
            assert!(dir.join(format!("textured/textures/{png}.png")).is_file());
        }
        let plain = crate::scene::load(&plain).unwrap();
        let textured = crate::scene::load(&textured).unwrap();
        assert_eq!(plain.triangles.len(), textured.triangles.len());
        assert_eq!(plain.bounds(), textured.bounds());
        let bitmaps: Vec<_> = textured
            .materials
            .iter()
            .filter_map(|m| match reflectance(m) {
                Some(crate::scene::Texture::Bitmap { image, .. }) => Some(image.clone()),
                _ => None,
            })
            .collect();
        assert_eq!(bitmaps.len(), 3);
        // every textured triangle spans a range of uvs, so the lookup varies
        for (t, &shape) in textured.triangles.iter().zip(&textured.tri_shape) {
            let m = &textured.materials[textured.shapes[shape as usize].material as usize];
            if matches!(reflectance(m), Some(crate::scene::Texture::Bitmap { .. })) {
                let uv = t.map(|i| textured.uvs[i as usize]);
                assert!(uv[0] != uv[1] || uv[1] != uv[2], "{uv:?}");
            }
        }
        // the floor's texture tiles: a planked wood, not a flat colour
        let floor = bitmaps
            .iter()
            .find(|i| i.width == 512 && i.height == 512)
            .unwrap();
        let lum: Vec<f32> = floor.pixels().map(|c| c.x + c.y + c.z).collect();
        let (lo, hi) = lum
            .iter()
            .fold((f32::MAX, 0.0f32), |(a, b), &l| (a.min(l), b.max(l)));
        assert!(hi > 2.0 * lo, "{lo} {hi}");
    }

    #[test]
    fn a_file_in_the_way_is_an_error_naming_it() {
        let (_tmp, dir) = scratch("blocked");
        std::fs::create_dir_all(&dir).unwrap();
        let file = dir.join("file");
        std::fs::write(&file, "").unwrap();
        let e = generate("terrain", &file.join("out"), 1).unwrap_err();
        assert!(matches!(e, GenError::CreateDir { .. }), "{e}");
        assert!(e.to_string().contains("file"), "{e}");
    }

    #[test]
    fn a_failed_write_names_the_file_and_leaves_no_temporary() {
        let (_tmp, dir) = scratch("xml-is-a-dir");
        std::fs::create_dir_all(dir.join("scene.xml")).unwrap();
        let e = generate("sphereflake", &dir, 1).unwrap_err();
        match &e {
            GenError::Write { path, .. } => assert_eq!(path, &dir.join("scene.xml")),
            other => panic!("{other}"),
        }
        let leftovers = std::fs::read_dir(&dir)
            .unwrap()
            .filter(|e| {
                e.as_ref()
                    .unwrap()
                    .file_name()
                    .to_string_lossy()
                    .contains(".tmp-")
            })
            .count();
        assert_eq!(leftovers, 0);
    }
}
