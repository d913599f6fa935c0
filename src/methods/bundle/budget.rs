//! Patch budgets: how the patches that `--patches` (or `--patch-edge`)
//! asks for are spread over the surfaces.
//!
//! - `area` (the paper's, and the default): one uniform edge length everywhere
//!   ([`Layout::area`]), so a surface gets patches in proportion to its area,
//!   seen or not. Every triangle keeps at least one patch, so a finely
//!   tessellated object (sphereflake's 56,814 sphere triangles) takes its
//!   triangle count whatever its size, and the rest goes by area.
//! - `projected`: the same number of patches, spread by what the camera
//!   sees. Large triangles are first cut into cells [`CELL_EDGES`] target
//!   edges long, so that the near part of a floor can be finer than its far
//!   part; then each cell gets k² patches so that the patches are about
//!   equal in the weight
//!
//!   w_c = β A_c / A + (1 − β) P_c / P,
//!
//!   where A_c is the cell's area, P_c the number of camera rays (one per
//!   pixel centre, through delta chains) that read the patch solution in
//!   the cell, and β = [`AREA_SHARE`]. A pixel reads the patch of its
//!   visible point, except that with the final gather a glossy pixel reads
//!   the patch its gather ray lands on (one BSDF-sampled bounce, as the
//!   gather draws it). The P term is the patch's pixel footprint: image
//!   error from a constant-radiance patch grows with the pixels that read
//!   it, so equal footprints spend patches where the image sees them. The A term keeps the surfaces the camera does not see (which
//!   still light the ones it does) meshed at a fraction of the uniform
//!   density instead of one patch a cell.
//!
//! The projected budget aims at the patch count of the area budget for the
//! same target edge, so that the two compare at equal patch count, and
//! gives at most that count: greedily, the cell whose patches carry the most
//! weight (w_c / k_c²) is split once more (k_c + 1, adding 2k_c + 1 patches)
//! while that fits, else it is passed over. The count then falls short of
//! the target by less than 2 k + 1 for the smallest k among the cells
//! still splittable (so by at most 2 when some cell is still whole), and
//! never goes below one patch per cell.

use std::cmp::Ordering;
use std::collections::BinaryHeap;

use rayon::prelude::*;

use super::patches::{Layout, MAX_SPLIT};
use crate::bsdf::Mode;
use crate::geometry::{offset_point, Ray};
use crate::methods::World;
use crate::sampling::Pcg32;
use crate::transport::orient;

/// Cells of the projected budget are this many target edges long, so that
/// a cell's density can range from 1/[`CELL_EDGES`]² of the uniform one
/// upward.
pub const CELL_EDGES: f32 = 4.0;

/// β: the share of the projected budget spread by area.
pub const AREA_SHARE: f64 = 0.5;

/// Longest chain of delta bounces followed from the camera.
const MAX_DELTA: u32 = 8;

/// The projected budget for target edge `edge`: the layout, and the camera
/// rays traced to measure the footprints.
/// `gather`: the final gather is on (glossy pixels read the patch their
/// gather ray lands on).
pub fn projected(world: &World, edge: f32, gather: bool) -> (Layout, u64) {
    let scene = &world.scene;
    let target = Layout::area(scene, edge).patch_count();
    let mut layout = Layout::cells(scene, CELL_EDGES * edge);
    let (pixels, rays) = coverage(world, &layout, gather);
    let area: Vec<f64> = (0..scene.triangles.len() as u32)
        .flat_map(|t| {
            let m = layout.m[t as usize] as usize;
            let a = scene.tri_area(t) as f64 / (m * m) as f64;
            std::iter::repeat_n(a, m * m)
        })
        .collect();
    let total_a: f64 = area.iter().sum();
    let total_p: f64 = pixels.iter().map(|&p| p as f64).sum();
    let beta = if total_p > 0.0 { AREA_SHARE } else { 1.0 };
    let w: Vec<f64> = area
        .iter()
        .zip(&pixels)
        .map(|(&a, &p)| {
            let pa = if total_a > 0.0 { a / total_a } else { 0.0 };
            let pp = if total_p > 0.0 {
                p as f64 / total_p
            } else {
                0.0
            };
            beta * pa + (1.0 - beta) * pp
        })
        .collect();
    spend(&mut layout.k, &w, target);
    (layout, rays)
}

