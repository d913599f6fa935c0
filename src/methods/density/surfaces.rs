//! Surfaces of the density estimate: coplanar, connected triangles of one
//! shape grouped into planar surfaces with a 2D chart (§3.2: "a locally
//! planar surface with orthogonal length parameters (u, v)"), and curved or
//! finely tessellated shapes whose triangles are estimated with a 3D kernel.
//! Which is which follows the geometry, not the shading normals alone
//! ([`build`]).
//!
//! Surfaces whose material has a diffuse part receive hits (the paper's
//! Lambertian surfaces with L = R·H/π, and the diffuse part of `phong`,
//! `plastic` and `roughplastic`: [`crate::bsdf::DiffusePart`]); the rest of
//! every material is ray-traced in the view pass.

use std::collections::HashMap;

use glam::{Vec2, Vec3};

use super::kernel::{TriGrid, NORMAL_COS};
use crate::scene::{Material, Scene, Texture};

/// A receiving surface and the side of it a hit or a mesh is for: the one
/// place where the side-tagged id of the hit file is encoded and decoded.
///
/// On disk and in every ordering, the id is the u32 `index | back << 31`
/// (§4.1 stores "the surface id (4 bytes)"; the side bit is ours: a
/// two-sided surface is lit separately on each side). The order of
/// [`SurfaceId`] is that of the encoded u32, front sides before back sides,
/// so that sorting by it sorts the records as the hit file holds them.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub struct SurfaceId {
    /// Index into [`Surfaces::list`].
    pub index: u32,
    /// True for the back side (against the triangles' normal).
    pub back: bool,
}

impl SurfaceId {
    /// The side bit of the encoded id.
    const BACK: u32 = 1 << 31;

    /// The front side of surface `index`.
    #[inline]
    pub fn front(index: u32) -> Self {
        SurfaceId { index, back: false }
    }

    /// The encoded id: `index`, with bit 31 set for the back side.
    #[inline]
    pub fn encode(self) -> u32 {
        debug_assert!(self.index < Self::BACK, "surface index {}", self.index);
        self.index | if self.back { Self::BACK } else { 0 }
    }

    /// The id of an encoded value (every u32 is one).
    #[inline]
    pub fn decode(v: u32) -> Self {
        SurfaceId {
            index: v & !Self::BACK,
            back: v & Self::BACK != 0,
        }
    }

    /// Position in per-side tables: 2·index + side.
    #[inline]
    pub fn side_index(self) -> usize {
        2 * self.index as usize + usize::from(self.back)
    }
}

impl Ord for SurfaceId {
    fn cmp(&self, other: &Self) -> std::cmp::Ordering {
        self.encode().cmp(&other.encode())
    }
}

impl PartialOrd for SurfaceId {
    fn partial_cmp(&self, other: &Self) -> Option<std::cmp::Ordering> {
        Some(self.cmp(other))
    }
}

/// How a surface is parameterised.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Kind {
    /// A planar group with a 2D chart; hits store chart coordinates.
    Planar,
    /// One triangle of a curved shape; hits store barycentrics, and the
    /// estimate is made over the whole shape with a 3D kernel.
    Curved,
}

/// One receiving surface.
#[derive(Clone, Debug)]
pub struct Surface {
    /// Planar group or curved triangle.
    pub kind: Kind,
    /// The shape it belongs to.
    pub shape: u32,
    /// Its triangles (one for a curved surface).
    pub tris: Vec<u32>,
    /// Chart origin (world).
    pub origin: Vec3,
    /// Chart u axis (unit, world).
    pub su: Vec3,
    /// Chart v axis (unit, world).
    pub sv: Vec3,
    /// Plane normal (the triangles' front side).
    pub normal: Vec3,
    /// Chart extent: u ∈ [0, size.x], v ∈ [0, size.y].
    pub size: Vec2,
    /// Area.
    pub area: f32,
    /// True when the group is exactly its chart rectangle.
    pub rectangle: bool,
    /// True when the material has a diffuse part, so the surface records
    /// hits and carries baked lighting.
    pub diffuse: bool,
    /// The diffuse reflectance R_d at the surface's first vertex (exact for
    /// untextured materials; see [`Surface::reflectance_at`]).
    pub reflectance: Vec3,
    /// True when R_d varies over the surface (a textured diffuse albedo).
    pub textured: bool,
}

