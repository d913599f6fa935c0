//! The visibility map on the transillumination plane (§6) and the radiance
//! transport in one global direction, for ω and −ω in one pass.
//!
//! The plane is perpendicular to the direction `d`; it covers the scene's
//! bounding sphere with `res` × `res` pixels of area δP, shifted by a random
//! sub-pixel offset every iteration so that point-sampled coverage is an
//! unbiased estimate of projected area.
//!
//! **Painter's algorithm** (the listing of §6). Patches are sorted by their
//! centroid along `d` (§6: "simply sorting them by their center introduces
//! just a negligible error") and scan-converted upstream first. In the
//! paper's one-directional listing a patch facing the flow reads the pixels
//! it covers, adds δP to A(i, j, ω) for the patch j found there, and clears
//! them, while a patch facing away writes its id. For the bi-directional
//! transfer (A(i, j, ω) = A(j, i, −ω), end of §5) every patch is a receiver
//! for one of ±ω and a sender for the other, so every patch reads the pixel
//! (the patch j just upstream of it along the line: i receives from j along
//! +d, j receives from i along −d) and writes its own id. Which side of each
//! patch takes part is decided later by the BRDF and the emission: a side
//! that does not face the flow has zero radiance in that direction, so the
//! facing test of the listing is folded into the radiance values. The
//! initial value of every pixel is the sky (§6: "initializing the image on
//! the transillumination plane by a special value"), so the first patch
//! along a line receives the sky radiance; the last patch receives the sky
//! along −d.
//!
//! Each pixel also remembers the depths of its last [`LAYERS`] writers,
//! which repairs misorders of the centroid sort up to that many layers
//! deep (see the painter band's notes).
//!
//! **Sub-pixel patches** (§6, §8) are handled by Russian roulette: a patch
//! whose projection is smaller than one pixel covers one pixel with
//! probability equal to its projected area in pixels, nothing otherwise, so
//! the expected coverage is exact. Two forms:
//!
//! - pixel-centre roulette (the default): thanks to the map's random
//!   sub-pixel offset, "the projection contains the pixel centre" *is* such
//!   a roulette, and it keeps every pixel a true line through the scene;
//! - single-pixel roulette: keep the patch with probability = its area and
//!   put it on the pixel under a uniformly chosen point of it. The expected
//!   coverage is the same, but the patch lands on a line that may not pass
//!   through it, so it is paired with patches it does not see (on cbox the
//!   luminaire, just under the ceiling, gives part of its light to the
//!   ceiling's back; the darkening is measured in BENCHMARKS.md).
//!
//! **Z-buffer variant**, for comparison (the hardware approach of ref. 40):
//! depth peeling. Each layer rasterises every patch and keeps, per pixel,
//! the nearest fragment beyond the previous layer's depth; consecutive
//! layers are the pairs (j, i). No sorting error, but one pass over all
//! patches per depth layer.
//!
//! **Parallelism and memory**: the map is cut into horizontal tiles small
//! enough for a core's L2 cache ([`tile_rows`]), each scanned with the
//! patches that touch it and its own accumulators; the tiles are summed in
//! a fixed order, so the result does not depend on the thread count. Each
//! thread keeps one tile's buffer from iteration to iteration.

use std::time::Instant;

use glam::{Vec2, Vec3};
use rayon::prelude::*;

use super::patches::Patches;
use crate::geometry::Frame;
use crate::sampling::{uniform_triangle, Pcg32};
use crate::scene::Rgb;

/// Pixel value of the sky (nothing upstream).
pub const SKY: u32 = u32::MAX;
const NONE: u32 = u32::MAX - 1;

/// How visibility is resolved.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "cli", derive(clap::ValueEnum))]
pub enum Visibility {
    /// Sorting plus scan conversion into an id buffer (§6).
    Painter,
    /// Depth peeling with a z-buffer.
    #[cfg_attr(feature = "cli", value(name = "zbuffer"))]
    ZBuffer,
}

/// Incoming radiance of every patch for the two flow directions ±d.
#[derive(Clone, Debug, Default)]
pub struct Incoming {
    /// Σ_j A(i, j, d) L_j(d): radiance flowing along +d into patch i, times
    /// the visible projected area (W/sr).
    pub e_plus: Vec<Rgb>,
    /// The same along −d.
    pub e_minus: Vec<Rgb>,
    /// Pixel fragments processed (the "rays" of the bundle).
    pub fragments: u64,
    /// Seconds spent sorting.
    pub t_sort: f64,
    /// Seconds spent projecting and scan-converting.
    pub t_raster: f64,
}

