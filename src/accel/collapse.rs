//! The collapse of obvhs's binary BVH into a `W`-wide one, shared by the
//! 4-wide layout (`wide.rs`) and the 8-wide one (`wide8.rs`), which differ
//! only in width, alignment and leaf costs.
//!
//! The collapse follows Wald et al., "Getting rid of packets" (2008): a wide
//! node takes the two children of a binary node, then keeps opening the
//! largest (by surface area, the likeliest to be entered) of its children
//! until it has `W`. Small subtrees become leaves where the surface area
//! heuristic says so ([`leaf_choice`]).

use obvhs::bvh2::Bvh2;
use obvhs::triangle::Triangle;

/// A child reference: a node index, or with [`LEAF_BIT`] set a leaf whose
/// first pack is in bits 3..31 and whose pack count minus one is in bits 0..3.
pub(super) const LEAF_BIT: u32 = 1 << 31;

/// The packs of the leaf reference `r` (see [`LEAF_BIT`]), as
/// `Collapsed::leaf` encodes them.
#[inline(always)]
pub(super) fn leaf_packs(r: u32) -> std::ops::Range<usize> {
    let first = ((r & !LEAF_BIT) >> 3) as usize;
    first..first + (r & 7) as usize + 1
}

/// Packs a leaf reference can count (bits 0..3).
pub(super) const MAX_LEAF_PACKS: usize = 8;

/// The leaf choice of the collapse (see [`leaf_choice`]).
#[derive(Clone, Copy, Debug)]
pub(super) struct Collapse {
    /// A binary node's cost per unit area, relative to one pack test.
    pub c_node: f32,
    /// The most triangles in a leaf, at most `W * MAX_LEAF_PACKS`.
    pub leaf_max: usize,
}

/// `W` triangles, each coordinate in its own row: `v0`, the edges
/// `e1 = v0 − v1` and `e2 = v2 − v0`, and `ng = e1 × e2`, in that order. An
/// unused slot is all zeros: its `ng` is zero, which the tests reject.
pub(super) type PackRows<const W: usize> = [[[f32; W]; 3]; 4];

/// A `W`-wide BVH in a neutral layout, which each width moves into its own
/// aligned node and pack types: per node its child boxes (`b[2 * axis]` the
/// minima, `b[2 * axis + 1]` the maxima; an unused slot has min +∞, max
/// −∞, which no ray enters) and child references; the packs in leaf order;
/// the scene triangle index of each pack slot (`u32::MAX` unused).
pub(super) struct Collapsed<const W: usize> {
    pub boxes: Vec<[[f32; W]; 6]>,
    pub child: Vec<[u32; W]>,
    pub packs: Vec<PackRows<W>>,
    pub ids: Vec<u32>,
    pub root: u32,
}

/// Collapses `bvh2` (over `tris`, not empty) into a `W`-wide BVH, or `None`
/// when the result would be too deep for a traversal stack of `stack`
/// entries (a node pushes at most `W − 1` and descends into the last), or
/// too large for a child reference's bits.
pub(super) fn collapse<const W: usize>(
    bvh2: &Bvh2,
    tris: &[Triangle],
    options: &Collapse,
    stack: usize,
) -> Option<Collapsed<W>> {
    let leaves = leaf_choice::<W>(bvh2, options);
    let mut out = Collapsed {
        boxes: Vec::with_capacity(bvh2.nodes.len() / (W - 1) + 1),
        child: Vec::with_capacity(bvh2.nodes.len() / (W - 1) + 1),
        packs: Vec::with_capacity(tris.len() / (3 * W / 4) + 1),
        ids: Vec::new(),
        root: 0,
    };
    let mut scratch = Vec::new();
    let mut kids = Vec::with_capacity(W);
    let is_inner = |k: u32| !bvh2.nodes[k as usize].is_leaf() && !leaves[k as usize];
    // (binary node, where its reference goes: wide node and slot, depth)
    let mut todo = vec![(0u32, None::<(usize, usize)>, 0usize)];
    while let Some((n, slot, depth)) = todo.pop() {
        if (W - 1) * (depth + 1) > stack {
            return None;
        }
        let r = if !is_inner(n) {
            scratch.clear();
            collect_prims(bvh2, n, &mut scratch);
            out.leaf(&scratch, tris)?
        } else {
            // Open the largest child until there are W
            let first = bvh2.nodes[n as usize].first_index;
            kids.clear();
            kids.extend([first, first + 1]);
            while kids.len() < W {
                let area = |k: u32| bvh2.nodes[k as usize].aabb().half_area();
                let open = (0..kids.len())
                    .filter(|&i| is_inner(kids[i]))
                    .max_by(|&a, &b| area(kids[a]).total_cmp(&area(kids[b])));
                let Some(i) = open else { break };
                let k = kids.swap_remove(i);
                let first = bvh2.nodes[k as usize].first_index;
                kids.extend([first, first + 1]);
            }
            let index = out.boxes.len();
            if index as u32 >= LEAF_BIT {
                return None;
            }
            let mut b = [
                [f32::INFINITY; W],
                [f32::NEG_INFINITY; W],
                [f32::INFINITY; W],
                [f32::NEG_INFINITY; W],
                [f32::INFINITY; W],
                [f32::NEG_INFINITY; W],
            ];
            for (i, &k) in kids.iter().enumerate() {
                let bb = bvh2.nodes[k as usize].aabb();
                for axis in 0..3 {
                    b[2 * axis][i] = bb.min[axis];
                    b[2 * axis + 1][i] = bb.max[axis];
                }
            }
            out.boxes.push(b);
            out.child.push([u32::MAX; W]);
            // Pushed in reverse so that the first child is laid out next
            for (i, &k) in kids.iter().enumerate().rev() {
                todo.push((k, Some((index, i)), depth + 1));
            }
            index as u32
        };
        match slot {
            Some((w, i)) => out.child[w][i] = r,
            None => out.root = r,
        }
    }
    Some(out)
}

