//! A top-down BVH builder: binned SAH (Wald 2007, "On fast construction of
//! SAH-based bounding volume hierarchies"), binning the centroids along all
//! three axes as Embree's builder does, one primitive per leaf as PLOC
//! leaves them, so that the collapse to the wide BVH treats both alike. It
//! serves the inputs that PLOC handles in quadratic time (see the parent
//! module), and `kalos bench --bvh sah`. Each level partitions its
//! primitives once, so the build takes O(n log n) time whatever the input:
//! where the centroids cannot be told apart (copies of one triangle) or the
//! tree grows too deep, a node is cut at its median instead. Subtrees of
//! many primitives are built in parallel.

use obvhs::aabb::Aabb;
use obvhs::bvh2::node::Bvh2Node;
use obvhs::bvh2::{Bvh2, DEFAULT_MAX_STACK_DEPTH};
use obvhs::triangle::Triangle;

/// Bins along each axis.
const BINS: usize = 32;
/// Subtrees of fewer primitives than this are built on one thread.
const PAR_MIN: usize = 4096;
/// Past this depth every node is cut at its median, which bounds the depth
/// by this plus log₂ n: obvhs's wide-BVH traversal keeps a fixed stack of
/// 32 entries (one per wide level), which a chain-like tree would overflow.
const MAX_SAH_DEPTH: usize = 40;

/// Builds a binary BVH over `tris` (not empty) top-down.
pub(super) fn build(tris: &[Triangle]) -> Bvh2 {
    let boxes: Vec<Aabb> = tris.iter().map(Triangle::aabb).collect();
    let centers: Vec<glam::Vec3A> = boxes.iter().map(Aabb::center).collect();
    let mut indices: Vec<u32> = (0..tris.len() as u32).collect();
    let ctx = Ctx {
        boxes: &boxes,
        centers: &centers,
    };
    let (nodes, deepest) = subtree(&ctx, &mut indices, 0, 0);
    Bvh2 {
        nodes,
        primitive_indices: indices,
        children_are_ordered_after_parents: true,
        max_depth: DEFAULT_MAX_STACK_DEPTH.max(deepest + 1),
        ..Bvh2::default()
    }
}

/// The primitives' boxes and centroids.
struct Ctx<'a> {
    boxes: &'a [Aabb],
    centers: &'a [glam::Vec3A],
}

/// The subtree over `items`, which sit at `offset` in the final primitive
/// order, with its root at depth `depth`: its nodes (the root first, and
/// siblings side by side, as obvhs expects) and its deepest level. Splits
/// a large subtree's two halves in parallel and joins their node lists.
fn subtree(ctx: &Ctx, items: &mut [u32], offset: usize, depth: usize) -> (Vec<Bvh2Node>, usize) {
    if items.len() < PAR_MIN {
        return sequential(ctx, items, offset, depth);
    }
    let bounds = bounds_of(ctx, items);
    let mid = split(items, ctx.boxes, ctx.centers, depth);
    let (l, r) = items.split_at_mut(mid);
    let ((ln, ld), (rn, rd)) = rayon::join(
        || subtree(ctx, l, offset, depth + 1),
        || subtree(ctx, r, offset + mid, depth + 1),
    );
    // [root, left root, right root, the rest of left, the rest of right]:
    // a left node i > 0 moves to i + 2, a right one to i + |left| + 1
    let (lshift, rshift) = (2u32, ln.len() as u32 + 1);
    let mut nodes = Vec::with_capacity(1 + ln.len() + rn.len());
    nodes.push(Bvh2Node::new(bounds, 0, 1));
    let moved = |n: &Bvh2Node, shift: u32| {
        let mut n = *n;
        if !n.is_leaf() {
            n.first_index += shift;
        }
        n
    };
    nodes.push(moved(&ln[0], lshift));
    nodes.push(moved(&rn[0], rshift));
    nodes.extend(ln[1..].iter().map(|n| moved(n, lshift)));
    nodes.extend(rn[1..].iter().map(|n| moved(n, rshift)));
    (nodes, ld.max(rd))
}

/// The union of the boxes of `items`.
fn bounds_of(ctx: &Ctx, items: &[u32]) -> Aabb {
    items
        .iter()
        .fold(Aabb::empty(), |b, &i| b.union(&ctx.boxes[i as usize]))
}

/// [`subtree`] on one thread.
fn sequential(ctx: &Ctx, items: &mut [u32], offset: usize, depth: usize) -> (Vec<Bvh2Node>, usize) {
    let mut nodes = vec![Bvh2Node::default()];
    nodes.reserve(2 * items.len());
    let mut deepest = depth;
    // (node slot, first index, end index, depth)
    let mut todo = vec![(0usize, 0usize, items.len(), depth)];
    while let Some((slot, start, end, depth)) = todo.pop() {
        deepest = deepest.max(depth);
        let items = &mut items[start..end];
        let bounds = bounds_of(ctx, items);
        if items.len() == 1 {
            nodes[slot] = Bvh2Node::new(bounds, 1, (offset + start) as u32);
            continue;
        }
        let mid = start + split(items, ctx.boxes, ctx.centers, depth);
        let first = nodes.len();
        nodes.push(Bvh2Node::default());
        nodes.push(Bvh2Node::default());
        nodes[slot] = Bvh2Node::new(bounds, 0, first as u32);
        todo.push((first, start, mid, depth + 1));
        todo.push((first + 1, mid, end, depth + 1));
    }
    (nodes, deepest)
}

