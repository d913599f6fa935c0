//! `teapot-room`: a room with a glossy metallic teapot (Fig. 8 of the
//! stochastic-iteration paper). The teapot is a procedural approximation (a
//! lathed body and lid, a tapered tube spout and a half-torus handle), not
//! the Utah Bezier data.

use std::f32::consts::PI;

use glam::Vec3;

use super::mesh::Mesh;
use super::xml::{header, light};
use super::SceneFiles;

/// The scene: `room.obj`, `teapot.obj` and `scene.xml`.
pub(super) fn build() -> SceneFiles {
    // The room, 6 × 4 × 6, normals inward: eight shared corners and six
    // quads, each counter-clockwise seen from inside
    let mut room = Mesh::default();
    room.positions.extend_from_slice(&[
        Vec3::new(-3.0, 0.0, -3.0),
        Vec3::new(3.0, 0.0, -3.0),
        Vec3::new(3.0, 4.0, -3.0),
        Vec3::new(-3.0, 4.0, -3.0),
        Vec3::new(-3.0, 0.0, 3.0),
        Vec3::new(3.0, 0.0, 3.0),
        Vec3::new(3.0, 4.0, 3.0),
        Vec3::new(-3.0, 4.0, 3.0),
    ]);
    for q in [
        [0, 1, 2, 3], // z = -3
        [4, 7, 6, 5], // z = 3
        [0, 4, 5, 1], // floor
        [3, 2, 6, 7], // ceiling
        [0, 3, 7, 4], // x = -3
        [1, 5, 6, 2], // x = 3
    ] {
        room.quad_indices(q);
    }

    // The teapot: body and lid lathed from one profile, then spout and handle
    let mut pot = Mesh::default();
    let base = Vec3::new(0.0, 0.0, 0.0);
    let body: Vec<(f32, f32)> = (0..=24)
        .map(|i| {
            let t = i as f32 / 24.0;
            let y = 1.2 * t;
            (
                0.05 + 0.85 * (PI * (0.1 + 0.8 * t)).sin() * (1.0 - 0.25 * t),
                y,
            )
        })
        .chain([(0.5, 1.25), (0.3, 1.35), (0.08, 1.45), (0.0, 1.5)])
        .collect();
    let mut prof = vec![(0.0f32, 0.0f32)];
    prof.extend(body);
    pot.lathe(base, &prof, 48);
    pot.tube(
        |t| Vec3::new(0.75 + 0.6 * t, 0.35 + 0.75 * t * t, 0.0),
        |t| 0.16 - 0.09 * t,
        16,
        12,
    );
    pot.tube(
        |t| {
            let a = PI * (t - 0.5);
            Vec3::new(-0.8 - 0.45 * a.cos(), 0.75 + 0.4 * a.sin(), 0.0)
        },
        |_| 0.06,
        16,
        10,
    );

    // The room is a box of flat walls: its OBJ has no normals, so the XML
    // asks for face normals (vertex normals averaged across the corners
    // would tilt the walls' shading by up to 55°)
    let mut xml = header(Vec3::new(0.0, 2.2, 2.9), Vec3::new(0.0, 0.7, 0.0), 55.0);
    xml += r#"    <bsdf type="diffuse" id="wall"><rgb name="reflectance" value="0.6, 0.55, 0.5"/></bsdf>
    <bsdf type="roughconductor" id="metal">
        <string name="material" value="Cu"/>
        <string name="distribution" value="ggx"/>
        <float name="alpha" value="0.15"/>
    </bsdf>
    <shape type="obj"><string name="filename" value="room.obj"/><boolean name="face_normals" value="true"/><ref id="wall"/></shape>
    <shape type="obj"><string name="filename" value="teapot.obj"/><ref id="metal"/></shape>
"#;
    xml += &light(Vec3::new(0.0, 3.95, 0.0), 1.2, Vec3::splat(12.0));
    xml += "</scene>\n";
    SceneFiles {
        meshes: vec![("room.obj".into(), room), ("teapot.obj".into(), pot)],
        images: Vec::new(),
        xml,
    }
}