/// What a sweep needs besides the patches.
pub struct SweepInput<'a> {
    /// Flow direction d (unit).
    pub d: Vec3,
    /// Radiance of every patch toward +d.
    pub l_plus: &'a [Rgb],
    /// Radiance of every patch toward −d.
    pub l_minus: &'a [Rgb],
    /// Sky radiance flowing along +d (the environment seen looking toward −d).
    pub sky_plus: Rgb,
    /// Sky radiance flowing along −d.
    pub sky_minus: Rgb,
    /// Map resolution (pixels per side over the bounding sphere's diameter).
    pub res: u32,
    /// Centre of the scene's bounding sphere.
    pub center: Vec3,
    /// Its radius.
    pub radius: f32,
    /// Random stream keys (seed, iteration).
    pub keys: [u64; 2],
    /// Painter or z-buffer.
    pub visibility: Visibility,
    /// Sub-pixel patches: Russian roulette by the pixel-centre test (true)
    /// or by a uniformly placed single pixel (false); see the module notes.
    pub centre_rr: bool,
}

#[derive(Clone, Copy)]
enum Cover {
    /// Scan-convert the projection.
    Raster,
    /// Sub-pixel patch kept by Russian roulette: one pixel, at this depth.
    One(i32, i32, f32),
    /// Sub-pixel patch dropped by Russian roulette, or off the map.
    Skip,
}

/// Bytes of one patch's projection (for the memory report).
pub const PROJ_BYTES: usize = std::mem::size_of::<Proj>();

#[derive(Clone, Copy)]
struct Proj {
    id: u32,
    t: [Vec2; 3],
    z: [f32; 3],
    y0: i32,
    y1: i32,
    cover: Cover,
}

#[inline]
fn edge(a: Vec2, b: Vec2, p: Vec2) -> f32 {
    (b.x - a.x) * (p.y - a.y) - (b.y - a.y) * (p.x - a.x)
}

/// Top-left style tie rule: of two triangles sharing an edge (traversed in
/// opposite directions) exactly one owns pixel centres on it.
#[inline]
fn owns(a: Vec2, b: Vec2) -> bool {
    let d = b - a;
    d.y > 0.0 || (d.y == 0.0 && d.x > 0.0)
}

/// ⌊v⌋ as i32 (saturating, NaN → 0), like `v.floor() as i32`, without the
/// libm call that `floor` compiles to on baseline x86-64.
#[inline]
fn floor_i32(v: f32) -> i32 {
    let i = v as i32;
    if (i as f32) > v {
        i.saturating_sub(1)
    } else {
        i
    }
}

/// ⌈v⌉ as i32 (saturating, NaN → 0), like `v.ceil() as i32`.
#[inline]
fn ceil_i32(v: f32) -> i32 {
    let i = v as i32;
    if (i as f32) < v {
        i.saturating_add(1)
    } else {
        i
    }
}

/// Calls `f(x, y, depth)` for every pixel centre inside the triangle, rows
/// `y0..y1`, columns `0..w`.
#[inline]
fn raster(t: &[Vec2; 3], z: &[f32; 3], y0: i32, y1: i32, w: i32, mut f: impl FnMut(i32, i32, f32)) {
    let (mut a, mut b, mut c) = (t[0], t[1], t[2]);
    let (za, mut zb, mut zc) = (z[0], z[1], z[2]);
    let mut area = edge(a, b, c);
    if area == 0.0 || !area.is_finite() {
        return;
    }
    if area < 0.0 {
        std::mem::swap(&mut b, &mut c);
        std::mem::swap(&mut zb, &mut zc);
        area = -area;
    }
    let _ = &mut a;
    let lo = a.min(b).min(c);
    let hi = a.max(b).max(c);
    let xs = ceil_i32(lo.x - 0.5).max(0);
    let xe = floor_i32(hi.x - 0.5).min(w - 1);
    let ys = ceil_i32(lo.y - 0.5).max(y0);
    let ye = floor_i32(hi.y - 0.5).min(y1 - 1);
    let (oa, ob, oc) = (owns(b, c), owns(c, a), owns(a, b));
    let inv = 1.0 / area;
    for y in ys..=ye {
        let py = y as f32 + 0.5;
        // edge(u, v, p) = (v.x − u.x)(p.y − u.y) − (v.y − u.y)(p.x − u.x):
        // the first product is the same along a row (same operations in
        // the same order, so the values are bit-identical to edge())
        let (ra, rb, rc) = (
            (c.x - b.x) * (py - b.y),
            (a.x - c.x) * (py - c.y),
            (b.x - a.x) * (py - a.y),
        );
        for x in xs..=xe {
            let px = x as f32 + 0.5;
            let wa = ra - (c.y - b.y) * (px - b.x);
            let wb = rb - (a.y - c.y) * (px - c.x);
            let wc = rc - (b.y - a.y) * (px - a.x);
            let inside = (wa > 0.0 || (wa == 0.0 && oa))
                && (wb > 0.0 || (wb == 0.0 && ob))
                && (wc > 0.0 || (wc == 0.0 && oc));
            if inside {
                f(x, y, (wa * za + wb * zb + wc * zc) * inv);
            }
        }
    }
}

