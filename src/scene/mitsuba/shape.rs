//! Shape plugins: `obj`, `ply`, `rectangle`, `cube`, `disk`, `sphere`, with
//! `to_world` and their nested BSDF and area emitter.
//!
//! Spheres are tessellated last, once the whole scene is read
//! ([`Builder::add_spheres`]): how finely depends on each sphere's size
//! relative to the scene and on how many there are
//! ([`shapes::sphere_rings`]). They therefore come after the other shapes in
//! [`crate::scene::Scene::shapes`].

use glam::{Mat3, Mat4, Vec3};

use crate::scene::shapes::{self, MeshData};
use crate::scene::{Material, Rgb, Texture};

use crate::scene::access::FileKind;

use super::builder::Builder;
use super::files;
use super::props::Props;
use super::xml::{resolve, El};
use super::Result;

impl<'t> Builder<'t> {
    fn default_material(&mut self) -> u32 {
        if let Some(m) = self.default_material {
            return m;
        }
        // Mitsuba's default BSDF for a shape without one
        let m = self.scene.add_material(Material::Diffuse {
            reflectance: Texture::Constant(Rgb::splat(0.5)),
        });
        self.default_material = Some(m);
        m
    }

    /// A `<shape>`: its geometry in world space, its nested BSDF and area
    /// emitter, added to the scene (a sphere once the whole scene is read).
    pub(super) fn shape(&mut self, el: &'t El) -> Result<()> {
        let ty = self.plugin_type(el)?;
        let mut p = Props::new(el);
        let to_world = self
            .transform(&mut p, "to_world")?
            .unwrap_or(Mat4::IDENTITY);
        let flip_normals = self.boolean(&mut p, "flip_normals", false)?;

        // Geometry in object space (a sphere's waits for the whole scene)
        let mut sphere = None;
        let (mut mesh, analytic) = match ty {
            "obj" | "ply" => (self.mesh_file(el, &mut p, ty, &to_world)?, false),
            "sphere" => {
                let center = self.point(&mut p, "center")?.unwrap_or(Vec3::ZERO);
                let radius = self.float(&mut p, "radius", 1.0)?;
                if !(radius.is_finite() && radius > 0.0) {
                    return Err(self.err(el, "sphere `radius` must be positive and finite"));
                }
                sphere = Some((center, radius));
                (MeshData::default(), true)
            }
            "rectangle" | "cube" | "disk" => {
                let mut mesh = match ty {
                    "rectangle" => shapes::rectangle(),
                    "cube" => shapes::cube(),
                    _ => shapes::disk(shapes::DISK_SEGMENTS),
                };
                mesh.transform(&to_world);
                (mesh, ty != "cube")
            }
            _ => {
                return Err(self.err(
                    el,
                    format!("unsupported shape plugin `{ty}` in {}", el.describe()),
                ))
            }
        };
        // Mitsuba's analytic shapes take their normal from the inverse
        // transpose of to_world; a mirroring to_world reverses the winding,
        // so reverse it back to keep the geometric normal on that side.
        if analytic && Mat3::from_mat4(to_world).determinant() < 0.0 {
            mesh.reverse_winding();
        }
        if flip_normals {
            mesh.flip();
        }

        // Nested BSDF and area emitter, inline or by reference
        let (bsdf, radiance) = self.shape_children(&mut p)?;
        self.finish(&p)?;
        let tris = self.scene.triangles.len() as u64 + mesh.indices.len() as u64;
        if tris > crate::scene::MAX_TRIANGLES {
            return Err(self.err(
                el,
                format!(
                    "this shape brings the scene to {tris} triangles; kalos loads at most {}",
                    crate::scene::MAX_TRIANGLES
                ),
            ));
        }
        if let Some(i) = mesh.positions.iter().position(|v| !v.is_finite()) {
            return Err(self.err(
                el,
                format!(
                    "vertex {i} of this shape is not finite ({})",
                    mesh.positions[i]
                ),
            ));
        }
        let material = match bsdf {
            Some(m) => m,
            None => self.default_material(),
        };
        let name = el.attr("id").map_or_else(
            || format!("{ty}{}", self.scene.shapes.len()),
            str::to_string,
        );
        match sphere {
            Some((center, radius)) => self.spheres.push(PendingSphere {
                name,
                center,
                radius,
                to_world,
                flip_normals,
                material,
                radiance,
            }),
            None => self.add(name, &mesh, material, radiance),
        }
        Ok(())
    }

