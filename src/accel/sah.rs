//! A top-down BVH builder for the inputs that PLOC handles in quadratic time
//! (see the parent module): binned SAH (Wald 2007, "On fast construction of
//! SAH-based bounding volume hierarchies"), one primitive per leaf as PLOC
//! leaves them, so that obvhs's conversion to the wide BVH collapses both
//! alike. Each level partitions its primitives once, so the build takes
//! O(n log n) time whatever the input: where the centroids cannot be told
//! apart (copies of one triangle) or the tree grows too deep, a node is cut
//! at its median instead.

use obvhs::aabb::Aabb;
use obvhs::bvh2::node::Bvh2Node;
use obvhs::bvh2::{Bvh2, DEFAULT_MAX_STACK_DEPTH};
use obvhs::triangle::Triangle;

/// Bins along the split axis.
const BINS: usize = 16;
/// Past this depth every node is cut at its median, which bounds the depth
/// by this plus log₂ n: obvhs's wide-BVH traversal keeps a fixed stack of
/// 32 entries (one per wide level), which a chain-like tree would overflow.
const MAX_SAH_DEPTH: usize = 40;

/// Builds a binary BVH over `tris` (not empty) top-down.
pub(super) fn build(tris: &[Triangle]) -> Bvh2 {
    let boxes: Vec<Aabb> = tris.iter().map(Triangle::aabb).collect();
    let centers: Vec<glam::Vec3A> = boxes.iter().map(Aabb::center).collect();
    let mut indices: Vec<u32> = (0..tris.len() as u32).collect();
    let mut nodes = vec![Bvh2Node::default()];
    nodes.reserve(2 * tris.len());
    let mut deepest = 0;
    // (node slot, first index, end index, depth)
    let mut todo = vec![(0usize, 0usize, tris.len(), 0usize)];
    while let Some((slot, start, end, depth)) = todo.pop() {
        deepest = deepest.max(depth);
        let items = &mut indices[start..end];
        let bounds = items
            .iter()
            .fold(Aabb::empty(), |b, &i| b.union(&boxes[i as usize]));
        if items.len() == 1 {
            nodes[slot] = Bvh2Node::new(bounds, 1, start as u32);
            continue;
        }
        let mid = start + split(items, &boxes, &centers, depth);
        let first = nodes.len();
        nodes.push(Bvh2Node::default());
        nodes.push(Bvh2Node::default());
        nodes[slot] = Bvh2Node::new(bounds, 0, first as u32);
        todo.push((first, start, mid, depth + 1));
        todo.push((first + 1, mid, end, depth + 1));
    }
    Bvh2 {
        nodes,
        primitive_indices: indices,
        children_are_ordered_after_parents: true,
        max_depth: DEFAULT_MAX_STACK_DEPTH.max(deepest + 1),
        ..Bvh2::default()
    }
}

/// Reorders `items` (two or more) and returns how many go to the first child
/// (at least one, at most all but one).
fn split(items: &mut [u32], boxes: &[Aabb], centers: &[glam::Vec3A], depth: usize) -> usize {
    let n = items.len();
    let cbounds = items.iter().fold(Aabb::empty(), |mut b, &i| {
        b.extend(centers[i as usize]);
        b
    });
    let axis = cbounds.largest_axis();
    let (lo, extent) = (cbounds.min[axis], cbounds.diagonal()[axis]);
    let median = |items: &mut [u32]| {
        let half = n / 2;
        items.select_nth_unstable_by(half, |&a, &b| {
            centers[a as usize][axis].total_cmp(&centers[b as usize][axis])
        });
        half
    };
    if !(extent > 0.0 && extent.is_finite()) || depth >= MAX_SAH_DEPTH {
        return median(items);
    }

    // Bin the centroids along the axis
    let bin_of = |i: u32| {
        let t = (centers[i as usize][axis] - lo) / extent;
        ((t * BINS as f32) as usize).min(BINS - 1)
    };
    let mut counts = [0usize; BINS];
    let mut bin_boxes = [Aabb::empty(); BINS];
    for &i in items.iter() {
        let b = bin_of(i);
        counts[b] += 1;
        bin_boxes[b] = bin_boxes[b].union(&boxes[i as usize]);
    }

    // Sweep: cost of cutting after bin k is A(left)·N(left) + A(right)·N(right)
    let mut right_cost = [0.0f32; BINS];
    let (mut acc, mut count) = (Aabb::empty(), 0usize);
    for k in (1..BINS).rev() {
        acc = acc.union(&bin_boxes[k]);
        count += counts[k];
        right_cost[k] = if count > 0 {
            acc.half_area() * count as f32
        } else {
            0.0
        };
    }
    let (mut best, mut best_cost) = (None, f32::INFINITY);
    let (mut acc, mut count) = (Aabb::empty(), 0usize);
    for k in 0..BINS - 1 {
        acc = acc.union(&bin_boxes[k]);
        count += counts[k];
        if count == 0 || count == n {
            continue;
        }
        let cost = acc.half_area() * count as f32 + right_cost[k + 1];
        if cost < best_cost {
            best_cost = cost;
            best = Some(k);
        }
    }
    let Some(k) = best else {
        return median(items);
    };

    // Partition in place: bins 0..=k first
    let mut left = 0;
    for j in 0..n {
        if bin_of(items[j]) <= k {
            items.swap(left, j);
            left += 1;
        }
    }
    left
}
