//! Shapes: `trianglemesh`, `plymesh`, `sphere`, `disk`, `bilinearmesh`,
//! `loopsubdiv` (its control mesh), and object instances.
//!
//! Orientation follows pbrt-v4: a triangle's geometric normal comes from
//! its winding and the shape's transform as a normal transforms (a
//! mirroring transform does not turn it inside out), `ReverseOrientation`
//! flips it, and a mesh with per-vertex normals faces its normals. Area
//! lights emit on that side.

use glam::{Mat3, Mat4, Vec2, Vec3};
use pbrt4::param::ParamType;

use super::lexer::Directive;
use super::params::Params;
use super::{Builder, Result};
use crate::scene::access::FileKind;
use crate::scene::mitsuba::files;
use crate::scene::shapes::{self, MeshData};
use crate::scene::{Rgb, MAX_TRIANGLES};

/// A shape's geometry: a mesh already in world space, or a sphere waiting
/// for the whole scene to choose its tessellation.
#[derive(Clone, Debug)]
pub(super) enum Geom {
    Mesh(MeshData),
    Sphere {
        radius: f32,
        to_world: Mat4,
        reverse: bool,
    },
}

/// A shape ready to add (or to copy under an instance's transform).
#[derive(Clone, Debug)]
pub(super) struct Built {
    name: String,
    geom: Geom,
    material: u32,
    emission: Option<Rgb>,
}

/// The bytes a mesh takes in the scene: per vertex a position, a normal
/// and a uv, per triangle its indices and its shape.
fn mesh_bytes(m: &MeshData) -> u64 {
    let vertex = 2 * std::mem::size_of::<Vec3>() + std::mem::size_of::<Vec2>();
    let triangle = std::mem::size_of::<[u32; 3]>() + std::mem::size_of::<u32>();
    (m.positions.len() * vertex + m.indices.len() * triangle) as u64
}

/// Puts an object-space mesh into world space with pbrt's orientation (see
/// the module doc).
fn orient(mesh: &mut MeshData, m: &Mat4, reverse: bool) {
    mesh.transform(m);
    if Mat3::from_mat4(*m).determinant() < 0.0 {
        mesh.reverse_winding();
    }
    if reverse {
        mesh.flip();
    }
    face_normals(mesh);
}

/// Winds each triangle of a mesh with normals to face the mean of its
/// vertex normals (pbrt lets the shading normal decide the side).
fn face_normals(mesh: &mut MeshData) {
    let Some(normals) = &mesh.normals else {
        return;
    };
    let n = mesh.positions.len();
    for t in &mut mesh.indices {
        if t.iter().any(|&i| i as usize >= n) {
            continue;
        }
        let [a, b, c] = t.map(|i| mesh.positions[i as usize]);
        let ns = normals[t[0] as usize] + normals[t[1] as usize] + normals[t[2] as usize];
        if (b - a).cross(c - a).dot(ns) < 0.0 {
            t.swap(1, 2);
        }
    }
}

/// A mesh's optional normals `N` and uvs `uv`, each checked to hold one
/// entry per vertex of its `n` positions.
#[allow(clippy::type_complexity)]
fn per_vertex(
    b: &Builder,
    ps: &mut Params<'_>,
    line: u32,
    n: usize,
) -> Result<(Option<Vec<Vec3>>, Option<Vec<Vec2>>)> {
    let normals = ps.vec3s(&b.cx, "N", &[ParamType::Normal, ParamType::Normal3])?;
    let uv = ps.vec2s(&b.cx, "uv")?;
    for (name, len) in [
        ("N", normals.as_ref().map(Vec::len)),
        ("uv", uv.as_ref().map(Vec::len)),
    ] {
        if len.is_some_and(|l| l != n) {
            return Err(b.cx.err(
                line,
                format!(
                    "{}: `{name}` must have one entry per vertex of P ({n})",
                    ps.what
                ),
            ));
        }
    }
    Ok((normals, uv))
}

