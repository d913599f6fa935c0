//! A light tree: emitting triangles chosen in proportion to an importance
//! that depends on the shading point (pbrt-v4's `BVHLightSampler`, after
//! Conty Estevez and Kulla's "Importance sampling of many lights with
//! adaptive tree splitting", 2018).
//!
//! Each node bounds the lights below it by a box, the cone of their normals
//! (axis ω, half-angle θ_o; a one-sided diffuse emitter adds θ_e = π/2 of
//! emission around each normal) and their power Φ. Seen from a point p, the
//! importance of a node is
//!
//! ```text
//! I(p, n) = Φ · cos θ' / d² · cos θ'_i
//! ```
//!
//! where d is the distance from p to the box's centre (at least the box's
//! half-diagonal), θ' the smallest angle that a direction from the box
//! toward p can make with a normal of the cone (θ_w − θ_o − θ_b, clamped
//! at 0, with θ_w the angle between ω and the direction from the centre to
//! p and θ_b the half-angle of the cone that bounds the box as seen from
//! p), and θ'_i the same bound on the angle to the surface normal n at p
//! (|cos|, so that transmission is not cut off; n = 0 leaves the factor
//! out). I is zero only when θ' ≥ π/2, where no point of any light below
//! faces p: such lights send nothing there, so the estimate stays unbiased.
//!
//! Sampling walks down from the root, choosing a child in proportion to
//! its importance and rescaling u; the probability of one triangle is the
//! product of the choices on its path, which [`LightTree::pmf`] finds again
//! from the triangle's bit trail with the same arithmetic, so that the two
//! agree bit for bit.

use std::f32::consts::PI;

use glam::Vec3;

mod group;

use group::Group;

/// The bounds of a set of emitting triangles.
#[derive(Clone, Copy, Debug)]
struct Bounds {
    lo: Vec3,
    hi: Vec3,
    /// Centre of the box.
    centre: Vec3,
    /// Radius r of the box's bounding sphere (half its diagonal), and r².
    r: f32,
    r2: f32,
    /// Axis ω of the normal cone.
    axis: Vec3,
    /// cos θ_o of the normal cone.
    cos_o: f32,
    /// sin θ_o.
    sin_o: f32,
    /// Power Φ (luminance-weighted watts).
    phi: f32,
}

impl Bounds {
    /// The bounds of one triangle with corners `c`, unit normal `n` and power `phi`.
    fn triangle(c: [Vec3; 3], n: Vec3, phi: f32) -> Self {
        Bounds::new(
            c[0].min(c[1]).min(c[2]),
            c[0].max(c[1]).max(c[2]),
            n,
            1.0,
            phi,
        )
    }

    /// The bounds of box `lo`..`hi`, cone (`axis`, `cos_o`) and power `phi`.
    fn new(lo: Vec3, hi: Vec3, axis: Vec3, cos_o: f32, phi: f32) -> Self {
        let r2 = (hi - lo).length_squared() * 0.25;
        Bounds {
            lo,
            hi,
            centre: (lo + hi) * 0.5,
            r: r2.sqrt(),
            r2,
            axis,
            cos_o,
            sin_o: (1.0 - cos_o * cos_o).max(0.0).sqrt(),
            phi,
        }
    }

    /// The bounds of both sets: the boxes' union, the smallest cone around
    /// both cones, the powers' sum.
    fn union(&self, o: &Bounds) -> Bounds {
        let (axis, cos_o) = cone_union(self.axis, self.cos_o, o.axis, o.cos_o);
        Bounds::new(
            self.lo.min(o.lo),
            self.hi.max(o.hi),
            axis,
            cos_o,
            self.phi + o.phi,
        )
    }

