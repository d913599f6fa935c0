//! The 4-wide BVH that the kernels in `traverse.rs` walk, collapsed from
//! obvhs's binary BVH: child boxes in structure-of-arrays layout so that one
//! node tests its four children at once, and leaf triangles in packs of four
//! for the same reason (the layout of Embree's BVH4 with its `Triangle4`).
//!
//! The collapse follows Wald et al., "Getting rid of packets" (2008): a wide
//! node takes the two children of a binary node, then keeps opening the
//! largest (by surface area, the likeliest to be entered) of its children
//! until it has four. Small subtrees become leaves where the surface area
//! heuristic says so ([`leaf_choice`]): testing four triangles costs about
//! as much as testing four boxes.

use obvhs::aabb::Aabb;
use obvhs::bvh2::Bvh2;
use obvhs::triangle::Triangle;

/// By default, a subtree with more triangles than this is never stored as
/// one leaf.
pub(super) const LEAF_MAX: usize = 4;

/// The default cost of a binary node's box tests per unit area, relative to
/// one pack of four triangle tests (see [`leaf_choice`]).
pub(super) const C_NODE: f32 = 0.5;

/// The leaf choice of the collapse (see [`leaf_choice`]).
#[derive(Clone, Copy, Debug)]
pub(super) struct Collapse {
    /// A binary node's cost per unit area, relative to one pack test.
    pub c_node: f32,
    /// The most triangles in a leaf, at most `4 * MAX_LEAF_PACKS`.
    pub leaf_max: usize,
}

/// Entries of the traversal stack. A wide node pushes at most three (it
/// descends into the fourth), so a tree of depth `d` needs at most `3d`;
/// [`Wide::from_bvh2`] declines trees that would need more.
pub(super) const STACK: usize = 256;

/// A child reference: a node index, or with [`LEAF_BIT`] set a leaf whose
/// first pack is in bits 3..31 and whose pack count minus one is in bits 0..3.
pub(super) const LEAF_BIT: u32 = 1 << 31;

/// Packs a leaf reference can count (bits 0..3).
pub(super) const MAX_LEAF_PACKS: usize = 8;
const _: () = assert!(LEAF_MAX.div_ceil(4) <= MAX_LEAF_PACKS);

/// Four child boxes. `b[2 * axis]` holds the four minima along `axis` and
/// `b[2 * axis + 1]` the maxima; an unused slot has an empty box (min +∞,
/// max −∞) that no ray enters.
#[derive(Clone, Copy)]
#[repr(C, align(16))]
pub(super) struct Node {
    pub b: [[f32; 4]; 6],
    pub child: [u32; 4],
}

/// Four triangles, each coordinate in its own row: `v0`, the edges
/// `e1 = v0 − v1` and `e2 = v2 − v0`, and `ng = e1 × e2` (the layout of
/// madmann91's `bvh` library, which obvhs's `RtTriangle` also uses). An
/// unused slot is all zeros: its `ng` is zero, which the test rejects.
#[derive(Clone, Copy, Default)]
#[repr(C, align(16))]
pub(super) struct Pack {
    pub v0: [[f32; 4]; 3],
    pub e1: [[f32; 4]; 3],
    pub e2: [[f32; 4]; 3],
    pub ng: [[f32; 4]; 3],
}

/// The wide BVH: nodes (the root first, unless the whole scene is one
/// leaf), triangle packs in leaf order, and the scene triangle index of each
/// pack slot.
pub(super) struct Wide {
    pub nodes: Vec<Node>,
    pub packs: Vec<Pack>,
    pub ids: Vec<u32>,
    pub root: u32,
}

