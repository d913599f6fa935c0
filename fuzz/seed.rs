//! Writes the fuzz targets' seed corpora (`corpus/<target>/`) in the
//! container format of `src/container.rs`: the small scenes of the
//! loader fuzz test (`tests/it/fuzz/cases.rs`) and the repository's scenes
//! (`scenes/`), each with the files of its folder up to [`MAX_FILE`] bytes.
//! Standard library only; `seed.sh` compiles and runs it.

#[path = "../tests/it/fuzz/cases.rs"]
mod cases;
#[allow(dead_code)]
#[path = "src/container.rs"]
mod container;

use std::collections::BTreeSet;
use std::path::{Path, PathBuf};

/// Largest side file a seed carries (bigger meshes and images are left out).
const MAX_FILE: u64 = 160 * 1024;

struct Corpora {
    root: PathBuf,
    seen: BTreeSet<Vec<u8>>,
    counts: std::collections::BTreeMap<&'static str, usize>,
}

impl Corpora {
    fn add(&mut self, target: &'static str, label: &str, input: Vec<u8>) {
        if !self.seen.insert(input.clone()) {
            return;
        }
        let dir = self.root.join(target);
        std::fs::create_dir_all(&dir).unwrap();
        let name: String = label
            .chars()
            .map(|c| {
                if c.is_ascii_alphanumeric() || c == '-' {
                    c
                } else {
                    '_'
                }
            })
            .collect();
        std::fs::write(dir.join(format!("seed-{name}")), &input).unwrap();
        *self.counts.entry(target).or_default() += 1;
    }

    /// A main file and side files as one input; refuses a side file that
    /// would be split by the marker (a binary file may hold it by chance).
    fn add_files(
        &mut self,
        target: &'static str,
        label: &str,
        main: &[u8],
        side: &[(String, Vec<u8>)],
    ) {
        let parts: Vec<(&str, &[u8])> = side
            .iter()
            .map(|(n, b)| (n.as_str(), b.as_slice()))
            .collect();
        let input = container::join(main, &parts);
        let (m, back) = container::split(&input);
        assert!(
            m == main && back.len() == side.len().min(container::MAX_FILES),
            "seed {label}: a file holds the container marker"
        );
        self.add(target, label, input);
    }
}

fn target_of(label: &str) -> &'static str {
    match label {
        "pbrt" | "pbrt-include" => "pbrt",
        "xml" | "xml-include" | "xml-obj" => "mitsuba_xml",
        "obj" | "mtl" => "obj_mtl",
        "ply-ascii" | "ply-binary" => "ply",
        "gltf" | "gltf-bin" | "glb" => "gltf",
        other => panic!("seed label {other} has no target"),
    }
}

/// Every file under `dir`, as paths relative to it, sorted.
fn files_under(dir: &Path, rel: &Path, out: &mut Vec<PathBuf>) {
    let mut entries: Vec<_> = std::fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().path())
        .collect();
    entries.sort();
    for p in entries {
        let r = rel.join(p.file_name().unwrap());
        if p.is_dir() {
            files_under(&p, &r, out);
        } else {
            out.push(r);
        }
    }
}

fn ext(p: &Path) -> String {
    p.extension()
        .and_then(|e| e.to_str())
        .unwrap_or("")
        .to_ascii_lowercase()
}