    /// The importance I(p, n) of the module documentation. The walk
    /// evaluates it two children at a time, through [`Group::importance`],
    /// which the tests hold to this definition bit for bit.
    #[cfg_attr(not(test), allow(dead_code))]
    fn importance(&self, p: Vec3, n: Vec3) -> f32 {
        let to_p = p - self.centre;
        let dist2 = to_p.length_squared();
        // Inside the bounding sphere every direction is possible: no angle bound
        if dist2 <= self.r2 {
            return self.phi / self.r2.max(f32::MIN_POSITIVE);
        }
        let inv_d = dist2.sqrt().recip();
        let wi = to_p * inv_d;
        // θ_b: half-angle of the cone from p that holds the bounding sphere
        let sin_b = self.r * inv_d;
        let cos_b = (1.0 - sin_b * sin_b).max(0.0).sqrt();
        // θ' = max(0, θ_w − θ_o − θ_b)
        let cos_w = self.axis.dot(wi).clamp(-1.0, 1.0);
        let sin_w = (1.0 - cos_w * cos_w).max(0.0).sqrt();
        let (cos_x, sin_x) = angle_minus(cos_w, sin_w, self.cos_o, self.sin_o);
        let (cos_t, _) = angle_minus(cos_x, sin_x, cos_b, sin_b);
        // One-sided emitters (θ_e = π/2): nothing reaches p when θ' ≥ π/2
        if cos_t <= 0.0 {
            return 0.0;
        }
        let mut imp = self.phi * cos_t * (inv_d * inv_d);
        if n != Vec3::ZERO {
            let cos_i = n.dot(wi).abs().min(1.0);
            let sin_i = (1.0 - cos_i * cos_i).max(0.0).sqrt();
            let (cos_ti, _) = angle_minus(cos_i, sin_i, cos_b, sin_b);
            imp *= cos_ti.max(0.0);
        }
        imp
    }
}

/// cos and sin of max(0, a − b) for angles a, b in [0, π] given by their
/// cosines and sines.
#[inline(always)]
fn angle_minus(cos_a: f32, sin_a: f32, cos_b: f32, sin_b: f32) -> (f32, f32) {
    if cos_a >= cos_b {
        (1.0, 0.0)
    } else {
        (cos_a * cos_b + sin_a * sin_b, sin_a * cos_b - cos_a * sin_b)
    }
}

/// The smallest cone (axis, cos half-angle) holding the cones (a, cos_a)
/// and (b, cos_b).
fn cone_union(a: Vec3, cos_a: f32, b: Vec3, cos_b: f32) -> (Vec3, f32) {
    let (th_a, th_b) = (cos_a.clamp(-1.0, 1.0).acos(), cos_b.clamp(-1.0, 1.0).acos());
    let th_d = a.dot(b).clamp(-1.0, 1.0).acos();
    // One holds the other
    if (th_d + th_b).min(PI) <= th_a {
        return (a, cos_a);
    }
    if (th_d + th_a).min(PI) <= th_b {
        return (b, cos_b);
    }
    let th_o = (th_a + th_d + th_b) * 0.5;
    if th_o >= PI {
        return (a, -1.0);
    }
    // Turn a toward b by θ_o − θ_a, about a × b
    let rot = th_o - th_a;
    let w = a.cross(b);
    if w.length_squared() < 1e-12 {
        return (a, -1.0);
    }
    let axis = glam::Quat::from_axis_angle(w.normalize(), rot) * a;
    (axis.normalize(), th_o.cos())
}

/// A node: its bounds, and either its second child (the first follows it)
/// or, for a leaf, the light it holds.
#[derive(Clone, Copy, Debug)]
struct Node {
    b: Bounds,
    /// Second child's index for an interior node, the light's for a leaf.
    index: u32,
    leaf: bool,
    /// For an interior node whose children have the same box and cone (the
    /// two triangles of a quad), the first child's probability Φ_a/(Φ_a +
    /// Φ_b), which their importances' ratio is wherever p is; negative
    /// otherwise.
    share: f32,
    /// For an interior node whose share is negative, its children's and
    /// grandchildren's bounds by field in [`LightTree::groups`].
    group: u32,
}

/// A binary tree over emitting triangles, for choosing one in proportion to
/// its importance at a shading point.
#[derive(Clone, Debug, Default)]
pub(super) struct LightTree {
    nodes: Vec<Node>,
    /// Per light: the branches from the root to its leaf (bit k set: the
    /// second child at depth k) and the leaf's depth.
    trail: Vec<(u64, u32)>,
    /// The children's and grandchildren's bounds of the interior nodes
    /// without a fixed share, for evaluating their importances at once.
    groups: Vec<Group>,
}

/// Deepest leaf the bit trail can hold.
const MAX_DEPTH: u32 = 64;

/// Buckets per axis for the split cost.
const BUCKETS: usize = 12;

