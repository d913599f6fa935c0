//! The lanes of [`super::radiance_camera_row`] and of
//! [`super::light_walks`] in AVX registers. Every `unsafe` block calls an
//! intrinsic on register values or on an array of eight f32 it names; the
//! functions run only inlined into [`radiance_row`] or
//! [`walks::light_walks`], which are compiled for AVX2 and called where the
//! CPU has it.

use std::arch::x86_64::*;
use std::f32::consts::{FRAC_1_PI, PI};

use glam::{Vec2, Vec3};

use super::{LaneSampler, LANES};
use crate::accel::Hit;
use crate::emitter::TriLight;
use crate::geometry::Ray;
use crate::sampling::{sin_cos_quarter, Sampler};
use crate::scene::records::TriRecord;
use crate::scene::Rgb;
use crate::simd::F8 as V;
use crate::transport::{CameraPath, DepthLimits};
use crate::world::World;

mod draw;
mod start;
mod walks;

pub use draw::{Lanes, Rngs, SobolLanes};
pub(super) use start::{CameraRow, Chunk, Continued, Starts};
pub(super) use walks::light_walks;

// The records are read as sixteen f32 in field order: p (3 × 3), uv
// (3 × 2), shape; corners (3 × 3), n, Le, area.
const _: () = {
    use std::mem::{align_of, offset_of, size_of};
    assert!(size_of::<TriRecord>() == 64 && align_of::<TriRecord>() == 64);
    assert!(offset_of!(TriRecord, uv) == 36 && offset_of!(TriRecord, shape) == 60);
    assert!(size_of::<TriLight>() == 64 && align_of::<TriLight>() == 64);
    assert!(offset_of!(TriLight, n) == 36 && offset_of!(TriLight, le) == 48);
    assert!(offset_of!(TriLight, area) == 60);
};

/// Three lanes of vectors, by component.
#[derive(Clone, Copy)]
struct V3 {
    x: V,
    y: V,
    z: V,
}

impl V3 {
    #[inline(always)]
    fn new(x: V, y: V, z: V) -> V3 {
        V3 { x, y, z }
    }
    #[inline(always)]
    fn splat(v: Vec3) -> V3 {
        V3::new(V::splat(v.x), V::splat(v.y), V::splat(v.z))
    }
    #[inline(always)]
    fn load(a: &[[f32; LANES]; 3]) -> V3 {
        V3::new(V::load(&a[0]), V::load(&a[1]), V::load(&a[2]))
    }
    #[inline(always)]
    fn store(self) -> [[f32; LANES]; 3] {
        [self.x.store(), self.y.store(), self.z.store()]
    }
    /// glam's `Vec3::dot`: (x x' + y y') + z z'.
    #[inline(always)]
    fn dot(self, b: V3) -> V {
        self.x * b.x + self.y * b.y + self.z * b.z
    }
    #[inline(always)]
    fn neg(self) -> V3 {
        V3::new(-self.x, -self.y, -self.z)
    }
    #[inline(always)]
    fn scale(self, k: V) -> V3 {
        V3::new(self.x * k, self.y * k, self.z * k)
    }
    #[inline(always)]
    fn select(m: V, a: V3, b: V3) -> V3 {
        V3::new(m.select(a.x, b.x), m.select(a.y, b.y), m.select(a.z, b.z))
    }
    /// Lane `i` as a `Vec3`.
    #[inline(always)]
    fn lane(a: &[[f32; LANES]; 3], i: usize) -> Vec3 {
        Vec3::new(a[0][i], a[1][i], a[2][i])
    }
    /// Sets lane `i` of `a` to `v`.
    #[inline(always)]
    fn set(a: &mut [[f32; LANES]; 3], i: usize, v: Vec3) {
        (a[0][i], a[1][i], a[2][i]) = (v.x, v.y, v.z);
    }
}

/// A matrix column's xyz in every lane (a function, not a closure: a
/// closure would not inherit the caller's AVX2).
#[inline(always)]
fn axis(a: glam::Vec4) -> V3 {
    V3::splat(Vec3::new(a.x, a.y, a.z))
}

/// Transposes eight rows of eight f32 (`r[i]` is lane i's row) into
/// eight columns (`r[j]` then holds field j of every lane).
#[inline(always)]
fn transpose(r: [__m256; 8]) -> [V; 8] {
    // SAFETY: only inlined into `radiance_row` or `light_walks`, which run where the CPU has AVX2
    unsafe { crate::simd::transpose8(r) }.map(V)
}

