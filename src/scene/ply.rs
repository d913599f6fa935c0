//! Stanford PLY meshes: `ascii`, `binary_little_endian` and
//! `binary_big_endian`.
//!
//! Reads the `vertex` element's `x y z`, optional `nx ny nz` and texture
//! coordinates (`u v`, `s t`, `texture_u texture_v` or `texture_s texture_t`),
//! and the `face` element's `vertex_indices` (or `vertex_index`) list, with any
//! scalar types. Polygons are fan-triangulated. Every other element and
//! property (lists included) is read and skipped.

use crate::scene::access::FileAccess;
use std::path::Path;

use glam::{Vec2, Vec3};

use super::shapes::MeshData;
use super::{Material, Rgb, Scene, SceneError, Texture};

/// A PLY scalar type.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Ty {
    I8,
    U8,
    I16,
    U16,
    I32,
    U32,
    F32,
    F64,
}

impl Ty {
    fn parse(s: &str) -> Option<Ty> {
        Some(match s {
            "char" | "int8" => Ty::I8,
            "uchar" | "uint8" => Ty::U8,
            "short" | "int16" => Ty::I16,
            "ushort" | "uint16" => Ty::U16,
            "int" | "int32" => Ty::I32,
            "uint" | "uint32" => Ty::U32,
            "float" | "float32" => Ty::F32,
            "double" | "float64" => Ty::F64,
            _ => return None,
        })
    }

    fn size(self) -> usize {
        match self {
            Ty::I8 | Ty::U8 => 1,
            Ty::I16 | Ty::U16 => 2,
            Ty::I32 | Ty::U32 | Ty::F32 => 4,
            Ty::F64 => 8,
        }
    }
}

#[derive(Clone, Debug)]
struct Property {
    name: String,
    /// `Some(count type)` for a list property.
    list: Option<Ty>,
    ty: Ty,
}

#[derive(Clone, Debug)]
struct Element {
    name: String,
    count: usize,
    props: Vec<Property>,
    /// The header line that declares it.
    line: u32,
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Format {
    Ascii,
    Le,
    Be,
}

/// Reads values of the body, whatever the format.
enum Reader<'a> {
    Ascii(std::str::SplitAsciiWhitespace<'a>),
    Binary {
        data: &'a [u8],
        pos: usize,
        le: bool,
    },
}

impl Reader<'_> {
    /// The next value, or `None` when the file ends early or a token is not a
    /// number.
    fn read(&mut self, ty: Ty) -> Option<f64> {
        match self {
            Reader::Ascii(tokens) => {
                let t = tokens.next()?;
                match ty {
                    Ty::F32 | Ty::F64 => t.parse::<f64>().ok(),
                    _ => t.parse::<i64>().ok().map(|v| v as f64),
                }
            }
            Reader::Binary { data, pos, le } => {
                let n = ty.size();
                let bytes = data.get(*pos..*pos + n)?;
                *pos += n;
                let mut b = [0u8; 8];
                b[..n].copy_from_slice(bytes);
                if !*le {
                    b[..n].reverse();
                }
                Some(match ty {
                    Ty::I8 => b[0] as i8 as f64,
                    Ty::U8 => b[0] as f64,
                    Ty::I16 => i16::from_le_bytes([b[0], b[1]]) as f64,
                    Ty::U16 => u16::from_le_bytes([b[0], b[1]]) as f64,
                    Ty::I32 => i32::from_le_bytes([b[0], b[1], b[2], b[3]]) as f64,
                    Ty::U32 => u32::from_le_bytes([b[0], b[1], b[2], b[3]]) as f64,
                    Ty::F32 => f32::from_le_bytes([b[0], b[1], b[2], b[3]]) as f64,
                    Ty::F64 => f64::from_le_bytes(b),
                })
            }
        }
    }
}

/// Loads a PLY file from disk.
pub fn load_ply(path: &Path, access: &FileAccess) -> Result<MeshData, SceneError> {
    let _ = access;
    let bytes = std::fs::read(path)
        .map_err(|e| SceneError::new(path, 0, format!("cannot read PLY file: {e}")))?;
    parse_ply(&bytes, path)
}

