//! Measures of a wide BVH's quality, for `kalos bench`: the surface area
//! heuristic's prediction of the tests a ray makes ([`TreeStats`]), and the
//! tests a ray actually made ([`Visits`]). Together they tell a tree that
//! makes rays do more work from a kernel that does the same work slowly.

use super::collapse::leaf_packs;
use super::wide::{Node, Wide, LEAF_BIT};
#[cfg(target_arch = "x86_64")]
use super::wide8::Wide8;
use super::Core;

/// The shape of a wide BVH and its surface area heuristic (SAH) cost.
///
/// The SAH prices a tree for rays that enter the root's box with uniformly
/// distributed lines (MacDonald and Booth 1990): such a ray enters a box
/// inside it with probability the ratio of their surface areas. It ignores
/// that a closest-hit ray stops early, so the measured visits of closest-hit
/// rays fall below it; it ranks trees, it does not predict a count.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct TreeStats {
    /// Children a node holds at most (4 or 8; 0 for no tree).
    pub width: usize,
    /// Wide nodes.
    pub nodes: usize,
    /// Leaves.
    pub leaves: usize,
    /// Triangle packs (`width` slots each).
    pub packs: usize,
    /// Triangles (filled pack slots).
    pub triangles: usize,
    /// Expected wide-node tests (`width` boxes each) of a ray entering the
    /// root.
    pub node_tests: f64,
    /// Expected pack tests (`width` triangles each) of such a ray.
    pub pack_tests: f64,
}

impl TreeStats {
    /// The SAH cost, with a wide node test priced as one pack test: a
    /// convention to rank trees by (the collapse itself weighs a node test
    /// at half a pack test, see `collapse.rs`).
    pub fn sah(&self) -> f64 {
        self.node_tests + self.pack_tests
    }
}

/// Tests made by the queries of [`super::Accel`]'s counted forms.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Visits {
    /// Wide nodes tested (all their boxes at once).
    pub nodes: u64,
    /// Triangle packs tested (all their triangles at once).
    pub packs: u64,
}

impl std::ops::AddAssign for Visits {
    fn add_assign(&mut self, o: Visits) {
        self.nodes += o.nodes;
        self.packs += o.packs;
    }
}

/// What [`tree_stats`] reads of a `W`-wide tree, whichever its layout.
trait WideTree<const W: usize> {
    fn root(&self) -> u32;
    /// Child boxes (`collapse.rs`'s `Collapsed` rows) and references.
    fn node(&self, r: u32) -> (&[[f32; W]; 6], &[u32; W]);
    fn node_count(&self) -> usize;
    fn pack_count(&self) -> usize;
    fn ids(&self) -> &[u32];
}

impl WideTree<4> for Wide {
    fn root(&self) -> u32 {
        self.root
    }
    fn node(&self, r: u32) -> (&[[f32; 4]; 6], &[u32; 4]) {
        let n: &Node = &self.nodes[r as usize];
        (&n.b, &n.child)
    }
    fn node_count(&self) -> usize {
        self.nodes.len()
    }
    fn pack_count(&self) -> usize {
        self.packs.len()
    }
    fn ids(&self) -> &[u32] {
        &self.ids
    }
}

#[cfg(target_arch = "x86_64")]
impl WideTree<8> for Wide8 {
    fn root(&self) -> u32 {
        self.root
    }
    fn node(&self, r: u32) -> (&[[f32; 8]; 6], &[u32; 8]) {
        let n = &self.nodes[r as usize];
        (&n.b, &n.child)
    }
    fn node_count(&self) -> usize {
        self.nodes.len()
    }
    fn pack_count(&self) -> usize {
        self.packs.len()
    }
    fn ids(&self) -> &[u32] {
        &self.ids
    }
}

/// Half the surface area of child `i`'s box in `b` (0 for an unused slot).
fn child_area<const W: usize>(b: &[[f32; W]; 6], i: usize) -> f64 {
    let e = |axis: usize| (b[2 * axis + 1][i] - b[2 * axis][i]).max(0.0) as f64;
    let (x, y, z) = (e(0), e(1), e(2));
    x * y + y * z + z * x
}

/// Half the surface area of the union of the child boxes `b`.
fn node_area<const W: usize>(b: &[[f32; W]; 6]) -> f64 {
    let e = |axis: usize| {
        let lo = b[2 * axis].iter().copied().fold(f32::INFINITY, f32::min);
        let hi = b[2 * axis + 1]
            .iter()
            .copied()
            .fold(f32::NEG_INFINITY, f32::max);
        (hi - lo).max(0.0) as f64
    };
    let (x, y, z) = (e(0), e(1), e(2));
    x * y + y * z + z * x
}

/// The shape and SAH cost of the tree `core`.
pub(super) fn core_stats(core: &Core) -> TreeStats {
    match core {
        Core::Bvh4(w) => tree_stats::<4>(w),
        #[cfg(target_arch = "x86_64")]
        Core::Bvh8(w) => tree_stats::<8>(w),
    }
}

/// The shape and SAH cost of `w`.
fn tree_stats<const W: usize>(w: &impl WideTree<W>) -> TreeStats {
    let mut s = TreeStats {
        width: W,
        nodes: w.node_count(),
        packs: w.pack_count(),
        triangles: w.ids().iter().filter(|&&id| id != u32::MAX).count(),
        ..TreeStats::default()
    };
    let root = w.root();
    if root & LEAF_BIT != 0 {
        s.leaves = 1;
        s.pack_tests = leaf_packs(root).len() as f64;
        return s;
    }
    let root_area = node_area(w.node(root).0);
    if root_area <= 0.0 || !root_area.is_finite() {
        return s;
    }
    // (node, its area relative to the root's)
    let mut todo = vec![(root, 1.0f64)];
    while let Some((r, p)) = todo.pop() {
        let (b, child) = w.node(r);
        s.node_tests += p;
        for (i, &c) in child.iter().enumerate() {
            if c == u32::MAX {
                continue;
            }
            let pc = child_area(b, i) / root_area;
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