/// The light of lanes that chose none.
static NO_LIGHT: TriLight = TriLight {
    corners: [Vec3::ZERO; 3],
    n: Vec3::ZERO,
    le: Vec3::ZERO,
    area: 0.0,
};

/// The state of eight [`CameraPath`]s, by field.
struct Paths {
    o: [[f32; LANES]; 3],
    d: [[f32; LANES]; 3],
    l: [[f32; LANES]; 3],
    beta: [[f32; LANES]; 3],
    prev_pdf: [f32; LANES],
    specular: u32,
    prev_p: [[f32; LANES]; 3],
    prev_n: [[f32; LANES]; 3],
    eta_scale: [f32; LANES],
    depth: [u32; LANES],
    rays: [u64; LANES],
}

impl Paths {
    /// Path `i`.
    #[inline(always)]
    fn get(&self, i: usize) -> CameraPath {
        let mut p = CameraPath::new(Ray::new(V3::lane(&self.o, i), V3::lane(&self.d, i)), 1);
        p.l = V3::lane(&self.l, i);
        p.beta = V3::lane(&self.beta, i);
        p.rays = self.rays[i];
        p.prev_pdf = self.prev_pdf[i];
        p.specular = self.specular & (1 << i) != 0;
        p.prev_p = V3::lane(&self.prev_p, i);
        p.prev_n = V3::lane(&self.prev_n, i);
        p.eta_scale = self.eta_scale[i];
        p.depth = self.depth[i];
        p
    }

    /// Sets path `i` to `p`.
    #[inline(always)]
    fn set(&mut self, i: usize, p: &CameraPath) {
        V3::set(&mut self.o, i, p.ray.o);
        V3::set(&mut self.d, i, p.ray.d);
        V3::set(&mut self.l, i, p.l);
        V3::set(&mut self.beta, i, p.beta);
        self.rays[i] = p.rays;
        self.prev_pdf[i] = p.prev_pdf;
        self.specular = (self.specular & !(1 << i)) | (u32::from(p.specular) << i);
        V3::set(&mut self.prev_p, i, p.prev_p);
        V3::set(&mut self.prev_n, i, p.prev_n);
        self.eta_scale[i] = p.eta_scale;
        self.depth[i] = p.depth;
    }
}

/// The lanes of `mask`, lowest first.
#[inline(always)]
fn lanes(mask: u32) -> Bits {
    Bits(mask)
}

/// The iterator of [`lanes`].
struct Bits(u32);

impl Iterator for Bits {
    type Item = usize;
    #[inline(always)]
    fn next(&mut self) -> Option<usize> {
        if self.0 == 0 {
            return None;
        }
        let i = self.0.trailing_zeros() as usize;
        self.0 &= self.0 - 1;
        Some(i)
    }
}

/// [`crate::geometry::offset_point`] in lanes, as its SSE2 form computes it: `p` moved off
/// the surface with geometric normal `ng` to the side `dir` points into.
#[inline(always)]
fn offset(p: V3, ng: V3, dir: V3) -> V3 {
    let n = V3::select(ng.dot(dir).lt(V::splat(0.0)), ng.neg(), ng);
    V3::new(offset_c(p.x, n.x), offset_c(p.y, n.y), offset_c(p.z, n.z))
}

/// One coordinate of [`offset`], `n` facing the side to move to.
#[inline(always)]
fn offset_c(p: V, n: V) -> V {
    // SAFETY: register operations only; only inlined into `radiance_row` or
    // `light_walks`, which run where the CPU has AVX2
    unsafe {
        // (256 n) as i32, saturating as Rust casts
        let sn = _mm256_mul_ps(_mm256_set1_ps(256.0), n.0);
        let mut oi = _mm256_cvttps_epi32(sn);
        oi = _mm256_xor_si256(
            oi,
            _mm256_castps_si256(_mm256_cmp_ps::<_CMP_GE_OQ>(
                sn,
                _mm256_set1_ps(2_147_483_648.0),
            )),
        );
        oi = _mm256_and_si256(oi, _mm256_castps_si256(_mm256_cmp_ps::<_CMP_ORD_Q>(sn, sn)));
        let neg = _mm256_castps_si256(_mm256_cmp_ps::<_CMP_LT_OQ>(p.0, _mm256_setzero_ps()));
        let signed = _mm256_sub_epi32(_mm256_xor_si256(oi, neg), neg);
        let pi = _mm256_castsi256_ps(_mm256_add_epi32(_mm256_castps_si256(p.0), signed));
        let pf = _mm256_add_ps(p.0, _mm256_mul_ps(_mm256_set1_ps(1.0 / 65536.0), n.0));
        let small = _mm256_cmp_ps::<_CMP_LT_OQ>(p.abs().0, _mm256_set1_ps(1.0 / 32.0));
        V(_mm256_blendv_ps(pi, pf, small))
    }
}

