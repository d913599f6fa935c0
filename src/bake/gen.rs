//! Scene generators: `big-room`, a furnished room of about 150k triangles
//! (after Fig. 6 of the density-estimation paper: tables, chairs, shelves
//! full of books, a lattice of ceiling lights), written as Mitsuba 3 XML
//! with OBJ meshes so that Mitsuba renders it too.

use std::fmt::Write as _;
use std::io::Write as _;
use std::path::Path;

use glam::Vec3;

use crate::image_io::{write_atomic, ImageIoError};
use crate::sampling::Pcg32;

#[derive(Default)]
struct Obj {
    v: Vec<Vec3>,
    f: Vec<[u32; 3]>,
}

impl Obj {
    /// An axis-aligned box, faces outward.
    fn cuboid(&mut self, lo: Vec3, hi: Vec3) {
        let b = self.v.len() as u32;
        for i in 0..8 {
            self.v.push(Vec3::new(
                if i & 1 == 0 { lo.x } else { hi.x },
                if i & 2 == 0 { lo.y } else { hi.y },
                if i & 4 == 0 { lo.z } else { hi.z },
            ));
        }
        // quads counter-clockwise seen from outside
        let q = [
            [0, 2, 3, 1], // z = lo
            [4, 5, 7, 6], // z = hi
            [0, 1, 5, 4], // y = lo
            [2, 6, 7, 3], // y = hi
            [0, 4, 6, 2], // x = lo
            [1, 3, 7, 5], // x = hi
        ];
        for f in q {
            self.f.push([b + f[0], b + f[1], b + f[2]]);
            self.f.push([b + f[0], b + f[2], b + f[3]]);
        }
    }

    fn quad(&mut self, p: [Vec3; 4]) {
        let b = self.v.len() as u32;
        self.v.extend_from_slice(&p);
        self.f.push([b, b + 1, b + 2]);
        self.f.push([b, b + 2, b + 3]);
    }

    fn text(&self) -> String {
        let mut s = String::with_capacity(self.v.len() * 30 + self.f.len() * 20);
        for v in &self.v {
            let _ = writeln!(s, "v {} {} {}", v.x, v.y, v.z);
        }
        for f in &self.f {
            let _ = writeln!(s, "f {} {} {}", f[0] + 1, f[1] + 1, f[2] + 1);
        }
        s
    }
}

fn write(path: &Path, text: &str) -> Result<(), ImageIoError> {
    write_atomic(path, |w| {
        w.write_all(text.as_bytes()).map_err(|e| ImageIoError::Io {
            path: path.to_path_buf(),
            source: e,
        })
    })
}