/// Calls `visit(x, y, depth)` for every map pixel in rows `y0..y1` that the
/// projected patch `pr` covers: its scan conversion, or the one pixel its
/// sub-pixel roulette kept. The one scan routine of the painter and the
/// z-buffer.
#[inline]
fn scan(pr: &Proj, y0: i32, y1: i32, w: i32, mut visit: impl FnMut(i32, i32, f32)) {
    match pr.cover {
        Cover::Raster => {
            if pr.y1 >= y0 && pr.y0 < y1 {
                raster(&pr.t, &pr.z, y0, y1, w, visit)
            }
        }
        Cover::One(x, y, z) => {
            if (y0..y1).contains(&y) {
                visit(x, y, z)
            }
        }
        Cover::Skip => {}
    }
}

/// Buffers a sweep reuses from one iteration to the next, so that an
/// iteration allocates nothing of the size of the patch set or the map.
#[derive(Default)]
pub struct Scratch {
    /// Sort keys (depth, patch id), and the radix sort's second buffer.
    order: Vec<u64>,
    spare: Vec<u64>,
    /// Projections in patch order, then in sorted order.
    by_id: Vec<Proj>,
    proj: Vec<Proj>,
    /// Per tile: the projections it scans, and what it gathers.
    lists: Vec<Vec<u32>>,
    tiles: Vec<(Band, u64)>,
}

/// Bytes of map one tile may hold, so that a tile of the painter's map
/// stays in a core's L2 cache while its patches are scanned.
const TILE_BYTES: usize = 512 * 1024;

/// Rows of the map per tile, for a map `w` pixels wide. The tiles, not the
/// threads, partition the map, so the sums do not depend on the thread
/// count.
pub fn tile_rows(w: usize) -> usize {
    (TILE_BYTES / (w.max(1) * std::mem::size_of::<Px>())).max(1)
}

/// Sorts keys by their high 32 bits, keeping the order of equal ones (LSD
/// radix sort, 4 passes of 8 bits). The keys are made in patch order with
/// the id in the low bits, so this gives the same order as sorting the
/// whole u64, in a fraction of the time of a comparison sort.
fn radix_sort_hi(keys: &mut Vec<u64>, spare: &mut Vec<u64>) {
    spare.clear();
    spare.resize(keys.len(), 0);
    for pass in 0..4 {
        let shift = 32 + 8 * pass;
        let mut count = [0usize; 256];
        for &k in keys.iter() {
            count[((k >> shift) & 0xFF) as usize] += 1;
        }
        if count.contains(&keys.len()) {
            continue; // every key has the same byte here
        }
        let mut at = 0;
        for c in count.iter_mut() {
            let n = *c;
            *c = at;
            at += n;
        }
        for &k in keys.iter() {
            let b = ((k >> shift) & 0xFF) as usize;
            spare[count[b]] = k;
            count[b] += 1;
        }
        std::mem::swap(keys, spare);
    }
}

