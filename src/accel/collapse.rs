//! The collapse of obvhs's binary BVH into a `W`-wide one, shared by the
//! 4-wide layout (`wide.rs`) and the 8-wide one (`wide8.rs`), which differ
//! only in width, alignment and leaf costs.
//!
//! Two rules ([`CollapseRule`]). The greedy one follows Wald et al., "Getting rid of
//! packets" (2008): a wide node takes the two children of a binary node,
//! then keeps opening the largest (by surface area, the likeliest to be
//! entered) of its children until it has `W`, and small subtrees become
//! leaves where the surface area heuristic says so ([`leaf_choice`]). The
//! optimal one chooses the wide nodes and leaves together, to minimise the
//! wide tree's SAH cost with the costs of its kernel ([`optimal_plan`]).

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

/// How the binary tree becomes a wide one.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum CollapseRule {
    /// Wald et al.'s greedy rule (2008): open the largest child until a
    /// node has its width's children, with leaves chosen by the SAH over
    /// binary nodes.
    Greedy,
    /// The choice of wide nodes and leaves that minimises the SAH cost of
    /// the wide tree, by dynamic programming over the binary one (Ylitie
    /// et al. 2017, §3).
    Sah,
}

/// The collapse's rule and costs.
#[derive(Clone, Copy, Debug)]
pub(super) struct Collapse {
    /// The rule.
    pub rule: CollapseRule,
    /// The cost per unit area of a node relative to one pack test: under
    /// [`CollapseRule::Greedy`] of a binary node (a wide node holds `W − 1` of them),
    /// under [`CollapseRule::Sah`] of one `W`-wide node test.
    pub c_node: f32,
    /// The most triangles in a leaf, at most `W * MAX_LEAF_PACKS`.
    pub leaf_max: usize,
}

impl Collapse {
    /// The collapse `rule` to width `width` (4 or 8) with the costs of that
    /// width's kernel, unless `c_node` or `leaf_max` say otherwise.
    pub fn new(
        rule: CollapseRule,
        width: usize,
        c_node: Option<f32>,
        leaf_max: Option<usize>,
    ) -> Self {
        // Greedy: a binary node's share of a 4-wide node's test costs about
        // half a pack of four triangles, an 8-wide node's (seven binary
        // nodes' worth of boxes, one test cheaper than a pack's) a quarter
        // of a pack of eight. Sah: one wide node test against one pack test
        // of the same width
        let (c, leaves) = match (rule, width) {
            (CollapseRule::Greedy, 8) => (0.25, 8),
            (CollapseRule::Greedy, _) => (0.5, 4),
            (CollapseRule::Sah, 8) => (SAH_C_NODE8, 8),
            (CollapseRule::Sah, _) => (SAH_C_NODE4, 4),
        };
        Collapse {
            rule,
            c_node: c_node.unwrap_or(c),
            leaf_max: leaf_max.unwrap_or(leaves),
        }
    }
}

/// [`CollapseRule::Sah`]'s cost of an 8-wide node test relative to a test
/// of a pack of eight triangles. A pack test costs more than the box test
/// (a division, and the leaf's bookkeeping): trees that trade node tests
/// for pack tests replay slower, and below this value the visits per ray
/// hardly change (docs/notebook/ray-core.md, "The 8-wide tree").
const SAH_C_NODE8: f32 = 0.5;
/// The same for four boxes against four triangles.
const SAH_C_NODE4: f32 = 0.5;

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