/// Stores the lanes of `m` of `v` into `dst`. The old values pass through
/// `black_box` so that LLVM does not fuse the load, the blend and the store
/// into a masked store (`vmaskmovps`), which is slow on AMD's cores.
#[inline(always)]
fn put(dst: &mut [[f32; LANES]; 3], m: V, v: V3) {
    let old = std::hint::black_box(V3::load(dst));
    *dst = V3::select(m, v, old).store();
}

/// Stores the lanes of `m` of `v` into `dst`, as [`put`] does.
#[inline(always)]
fn put1(dst: &mut [f32; LANES], m: V, v: V) {
    *dst = m.select(v, std::hint::black_box(V::load(dst))).store();
}

/// a b0 + b b1 + c b2, as glam computes it.
#[inline(always)]
fn lerp(a: V, b: V, c: V, b0: V, b1: V, b2: V) -> V {
    a * b0 + b * b1 + c * b2
}

/// Paths whose starts are made together before they run.
const CHUNK: usize = 8 * LANES;

/// [`super::radiance_camera_row`] and [`super::radiance_continued`] with
/// the common case in AVX lanes: the paths of `start`, whose answers go to
/// `finish(k, L, rays)` for path k.
#[target_feature(enable = "avx2")]
pub(super) fn radiance_row<S: LaneSampler>(
    world: &World,
    limits: &DepthLimits,
    mut start: impl Starts<S>,
    mut finish: impl FnMut(usize, Rgb, u64),
) {
    let mut paths = Paths {
        o: [[0.0; LANES]; 3],
        d: [[0.0; LANES]; 3],
        l: [[0.0; LANES]; 3],
        beta: [[0.0; LANES]; 3],
        prev_pdf: [0.0; LANES],
        specular: 0,
        prev_p: [[0.0; LANES]; 3],
        prev_n: [[0.0; LANES]; 3],
        eta_scale: [0.0; LANES],
        depth: [0; LANES],
        rays: [0; LANES],
    };
    let (w, depth) = (start.count(), start.depth());
    let mut rngs = S::Lanes::new();
    let mut pixel = [0usize; LANES];
    let mut found = [None; LANES];
    let mut alive = 0u32;
    // The starts of CHUNK paths at a time are made up front (`path`'s
    // camera rays traced in packets of neighbouring pixels); a lane whose
    // path ended takes the next path of the chunk
    let mut chunk_rngs: [S; CHUNK] = std::array::from_fn(|_| S::Lanes::blank());
    let mut chunk_rays = [Ray::new(Vec3::ZERO, Vec3::Z); CHUNK];
    let mut chunk_hits = [None; CHUNK];
    let (mut chunk0, mut chunk_n) = (0, 0);
    let mut next = 0;
    loop {
        if next == chunk0 + chunk_n && next < w {
            chunk0 = next;
            chunk_n = CHUNK.min(w - next);
            let out = Chunk {
                rngs: &mut chunk_rngs[..chunk_n],
                rays: &mut chunk_rays[..chunk_n],
                hits: &mut chunk_hits[..chunk_n],
            };
            start.starts(world, chunk0, out);
        }
        // Lanes given a path whose first segment is still to be traced
        let mut fresh = 0u32;
        for i in lanes(!alive & ((1 << LANES) - 1)) {
            if next == chunk0 + chunk_n {
                break;
            }
            let k = next - chunk0;
            rngs.set(i, &chunk_rngs[k]);
            pixel[i] = next;
            next += 1;
            let mut p = CameraPath::new(chunk_rays[k], depth);
            p.rays = 1;
            paths.set(i, &p);
            match chunk_hits[k] {
                Some(h) => found[i] = h,
                None => fresh |= 1 << i,
            }
            alive |= 1 << i;
        }
        if alive == 0 {
            return;
        }
        if fresh != 0 {
            world
                .accel
                .intersect_lanes(&paths.o, &paths.d, fresh, &mut found);
        }
        let mut hit = 0u32;
        for i in lanes(alive) {
            hit |= u32::from(found[i].is_some()) << i;
        }
        // Paths that escaped end with the environment
        for i in lanes(alive & !hit) {
            let mut p = paths.get(i);
            p.escape(world);
            paths.set(i, &p);
        }
        let was = alive;
        alive &= hit;
        if alive != 0 {
            alive = vertices(world, limits, &mut paths, &found, &mut rngs, alive);
        }
        for i in lanes(was & !alive) {
            finish(pixel[i], V3::lane(&paths.l, i), paths.rays[i]);
        }
        // The next segment of each path that goes on
        for i in lanes(alive) {
            paths.rays[i] += 1;
        }
        world
            .accel
            .intersect_lanes(&paths.o, &paths.d, alive, &mut found);
    }
}