impl Surface {
    /// Chart coordinates of a world point.
    #[inline]
    pub fn to_chart(&self, p: Vec3) -> Vec2 {
        let d = p - self.origin;
        Vec2::new(d.dot(self.su), d.dot(self.sv))
    }

    /// World point of chart coordinates.
    #[inline]
    pub fn to_world(&self, c: Vec2) -> Vec3 {
        self.origin + self.su * c.x + self.sv * c.y
    }

    /// R_d at chart points `pts` of a planar surface (at the corners
    /// (b1, b2) ∈ {(0,0), (1,0), (0,1)} of a curved one's triangle, given as
    /// `pts`): the material's textures looked up through the mesh uvs of
    /// the triangle containing each point, so that the display mesh carries
    /// R(u, v)·H/π with the reflectance at each vertex (§3.2). Untextured
    /// materials: [`Surface::reflectance`] everywhere.
    pub fn reflectance_at(&self, scene: &Scene, pts: &[Vec2]) -> Vec<Vec3> {
        if !self.textured {
            return vec![self.reflectance; pts.len()];
        }
        let material = &scene.materials[scene.shapes[self.shape as usize].material as usize];
        let rd = |tri: u32, b1: f32, b2: f32| {
            let uv = scene.surface_point(tri, b1, b2).uv;
            diffuse_reflectance(material, uv).unwrap_or(Vec3::ZERO)
        };
        if self.kind == Kind::Curved {
            return pts.iter().map(|b| rd(self.tris[0], b.x, b.y)).collect();
        }
        let ct = self.chart_tris(scene);
        let mut pv = Vec::with_capacity(ct.len() * 3);
        let mut pt = Vec::with_capacity(ct.len());
        for t in &ct {
            let b = pv.len() as u32;
            pv.extend_from_slice(t);
            pt.push([b, b + 1, b + 2]);
        }
        let grid = TriGrid::new(&pv, &pt);
        pts.iter()
            .map(|&c| match grid.locate(&pv, &pt, c) {
                Some((t, b)) => rd(self.tris[t as usize], b.y, b.z),
                None => self.reflectance,
            })
            .collect()
    }

    /// The triangles in chart coordinates.
    pub fn chart_tris(&self, scene: &Scene) -> Vec<[Vec2; 3]> {
        self.tris
            .iter()
            .map(|&t| scene.tri_vertices(t).map(|p| self.to_chart(p)))
            .collect()
    }
}

/// All receiving surfaces of a scene, and the surface of every triangle.
#[derive(Clone, Debug)]
pub struct Surfaces {
    /// The surfaces; the index is [`SurfaceId::index`].
    pub list: Vec<Surface>,
    /// Surface index of each scene triangle.
    pub tri_surface: Vec<u32>,
}

impl Surfaces {
    /// The surface an id names (either side).
    #[inline]
    pub fn get(&self, id: SurfaceId) -> Option<&Surface> {
        self.list.get(id.index as usize)
    }

    /// The surface an id names; the id must come from these surfaces.
    #[inline]
    pub fn of(&self, id: SurfaceId) -> &Surface {
        &self.list[id.index as usize]
    }
}

/// The diffuse reflectance R_d of a material at `uv`, if it has a diffuse
/// part: R for `diffuse` (exactly its texture), π k T̄ for the others
/// ([`crate::bsdf::DiffusePart::rd`]).
pub fn diffuse_reflectance(m: &Material, uv: Vec2) -> Option<Vec3> {
    match m {
        Material::Diffuse { reflectance } => Some(reflectance.eval(uv)),
        Material::TwoSided(inner) => diffuse_reflectance(inner, uv),
        _ => m.bsdf(uv).diffuse_part().map(|d| d.rd()),
    }
}