/// PLY seeds beyond the test's two: each binary byte order, every scalar
/// type of a vertex coordinate and of a face list, and the optional
/// normals and texture coordinates.
fn ply_seeds() -> Vec<(String, Vec<u8>)> {
    let v: [[f32; 3]; 4] = [
        [-1.0, 0.0, -1.0],
        [1.0, 0.0, -1.0],
        [1.0, 0.0, 1.0],
        [-1.0, 0.0, 1.0],
    ];
    let f: [[u32; 3]; 2] = [[0, 2, 1], [0, 3, 2]];
    let mut out = Vec::new();
    for (format, big) in [("binary_little_endian", false), ("binary_big_endian", true)] {
        for (coord, list, extra) in [
            ("float", "uchar int", true),
            ("double", "uchar uint", false),
            ("float32", "uint8 int32", true),
            ("float", "int ushort", false),
        ] {
            let mut h = format!("ply\nformat {format} 1.0\nelement vertex 4\n");
            for c in ["x", "y", "z"] {
                h += &format!("property {coord} {c}\n");
            }
            if extra {
                h += "property float nx\nproperty float ny\nproperty float nz\nproperty float u\nproperty float v\n";
            }
            h += &format!("element face 2\nproperty list {list} vertex_indices\nend_header\n");
            let mut b = h.into_bytes();
            let put = |b: &mut Vec<u8>, bytes: &[u8]| {
                if big {
                    b.extend(bytes.iter().rev());
                } else {
                    b.extend_from_slice(bytes);
                }
            };
            for p in &v {
                for &c in p {
                    if coord == "double" {
                        put(&mut b, &(c as f64).to_le_bytes());
                    } else {
                        put(&mut b, &c.to_le_bytes());
                    }
                }
                if extra {
                    for c in [0.0f32, 1.0, 0.0, p[0], p[2]] {
                        put(&mut b, &c.to_le_bytes());
                    }
                }
            }
            for t in &f {
                match list {
                    "int ushort" => put(&mut b, &3i32.to_le_bytes()),
                    _ => b.push(3),
                }
                for &i in t {
                    match list {
                        "int ushort" => put(&mut b, &(i as u16).to_le_bytes()),
                        _ => put(&mut b, &i.to_le_bytes()),
                    }
                }
            }
            out.push((format!("{format}-{coord}-{}", list.replace(' ', "-")), b));
        }
    }
    out
}

/// A second pbrt-v4 seed: the directives and files the test's seed leaves
/// out (an image texture, a spectrum file, Import, CoordinateSystem, a
/// gzip-free PLY with normals, cameras and transforms of other kinds).
fn pbrt_seed(repo: &Path) -> (Vec<u8>, Vec<(String, Vec<u8>)>) {
    let main = r#"Scale -1 1 1
LookAt 0 1 -4  0 0.5 0  0 1 0
CoordinateSystem "cam"
Camera "perspective" "float fov" [45] "float lensradius" 0.01 "float focaldistance" 4
Film "rgb" "integer xresolution" [16] "integer yresolution" [12] "string filename" "out.exr"
Sampler "halton" "integer pixelsamples" 4
Integrator "volpath" "integer maxdepth" 5
PixelFilter "gaussian"
ColorSpace "srgb"
Option "bool disablepixeljitter" true
WorldBegin
Attribute "light" "float scale" 1.5
LightSource "infinite" "spectrum L" "spds/lamp.spd" "float scale" 2
Import "geometry.pbrt"
Texture "img" "spectrum" "imagemap" "string filename" "tex/checker.png" "float uscale" 2 "bool invert" false
Texture "r" "float" "constant" "float value" 0.3
MakeNamedMaterial "wall" "string type" "diffuse" "texture reflectance" "img"
MakeNamedMaterial "gloss" "string type" "conductor" "texture roughness" "r" "spectrum eta" [400 0.2 500 0.5 600 0.9 700 1.1] "spectrum k" [400 3 700 4]
TransformBegin
  Rotate 30 0 1 0
  Translate 0.5 0 0.5
  NamedMaterial "gloss"
  Shape "sphere"
TransformEnd
AttributeBegin
  CoordSysTransform "cam"
  ConcatTransform [1 0 0 0  0 1 0 0  0 0 1 0  0 0 3 1]
  AreaLightSource "diffuse" "rgb L" [4 4 4] "bool twosided" true
  ReverseOrientation
  Shape "trianglemesh" "point3 P" [-1 -1 0 1 -1 0 1 1 0 -1 1 0] "integer indices" [0 1 2 0 2 3] "normal N" [0 0 1 0 0 1 0 0 1 0 0 1]
AttributeEnd
AttributeBegin
  NamedMaterial "wall"
  Transform [1 0 0 0  0 1 0 0  0 0 1 0  0 0 0 1]
  Shape "plymesh" "string filename" "meshes/quad.ply"
AttributeEnd
"#;
    let geometry = r#"AttributeBegin
  Material "coateddiffuse" "rgb reflectance" [0.2 0.3 0.4] "float roughness" 0.1 "float thickness" 0.01
  Translate 0 0.5 0
  Shape "loopsubdiv" "integer levels" 1 "point3 P" [0 0 0 1 0 0 0 1 0 0 0 1] "integer indices" [0 2 1 0 1 3 0 3 2 1 2 3]
AttributeEnd
Material "dielectric" "spectrum eta" "glass-BK7"
Shape "disk" "float radius" 0.2 "float height" 0.1
Shape "bilinearmesh" "point3 P" [0 0 0 1 0 0 0 1 0 1 1 0] "integer indices" [0 1 2 3]
"#;
    let spd = "# lamp\n400 1.0\n500 1.2\n600 1.1\n700 0.9\n";
    let ply = "ply\nformat ascii 1.0\nelement vertex 4\nproperty float x\nproperty float y\nproperty float z\nproperty float nx\nproperty float ny\nproperty float nz\nproperty float u\nproperty float v\nelement face 1\nproperty list uchar int vertex_indices\nend_header\n-2 0 -2 0 1 0 0 0\n2 0 -2 0 1 0 1 0\n2 0 2 0 1 0 1 1\n-2 0 2 0 1 0 0 1\n4 0 1 2 3\n";
    let png = std::fs::read(repo.join("scenes/cornell-box-gltf/checker-meter.png")).unwrap();
    (
        main.as_bytes().to_vec(),
        vec![
            ("geometry.pbrt".into(), geometry.as_bytes().to_vec()),
            ("spds/lamp.spd".into(), spd.as_bytes().to_vec()),
            ("meshes/quad.ply".into(), ply.as_bytes().to_vec()),
            ("tex/checker.png".into(), png),
        ],
    )
}

