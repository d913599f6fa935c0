//! Triangle meshes in object space, and the tessellation of Mitsuba 3's
//! analytic shapes into them.
//!
//! Each analytic shape follows Mitsuba 3's canonical definition, so that a
//! scene file's `to_world` puts it where Mitsuba puts it:
//!
//! | shape | object space | uv (Mitsuba's `si.uv`) |
//! | --- | --- | --- |
//! | [`rectangle`] | `[-1,1]²` at z = 0, normal +z | `((x+1)/2, (y+1)/2)` |
//! | [`cube`] | `[-1,1]³`, flat faces, outward normals | `[0,1]²` on each face |
//! | [`disk`] | unit disk at z = 0, normal +z | `(r, φ/2π)` |
//! | [`sphere`] | unit sphere (then `center`, `radius`), outward | `(φ/2π, θ/π)` |
//!
//! [`LatLong`] is the crate's one sphere tessellation, shared with the
//! generated scenes of [`crate::scenegen`].

use std::f32::consts::{PI, TAU};

use glam::{Mat3, Mat4, Vec2, Vec3};

use crate::geometry;

/// Segments around the rim of a tessellated disk: the polygon's area is
/// `π·sin(2π/n)/(2π/n)`, within 0.04 % of π for n = 128.
pub const DISK_SEGMENTS: u32 = 128;
/// Rings (in θ) of a tessellated sphere; there are twice as many segments in φ.
/// The polyhedron's area is within 0.1 % of 4π. This is the most a sphere of a
/// scene file gets: [`sphere_rings`] gives small spheres fewer.
pub const SPHERE_RINGS: u32 = 48;
/// The fewest rings a sphere of a scene file gets (48 triangles).
pub const SPHERE_MIN_RINGS: u32 = 4;
/// The largest distance between a tessellated sphere and the true one (the
/// sagitta of a segment, `r·(1 − cos(π/2n))` ≈ `r·π²/(8n²)` for n rings), as a
/// fraction of the scene's bounding-box diagonal. docs/notebook/loaders.md ("Geometry:
/// spheres and degenerate BVH inputs") has the measurement behind it.
pub const SPHERE_TOLERANCE: f32 = 1e-4;
/// The most triangles all the spheres of a scene may take together; past it
/// every sphere gets proportionally fewer rings (down to
/// [`SPHERE_MIN_RINGS`]), so that many small spheres load in bounded memory.
pub const SPHERE_TRIANGLE_BUDGET: u64 = 2_000_000;

/// Triangles of a Mitsuba sphere of `rings` rings (the pole rings have one
/// triangle per segment instead of two).
pub fn sphere_triangles(rings: u32) -> u64 {
    let rings = rings.max(2) as u64;
    4 * rings * (rings - 1)
}

/// The rings of each sphere of a scene, from its radius and the scene's
/// bounding-box diagonal `extent`: enough that the tessellation stays within
/// [`SPHERE_TOLERANCE`]·`extent` of the sphere, between [`SPHERE_MIN_RINGS`]
/// and [`SPHERE_RINGS`], and together within [`SPHERE_TRIANGLE_BUDGET`]
/// (every sphere's rings scaled by one factor, so that the large ones stay
/// finer than the small ones). A sphere as large as the scene gets the most.
pub fn sphere_rings(radii: &[f32], extent: f32) -> Vec<u32> {
    let tol = SPHERE_TOLERANCE * extent.max(f32::MIN_POSITIVE);
    let wanted: Vec<f32> = radii
        .iter()
        .map(|&r| {
            let n = PI * (r.abs() / (8.0 * tol)).sqrt();
            if n.is_finite() {
                n
            } else {
                SPHERE_RINGS as f32
            }
        })
        .collect();
    let rings_at = |scale: f32| -> Vec<u32> {
        wanted
            .iter()
            .map(|&n| ((n * scale).ceil() as u32).clamp(SPHERE_MIN_RINGS, SPHERE_RINGS))
            .collect()
    };
    let total = |rings: &[u32]| rings.iter().map(|&n| sphere_triangles(n)).sum::<u64>();
    let full = rings_at(1.0);
    if total(&full) <= SPHERE_TRIANGLE_BUDGET {
        return full;
    }
    // Bisect the scale: the triangle count grows with it
    let (mut lo, mut hi) = (0.0f32, 1.0f32);
    for _ in 0..32 {
        let mid = 0.5 * (lo + hi);
        if total(&rings_at(mid)) <= SPHERE_TRIANGLE_BUDGET {
            lo = mid;
        } else {
            hi = mid;
        }
    }
    rings_at(lo)
}

