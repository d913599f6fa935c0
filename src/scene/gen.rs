//! Generated test scenes of the stochastic-iteration paper (`kalos gen NAME
//! -o DIR`): Mitsuba 3 XML plus OBJ meshes.
//!
//! - `sphereflake`: a golden Phong sphere-flake of 91 spheres (about 57k
//!   triangles) on a grey floor, under two area lights (Fig. 9);
//! - `teapot-room`: a room with a glossy metallic teapot (Fig. 8). The teapot
//!   is a procedural approximation (a lathed body and lid, a tapered tube
//!   spout and a half-torus handle), not the Utah Bezier data;
//! - `terrain`: a fractal terrain (value-noise octaves), wavy water, a
//!   glowing moon and a constant sky (Fig. 11).

use std::f32::consts::PI;
use std::fmt::Write as _;
use std::path::Path;

use glam::Vec3;

use super::shapes::{Diagonal, LatLong, Pole};

/// Names `generate` knows.
pub const SCENES: &[&str] = &["sphereflake", "teapot-room", "terrain"];

#[derive(Default)]
struct Obj {
    v: Vec<Vec3>,
    n: Vec<Vec3>,
    f: Vec<[u32; 3]>,
}

impl Obj {
    fn text(&self) -> String {
        let mut s = String::new();
        for v in &self.v {
            let _ = writeln!(s, "v {} {} {}", v.x, v.y, v.z);
        }
        for n in &self.n {
            let _ = writeln!(s, "vn {} {} {}", n.x, n.y, n.z);
        }
        let with_n = self.n.len() == self.v.len();
        for f in &self.f {
            let [a, b, c] = f.map(|i| i + 1);
            if with_n {
                let _ = writeln!(s, "f {a}//{a} {b}//{b} {c}//{c}");
            } else {
                let _ = writeln!(s, "f {a} {b} {c}");
            }
        }
        s
    }

    /// A sphere around +y with `rings` rings and 2·rings segments, outward
    /// normals: the crate's [`LatLong`] tessellation, welded at the seam.
    fn sphere(&mut self, c: Vec3, r: f32, rings: u32) {
        let sphere = LatLong {
            rings,
            pole: Pole::Y,
            diagonal: Diagonal::Anti,
            seam: false,
            pole_triangles: false,
        }
        .mesh(c, r);
        let base = self.v.len() as u32;
        self.v.extend_from_slice(&sphere.positions);
        self.n.extend(sphere.normals.iter().flatten());
        self.f
            .extend(sphere.indices.iter().map(|t| t.map(|i| base + i)));
    }

    /// A surface of revolution around +y of a profile (radius, height),
    /// normals outward when the profile runs upward.
    fn lathe(&mut self, c: Vec3, profile: &[(f32, f32)], segs: u32) {
        let base = self.v.len() as u32;
        for &(r, y) in profile {
            for j in 0..segs {
                let ph = 2.0 * PI * j as f32 / segs as f32;
                self.v.push(c + Vec3::new(r * ph.cos(), y, r * ph.sin()));
            }
        }
        for i in 0..profile.len() as u32 - 1 {
            for j in 0..segs {
                let a = base + i * segs + j;
                let b = base + i * segs + (j + 1) % segs;
                let c2 = a + segs;
                let d = b + segs;
                self.f.push([a, c2, b]);
                self.f.push([b, c2, d]);
            }
        }
    }

    /// A tube along a curve `p(t)`, t in [0, 1], radius `r(t)`.
    fn tube(&mut self, p: impl Fn(f32) -> Vec3, r: impl Fn(f32) -> f32, n: u32, segs: u32) {
        let base = self.v.len() as u32;
        for i in 0..=n {
            let t = i as f32 / n as f32;
            let c = p(t);
            let tan = (p((t + 0.01).min(1.0)) - p((t - 0.01).max(0.0))).normalize_or(Vec3::Y);
            let u = tan.any_orthonormal_vector();
            let w = tan.cross(u);
            for j in 0..segs {
                let ph = 2.0 * PI * j as f32 / segs as f32;
                self.v.push(c + (u * ph.cos() + w * ph.sin()) * r(t));
            }
        }
        for i in 0..n {
            for j in 0..segs {
                let a = base + i * segs + j;
                let b = base + i * segs + (j + 1) % segs;
                self.f.push([a, b, a + segs]);
                self.f.push([b, b + segs, a + segs]);
            }
        }
    }

    /// A height field over [x0, x1] × [z0, z1], normals up.
    fn grid(&mut self, n: u32, x0: f32, x1: f32, z0: f32, z1: f32, h: impl Fn(f32, f32) -> f32) {
        let base = self.v.len() as u32;
        for i in 0..=n {
            for j in 0..=n {
                let x = x0 + (x1 - x0) * j as f32 / n as f32;
                let z = z0 + (z1 - z0) * i as f32 / n as f32;
                self.v.push(Vec3::new(x, h(x, z), z));
            }
        }
        let id = |i: u32, j: u32| base + i * (n + 1) + j;
        for i in 0..n {
            for j in 0..n {
                self.f.push([id(i, j), id(i + 1, j), id(i, j + 1)]);
                self.f.push([id(i, j + 1), id(i + 1, j), id(i + 1, j + 1)]);
            }
        }
    }
}