/// A standalone PLY file as a scene: one shape with Mitsuba's default
/// material (diffuse 0.5) and a synthesised camera.
pub fn load_ply_scene(path: &Path, access: &FileAccess) -> Result<Scene, SceneError> {
    let _ = access;
    let mut mesh = load_ply(path, access)?;
    if mesh.normals.is_none() {
        mesh.compute_vertex_normals();
    }
    let mut scene = Scene::empty(path.display().to_string());
    let material = scene.add_material(Material::Diffuse {
        reflectance: Texture::Constant(Rgb::splat(0.5)),
    });
    let name = path
        .file_stem()
        .map_or_else(|| "ply".to_string(), |s| s.to_string_lossy().into_owned());
    scene.add_mesh(
        name,
        &mesh.positions,
        mesh.normals.as_deref(),
        mesh.uvs.as_deref(),
        &mesh.indices,
        material,
        None,
    );
    if scene.triangles.is_empty() {
        return Err(SceneError::new(path, 0, "PLY file has no triangles"));
    }
    scene.light_if_dark(path);
    super::obj::synthesise_camera(&mut scene, path);
    Ok(scene)
}

/// Parses PLY bytes; `path` only names the file in errors.
pub fn parse_ply(bytes: &[u8], path: &Path) -> Result<MeshData, SceneError> {
    let err = |line: u32, msg: String| SceneError::new(path, line, msg);
    let (format, elements, body_start) = parse_header(bytes, path)?;
    let body = &bytes[body_start..];
    check_counts(format, &elements, body, path)?;
    let mut reader = match format {
        Format::Ascii => Reader::Ascii(
            std::str::from_utf8(body)
                .map_err(|_| err(0, "ASCII PLY body is not valid text".into()))?
                .split_ascii_whitespace(),
        ),
        Format::Le => Reader::Binary {
            data: body,
            pos: 0,
            le: true,
        },
        Format::Be => Reader::Binary {
            data: body,
            pos: 0,
            le: false,
        },
    };

    // Read the elements in order: the first `vertex` and the first `face`
    // with polygons are kept, every other one is skipped
    let mut read = Elements::default();
    for el in &elements {
        match el.name.as_str() {
            "vertex" if !read.seen_vertex => {
                read.seen_vertex = true;
                read_vertices(&mut reader, el, body.len(), &mut read, path)?;
            }
            "face" if read.faces.is_empty() => {
                read_faces(&mut reader, el, body.len(), &mut read.faces, path)?;
            }
            _ if el.props.is_empty() => {}
            _ => skip_element(&mut reader, el, path)?,
        }
    }
    if !read.seen_vertex {
        return Err(err(0, "PLY file has no vertex element".into()));
    }
    assemble(read, path)
}

/// Parses the header, line by line, up to `end_header`: the body's format,
/// the elements it declares, and where the body starts.
fn parse_header(bytes: &[u8], path: &Path) -> Result<(Format, Vec<Element>, usize), SceneError> {
    let err = |line: u32, msg: String| SceneError::new(path, line, msg);
    let mut pos = 0usize;
    let mut line_no = 0u32;
    let mut format = None;
    let mut elements: Vec<Element> = Vec::new();
    let mut ended = false;
    while pos < bytes.len() {
        let end = bytes[pos..]
            .iter()
            .position(|&b| b == b'\n')
            .map_or(bytes.len(), |i| pos + i);
        let line = String::from_utf8_lossy(&bytes[pos..end]);
        let line = line.trim_end_matches('\r');
        pos = (end + 1).min(bytes.len());
        line_no += 1;
        let words: Vec<&str> = line.split_ascii_whitespace().collect();
        if line_no == 1 {
            if words.first() != Some(&"ply") {
                return Err(err(
                    1,
                    "not a PLY file: expected `ply` on the first line".into(),
                ));
            }
            continue;
        }
        match words.as_slice() {
            [] => {}
            ["comment", ..] | ["obj_info", ..] => {}
            ["format", f, _version] => {
                format = Some(match *f {
                    "ascii" => Format::Ascii,
                    "binary_little_endian" => Format::Le,
                    "binary_big_endian" => Format::Be,
                    _ => return Err(err(line_no, format!("unknown PLY format `{f}`"))),
                })
            }
            ["element", name, count] => {
                let count = count.parse::<usize>().map_err(|_| {
                    err(
                        line_no,
                        format!("expected an element count, found `{count}`"),
                    )
                })?;
                elements.push(Element {
                    name: (*name).to_string(),
                    count,
                    props: Vec::new(),
                    line: line_no,
                });
            }
            ["property", "list", ct, it, name] => {
                let (Some(ct), Some(it)) = (Ty::parse(ct), Ty::parse(it)) else {
                    return Err(err(line_no, format!("unknown PLY type in `{line}`")));
                };
                if matches!(ct, Ty::F32 | Ty::F64) {
                    return Err(err(line_no, "a list count must be an integer type".into()));
                }
                let el = elements
                    .last_mut()
                    .ok_or_else(|| err(line_no, "property before any element".into()))?;
                el.props.push(Property {
                    name: (*name).to_string(),
                    list: Some(ct),
                    ty: it,
                });
            }
            ["property", ty, name] => {
                let ty = Ty::parse(ty)
                    .ok_or_else(|| err(line_no, format!("unknown PLY type `{ty}`")))?;
                let el = elements
                    .last_mut()
                    .ok_or_else(|| err(line_no, "property before any element".into()))?;
                el.props.push(Property {
                    name: (*name).to_string(),
                    list: None,
                    ty,
                });
            }
            ["end_header"] => {
                ended = true;
                break;
            }
            _ => return Err(err(line_no, format!("unexpected PLY header line `{line}`"))),
        }
    }
    if !ended {
        return Err(err(line_no, "PLY header has no `end_header`".into()));
    }
    let format = format.ok_or_else(|| err(0, "PLY header has no `format` line".into()))?;
    Ok((format, elements, pos))
}

