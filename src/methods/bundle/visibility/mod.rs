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
//!   ceiling's back; the darkening is measured in docs/notebook/bundle.md).
//!
//! **Z-buffer variant**, for comparison (the hardware approach of ref. 40):
//! depth peeling. Each layer rasterises every patch and keeps, per pixel,
//! the nearest fragment beyond the previous layer's depth; consecutive
//! layers are the pairs (j, i). No sorting error, but one pass over all
//! patches per depth layer.
//!
//! **Parallelism and memory**: the map is cut into horizontal tiles small
//! enough for a core's L2 cache ([`tile_rows`]). The patches are projected
//! in patch order (memory order) in a fixed number of chunks, each putting
//! every projection into the bins of the tiles it touches; each tile then
//! sorts its own projections by depth and scans them with its own
//! accumulators, so nothing is gathered across the whole patch set in
//! depth order and both phases keep every core busy. The tiles are summed
//! in a fixed order, and a tile's order is a sort by unique keys, so the
//! result does not depend on the thread count. Each thread keeps one
//! tile's buffer from iteration to iteration. The threads take the tiles
//! from a queue, largest first. The projection depends on the direction
//! only, so [`project`] can run apart from the sweep, ahead of it.

#[cfg(target_arch = "x86_64")]
mod lanes;
mod painter;
mod raster;

use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::Mutex;
use std::time::Instant;

use glam::Vec3;
use rayon::prelude::*;

use super::patches::Patches;
use crate::geometry::Frame;
use crate::scene::Rgb;
pub use painter::LAYERS;
use painter::{painter_band, zbuffer_band, Px};
use raster::{order_bits, Proj, Projector, ToMap};

/// Pixel value of the sky (nothing upstream).
pub const SKY: u32 = u32::MAX;
const NONE: u32 = u32::MAX - 1;

/// How visibility is resolved.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "kebab-case")]
#[cfg_attr(feature = "cli", derive(clap::ValueEnum))]
pub enum Visibility {
    /// Sorting plus scan conversion into an id buffer (§6).
    Painter,
    /// Depth peeling with a z-buffer.
    #[cfg_attr(feature = "cli", value(name = "zbuffer"))]
    #[serde(rename = "zbuffer")]
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
    /// Seconds spent projecting the patches into the tiles' bins.
    pub t_project: f64,
    /// Seconds spent sorting each tile's projections, scan-converting them
    /// and summing the tiles.
    pub t_raster: f64,
}

/// What a sweep needs besides the patches.
pub struct SweepInput<'a> {
    /// The direction, the map and its random streams.
    pub plane: Plane,
    /// Radiance of every patch toward +d.
    pub l_plus: &'a [Rgb],
    /// Radiance of every patch toward −d.
    pub l_minus: &'a [Rgb],
    /// Sky radiance flowing along +d (the environment seen looking toward −d).
    pub sky_plus: Rgb,
    /// Sky radiance flowing along −d.
    pub sky_minus: Rgb,
}

/// What the projection of the patches depends on: the direction, the map
/// and its random streams, not the radiance. So the next direction's
/// projection can be made while this one's radiance is still being
/// reflected ([`project`]).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Plane {
    /// Flow direction d (unit).
    pub d: Vec3,
    /// Map resolution.
    pub res: u32,
    /// Centre of the scene's bounding sphere.
    pub center: Vec3,
    /// Its radius.
    pub radius: f32,
    /// Random stream keys (seed, iteration).
    pub keys: [u64; 2],
    /// Painter or z-buffer (the painter sorts by depth).
    pub visibility: Visibility,
    /// Sub-pixel patches: Russian roulette by the pixel-centre test (true)
    /// or by a uniformly placed single pixel (false); see the module notes.
    pub centre_rr: bool,
}

/// The sizes of a plane's map and of its partition into tiles and chunks.
struct Layout {
    w: i32,
    h: i32,
    delta: f32,
    rows_per_tile: i32,
    ntiles: usize,
    chunk_len: usize,
}

impl Plane {
    fn layout(&self, n: usize) -> Layout {
        let res = self.res.max(1);
        let w = res as i32 + 1;
        let h = res as i32 + 1;
        let rows_per_tile = tile_rows(w as usize) as i32;
        Layout {
            w,
            h,
            delta: 2.0 * self.radius / res as f32,
            rows_per_tile,
            ntiles: (h as usize).div_ceil(rows_per_tile as usize),
            chunk_len: n.div_ceil(CHUNKS).max(1),
        }
    }
}