/// Transports the radiance of every patch along +d and −d at once and
/// returns what each patch receives. `scratch` holds the buffers of the
/// previous call, reused.
pub fn sweep(patches: &Patches, inp: &SweepInput, scratch: &mut Scratch) -> Incoming {
    let n = patches.len();
    let d = inp.d;
    let res = inp.res.max(1);
    let w = res as i32 + 1;
    let h = res as i32 + 1;
    let frame = Frame::from_normal(d);
    let delta = 2.0 * inp.radius / res as f32;
    let mut jr = Pcg32::keyed(&[inp.keys[0], inp.keys[1], 0x0FF5]);
    let jitter = jr.next_2d();
    let Scratch {
        order,
        spare,
        by_id,
        proj,
        lists,
        tiles,
    } = scratch;

    // Sort the patches along d (upstream first); the z-buffer needs no order
    let t0 = Instant::now();
    let painter = inp.visibility == Visibility::Painter;
    if painter {
        patches
            .p
            .par_iter()
            .enumerate()
            .map(|(i, p)| {
                let k = p.centroid().dot(d).to_bits();
                let k = if k >> 31 == 1 { !k } else { k | 0x8000_0000 };
                ((k as u64) << 32) | i as u64
            })
            .collect_into_vec(order);
        radix_sort_hi(order, spare);
    }
    let t_sort = t0.elapsed().as_secs_f64();

    // Project every patch onto the plane; Russian roulette for sub-pixel ones
    let t1 = Instant::now();
    let to_map = |x: Vec3| -> (Vec2, f32) {
        let r = x - inp.center;
        (
            Vec2::new(
                (r.dot(frame.s) + inp.radius) / delta + jitter.x,
                (r.dot(frame.t) + inp.radius) / delta + jitter.y,
            ),
            r.dot(d),
        )
    };
    // in patch order, so that the patches are read in memory order, then
    // gathered into depth order: reading them in depth order stalled on
    // every patch
    patches
        .p
        .par_iter()
        .enumerate()
        .map(|(id, p)| {
            let id = id as u32;
            let (a, za) = to_map(p.v[0]);
            let (b, zb) = to_map(p.v[1]);
            let (c, zc) = to_map(p.v[2]);
            let t = [a, b, c];
            let z = [za, zb, zc];
            let lo = a.min(b).min(c);
            let hi = a.max(b).max(c);
            let parea = 0.5 * edge(a, b, c).abs();
            let cover = if parea >= 1.0 || inp.centre_rr {
                Cover::Raster
            } else {
                let mut rng = Pcg32::keyed(&[inp.keys[0], inp.keys[1], id as u64, 0x5B]);
                if rng.next_f32() < parea {
                    let bc = uniform_triangle(rng.next_2d());
                    let q = a * (1.0 - bc.x - bc.y) + b * bc.x + c * bc.y;
                    let zq = za * (1.0 - bc.x - bc.y) + zb * bc.x + zc * bc.y;
                    let (x, y) = (q.x.floor() as i32, q.y.floor() as i32);
                    if (0..w).contains(&x) && (0..h).contains(&y) {
                        Cover::One(x, y, zq)
                    } else {
                        Cover::Skip
                    }
                } else {
                    Cover::Skip
                }
            };
            Proj {
                id,
                t,
                z,
                y0: ceil_i32(lo.y - 0.5),
                y1: floor_i32(hi.y - 0.5),
                cover,
            }
        })
        .collect_into_vec(by_id);
    let proj: &[Proj] = if painter {
        order
            .par_iter()
            .map(|&o| by_id[(o & 0xFFFF_FFFF) as usize])
            .collect_into_vec(proj);
        proj
    } else {
        by_id
    };

    // Scan-convert tile by tile
    let rows_per_tile = tile_rows(w as usize) as i32;
    let ntiles = (h as usize).div_ceil(rows_per_tile as usize);
    // Which projections each tile scans, in sorted order (a patch spans
    // one tile or a few, so a tile does not walk every patch to skip it)
    lists.resize_with(ntiles, Vec::new);
    lists.iter_mut().for_each(Vec::clear);
    for (k, pr) in proj.iter().enumerate() {
        let (r0, r1) = match pr.cover {
            Cover::Raster => (pr.y0.max(0), pr.y1.min(h - 1)),
            Cover::One(_, y, _) => (y, y),
            Cover::Skip => continue,
        };
        if r0 > r1 {
            continue;
        }
        for list in &mut lists[(r0 / rows_per_tile) as usize..=(r1 / rows_per_tile) as usize] {
            list.push(k as u32);
        }
    }
    tiles.resize_with(ntiles, Default::default);
    let lists = &*lists;
    tiles
        .par_iter_mut()
        .enumerate()
        .for_each(|(tile, (acc, frags))| {
            let y0 = tile as i32 * rows_per_tile;
            let y1 = (y0 + rows_per_tile).min(h);
            let list = &lists[tile];
            acc.gid.clear();
            acc.gid.extend(list.iter().map(|&k| proj[k as usize].id));
            acc.ep.clear();
            acc.ep.resize(list.len(), Rgb::ZERO);
            acc.em.clear();
            acc.em.resize(list.len(), Rgb::ZERO);
            *frags = match inp.visibility {
                Visibility::Painter => painter_band(proj, list, inp, y0..y1, w, acc),
                Visibility::ZBuffer => zbuffer_band(proj, list, inp, y0..y1, w, acc),
            };
        });

    // Sum the tiles in a fixed order
    let da = delta * delta;
    let mut e_plus = vec![Rgb::ZERO; n];
    let mut e_minus = vec![Rgb::ZERO; n];
    for (b, _) in tiles.iter() {
        for (j, &g) in b.gid.iter().enumerate() {
            e_plus[g as usize] += b.ep[j];
            e_minus[g as usize] += b.em[j];
        }
    }
    e_plus
        .par_iter_mut()
        .zip(e_minus.par_iter_mut())
        .for_each(|(p, m)| {
            *p *= da;
            *m *= da;
        });
    let fragments = tiles.iter().map(|b| b.1).sum();
    Incoming {
        e_plus,
        e_minus,
        fragments,
        t_sort,
        t_raster: t1.elapsed().as_secs_f64(),
    }
}