impl LightTree {
    /// Builds the tree over lights `i` = 0..n, light i a triangle with
    /// corners `corners[i]`, unit normal `normals[i]` and power `phi[i]`.
    pub(super) fn new(corners: &[[Vec3; 3]], normals: &[Vec3], phi: &[f32]) -> Self {
        let leaves: Vec<Bounds> = (0..phi.len())
            .map(|i| Bounds::triangle(corners[i], normals[i], phi[i]))
            .collect();
        let mut tree = LightTree {
            nodes: Vec::with_capacity(2 * leaves.len()),
            trail: vec![(0, 0); leaves.len()],
            groups: Vec::new(),
        };
        if !leaves.is_empty() {
            let mut ids: Vec<u32> = (0..leaves.len() as u32).collect();
            tree.build(&leaves, &mut ids, 0, 0);
        }
        for i in 0..tree.nodes.len() {
            let node = tree.nodes[i];
            if node.leaf || node.share >= 0.0 {
                continue;
            }
            // a child's children, when its walk reads their importances
            let below = |c: usize| {
                let child = &tree.nodes[c];
                (!child.leaf && child.share < 0.0)
                    .then(|| [&tree.nodes[c + 1].b, &tree.nodes[child.index as usize].b])
            };
            let second = node.index as usize;
            let group = Group::new(
                &tree.nodes[i + 1].b,
                &tree.nodes[second].b,
                below(i + 1),
                below(second),
            );
            tree.nodes[i].group = tree.groups.len() as u32;
            tree.groups.push(group);
        }
        tree
    }

    /// Appends the subtree over `ids` (reached by bit trail `bits` at
    /// `depth`) and returns its bounds.
    fn build(&mut self, leaves: &[Bounds], ids: &mut [u32], bits: u64, depth: u32) -> Bounds {
        let at = self.nodes.len();
        if ids.len() == 1 {
            let b = leaves[ids[0] as usize];
            self.nodes.push(Node {
                b,
                index: ids[0],
                leaf: true,
                share: -1.0,
                group: 0,
            });
            self.trail[ids[0] as usize] = (bits, depth);
            return b;
        }
        // A split by cost may leave n − 1 lights on one side; halving from
        // there must still fit the trail, else halve now.
        let halving_depth = (ids.len() as u64).next_power_of_two().trailing_zeros();
        let mid = if depth + 1 + halving_depth > MAX_DEPTH {
            ids.len() / 2
        } else {
            split(leaves, ids)
        };
        self.nodes.push(Node {
            b: leaves[ids[0] as usize],
            index: 0,
            leaf: false,
            share: -1.0,
            group: 0,
        });
        let (left, right) = ids.split_at_mut(mid);
        let bl = self.build(leaves, left, bits, depth + 1);
        let second = self.nodes.len() as u32;
        let br = self.build(leaves, right, bits | (1 << depth), depth + 1);
        let b = bl.union(&br);
        let same = bl.lo == br.lo && bl.hi == br.hi && bl.axis == br.axis && bl.cos_o == br.cos_o;
        let s = bl.phi + br.phi;
        self.nodes[at] = Node {
            b,
            index: second,
            leaf: false,
            share: if same && s > 0.0 { bl.phi / s } else { -1.0 },
            group: 0,
        };
        b
    }

    /// Chooses a light for `u` in [0, 1) as seen from `p` with surface
    /// normal `n` (zero for none): the light and its probability; None when
    /// no light can reach p. The root is not tested: a tree of one light
    /// gives it with probability 1 (where it cannot reach p, its sample
    /// faces away and is refused), and below the root the children's
    /// importances decide. Not inlined: the walk is long, and the caller's
    /// loop (the path tracer's) keeps its registers.
    #[inline(never)]
    pub(super) fn sample(&self, p: Vec3, n: Vec3, mut u: f32) -> Option<(u32, f32)> {
        if self.nodes.is_empty() {
            return None;
        }
        let mut i = 0usize;
        let mut pmf = 1.0f32;
        let mut walk = Walk::default();
        loop {
            let node = &self.nodes[i];
            if node.leaf {
                return Some((node.index, pmf));
            }
            let p_a = walk.share(self, node, p, n)?;
            if u < p_a {
                u = (u / p_a).min(ONE_BELOW);
                pmf *= p_a;
                walk.down(false);
                i += 1;
            } else {
                u = ((u - p_a) / (1.0 - p_a)).clamp(0.0, ONE_BELOW);
                pmf *= 1.0 - p_a;
                walk.down(true);
                i = node.index as usize;
            }
        }
    }