/// Bytes of one patch's projection in a tile's bin (for the memory report).
pub const PROJ_BYTES: usize = std::mem::size_of::<Proj>();

/// Chunks of the patch array projected in parallel. A fixed number, so
/// that a tile's bins are the same whatever the thread count (the sort
/// would undo any other order anyway, the keys being unique).
const CHUNKS: usize = 16;
/// Bits of a sort key that hold the slot in a chunk's bin (below them the
/// chunk, above them the depth): a chunk holds at most 2^32 / 16 patches.
const SLOT_BITS: u32 = 28;
const SLOT_MASK: u64 = (1 << SLOT_BITS) - 1;

/// One tile's projections: each chunk's bin for the tile.
pub(super) struct Src<'a> {
    bins: [&'a [Proj]; CHUNKS],
}

impl Src<'_> {
    /// The projection a sort key points at.
    #[inline(always)]
    fn at(&self, key: u64) -> &Proj {
        let chunk = (key >> SLOT_BITS) as usize % CHUNKS;
        &self.bins[chunk][(key & SLOT_MASK) as usize]
    }
}

/// Buffers a sweep reuses from one iteration to the next, so that an
/// iteration allocates nothing of the size of the patch set or the map.
/// Each is sized by the iteration's exact count (per chunk, or in all),
/// not by the largest count any one tile ever had, so that they do not
/// grow with the number of directions swept.
#[derive(Default)]
pub struct Scratch {
    /// Per chunk of patches, its projections grouped by tile.
    chunks: Vec<Chunk>,
    /// Per tile entry, tile after tile, what it received along +d and −d.
    /// Within a tile the entries are in bin order (chunk after chunk, each
    /// chunk's bin in patch order), not in the sorted order of the scan, so
    /// that the sum over the tiles can run chunk by chunk in parallel.
    ep: Vec<Rgb>,
    em: Vec<Rgb>,
    /// Each tile's first entry in `ep` and `em` (one more at the end).
    start: Vec<usize>,
    /// The tile of each row of the map.
    tile_of: Vec<u32>,
    /// The plane (and patch count) whose projections `chunks` hold.
    projected: Option<(Plane, usize)>,
}

/// One chunk's projections.
#[derive(Default)]
struct Chunk {
    /// In patch order.
    by_id: Vec<Proj>,
    /// Grouped by tile, in patch order within a tile: tile t's are
    /// `by_tile[start[t]..start[t + 1]]`.
    by_tile: Vec<Proj>,
    start: Vec<usize>,
    /// Where the next projection of each tile goes.
    next: Vec<usize>,
}

/// A tile's index and its shares of the entries' accumulators (+d, −d).
type TilePart<'a> = (usize, &'a mut [Rgb], &'a mut [Rgb]);

/// A thread's buffers for the tile it scans.
#[derive(Default)]
struct Work {
    /// Sort keys of the tile's projections, and the radix sort's second
    /// buffer.
    keys: Vec<u64>,
    spare: Vec<u64>,
    /// L(+d) and L(−d) of the tile's patches in sorted order.
    lp: Vec<Rgb>,
    lm: Vec<Rgb>,
    /// What they received along +d and −d, in sorted order.
    ep: Vec<Rgb>,
    em: Vec<Rgb>,
}