/// What one band of the map gathers. Its patches are numbered by their
/// place in the band's list (the map buffers hold these local numbers), so
/// that the accumulators hold only the band's own patches and stay small
/// enough for the cache, instead of one full-length pair per band.
#[derive(Default)]
struct Band {
    /// Patch id of each local number.
    gid: Vec<u32>,
    /// Σ L(+d) δP/δP received along +d, per local number.
    ep: Vec<Rgb>,
    /// The same along −d.
    em: Vec<Rgb>,
}

impl Band {
    /// Adds (sign = 1) or removes (sign = −1) the transfer between `a`
    /// (upstream, or [`SKY`]) and `b` (downstream) through one pixel; `a`
    /// and `b` are local numbers.
    #[inline(always)]
    fn pair(&mut self, inp: &SweepInput, a: u32, b: u32, sign: f32) {
        if a == SKY {
            self.ep[b as usize] += inp.sky_plus * sign;
        } else {
            self.ep[b as usize] += inp.l_plus[self.gid[a as usize] as usize] * sign;
            self.em[a as usize] += inp.l_minus[self.gid[b as usize] as usize] * sign;
        }
    }
}

/// Bytes of the visibility map at resolution `res`: one tile of it per
/// thread (the painter's pixels, or the z-buffer's two depth and two id
/// arrays), as the map is scanned tile by tile. For the memory check
/// before a render ([`crate::render::memory_estimate`]).
pub fn map_bytes(res: u32, visibility: Visibility) -> u64 {
    // the map is (res + 1)² pixels, as in `sweep`
    let side = res.max(1) as usize + 1;
    let per_pixel = match visibility {
        Visibility::Painter => std::mem::size_of::<Px>(),
        Visibility::ZBuffer => 2 * std::mem::size_of::<f32>() + 2 * std::mem::size_of::<u32>(),
    };
    let rows = tile_rows(side).min(side);
    (rayon::current_num_threads() * rows * side * per_pixel) as u64
}

/// Layers of depth the painter keeps per pixel to repair the centroid
/// sort (see `painter_band`).
pub const LAYERS: usize = 2;

/// One pixel of the painter's map: the last [`LAYERS`] patches along the
/// line with their depths, most downstream first (unused layers hold
/// [`SKY`] at depth −∞), and the patch upstream of the deepest kept layer.
#[derive(Clone, Copy)]
struct Px {
    id: [u32; LAYERS],
    z: [f32; LAYERS],
    base: u32,
}

impl Px {
    const EMPTY: Px = Px {
        id: [SKY; LAYERS],
        z: [f32::NEG_INFINITY; LAYERS],
        base: SKY,
    };