/// An indexed triangle mesh with optional per-vertex normals and uvs.
#[derive(Clone, Debug, Default)]
pub struct MeshData {
    /// Vertex positions.
    pub positions: Vec<Vec3>,
    /// Per-vertex shading normals (one per position) when the mesh is smooth.
    pub normals: Option<Vec<Vec3>>,
    /// Per-vertex texture coordinates (one per position).
    pub uvs: Option<Vec<Vec2>>,
    /// Vertex indices of each triangle, counter-clockwise around the
    /// geometric normal.
    pub indices: Vec<[u32; 3]>,
}

impl MeshData {
    /// Applies `m` to the positions and its inverse transpose to the normals.
    /// The inverse transpose is taken as the cofactor matrix (times the sign
    /// of the determinant), which stays defined for a singular `m` (a
    /// rectangle squashed to a line keeps a normal).
    pub fn transform(&mut self, m: &Mat4) {
        for p in &mut self.positions {
            *p = m.transform_point3(*p);
        }
        if let Some(normals) = &mut self.normals {
            let cof = normal_matrix(m);
            for n in normals.iter_mut() {
                *n = (cof * *n).normalize_or(*n);
            }
        }
    }

    /// Reverses the orientation: the winding of every triangle and the
    /// direction of every normal.
    pub fn flip(&mut self) {
        for t in &mut self.indices {
            t.swap(1, 2);
        }
        if let Some(normals) = &mut self.normals {
            for n in normals.iter_mut() {
                *n = -*n;
            }
        }
    }

    /// Reverses the winding only (the normals keep their direction).
    pub fn reverse_winding(&mut self) {
        for t in &mut self.indices {
            t.swap(1, 2);
        }
    }

    /// Total area of the triangles.
    pub fn area(&self) -> f32 {
        let n = self.positions.len();
        self.indices
            .iter()
            .filter(|t| t.iter().all(|&i| (i as usize) < n))
            .map(|t| {
                let [a, b, c] = t.map(|i| self.positions[i as usize]);
                0.5 * (b - a).cross(c - a).length()
            })
            .sum()
    }

    /// Replaces the normals by angle-weighted averages of the adjacent face
    /// normals (what Mitsuba 3 does for a mesh file without normals unless
    /// `face_normals` is set). Vertices shared by faces meeting at a crease
    /// get a blended normal: that is the file's choice, not ours.
    pub fn compute_vertex_normals(&mut self) {
        let n = self.positions.len();
        let mut acc = vec![Vec3::ZERO; n];
        for t in &self.indices {
            if t.iter().any(|&i| i as usize >= n) {
                continue;
            }
            let p = t.map(|i| self.positions[i as usize]);
            let face = (p[1] - p[0]).cross(p[2] - p[0]);
            let Some(face) = face.try_normalize() else {
                continue;
            };
            for k in 0..3 {
                let e1 = (p[(k + 1) % 3] - p[k]).normalize_or_zero();
                let e2 = (p[(k + 2) % 3] - p[k]).normalize_or_zero();
                let angle = e1.dot(e2).clamp(-1.0, 1.0).acos();
                acc[t[k] as usize] += face * angle;
            }
        }
        self.normals = Some(acc.into_iter().map(|v| v.normalize_or(Vec3::Z)).collect());
    }
}