/// Whether a material's surfaces record hits (`diffuse` always, as the
/// paper's Lambertian surfaces, even black ones; the other models when
/// their diffuse albedo is not zero everywhere), and whether that albedo is
/// textured.
fn records_hits(m: &Material) -> (bool, bool) {
    fn lambertian(m: &Material) -> bool {
        match m {
            Material::Diffuse { .. } => true,
            Material::TwoSided(inner) => lambertian(inner),
            _ => false,
        }
    }
    match (lambertian(m), m.diffuse_texture()) {
        (true, Some(t)) => (true, !matches!(t, Texture::Constant(_))),
        (false, Some(t)) => (
            t.mean().max_element() > 0.0,
            !matches!(t, Texture::Constant(_)),
        ),
        _ => (false, false),
    }
}

fn find(parent: &mut [u32], mut x: u32) -> u32 {
    while parent[x as usize] != x {
        let p = parent[x as usize];
        parent[x as usize] = parent[p as usize];
        x = p;
    }
    x
}

/// Groups the triangles of `scene`. A shape is curved (one surface per
/// triangle) when its shading normals leave its face normals and its
/// geometry folds gently somewhere ([`curved_shapes`]); otherwise triangles
/// of one shape that share an edge and lie in one plane (normals within
/// 1e-4, offsets within 1e-5 of the scene size) join one planar surface.
pub fn build(scene: &Scene) -> Surfaces {
    let nt = scene.triangles.len();
    let (lo, hi) = scene.bounds();
    let scale = (hi - lo).max_element().max(1e-6);
    let q = |p: Vec3| {
        let s = (p - lo) / scale * 1e6;
        (s.x.round() as i64, s.y.round() as i64, s.z.round() as i64)
    };
    let normal = |t: u32| {
        let [a, b, c] = scene.tri_vertices(t);
        (b - a).cross(c - a).normalize_or(Vec3::Z)
    };

    let curved = curved_shapes(scene, &q, &normal);

    // Union-find over shared edges of coplanar triangles of one flat shape
    let mut parent: Vec<u32> = (0..nt as u32).collect();
    type Key = (i64, i64, i64);
    let mut edges: HashMap<(Key, Key), u32> = HashMap::new();
    for (t, tri) in scene.triangles.iter().enumerate() {
        let shape = scene.tri_shape[t] as usize;
        if curved[shape] {
            continue;
        }
        let keys = tri.map(|i| q(scene.positions[i as usize]));
        for e in 0..3 {
            let (a, b) = (keys[e], keys[(e + 1) % 3]);
            let key = if a < b { (a, b) } else { (b, a) };
            match edges.get(&key) {
                Some(&o) => {
                    let same_shape = scene.tri_shape[o as usize] as usize == shape;
                    let (n0, n1) = (normal(o), normal(t as u32));
                    let p0 = scene.tri_vertices(o)[0];
                    let p1 = scene.tri_vertices(t as u32)[0];
                    let coplanar =
                        n0.dot(n1) > 1.0 - 1e-4 && (p1 - p0).dot(n0).abs() < 1e-5 * scale;
                    if same_shape && coplanar {
                        let (ra, rb) = (find(&mut parent, o), find(&mut parent, t as u32));
                        if ra != rb {
                            parent[ra.max(rb) as usize] = ra.min(rb);
                        }
                    }
                }
                None => {
                    edges.insert(key, t as u32);
                }
            }
        }
    }
    drop(edges);

    // Collect the groups in triangle order (deterministic ids)
    let mut group_of_root: HashMap<u32, u32> = HashMap::new();
    let mut groups: Vec<Vec<u32>> = Vec::new();
    let mut tri_surface = vec![0u32; nt];
    for t in 0..nt as u32 {
        let r = if curved[scene.tri_shape[t as usize] as usize] {
            u32::MAX - t // every curved triangle is its own group
        } else {
            find(&mut parent, t)
        };
        let g = *group_of_root.entry(r).or_insert_with(|| {
            groups.push(Vec::new());
            (groups.len() - 1) as u32
        });
        groups[g as usize].push(t);
        tri_surface[t as usize] = g;
    }

    // once per material: a bitmap's mean is a pass over its pixels
    let records: Vec<(bool, bool)> = scene.materials.iter().map(records_hits).collect();
    let list = groups
        .into_iter()
        .map(|tris| {
            let c = curved[scene.tri_shape[tris[0] as usize] as usize];
            make_surface(scene, tris, c, &records)
        })
        .collect();
    Surfaces { list, tri_surface }
}