    /// True when no choice depends on the shading point: every interior
    /// node has a fixed share (one quad, or none), so that the tree gives
    /// each light its power share.
    pub(super) fn is_static(&self) -> bool {
        self.nodes.iter().all(|n| n.leaf || n.share >= 0.0)
    }

    /// Probability that [`LightTree::sample`] chooses light `light` from
    /// `p` with normal `n`.
    #[inline(never)]
    pub(super) fn pmf(&self, p: Vec3, n: Vec3, light: u32) -> f32 {
        let Some(&(bits, depth)) = self.trail.get(light as usize) else {
            return 0.0;
        };
        let mut i = 0usize;
        let mut pmf = 1.0f32;
        let mut walk = Walk::default();
        for k in 0..depth {
            let node = &self.nodes[i];
            let Some(p_a) = walk.share(self, node, p, n) else {
                return 0.0;
            };
            let second = bits & (1 << k) != 0;
            walk.down(second);
            if second {
                pmf *= 1.0 - p_a;
                i = node.index as usize;
            } else {
                pmf *= p_a;
                i += 1;
            }
        }
        pmf
    }
}

/// A walk down a [`LightTree`] from one shading point: the importances of
/// the last group evaluated, whose lanes 2–5 hold the next level's.
#[derive(Default)]
struct Walk {
    imp: [f32; 8],
    /// Where in `imp` the importances of the next node's children are:
    /// `Some(0)` right after a node's own group was evaluated (its
    /// children in lanes 0–1, consumed; its grandchildren in 2–5), which
    /// [`Walk::down`] turns into `Some(2)` or `Some(4)` for the child taken;
    /// None when the next node must evaluate its own group.
    next: Option<usize>,
}

impl Walk {
    /// The probability of the first child of interior node `node`, from p
    /// with normal n; None when neither child can reach p.
    #[inline(always)]
    fn share(&mut self, tree: &LightTree, node: &Node, p: Vec3, n: Vec3) -> Option<f32> {
        if node.share >= 0.0 {
            self.next = None;
            return Some(node.share);
        }
        if let Some(at) = self.next.take() {
            return first_share(self.imp[at], self.imp[at + 1]);
        }
        self.imp = tree.groups[node.group as usize].importance(p, n);
        self.next = Some(0);
        first_share(self.imp[0], self.imp[1])
    }

    /// Steps to the first child or the `second`: its children's
    /// importances are at hand if this node's group was just evaluated.
    #[inline(always)]
    fn down(&mut self, second: bool) {
        self.next = match self.next {
            Some(0) => Some(if second { 4 } else { 2 }),
            _ => None,
        };
    }
}

/// The largest f32 below 1.
const ONE_BELOW: f32 = 1.0 - f32::EPSILON / 2.0;

/// The probability of the first of two children, from their importances
/// `ia` and `ib`; None when neither can reach p.
#[inline(always)]
fn first_share(ia: f32, ib: f32) -> Option<f32> {
    let s = ia + ib;
    // NaN fails both tests
    if !(s.is_finite() && s > 0.0) {
        return None;
    }
    Some(ia / s)
}