thread_local! {
    static WORK: std::cell::RefCell<Work> = std::cell::RefCell::default();
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
/// radix sort, 4 passes of 8 bits). A tile's keys are made in patch order
/// with a slot that grows with the patch id in the low bits, so this gives
/// the order of sorting by (depth, patch id), in a fraction of the time of
/// a comparison sort.
fn radix_sort_hi(keys: &mut Vec<u64>, spare: &mut Vec<u64>) {
    spare.clear();
    spare.resize(keys.len(), 0);
    // the four bytes' counts in one pass (they do not depend on the order)
    let mut counts = [[0u32; 256]; 4];
    for &k in keys.iter() {
        let hi = (k >> 32) as u32;
        for (pass, count) in counts.iter_mut().enumerate() {
            count[(hi >> (8 * pass) & 0xFF) as usize] += 1;
        }
    }
    for (pass, count) in counts.iter_mut().enumerate() {
        let shift = 32 + 8 * pass;
        if count.contains(&(keys.len() as u32)) {
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
            spare[count[b] as usize] = k;
            count[b] += 1;
        }
        std::mem::swap(keys, spare);
    }
}

/// Transports the radiance of every patch along +d and −d at once and
/// returns what each patch receives. `scratch` holds the buffers of the
/// previous call, reused.
pub fn sweep(patches: &Patches, inp: &SweepInput, scratch: &mut Scratch) -> Incoming {
    let mut out = Incoming::default();
    sweep_into(patches, inp, scratch, &mut out);
    out
}

/// Projects every patch onto the map of `plane`, in patch order, and
/// groups the projections by the tiles they touch (Russian roulette for
/// sub-pixel ones), into `scratch`, for a later [`sweep_into`] with the
/// same plane. Nothing here reads the radiance, so the caller may project
/// the next direction while the radiance of this one is still in use.
pub fn project(patches: &Patches, plane: &Plane, scratch: &mut Scratch) {
    let n = patches.len();
    let d = plane.d;
    let Layout {
        w,
        h,
        delta,
        rows_per_tile,
        ntiles,
        chunk_len,
    } = plane.layout(n);
    let frame = Frame::from_normal(d);
    let mut jr = crate::sampling::Pcg32::keyed(&[plane.keys[0], plane.keys[1], 0x0FF5]);
    let jitter = jr.next_2d();
    let painter = plane.visibility == Visibility::Painter;
    let to_map = ToMap {
        center: plane.center,
        frame,
        d,
        radius: plane.radius,
        delta,
        jitter,
    };
    let pj = Projector {
        w,
        h,
        centre_rr: plane.centre_rr,
        keys: plane.keys,
    };
    // each row's tile, looked up: a division by a number known only at run
    // time, four per patch, was a long-latency instruction in this loop
    let tile_of = &mut scratch.tile_of;
    tile_of.clear();
    tile_of.extend((0..h).map(|y| (y / rows_per_tile) as u32));
    let tile_of = &*tile_of;
    let chunks = &mut scratch.chunks;
    chunks.resize_with(CHUNKS, Default::default);
    // eight patches at once where the CPU can, from the corners kept by
    // coordinate; single-pixel roulette stays scalar (its random streams
    // are per patch)
    #[cfg(target_arch = "x86_64")]
    let eight = plane.centre_rr && lanes::available();
    #[cfg(not(target_arch = "x86_64"))]
    let eight = false;
    let corners = patches.corners();
    // a projection's rows are inside the map (Proj::new clips them)
    // (an exclusive range: an inclusive one iterates with an extra flag)
    let tiles_of =
        |pr: &Proj| tile_of[pr.y0 as usize] as usize..tile_of[pr.y1 as usize] as usize + 1;
    patches
        .p
        .par_chunks(chunk_len)
        .zip(chunks.par_iter_mut())
        .enumerate()
        .for_each(|(chunk, (ps, ck))| {
            // project, counting each tile's projections
            ck.by_id.clear();
            ck.start.clear();
            ck.start.resize(ntiles + 1, 0);
            let first = chunk * chunk_len;
            if eight {
                // SAFETY: `eight` says the CPU has AVX2, and the chunk's
                // patches are patches of `corners`
                #[cfg(target_arch = "x86_64")]
                unsafe {
                    lanes::project_avx2(
                        corners,
                        first..first + ps.len(),
                        &to_map,
                        &pj,
                        painter,
                        &mut ck.by_id,
                    )
                };
                for pr in &ck.by_id {
                    for t in tiles_of(pr) {
                        ck.start[t + 1] += 1;
                    }
                }
            } else {
                for (j, p) in ps.iter().enumerate() {
                    let id = (first + j) as u32;
                    let (t, z, centroid) = to_map.patch(&p.v);
                    // the painter's order is the centroid's depth (§6); the
                    // z-buffer keeps patch order
                    let key = if painter { order_bits(centroid) } else { 0 };
                    if let Some(pr) = Proj::new(&pj, id, t, z, key) {
                        for t in tiles_of(&pr) {
                            ck.start[t + 1] += 1;
                        }
                        ck.by_id.push(pr);
                    }
                }
            }
            // group by tile (a counting sort, which keeps patch order)
            for t in 0..ntiles {
                ck.start[t + 1] += ck.start[t];
            }
            ck.next.clear();
            ck.next.extend_from_slice(&ck.start[..ntiles]);
            // every entry below start[ntiles] is written next, so the old
            // ones need no clearing (only new room is filled)
            let total = ck.start[ntiles];
            ck.by_tile.truncate(total);
            if let Some(&first) = ck.by_id.first() {
                ck.by_tile.resize(total, first);
            }
            for pr in &ck.by_id {
                for t in tiles_of(pr) {
                    ck.by_tile[ck.next[t]] = *pr;
                    ck.next[t] += 1;
                }
            }
        });
    // chunks past the patches (fewer than CHUNKS of them) hold nothing
    for ck in chunks.iter_mut().skip(n.div_ceil(chunk_len)) {
        ck.by_tile.clear();
        ck.start.clear();
        ck.start.resize(ntiles + 1, 0);
    }
    scratch.projected = Some((*plane, n));
}

/// [`sweep`] into `out`, whose buffers are reused. The projection is the
/// one [`project`] left in `scratch` for this plane, or made now.
pub fn sweep_into(patches: &Patches, inp: &SweepInput, scratch: &mut Scratch, out: &mut Incoming) {
    scan_into(patches, inp, scratch, out);
    sum_into(patches, scratch, out, &mut [], &mut [], |_, _, _, _, _| 0);
}

/// The first half of [`sweep_into`]: projects (unless done ahead), sorts
/// and scans every tile, leaving each tile entry's share of the incoming
/// radiance in `scratch` for [`sum_into`]. Sets `out`'s fragment count and
/// timings (the scan's; [`sum_into`] adds its own).
pub fn scan_into(patches: &Patches, inp: &SweepInput, scratch: &mut Scratch, out: &mut Incoming) {
    let n = patches.len();
    let plane = inp.plane;
    let Layout {
        w,
        h,
        rows_per_tile,
        ntiles,
        ..
    } = plane.layout(n);

    // Project every patch onto the plane, unless done ahead
    let t0 = Instant::now();
    if scratch.projected != Some((plane, n)) {
        project(patches, &plane, scratch);
    }
    let t_project = t0.elapsed().as_secs_f64();
    let Scratch {
        chunks,
        ep,
        em,
        start,
        ..
    } = scratch;

    // Per tile: sort its projections by depth, then scan-convert them
    let t1 = Instant::now();
    start.clear();
    start.push(0);
    for t in 0..ntiles {
        let count: usize = chunks.iter().map(|c| c.start[t + 1] - c.start[t]).sum();
        start.push(start[t] + count);
    }
    let total = start[ntiles];
    // every entry is written by its tile below, so the old values need no
    // clearing (a serial pass over all entries, while the other core waits)
    ep.resize(total, Rgb::ZERO);
    ep.truncate(total);
    em.resize(total, Rgb::ZERO);
    em.truncate(total);
    // each tile's share of the entries, as disjoint slices
    let mut parts = Vec::with_capacity(ntiles);
    let (mut p, mut m) = (&mut ep[..], &mut em[..]);
    for t in 0..ntiles {
        let k = start[t + 1] - start[t];
        let (p0, p1) = std::mem::take(&mut p).split_at_mut(k);
        let (m0, m1) = std::mem::take(&mut m).split_at_mut(k);
        parts.push((t, p0, m0));
        (p, m) = (p1, m1);
    }
    let chunks = &*chunks;
    // The tiles' costs differ by orders of magnitude (most of the plane is
    // empty), so the threads take them from one queue, largest first, and
    // none is left alone with a big tile at the end. Each tile writes only
    // its own entries, so the order they run in changes no sum.
    parts.sort_by_key(|(_, p, _)| std::cmp::Reverse(p.len()));
    let queue: Vec<Mutex<Option<TilePart>>> =
        parts.into_iter().map(|x| Mutex::new(Some(x))).collect();
    let taken = AtomicUsize::new(0);
    let scan_tile = |(tile, ep_out, em_out): (usize, &mut [Rgb], &mut [Rgb])| {
        let y0 = tile as i32 * rows_per_tile;
        let y1 = (y0 + rows_per_tile).min(h);
        let src = Src {
            bins: std::array::from_fn(|c| {
                let ck = &chunks[c];
                &ck.by_tile[ck.start[tile]..ck.start[tile + 1]]
            }),
        };
        // where each chunk's bin starts among the tile's entries
        let mut bin_at = [0usize; CHUNKS];
        for c in 1..CHUNKS {
            bin_at[c] = bin_at[c - 1] + src.bins[c - 1].len();
        }
        WORK.with_borrow_mut(|wk| {
            // keys in patch order: depth high, (chunk, slot) low
            wk.keys.clear();
            for (c, bin) in src.bins.iter().enumerate() {
                let hi = (c as u64) << SLOT_BITS;
                wk.keys.extend(
                    bin.iter()
                        .enumerate()
                        .map(|(i, pr)| (pr.key as u64) << 32 | hi | i as u64),
                );
            }
            radix_sort_hi(&mut wk.keys, &mut wk.spare);
            // the band fills lp and lm as it reaches each patch
            wk.lp.clear();
            wk.lm.clear();
            let n = wk.keys.len();
            wk.ep.clear();
            wk.ep.resize(n, Rgb::ZERO);
            wk.em.clear();
            wk.em.resize(n, Rgb::ZERO);
            let mut acc = Band {
                lp: &mut wk.lp,
                lm: &mut wk.lm,
                ep: &mut wk.ep,
                em: &mut wk.em,
            };
            let frags = match inp.plane.visibility {
                Visibility::Painter => painter_band(&src, &wk.keys, inp, y0..y1, w, &mut acc),
                Visibility::ZBuffer => zbuffer_band(&src, &wk.keys, inp, y0..y1, w, &mut acc),
            };
            // back from sorted order to bin order
            for ((&k, &p), &m) in wk.keys.iter().zip(&wk.ep).zip(&wk.em) {
                let at = bin_at[(k >> SLOT_BITS) as usize % CHUNKS] + (k & SLOT_MASK) as usize;
                ep_out[at] = p;
                em_out[at] = m;
            }
            frags
        })
    };
    let fragments: u64 = (0..rayon::current_num_threads())
        .into_par_iter()
        .map(|_| {
            let mut frags = 0;
            while let Some(slot) = queue.get(taken.fetch_add(1, Ordering::Relaxed)) {
                let part = slot.lock().map(|mut s| s.take()).ok().flatten();
                frags += part.map_or(0, scan_tile);
            }
            frags
        })
        .sum();
    out.fragments = fragments;
    out.t_project = t_project;
    out.t_raster = t1.elapsed().as_secs_f64();
}

/// The second half of [`sweep_into`], after [`scan_into`]: sums the tiles'
/// entries into each patch's incoming radiance `out.e_plus`, `out.e_minus`,
/// then runs `then` on each chunk of patches while the chunk's sums are
/// still in cache: `then(first, e_plus, e_minus, a, b)` gets the chunk's
/// first patch id, the chunk's incoming radiance and its ranges of `a` and
/// `b` (per-patch buffers of the caller, such as the transfer's
/// L(±ω_{m+1})); when `a` and `b` are empty it only sums, without calling
/// `then`. Returns the sum of what `then` returned; adds the time to
/// `out.t_raster`.
pub fn sum_into<F>(
    patches: &Patches,
    scratch: &Scratch,
    out: &mut Incoming,
    a: &mut [Rgb],
    b: &mut [Rgb],
    then: F,
) -> u64
where
    F: Fn(usize, &[Rgb], &[Rgb], &mut [Rgb], &mut [Rgb]) -> u64 + Sync,
{
    let t0 = Instant::now();
    let n = patches.len();
    assert!(
        a.len() == b.len() && (a.is_empty() || a.len() == n),
        "sum_into: the caller's buffers hold one value per patch, or none"
    );
    let Some((plane, _)) = scratch.projected else {
        return 0;
    };
    let Layout {
        delta,
        ntiles,
        chunk_len,
        ..
    } = plane.layout(n);
    let Scratch {
        chunks,
        ep,
        em,
        start,
        ..
    } = scratch;

    // Sum the tiles in a fixed order: each patch's entries, tile after
    // tile. A chunk's patches are a range of ids and its bins give their
    // entries, so the chunks sum in parallel into disjoint ranges; every
    // patch still adds its tiles' terms in tile order, to zero, as a
    // serial pass over the tiles would
    let da = delta * delta;
    let sum_chunk = |c: usize, e_plus: &mut [Rgb], e_minus: &mut [Rgb]| {
        let first = c * chunk_len;
        e_plus.fill(Rgb::ZERO);
        e_minus.fill(Rgb::ZERO);
        let ck = &chunks[c];
        for (t, &tile_at) in start[..ntiles].iter().enumerate() {
            // this chunk's bin for tile t, among the tile's entries
            let before: usize = chunks[..c]
                .iter()
                .map(|o| o.start[t + 1] - o.start[t])
                .sum();
            let at = tile_at + before;
            let bin = &ck.by_tile[ck.start[t]..ck.start[t + 1]];
            for (k, pr) in bin.iter().enumerate() {
                let i = pr.id as usize - first;
                e_plus[i] += ep[at + k];
                e_minus[i] += em[at + k];
            }
        }
        for (p, m) in e_plus.iter_mut().zip(e_minus.iter_mut()) {
            *p *= da;
            *m *= da;
        }
    };
    out.e_plus.resize(n, Rgb::ZERO);
    out.e_minus.resize(n, Rgb::ZERO);
    out.e_plus.truncate(n);
    out.e_minus.truncate(n);
    let sums = out
        .e_plus
        .par_chunks_mut(chunk_len)
        .zip(out.e_minus.par_chunks_mut(chunk_len))
        .enumerate();
    // the caller's buffers, when given, cut into the same chunks
    let r = if a.is_empty() {
        sums.for_each(|(c, (p, m))| sum_chunk(c, p, m));
        0
    } else {
        sums.zip(a.par_chunks_mut(chunk_len).zip(b.par_chunks_mut(chunk_len)))
            .map(|((c, (p, m)), (a, b))| {
                sum_chunk(c, p, m);
                then(c * chunk_len, p, m, a, b)
            })
            .sum()
    };
    out.t_raster += t0.elapsed().as_secs_f64();
    r
}

/// What one band of the map gathers. Its patches are numbered by their
/// place in the band's sorted list (the map buffers hold these local
/// numbers), so that the accumulators hold only the band's own patches and
/// stay small enough for the cache, instead of one full-length pair per
/// band; the band's copy of their radiance is read in that order too,
/// instead of a scattered read of the whole array per fragment.
struct Band<'a> {
    /// L(+d) and L(−d) of each local number, pushed by the band's sweep
    /// in sorted order (see [`Band::reach`]).
    lp: &'a mut Vec<Rgb>,
    lm: &'a mut Vec<Rgb>,
    /// Σ L(+d) δP/δP received along +d, per local number.
    ep: &'a mut [Rgb],
    /// The same along −d.
    em: &'a mut [Rgb],
}