/// Which shapes are curved: those whose shading normals leave their face
/// normals (vertex normals that equal the face normals, as OBJ files often
/// carry, do not make a shape curved) and whose geometry has a gentle fold:
/// two triangles sharing an edge, not coplanar, with face normals within the
/// 3D kernel's normal test (n₀·n₁ ≥ [`NORMAL_COS`]).
///
/// The irradiance is power per unit area of the geometry the particles hit
/// (§3.2); shading normals do not move a hit. A shape whose triangles meet
/// only flat or at sharp creases (a box exported with smoothed normals, as
/// glTF exporters do) is a set of planes, each a "locally planar surface
/// with orthogonal length parameters" on which the 2D kernel of eq. (2)
/// conserves energy with the boundary treatment at its edges, and on which
/// the over-mesh samples H densely. The 3D kernel would add nothing there:
/// its normal test keeps the facets of such a crease apart, and it samples H
/// only at the shape's vertices, which on a coarse box are its corners
/// (where its one-sided kernel is cut by the shape's border), so the walls
/// came out several times too dark. A gentle fold is what marks a
/// tessellated curved surface, whose facets are too small for a chart each
/// and which the 3D kernel spans.
fn curved_shapes(
    scene: &Scene,
    q: &impl Fn(Vec3) -> (i64, i64, i64),
    normal: &impl Fn(u32) -> Vec3,
) -> Vec<bool> {
    let smooth: Vec<bool> = scene
        .shapes
        .iter()
        .map(|sh| {
            sh.smooth
                && (sh.first_tri..sh.first_tri + sh.tri_count).any(|t| {
                    let n = normal(t);
                    scene.triangles[t as usize]
                        .iter()
                        .any(|&i| scene.normals[i as usize].dot(n).abs() < 0.9998)
                })
        })
        .collect();
    let mut folds = vec![false; scene.shapes.len()];
    type Key = (i64, i64, i64);
    let mut edges: HashMap<(u32, Key, Key), u32> = HashMap::new();
    for (s, sh) in scene.shapes.iter().enumerate() {
        if !smooth[s] {
            continue;
        }
        for t in sh.first_tri..sh.first_tri + sh.tri_count {
            let keys = scene.triangles[t as usize].map(|i| q(scene.positions[i as usize]));
            for e in 0..3 {
                let (a, b) = (keys[e], keys[(e + 1) % 3]);
                let key = if a < b {
                    (s as u32, a, b)
                } else {
                    (s as u32, b, a)
                };
                match edges.get(&key) {
                    Some(&o) => {
                        let c = normal(o).dot(normal(t));
                        folds[s] |= (NORMAL_COS..=1.0 - 1e-4).contains(&c);
                    }
                    None => {
                        edges.insert(key, t);
                    }
                }
            }
        }
    }
    smooth.iter().zip(&folds).map(|(&s, &f)| s && f).collect()
}