/// Trusts no count beyond what the body can hold: every entry takes at
/// least its scalars' bytes (binary) or one digit and a separator per
/// value (ASCII), so a lying header is refused before anything is sized
/// from it.
fn check_counts(
    format: Format,
    elements: &[Element],
    body: &[u8],
    path: &Path,
) -> Result<(), SceneError> {
    let mut need = 0u64;
    for el in elements {
        let min_entry: u64 = el
            .props
            .iter()
            .map(|p| match (format, p.list) {
                (Format::Ascii, _) => 2,
                (_, Some(ct)) => ct.size() as u64,
                (_, None) => p.ty.size() as u64,
            })
            .sum();
        need = need.saturating_add((el.count as u64).saturating_mul(min_entry));
        if need > body.len() as u64 + 1 {
            return Err(SceneError::new(
                path,
                el.line,
                format!(
                    "element `{}` declares {} entries, but the {} bytes after the header \
                     cannot hold them: truncated file or a wrong count",
                    el.name,
                    el.count,
                    body.len()
                ),
            ));
        }
    }
    Ok(())
}

/// What the body's elements give: the vertices (positions in `mesh`, with
/// their optional normals and uvs) and the polygons.
#[derive(Default)]
struct Elements {
    mesh: MeshData,
    normals: Vec<Vec3>,
    uvs: Vec<Vec2>,
    seen_vertex: bool,
    faces: Vec<Vec<i64>>,
}

/// The error for an element the body ends in, or that holds a token that
/// is not a number.
fn truncated(el: &Element, path: &Path) -> SceneError {
    SceneError::new(
        path,
        0,
        format!(
            "PLY file is truncated or malformed in element `{}` (expected {} entries)",
            el.name, el.count
        ),
    )
}

/// Reads the `vertex` element: its positions, and its normals and uvs when
/// it has them. `body_len` bounds what is reserved, so a lying count cannot
/// make us allocate gigabytes.
fn read_vertices(
    reader: &mut Reader,
    el: &Element,
    body_len: usize,
    out: &mut Elements,
    path: &Path,
) -> Result<(), SceneError> {
    let truncated = || truncated(el, path);
    let find = |names: &[&str]| {
        names.iter().find_map(|n| {
            el.props
                .iter()
                .position(|p| p.name == *n && p.list.is_none())
        })
    };
    let (Some(ix), Some(iy), Some(iz)) = (find(&["x"]), find(&["y"]), find(&["z"])) else {
        return Err(SceneError::new(
            path,
            0,
            "PLY vertex element has no x, y, z",
        ));
    };
    let inormal = match (find(&["nx"]), find(&["ny"]), find(&["nz"])) {
        (Some(a), Some(b), Some(c)) => Some([a, b, c]),
        _ => None,
    };
    let iuv = [
        ("u", "v"),
        ("s", "t"),
        ("texture_u", "texture_v"),
        ("texture_s", "texture_t"),
    ]
    .iter()
    .find_map(|(u, v)| Some([find(&[u])?, find(&[v])?]));
    out.mesh.positions.reserve(el.count.min(body_len));
    let mut vals = vec![0.0f64; el.props.len()];
    for _ in 0..el.count {
        for (k, p) in el.props.iter().enumerate() {
            match p.list {
                None => vals[k] = reader.read(p.ty).ok_or_else(truncated)?,
                Some(ct) => skip_list(reader, ct, p.ty).ok_or_else(truncated)?,
            }
        }
        let v3 = |i: [usize; 3]| Vec3::new(vals[i[0]] as f32, vals[i[1]] as f32, vals[i[2]] as f32);
        out.mesh.positions.push(v3([ix, iy, iz]));
        if let Some(i) = inormal {
            out.normals.push(v3(i));
        }
        if let Some([iu, iv]) = iuv {
            out.uvs.push(Vec2::new(vals[iu] as f32, vals[iv] as f32));
        }
    }
    Ok(())
}

