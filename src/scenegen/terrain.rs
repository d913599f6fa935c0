//! `terrain`: a fractal terrain (value-noise octaves), wavy water, a
//! glowing moon and a constant sky (Fig. 11 of the stochastic-iteration
//! paper).

use glam::Vec3;

use super::mesh::Mesh;
use super::xml::header;
use super::SceneFiles;

/// A hash of the lattice point (i, j) to [0, 1].
fn hash(i: i32, j: i32, seed: u32) -> f32 {
    let mut h = (i as u32).wrapping_mul(0x8da6_b343) ^ (j as u32).wrapping_mul(0xd816_3841) ^ seed;
    h = (h ^ (h >> 13)).wrapping_mul(0x5bd1_e995);
    h ^= h >> 15;
    (h & 0xFFFF) as f32 / 65535.0
}

/// Value noise: the lattice hashes around (x, z), blended with smoothstep.
fn value_noise(x: f32, z: f32, seed: u32) -> f32 {
    let (i, j) = (x.floor() as i32, z.floor() as i32);
    let (fx, fz) = (x - i as f32, z - j as f32);
    let s = |t: f32| t * t * (3.0 - 2.0 * t);
    let (sx, sz) = (s(fx), s(fz));
    let a = hash(i, j, seed) * (1.0 - sx) + hash(i + 1, j, seed) * sx;
    let b = hash(i, j + 1, seed) * (1.0 - sx) + hash(i + 1, j + 1, seed) * sx;
    a * (1.0 - sz) + b * sz
}

/// The scene: `land.obj`, `water.obj` and `scene.xml` (the moon is an
/// analytic sphere, the sky a constant emitter).
pub(super) fn build() -> SceneFiles {
    // Six octaves of value noise, each twice the frequency and half the
    // amplitude of the last
    let mut land = Mesh::default();
    land.grid(140, -10.0, 10.0, -10.0, 10.0, |x, z| {
        let mut h = 0.0;
        let (mut f, mut a) = (0.25, 2.2);
        for o in 0..6 {
            h += a * value_noise(x * f, z * f, 17 + o);
            f *= 2.0;
            a *= 0.5;
        }
        h - 1.6
    });
    let mut water = Mesh::default();
    water.grid(90, -10.0, 10.0, -10.0, 10.0, |x, z| {
        0.04 * (1.7 * x + 0.3 * z).sin() + 0.03 * (2.3 * z - 0.9 * x).sin()
    });
    let mut xml = header(Vec3::new(0.0, 3.5, 11.0), Vec3::new(0.0, 0.0, 0.0), 50.0);
    xml += r#"    <bsdf type="diffuse" id="rock"><rgb name="reflectance" value="0.45, 0.4, 0.3"/></bsdf>
    <bsdf type="phong" id="water">
        <rgb name="diffuse_reflectance" value="0.02, 0.05, 0.08"/>
        <rgb name="specular_reflectance" value="0.6"/>
        <float name="exponent" value="60"/>
    </bsdf>
    <shape type="obj"><string name="filename" value="land.obj"/><ref id="rock"/></shape>
    <shape type="obj"><string name="filename" value="water.obj"/><ref id="water"/></shape>
    <shape type="sphere">
        <point name="center" x="-4" y="6" z="-12"/><float name="radius" value="1.2"/>
        <bsdf type="diffuse"><rgb name="reflectance" value="0"/></bsdf>
        <emitter type="area"><rgb name="radiance" value="30, 28, 22"/></emitter>
    </shape>
    <emitter type="constant"><rgb name="radiance" value="0.25, 0.35, 0.6"/></emitter>
"#;
    xml += "</scene>\n";
    SceneFiles {
        meshes: vec![("land.obj".into(), land), ("water.obj".into(), water)],
        images: Vec::new(),
        xml,
    }
}