/// Writes `big-room` into `dir` (scene.xml and meshes/*.obj); returns the
/// triangle count.
pub fn big_room(dir: &Path, seed: u64) -> Result<usize, ImageIoError> {
    let io = |e| ImageIoError::Io {
        path: dir.to_path_buf(),
        source: e,
    };
    std::fs::create_dir_all(dir.join("meshes")).map_err(io)?;
    let mut rng = Pcg32::keyed(&[seed, 0xB16_0000]);
    let (w, h, d) = (16.0f32, 3.0f32, 12.0f32);
    let mut room = Obj::default();
    // inward-facing floor, ceiling and walls
    room.quad([
        Vec3::new(0.0, 0.0, 0.0),
        Vec3::new(0.0, 0.0, d),
        Vec3::new(w, 0.0, d),
        Vec3::new(w, 0.0, 0.0),
    ]);
    let mut ceiling = Obj::default();
    ceiling.quad([
        Vec3::new(0.0, h, 0.0),
        Vec3::new(w, h, 0.0),
        Vec3::new(w, h, d),
        Vec3::new(0.0, h, d),
    ]);
    let mut walls = Obj::default();
    walls.quad([
        Vec3::new(0.0, 0.0, 0.0),
        Vec3::new(w, 0.0, 0.0),
        Vec3::new(w, h, 0.0),
        Vec3::new(0.0, h, 0.0),
    ]);
    walls.quad([
        Vec3::new(0.0, 0.0, d),
        Vec3::new(0.0, h, d),
        Vec3::new(w, h, d),
        Vec3::new(w, 0.0, d),
    ]);
    walls.quad([
        Vec3::new(0.0, 0.0, 0.0),
        Vec3::new(0.0, h, 0.0),
        Vec3::new(0.0, h, d),
        Vec3::new(0.0, 0.0, d),
    ]);
    walls.quad([
        Vec3::new(w, 0.0, 0.0),
        Vec3::new(w, 0.0, d),
        Vec3::new(w, h, d),
        Vec3::new(w, h, 0.0),
    ]);

    let mut wood = Obj::default();
    let mut chairs = Obj::default();
    let mut shelves = Obj::default();
    let mut books = [Obj::default(), Obj::default(), Obj::default()];

    // Tables with four chairs each, on a grid in the middle of the room
    for i in 0..6 {
        for j in 0..4 {
            let c = Vec3::new(3.5 + i as f32 * 1.9, 0.0, 2.6 + j as f32 * 2.3);
            let (tw, td) = (1.2, 0.8);
            wood.cuboid(
                c + Vec3::new(-tw / 2.0, 0.72, -td / 2.0),
                c + Vec3::new(tw / 2.0, 0.76, td / 2.0),
            );
            for (sx, sz) in [(-1.0, -1.0), (1.0, -1.0), (-1.0, 1.0), (1.0, 1.0)] {
                let l = c + Vec3::new(sx * (tw / 2.0 - 0.06), 0.0, sz * (td / 2.0 - 0.06));
                wood.cuboid(
                    l - Vec3::new(0.03, 0.0, 0.03),
                    l + Vec3::new(0.03, 0.72, 0.03),
                );
            }
            for k in 0..4 {
                let side = if k % 2 == 0 { -1.0 } else { 1.0 };
                let off = if k < 2 { -0.3 } else { 0.3 };
                let s = c + Vec3::new(off, 0.0, side * (td / 2.0 + 0.25));
                let jitter = Vec3::new(rng.next_f32() - 0.5, 0.0, rng.next_f32() - 0.5) * 0.1;
                let s = s + jitter;
                chairs.cuboid(
                    s + Vec3::new(-0.22, 0.44, -0.22),
                    s + Vec3::new(0.22, 0.48, 0.22),
                );
                for (lx, lz) in [(-0.19, -0.19), (0.19, -0.19), (-0.19, 0.19), (0.19, 0.19)] {
                    let l = s + Vec3::new(lx, 0.0, lz);
                    chairs.cuboid(
                        l - Vec3::new(0.02, 0.0, 0.02),
                        l + Vec3::new(0.02, 0.44, 0.02),
                    );
                }
                let bz = s.z + side * 0.2;
                chairs.cuboid(
                    Vec3::new(s.x - 0.22, 0.48, bz - 0.02),
                    Vec3::new(s.x + 0.22, 0.95, bz + 0.02),
                );
            }
        }
    }

    // Shelf units along the four walls, filled with books. A unit is built
    // in wall coordinates (a along the wall, y up, depth from the wall) and
    // mapped to the room by `map`.
    let shelf = |a0: f32,
                 map: &dyn Fn(f32, f32, f32) -> Vec3,
                 shelves: &mut Obj,
                 books: &mut [Obj; 3],
                 rng: &mut Pcg32| {
        let put = |o: &mut Obj, lo: Vec3, hi: Vec3| {
            let (p, q) = (map(lo.x, lo.y, lo.z), map(hi.x, hi.y, hi.z));
            o.cuboid(p.min(q), p.max(q));
        };
        let (uw, ud, uh) = (0.9f32, 0.35f32, 2.2f32);
        put(
            shelves,
            Vec3::new(a0, 0.0, 0.0),
            Vec3::new(a0 + 0.02, uh, ud),
        );
        put(
            shelves,
            Vec3::new(a0 + uw - 0.02, 0.0, 0.0),
            Vec3::new(a0 + uw, uh, ud),
        );
        for b in 0..7 {
            let y = 0.05 + b as f32 * 0.36;
            put(
                shelves,
                Vec3::new(a0 + 0.02, y, 0.0),
                Vec3::new(a0 + uw - 0.02, y + 0.02, ud),
            );
            if b == 6 {
                break;
            }
            let mut x = a0 + 0.025;
            loop {
                let t = 0.012 + 0.018 * rng.next_f32();
                if x + t > a0 + uw - 0.025 {
                    break;
                }
                let bh = 0.2 + 0.12 * rng.next_f32();
                let bd = 0.18 + 0.12 * rng.next_f32();
                let k = (rng.next_u32() % 3) as usize;
                put(
                    &mut books[k],
                    Vec3::new(x, y + 0.02, 0.01),
                    Vec3::new(x + t, y + 0.02 + bh, 0.01 + bd),
                );
                x += t + 0.001;
            }
        }
    };
    for i in 0..16 {
        let a0 = 0.4 + i as f32 * 0.95;
        shelf(
            a0,
            &|a, y, p| Vec3::new(a, y, p),
            &mut shelves,
            &mut books,
            &mut rng,
        );
        shelf(
            a0,
            &|a, y, p| Vec3::new(a, y, d - p),
            &mut shelves,
            &mut books,
            &mut rng,
        );
    }
    for i in 0..11 {
        let a0 = 0.55 + i as f32 * 0.95;
        shelf(
            a0,
            &|a, y, p| Vec3::new(p, y, a),
            &mut shelves,
            &mut books,
            &mut rng,
        );
        shelf(
            a0,
            &|a, y, p| Vec3::new(w - p, y, a),
            &mut shelves,
            &mut books,
            &mut rng,
        );
    }

    let parts: [(&str, &Obj, &str); 9] = [
        ("floor", &room, "floor"),
        ("ceiling", &ceiling, "white"),
        ("walls", &walls, "white"),
        ("wood", &wood, "wood"),
        ("chairs", &chairs, "dark"),
        ("shelves", &shelves, "white"),
        ("books-red", &books[0], "red"),
        ("books-green", &books[1], "green"),
        ("books-blue", &books[2], "blue"),
    ];
    let mut tris = 0;
    let mut shapes = String::new();
    for (name, obj, mat) in parts {
        write(&dir.join(format!("meshes/{name}.obj")), &obj.text())?;
        tris += obj.f.len();
        let _ = writeln!(
            shapes,
            "    <shape type=\"obj\" id=\"mesh-{name}\">\n        <string name=\"filename\" value=\"meshes/{name}.obj\"/>\n        <boolean name=\"face_normals\" value=\"true\"/>\n        <ref id=\"{mat}\"/>\n    </shape>"
        );
    }
    // A 4 × 3 lattice of ceiling panels, facing down
    for i in 0..4 {
        for j in 0..3 {
            let (x, z) = (2.0 + i as f32 * 4.0, 2.0 + j as f32 * 4.0);
            let _ = writeln!(
                shapes,
                "    <shape type=\"rectangle\">\n        <transform name=\"to_world\">\n            <scale x=\"0.4\" y=\"0.4\"/>\n            <rotate x=\"1\" angle=\"90\"/>\n            <translate x=\"{x}\" y=\"{}\" z=\"{z}\"/>\n        </transform>\n        <ref id=\"white\"/>\n        <emitter type=\"area\"><rgb name=\"radiance\" value=\"30, 28, 24\"/></emitter>\n    </shape>",
                h - 0.01
            );
            tris += 2;
        }
    }
    let xml = format!(
        r#"<scene version="3.0.0">
    <!-- big-room: generated by `kalos gen big-room` (seed {seed}), {tris} triangles -->
    <integrator type="path"/>
    <sensor type="perspective">
        <float name="fov" value="70"/>
        <transform name="to_world">
            <lookat origin="15.5, 2.2, 6" target="4, 0.6, 6" up="0, 1, 0"/>
        </transform>
        <sampler type="independent"><integer name="sample_count" value="64"/></sampler>
        <film type="hdrfilm">
            <integer name="width" value="320"/>
            <integer name="height" value="240"/>
            <rfilter type="box"/>
        </film>
    </sensor>
    <bsdf type="twosided" id="white"><bsdf type="diffuse"><rgb name="reflectance" value="0.75, 0.74, 0.72"/></bsdf></bsdf>
    <bsdf type="twosided" id="floor"><bsdf type="diffuse"><rgb name="reflectance" value="0.45, 0.38, 0.3"/></bsdf></bsdf>
    <bsdf type="twosided" id="wood"><bsdf type="diffuse"><rgb name="reflectance" value="0.55, 0.36, 0.2"/></bsdf></bsdf>
    <bsdf type="twosided" id="dark"><bsdf type="diffuse"><rgb name="reflectance" value="0.15, 0.15, 0.17"/></bsdf></bsdf>
    <bsdf type="twosided" id="red"><bsdf type="diffuse"><rgb name="reflectance" value="0.6, 0.1, 0.08"/></bsdf></bsdf>
    <bsdf type="twosided" id="green"><bsdf type="diffuse"><rgb name="reflectance" value="0.1, 0.45, 0.12"/></bsdf></bsdf>
    <bsdf type="twosided" id="blue"><bsdf type="diffuse"><rgb name="reflectance" value="0.1, 0.15, 0.55"/></bsdf></bsdf>
{shapes}</scene>
"#
    );
    write(&dir.join("scene.xml"), &xml)?;
    Ok(tris)
}