/// Indices as triangles, checked against the vertex count.
fn triangles(
    b: &Builder,
    ps: &Params<'_>,
    idx: &[i64],
    per: usize,
    n: usize,
) -> Result<Vec<Vec<u32>>> {
    if !idx.len().is_multiple_of(per) {
        return Err(b.cx.err(
            ps.line,
            format!(
                "{}: `indices` has {} entries, not a multiple of {per}",
                ps.what,
                idx.len()
            ),
        ));
    }
    if let Some(bad) = idx.iter().find(|&&i| i < 0 || i as usize >= n) {
        return Err(b.cx.err(
            ps.line,
            format!(
                "{}: index {bad} is out of range (the shape has {n} vertices)",
                ps.what
            ),
        ));
    }
    Ok(idx
        .chunks_exact(per)
        .map(|c| c.iter().map(|&i| i as u32).collect())
        .collect())
}

impl Builder {
    /// A `Shape` directive: reads its geometry in object space, puts it in
    /// world space, and adds it to the scene (or to the object being
    /// defined) with the current material and area light.
    pub(super) fn shape(&mut self, d: &Directive) -> Result<()> {
        let ty = self.strs(d, 1)?[0];
        let defaults = self.g.attrs[0].clone();
        let mut ps = Params::new(d, format!("Shape \"{ty}\""), &defaults);
        if ps.has("alpha") {
            self.warn(
                d.line,
                format!("`alpha` of {} ignored: kalos has no cut-outs", ps.what),
            );
            ps.ignore(&["alpha"]);
        }
        ps.ignore(&["emissionfilename"]);
        let (ctm, reverse) = (self.g.ctm, self.g.reverse_orientation);

        // Geometry in object space
        let geom = match ty {
            "trianglemesh" | "loopsubdiv" => self.triangle_mesh(&mut ps, d, ty)?,
            "bilinearmesh" => self.bilinear_mesh(&mut ps, d)?,
            "plymesh" => self.ply_mesh(&mut ps, d)?,
            "sphere" => {
                let radius = ps.float(&self.cx, "radius", 1.0)?;
                if !(radius.is_finite() && radius > 0.0) {
                    return Err(self.cx.err(d.line, format!("sphere `radius` must be positive, found {radius}")));
                }
                let zmin = ps.float(&self.cx, "zmin", -radius)?;
                let zmax = ps.float(&self.cx, "zmax", radius)?;
                let phimax = ps.float(&self.cx, "phimax", 360.0)?;
                if zmin > -radius || zmax < radius || phimax < 360.0 {
                    return Err(self.cx.err(d.line, "partial spheres (zmin, zmax, phimax) are not supported"));
                }
                Geom::Sphere { radius, to_world: ctm, reverse }
            }
            "disk" => {
                let radius = ps.float(&self.cx, "radius", 1.0)?;
                let height = ps.float(&self.cx, "height", 0.0)?;
                let inner = ps.float(&self.cx, "innerradius", 0.0)?;
                let phimax = ps.float(&self.cx, "phimax", 360.0)?;
                if !(radius.is_finite() && radius > 0.0) {
                    return Err(self.cx.err(d.line, format!("disk `radius` must be positive, found {radius}")));
                }
                if inner > 0.0 || phimax < 360.0 {
                    return Err(self.cx.err(d.line, "partial disks (innerradius, phimax) are not supported"));
                }
                let mut m = shapes::disk(shapes::DISK_SEGMENTS);
                m.transform(&(Mat4::from_translation(Vec3::new(0.0, 0.0, height)) * Mat4::from_scale(Vec3::new(radius, radius, 1.0))));
                Geom::Mesh(m)
            }
            "cylinder" | "curve" | "cone" | "paraboloid" | "hyperboloid" => {
                return Err(self.cx.err(d.line, format!("unsupported shape \"{ty}\": kalos reads trianglemesh, plymesh, sphere, disk, bilinearmesh and loopsubdiv")))
            }
            _ => return Err(self.cx.err(d.line, format!("unknown shape \"{ty}\": expected trianglemesh, plymesh, sphere, disk, bilinearmesh or loopsubdiv"))),
        };
        ps.finish(&self.cx)?;

        // Orientation, material and emission
        let geom = match geom {
            Geom::Mesh(mut m) => {
                if let Some(i) = m.positions.iter().position(|v| !v.is_finite()) {
                    return Err(self
                        .cx
                        .err(d.line, format!("vertex {i} of {} is not finite", ps.what)));
                }
                orient(&mut m, &ctm, reverse);
                Geom::Mesh(m)
            }
            s => s,
        };
        self.place_shape(d, ty, geom)
    }