/// Orders `ids` so that the split at the returned index (in 1..len) has the
/// least cost Φ · M_Ω · area summed over both sides, among bucket
/// boundaries of the centroids on each axis (the axis's cost scaled by how
/// thin the box is along it, so that long boxes are cut across).
fn split(leaves: &[Bounds], ids: &mut [u32]) -> usize {
    let centre = |i: u32| {
        let b = &leaves[i as usize];
        (b.lo + b.hi) * 0.5
    };
    let (mut clo, mut chi) = (Vec3::splat(f32::INFINITY), Vec3::splat(f32::NEG_INFINITY));
    let (mut lo, mut hi) = (clo, chi);
    for &i in ids.iter() {
        let c = centre(i);
        clo = clo.min(c);
        chi = chi.max(c);
        lo = lo.min(leaves[i as usize].lo);
        hi = hi.max(leaves[i as usize].hi);
    }
    let diag = hi - lo;
    let mut best: Option<(f32, usize, usize)> = None;
    for axis in 0..3 {
        let (a, b) = (clo[axis], chi[axis]);
        if b <= a || !(b - a).is_finite() {
            continue;
        }
        let bucket = |i: u32| {
            let t = (centre(i)[axis] - a) / (b - a);
            ((t * BUCKETS as f32) as usize).min(BUCKETS - 1)
        };
        let mut sets: [Option<Bounds>; BUCKETS] = [None; BUCKETS];
        for &i in ids.iter() {
            let k = bucket(i);
            let l = &leaves[i as usize];
            sets[k] = Some(sets[k].map_or(*l, |s| s.union(l)));
        }
        let stretch = diag.max_element() / diag[axis].max(1e-12);
        for cut in 1..BUCKETS {
            let below = sets[..cut]
                .iter()
                .flatten()
                .copied()
                .reduce(|x, y| x.union(&y));
            let above = sets[cut..]
                .iter()
                .flatten()
                .copied()
                .reduce(|x, y| x.union(&y));
            let (Some(l), Some(r)) = (below, above) else {
                continue;
            };
            let cost = stretch * (cost(&l) + cost(&r));
            if best.is_none_or(|(c, _, _)| cost < c) {
                best = Some((cost, axis, cut));
            }
        }
    }
    let Some((_, axis, cut)) = best else {
        // All centroids coincide: halve the list
        return ids.len() / 2;
    };
    let (a, b) = (clo[axis], chi[axis]);
    let below = |i: u32| {
        let t = (centre(i)[axis] - a) / (b - a);
        ((t * BUCKETS as f32) as usize).min(BUCKETS - 1) < cut
    };
    // Partition: those below the cut first
    let mut m = 0;
    for j in 0..ids.len() {
        if below(ids[j]) {
            ids.swap(j, m);
            m += 1;
        }
    }
    m.clamp(1, ids.len() - 1)
}