/// Which binary nodes become leaves, and which become the children of a
/// wide node: the rule's answer, read by [`collapse`].
enum Plan {
    Greedy(Vec<bool>),
    Sah(OptimalPlan),
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
    let plan = match options.rule {
        CollapseRule::Greedy => Plan::Greedy(leaf_choice::<W>(bvh2, options)),
        CollapseRule::Sah => Plan::Sah(optimal_plan::<W>(bvh2, options)),
    };
    let mut out = Collapsed {
        boxes: Vec::with_capacity(bvh2.nodes.len() / (W - 1) + 1),
        child: Vec::with_capacity(bvh2.nodes.len() / (W - 1) + 1),
        packs: Vec::with_capacity(tris.len() / (3 * W / 4) + 1),
        ids: Vec::new(),
        root: 0,
    };
    let mut scratch = Vec::new();
    let mut kids = Vec::with_capacity(W);
    let is_inner = |k: u32| {
        !bvh2.nodes[k as usize].is_leaf()
            && match &plan {
                Plan::Greedy(leaves) => !leaves[k as usize],
                Plan::Sah(p) => !p.is_leaf(k),
            }
    };
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
            kids.clear();
            match &plan {
                Plan::Greedy(_) => {
                    // Open the largest child until there are W
                    let first = bvh2.nodes[n as usize].first_index;
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
                }
                Plan::Sah(p) => p.children::<W>(bvh2, n, &mut kids),
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
    let width = W as f32;
    for &n in preorder(bvh2).iter().rev() {
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

/// [`CollapseRule::Sah`]'s decisions: per binary node, one byte for each number of
/// wide-node slots `i` = 1..=`W` it may fill (Ylitie et al. 2017, "Efficient
/// incoherent ray traversal on GPUs through compressed wide BVHs", §3).
/// Slot 1's byte says whether the node is a leaf ([`PLAN_LEAF`]); the
/// others, whether the node costs no more in `i − 1` slots
/// ([`PLAN_FEWER`]), and in their low bits how many of the `i` slots go to
/// the left child in the best way to spread its two subtrees over them.
struct OptimalPlan {
    width: usize,
    decisions: Vec<u8>,
}

const PLAN_LEAF: u8 = 0x80;
const PLAN_FEWER: u8 = 0x40;
const PLAN_LEFT: u8 = 0x3f;

impl OptimalPlan {
    fn is_leaf(&self, n: u32) -> bool {
        self.decisions[n as usize * self.width] & PLAN_LEAF != 0
    }

    /// The children of the wide node made of binary node `n`, in tree
    /// order (left subtree first), into `kids`.
    fn children<const W: usize>(&self, bvh2: &Bvh2, n: u32, kids: &mut Vec<u32>) {
        let first = bvh2.nodes[n as usize].first_index;
        let left = (self.decisions[n as usize * W + W - 1] & PLAN_LEFT) as usize;
        self.gather::<W>(bvh2, first, left, kids);
        self.gather::<W>(bvh2, first + 1, W - left, kids);
    }

    /// The subtree of `n` spread over at most `i` slots, as chosen.
    fn gather<const W: usize>(&self, bvh2: &Bvh2, n: u32, mut i: usize, kids: &mut Vec<u32>) {
        loop {
            if i == 1 {
                kids.push(n);
                return;
            }
            let d = self.decisions[n as usize * W + i - 1];
            if d & PLAN_FEWER != 0 {
                i -= 1;
                continue;
            }
            let left = (d & PLAN_LEFT) as usize;
            let first = bvh2.nodes[n as usize].first_index;
            self.gather::<W>(bvh2, first, left, kids);
            self.gather::<W>(bvh2, first + 1, i - left, kids);
            return;
        }
    }
}

/// The collapse that minimises the SAH cost of the `W`-wide tree, by
/// dynamic programming over the binary tree, children before parents
/// (Ylitie et al. 2017, §3). `C(n, i)`, the least cost of the subtree of
/// `n` spread over at most `i` slots of a wide node, is:
///
/// - for `i = 1`, the cheaper of a leaf (its area times its packs, where it
///   holds at most `leaf_max` triangles) and a wide node (`c_node` times its
///   area, plus its subtrees spread over `W` slots);
/// - for `i > 1`, the cheaper of `C(n, i − 1)` and the best split of the
///   `i` slots between the two children, `min over k of C(l, k) + C(r, i − k)`.
///
/// Unlike the greedy rule, this may leave a large child closed to open two
/// small ones whose boxes are rays' likelier targets, and it sizes leaves
/// by whole packs of `W` triangles.
fn optimal_plan<const W: usize>(bvh2: &Bvh2, options: &Collapse) -> OptimalPlan {
    const { assert!(W <= PLAN_LEFT as usize) };
    let leaf_max = options.leaf_max.clamp(1, W * MAX_LEAF_PACKS);
    let mut decisions = vec![0u8; bvh2.nodes.len() * W];
    // (C(n, 1..=W), triangles under n) of the subtrees done; walking the
    // preorder backwards, each node finds its children's on top
    let mut done: Vec<([f32; W], u32)> = Vec::new();
    let width = W as f32;
    for &n in preorder(bvh2).iter().rev() {
        let node = &bvh2.nodes[n as usize];
        let d = &mut decisions[n as usize * W..][..W];
        let area = node.aabb().half_area();
        if node.is_leaf() {
            let count = node.prim_count;
            d[0] = PLAN_LEAF;
            d[1..].fill(PLAN_FEWER);
            done.push(([area * (count as f32 / width).ceil(); W], count));
            continue;
        }
        let (Some((right, rn)), Some((left, ln))) = (done.pop(), done.pop()) else {
            unreachable!("a binary node's two subtrees come before it");
        };
        let count = ln + rn;
        // The best split of i slots between the children, for i = 2..=m: a
        // subtree fills at most as many slots as it has triangles, so more
        // than m cost the same as m (and the first best k of m is the first
        // best of any more)
        let m = (count as usize).min(W);
        let mut split = [f32::INFINITY; W];
        let mut split_left = [0u8; W];
        for i in 2..=m {
            for k in 1..i {
                let c = left[k - 1] + right[i - k - 1];
                // The first k is taken whatever its cost, so that a split
                // exists even where every cost is infinite or NaN (boxes
                // of extreme coordinates overflow their areas)
                if split_left[i - 1] == 0 || c < split[i - 1] {
                    split[i - 1] = c;
                    split_left[i - 1] = k as u8;
                }
            }
        }
        let inner = options.c_node * area + split[m - 1];
        let leaf = if count as usize <= leaf_max {
            area * (count as f32 / width).ceil()
        } else {
            f32::INFINITY
        };
        let mut cost = [0f32; W];
        // Tested on the count too: with an infinite area an oversized
        // leaf would tie with the inner node
        if count as usize <= leaf_max && leaf <= inner {
            cost[0] = leaf;
            d[0] = PLAN_LEAF;
        } else {
            cost[0] = inner;
        }
        for i in 2..=W {
            if i <= m && split[i - 1] < cost[i - 2] {
                cost[i - 1] = split[i - 1];
                d[i - 1] = split_left[i - 1];
            } else {
                cost[i - 1] = cost[i - 2];
                d[i - 1] = PLAN_FEWER | split_left[i.min(m) - 1];
            }
        }
        done.push((cost, count));
    }
    OptimalPlan {
        width: W,
        decisions,
    }
}

/// The nodes of `bvh2` in preorder, right subtree first. Walked backwards
/// it visits children before parents, each subtree's nodes together with
/// its root last, the left subtree before the right.
fn preorder(bvh2: &Bvh2) -> Vec<u32> {
    let mut order = Vec::with_capacity(bvh2.nodes.len());
    let mut todo = vec![0u32];
    while let Some(n) = todo.pop() {
        order.push(n);
        let node = &bvh2.nodes[n as usize];
        if !node.is_leaf() {
            todo.extend([node.first_index, node.first_index + 1]);
        }
    }
    order
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