    /// Gives a shape in world space the current material and area light,
    /// then adds it to the object being defined, or to the scene.
    fn place_shape(&mut self, d: &Directive, ty: &str, geom: Geom) -> Result<()> {
        let Some(material) = self.current_material() else {
            self.warn_once(
                "interface",
                d.line,
                "shapes with the `interface` material are not drawn",
            );
            return Ok(());
        };
        let mut emission = self.g.area_light;
        if self.defining.is_some() && emission.is_some() {
            self.warn(
                d.line,
                "area lights inside ObjectBegin are ignored (as pbrt-v4 does)",
            );
            emission = None;
        }
        let name = format!("{ty}{}", self.scene.shapes.len() + self.pending.len());
        let built = Built {
            name,
            geom,
            material,
            emission,
        };
        if let Some(obj) = &self.defining {
            if let Some(o) = self.objects.get_mut(obj) {
                o.shapes.push(built);
            }
            return Ok(());
        }
        self.add_built(built, d.line)
    }

    /// `trianglemesh`, and `loopsubdiv` as its control mesh (with a
    /// warning), in object space.
    fn triangle_mesh(&mut self, ps: &mut Params<'_>, d: &Directive, ty: &str) -> Result<Geom> {
        let p = ps
            .vec3s(&self.cx, "P", &[ParamType::Point3])?
            .ok_or_else(|| {
                self.cx
                    .err(d.line, format!("{} needs \"point3 P\"", ps.what))
            })?;
        let idx = match ps.ints(&self.cx, "indices")? {
            Some(i) => i,
            None if p.len() == 3 && ty == "trianglemesh" => vec![0, 1, 2],
            None => {
                return Err(self
                    .cx
                    .err(d.line, format!("{} needs \"integer indices\"", ps.what)))
            }
        };
        let tris = triangles(self, ps, &idx, 3, p.len())?;
        let (n, uv) = per_vertex(self, ps, d.line, p.len())?;
        if ty == "loopsubdiv" {
            ps.ignore(&["levels"]);
            self.warn(
                d.line,
                "loopsubdiv drawn as its control mesh (kalos does not subdivide)",
            );
        }
        ps.ignore(&["S", "faceIndices"]);
        Ok(Geom::Mesh(MeshData {
            positions: p,
            normals: n,
            uvs: uv,
            indices: tris.iter().map(|t| [t[0], t[1], t[2]]).collect(),
        }))
    }

