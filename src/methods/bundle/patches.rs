//! Patches: the finite elements of §5 (eq. (23)). Every scene triangle is cut
//! into m² congruent cells, and every cell into k² congruent sub-triangles;
//! each sub-triangle is a patch with constant emission L_i^e(ω), BRDF f̃_i,
//! area A_i and radiance L\[i\]. The [`Layout`] holds m per triangle and k
//! per cell:
//!
//! - the area budget (the paper's uniform mesh, [`Layout::area`]) has m = 1
//!   and k chosen per triangle so that no edge is longer than the target
//!   edge length;
//! - the projected budget ([`super::budget`]) cuts large triangles into
//!   cells a few target edges long, then spends the patches cell by cell.
//!
//! The cells of a triangle, and the sub-triangles of a cell, are numbered
//! row by row in the barycentric grid (b1 = i/k, b2 = j/k): row j holds
//! k − j "up" and k − j − 1 "down" triangles, interleaved, so that a ray
//! hit (t, b1, b2) finds its cell and then its patch in O(1)
//! ([`Patches::locate`]).

use std::collections::HashMap;
use std::hash::{BuildHasherDefault, Hash, Hasher};

use glam::{Vec2, Vec3};
use rayon::prelude::*;

use crate::bsdf::Bsdf;
use crate::emitter::Lights;
use crate::scene::{Rgb, Scene};

/// One patch.
#[derive(Clone, Copy, Debug)]
pub struct Patch {
    /// Corners, counter-clockwise around `ng`.
    pub v: [Vec3; 3],
    /// Geometric normal (unit); its side is the front.
    pub ng: Vec3,
    /// Shading normal at the centroid, on the side of `ng`.
    pub ns: Vec3,
    /// Area A_i.
    pub area: f32,
    /// Emitted radiance of the front side (zero when the patch does not emit).
    pub le: Rgb,
    /// The BRDF at the centroid.
    pub bsdf: Bsdf,
    /// True when the back side reflects too (Mitsuba `twosided`).
    pub two_sided: bool,
    /// True when the patch is glass that the transfer reflects and
    /// transmits through ([`super::transfer::eval_glass`]); false for other
    /// BSDFs, and for glass with `--glass off`.
    pub glass: bool,
}

impl Patch {
    /// The centroid.
    #[inline]
    pub fn centroid(&self) -> Vec3 {
        (self.v[0] + self.v[1] + self.v[2]) / 3.0
    }

    /// L_i^e(ω): emission toward `w` (unit), front side only.
    #[inline]
    pub fn le(&self, w: Vec3) -> Rgb {
        if self.ng.dot(w) > 0.0 {
            self.le
        } else {
            Rgb::ZERO
        }
    }
}

/// The two-level subdivision: m per scene triangle, k per cell.
#[derive(Clone, Debug)]
pub struct Layout {
    /// Cells per edge m of each scene triangle (m² cells).
    pub m: Vec<u16>,
    /// First cell of each scene triangle.
    pub cell0: Vec<u32>,
    /// Sub-triangles per edge k of each cell (k² patches).
    pub k: Vec<u16>,
}

/// The largest m or k: a cell or a patch row beyond this is not useful,
/// and it keeps the counts in `u16`.
pub const MAX_SPLIT: u32 = 256;

/// Index within a row-by-row numbered grid of n² triangles, and the local
/// barycentrics (u, v) in that triangle, of grid coordinates (`u`, `v`)
/// (each scaled by n, so that the grid cells are unit). "Down" triangles
/// have corners (1,0), (1,1), (0,1) of their square and local coordinates
/// relative to the first.
#[inline]
fn grid_cell(n: u32, u: f32, v: f32) -> (u32, f32, f32) {
    let (u, v) = (u.max(0.0), v.max(0.0));
    let j = (v.floor() as u32).min(n - 1);
    let i = (u.floor() as u32).min(n - 1 - j);
    let (fu, fv) = (u - i as f32, v - j as f32);
    let row = 2 * n * j - j * j;
    let down = fu + fv > 1.0 && i + j + 1 < n;
    let idx = row + 2 * i + down as u32;
    if down {
        let t = 1.0 - fu;
        (idx, fv - t, t)
    } else {
        (idx, fu, fv)
    }
}

