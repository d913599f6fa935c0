//! The 8-wide BVH that the AVX2 kernels in `traverse8.rs` walk, collapsed
//! from the same binary BVH as the 4-wide one (`wide.rs`): eight child boxes
//! in structure-of-arrays layout, tested at once in one 256-bit register, so
//! that a ray passes through about half as many levels (the layout of
//! Embree's BVH8). Leaf triangles are in packs of eight ([`Pack8`], the
//! layout of `wide.rs`'s `Pack` eight lanes wide), tested at once too.
//!
//! The collapse is `wide.rs`'s, opening the largest child until a node has
//! eight; which subtrees become leaves is chosen by the surface area
//! heuristic ([`leaf_choice`]) with the costs of this layout, where one
//! node test covers eight boxes and one pack test eight triangles.
//!
//! A [`Wide8`] can only be built with an [`Avx2`] token, which only
//! [`Avx2::detect`] makes, on a CPU that has AVX2: the kernels' safety rests
//! on it.

use obvhs::aabb::Aabb;
use obvhs::bvh2::Bvh2;
use obvhs::triangle::Triangle;

/// A subtree with more triangles than this is never stored as one leaf.
const LEAF_MAX: usize = 8;

/// The cost of a binary node's box tests per unit area, relative to one
/// pack of eight triangle tests (see [`leaf_choice`]). An 8-wide node
/// holds seven binary nodes' worth of boxes for one test that costs less
/// than a pack's.
const C_NODE: f32 = 0.25;

/// Entries of the traversal stack. A node pushes at most seven (it
/// descends into the eighth), so a tree of depth `d` needs at most `7d`;
/// [`Wide8::from_bvh2`] declines trees that would need more.
pub(super) const STACK: usize = 512;

/// A child reference: a node index, or with [`LEAF_BIT`] set a leaf whose
/// first pack is in bits 3..31 and whose pack count minus one is in bits 0..3.
pub(super) const LEAF_BIT: u32 = 1 << 31;

/// Packs a leaf reference can count (bits 0..3).
const MAX_LEAF_PACKS: usize = 8;
const _: () = assert!(LEAF_MAX.div_ceil(8) <= MAX_LEAF_PACKS);

/// Proof that the CPU running this process has AVX2.
#[derive(Clone, Copy)]
pub(super) struct Avx2(());

impl Avx2 {
    /// The token, when the CPU has AVX2.
    pub fn detect() -> Option<Avx2> {
        std::arch::is_x86_feature_detected!("avx2").then_some(Avx2(()))
    }
}

/// Eight child boxes. `b[2 * axis]` holds the eight minima along `axis` and
/// `b[2 * axis + 1]` the maxima; an unused slot has an empty box (min +∞,
/// max −∞) that no ray enters. Aligned so that each row is one aligned
/// 256-bit load.
#[derive(Clone, Copy)]
#[repr(C, align(32))]
pub(super) struct Node8 {
    pub b: [[f32; 8]; 6],
    pub child: [u32; 8],
}

/// The 8-wide BVH: nodes (the root first, unless the whole scene is one
/// leaf), triangle packs in leaf order, and the scene triangle index of each
/// pack slot.
pub(super) struct Wide8 {
    pub nodes: Vec<Node8>,
    pub packs: Vec<Pack8>,
    pub ids: Vec<u32>,
    pub root: u32,
    /// The kernels run only where this was detected.
    pub avx2: Avx2,
}