fn main() {
    let mut args = std::env::args().skip(1);
    let repo = PathBuf::from(args.next().expect("usage: seed REPO OUT"));
    let out = PathBuf::from(args.next().expect("usage: seed REPO OUT"));
    let mut c = Corpora {
        root: out,
        seen: BTreeSet::new(),
        counts: Default::default(),
    };

    for s in cases::seeds() {
        let main = s.files.iter().find(|f| f.name == s.main).unwrap();
        let side: Vec<(String, Vec<u8>)> = s
            .files
            .iter()
            .filter(|f| f.name != s.main)
            .map(|f| (f.name.clone(), f.bytes.clone()))
            .collect();
        let target = target_of(s.label);
        if target == "ply" {
            c.add(target, &format!("cases-{}", s.label), main.bytes.clone());
        } else {
            c.add_files(target, &format!("cases-{}", s.label), &main.bytes, &side);
        }
    }

    let (main, side) = pbrt_seed(&repo);
    c.add_files("pbrt", "directives", &main, &side);
    for (label, bytes) in ply_seeds() {
        c.add("ply", &label, bytes);
    }

    let scenes = repo.join("scenes");
    let mut dirs: Vec<_> = std::fs::read_dir(&scenes)
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| p.is_dir())
        .collect();
    dirs.sort();
    for dir in dirs {
        let mut all = Vec::new();
        files_under(&dir, Path::new(""), &mut all);
        let small: Vec<(String, Vec<u8>)> = all
            .iter()
            .filter(|r| !matches!(ext(r).as_str(), "txt" | "md"))
            .filter(|r| std::fs::metadata(dir.join(r)).unwrap().len() <= MAX_FILE)
            .map(|r| {
                (
                    r.to_str().unwrap().to_string(),
                    std::fs::read(dir.join(r)).unwrap(),
                )
            })
            .collect();
        let folder = dir.file_name().unwrap().to_str().unwrap();
        for (name, bytes) in &small {
            let target = match ext(Path::new(name)).as_str() {
                "xml" => "mitsuba_xml",
                "pbrt" => "pbrt",
                "gltf" | "glb" => "gltf",
                "obj" => "obj_mtl",
                "ply" => "ply",
                _ => continue,
            };
            let label = format!("{folder}-{name}");
            if target == "ply" {
                c.add(target, &label, bytes.clone());
                continue;
            }
            // the main file keeps its folder's other files beside it; a
            // main file in a subfolder sees them one level up, so those
            // mains are given only the files of their own subfolder
            let sub = Path::new(name).parent().unwrap_or(Path::new(""));
            let side: Vec<(String, Vec<u8>)> = small
                .iter()
                .filter(|(n, _)| n != name)
                .filter_map(|(n, b)| {
                    let r = Path::new(n).strip_prefix(sub).ok()?;
                    Some((r.to_str().unwrap().to_string(), b.clone()))
                })
                // an OBJ seed needs only its MTLs and textures
                .filter(|(n, _)| {
                    target != "obj_mtl"
                        || !matches!(ext(Path::new(n)).as_str(), "obj" | "xml" | "pbrt")
                })
                .collect();
            c.add_files(target, &label, bytes, &side);
        }
    }
    for (t, n) in &c.counts {
        println!("{t}: {n} seeds");
    }
}