/// The grid triangles of an n² grid in index order, as the grid
/// coordinates of their three corners (counter-clockwise, as the parent).
fn grid_triangles(n: u32) -> impl Iterator<Item = [(u32, u32); 3]> {
    (0..n).flat_map(move |j| {
        (0..n - j).flat_map(move |i| {
            let up = [(i, j), (i + 1, j), (i, j + 1)];
            let down = (i + j + 1 < n).then_some([(i + 1, j), (i + 1, j + 1), (i, j + 1)]);
            std::iter::once(up).chain(down)
        })
    })
}

/// Longest edge of scene triangle `t`.
fn longest_edge(scene: &Scene, t: u32) -> f32 {
    let [a, b, c] = scene.tri_vertices(t);
    (b - a).length().max((c - b).length()).max((a - c).length())
}

impl Layout {
    /// The paper's uniform mesh: one cell per triangle, k so that no patch
    /// edge is longer than `edge`.
    pub fn area(scene: &Scene, edge: f32) -> Self {
        let nt = scene.triangles.len();
        Layout {
            m: vec![1; nt],
            cell0: (0..nt as u32).collect(),
            k: (0..nt as u32)
                .into_par_iter()
                .map(|t| subdivision(longest_edge(scene, t), edge) as u16)
                .collect(),
        }
    }

    /// Cells no longer than `cell_edge` (each with k = 1, for a budget to
    /// fill).
    pub fn cells(scene: &Scene, cell_edge: f32) -> Self {
        let nt = scene.triangles.len();
        let mut m = Vec::with_capacity(nt);
        let mut cell0 = Vec::with_capacity(nt);
        let mut n = 0u32;
        for t in 0..nt as u32 {
            let mt = subdivision(longest_edge(scene, t), cell_edge);
            m.push(mt as u16);
            cell0.push(n);
            n += mt * mt;
        }
        Layout {
            m,
            cell0,
            k: vec![1; n as usize],
        }
    }

    /// Number of cells.
    pub fn cell_count(&self) -> usize {
        self.k.len()
    }

    /// Number of patches: Σ k² over the cells.
    pub fn patch_count(&self) -> usize {
        self.k.iter().map(|&k| (k as usize).pow(2)).sum()
    }

    /// The cell holding barycentrics (`b1`, `b2`) of scene triangle `tri`,
    /// and the point's barycentrics within the cell.
    #[inline]
    pub fn cell_of(&self, tri: u32, b1: f32, b2: f32) -> (u32, f32, f32) {
        let m = self.m[tri as usize] as u32;
        if m == 1 {
            return (self.cell0[tri as usize], b1, b2);
        }
        let mf = m as f32;
        let (c, u, v) = grid_cell(m, b1 * mf, b2 * mf);
        (self.cell0[tri as usize] + c, u, v)
    }

    /// The barycentrics, in scene triangle `tri`, of the corners of each of
    /// its cells, in cell order.
    fn cell_corners(&self, tri: u32) -> impl Iterator<Item = [Vec2; 3]> {
        let m = self.m[tri as usize] as u32;
        let mf = m as f32;
        grid_triangles(m).map(move |cs| cs.map(|(i, j)| Vec2::new(i as f32, j as f32) / mf))
    }
}

/// Scene triangles per parallel run of [`Patches::with_layout`].
const LAYOUT_CHUNK: usize = 512;