impl Wide {
    /// Collapses `bvh2` (over `tris`, not empty) into a wide BVH, or `None`
    /// when the result would be too deep for the fixed traversal stack, or
    /// too large for a child reference's bits.
    pub fn from_bvh2(bvh2: &Bvh2, tris: &[Triangle], collapse: &Collapse) -> Option<Wide> {
        let leaves = leaf_choice(bvh2, collapse);
        let mut out = Wide {
            nodes: Vec::with_capacity(bvh2.nodes.len() / 3 + 1),
            packs: Vec::with_capacity(tris.len() / 3 + 1),
            ids: Vec::new(),
            root: 0,
        };
        let mut scratch = Vec::new();
        // (binary node, where its reference goes: wide node and slot, depth)
        let mut todo = vec![(0u32, None::<(usize, usize)>, 0usize)];
        while let Some((n, slot, depth)) = todo.pop() {
            if 3 * (depth + 1) > STACK {
                return None;
            }
            let node = &bvh2.nodes[n as usize];
            let r = if node.is_leaf() || leaves[n as usize] {
                scratch.clear();
                collect_prims(bvh2, n, &mut scratch);
                out.leaf(&scratch, tris)?
            } else {
                // Open the largest child until there are four
                let mut kids = vec![node.first_index, node.first_index + 1];
                while kids.len() < 4 {
                    let open = kids
                        .iter()
                        .enumerate()
                        .filter(|&(_, &k)| {
                            let k = k as usize;
                            !bvh2.nodes[k].is_leaf() && !leaves[k]
                        })
                        .max_by(|a, b| {
                            let area = |k: u32| bvh2.nodes[k as usize].aabb().half_area();
                            area(*a.1).total_cmp(&area(*b.1))
                        })
                        .map(|(i, _)| i);
                    let Some(i) = open else { break };
                    let k = kids.swap_remove(i);
                    let first = bvh2.nodes[k as usize].first_index;
                    kids.extend([first, first + 1]);
                }
                let index = out.nodes.len();
                if index as u32 >= LEAF_BIT {
                    return None;
                }
                let mut wide = Node {
                    b: [
                        [f32::INFINITY; 4],
                        [f32::NEG_INFINITY; 4],
                        [f32::INFINITY; 4],
                        [f32::NEG_INFINITY; 4],
                        [f32::INFINITY; 4],
                        [f32::NEG_INFINITY; 4],
                    ],
                    child: [u32::MAX; 4],
                };
                for (i, &k) in kids.iter().enumerate() {
                    let bb: &Aabb = bvh2.nodes[k as usize].aabb();
                    for axis in 0..3 {
                        wide.b[2 * axis][i] = bb.min[axis];
                        wide.b[2 * axis + 1][i] = bb.max[axis];
                    }
                }
                out.nodes.push(wide);
                // Pushed in reverse so that the first child is laid out next
                for (i, &k) in kids.iter().enumerate().rev() {
                    todo.push((k, Some((index, i)), depth + 1));
                }
                index as u32
            };
            match slot {
                Some((w, i)) => out.nodes[w].child[i] = r,
                None => out.root = r,
            }
        }
        Some(out)
    }

    /// Appends the packs of a leaf over the triangles `prims` (indices into
    /// `tris`) and returns its reference.
    fn leaf(&mut self, prims: &[u32], tris: &[Triangle]) -> Option<u32> {
        let first = self.packs.len();
        let n_packs = prims.len().div_ceil(4);
        if n_packs > MAX_LEAF_PACKS || (first + n_packs) >> 28 != 0 {
            return None;
        }
        for chunk in prims.chunks(4) {
            let mut pack = Pack::default();
            for (lane, &p) in chunk.iter().enumerate() {
                let t = &tris[p as usize];
                let e1 = t.v0 - t.v1;
                let e2 = t.v2 - t.v0;
                let ng = e1.cross(e2);
                for axis in 0..3 {
                    pack.v0[axis][lane] = t.v0[axis];
                    pack.e1[axis][lane] = e1[axis];
                    pack.e2[axis][lane] = e2[axis];
                    pack.ng[axis][lane] = ng[axis];
                }
            }
            self.packs.push(pack);
            self.ids.extend(chunk);
            self.ids
                .extend(std::iter::repeat_n(u32::MAX, 4 - chunk.len()));
        }
        Some(LEAF_BIT | ((first as u32) << 3) | (n_packs as u32 - 1))
    }
}

/// Which nodes of `bvh2` become leaves: those with at most
/// `collapse.leaf_max` triangles where the surface area heuristic prices
/// one leaf no higher than the best split below. A leaf costs its area
/// times its packs (one four-wide test each); a binary node costs
/// `collapse.c_node` times its area (its two child boxes take half of a
/// four-wide node's test) plus its children.
/// Where two triangles of a leaf face different ways (the walls of a room)
/// their joint box is much larger than their own, and splitting pays.
fn leaf_choice(bvh2: &Bvh2, collapse: &Collapse) -> Vec<bool> {
    let leaf_max = collapse.leaf_max.clamp(1, 4 * MAX_LEAF_PACKS);
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
    for &n in order.iter().rev() {
        let node = &bvh2.nodes[n as usize];
        let n = n as usize;
        let area = node.aabb().half_area();
        if node.is_leaf() {
            counts[n] = node.prim_count;
            cost[n] = area * (node.prim_count as f32 / 4.0).ceil();
            leaf[n] = true;
        } else {
            let (l, r) = (node.first_index as usize, node.first_index as usize + 1);
            counts[n] = counts[l] + counts[r];
            let split = collapse.c_node * area + cost[l] + cost[r];
            let packs = (counts[n] as f32 / 4.0).ceil();
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