    /// `bilinearmesh`: each patch as two triangles (exact when planar; a
    /// warning when some are not), in object space.
    fn bilinear_mesh(&mut self, ps: &mut Params<'_>, d: &Directive) -> Result<Geom> {
        let p = ps
            .vec3s(&self.cx, "P", &[ParamType::Point3])?
            .ok_or_else(|| {
                self.cx
                    .err(d.line, format!("{} needs \"point3 P\"", ps.what))
            })?;
        let idx = match ps.ints(&self.cx, "indices")? {
            Some(i) => i,
            None if p.len() == 4 => vec![0, 1, 2, 3],
            None => {
                return Err(self
                    .cx
                    .err(d.line, format!("{} needs \"integer indices\"", ps.what)))
            }
        };
        let quads = triangles(self, ps, &idx, 4, p.len())?;
        let (n, uv) = per_vertex(self, ps, d.line, p.len())?;
        ps.ignore(&["faceIndices"]);
        // pbrt's patch corners are p00 p10 p01 p11; two triangles
        // are exact for a planar patch
        let mut curved = false;
        let mut indices = Vec::with_capacity(2 * quads.len());
        for q in &quads {
            let [a, b, c, e] = [q[0], q[1], q[2], q[3]];
            let (pa, pb, pc, pe) = (p[a as usize], p[b as usize], p[c as usize], p[e as usize]);
            let nrm = (pb - pa).cross(pc - pa);
            let size = (pe - pa).length().max(f32::MIN_POSITIVE);
            if nrm.length() > 0.0 && ((pe - pa).dot(nrm.normalize())).abs() > 1e-4 * size {
                curved = true;
            }
            indices.push([a, b, e]);
            indices.push([a, e, c]);
        }
        if curved {
            self.warn(
                d.line,
                "bilinearmesh: non-planar patches approximated by two triangles each",
            );
        }
        Ok(Geom::Mesh(MeshData {
            positions: p,
            normals: n,
            uvs: uv,
            indices,
        }))
    }

    /// `plymesh`: the mesh of its PLY file, in object space.
    fn ply_mesh(&mut self, ps: &mut Params<'_>, d: &Directive) -> Result<Geom> {
        let file = ps.string(&self.cx, "filename")?.ok_or_else(|| {
            self.cx
                .err(d.line, format!("{} needs a \"string filename\"", ps.what))
        })?;
        for n in ["displacement", "edgelength"] {
            if ps.has(n) {
                self.warn(
                    d.line,
                    format!(
                        "`{n}` of {} ignored: kalos does not displace meshes",
                        ps.what
                    ),
                );
                ps.ignore(&[n]);
            }
        }
        let path = self.cx.resolve(file);
        let bytes = super::spectra::read_file(&self.cx.access, &path, FileKind::Mesh)
            .map_err(|e| self.cx.err(d.line, files::message("PLY file", file, &e)))?;
        let mesh = crate::scene::ply::parse_ply(&bytes, &path).map_err(|e| {
            self.cx
                .err(d.line, format!("in the mesh of this shape: {e}"))
        })?;
        Ok(Geom::Mesh(mesh))
    }

    /// Adds a shape now (a mesh) or at the end (a sphere).
    fn add_built(&mut self, b: Built, line: u32) -> Result<()> {
        match b.geom {
            Geom::Mesh(m) => {
                let tris = self.scene.triangles.len() as u64 + m.indices.len() as u64;
                if tris > MAX_TRIANGLES {
                    return Err(self.cx.err(line, format!("this shape brings the scene to {tris} triangles; kalos loads at most {MAX_TRIANGLES}")));
                }
                // what the scene's copy of the mesh takes, before it is made
                let item = format!("shape `{}` ({} triangles)", b.name, m.indices.len());
                self.cx
                    .access
                    .reserve(item, mesh_bytes(&m))
                    .map_err(|e| self.cx.err(line, e.to_string()))?;
                self.scene.add_mesh(
                    b.name,
                    &m.positions,
                    m.normals.as_deref(),
                    m.uvs.as_deref(),
                    &m.indices,
                    b.material,
                    b.emission,
                );
            }
            Geom::Sphere { .. } => {
                // each sphere takes at least the fewest rings' triangles
                let min = shapes::sphere_triangles(shapes::SPHERE_MIN_RINGS);
                let tris =
                    self.scene.triangles.len() as u64 + (self.pending.len() as u64 + 1) * min;
                if tris > MAX_TRIANGLES {
                    return Err(self.cx.err(
                        line,
                        format!("this sphere brings the scene past {MAX_TRIANGLES} triangles"),
                    ));
                }
                self.pending.push(b)
            }
        }
        Ok(())
    }