/// Φ · M_Ω · area of a set's bounds, M_Ω being the measure of the emitted
/// directions: the cone θ_o, widened by θ_e = π/2 with a cosine falloff,
/// M_Ω = 2π(1 − cos θ_o) + π[(cos θ_o − cos(2θ_w − θ_o))/2 + (θ_w − θ_o) sin θ_o],
/// θ_w = min(θ_o + θ_e, π).
fn cost(b: &Bounds) -> f32 {
    let th_o = b.cos_o.clamp(-1.0, 1.0).acos();
    let th_w = (th_o + PI / 2.0).min(PI);
    let sin_o = th_o.sin();
    let m_omega = 2.0 * PI * (1.0 - b.cos_o)
        + PI * ((b.cos_o - (2.0 * th_w - th_o).cos()) * 0.5 + (th_w - th_o) * sin_o);
    let d = b.hi - b.lo;
    let area = 2.0 * (d.x * d.y + d.y * d.z + d.z * d.x);
    b.phi * m_omega * area
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The union of two cones holds both; of a cone with itself is itself.
    #[test]
    fn cone_union_holds_both() {
        let (a, b) = (Vec3::Z, Vec3::X);
        let (w, c) = cone_union(a, 1.0, b, 1.0);
        assert!((c - (PI / 4.0).cos()).abs() < 1e-5, "{c}");
        assert!(w.dot(a) >= c - 1e-5 && w.dot(b) >= c - 1e-5, "{w} {c}");
        let (w, c) = cone_union(a, 0.5, a, 0.5);
        assert_eq!((w, c), (a, 0.5));
        let (_, c) = cone_union(a, 1.0, -a, 1.0);
        assert!(c <= -1.0 + 1e-6, "{c}");
    }

    /// A group's eight importances are the scalar definition's, bit for
    /// bit, in both of its forms (AVX where the CPU has it, and SSE): over
    /// random boxes, cones (including the full sphere and a single
    /// direction), powers, points (inside a bounding sphere, on a centre,
    /// far away, behind) and normals (none, random, along the direction to
    /// a light).
    #[test]
    fn group_importance_is_the_scalar_one_bit_for_bit() {
        let mut rng = crate::sampling::Pcg32::new(7, 0);
        let mut f = |lo: f32, hi: f32| lo + (hi - lo) * rng.next_f32();
        let mut positive = 0;
        for k in 0..20_000 {
            let bounds: [Bounds; 6] = std::array::from_fn(|j| {
                let lo = Vec3::new(f(-2.0, 2.0), f(-2.0, 2.0), f(-2.0, 2.0));
                let size = Vec3::new(f(0.0, 1.0), f(0.0, 1.0), f(0.0, 1.0));
                let axis =
                    Vec3::new(f(-1.0, 1.0), f(-1.0, 1.0), f(-1.0, 1.0)).normalize_or(Vec3::Z);
                let cos_o = match (k + j) % 4 {
                    0 => 1.0,
                    1 => -1.0,
                    _ => f(-1.0, 1.0),
                };
                Bounds::new(
                    lo,
                    lo + size * ((k + j) % 3) as f32,
                    axis,
                    cos_o,
                    f(0.0, 10.0),
                )
            });
            let p = match k % 5 {
                0 => bounds[k % 6].centre,
                1 => bounds[1].centre + Vec3::splat(f(-0.1, 0.1)),
                2 => Vec3::new(f(-50.0, 50.0), f(-50.0, 50.0), f(-50.0, 50.0)),
                _ => Vec3::new(f(-4.0, 4.0), f(-4.0, 4.0), f(-4.0, 4.0)),
            };
            let n = match k % 7 {
                0 => Vec3::ZERO,
                1 => (bounds[0].centre - p).normalize_or(Vec3::Z),
                _ => Vec3::new(f(-1.0, 1.0), f(-1.0, 1.0), f(-1.0, 1.0)).normalize_or(Vec3::X),
            };
            let [a, b, a1, a2, b1, b2] = &bounds;
            let group = Group::new(a, b, Some([a1, a2]), Some([b1, b2]));
            let want = [a, b, a1, a2, b1, b2, a, b].map(|x| x.importance(p, n).to_bits());
            for (form, got) in [
                ("dispatched", group.importance(p, n)),
                ("sse", group.importance_sse(p, n)),
            ] {
                assert_eq!(
                    got.map(f32::to_bits),
                    want,
                    "case {k}, {form}: at p {p}, n {n}: {got:?}"
                );
            }
            positive += want.iter().filter(|&&w| f32::from_bits(w) > 0.0).count();
        }
        // most lanes see some light, so the comparison is not of zeros alone
        assert!(positive > 80_000, "{positive} positive importances");
    }

    /// A triangle facing away from p has no importance; facing p, some.
    #[test]
    fn behind_a_one_sided_light_is_zero() {
        let b = Bounds::triangle([Vec3::ZERO, Vec3::X, Vec3::Y], Vec3::Z, 1.0);
        assert_eq!(b.importance(Vec3::new(0.2, 0.2, -1.0), Vec3::ZERO), 0.0);
        assert!(b.importance(Vec3::new(0.2, 0.2, 1.0), Vec3::ZERO) > 0.0);
        // in the plane but off the triangle: grazing, still reachable by the bound
        assert!(b.importance(Vec3::new(3.0, 3.0, 0.0), Vec3::Z) >= 0.0);
    }

    /// Thousands of lights stay cheap: sampling evaluates two importances
    /// per level, and the deepest of 4,096 triangles (random places in a
    /// room and random orientations) is within 3 log₂ N of the root. Every
    /// light is reachable from the root by its trail.
    #[test]
    fn many_lights_make_a_shallow_tree() {
        let n = 4096;
        let mut rng = crate::sampling::Pcg32::new(1, 0);
        let mut corners = Vec::new();
        let mut normals = Vec::new();
        for _ in 0..n {
            let o = Vec3::new(
                rng.next_f32() * 12.0,
                rng.next_f32() * 12.0,
                rng.next_f32() * 3.0,
            );
            let a = crate::sampling::uniform_sphere(rng.next_2d()) * 0.2;
            let b = crate::sampling::uniform_sphere(rng.next_2d()) * 0.2;
            corners.push([o, o + a, o + b]);
            normals.push(a.cross(b).normalize_or(Vec3::Z));
        }
        let tree = LightTree::new(&corners, &normals, &vec![1.0; n]);
        let deepest = tree.trail.iter().map(|t| t.1).max().unwrap_or(0);
        eprintln!("4,096 lights: deepest leaf at depth {deepest}");
        assert!(deepest <= 36, "deepest leaf at {deepest}");
        for (i, &(bits, depth)) in tree.trail.iter().enumerate() {
            let mut at = 0usize;
            for k in 0..depth {
                assert!(!tree.nodes[at].leaf);
                at = if bits & (1 << k) == 0 {
                    at + 1
                } else {
                    tree.nodes[at].index as usize
                };
            }
            assert!(tree.nodes[at].leaf && tree.nodes[at].index == i as u32);
        }
    }
}