/// One vertex of each path of `mask`, whose rays hit at `hits`; returns the
/// paths that go on.
#[inline(always)]
fn vertices<S: Sampler>(
    world: &World,
    limits: &DepthLimits,
    paths: &mut Paths,
    hits: &[Option<Hit>; LANES],
    rngs: &mut impl Lanes<S>,
    mask: u32,
) -> u32 {
    let lh = lane_hits(hits, mask);
    let sp = surface_points(world.tris.records(), &lh);
    // The common case: below the depth limit, on a surface that does not
    // emit
    let (max_depth, mut common) = (limits.max_depth.unwrap_or(u32::MAX), 0);
    for i in lanes(mask) {
        let c = paths.depth[i] < max_depth && !world.lights.is_emitter_of(lh[i].tri, sp.shape[i]);
        common |= u32::from(c) << i;
    }
    let mut sh = shade(world, &lh, &sp, mask, common);
    // Every other vertex takes the scalar step
    for i in lanes(mask & !sh.vec) {
        let mut path = paths.get(i);
        let spi = world.surface_point(&lh[i]);
        let mut rng = rngs.get(i);
        if !path.scatter(world, limits, &spi, &mut rng) {
            sh.alive &= !(1 << i);
        }
        rngs.set(i, &rng);
        paths.set(i, &path);
    }
    if sh.vec == 0 {
        return sh.alive;
    }
    // The lanes' numbers, in the scalar order: the light's choice and
    // point, then the BSDF's lobe and direction
    let u = rngs.vertex(sh.vec, &paths.depth).map(V);
    let fr = frame(&sh, sp.ng, V3::load(&paths.d).neg());
    let ls = choose_lights(world, limits, sp.p, fr.ng_o, u[0], sh.vec);
    let ne = next_event(paths, &sh, &sp, &fr, &ls, [u[1], u[2]]);
    let bs = sample_bsdf(paths, &sh, &fr, [u[4], u[5]]);
    trace_shadows(world, paths, &sp, &fr, &ls, &ne, sh.vec);
    next_segment(limits, paths, rngs, &sp, &fr, &bs, sh)
}

/// Each lane's hit, of the lanes of `mask`, which hit; lanes outside the
/// mask repeat the first lane's (and are not written back).
#[inline(always)]
fn lane_hits(hits: &[Option<Hit>; LANES], mask: u32) -> [Hit; LANES] {
    let first = mask.trailing_zeros() as usize;
    std::array::from_fn(|i| {
        let h = hits[if mask & (1 << i) != 0 { i } else { first }];
        h.unwrap_or(Hit {
            t: 0.0,
            tri: 0,
            b1: 0.0,
            b2: 0.0,
        })
    })
}

/// The surface points of eight hits, by lane.
struct Surface {
    /// The point.
    p: V3,
    /// The geometric normal.
    ng: V3,
    /// The texture coordinates, u then v.
    uv: [[f32; LANES]; 2],
    /// The first barycentric coordinate.
    b0: V,
    /// The shape hit.
    shape: [u32; LANES],
}

