//! Measures of a wide BVH's quality, for `kalos bench`: the surface area
//! heuristic's prediction of the tests a ray makes ([`TreeStats`]), and the
//! tests a ray actually made ([`Visits`]). Together they tell a tree that
//! makes rays do more work from a kernel that does the same work slowly.

use super::collapse::leaf_packs;
use super::wide::{Node, Wide, LEAF_BIT};

/// The shape of a wide BVH and its surface area heuristic (SAH) cost.
///
/// The SAH prices a tree for rays that enter the root's box with uniformly
/// distributed lines (MacDonald and Booth 1990): such a ray enters a box
/// inside it with probability the ratio of their surface areas. It ignores
/// that a closest-hit ray stops early, so the measured visits of closest-hit
/// rays fall below it; it ranks trees, it does not predict a count.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct TreeStats {
    /// Wide nodes.
    pub nodes: usize,
    /// Leaves.
    pub leaves: usize,
    /// Triangle packs (four slots each).
    pub packs: usize,
    /// Triangles (filled pack slots).
    pub triangles: usize,
    /// Expected wide-node tests (four boxes each) of a ray entering the root.
    pub node_tests: f64,
    /// Expected pack tests (four triangles each) of such a ray.
    pub pack_tests: f64,
}

impl TreeStats {
    /// The SAH cost, with a wide node's four box tests priced as one pack's
    /// four triangle tests (the leaf choice's `C_NODE` of 0.5 per binary
    /// node makes the same assumption).
    pub fn sah(&self) -> f64 {
        self.node_tests + self.pack_tests
    }
}

/// Tests made by the queries of [`super::Accel`]'s counted forms.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Visits {
    /// Wide nodes tested (four boxes each).
    pub nodes: u64,
    /// Triangle packs tested (four triangles each).
    pub packs: u64,
}

impl std::ops::AddAssign for Visits {
    fn add_assign(&mut self, o: Visits) {
        self.nodes += o.nodes;
        self.packs += o.packs;
    }
}

/// Half the surface area of child `i`'s box in `node` (0 for an unused slot).
fn child_area(node: &Node, i: usize) -> f64 {
    let e = |axis: usize| (node.b[2 * axis + 1][i] - node.b[2 * axis][i]).max(0.0) as f64;
    let (x, y, z) = (e(0), e(1), e(2));
    x * y + y * z + z * x
}

/// Half the surface area of the union of `node`'s child boxes.
fn node_area(node: &Node) -> f64 {
    let e = |axis: usize| {
        let lo = node.b[2 * axis]
            .iter()
            .copied()
            .fold(f32::INFINITY, f32::min);
        let hi = node.b[2 * axis + 1]
            .iter()
            .copied()
            .fold(f32::NEG_INFINITY, f32::max);
        (hi - lo).max(0.0) as f64
    };
    let (x, y, z) = (e(0), e(1), e(2));
    x * y + y * z + z * x
}

/// The shape and SAH cost of `w`.
pub(super) fn tree_stats(w: &Wide) -> TreeStats {
    let mut s = TreeStats {
        nodes: w.nodes.len(),
        packs: w.packs.len(),
        triangles: w.ids.iter().filter(|&&id| id != u32::MAX).count(),
        ..TreeStats::default()
    };
    if w.root & LEAF_BIT != 0 {
        s.leaves = 1;
        s.pack_tests = leaf_packs(w.root).len() as f64;
        return s;
    }
    let root_area = node_area(&w.nodes[w.root as usize]);
    if root_area <= 0.0 || !root_area.is_finite() {
        return s;
    }
    // (node, its area relative to the root's)
    let mut todo = vec![(w.root, 1.0f64)];
    while let Some((r, p)) = todo.pop() {
        let node = &w.nodes[r as usize];
        s.node_tests += p;
        for (i, &c) in node.child.iter().enumerate() {
            if c == u32::MAX {
                continue;
            }
            let pc = child_area(node, i) / root_area;
            if c & LEAF_BIT != 0 {
                s.leaves += 1;
                s.pack_tests += pc * leaf_packs(c).len() as f64;
            } else {
                todo.push((c, pc));
            }
        }
    }
    s
}