impl Wide8 {
    /// Collapses `bvh2` (over `tris`, not empty) into an 8-wide BVH, or
    /// `None` when the result would be too deep for the fixed traversal
    /// stack, or too large for a child reference's bits.
    pub fn from_bvh2(bvh2: &Bvh2, tris: &[Triangle], avx2: Avx2) -> Option<Wide8> {
        let leaves = leaf_choice(bvh2);
        let mut out = Wide8 {
            nodes: Vec::with_capacity(bvh2.nodes.len() / 7 + 1),
            packs: Vec::with_capacity(tris.len() / 6 + 1),
            ids: Vec::new(),
            root: 0,
            avx2,
        };
        let mut scratch = Vec::new();
        let mut kids = Vec::with_capacity(8);
        let is_inner = |k: u32| !bvh2.nodes[k as usize].is_leaf() && !leaves[k as usize];
        // (binary node, where its reference goes: wide node and slot, depth)
        let mut todo = vec![(0u32, None::<(usize, usize)>, 0usize)];
        while let Some((n, slot, depth)) = todo.pop() {
            if 7 * (depth + 1) > STACK {
                return None;
            }
            let r = if !is_inner(n) {
                scratch.clear();
                collect_prims(bvh2, n, &mut scratch);
                out.leaf(&scratch, tris)?
            } else {
                // Open the largest child until there are eight
                let first = bvh2.nodes[n as usize].first_index;
                kids.clear();
                kids.extend([first, first + 1]);
                while kids.len() < 8 {
                    let area = |k: u32| bvh2.nodes[k as usize].aabb().half_area();
                    let open = (0..kids.len())
                        .filter(|&i| is_inner(kids[i]))
                        .max_by(|&a, &b| area(kids[a]).total_cmp(&area(kids[b])));
                    let Some(i) = open else { break };
                    let k = kids.swap_remove(i);
                    let first = bvh2.nodes[k as usize].first_index;
                    kids.extend([first, first + 1]);
                }
                let index = out.nodes.len();
                if index as u32 >= LEAF_BIT {
                    return None;
                }
                let mut wide = Node8 {
                    b: [
                        [f32::INFINITY; 8],
                        [f32::NEG_INFINITY; 8],
                        [f32::INFINITY; 8],
                        [f32::NEG_INFINITY; 8],
                        [f32::INFINITY; 8],
                        [f32::NEG_INFINITY; 8],
                    ],
                    child: [u32::MAX; 8],
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
        let n_packs = prims.len().div_ceil(8);
        if n_packs > MAX_LEAF_PACKS || (first + n_packs) >> 28 != 0 {
            return None;
        }
        for chunk in prims.chunks(8) {
            let mut pack = Pack8::default();
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
                .extend(std::iter::repeat_n(u32::MAX, 8 - chunk.len()));
        }
        Some(LEAF_BIT | ((first as u32) << 3) | (n_packs as u32 - 1))
    }
}

/// Eight triangles, each coordinate in its own row: `v0`, the edges
/// `e1 = v0 − v1` and `e2 = v2 − v0`, and `ng = e1 × e2`, as in `wide.rs`'s
/// `Pack`. An unused slot is all zeros: its `ng` is zero, which the test
/// rejects.
#[derive(Clone, Copy, Default)]
#[repr(C, align(32))]
pub(super) struct Pack8 {
    pub v0: [[f32; 8]; 3],
    pub e1: [[f32; 8]; 3],
    pub e2: [[f32; 8]; 3],
    pub ng: [[f32; 8]; 3],
}

/// Which nodes of `bvh2` become leaves: those with at most [`LEAF_MAX`]
/// triangles where the surface area heuristic prices one leaf no higher
/// than the best split below. A leaf costs its area times its packs (one
/// eight-wide test each); a binary node costs [`C_NODE`] times its area plus
/// its children.
fn leaf_choice(bvh2: &Bvh2) -> Vec<bool> {
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
            cost[n] = area * (node.prim_count as f32 / 8.0).ceil();
            leaf[n] = true;
        } else {
            let (l, r) = (node.first_index as usize, node.first_index as usize + 1);
            counts[n] = counts[l] + counts[r];
            let split = C_NODE * area + cost[l] + cost[r];
            let packs = (counts[n] as f32 / 8.0).ceil();
            if counts[n] as usize <= LEAF_MAX && area * packs <= split {
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