    /// Puts `cur` at layer `k` (0 = top), pushing the deeper layers down;
    /// the deepest one falls out into `base`. `k == LAYERS` makes `cur`
    /// the new base.
    #[inline]
    fn insert(&mut self, k: usize, cur: u32, z: f32) {
        if k == LAYERS {
            self.base = cur;
            return;
        }
        self.base = self.id[LAYERS - 1];
        for j in (k + 1..LAYERS).rev() {
            self.id[j] = self.id[j - 1];
            self.z[j] = self.z[j - 1];
        }
        self.id[k] = cur;
        self.z[k] = z;
    }
}

/// The painter's sweep over `rows` of the map, for the projections in
/// `list` (indices into `proj`, in sorted order).
///
/// Sorting by centroid misorders patches whose projections overlap while
/// their centroids do not follow their true order, which happens for large
/// parallel patches close together: cbox's luminaire hangs 0.5 units under
/// a ceiling whose mesh holds, at the luminaire, a second, reversed quad
/// coplanar with the ceiling. Each pixel therefore keeps the last
/// [`LAYERS`] patches along its line with their depths. A fragment that
/// arrives with a smaller depth than the last writer is slid in where its
/// depth belongs, between the kept layers a (upstream) and b (downstream):
/// the pair (a, b) is undone and replaced by (a, new) and (new, b).
///
/// Why two layers: with one, when two coplanar patches (cbox's ceiling
/// quads) both sort before a third that lies between them in depth (the
/// luminaire), the third slides in between them and gives its light to the
/// ceiling instead of the floor (the bias is measured in BENCHMARKS.md).
/// Misorders deeper than [`LAYERS`] are still slid in above the base.
fn painter_band(
    proj: &[Proj],
    list: &[u32],
    inp: &SweepInput,
    rows: std::ops::Range<i32>,
    w: i32,
    acc: &mut Band,
) -> u64 {
    let (y0, y1) = (rows.start, rows.end);
    TILE.with_borrow_mut(|tile| {
        let (buf, used) = tile.take(w, y1 - y0);
        let mut frags = 0u64;
        for (cur, &k) in list.iter().enumerate() {
            let (pr, cur) = (&proj[k as usize], cur as u32);
            scan(pr, y0, y1, w, |x, y, z| {
                let row = (y - y0) as usize;
                let span = &mut used[row];
                *span = (span.0.min(x), span.1.max(x + 1));
                let px = &mut buf[row * w as usize + x as usize];
                // the first kept layer that cur lies downstream of (ties
                // keep the sorted order)
                let k = (0..LAYERS)
                    .find(|&k| px.id[k] == SKY || z >= px.z[k])
                    .unwrap_or(LAYERS);
                let a = if k < LAYERS { px.id[k] } else { px.base };
                if k == 0 {
                    // in order: cur sees the last writer upstream
                    acc.pair(inp, a, cur, 1.0);
                } else {
                    // sorted too late: slide cur in between a and b
                    let b = px.id[k - 1];
                    acc.pair(inp, a, b, -1.0);
                    acc.pair(inp, a, cur, 1.0);
                    acc.pair(inp, cur, b, 1.0);
                }
                px.insert(k, cur, z);
                frags += 1;
            });
        }
        // the last patch along each line receives the sky along −d
        if inp.sky_minus != Rgb::ZERO {
            for (row, &(x0, x1)) in used.iter().enumerate() {
                if x0 >= x1 {
                    continue;
                }
                let at = row * w as usize;
                for px in &buf[at + x0 as usize..at + x1 as usize] {
                    if px.id[0] != SKY {
                        acc.em[px.id[0] as usize] += inp.sky_minus;
                    }
                }
            }
        }
        frags
    })
}

/// A thread's painter map for one tile, kept from tile to tile and from
/// iteration to iteration: allocating and clearing the whole map every
/// iteration cost more than scanning it, as most of the plane is empty
/// for most directions. Only the span of each row that the last tile
/// wrote is cleared.
#[derive(Default)]
struct TileMap {
    px: Vec<Px>,
    /// Per row, the columns written since the last clear (start, end).
    used: Vec<(i32, i32)>,
}