fn make_surface(scene: &Scene, tris: Vec<u32>, curved: bool, records: &[(bool, bool)]) -> Surface {
    let shape = scene.tri_shape[tris[0] as usize];
    let sh = &scene.shapes[shape as usize];
    let material = &scene.materials[sh.material as usize];
    let uv0 = scene.uvs[scene.triangles[tris[0] as usize][0] as usize];
    let (diffuse, textured) = records[sh.material as usize];
    let refl = diffuse_reflectance(material, uv0);
    let area: f32 = tris.iter().map(|&t| scene.tri_area(t)).sum();
    // The largest triangle fixes the plane; its edges are chart-axis candidates
    let big = *tris
        .iter()
        .max_by(|&&a, &&b| scene.tri_area(a).total_cmp(&scene.tri_area(b)))
        .unwrap_or(&tris[0]);
    let [a, b, c] = scene.tri_vertices(big);
    let normal = (b - a).cross(c - a).normalize_or(Vec3::Z);
    let kind = if curved { Kind::Curved } else { Kind::Planar };
    let mut best: Option<(f32, Vec3, Vec3, Vec2, Vec2)> = None;
    for (p, q) in [(a, b), (b, c), (c, a)] {
        let su = (q - p).normalize_or(Vec3::X);
        let sv = normal.cross(su);
        let mut lo = Vec2::splat(f32::INFINITY);
        let mut hi = Vec2::splat(f32::NEG_INFINITY);
        for &t in &tris {
            for v in scene.tri_vertices(t) {
                let d = v - a;
                let cc = Vec2::new(d.dot(su), d.dot(sv));
                lo = lo.min(cc);
                hi = hi.max(cc);
            }
        }
        let box_area = (hi - lo).x * (hi - lo).y;
        if best.as_ref().is_none_or(|b| box_area < b.0) {
            best = Some((box_area, su, sv, lo, hi));
        }
    }
    let (box_area, su, sv, lo, hi) = best.unwrap_or((0.0, Vec3::X, Vec3::Y, Vec2::ZERO, Vec2::ONE));
    let origin = a + su * lo.x + sv * lo.y;
    Surface {
        kind,
        shape,
        tris,
        origin,
        su,
        sv,
        normal,
        size: (hi - lo).max(Vec2::splat(1e-9)),
        area,
        rectangle: kind == Kind::Planar && (box_area - area).abs() <= 1e-4 * area,
        diffuse,
        reflectance: refl.unwrap_or(Vec3::ZERO),
        textured,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::scene::shapes;

    /// A cube whose corner normals are smoothed over its faces (as glTF
    /// exporters write a box) is six planar surfaces; a tessellated sphere
    /// with smooth normals stays curved; a cube with its own face normals
    /// is planar as before.
    #[test]
    fn smoothed_box_is_planar_and_sphere_curved() {
        let mut sc = Scene::empty("smoothed");
        let m = sc.add_material(Material::Diffuse {
            reflectance: Texture::Constant(Vec3::splat(0.5)),
        });
        let cube = shapes::cube();
        let smoothed: Vec<Vec3> = cube.positions.iter().map(|p| p.normalize()).collect();
        sc.add_mesh(
            "box",
            &cube.positions,
            Some(&smoothed),
            None,
            &cube.indices,
            m,
            None,
        );
        let ball = shapes::sphere(Vec3::new(4.0, 0.0, 0.0), 1.0, 16);
        sc.add_mesh(
            "ball",
            &ball.positions,
            ball.normals.as_deref(),
            None,
            &ball.indices,
            m,
            None,
        );
        let s = build(&sc);
        let of_shape = |shape: u32| {
            s.list
                .iter()
                .filter(|x| x.shape == shape)
                .collect::<Vec<_>>()
        };
        let boxes = of_shape(0);
        assert_eq!(boxes.len(), 6, "six faces");
        for f in &boxes {
            assert_eq!(f.kind, Kind::Planar);
            assert!(f.rectangle && (f.area - 4.0).abs() < 1e-5, "face {f:?}");
        }
        let balls = of_shape(1);
        assert_eq!(balls.len(), ball.indices.len(), "one surface per triangle");
        assert!(balls.iter().all(|x| x.kind == Kind::Curved));
    }
}