fn flake(o: &mut Obj, c: Vec3, r: f32, up: Vec3, depth: u32) {
    o.sphere(c, r, 13);
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

fn header(origin: Vec3, target: Vec3, fov: f32) -> String {
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

/// A horizontal rectangle light of size `s` at `c`, facing down.
fn light(c: Vec3, s: f32, le: Vec3) -> String {
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

fn hash(i: i32, j: i32, seed: u32) -> f32 {
    let mut h = (i as u32).wrapping_mul(0x8da6_b343) ^ (j as u32).wrapping_mul(0xd816_3841) ^ seed;
    h = (h ^ (h >> 13)).wrapping_mul(0x5bd1_e995);
    h ^= h >> 15;
    (h & 0xFFFF) as f32 / 65535.0
}

fn value_noise(x: f32, z: f32, seed: u32) -> f32 {
    let (i, j) = (x.floor() as i32, z.floor() as i32);
    let (fx, fz) = (x - i as f32, z - j as f32);
    let s = |t: f32| t * t * (3.0 - 2.0 * t);
    let (sx, sz) = (s(fx), s(fz));
    let a = hash(i, j, seed) * (1.0 - sx) + hash(i + 1, j, seed) * sx;
    let b = hash(i, j + 1, seed) * (1.0 - sx) + hash(i + 1, j + 1, seed) * sx;
    a * (1.0 - sz) + b * sz
}

/// Writes scene `name` into `dir` (scene.xml and its meshes); returns the
/// path of the XML file.
pub fn generate(name: &str, dir: &Path) -> std::io::Result<std::path::PathBuf> {
    std::fs::create_dir_all(dir)?;
    let mut xml;
    let mut meshes: Vec<(&str, Obj)> = Vec::new();
    match name {
        "sphereflake" => {
            let mut o = Obj::default();
            flake(&mut o, Vec3::new(0.0, 1.0, 0.0), 1.0, Vec3::Y, 2);
            let mut floor = Obj::default();
            floor.grid(4, -6.0, 6.0, -6.0, 6.0, |_, _| 0.0);
            meshes.push(("flake.obj", o));
            meshes.push(("floor.obj", floor));
            xml = header(Vec3::new(3.2, 3.0, 4.2), Vec3::new(0.0, 1.1, 0.0), 40.0);
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
        }
        "teapot-room" => {
            // room 6 × 4 × 6, normals inward
            let mut room = Obj::default();
            let c = [
                Vec3::new(-3.0, 0.0, -3.0),
                Vec3::new(3.0, 0.0, -3.0),
                Vec3::new(3.0, 4.0, -3.0),
                Vec3::new(-3.0, 4.0, -3.0),
                Vec3::new(-3.0, 0.0, 3.0),
                Vec3::new(3.0, 0.0, 3.0),
                Vec3::new(3.0, 4.0, 3.0),
                Vec3::new(-3.0, 4.0, 3.0),
            ];
            room.v.extend_from_slice(&c);
            for q in [
                [0u32, 1, 2, 3],
                [4, 7, 6, 5],
                [0, 4, 5, 1],
                [3, 2, 6, 7],
                [0, 3, 7, 4],
                [1, 5, 6, 2],
            ] {
                // orient inward
                let n = (c[q[1] as usize] - c[q[0] as usize])
                    .cross(c[q[2] as usize] - c[q[0] as usize]);
                let mid = (c[q[0] as usize] + c[q[2] as usize]) * 0.5 - Vec3::new(0.0, 2.0, 0.0);
                if n.dot(mid) > 0.0 {
                    room.f.push([q[0], q[2], q[1]]);
                    room.f.push([q[0], q[3], q[2]]);
                } else {
                    room.f.push([q[0], q[1], q[2]]);
                    room.f.push([q[0], q[2], q[3]]);
                }
            }
            let mut pot = Obj::default();
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
            // the room is a box of flat walls: its OBJ has no normals, so
            // the XML asks for face normals (vertex normals averaged across
            // the corners would tilt the walls' shading by up to 55°)
            meshes.push(("room.obj", room));
            meshes.push(("teapot.obj", pot));
            xml = header(Vec3::new(0.0, 2.2, 2.9), Vec3::new(0.0, 0.7, 0.0), 55.0);
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
        }
        "terrain" => {
            let mut land = Obj::default();
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
            let mut water = Obj::default();
            water.grid(90, -10.0, 10.0, -10.0, 10.0, |x, z| {
                0.04 * (1.7 * x + 0.3 * z).sin() + 0.03 * (2.3 * z - 0.9 * x).sin()
            });
            meshes.push(("land.obj", land));
            meshes.push(("water.obj", water));
            xml = header(Vec3::new(0.0, 3.5, 11.0), Vec3::new(0.0, 0.0, 0.0), 50.0);
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
        }
        other => {
            return Err(std::io::Error::new(
                std::io::ErrorKind::InvalidInput,
                format!("unknown scene '{other}'; known: {}", SCENES.join(", ")),
            ))
        }
    }
    xml += "</scene>\n";
    for (file, o) in &meshes {
        std::fs::write(dir.join(file), o.text())?;
    }
    let path = dir.join("scene.xml");
    std::fs::write(&path, xml)?;
    Ok(path)
}
