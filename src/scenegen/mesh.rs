//! The mesh builder of the generated scenes and its OBJ text.

use std::f32::consts::PI;
use std::fmt::Write as _;

use glam::{Vec2, Vec3};

use crate::scene::shapes::{Diagonal, LatLong, MeshData, Pole};

/// The faces of a box over its corners (bit 0: x, bit 1: y, bit 2: z set
/// to the high side), each quad counter-clockwise seen from outside.
const CUBOID_FACES: [[u32; 4]; 6] = [
    [0, 2, 3, 1], // z = lo
    [4, 5, 7, 6], // z = hi
    [0, 1, 5, 4], // y = lo
    [2, 6, 7, 3], // y = hi
    [0, 4, 6, 2], // x = lo
    [1, 3, 7, 5], // x = hi
];

/// A triangle mesh under construction: each builder appends its vertices
/// and triangles. Normals and uvs are each either absent (empty) or one
/// per vertex.
#[derive(Default)]
pub(crate) struct Mesh {
    /// Vertex positions.
    pub positions: Vec<Vec3>,
    /// Per-vertex normals, or empty.
    pub normals: Vec<Vec3>,
    /// Per-vertex texture coordinates (OBJ convention, v up), or empty.
    pub uvs: Vec<Vec2>,
    /// Vertex indices of each triangle.
    pub indices: Vec<[u32; 3]>,
}

impl Mesh {
    /// The next vertex index.
    fn base(&self) -> u32 {
        self.positions.len() as u32
    }

    /// Two triangles (a, b, c) and (a, c, d) over existing vertices.
    pub fn quad_indices(&mut self, [a, b, c, d]: [u32; 4]) {
        self.indices.push([a, b, c]);
        self.indices.push([a, c, d]);
    }

    /// A quad of four new vertices, counter-clockwise around its front.
    pub fn quad(&mut self, p: [Vec3; 4]) {
        let b = self.base();
        self.positions.extend_from_slice(&p);
        self.quad_indices([b, b + 1, b + 2, b + 3]);
    }

    /// A quad of four new vertices with their texture coordinates.
    pub fn quad_uv(&mut self, p: [Vec3; 4], uv: [Vec2; 4]) {
        debug_assert_eq!(self.uvs.len(), self.positions.len());
        self.uvs.extend_from_slice(&uv);
        self.quad(p);
    }

    /// An axis-aligned box, faces outward, each face its own four vertices
    /// so that each can carry the whole `cell` of the texture: u runs from
    /// `cell.0` to `cell.1` along the face's horizontal side (x, or z on the
    /// faces normal to x), v from 0 to 1 upward (along z on the top and
    /// bottom).
    pub fn cuboid_uv(&mut self, lo: Vec3, hi: Vec3, cell: (f32, f32)) {
        let corner = |i: u32| {
            Vec3::new(
                if i & 1 == 0 { lo.x } else { hi.x },
                if i & 2 == 0 { lo.y } else { hi.y },
                if i & 4 == 0 { lo.z } else { hi.z },
            )
        };
        let size = (hi - lo).max(Vec3::splat(f32::MIN_POSITIVE));
        for (k, f) in CUBOID_FACES.iter().enumerate() {
            let p = f.map(corner);
            let uv = p.map(|c| {
                let t = (c - lo) / size;
                let (s, v) = match k / 2 {
                    0 => (t.x, t.y), // normal z
                    1 => (t.x, t.z), // normal y
                    _ => (t.z, t.y), // normal x
                };
                Vec2::new(cell.0 + (cell.1 - cell.0) * s, v)
            });
            self.quad_uv(p, uv);
        }
    }

    /// An axis-aligned box, faces outward.
    pub fn cuboid(&mut self, lo: Vec3, hi: Vec3) {
        let b = self.base();
        for i in 0..8 {
            self.positions.push(Vec3::new(
                if i & 1 == 0 { lo.x } else { hi.x },
                if i & 2 == 0 { lo.y } else { hi.y },
                if i & 4 == 0 { lo.z } else { hi.z },
            ));
        }
        for f in CUBOID_FACES {
            self.quad_indices(f.map(|i| b + i));
        }
    }

    /// Appends a mesh of the shapes module (positions, normals if it has
    /// them, triangles; its uvs are not written to OBJ here).
    pub fn append(&mut self, m: &MeshData) {
        let b = self.base();
        self.positions.extend_from_slice(&m.positions);
        if let Some(n) = &m.normals {
            self.normals.extend_from_slice(n);
        }
        self.indices
            .extend(m.indices.iter().map(|t| t.map(|i| b + i)));
    }

