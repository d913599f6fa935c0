//! Shape plugins: `obj`, `ply`, `rectangle`, `cube`, `disk`, `sphere`, with
//! `to_world` and their nested BSDF and area emitter.

use glam::{Mat3, Mat4, Vec3};

use crate::scene::shapes::{self, MeshData};
use crate::scene::{Material, Rgb, Texture};

use super::builder::Builder;
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

    pub(super) fn shape(&mut self, el: &'t El) -> Result<()> {
        let ty = self.plugin_type(el)?;
        let mut p = Props::new(el);
        let to_world = self
            .transform(&mut p, "to_world")?
            .unwrap_or(Mat4::IDENTITY);
        let flip_normals = self.boolean(&mut p, "flip_normals", false)?;

        // Geometry in object space
        let (mut mesh, analytic) = match ty {
            "obj" | "ply" => {
                let filename = self
                    .string(&mut p, "filename")?
                    .ok_or_else(|| self.err(el, format!("{} needs a `filename`", el.describe())))?;
                let face_normals = self.boolean(&mut p, "face_normals", false)?;
                let flip_tex = self.boolean(&mut p, "flip_tex_coords", ty == "obj")?;
                let path = resolve(self.main_dir, &self.file(el), filename);
                if !path.is_file() {
                    return Err(self.err(
                        el,
                        format!(
                            "mesh file `{filename}` not found (looked for {})",
                            path.display()
                        ),
                    ));
                }
                let mut mesh = if ty == "obj" {
                    crate::scene::obj::load_obj(&path, flip_tex)
                } else {
                    crate::scene::ply::load_ply(&path).map(|mut m| {
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
                mesh.transform(&to_world);
                if mesh.normals.is_none() && !face_normals {
                    mesh.compute_vertex_normals();
                }
                (mesh, false)
            }
            "rectangle" | "cube" | "disk" | "sphere" => {
                let mut mesh = match ty {
                    "rectangle" => shapes::rectangle(),
                    "cube" => shapes::cube(),
                    "disk" => shapes::disk(shapes::DISK_SEGMENTS),
                    _ => {
                        let center = self.point(&mut p, "center")?.unwrap_or(Vec3::ZERO);
                        let radius = self.float(&mut p, "radius", 1.0)?;
                        if !(radius.is_finite() && radius > 0.0) {
                            return Err(self.err(el, "sphere `radius` must be positive and finite"));
                        }
                        shapes::sphere(center, radius, shapes::SPHERE_RINGS)
                    }
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
        self.add(name, &mesh, material, radiance);
        Ok(())
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