impl TileMap {
    /// The map for `rows` rows of `w` pixels (at most a tile's,
    /// [`tile_rows`]), all [`Px::EMPTY`], and its (empty) row spans.
    fn take(&mut self, w: i32, rows: i32) -> (&mut [Px], &mut [(i32, i32)]) {
        let (w, rows) = (w as usize, rows as usize);
        let size = w * tile_rows(w).max(rows);
        if self.px.len() != size {
            // a new map size: start afresh
            self.px.clear();
            self.px.resize(size, Px::EMPTY);
            self.used.clear();
        } else {
            for (row, &(x0, x1)) in self.used.iter().enumerate() {
                if x0 < x1 {
                    self.px[row * w + x0 as usize..row * w + x1 as usize].fill(Px::EMPTY);
                }
            }
        }
        self.used.clear();
        self.used.resize(rows, (i32::MAX, i32::MIN));
        (&mut self.px, &mut self.used)
    }
}

thread_local! {
    static TILE: std::cell::RefCell<TileMap> = std::cell::RefCell::default();
}

/// The z-buffer (depth-peeling) sweep over `rows`, for the projections in
/// `list`.
fn zbuffer_band(
    proj: &[Proj],
    list: &[u32],
    inp: &SweepInput,
    rows: std::ops::Range<i32>,
    w: i32,
    acc: &mut Band,
) -> u64 {
    let (y0, y1) = (rows.start, rows.end);
    let size = (w * (y1 - y0)) as usize;
    let mut prev_z = vec![f32::NEG_INFINITY; size];
    let mut prev_id = vec![SKY; size];
    let mut cur_z = vec![f32::INFINITY; size];
    let mut cur_id = vec![NONE; size];
    let mut frags = 0u64;
    for _layer in 0..1024 {
        cur_z.fill(f32::INFINITY);
        cur_id.fill(NONE);
        for (local, &k) in list.iter().enumerate() {
            scan(&proj[k as usize], y0, y1, w, |x, y, z| {
                let k = ((y - y0) * w + x) as usize;
                if z > prev_z[k] && z < cur_z[k] {
                    cur_z[k] = z;
                    cur_id[k] = local as u32;
                }
            });
        }
        let mut any = false;
        for k in 0..size {
            let cur = cur_id[k];
            if cur == NONE {
                continue;
            }
            any = true;
            frags += 1;
            acc.pair(inp, prev_id[k], cur, 1.0);
            prev_id[k] = cur;
            prev_z[k] = cur_z[k];
        }
        if !any {
            break;
        }
    }
    if inp.sky_minus != Rgb::ZERO {
        for &id in &prev_id {
            if id != SKY {
                acc.em[id as usize] += inp.sky_minus;
            }
        }
    }
    frags
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The radix sort gives the comparison sort's order for keys made as
    /// the sweep makes them (depth bits high, patch id low), including
    /// equal depths and keys whose high bytes are all alike.
    #[test]
    fn radix_sort_matches_sort() {
        let mut rng = Pcg32::keyed(&[78]);
        for n in [0usize, 1, 2, 100, 5000] {
            for spread in [u32::MAX, 255, 0] {
                let mut keys: Vec<u64> = (0..n)
                    .map(|i| (((rng.next_u32() & spread) as u64) << 32) | i as u64)
                    .collect();
                let mut want = keys.clone();
                want.sort_unstable();
                radix_sort_hi(&mut keys, &mut Vec::new());
                assert_eq!(keys, want, "n {n}, spread {spread:#x}");
            }
        }
    }

    /// The integer floor and ceiling agree with `floor`/`ceil` then `as
    /// i32`, including the saturating and NaN cases.
    #[test]
    fn floor_ceil_match_std() {
        let mut rng = Pcg32::keyed(&[77]);
        let mut vals = vec![
            0.0,
            -0.0,
            0.5,
            -0.5,
            1.0,
            -1.0,
            2.5e9,
            -2.5e9,
            f32::INFINITY,
            f32::NEG_INFINITY,
            f32::NAN,
            16777217.0,
            -0.49999997,
        ];
        vals.extend((0..100_000).map(|_| (rng.next_f32() - 0.5) * 5000.0));
        for v in vals {
            assert_eq!(floor_i32(v), v.floor() as i32, "floor {v}");
            assert_eq!(ceil_i32(v), v.ceil() as i32, "ceil {v}");
        }
    }
}