/// Camera rays per cell: one ray through each pixel centre, followed
/// through delta bounces (one sampled branch, keyed by the pixel) to the
/// first non-delta surface, and with `gather` from a glossy one through one
/// BSDF-sampled bounce more. Returns the counts and the rays traced.
pub fn coverage(world: &World, layout: &Layout, gather: bool) -> (Vec<u32>, u64) {
    let (w, h) = (world.camera.width as usize, world.camera.height as usize);
    let seen: Vec<(Option<u32>, u64)> = (0..w * h)
        .into_par_iter()
        .map(|pix| {
            let (x, y) = ((pix % w) as f32 + 0.5, (pix / w) as f32 + 0.5);
            let mut rng = Pcg32::keyed(&[pix as u64, 0xB0D6]);
            read_cell(world, layout, world.camera.ray(x, y), gather, &mut rng)
        })
        .collect();
    let mut count = vec![0u32; layout.cell_count()];
    for &(c, _) in &seen {
        if let Some(c) = c {
            count[c as usize] += 1;
        }
    }
    (count, seen.iter().map(|s| s.1).sum())
}

/// The cell whose patch the pixel of `ray` reads, and the rays traced.
fn read_cell(
    world: &World,
    layout: &Layout,
    mut ray: Ray,
    mut gather: bool,
    rng: &mut Pcg32,
) -> (Option<u32>, u64) {
    let mut rays = 0;
    for _ in 0..=MAX_DELTA + 1 {
        rays += 1;
        let Some(hit) = world.accel.intersect(&ray) else {
            break;
        };
        let sp = world.scene.surface_point(hit.tri, hit.b1, hit.b2);
        let material = world.scene.material_of(&sp);
        let bsdf = material.bsdf(sp.uv);
        let glossy = gather && bsdf.has_glossy();
        if !bsdf.is_delta() && !glossy {
            return (Some(layout.cell_of(hit.tri, hit.b1, hit.b2).0), rays);
        }
        // Follow one branch of the delta chain, or the gather's bounce
        gather &= !glossy;
        let wo_world = -ray.d;
        let (frame, ng) = orient(sp.frame, sp.ng, wo_world, material.is_two_sided());
        let wo = frame.to_local(wo_world);
        let uc = rng.next_f32();
        let u = rng.next_2d();
        let Some(s) = bsdf.sample(wo, uc, u, Mode::Radiance) else {
            break;
        };
        let wi = frame.to_world(s.wi);
        ray = Ray::new(offset_point(sp.p, ng, wi), wi);
    }
    (None, rays)
}

/// A cell in the greedy split queue, ordered by the weight its patches
/// carry, then by index (lower first), so that the order is total.
struct Queued {
    per_patch: f64,
    cell: u32,
}

impl PartialEq for Queued {
    fn eq(&self, o: &Self) -> bool {
        self.cmp(o) == Ordering::Equal
    }
}
impl Eq for Queued {}
impl PartialOrd for Queued {
    fn partial_cmp(&self, o: &Self) -> Option<Ordering> {
        Some(self.cmp(o))
    }
}
impl Ord for Queued {
    fn cmp(&self, o: &Self) -> Ordering {
        self.per_patch
            .total_cmp(&o.per_patch)
            .then(o.cell.cmp(&self.cell))
    }
}

/// Splits cells (raising `k`) by weight `w` until `target` patches are
/// spent, as the module doc says. Cells of zero (or non-finite) weight stay
/// as they are.
pub fn spend(k: &mut [u16], w: &[f64], target: usize) {
    let mut count: usize = k.iter().map(|&k| (k as usize).pow(2)).sum();
    let mut heap: BinaryHeap<Queued> = w
        .iter()
        .enumerate()
        .filter(|(_, &w)| w.is_finite() && w > 0.0)
        .map(|(c, &w)| Queued {
            per_patch: w / (k[c] as f64).powi(2),
            cell: c as u32,
        })
        .collect();
    while let Some(q) = heap.pop() {
        let c = q.cell as usize;
        let kc = k[c] as usize;
        if kc as u32 >= MAX_SPLIT || count + 2 * kc + 1 > target {
            continue;
        }
        k[c] += 1;
        count += 2 * kc + 1;
        heap.push(Queued {
            per_patch: w[c] / ((kc + 1) as f64).powi(2),
            cell: q.cell,
        });
    }
}