/// Appends the patches of scene triangle `t`, cell by cell, to `p`.
fn mesh_triangle(scene: &Scene, lights: &Lights, layout: &Layout, t: u32, p: &mut Vec<Patch>) {
    let [a, b, c] = scene.tri_vertices(t);
    let shape = scene.tri_shape[t as usize];
    let material = &scene.materials[scene.shapes[shape as usize].material as usize];
    let two_sided = material.is_two_sided();
    let ng = (b - a).cross(c - a).normalize_or(Vec3::Z);
    let le = lights.le_tri(t, ng, ng);
    let m = layout.m[t as usize];
    for (ci, cb) in layout.cell_corners(t).enumerate() {
        let cell = layout.cell0[t as usize] as usize + ci;
        // a whole triangle keeps its exact corners, so that the area
        // budget's patches are those of the uniform mesh bit for bit
        let [ca, cb_, cc] = if m == 1 {
            [a, b, c]
        } else {
            cb.map(|x| a + (b - a) * x.x + (c - a) * x.y)
        };
        let k = layout.k[cell] as u32;
        let kf = k as f32;
        let at = |i: u32, j: u32| ca + (cb_ - ca) * (i as f32 / kf) + (cc - ca) * (j as f32 / kf);
        for cs in grid_triangles(k) {
            let v = cs.map(|(ii, jj)| at(ii, jj));
            // the centroid's barycentrics in the cell, then in t
            let bl: Vec2 = cs
                .iter()
                .map(|&(ii, jj)| Vec2::new(ii as f32, jj as f32) / kf)
                .sum::<Vec2>()
                / 3.0;
            let bary = if m == 1 {
                bl
            } else {
                cb[0] + (cb[1] - cb[0]) * bl.x + (cb[2] - cb[0]) * bl.y
            };
            let sp = scene.surface_point(t, bary.x, bary.y);
            let area = 0.5 * (v[1] - v[0]).cross(v[2] - v[0]).length();
            let bsdf = material.bsdf(sp.uv);
            p.push(Patch {
                v,
                ng,
                ns: sp.frame.n,
                area: area.max(1e-30),
                le,
                glass: super::transfer::is_glass(&bsdf),
                bsdf,
                two_sided,
            });
        }
    }
}

/// A patch corner for sharing: its shape and its position quantised to
/// steps of q.
#[derive(Clone, Copy, PartialEq, Eq)]
struct CornerKey {
    shape: u32,
    x: [i64; 3],
}

impl CornerKey {
    fn new(shape: u32, x: Vec3, q: f32) -> Self {
        CornerKey {
            shape,
            x: [
                (x.x / q).round() as i64,
                (x.y / q).round() as i64,
                (x.z / q).round() as i64,
            ],
        }
    }
}

impl Hash for CornerKey {
    fn hash<H: Hasher>(&self, state: &mut H) {
        // one word: the four integers mixed by odd multipliers
        let mut h = self.shape as u64;
        for x in self.x {
            h = (h.rotate_left(23) ^ x as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15);
        }
        state.write_u64(h);
    }
}

/// The hasher of [`CornerKey`]s: the key already mixes its words, and
/// SipHash's defence against chosen keys is not needed for a scene's own
/// corners, so this only folds the high bits down.
#[derive(Default)]
struct CornerHasher(u64);

impl Hasher for CornerHasher {
    fn write(&mut self, bytes: &[u8]) {
        for &b in bytes {
            self.0 = (self.0.rotate_left(8) ^ b as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15);
        }
    }
    fn write_u64(&mut self, x: u64) {
        self.0 = x ^ (x >> 29);
    }
    fn finish(&self) -> u64 {
        self.0
    }
}

/// All patches with their bookkeeping.
pub struct Patches {
    /// The patches. Their corners are copied into [`Patches::corners`] when
    /// built, so they must not be changed afterwards.
    pub p: Vec<Patch>,
    /// Shared vertex index of each patch corner (for Gouraud smoothing;
    /// where two cells of different k meet, the finer cell's extra corners
    /// are not shared).
    pub vid: Vec<[u32; 3]>,
    /// Number of shared vertices.
    pub vertex_count: usize,
    /// The cells and their subdivisions.
    layout: Layout,
    /// First patch of each cell.
    first: Vec<u32>,
    /// The edge length the tessellation aimed at (the area budget's: it
    /// sets the visibility map's resolution whatever the budget).
    pub edge: f32,
    /// The corners of `p` again, by coordinate, for the projection.
    corners: Corners,
}

/// Lanes past the last patch that [`Corners`] pads with zeros.
pub const CORNER_PAD: usize = 8;

/// The corners of every patch by coordinate (structure of arrays), made
/// once with the patches: the projection reads nothing else of a patch,
/// and this way reads them eight patches at a time instead of 36 bytes of
/// every 136-byte [`Patch`]. `c[3 * k + axis][i]` is coordinate `axis` of
/// corner k of patch i; every array holds [`CORNER_PAD`] zeros past the
/// last patch, so that eight lanes may be loaded from any patch.
#[derive(Clone, Debug, Default)]
pub struct Corners {
    /// The nine coordinate arrays.
    pub c: [Vec<f32>; 9],
}

