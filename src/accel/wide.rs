//! The 4-wide BVH that the kernels in `traverse.rs` walk, collapsed from
//! obvhs's binary BVH: child boxes in structure-of-arrays layout so that one
//! node tests its four children at once, and leaf triangles in packs of four
//! for the same reason (the layout of Embree's BVH4 with its `Triangle4`).
//!
//! The collapse is `collapse.rs`'s, four wide: small subtrees become leaves
//! where the surface area heuristic says so, and testing four triangles
//! costs about as much as testing four boxes.

use obvhs::bvh2::Bvh2;
use obvhs::triangle::Triangle;

use super::collapse::collapse;
pub(super) use super::collapse::{Collapse, LEAF_BIT};

/// Entries of the traversal stack. A wide node pushes at most three (it
/// descends into the fourth), so a tree of depth `d` needs at most `3d`;
/// [`Wide::from_bvh2`] declines trees that would need more.
pub(super) const STACK: usize = 256;

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
    pub fn from_bvh2(bvh2: &Bvh2, tris: &[Triangle], options: &Collapse) -> Option<Wide> {
        let c = collapse::<4>(bvh2, tris, options, STACK)?;
        Some(Wide {
            nodes: (c.boxes.into_iter().zip(c.child))
                .map(|(b, child)| Node { b, child })
                .collect(),
            packs: (c.packs.into_iter())
                .map(|[v0, e1, e2, ng]| Pack { v0, e1, e2, ng })
                .collect(),
            ids: c.ids,
            root: c.root,
        })
    }
}
