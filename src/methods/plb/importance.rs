//! Hit importance, §3.1: the paper's `ComputeImportance` (eqs. (8) and (9)),
//! and the pooled-importance grid of `--variant pooled` (our extension, not
//! in the paper).

use super::iterate::{Hit, Lane, Measured, NO_PARENT};
use crate::scene::luminance;

/// `ComputeImportance` of §3.1: the potential impact of eq. (9) plus λ times
/// the image impact of each child, eq. (8), averaged over the hit and its
/// children. Left unnormalised (the selection normalises by the sum).
#[inline]
pub(super) fn compute_importance(hits: &mut [Hit], measured: &mut [Measured], lambda: f64) {
    debug_assert_eq!(hits.len(), measured.len());
    for (h, m) in hits.iter_mut().zip(measured.iter_mut()) {
        h.s = 0.0;
        m.nchild = 0;
    }
    for i in 0..hits.len() {
        let potential = (hits[i].out_lum * measured[i].g_star) as f64;
        hits[i].s += potential;
        let p = measured[i].parent;
        if p != NO_PARENT {
            let impact = luminance(measured[i].contrib).max(0.0) as f64;
            hits[p as usize].s += lambda * impact;
            measured[p as usize].nchild += 1;
        }
    }
    for (h, m) in hits.iter_mut().zip(measured.iter()) {
        h.s /= (m.nchild + 1) as f64;
    }
}

/// Cells per axis of the pooled-importance grid.
pub(super) const GRID_RES: usize = 16;
/// Slots of the grid's statistics: the cells, then one for the rays the
/// lights emit (`--variant guided` chooses the lights by it).
pub(super) const SLOTS: usize = GRID_RES * GRID_RES * GRID_RES + 1;
/// The slot of the lights' emitted rays.
pub(super) const LIGHT_SLOT: u32 = (SLOTS - 1) as u32;
/// Pseudo-count of the grid's prior: a cell's weight is shrunk toward the
/// mean over all cells as if it had this many samples at the mean.
const GRID_PRIOR: f64 = 4.0;
/// Defensive floor of a cell's weight, as a fraction of the mean, so that
/// every hit keeps a positive selection probability (E[T*L] = TL).
const GRID_FLOOR: f64 = 0.05;

/// Pooled importance (`--variant pooled` and `guided`, not in the paper;
/// guided's r also counts what the landing point passes on,
/// `iterate::landing_value`, and its lights record into [`LIGHT_SLOT`]):
/// a uniform grid
/// over the scene's bounds. Each cell keeps Σr and the count of the rays
/// spawned from hits inside it, where r = Lum(child's image contribution) /
/// Lum(child's power) is the image impact per unit power of where the ray
/// landed (0 when it escaped or landed hidden from the camera). Then
/// W(cell) = (Σr + n₀ r̄) / (n + n₀), shrunk toward the mean r̄ over all
/// cells, estimates how much of the light reflected in that cell reaches
/// the image, pooled over every hit ever spawned there instead of over one
/// hit's children (eq. (8)). A hit's importance is Lum(Φ a) · (W + f r̄).
///
/// The lanes share what they learn: each lane reads the grid as merged at
/// the end of the last pass plus its own records since, and at the end of
/// every pass the lanes' new records are merged in lane order (so a seed
/// still gives the same image whatever the thread count).
#[derive(Clone, Debug)]
pub(super) struct ImportanceGrid {
    lo: glam::Vec3,
    scale: glam::Vec3,
    /// Everything this lane knows: the shared grid plus `fresh`.
    all: CellStats,
    /// This lane's records since the last merge.
    fresh: CellStats,
    /// The mean r over all slots of `all` ([`CellStats::mean`]), kept
    /// beside it: read two or three times a step, changed once.
    mean: f64,
}

/// Σr and counts per cell, and over all cells.
#[derive(Clone, Debug)]
pub(super) struct CellStats {
    sum: Vec<f64>,
    n: Vec<u32>,
    total: f64,
    /// The number of records, as a float: a whole number, exact below
    /// 2^53, so the same as converting an integer count (which costs a
    /// dozen instructions on x86-64 without AVX-512).
    count: f64,
}

impl CellStats {
    pub(super) fn new(cells: usize) -> Self {
        CellStats {
            sum: vec![0.0; cells],
            n: vec![0; cells],
            total: 0.0,
            count: 0.0,
        }
    }

    #[inline]
    fn add(&mut self, cell: usize, r: f64) {
        self.sum[cell] += r;
        self.n[cell] += 1;
        self.total += r;
        self.count += 1.0;
    }

    fn clear(&mut self) {
        self.sum.fill(0.0);
        self.n.fill(0);
        self.total = 0.0;
        self.count = 0.0;
    }

    /// The mean r over all slots (1 before anything was recorded).
    #[inline]
    fn mean(&self) -> f64 {
        if self.total > 0.0 {
            self.total / self.count
        } else {
            1.0
        }
    }