    /// A sphere around +y with `rings` rings and 2·rings segments, outward
    /// normals: the crate's [`LatLong`] tessellation, welded at the seam.
    pub fn sphere(&mut self, c: Vec3, r: f32, rings: u32) {
        let sphere = LatLong {
            rings,
            pole: Pole::Y,
            diagonal: Diagonal::Anti,
            seam: false,
            pole_triangles: false,
        };
        self.append(&sphere.mesh(c, r));
    }

    /// A surface of revolution around +y of a profile (radius, height),
    /// normals outward when the profile runs upward.
    pub fn lathe(&mut self, c: Vec3, profile: &[(f32, f32)], segs: u32) {
        let base = self.base();
        for &(r, y) in profile {
            for j in 0..segs {
                let ph = 2.0 * PI * j as f32 / segs as f32;
                self.positions
                    .push(c + Vec3::new(r * ph.cos(), y, r * ph.sin()));
            }
        }
        for i in 0..profile.len() as u32 - 1 {
            for j in 0..segs {
                let a = base + i * segs + j;
                let b = base + i * segs + (j + 1) % segs;
                let c2 = a + segs;
                let d = b + segs;
                self.indices.push([a, c2, b]);
                self.indices.push([b, c2, d]);
            }
        }
    }

    /// A tube along a curve `p(t)`, t in [0, 1], radius `r(t)`.
    pub fn tube(&mut self, p: impl Fn(f32) -> Vec3, r: impl Fn(f32) -> f32, n: u32, segs: u32) {
        let base = self.base();
        for i in 0..=n {
            let t = i as f32 / n as f32;
            let c = p(t);
            let tan = (p((t + 0.01).min(1.0)) - p((t - 0.01).max(0.0))).normalize_or(Vec3::Y);
            let u = tan.any_orthonormal_vector();
            let w = tan.cross(u);
            for j in 0..segs {
                let ph = 2.0 * PI * j as f32 / segs as f32;
                self.positions
                    .push(c + (u * ph.cos() + w * ph.sin()) * r(t));
            }
        }
        for i in 0..n {
            for j in 0..segs {
                let a = base + i * segs + j;
                let b = base + i * segs + (j + 1) % segs;
                self.indices.push([a, b, a + segs]);
                self.indices.push([b, b + segs, a + segs]);
            }
        }
    }

    /// A height field `y = h(x, z)` over [x0, x1] × [z0, z1] on an n × n
    /// grid, front side up.
    pub fn grid(
        &mut self,
        n: u32,
        x0: f32,
        x1: f32,
        z0: f32,
        z1: f32,
        h: impl Fn(f32, f32) -> f32,
    ) {
        let base = self.base();
        for i in 0..=n {
            for j in 0..=n {
                let x = x0 + (x1 - x0) * j as f32 / n as f32;
                let z = z0 + (z1 - z0) * i as f32 / n as f32;
                self.positions.push(Vec3::new(x, h(x, z), z));
            }
        }
        let id = |i: u32, j: u32| base + i * (n + 1) + j;
        for i in 0..n {
            for j in 0..n {
                self.indices.push([id(i, j), id(i + 1, j), id(i, j + 1)]);
                self.indices
                    .push([id(i, j + 1), id(i + 1, j), id(i + 1, j + 1)]);
            }
        }
    }

    /// The mesh as Wavefront OBJ: `v` lines, `vt` and `vn` lines when there
    /// is one uv or normal per vertex, then 1-based `f` lines.
    pub fn obj_text(&self) -> String {
        debug_assert!(self.normals.is_empty() || self.normals.len() == self.positions.len());
        debug_assert!(self.uvs.is_empty() || self.uvs.len() == self.positions.len());
        let mut s = String::with_capacity(self.positions.len() * 30 + self.indices.len() * 20);
        for v in &self.positions {
            let _ = writeln!(s, "v {} {} {}", v.x, v.y, v.z);
        }
        for t in &self.uvs {
            let _ = writeln!(s, "vt {} {}", t.x, t.y);
        }
        for n in &self.normals {
            let _ = writeln!(s, "vn {} {} {}", n.x, n.y, n.z);
        }
        let with_n = !self.normals.is_empty();
        let with_t = !self.uvs.is_empty();
        for f in &self.indices {
            let [a, b, c] = f.map(|i| i + 1);
            let _ = match (with_t, with_n) {
                (false, false) => writeln!(s, "f {a} {b} {c}"),
                (false, true) => writeln!(s, "f {a}//{a} {b}//{b} {c}//{c}"),
                (true, false) => writeln!(s, "f {a}/{a} {b}/{b} {c}/{c}"),
                (true, true) => writeln!(s, "f {a}/{a}/{a} {b}/{b}/{b} {c}/{c}/{c}"),
            };
        }
        s
    }
}