/// The matrix that maps normals under `m`: the cofactor matrix of the upper
/// 3×3, with the sign of the determinant, i.e. a positive multiple of the
/// inverse transpose when `m` is invertible.
pub fn normal_matrix(m: &Mat4) -> Mat3 {
    let a = Mat3::from_mat4(*m);
    let (c0, c1, c2) = (a.x_axis, a.y_axis, a.z_axis);
    let cof = Mat3::from_cols(c1.cross(c2), c2.cross(c0), c0.cross(c1));
    if a.determinant() < 0.0 {
        -cof
    } else {
        cof
    }
}

/// Mitsuba's `rectangle`: `[-1,1]²` at z = 0, normal +z (flat).
pub fn rectangle() -> MeshData {
    let positions = vec![
        Vec3::new(-1.0, -1.0, 0.0),
        Vec3::new(1.0, -1.0, 0.0),
        Vec3::new(1.0, 1.0, 0.0),
        Vec3::new(-1.0, 1.0, 0.0),
    ];
    let uvs = positions
        .iter()
        .map(|p| Vec2::new(0.5 * (p.x + 1.0), 0.5 * (p.y + 1.0)))
        .collect();
    MeshData {
        positions,
        normals: None,
        uvs: Some(uvs),
        indices: vec![[0, 1, 2], [0, 2, 3]],
    }
}

/// Mitsuba's `cube`: `[-1,1]³` with flat faces and outward normals
/// (24 vertices, 12 triangles).
pub fn cube() -> MeshData {
    let mut m = MeshData {
        uvs: Some(Vec::new()),
        ..MeshData::default()
    };
    let axes = [Vec3::X, Vec3::Y, Vec3::Z];
    for a in 0..3 {
        for s in [-1.0f32, 1.0] {
            // n = s e_a; u × v = s e_a, so the quad (−u−v, u−v, u+v, −u+v) is
            // counter-clockwise around the outward normal.
            let n = axes[a] * s;
            let u = axes[(a + 1) % 3];
            let v = axes[(a + 2) % 3] * s;
            let base = m.positions.len() as u32;
            for (du, dv) in [(-1.0, -1.0), (1.0, -1.0), (1.0, 1.0), (-1.0, 1.0)] {
                m.positions.push(n + u * du + v * dv);
                if let Some(uvs) = &mut m.uvs {
                    uvs.push(Vec2::new(0.5 * (du + 1.0), 0.5 * (dv + 1.0)));
                }
            }
            m.indices.push([base, base + 1, base + 2]);
            m.indices.push([base, base + 2, base + 3]);
        }
    }
    m
}

/// Mitsuba's `disk`: the unit disk at z = 0, normal +z (flat), as a fan of
/// `segments` triangles.
pub fn disk(segments: u32) -> MeshData {
    let segments = segments.max(3);
    let mut positions = vec![Vec3::ZERO];
    let mut uvs = vec![Vec2::ZERO];
    // one extra rim vertex so that the seam at φ = 2π has its own uv
    for j in 0..=segments {
        let phi = TAU * j as f32 / segments as f32;
        positions.push(Vec3::new(phi.cos(), phi.sin(), 0.0));
        uvs.push(Vec2::new(1.0, j as f32 / segments as f32));
    }
    let indices = (0..segments).map(|j| [0, j + 1, j + 2]).collect();
    MeshData {
        positions,
        normals: None,
        uvs: Some(uvs),
        indices,
    }
}

/// The axis through the poles of a [`LatLong`] sphere.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Pole {
    /// +z, Mitsuba's `sphere`: the unit direction is
    /// (sin θ cos φ, sin θ sin φ, cos θ).
    Z,
    /// +y, for the generated scenes (whose up is +y): the same direction
    /// with y and z exchanged, (sin θ cos φ, cos θ, sin θ sin φ).
    Y,
}

/// Which diagonal cuts each quad (i, j), (i, j+1), (i+1, j), (i+1, j+1) of
/// the latitude–longitude grid, i counting rings and j segments.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Diagonal {
    /// From (i, j) to (i+1, j+1): Mitsuba's `sphere`.
    Main,
    /// From (i, j+1) to (i+1, j): the generated scenes.
    Anti,
}