/// Reorders `items` (two or more) and returns how many go to the first child
/// (at least one, at most all but one).
fn split(items: &mut [u32], boxes: &[Aabb], centers: &[glam::Vec3A], depth: usize) -> usize {
    let n = items.len();
    let cbounds = items.iter().fold(Aabb::empty(), |mut b, &i| {
        b.extend(centers[i as usize]);
        b
    });
    let lo = cbounds.min;
    let extent = cbounds.diagonal();
    let median = |items: &mut [u32]| {
        let axis = cbounds.largest_axis();
        let half = n / 2;
        items.select_nth_unstable_by(half, |&a, &b| {
            centers[a as usize][axis].total_cmp(&centers[b as usize][axis])
        });
        half
    };
    let usable = |axis: usize| extent[axis] > 0.0 && extent[axis].is_finite();
    if !(0..3).any(usable) || depth >= MAX_SAH_DEPTH {
        return median(items);
    }
    if n <= BINS {
        return exact(items, boxes, centers);
    }

    // Bin the centroids along each axis
    let scale: [f32; 3] = std::array::from_fn(|axis| {
        if usable(axis) {
            BINS as f32 / extent[axis]
        } else {
            0.0
        }
    });
    // Clamped while still a float (max first, so that NaN goes to bin 0 as
    // before): f32 to i32 is one conversion where f32 to usize is several
    let bin_of = |i: u32, axis: usize| {
        let t = (centers[i as usize][axis] - lo[axis]) * scale[axis];
        t.max(0.0).min((BINS - 1) as f32) as i32 as usize
    };
    let mut counts = [[0usize; BINS]; 3];
    let mut bin_boxes = [[Aabb::empty(); BINS]; 3];
    for &i in items.iter() {
        let b = &boxes[i as usize];
        for axis in 0..3 {
            let k = bin_of(i, axis);
            counts[axis][k] += 1;
            bin_boxes[axis][k] = bin_boxes[axis][k].union(b);
        }
    }

    // Sweep each axis: cutting after bin k costs A(left)·N(left) + A(right)·N(right)
    let (mut best, mut best_cost) = (None, f32::INFINITY);
    for axis in (0..3).filter(|&a| usable(a)) {
        let mut right_cost = [0.0f32; BINS];
        let (mut acc, mut count) = (Aabb::empty(), 0usize);
        for k in (1..BINS).rev() {
            acc = acc.union(&bin_boxes[axis][k]);
            count += counts[axis][k];
            right_cost[k] = if count > 0 {
                acc.half_area() * count as f32
            } else {
                0.0
            };
        }
        let (mut acc, mut count) = (Aabb::empty(), 0usize);
        for k in 0..BINS - 1 {
            acc = acc.union(&bin_boxes[axis][k]);
            count += counts[axis][k];
            if count == 0 || count == n {
                continue;
            }
            let cost = acc.half_area() * count as f32 + right_cost[k + 1];
            if cost < best_cost {
                best_cost = cost;
                best = Some((axis, k));
            }
        }
    }
    let Some((axis, k)) = best else {
        return median(items);
    };

    // Partition in place: bins 0..=k first
    let mut left = 0;
    for j in 0..n {
        if bin_of(items[j], axis) <= k {
            items.swap(left, j);
            left += 1;
        }
    }
    left
}

/// [`split`] for a node of at most [`BINS`] primitives: every cut between
/// neighbours in centroid order along each axis, where binning would lump
/// several primitives into one bin.
fn exact(items: &mut [u32], boxes: &[Aabb], centers: &[glam::Vec3A]) -> usize {
    let n = items.len();
    let mut sorted = [0u32; BINS];
    let mut best_sorted = [0u32; BINS];
    let mut right = [0.0f32; BINS];
    let (mut best_axis, mut best_cut, mut best_cost) = (None, n / 2, f32::INFINITY);
    for axis in [0, 1, 2] {
        let sorted = &mut sorted[..n];
        sorted.copy_from_slice(items);
        sorted.sort_unstable_by(|&a, &b| {
            centers[a as usize][axis].total_cmp(&centers[b as usize][axis])
        });
        let mut acc = Aabb::empty();
        for k in (1..n).rev() {
            acc = acc.union(&boxes[sorted[k] as usize]);
            right[k] = acc.half_area() * (n - k) as f32;
        }
        let mut acc = Aabb::empty();
        for k in 1..n {
            acc = acc.union(&boxes[sorted[k - 1] as usize]);
            let cost = acc.half_area() * k as f32 + right[k];
            if cost < best_cost {
                (best_axis, best_cut, best_cost) = (Some(axis), k, cost);
            }
        }
        // Keep the best axis's order rather than sort again at the end
        if best_axis == Some(axis) {
            best_sorted[..n].copy_from_slice(sorted);
        }
    }
    match best_axis {
        Some(_) => items.copy_from_slice(&best_sorted[..n]),
        // No finite cost (boxes of infinite area): x, as before
        None => items
            .sort_unstable_by(|&a, &b| centers[a as usize][0].total_cmp(&centers[b as usize][0])),
    }
    best_cut
}
