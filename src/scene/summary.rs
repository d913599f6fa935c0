//! What `kalos info` prints about a scene: triangles, emitters, materials,
//! bounds, camera.

use std::fmt;

use super::{EmitterDesc, Material, Scene};

/// A scene's summary, for display.
pub struct Summary<'a>(pub &'a Scene);

/// The Mitsuba plugin name of a material.
fn material_name(m: &Material) -> String {
    use Material as M;
    match m {
        M::Diffuse { .. } => "diffuse".into(),
        M::Phong { .. } => "phong".into(),
        M::Conductor { .. } => "conductor".into(),
        M::RoughConductor { .. } => "roughconductor".into(),
        M::Plastic { .. } => "plastic".into(),
        M::RoughPlastic { .. } => "roughplastic".into(),
        M::Dielectric { .. } => "dielectric".into(),
        M::RoughDielectric { .. } => "roughdielectric".into(),
        M::ThinDielectric { .. } => "thindielectric".into(),
        M::TwoSided(inner) => format!("twosided({})", material_name(inner)),
        M::MetallicRoughness(_) => "gltf metallic-roughness (per texel)".into(),
    }
}

impl fmt::Display for Summary<'_> {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let s = self.0;
        let (lo, hi) = s.bounds();
        writeln!(f, "scene      {}", s.source)?;
        writeln!(f, "triangles  {}", s.triangles.len())?;
        writeln!(f, "vertices   {}", s.positions.len())?;
        writeln!(f, "shapes     {}", s.shapes.len())?;
        writeln!(f, "materials  {}", s.materials.len())?;
        for (i, m) in s.materials.iter().enumerate() {
            writeln!(f, "  [{i}] {}", material_name(m))?;
        }
        writeln!(f, "emitters   {}", s.emitters.len())?;
        for e in &s.emitters {
            match e {
                EmitterDesc::Area { shape, radiance } => writeln!(
                    f,
                    "  area on '{}', radiance ({}, {}, {})",
                    s.shapes[*shape as usize].name, radiance.x, radiance.y, radiance.z
                )?,
                EmitterDesc::Constant { radiance } => writeln!(
                    f,
                    "  constant, radiance ({}, {}, {})",
                    radiance.x, radiance.y, radiance.z
                )?,
                EmitterDesc::EnvMap { image, scale, .. } => writeln!(
                    f,
                    "  envmap {}x{}, scale {scale}",
                    image.width, image.height
                )?,
                EmitterDesc::Punctual(l) => writeln!(f, "  {}", l.describe())?,
            }
        }
        writeln!(
            f,
            "bounds     ({}, {}, {}) .. ({}, {}, {})",
            lo.x, lo.y, lo.z, hi.x, hi.y, hi.z
        )?;
        write!(
            f,
            "camera     {}x{}, fov_x {:.3} deg",
            s.camera.width, s.camera.height, s.camera.fov_x_deg
        )
    }
}