/// A latitude–longitude tessellation of a sphere, the one sphere
/// tessellation of the crate: Mitsuba's `sphere` shape ([`sphere`]), the
/// spheres of the generated scenes ([`crate::scenegen`]) and of the bench
/// scene all come from [`LatLong::mesh`].
///
/// Vertex (i, j) sits at θ = π·i/rings from the pole and φ = 2π·j/segments
/// with segments = 2·rings, rows i = 0..=rings. The options below differ
/// between the users only because each one's output (scene files on disk,
/// the bench scene's triangle count, rendered images) is fixed.
#[derive(Clone, Copy, Debug)]
pub struct LatLong {
    /// Rings in θ; there are twice as many segments in φ.
    pub rings: u32,
    /// The polar axis.
    pub pole: Pole,
    /// How each grid quad is cut into two triangles.
    pub diagonal: Diagonal,
    /// Repeat the φ = 0 column at φ = 2π, so that the seam has its own uvs
    /// (u = 1); without it the last segment wraps around to column 0 and
    /// the uvs jump there.
    pub seam: bool,
    /// Keep the triangles of the first and last rings that have two
    /// vertices on a pole (zero area up to rounding), so that there are
    /// exactly 2·rings·segments triangles.
    pub pole_triangles: bool,
}

impl LatLong {
    /// Mitsuba's `sphere`: pole +z, main diagonal, a seam, no pole triangles.
    pub fn mitsuba(rings: u32) -> Self {
        LatLong {
            rings,
            pole: Pole::Z,
            diagonal: Diagonal::Main,
            seam: true,
            pole_triangles: false,
        }
    }

    /// The sphere of `radius` (its absolute value) around `center`: smooth
    /// (exact) normals, uvs (φ/2π, θ/π), triangles counter-clockwise seen
    /// from outside.
    pub fn mesh(&self, center: Vec3, radius: f32) -> MeshData {
        let rings = self.rings;
        let segs = 2 * rings;
        let cols = if self.seam { segs + 1 } else { segs };
        let count = ((rings + 1) * cols) as usize;
        let mut positions = Vec::with_capacity(count);
        let mut normals = Vec::with_capacity(count);
        let mut uvs = Vec::with_capacity(count);
        for i in 0..=rings {
            let theta = PI * i as f32 / rings as f32;
            for j in 0..cols {
                let phi = TAU * j as f32 / segs as f32;
                let (x, y, z) = (
                    theta.sin() * phi.cos(),
                    theta.sin() * phi.sin(),
                    theta.cos(),
                );
                let n = match self.pole {
                    Pole::Z => Vec3::new(x, y, z),
                    Pole::Y => Vec3::new(x, z, y),
                };
                positions.push(center + n * radius.abs());
                normals.push(n);
                uvs.push(Vec2::new(j as f32 / segs as f32, i as f32 / rings as f32));
            }
        }

        // Cut each quad along the chosen diagonal. Around +z, ∂p/∂θ × ∂p/∂φ
        // points outward, so a triangle that steps in θ before φ is
        // counter-clockwise seen from outside; exchanging y and z mirrors the
        // sphere, which reverses that. The triangle on the (i, j)–(i+1, j)
        // edge comes first; `north`/`south` say which one has two vertices
        // on a pole in the first/last ring.
        let id = |i: u32, j: u32| i * cols + j % cols;
        let mut indices = Vec::with_capacity((2 * rings * segs) as usize);
        for i in 0..rings {
            for j in 0..segs {
                let (p00, p01) = (id(i, j), id(i, j + 1));
                let (p10, p11) = (id(i + 1, j), id(i + 1, j + 1));
                let (first, second, first_at_north) = match self.diagonal {
                    Diagonal::Main => ([p00, p10, p11], [p00, p11, p01], false),
                    Diagonal::Anti => ([p00, p10, p01], [p01, p10, p11], true),
                };
                let north = i == 0 && !self.pole_triangles;
                let south = i + 1 == rings && !self.pole_triangles;
                let (skip_first, skip_second) = if first_at_north {
                    (north, south)
                } else {
                    (south, north)
                };
                for (mut t, skip) in [(first, skip_first), (second, skip_second)] {
                    if skip {
                        continue;
                    }
                    if self.pole == Pole::Y {
                        t.swap(1, 2);
                    }
                    indices.push(t);
                }
            }
        }
        MeshData {
            positions,
            normals: Some(normals),
            uvs: Some(uvs),
            indices,
        }
    }
}

