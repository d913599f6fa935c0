//! The painter's sweep over one tile of the map, and the z-buffer's for
//! comparison. Both walk the tile's projections in the order of its sorted
//! keys and number its patches by their place in that order.

use super::raster::Visit;
use super::{Band, Src, SweepInput, NONE, SKY};
use crate::scene::Rgb;
use crate::simd::prefetch;

/// Layers of depth the painter keeps per pixel to repair the centroid
/// sort (see `painter_band`).
pub const LAYERS: usize = 2;

/// One pixel of the painter's map: the last [`LAYERS`] patches along the
/// line with their depths, most downstream first (unused layers hold
/// [`SKY`] at depth −∞), and the patch upstream of the deepest kept layer.
#[derive(Clone, Copy)]
pub(super) struct Px {
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

/// The painter's sweep over `rows` of the map, for the projections whose
/// keys are `keys` (in sorted order).
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
/// ceiling instead of the floor (the bias is measured in docs/notebook/bundle.md).
/// Misorders deeper than [`LAYERS`] are still slid in above the base.
pub(super) fn painter_band(
    src: &Src,
    keys: &[u64],
    inp: &SweepInput,
    rows: std::ops::Range<i32>,
    w: i32,
    acc: &mut Band<'_>,
) -> u64 {
    let (y0, y1) = (rows.start, rows.end);
    TILE.with_borrow_mut(|tile| {
        let (buf, used) = tile.take(w, y1 - y0);
        let mut fr = Fragment {
            buf,
            w: w as usize,
            y0,
            inp,
            acc,
            cur: 0,
            frags: 0,
        };
        for (cur, &k) in keys.iter().enumerate() {
            // The projections, their radiance and their map rows are read
            // in depth order, scattered in memory: ask for them ahead
            if let Some(&far) = keys.get(cur + AHEAD_FAR) {
                prefetch(src.at(far));
            }
            if let Some(&near) = keys.get(cur + AHEAD) {
                let pr = src.at(near);
                prefetch(&inp.l_plus[pr.id as usize]);
                prefetch(&inp.l_minus[pr.id as usize]);
                let row = (pr.y0.max(y0) - y0) as usize;
                if let Some(px) = fr.buf.get(row * w as usize + pr.x0 as usize) {
                    prefetch(px);
                }
            }
            let (pr, cur) = (src.at(k), cur as u32);
            // the rows' written spans, from the patch's box (a pixel inside
            // the box but not the patch is still empty: clearing it is
            // harmless, and far cheaper than a test per fragment)
            for span in &mut used[(pr.y0.max(y0) - y0) as usize..=(pr.y1.min(y1 - 1) - y0) as usize]
            {
                *span = (span.0.min(pr.x0), span.1.max(pr.x1 + 1));
            }
            fr.cur = cur;
            fr.acc.reach(inp, pr.id);
            pr.scan(y0, y1, &mut fr);
        }
        let frags = fr.frags;
        // the last patch along each line receives the sky along −d
        if inp.sky_minus != Rgb::ZERO {
            for (row, &(x0, x1)) in used.iter().enumerate() {
                if x0 >= x1 {
                    continue;
                }
                let at = row * w as usize;
                for px in &fr.buf[at + x0 as usize..at + x1 as usize] {
                    if px.id[0] != SKY {
                        fr.acc.em[px.id[0] as usize] += inp.sky_minus;
                    }
                }
            }
        }
        frags
    })
}

/// How many patches ahead, in sorted order, the painter asks for a
/// projection ([`AHEAD_FAR`]), and for its radiance and map row
/// ([`AHEAD`], which reads the projection asked for before).
const AHEAD_FAR: usize = 16;
/// See [`AHEAD_FAR`].
const AHEAD: usize = 8;

/// The painter's update of one pixel by one fragment of patch `cur`.
struct Fragment<'a, 'b, 'c> {
    buf: &'a mut [Px],
    w: usize,
    y0: i32,
    inp: &'a SweepInput<'b>,
    acc: &'a mut Band<'c>,
    /// Local number of the patch being scanned.
    cur: u32,
    /// Fragments so far.
    frags: u64,
}

impl Visit for Fragment<'_, '_, '_> {
    #[inline(always)]
    fn visit(&mut self, x: i32, y: i32, z: f32) {
        let (cur, inp) = (self.cur, self.inp);
        let px = &mut self.buf[(y - self.y0) as usize * self.w + x as usize];
        // the first kept layer that cur lies downstream of (ties keep the
        // sorted order)
        let k = (0..LAYERS)
            .find(|&k| px.id[k] == SKY || z >= px.z[k])
            .unwrap_or(LAYERS);
        let a = if k < LAYERS { px.id[k] } else { px.base };
        if k == 0 {
            // in order: cur sees the last writer upstream
            self.acc.pair(inp, a, cur, 1.0);
        } else {
            // sorted too late: slide cur in between a and b
            let b = px.id[k - 1];
            self.acc.pair(inp, a, b, -1.0);
            self.acc.pair(inp, a, cur, 1.0);
            self.acc.pair(inp, cur, b, 1.0);
        }
        px.insert(k, cur, z);
        self.frags += 1;
    }
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
    /// [`super::tile_rows`]), all [`Px::EMPTY`], and its (empty) row spans.
    fn take(&mut self, w: i32, rows: i32) -> (&mut [Px], &mut [(i32, i32)]) {
        let (w, rows) = (w as usize, rows as usize);
        let size = w * super::tile_rows(w).max(rows);
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

/// The z-buffer (depth-peeling) sweep over `rows`, for the projections
/// whose keys are `keys`.
pub(super) fn zbuffer_band(
    src: &Src,
    keys: &[u64],
    inp: &SweepInput,
    rows: std::ops::Range<i32>,
    w: i32,
    acc: &mut Band<'_>,
) -> u64 {
    let (y0, y1) = (rows.start, rows.end);
    let size = (w * (y1 - y0)) as usize;
    let mut prev_z = vec![f32::NEG_INFINITY; size];
    let mut prev_id = vec![SKY; size];
    let mut cur_z = vec![f32::INFINITY; size];
    let mut cur_id = vec![NONE; size];
    let mut frags = 0u64;
    for &k in keys {
        acc.reach(inp, src.at(k).id);
    }
    for _layer in 0..1024 {
        cur_z.fill(f32::INFINITY);
        cur_id.fill(NONE);
        for (local, &k) in keys.iter().enumerate() {
            src.at(k).scan(y0, y1, &mut |x, y, z: f32| {
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
