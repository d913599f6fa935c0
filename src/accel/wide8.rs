//! The 8-wide BVH that the AVX2 kernels in `traverse8.rs` walk, collapsed
//! from the same binary BVH as the 4-wide one (`wide.rs`): eight child boxes
//! in structure-of-arrays layout, tested at once in one 256-bit register, so
//! that a ray passes through about half as many levels (the layout of
//! Embree's BVH8). Leaf triangles are in packs of eight ([`Pack8`], the
//! layout of `wide.rs`'s `Pack` eight lanes wide), tested at once too.
//!
//! The collapse is `collapse.rs`'s, eight wide, with the costs of this
//! layout, where one node test covers eight boxes and one pack test eight
//! triangles.
//!
//! A [`Wide8`] can only be built with an [`Avx2`] token, which only
//! [`Avx2::detect`] makes, on a CPU that has AVX2: the kernels' safety rests
//! on it.

use obvhs::bvh2::Bvh2;
use obvhs::triangle::Triangle;

/// Entries of the traversal stack. A node pushes at most seven (it
/// descends into the eighth), so a tree of depth `d` needs at most `7d`;
/// [`Wide8::from_bvh2`] declines trees that would need more.
pub(super) const STACK: usize = 512;

pub(super) use super::collapse::LEAF_BIT;
use super::collapse::{collapse, Collapse};

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
    /// stack, or too large for a child reference's bits or for i32
    /// triangle indices.
    pub fn from_bvh2(
        bvh2: &Bvh2,
        tris: &[Triangle],
        options: &Collapse,
        avx2: Avx2,
    ) -> Option<Wide8> {
        // The packets of `packet8.rs` hold scene triangle indices in i32
        // lanes, −1 for none
        if tris.len() > i32::MAX as usize {
            return None;
        }
        let c = collapse::<8>(bvh2, tris, options, STACK)?;
        Some(Wide8 {
            nodes: (c.boxes.into_iter().zip(c.child))
                .map(|(b, child)| Node8 { b, child })
                .collect(),
            packs: (c.packs.into_iter())
                .map(|[v0, e1, e2, ng]| Pack8 { v0, e1, e2, ng })
                .collect(),
            ids: c.ids,
            root: c.root,
            avx2,
        })
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