/// The surface points of the hits `lh`, as `records::interpolate` computes
/// them.
#[inline(always)]
fn surface_points(recs: &[TriRecord], lh: &[Hit; LANES]) -> Surface {
    let mut lo = [V::splat(0.0).0; 8];
    let mut hi = lo;
    let mut shape = [0u32; LANES];
    for (i, h) in lh.iter().enumerate() {
        let r: &TriRecord = &recs[h.tri as usize];
        shape[i] = r.shape;
        let ptr = (r as *const TriRecord).cast::<f32>();
        // SAFETY: a record is 64 bytes of f32-sized fields, 64-aligned;
        // only inlined into `radiance_row` or `light_walks`, which run where the CPU has AVX2
        unsafe {
            lo[i] = _mm256_load_ps(ptr);
            hi[i] = _mm256_load_ps(ptr.add(8));
        }
    }
    // fields: p0 p1 p2 (xyz each), uv0 uv1 uv2 (xy each), shape
    let [ax, ay, az, bx, by, bz, cx, cy] = transpose(lo);
    let [cz, u0x, u0y, u1x, u1y, u2x, u2y, _] = transpose(hi);
    let b1 = V::load(&lh.map(|h| h.b1));
    let b2 = V::load(&lh.map(|h| h.b2));
    let b0 = V::splat(1.0) - b1 - b2;
    let p = V3::new(
        lerp(ax, bx, cx, b0, b1, b2),
        lerp(ay, by, cy, b0, b1, b2),
        lerp(az, bz, cz, b0, b1, b2),
    );
    let uv = [
        lerp(u0x, u1x, u2x, b0, b1, b2).store(),
        lerp(u0y, u1y, u2y, b0, b1, b2).store(),
    ];
    let e1 = V3::new(bx - ax, by - ay, bz - az);
    let e2 = V3::new(cx - ax, cy - ay, cz - az);
    let cross = V3::new(
        e1.y * e2.z - e2.y * e1.z,
        e1.z * e2.x - e2.z * e1.x,
        e1.x * e2.y - e2.x * e1.y,
    );
    // normalize_or(+z)
    let rcp = V::splat(1.0) / cross.dot(cross).sqrt();
    let unit = rcp.finite() & rcp.gt(V::splat(0.0));
    let ng = V3::select(unit, cross.scale(rcp), V3::splat(Vec3::Z));
    Surface {
        p,
        ng,
        uv,
        b0,
        shape,
    }
}

/// Which vertices the lanes shade, and what they need to.
struct Shaded {
    /// The paths still going on (so far: the scalar steps' answers).
    alive: u32,
    /// The lanes shaded in lanes.
    vec: u32,
    /// The lanes whose material is two-sided.
    two_sided: u32,
    /// The diffuse reflectance.
    r: [[f32; LANES]; 3],
    /// The shading normal, facing the geometric one.
    ns: [[f32; LANES]; 3],
}

/// Which vertices of `mask` the lanes shade: those of `common` whose
/// material is diffuse there; the caller takes every other vertex's scalar
/// step. A shaded lane's reflectance and shading normal (interpolated for
/// smooth shapes, lane by lane; a normal-mapped shape's is the scalar
/// surface point's).
#[inline(always)]
fn shade(world: &World, lh: &[Hit; LANES], sp: &Surface, mask: u32, common: u32) -> Shaded {
    let scene = &world.scene;
    let ng_a = sp.ng.store();
    let b0_a = sp.b0.store();
    let mut sh = Shaded {
        alive: mask,
        vec: 0,
        two_sided: 0,
        r: [[0.0f32; LANES]; 3],
        ns: ng_a,
    };
    let (mut raw, mut smooth) = ([[0.0f32; LANES]; 3], 0u32);
    for i in lanes(mask & common) {
        let shape = sp.shape[i];
        let s = &scene.shapes[shape as usize];
        let material = &scene.materials[s.material as usize];
        let uv = Vec2::new(sp.uv[0][i], sp.uv[1][i]);
        let Some(ri) = material.diffuse_at(uv) else {
            continue;
        };
        sh.vec |= 1 << i;
        sh.two_sided |= u32::from(material.is_two_sided()) << i;
        V3::set(&mut sh.r, i, ri);
        if s.normal_map.is_some() {
            // a normal map's frame is the scalar surface point's
            V3::set(&mut sh.ns, i, world.surface_point(&lh[i]).frame.n);
        } else if s.smooth {
            // interpolated here, normalised below in lanes
            let [i0, i1, i2] = scene.triangles[lh[i].tri as usize].map(|i| i as usize);
            let n = scene.normals[i0] * b0_a[i]
                + scene.normals[i1] * lh[i].b1
                + scene.normals[i2] * lh[i].b2;
            V3::set(&mut raw, i, n);
            smooth |= 1 << i;
        }
    }
    if smooth != 0 {
        // `normalize_or(ng)`, then facing ng, as the scalar surface point
        // computes them (the same operations, eight lanes at once: a
        // division a lane, lane by lane, was a stall)
        let (n, ng) = (V3::load(&raw), sp.ng);
        let rcp = V::splat(1.0) / n.dot(n).sqrt();
        let unit = rcp.finite() & rcp.gt(V::splat(0.0));
        let n = V3::select(unit, n.scale(rcp), ng);
        let n = V3::select(n.dot(ng).lt(V::splat(0.0)), n.neg(), n);
        put(&mut sh.ns, V::mask(smooth), n);
    }
    sh
}

/// The shading frames, oriented.
struct Frame8 {
    /// The frame's first tangent.
    fs: V3,
    /// Its second tangent.
    ft: V3,
    /// Its normal.
    fn_: V3,
    /// The direction to the viewer.
    wo: V3,
    /// The geometric normal, facing the viewer on two-sided materials.
    ng_o: V3,
}