impl Band<'_> {
    /// Copies the radiance of patch `id`, the next local number in sorted
    /// order. A fragment pairs the patch being scanned only with patches
    /// scanned before it, so the painter copies each patch's radiance when
    /// it reaches it: one read of the projection per entry instead of
    /// three scattered passes (two gathers and the scan).
    #[inline(always)]
    fn reach(&mut self, inp: &SweepInput, id: u32) {
        self.lp.push(inp.l_plus[id as usize]);
        self.lm.push(inp.l_minus[id as usize]);
    }

    /// Adds (sign = 1) or removes (sign = −1) the transfer between `a`
    /// (upstream, or [`SKY`]) and `b` (downstream) through one pixel; `a`
    /// and `b` are local numbers.
    #[inline(always)]
    fn pair(&mut self, inp: &SweepInput, a: u32, b: u32, sign: f32) {
        if a == SKY {
            self.ep[b as usize] += inp.sky_plus * sign;
        } else {
            self.ep[b as usize] += self.lp[a as usize] * sign;
            self.em[a as usize] += self.lm[b as usize] * sign;
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sampling::Pcg32;

    /// The radix sort gives the comparison sort's order for keys made as
    /// the sweep makes them (depth bits high, a slot growing with the patch
    /// id low), including equal depths and keys whose high bytes are all
    /// alike.
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
}