impl<const W: usize> Collapsed<W> {
    /// Appends the packs of a leaf over the triangles `prims` (indices into
    /// `tris`) and returns its reference.
    fn leaf(&mut self, prims: &[u32], tris: &[Triangle]) -> Option<u32> {
        let first = self.packs.len();
        let n_packs = prims.len().div_ceil(W);
        if n_packs > MAX_LEAF_PACKS || (first + n_packs) >> 28 != 0 {
            return None;
        }
        for chunk in prims.chunks(W) {
            let mut pack: PackRows<W> = [[[0.0; W]; 3]; 4];
            for (lane, &p) in chunk.iter().enumerate() {
                let t = &tris[p as usize];
                let e1 = t.v0 - t.v1;
                let e2 = t.v2 - t.v0;
                let ng = e1.cross(e2);
                for axis in 0..3 {
                    pack[0][axis][lane] = t.v0[axis];
                    pack[1][axis][lane] = e1[axis];
                    pack[2][axis][lane] = e2[axis];
                    pack[3][axis][lane] = ng[axis];
                }
            }
            self.packs.push(pack);
            self.ids.extend(chunk);
            self.ids
                .extend(std::iter::repeat_n(u32::MAX, W - chunk.len()));
        }
        Some(LEAF_BIT | ((first as u32) << 3) | (n_packs as u32 - 1))
    }
}

/// Which nodes of `bvh2` become leaves: those with at most
/// `options.leaf_max` triangles where the surface area heuristic prices
/// one leaf no higher than the best split below. A leaf costs its area
/// times its packs (one `W`-wide test each); a binary node costs
/// `options.c_node` times its area plus its children.
/// Where two triangles of a leaf face different ways (the walls of a room)
/// their joint box is much larger than their own, and splitting pays.
fn leaf_choice<const W: usize>(bvh2: &Bvh2, options: &Collapse) -> Vec<bool> {
    let leaf_max = options.leaf_max.clamp(1, W * MAX_LEAF_PACKS);
    let mut counts = vec![0u32; bvh2.nodes.len()];
    let mut cost = vec![0f32; bvh2.nodes.len()];
    let mut leaf = vec![false; bvh2.nodes.len()];
    // Preorder, then children before parents by walking it backwards
    let mut order = Vec::with_capacity(bvh2.nodes.len());
    let mut stack = vec![0u32];
    while let Some(n) = stack.pop() {
        order.push(n);
        let node = &bvh2.nodes[n as usize];
        if !node.is_leaf() {
            stack.extend([node.first_index, node.first_index + 1]);
        }
    }
    let width = W as f32;
    for &n in order.iter().rev() {
        let node = &bvh2.nodes[n as usize];
        let n = n as usize;
        let area = node.aabb().half_area();
        if node.is_leaf() {
            counts[n] = node.prim_count;
            cost[n] = area * (node.prim_count as f32 / width).ceil();
            leaf[n] = true;
        } else {
            let (l, r) = (node.first_index as usize, node.first_index as usize + 1);
            counts[n] = counts[l] + counts[r];
            let split = options.c_node * area + cost[l] + cost[r];
            let packs = (counts[n] as f32 / width).ceil();
            if counts[n] as usize <= leaf_max && area * packs <= split {
                cost[n] = area * packs;
                leaf[n] = true;
            } else {
                cost[n] = split;
            }
        }
    }
    leaf
}

/// Appends the triangle indices under node `n` of `bvh2` to `out`.
fn collect_prims(bvh2: &Bvh2, n: u32, out: &mut Vec<u32>) {
    let mut stack = vec![n];
    while let Some(n) = stack.pop() {
        let node = &bvh2.nodes[n as usize];
        if node.is_leaf() {
            let first = node.first_index as usize;
            out.extend(&bvh2.primitive_indices[first..first + node.prim_count as usize]);
        } else {
            stack.extend([node.first_index + 1, node.first_index]);
        }
    }
}
