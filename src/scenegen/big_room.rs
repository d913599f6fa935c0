//! `big-room`: a furnished room of about 150k triangles (after Fig. 6 of the
//! density-estimation paper: tables, chairs, shelves full of books, a
//! lattice of ceiling lights), its furniture jittered by a seed; textured,
//! the same layout with bitmaps on the floor, the walls and the books.

use std::fmt::Write as _;

use glam::{Vec2, Vec3};
use image::RgbImage;

use super::mesh::Mesh;
use super::{textures, SceneFiles};
use crate::sampling::Pcg32;

/// Metres of floor covered by one copy of the wood texture (eight planks).
const WOOD_TILE: f32 = 1.6;
/// Metres of wall covered by one copy of the wallpaper (four stripes).
const WALLPAPER_TILE: f32 = 0.8;

/// A quad of `mesh`; with `tile` (metres per texture copy), uvs from the
/// corners' coordinates along `axes` (two of x, y, z).
fn quad(mesh: &mut Mesh, p: [Vec3; 4], tile: Option<f32>, axes: [usize; 2]) {
    match tile {
        Some(t) => mesh.quad_uv(p, p.map(|c| Vec2::new(c[axes[0]], c[axes[1]]) / t)),
        None => mesh.quad(p),
    }
}

/// Room width (x), height (y) and depth (z), in metres.
const ROOM: (f32, f32, f32) = (16.0, 3.0, 12.0);

/// The scene: `meshes/*.obj` and `scene.xml` (and `textures/*.png` when
/// `textured`), the furniture laid out by `seed` alike either way.
pub(super) fn build(seed: u64, textured: bool) -> SceneFiles {
    let mut rng = Pcg32::keyed(&[seed, 0xB16_0000]);
    let (room, ceiling, walls) = shell(textured);
    let (wood, chairs) = tables(&mut rng);
    let (shelves, books) = shelves(textured, &mut rng);

    // One mesh file per material
    let [red, green, blue] = books;
    let walls_mat = if textured { "wallpaper" } else { "white" };
    let mut parts: Vec<(&str, Mesh, &str)> = vec![
        ("floor", room, "floor"),
        ("ceiling", ceiling, "white"),
        ("walls", walls, walls_mat),
        ("wood", wood, "wood"),
        ("chairs", chairs, "dark"),
        ("shelves", shelves, "white"),
    ];
    if textured {
        parts.push(("books", red, "books"));
    } else {
        parts.extend([
            ("books-red", red, "red"),
            ("books-green", green, "green"),
            ("books-blue", blue, "blue"),
        ]);
    }
    let (shapes, meshes, tris) = shapes(parts);
    let (name, floor, images) = materials(textured);
    SceneFiles {
        meshes,
        images,
        xml: scene_xml(name, seed, tris, &floor, &shapes),
    }
}

/// The inward-facing floor (planks along x), ceiling and walls (u along
/// the wall, v up), with uvs when `textured`.
fn shell(textured: bool) -> (Mesh, Mesh, Mesh) {
    let (w, h, d) = ROOM;
    let floor_tile = textured.then_some(WOOD_TILE);
    let wall_tile = textured.then_some(WALLPAPER_TILE);
    let mut room = Mesh::default();
    quad(
        &mut room,
        [
            Vec3::new(0.0, 0.0, 0.0),
            Vec3::new(0.0, 0.0, d),
            Vec3::new(w, 0.0, d),
            Vec3::new(w, 0.0, 0.0),
        ],
        floor_tile,
        [0, 2],
    );
    let mut ceiling = Mesh::default();
    ceiling.quad([
        Vec3::new(0.0, h, 0.0),
        Vec3::new(w, h, 0.0),
        Vec3::new(w, h, d),
        Vec3::new(0.0, h, d),
    ]);
    let mut walls = Mesh::default();
    for (p, along) in [
        (
            [
                Vec3::new(0.0, 0.0, 0.0),
                Vec3::new(w, 0.0, 0.0),
                Vec3::new(w, h, 0.0),
                Vec3::new(0.0, h, 0.0),
            ],
            0,
        ),
        (
            [
                Vec3::new(0.0, 0.0, d),
                Vec3::new(0.0, h, d),
                Vec3::new(w, h, d),
                Vec3::new(w, 0.0, d),
            ],
            0,
        ),
        (
            [
                Vec3::new(0.0, 0.0, 0.0),
                Vec3::new(0.0, h, 0.0),
                Vec3::new(0.0, h, d),
                Vec3::new(0.0, 0.0, d),
            ],
            2,
        ),
        (
            [
                Vec3::new(w, 0.0, 0.0),
                Vec3::new(w, 0.0, d),
                Vec3::new(w, h, d),
                Vec3::new(w, h, 0.0),
            ],
            2,
        ),
    ] {
        quad(&mut walls, p, wall_tile, [along, 1]);
    }
    (room, ceiling, walls)
}