/// `Frame::from_normal` of the shading normals, then `orient`: two-sided
/// materials face the viewer at `wo`.
#[inline(always)]
fn frame(sh: &Shaded, ng: V3, wo: V3) -> Frame8 {
    let nn = V3::load(&sh.ns);
    let (fs, ft) = tangents(nn);
    let flip = V::mask(sh.two_sided) & ng.dot(wo).lt(V::splat(0.0));
    Frame8 {
        fs,
        ft: V3::select(flip, ft.neg(), ft),
        fn_: V3::select(flip, nn.neg(), nn),
        wo,
        ng_o: V3::select(flip, ng.neg(), ng),
    }
}

/// The tangents of `Frame::from_normal(nn)`.
#[inline(always)]
fn tangents(nn: V3) -> (V3, V3) {
    let sign = (nn.z & V::splat(-0.0)) | V::splat(1.0);
    let a = V::splat(-1.0) / (sign + nn.z);
    let b = nn.x * nn.y * a;
    let fs = V3::new(
        V::splat(1.0) + sign * nn.x * nn.x * a,
        sign * b,
        -sign * nn.x,
    );
    let ft = V3::new(b, sign + nn.y * nn.y * a, -nn.y);
    (fs, ft)
}

/// The lights the lanes chose, by field.
struct Chosen {
    /// The lanes that chose one.
    chosen: u32,
    /// Its probability.
    pmf: [f32; LANES],
    /// Its corners.
    q: [V3; 3],
    /// Its normal.
    n: V3,
    /// Its emitted radiance.
    le: V3,
    /// Its area.
    area: V,
}

/// The light each lane of `vec` chooses with the number `u_sel`, as seen
/// from its point `p` and normal `ng_o`, read by field.
#[inline(always)]
fn choose_lights(
    world: &World,
    limits: &DepthLimits,
    p: V3,
    ng_o: V3,
    u_sel: V,
    vec: u32,
) -> Chosen {
    let u_sel = u_sel.store();
    let mut light: [&TriLight; LANES] = [&NO_LIGHT; LANES];
    let mut pmf = [0.0f32; LANES];
    let mut chosen = 0u32;
    let (p_a, ngo_a) = (p.store(), ng_o.store());
    for i in lanes(vec) {
        let (pi, ni) = (V3::lane(&p_a, i), V3::lane(&ngo_a, i));
        let selection = limits.light_selection;
        if let Some((tl, pm)) = world.lights.select_tri(selection, pi, ni, u_sel[i]) {
            chosen |= 1 << i;
            (light[i], pmf[i]) = (tl, pm);
        }
    }
    gather_lights(&light, chosen, pmf)
}

/// The lights `light`, by field: corners, normal, Le, area.
#[inline(always)]
fn gather_lights(light: &[&TriLight; LANES], chosen: u32, pmf: [f32; LANES]) -> Chosen {
    let mut lo = [V::splat(0.0).0; 8];
    let mut hi = lo;
    for (i, tl) in light.iter().enumerate() {
        let ptr = (*tl as *const TriLight).cast::<f32>();
        // SAFETY: a TriLight is 64 bytes of f32, 64-aligned; only inlined
        // into `radiance_row` or `light_walks`, which run where the CPU
        // has AVX2
        unsafe {
            lo[i] = _mm256_load_ps(ptr);
            hi[i] = _mm256_load_ps(ptr.add(8));
        }
    }
    let [qax, qay, qaz, qbx, qby, qbz, qcx, qcy] = transpose(lo);
    let [qcz, lnx, lny, lnz, lex, ley, lez, larea] = transpose(hi);
    Chosen {
        chosen,
        pmf,
        q: [
            V3::new(qax, qay, qaz),
            V3::new(qbx, qby, qbz),
            V3::new(qcx, qcy, qcz),
        ],
        n: V3::new(lnx, lny, lnz),
        le: V3::new(lex, ley, lez),
        area: larea,
    }
}

/// Next-event estimation's sample of each lane.
struct NextEvent {
    /// The point on the light.
    q: V3,
    /// The unit direction to it.
    wi_l: V3,
    /// The lanes whose shadow ray is traced.
    shadow: V,
    /// Their contribution where the light is not blocked.
    contrib: V3,
}