    fn merge(&mut self, o: &CellStats) {
        for (a, b) in self.sum.iter_mut().zip(&o.sum) {
            *a += b;
        }
        for (a, b) in self.n.iter_mut().zip(&o.n) {
            *a += b;
        }
        self.total += o.total;
        self.count += o.count;
    }
}

impl ImportanceGrid {
    pub(super) fn new(lo: glam::Vec3, hi: glam::Vec3) -> Self {
        let extent = (hi - lo).max(glam::Vec3::splat(1e-6));
        ImportanceGrid {
            lo,
            scale: glam::Vec3::splat(GRID_RES as f32) / extent,
            all: CellStats::new(SLOTS),
            fresh: CellStats::new(SLOTS),
            mean: 1.0,
        }
    }

    /// The cell of `p`, clamped to the grid. (`q` is ≥ 0 and not NaN
    /// after `max`, so clamping before the conversion, which then needs no
    /// saturation, gives what clamping after it did.)
    #[inline]
    pub(super) fn cell(&self, p: glam::Vec3) -> u32 {
        let q = ((p - self.lo) * self.scale).max(glam::Vec3::ZERO);
        let q = q.min(glam::Vec3::splat((GRID_RES - 1) as f32));
        // Through i32: a cheaper saturating conversion than to u32
        let (x, y, z) = (q.x as i32 as u32, q.y as i32 as u32, q.z as i32 as u32);
        (z * GRID_RES as u32 + y) * GRID_RES as u32 + x
    }

    #[inline(always)]
    pub(super) fn record(&mut self, cell: u32, r: f64) {
        if !r.is_finite() {
            return;
        }
        self.all.add(cell as usize, r);
        self.fresh.add(cell as usize, r);
        self.mean = self.all.mean();
    }

    /// The mean r over all slots (1 before anything was recorded).
    #[inline]
    fn mean(&self) -> f64 {
        self.mean
    }

    /// W(cell): the mean r of the cell's rays, shrunk toward the mean.
    #[inline]
    pub(super) fn value(&self, cell: u32) -> f64 {
        let a = &self.all;
        let (sum, n) = (a.sum[cell as usize], a.n[cell as usize] as f64);
        (sum + GRID_PRIOR * self.mean()) / (n + GRID_PRIOR)
    }

    /// W(cell) + f r̄, always positive.
    #[inline]
    pub(super) fn weight(&self, cell: u32) -> f64 {
        self.weights()(cell)
    }

    /// [`ImportanceGrid::weight`] of any cell, with the mean r̄ computed
    /// once (the same values: for the phase end's pass over the population).
    #[inline]
    pub(super) fn weights(&self) -> impl Fn(u32) -> f64 + '_ {
        let mean = self.mean();
        move |cell| {
            let a = &self.all;
            let (sum, n) = (a.sum[cell as usize], a.n[cell as usize] as f64);
            (sum + GRID_PRIOR * mean) / (n + GRID_PRIOR) + GRID_FLOOR * mean
        }
    }
}

/// Merges the lanes' fresh records into `shared` in lane order and gives
/// every lane the merged grid.
pub(super) fn share_grids(shared: &mut CellStats, lanes: &mut [Lane]) {
    for l in lanes.iter() {
        if let Some(g) = &l.grid {
            shared.merge(&g.fresh);
        }
    }
    for l in lanes.iter_mut() {
        if let Some(g) = l.grid.as_mut() {
            g.all.clone_from(shared);
            g.mean = g.all.mean();
            g.fresh.clear();
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sampling::Pcg32;
    use glam::Vec3;

    /// The cell clamped before the conversion is the cell clamped after it
    /// (as first written), inside the bounds, outside them, and for
    /// infinite and NaN coordinates.
    #[test]
    fn cell_matches_clamping_after_the_conversion() {
        let g = ImportanceGrid::new(Vec3::new(-1.0, 0.0, 2.0), Vec3::new(3.0, 0.5, 9.0));
        let old = |p: Vec3| {
            let q = ((p - g.lo) * g.scale).max(Vec3::ZERO);
            let r = GRID_RES as u32 - 1;
            let (x, y, z) = (
                (q.x as u32).min(r),
                (q.y as u32).min(r),
                (q.z as u32).min(r),
            );
            (z * GRID_RES as u32 + y) * GRID_RES as u32 + x
        };
        let mut rng = Pcg32::keyed(&[4]);
        let specials = [
            0.0,
            -0.0,
            1e30,
            -1e30,
            f32::INFINITY,
            f32::NEG_INFINITY,
            f32::NAN,
        ];
        for i in 0..200_000 {
            let mut c = [0.0f32; 3];
            for (k, x) in c.iter_mut().enumerate() {
                *x = 24.0 * rng.next_f32() - 12.0;
                if (i + k) % 17 == 0 {
                    *x = specials[(i / 17 + k) % specials.len()];
                }
            }
            let p = Vec3::from(c);
            assert_eq!(g.cell(p), old(p), "{p:?}");
        }
    }
}