/// Tables with four chairs each, on a 6 × 4 grid in the middle of the
/// room, the chairs jittered by `rng`: (the tables' wood, the chairs).
fn tables(rng: &mut Pcg32) -> (Mesh, Mesh) {
    let mut wood = Mesh::default();
    let mut chairs = Mesh::default();
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
                chair(&mut chairs, s + jitter, side);
            }
        }
    }
    (wood, chairs)
}

/// A chair standing at `s` (floor level), its back on the `side` (±1) of
/// z away from the table.
fn chair(chairs: &mut Mesh, s: Vec3, side: f32) {
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

/// Shelf units along the four walls, filled with books drawn by `rng`:
/// (the shelves, the books by colour; textured, all books in the first).
fn shelves(textured: bool, rng: &mut Pcg32) -> (Mesh, [Mesh; 3]) {
    let (w, _, d) = ROOM;
    let mut shelves = Mesh::default();
    let mut books = [Mesh::default(), Mesh::default(), Mesh::default()];
    let mut unit = |a0: f32, map: &dyn Fn(f32, f32, f32) -> Vec3| {
        shelf_unit(a0, map, textured, &mut shelves, &mut books, rng);
    };
    for i in 0..16 {
        let a0 = 0.4 + i as f32 * 0.95;
        unit(a0, &|a, y, p| Vec3::new(a, y, p));
        unit(a0, &|a, y, p| Vec3::new(a, y, d - p));
    }
    for i in 0..11 {
        let a0 = 0.55 + i as f32 * 0.95;
        unit(a0, &|a, y, p| Vec3::new(p, y, a));
        unit(a0, &|a, y, p| Vec3::new(w - p, y, a));
    }
    (shelves, books)
}

/// One shelf unit starting at `a0` along its wall, with its books. The
/// unit is built in wall coordinates (a along the wall, y up, depth from
/// the wall) and mapped to the room by `map`.
fn shelf_unit(
    a0: f32,
    map: &dyn Fn(f32, f32, f32) -> Vec3,
    textured: bool,
    shelves: &mut Mesh,
    books: &mut [Mesh; 3],
    rng: &mut Pcg32,
) {
    let put = |o: &mut Mesh, lo: Vec3, hi: Vec3| {
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
        // Books side by side until the board is full
        let mut x = a0 + 0.025;
        loop {
            let t = 0.012 + 0.018 * rng.next_f32();
            if x + t > a0 + uw - 0.025 {
                break;
            }
            let bh = 0.2 + 0.12 * rng.next_f32();
            let bd = 0.18 + 0.12 * rng.next_f32();
            let k = (rng.next_u32() % 3) as usize;
            let (lo, hi) = (
                Vec3::new(x, y + 0.02, 0.01),
                Vec3::new(x + t, y + 0.02 + bh, 0.01 + bd),
            );
            if textured {
                // one mesh, the spine drawn from the book's place (the
                // random draws stay those of the untextured room)
                let (p, q) = (map(lo.x, lo.y, lo.z), map(hi.x, hi.y, hi.z));
                let cell = spine_cell(lo);
                books[0].cuboid_uv(p.min(q), p.max(q), cell);
            } else {
                put(&mut books[k], lo, hi);
            }
            x += t + 0.001;
        }
    }
}

/// The `<shape>` elements of `parts` (name, mesh, material) and of the
/// 4 × 3 lattice of ceiling panels facing down; the mesh files; the
/// triangle count.
fn shapes(parts: Vec<(&str, Mesh, &str)>) -> (String, Vec<(String, Mesh)>, usize) {
    let (_, h, _) = ROOM;
    let mut tris = 0;
    let mut shapes = String::new();
    let mut meshes = Vec::new();
    for (name, mesh, mat) in parts {
        tris += mesh.indices.len();
        meshes.push((format!("meshes/{name}.obj"), mesh));
        let _ = writeln!(
            shapes,
            "    <shape type=\"obj\" id=\"mesh-{name}\">\n        <string name=\"filename\" value=\"meshes/{name}.obj\"/>\n        <boolean name=\"face_normals\" value=\"true\"/>\n        <ref id=\"{mat}\"/>\n    </shape>"
        );
    }
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
    (shapes, meshes, tris)
}

/// The scene's name, the rest of the floor's `<bsdf>` and the materials
/// after it, and the texture images: bitmaps with `textured`, plain
/// colours (and the three book colours) without.
fn materials(textured: bool) -> (&'static str, String, Vec<(String, RgbImage)>) {
    if textured {
        let bitmap = |f: &str| {
            format!("<texture type=\"bitmap\" name=\"reflectance\"><string name=\"filename\" value=\"textures/{f}\"/></texture>")
        };
        let extra = format!(
            "    <bsdf type=\"twosided\" id=\"wallpaper\"><bsdf type=\"diffuse\">{}</bsdf></bsdf>\n    <bsdf type=\"twosided\" id=\"books\"><bsdf type=\"diffuse\">{}</bsdf></bsdf>\n",
            bitmap("wallpaper.png"),
            bitmap("spines.png")
        );
        let images = vec![
            ("textures/wood.png".to_string(), textures::wood()),
            ("textures/wallpaper.png".to_string(), textures::wallpaper()),
            ("textures/spines.png".to_string(), textures::spines()),
        ];
        (
            "big-room-textured",
            bitmap("wood.png") + "</bsdf></bsdf>\n" + &extra,
            images,
        )
    } else {
        let floor = r#"<rgb name="reflectance" value="0.45, 0.38, 0.3"/></bsdf></bsdf>
    <bsdf type="twosided" id="red"><bsdf type="diffuse"><rgb name="reflectance" value="0.6, 0.1, 0.08"/></bsdf></bsdf>
    <bsdf type="twosided" id="green"><bsdf type="diffuse"><rgb name="reflectance" value="0.1, 0.45, 0.12"/></bsdf></bsdf>
    <bsdf type="twosided" id="blue"><bsdf type="diffuse"><rgb name="reflectance" value="0.1, 0.15, 0.55"/></bsdf></bsdf>
"#;
        ("big-room", floor.to_string(), Vec::new())
    }
}

/// `scene.xml`: the camera and the materials, then `floor` (the floor's
/// reflectance and the materials after it) and `shapes`.
fn scene_xml(name: &str, seed: u64, tris: usize, floor: &str, shapes: &str) -> String {
    format!(
        r#"<scene version="3.0.0">
    <!-- {name}: generated by `kalos gen {name}` (seed {seed}), {tris} triangles -->
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
    <bsdf type="twosided" id="wood"><bsdf type="diffuse"><rgb name="reflectance" value="0.55, 0.36, 0.2"/></bsdf></bsdf>
    <bsdf type="twosided" id="dark"><bsdf type="diffuse"><rgb name="reflectance" value="0.15, 0.15, 0.17"/></bsdf></bsdf>
    <bsdf type="twosided" id="floor"><bsdf type="diffuse">{floor}{shapes}</scene>
"#
    )
}

/// The spine of the book whose near lower corner (in wall coordinates) is
/// `lo`: a hash of its place picks one of the [`textures::SPINES`] cells.
fn spine_cell(lo: Vec3) -> (f32, f32) {
    let key = ((lo.x * 1000.0) as i64 as u64) ^ (((lo.y * 100.0) as i64 as u64) << 20);
    let k = (crate::sampling::mix64(key) % textures::SPINES as u64) as f32;
    let n = textures::SPINES as f32;
    (k / n, (k + 1.0) / n)
}