/// Next-event estimation with MIS (Lights::sample_entry, Bsdf::eval and
/// Bsdf::pdf of Diffuse, power_heuristic), from the numbers `u`.
#[inline(always)]
fn next_event(
    paths: &Paths,
    sh: &Shaded,
    sp: &Surface,
    fr: &Frame8,
    ls: &Chosen,
    u: [V; 2],
) -> NextEvent {
    let (zero, one) = (V::splat(0.0), V::splat(1.0));
    let (p, [qa, qb, qc]) = (sp.p, ls.q);
    let wol = V3::new(fr.wo.dot(fr.fs), fr.wo.dot(fr.ft), fr.wo.dot(fr.fn_));
    let beta = V3::load(&paths.beta);
    let (ux, uy) = (u[0], u[1]);
    let su = ux.sqrt();
    let (tb_x, tb_y) = (one - su, uy * su);
    let w0 = one - tb_x - tb_y;
    let q = V3::new(
        lerp(qa.x, qb.x, qc.x, w0, tb_x, tb_y),
        lerp(qa.y, qb.y, qc.y, w0, tb_x, tb_y),
        lerp(qa.z, qb.z, qc.z, w0, tb_x, tb_y),
    );
    let dq = V3::new(q.x - p.x, q.y - p.y, q.z - p.z);
    let dist2 = dq.dot(dq);
    let len = dist2.sqrt();
    let wi_l = V3::new(dq.x / len, dq.y / len, dq.z / len);
    let cos_l = -ls.n.dot(wi_l);
    let lpdf = V::load(&ls.pmf) / ls.area * dist2 / cos_l;
    let sampled = V::mask(ls.chosen) & dist2.nle(zero) & cos_l.nle(zero);
    let wi = V3::new(wi_l.dot(fr.fs), wi_l.dot(fr.ft), wi_l.dot(fr.fn_));
    let up = wol.z.nle(zero) & wi.z.nle(zero);
    let fr_ = V3::load(&sh.r).scale(V::splat(FRAC_1_PI));
    let cos_i = wi.z.abs();
    let f = V3::new(
        up.select(fr_.x, zero) * cos_i,
        up.select(fr_.y, zero) * cos_i,
        up.select(fr_.z, zero) * cos_i,
    );
    let nonzero = f.x.ne(zero) | f.y.ne(zero) | f.z.ne(zero);
    let shadow = sampled & nonzero & (wi_l.dot(fr.ng_o) * wi.z).gt(zero);
    let bpdf = wol.z.le(zero).select(zero, wi.z.max0() / V::splat(PI));
    let (pa, pb) = (lpdf * lpdf, bpdf * bpdf);
    let mis = (pa + pb).eq(zero).select(
        zero,
        pa.abs()
            .eq(V::splat(f32::INFINITY))
            .select(one, pa / (pa + pb)),
    );
    let k = mis / lpdf;
    let lle = ls.le;
    let contrib = V3::new(
        beta.x * f.x * lle.x * k,
        beta.y * f.y * lle.y * k,
        beta.z * f.z * lle.z * k,
    );
    NextEvent {
        q,
        wi_l,
        shadow,
        contrib,
    }
}

/// The BSDF's sample of each lane.
struct BsdfSample {
    /// The direction, in world space.
    wiw: V3,
    /// Its density.
    spdf: V,
    /// The throughput after it.
    nbeta: V3,
    /// The lanes that go on.
    goes_on: V,
    /// Russian roulette's threshold, for lanes past `rr_depth`.
    qrr: V,
}

/// Samples the BSDF from the numbers `u` (Diffuse: cosine_hemisphere,
/// concentric_disk's polynomial in lanes), and Russian roulette's
/// threshold.
#[inline(always)]
fn sample_bsdf(paths: &Paths, sh: &Shaded, fr: &Frame8, u: [V; 2]) -> BsdfSample {
    let zero = V::splat(0.0);
    let wol_z = fr.wo.dot(fr.fn_);
    let fr_ = V3::load(&sh.r).scale(V::splat(FRAC_1_PI));
    let beta = V3::load(&paths.beta);
    let (z, spdf, wiw) = cosine_sample(fr, u);
    let kb = z.abs() / spdf;
    let nbeta = V3::new(
        beta.x * (fr_.x * kb),
        beta.y * (fr_.y * kb),
        beta.z * (fr_.z * kb),
    );
    let finite = nbeta.x.finite() & nbeta.y.finite() & nbeta.z.finite();
    let zero_beta = nbeta.x.eq(zero) & nbeta.y.eq(zero) & nbeta.z.eq(zero);
    let goes_on =
        wol_z.nle(zero) & spdf.nle(zero) & (wiw.dot(fr.ng_o) * z).nle(zero) & finite & !zero_beta;
    let m = nbeta.y.gt(nbeta.z).select(nbeta.y, nbeta.z);
    let m = nbeta.x.gt(m).select(nbeta.x, m);
    let qrr = (m * V::load(&paths.eta_scale)).min(V::splat(0.95));
    BsdfSample {
        wiw,
        spdf,
        nbeta,
        goes_on,
        qrr,
    }
}