/// Reads the `face` element's `vertex_indices` (or `vertex_index`) lists
/// into `faces`, skipping its other properties. `body_len` bounds what is
/// reserved.
fn read_faces(
    reader: &mut Reader,
    el: &Element,
    body_len: usize,
    faces: &mut Vec<Vec<i64>>,
    path: &Path,
) -> Result<(), SceneError> {
    let truncated = || truncated(el, path);
    let Some(fi) = el
        .props
        .iter()
        .position(|p| p.list.is_some() && (p.name == "vertex_indices" || p.name == "vertex_index"))
    else {
        return Err(SceneError::new(
            path,
            0,
            "PLY face element has no vertex_indices list",
        ));
    };
    faces.reserve(el.count.min(body_len));
    for _ in 0..el.count {
        for (k, p) in el.props.iter().enumerate() {
            match p.list {
                Some(ct) if k == fi => {
                    let n = reader.read(ct).ok_or_else(truncated)?;
                    if !(0.0..=1e6).contains(&n) {
                        return Err(SceneError::new(path, 0, format!("bad PLY face size {n}")));
                    }
                    let mut poly = Vec::with_capacity(n as usize);
                    for _ in 0..n as usize {
                        poly.push(reader.read(p.ty).ok_or_else(truncated)? as i64);
                    }
                    faces.push(poly);
                }
                Some(ct) => skip_list(reader, ct, p.ty).ok_or_else(truncated)?,
                None => {
                    reader.read(p.ty).ok_or_else(truncated)?;
                }
            }
        }
    }
    Ok(())
}

/// Skips an element we do not use, value by value.
fn skip_element(reader: &mut Reader, el: &Element, path: &Path) -> Result<(), SceneError> {
    for _ in 0..el.count {
        for p in &el.props {
            match p.list {
                Some(ct) => skip_list(reader, ct, p.ty).ok_or_else(|| truncated(el, path))?,
                None => {
                    reader.read(p.ty).ok_or_else(|| truncated(el, path))?;
                }
            }
        }
    }
    Ok(())
}

/// Builds the mesh: fan-triangulates the faces (checking their indices)
/// and checks that the positions are finite.
fn assemble(read: Elements, path: &Path) -> Result<MeshData, SceneError> {
    let Elements {
        mut mesh,
        normals,
        uvs,
        faces,
        ..
    } = read;
    let nv = mesh.positions.len() as i64;
    for (f, poly) in faces.iter().enumerate() {
        if let Some(&bad) = poly.iter().find(|&&i| i < 0 || i >= nv) {
            return Err(SceneError::new(
                path,
                0,
                format!("PLY face {f} has vertex index {bad}, but there are {nv} vertices"),
            ));
        }
        for k in 1..poly.len().saturating_sub(1) {
            mesh.indices
                .push([poly[0] as u32, poly[k] as u32, poly[k + 1] as u32]);
        }
    }
    super::check_finite(path, "the PLY vertex element", &mesh.positions)?;
    if !normals.is_empty() {
        mesh.normals = Some(normals);
    }
    if !uvs.is_empty() {
        mesh.uvs = Some(uvs);
    }
    Ok(mesh)
}

/// Reads and drops one list property.
fn skip_list(r: &mut Reader, count_ty: Ty, ty: Ty) -> Option<()> {
    let n = r.read(count_ty)?;
    if !(0.0..=1e9).contains(&n) {
        return None;
    }
    for _ in 0..n as usize {
        r.read(ty)?;
    }
    Some(())
}