/// Mitsuba's `sphere` (unit sphere, then `center` and `radius`), as a
/// latitude–longitude mesh of `rings` rings and `2·rings` segments with
/// smooth (exact) normals, in object space: [`LatLong::mitsuba`].
pub fn sphere(center: Vec3, radius: f32, rings: u32) -> MeshData {
    LatLong::mitsuba(rings.max(2)).mesh(center, radius)
}

/// Mitsuba's `lookat` transform, [`geometry::look_at`], or `None` when `up`
/// is parallel to the view direction or `target` equals `origin` (where
/// that one falls back to an arbitrary axis): a loader reports those as
/// errors in the scene file.
pub fn look_at(origin: Vec3, target: Vec3, up: Vec3) -> Option<Mat4> {
    let dir = (target - origin).try_normalize()?;
    up.cross(dir).try_normalize()?;
    Some(geometry::look_at(origin, target, up))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Every variant of the sphere: the triangle count its options promise,
    /// non-degenerate triangles wound outward, vertices on the sphere.
    #[test]
    fn lat_long_counts_and_winding() {
        let (c, r, rings) = (Vec3::new(0.5, -1.0, 2.0), 0.75, 6);
        let segs = 2 * rings;
        for pole in [Pole::Z, Pole::Y] {
            for diagonal in [Diagonal::Main, Diagonal::Anti] {
                for seam in [false, true] {
                    for pole_triangles in [false, true] {
                        let s = LatLong {
                            rings,
                            pole,
                            diagonal,
                            seam,
                            pole_triangles,
                        };
                        let m = s.mesh(c, r);
                        let cols = segs + seam as u32;
                        assert_eq!(m.positions.len() as u32, (rings + 1) * cols);
                        let tris = 2 * rings * segs - if pole_triangles { 0 } else { 2 * segs };
                        assert_eq!(m.indices.len() as u32, tris, "{s:?}");
                        for p in &m.positions {
                            assert!(((*p - c).length() - r).abs() < 1e-5);
                        }
                        for t in &m.indices {
                            let [a, b, d] = t.map(|i| m.positions[i as usize]);
                            let n = (b - a).cross(d - a);
                            if n.length() > 1e-6 {
                                assert!(n.dot((a + b + d) / 3.0 - c) > 0.0, "{s:?} {t:?}");
                            }
                        }
                    }
                }
            }
        }
    }

    /// Mitsuba's sphere has its pole on +z, the generated scenes' on +y.
    #[test]
    fn lat_long_poles() {
        let mut s = LatLong::mitsuba(4);
        assert_eq!(s.mesh(Vec3::ZERO, 1.0).positions[0], Vec3::Z);
        s.pole = Pole::Y;
        assert_eq!(s.mesh(Vec3::ZERO, 1.0).positions[0], Vec3::Y);
    }

    /// A degenerate lookat is `None`; otherwise the matrix is geometry's.
    #[test]
    fn look_at_reports_degenerate_input() {
        assert!(look_at(Vec3::ONE, Vec3::ONE, Vec3::Y).is_none());
        assert!(look_at(Vec3::ZERO, Vec3::Y, Vec3::Y).is_none());
        let (o, t) = (Vec3::new(1.0, 2.0, 3.0), Vec3::new(0.0, 0.5, -1.0));
        assert_eq!(
            look_at(o, t, Vec3::Y),
            Some(geometry::look_at(o, t, Vec3::Y))
        );
    }
}