    /// An `obj` or `ply` shape's mesh file, in world space, with vertex
    /// normals computed when it has none (unless `face_normals`).
    fn mesh_file(
        &mut self,
        el: &'t El,
        p: &mut Props<'t>,
        ty: &str,
        to_world: &Mat4,
    ) -> Result<MeshData> {
        let filename = self
            .string(p, "filename")?
            .ok_or_else(|| self.err(el, format!("{} needs a `filename`", el.describe())))?;
        let face_normals = self.boolean(p, "face_normals", false)?;
        let flip_tex = self.boolean(p, "flip_tex_coords", ty == "obj")?;
        let path = resolve(self.main_dir, &self.file(el), filename);
        // refused here, naming this shape's line, before the loader opens it
        self.access
            .check(&path, FileKind::Mesh)
            .map_err(|e| self.err(el, files::message("mesh file", filename, &e)))?;
        let mut mesh = if ty == "obj" {
            crate::scene::obj::load_obj(&path, flip_tex, self.access)
        } else {
            crate::scene::ply::load_ply(&path, self.access).map(|mut m| {
                if flip_tex {
                    if let Some(uvs) = &mut m.uvs {
                        uvs.iter_mut().for_each(|t| t.y = 1.0 - t.y);
                    }
                }
                m
            })
        }
        .map_err(|e| self.err(el, format!("in the mesh of this shape: {e}")))?;
        if face_normals {
            mesh.normals = None;
        }
        mesh.transform(to_world);
        if mesh.normals.is_none() && !face_normals {
            mesh.compute_vertex_normals();
        }
        Ok(mesh)
    }

    /// A shape's nested `<bsdf>` (its material index) and area `<emitter>`
    /// (its radiance), each inline or by reference, at most one of each.
    fn shape_children(&mut self, p: &mut Props<'t>) -> Result<(Option<u32>, Option<Rgb>)> {
        let mut bsdf = None;
        let mut radiance = None;
        for o in p.objects() {
            let target = if o.tag == "ref" { self.lookup(o)? } else { o };
            match target.tag.as_str() {
                "bsdf" => {
                    if bsdf.is_some() {
                        return Err(self.err(o, "a shape can have only one <bsdf>"));
                    }
                    bsdf = Some(self.bsdf(target)?);
                }
                "emitter" => {
                    if radiance.is_some() {
                        return Err(self.err(o, "a shape can have only one <emitter>"));
                    }
                    radiance = Some(self.area_emitter(target)?);
                }
                _ => {
                    return Err(self.err(
                        o,
                        format!("unsupported {} inside a shape", target.describe()),
                    ))
                }
            }
        }
        Ok((bsdf, radiance))
    }

    /// Tessellates the spheres read so far and adds them to the scene, each
    /// with the rings [`shapes::sphere_rings`] gives it from its world
    /// radius and the diagonal of the whole scene (the other shapes and every
    /// sphere's bounds).
    pub(super) fn add_spheres(&mut self) {
        let spheres = std::mem::take(&mut self.spheres);
        if spheres.is_empty() {
            return;
        }
        let (mut lo, mut hi) = if self.scene.triangles.is_empty() {
            (Vec3::INFINITY, Vec3::NEG_INFINITY)
        } else {
            self.scene.bounds()
        };
        let world: Vec<(Vec3, f32)> = spheres.iter().map(PendingSphere::world).collect();
        for &(c, r) in &world {
            lo = lo.min(c - r);
            hi = hi.max(c + r);
        }
        let extent = (hi - lo).length();
        let radii: Vec<f32> = world.iter().map(|w| w.1).collect();
        let rings = shapes::sphere_rings(&radii, extent);
        for (s, n) in spheres.into_iter().zip(rings) {
            let mut mesh = shapes::sphere(s.center, s.radius, n);
            mesh.transform(&s.to_world);
            // as for the other analytic shapes (see `shape`)
            if Mat3::from_mat4(s.to_world).determinant() < 0.0 {
                mesh.reverse_winding();
            }
            if s.flip_normals {
                mesh.flip();
            }
            self.add(s.name, &mesh, s.material, s.radiance);
        }
    }

    fn add(&mut self, name: String, m: &MeshData, material: u32, radiance: Option<Rgb>) {
        self.scene.add_mesh(
            name,
            &m.positions,
            m.normals.as_deref(),
            m.uvs.as_deref(),
            &m.indices,
            material,
            radiance,
        );
    }
}

/// A `sphere` shape read but not yet tessellated: [`Builder::add_spheres`]
/// chooses its rings once the whole scene is known.
pub(super) struct PendingSphere {
    name: String,
    center: Vec3,
    radius: f32,
    to_world: Mat4,
    flip_normals: bool,
    material: u32,
    radiance: Option<Rgb>,
}

impl PendingSphere {
    /// World-space centre and radius. Under a non-uniform `to_world` the
    /// radius is the longest transformed axis (the ellipsoid's longest
    /// semi-axis unless `to_world` shears), so that its tessellation errs on
    /// the fine side.
    fn world(&self) -> (Vec3, f32) {
        let m = Mat3::from_mat4(self.to_world);
        let stretch = m
            .x_axis
            .length()
            .max(m.y_axis.length())
            .max(m.z_axis.length());
        let r = self.radius * stretch;
        let c = self.to_world.transform_point3(self.center);
        (c, if r.is_finite() { r } else { 0.0 })
    }
}