impl Corners {
    /// Patch i's corners `v(i)`, for i in `0..n`.
    pub fn new(n: usize, v: impl Fn(usize) -> [Vec3; 3]) -> Self {
        Corners {
            c: std::array::from_fn(|j| {
                let (k, axis) = (j / 3, j % 3);
                ((0..n).map(|i| v(i)[k][axis]))
                    .chain(std::iter::repeat_n(0.0, CORNER_PAD))
                    .collect()
            }),
        }
    }
}

/// Subdivision of a triangle with longest edge `longest` for target `edge`.
fn subdivision(longest: f32, edge: f32) -> u32 {
    if edge > 0.0 && edge.is_finite() {
        ((longest / edge).ceil() as u32).clamp(1, MAX_SPLIT)
    } else {
        1
    }
}

/// The target edge length h for `n` patches: the shortest h whose uniform
/// mesh has at most `n` patches, so that `--patches n` gives as many as the
/// mesh can come to without passing `n`. Every scene triangle keeps at least
/// one patch, so a scene of more than `n` triangles gets one patch per
/// triangle (h = its longest edge).
///
/// The count Σ k², with k = ⌈longest edge / h⌉ per triangle, falls as h
/// grows, in steps; a bisection on h finds the step at `n`. A single
/// rescaling from the equilateral estimate (area √3/4 h² per patch) misses
/// it, because rounding k up per triangle adds patches.
pub fn edge_for_count(scene: &Scene, n: usize) -> f32 {
    let n = n.max(1) as u64;
    let longest: Vec<f32> = (0..scene.triangles.len() as u32)
        .into_par_iter()
        .map(|t| longest_edge(scene, t))
        .collect();
    // an integer sum: the same whatever the split across threads
    let count = |h: f32| -> u64 {
        longest
            .par_iter()
            .with_min_len(4096)
            .map(|&l| (subdivision(l, h) as u64).pow(2))
            .sum()
    };
    // the coarsest mesh: one patch per triangle (an infinite edge, from
    // coordinates near f32::MAX, splits nothing, as `subdivision` says)
    let hi = longest.iter().copied().fold(0.0f32, f32::max);
    if hi.is_nan() || hi <= 0.0 {
        return 1.0;
    }
    if count(hi) >= n {
        return hi;
    }
    let total: f64 = (0..scene.triangles.len() as u32)
        .map(|t| scene.tri_area(t) as f64)
        .sum();
    // from the equilateral estimate, halve until the mesh has more than n
    // (or every triangle is split as finely as allowed)
    let estimate = (4.0 * total / (3f64.sqrt() * n as f64)).sqrt() as f32;
    let mut lo = if estimate > 0.0 { estimate.min(hi) } else { hi };
    let mut at_lo = count(lo);
    while at_lo <= n {
        let finer = lo * 0.5;
        let at_finer = count(finer);
        if finer <= 0.0 || at_finer == at_lo {
            return lo;
        }
        (lo, at_lo) = (finer, at_finer);
    }
    // count(lo) > n ≥ count(hi): bisect to the shortest h with count ≤ n
    let mut hi = hi;
    for _ in 0..64 {
        let mid = 0.5 * (lo + hi);
        if mid <= lo || mid >= hi {
            break;
        }
        if count(mid) > n {
            lo = mid;
        } else {
            hi = mid;
        }
    }
    hi
}

impl Patches {
    /// Tessellates `scene` with edges no longer than `edge` (plus the
    /// triangles' own shape: a thin sliver keeps its aspect ratio): the
    /// area budget, the paper's uniform mesh.
    pub fn build(scene: &Scene, lights: &Lights, edge: f32) -> Self {
        Self::with_layout(scene, lights, Layout::area(scene, edge), edge)
    }

    /// Tessellates `scene` as `layout` says; `edge` is only recorded.
    pub fn with_layout(scene: &Scene, lights: &Lights, layout: Layout, edge: f32) -> Self {
        Self::with_layout_in(scene, lights, layout, edge, LAYOUT_CHUNK)
    }