    /// `ObjectInstance`: the object's shapes under the current transform.
    pub(super) fn instance(&mut self, name: &str, line: u32) -> Result<()> {
        if self.defining.is_some() {
            return Err(self
                .cx
                .err(line, "ObjectInstance inside ObjectBegin is not allowed"));
        }
        let obj = self.objects.get(name).ok_or_else(|| {
            self.cx.err(
                line,
                format!(
                    "ObjectInstance \"{name}\": no object of this name is defined before this line"
                ),
            )
        })?;
        let _ = obj.line;
        let add: u64 = obj
            .shapes
            .iter()
            .map(|s| match &s.geom {
                Geom::Mesh(m) => m.indices.len() as u64,
                Geom::Sphere { .. } => 0,
            })
            .sum();
        if self.scene.triangles.len() as u64 + add > MAX_TRIANGLES {
            return Err(self.cx.err(
                line,
                format!("this instance brings the scene past {MAX_TRIANGLES} triangles"),
            ));
        }
        // one shape copied at a time, each reserved before the scene's copy
        // of it is made (see `add_built`)
        let count = obj.shapes.len();
        let m = self.g.ctm;
        for i in 0..count {
            let Some(mut s) = self
                .objects
                .get(name)
                .and_then(|o| o.shapes.get(i))
                .cloned()
            else {
                break;
            };
            s.geom = match s.geom {
                Geom::Mesh(mut mesh) => {
                    mesh.transform(&m);
                    if Mat3::from_mat4(m).determinant() < 0.0 {
                        mesh.reverse_winding();
                    }
                    face_normals(&mut mesh);
                    Geom::Mesh(mesh)
                }
                Geom::Sphere {
                    radius,
                    to_world,
                    reverse,
                } => Geom::Sphere {
                    radius,
                    to_world: m * to_world,
                    reverse,
                },
            };
            self.add_built(s, line)?;
        }
        Ok(())
    }

    /// Tessellates the spheres, each by its world radius against the whole
    /// scene's extent ([`shapes::sphere_rings`], as the Mitsuba loader).
    pub(super) fn add_pending(&mut self) {
        let pending = std::mem::take(&mut self.pending);
        if pending.is_empty() {
            return;
        }
        let world: Vec<(Vec3, f32)> = pending
            .iter()
            .map(|b| match &b.geom {
                Geom::Sphere {
                    radius, to_world, ..
                } => {
                    let a = Mat3::from_mat4(*to_world);
                    let s = a
                        .x_axis
                        .length()
                        .max(a.y_axis.length())
                        .max(a.z_axis.length());
                    let r = radius * s;
                    (
                        to_world.transform_point3(Vec3::ZERO),
                        if r.is_finite() { r } else { 0.0 },
                    )
                }
                Geom::Mesh(_) => (Vec3::ZERO, 0.0),
            })
            .collect();
        let (mut lo, mut hi) = if self.scene.triangles.is_empty() {
            (Vec3::INFINITY, Vec3::NEG_INFINITY)
        } else {
            self.scene.bounds()
        };
        for &(c, r) in &world {
            lo = lo.min(c - r);
            hi = hi.max(c + r);
        }
        let radii: Vec<f32> = world.iter().map(|w| w.1).collect();
        let rings = shapes::sphere_rings(&radii, (hi - lo).length());
        for (b, n) in pending.into_iter().zip(rings) {
            if let Geom::Sphere {
                radius,
                to_world,
                reverse,
            } = b.geom
            {
                let mut m = shapes::sphere(Vec3::ZERO, radius, n);
                orient(&mut m, &to_world, reverse);
                self.scene.add_mesh(
                    b.name,
                    &m.positions,
                    m.normals.as_deref(),
                    m.uvs.as_deref(),
                    &m.indices,
                    b.material,
                    b.emission,
                );
            }
        }
    }
}