/// A direction from the numbers `u` by the cosine's density
/// (`cosine_hemisphere`: concentric_disk's polynomial in lanes): its
/// cosine in the frame, its density, and the direction in world space.
#[inline(always)]
fn cosine_sample(fr: &Frame8, u: [V; 2]) -> (V, V, V3) {
    let (zero, one) = (V::splat(0.0), V::splat(1.0));
    let (fs, ft, fn_) = (fr.fs, fr.ft, fr.fn_);
    let (ox, oy) = (V::splat(2.0) * u[0] - one, V::splat(2.0) * u[1] - one);
    let centre = ox.eq(zero) & oy.eq(zero);
    let wide = ox.abs().gt(oy.abs());
    let rad = wide.select(ox, oy);
    let phi = V::splat(PI / 4.0) * wide.select(oy / ox, ox / oy);
    let (sin, cos) = sin_cos_quarter(phi, V::splat);
    let dx = centre.select(zero, rad * wide.select(cos, sin));
    let dy = centre.select(zero, rad * wide.select(sin, cos));
    let z = (one - (dx * dx + dy * dy)).max0().sqrt();
    let spdf = z.max0() / V::splat(PI);
    let swi = V3::new(dx, dy, z);
    let wiw = V3::new(
        fs.x * swi.x + ft.x * swi.y + fn_.x * swi.z,
        fs.y * swi.x + ft.y * swi.y + fn_.y * swi.z,
        fs.z * swi.x + ft.z * swi.y + fn_.z * swi.z,
    );
    (z, spdf, wiw)
}

/// Traces the shadow rays of next-event estimation, lane by lane, and adds
/// the contributions of the lanes whose light is not blocked.
#[inline(always)]
fn trace_shadows(
    world: &World,
    paths: &mut Paths,
    sp: &Surface,
    fr: &Frame8,
    ls: &Chosen,
    ne: &NextEvent,
    vec: u32,
) {
    let l = V3::load(&paths.l);
    let shadow_bits = ne.shadow.bits() & vec;
    let origin = offset(sp.p, fr.ng_o, ne.wi_l).store();
    let target = offset(ne.q, ls.n, ne.wi_l.neg()).store();
    for i in lanes(shadow_bits) {
        paths.rays[i] += 1;
    }
    let clear = shadow_bits & !world.accel.occluded_lanes(&origin, &target, shadow_bits);
    let c = ne.contrib;
    let lc = V3::new(l.x + c.x, l.y + c.y, l.z + c.z);
    put(&mut paths.l, V::mask(clear), lc);
}

/// The next segment of the lanes that go on, after Russian roulette's
/// draws; returns the paths that go on.
#[inline(always)]
fn next_segment<S: Sampler>(
    limits: &DepthLimits,
    paths: &mut Paths,
    rngs: &mut impl Lanes<S>,
    sp: &Surface,
    fr: &Frame8,
    bs: &BsdfSample,
    sh: Shaded,
) -> u32 {
    let (vec, mut alive) = (sh.vec, sh.alive);
    let on = bs.goes_on.bits() & vec;
    let mut rr_lanes = 0u32;
    for i in lanes(vec) {
        if on & (1 << i) == 0 {
            alive &= !(1 << i);
            continue;
        }
        paths.depth[i] += 1;
        if paths.depth[i] > limits.rr_depth {
            rr_lanes |= 1 << i;
        }
    }
    let (qrr, nbeta) = (bs.qrr, bs.nbeta);
    let rr_m = V::mask(rr_lanes);
    let stop = if rr_lanes == 0 {
        0
    } else {
        let u_rr = V(rngs.roulette(rr_lanes));
        (rr_m & u_rr.ge(qrr)).bits()
    };
    alive &= !stop;
    let nbeta = V3::select(
        rr_m,
        V3::new(nbeta.x / qrr, nbeta.y / qrr, nbeta.z / qrr),
        nbeta,
    );
    let m = V::mask(on & !stop);
    paths.specular &= !on;
    put1(&mut paths.prev_pdf, m, bs.spdf);
    put(&mut paths.prev_p, m, sp.p);
    put(&mut paths.prev_n, m, fr.ng_o);
    put(&mut paths.o, m, offset(sp.p, sp.ng, bs.wiw));
    put(&mut paths.d, m, bs.wiw);
    put(&mut paths.beta, m, nbeta);
    alive
}