    /// [`Patches::with_layout`], with the scene's triangles meshed in
    /// parallel in runs of `chunk` (at least one) triangles. The patches and
    /// their vertex numbering do not depend on `chunk`: the runs are joined
    /// in triangle order, and the shared corners are then numbered in patch
    /// order, as one sequential pass would number them.
    pub fn with_layout_in(
        scene: &Scene,
        lights: &Lights,
        layout: Layout,
        edge: f32,
        chunk: usize,
    ) -> Self {
        let nt = scene.triangles.len();
        let chunk = chunk.max(1);
        // corners are shared between patches of one shape when their positions
        // agree after quantisation to 1e-5 of the scene size
        let (lo, hi) = scene.bounds();
        let q = ((hi - lo).max_element() * 1e-5).max(1e-12);

        // Mesh the runs of triangles in parallel, each with its corners' keys
        let runs: Vec<(Vec<Patch>, Vec<[CornerKey; 3]>)> = (0..nt.div_ceil(chunk))
            .into_par_iter()
            .map(|r| {
                let mut p = Vec::new();
                let mut keys = Vec::new();
                for t in (r * chunk) as u32..((r + 1) * chunk).min(nt) as u32 {
                    mesh_triangle(scene, lights, &layout, t, &mut p);
                    let shape = scene.tri_shape[t as usize];
                    keys.extend(
                        p[keys.len()..]
                            .iter()
                            .map(|x| x.v.map(|c| CornerKey::new(shape, c, q))),
                    );
                }
                (p, keys)
            })
            .collect();

        // Join them in triangle order; the first patch of each cell follows
        let total = runs.iter().map(|r| r.0.len()).sum();
        let mut p = Vec::with_capacity(total);
        let mut keys = Vec::with_capacity(total);
        for (rp, rk) in runs {
            p.extend_from_slice(&rp);
            keys.extend_from_slice(&rk);
        }
        let mut first = Vec::with_capacity(layout.cell_count());
        let mut n = 0u32;
        for &k in &layout.k {
            first.push(n);
            n += (k as u32).pow(2);
        }

        // Number the shared corners in order of first use
        let mut vmap: HashMap<CornerKey, u32, BuildHasherDefault<CornerHasher>> =
            HashMap::with_capacity_and_hasher(total, Default::default());
        let vid: Vec<[u32; 3]> = keys
            .iter()
            .map(|ks| {
                ks.map(|key| {
                    let n = vmap.len() as u32;
                    *vmap.entry(key).or_insert(n)
                })
            })
            .collect();
        let vertex_count = vmap.len();
        Patches {
            corners: Corners::new(p.len(), |i| p[i].v),
            p,
            vid,
            vertex_count,
            layout,
            first,
            edge,
        }
    }

    /// The corners of the patches by coordinate.
    pub fn corners(&self) -> &Corners {
        &self.corners
    }

    /// The cells and their subdivisions.
    pub fn layout(&self) -> &Layout {
        &self.layout
    }

    /// The patches of each cell, as a range of patch indices.
    pub fn cell_patches(&self, cell: usize) -> std::ops::Range<usize> {
        let k = self.layout.k[cell] as usize;
        let f = self.first[cell] as usize;
        f..f + k * k
    }

    /// Turns the glass transfer off (`--glass off`: glass neither reflects
    /// nor transmits in the transfer, as before it existed) or back on.
    pub fn set_glass(&mut self, on: bool) {
        for p in &mut self.p {
            p.glass = on && super::transfer::is_glass(&p.bsdf);
        }
    }

    /// Number of patches.
    pub fn len(&self) -> usize {
        self.p.len()
    }

    /// True when there are no patches.
    pub fn is_empty(&self) -> bool {
        self.p.is_empty()
    }

    /// The patch holding barycentrics (`b1`, `b2`) of scene triangle `tri`,
    /// and the point's barycentric weights on that patch's three corners.
    pub fn locate(&self, tri: u32, b1: f32, b2: f32) -> (u32, Vec3) {
        let (cell, b1, b2) = self.layout.cell_of(tri, b1, b2);
        let k = self.layout.k[cell as usize] as u32;
        let kf = k as f32;
        let (idx, s, t) = grid_cell(k, b1 * kf, b2 * kf);
        let w = Vec3::new(1.0 - s - t, s, t);
        (
            self.first[cell as usize] + idx,
            w.clamp(Vec3::ZERO, Vec3::ONE),
        )
    }
}
