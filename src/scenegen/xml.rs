//! Mitsuba 3 XML pieces shared by the scenes of the stochastic-iteration
//! paper.

use glam::Vec3;

/// The scene's opening tag and a 256 × 256 perspective sensor looking from
/// `origin` at `target` (up +y) with horizontal field of view `fov` degrees.
pub(super) fn header(origin: Vec3, target: Vec3, fov: f32) -> String {
    format!(
        r#"<scene version="3.0.0">
    <sensor type="perspective">
        <float name="fov" value="{fov}"/>
        <transform name="to_world">
            <lookat origin="{}, {}, {}" target="{}, {}, {}" up="0, 1, 0"/>
        </transform>
        <film type="hdrfilm">
            <integer name="width" value="256"/>
            <integer name="height" value="256"/>
        </film>
    </sensor>
"#,
        origin.x, origin.y, origin.z, target.x, target.y, target.z
    )
}

/// A horizontal rectangle light of size `s` at `c`, facing down, of
/// radiance `le`.
pub(super) fn light(c: Vec3, s: f32, le: Vec3) -> String {
    format!(
        r#"    <shape type="rectangle">
        <transform name="to_world">
            <scale value="{}"/><rotate x="1" angle="90"/><translate x="{}" y="{}" z="{}"/>
        </transform>
        <bsdf type="diffuse"><rgb name="reflectance" value="0"/></bsdf>
        <emitter type="area"><rgb name="radiance" value="{}, {}, {}"/></emitter>
    </shape>
"#,
        s * 0.5,
        c.x,
        c.y,
        c.z,
        le.x,
        le.y,
        le.z
    )
}
