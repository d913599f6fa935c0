//! `sphereflake`: a golden Phong sphere-flake of 91 spheres on a grey floor
//! under two area lights (Fig. 9 of the stochastic-iteration paper).

use std::f32::consts::PI;

use glam::Vec3;

use super::mesh::Mesh;
use super::xml::{header, light};
use super::SceneFiles;

/// Rings of each sphere of the flake (26 segments around).
const RINGS: u32 = 13;

/// A sphere at `c` of radius `r` and, `depth` levels down, nine children a
/// third its size: six around its equator (tilted up a little) and three
/// above, on the axis `up`.
fn flake(o: &mut Mesh, c: Vec3, r: f32, up: Vec3, depth: u32) {
    o.sphere(c, r, RINGS);
    if depth == 0 {
        return;
    }
    let u = up.any_orthonormal_vector();
    let w = up.cross(u);
    let mut dirs = Vec::new();
    for k in 0..6 {
        let a = 2.0 * PI * k as f32 / 6.0;
        dirs.push((u * a.cos() + w * a.sin() + up * 0.2).normalize());
    }
    for k in 0..3 {
        let a = 2.0 * PI * (k as f32 + 0.25) / 3.0;
        dirs.push((up * 1.4 + u * a.cos() + w * a.sin()).normalize());
    }
    let rc = r / 3.0;
    for d in dirs {
        flake(o, c + d * (r + rc), rc, d, depth - 1);
    }
}

/// The scene: `flake.obj`, `floor.obj` and `scene.xml`.
pub(super) fn build() -> SceneFiles {
    let mut o = Mesh::default();
    flake(&mut o, Vec3::new(0.0, 1.0, 0.0), 1.0, Vec3::Y, 2);
    let mut floor = Mesh::default();
    floor.grid(4, -6.0, 6.0, -6.0, 6.0, |_, _| 0.0);
    let mut xml = header(Vec3::new(3.2, 3.0, 4.2), Vec3::new(0.0, 1.1, 0.0), 40.0);
    xml += r#"    <bsdf type="phong" id="gold">
        <rgb name="diffuse_reflectance" value="0.15, 0.11, 0.03"/>
        <rgb name="specular_reflectance" value="0.75, 0.55, 0.2"/>
        <float name="exponent" value="30"/>
    </bsdf>
    <bsdf type="diffuse" id="grey"><rgb name="reflectance" value="0.5"/></bsdf>
    <shape type="obj"><string name="filename" value="flake.obj"/><ref id="gold"/></shape>
    <shape type="obj"><string name="filename" value="floor.obj"/><ref id="grey"/></shape>
"#;
    xml += &light(Vec3::new(-2.0, 5.0, 1.0), 2.0, Vec3::splat(6.0));
    xml += &light(Vec3::new(2.5, 4.5, -1.5), 1.5, Vec3::new(6.0, 5.5, 5.0));
    xml += "</scene>\n";
    SceneFiles {
        meshes: vec![("flake.obj".into(), o), ("floor.obj".into(), floor)],
        images: Vec::new(),
        xml,
    }
}
