//! Every hit of a lightmap bake, decoded to world points and grouped by
//! surface side, each group in a kd-tree for the texels' queries
//! ([`super::estimate`]).
//!
//! A worker of a dataflow bake ([`super::dataflow`]) holds only some of a
//! group's hits: those of its tiles and a halo around them. It is told
//! every group's total ([`HitIndex::set_totals`]), so that it picks a
//! texel's side as one process does, and the estimator says how far from
//! a texel the hits it used lie ([`super::estimate::TexelEstimate::reach`]),
//! so that the worker knows when its halo held them all.

use std::collections::{BTreeMap, HashMap};

use glam::{Vec2, Vec3};
use kiddo::ImmutableKdTree;

use crate::methods::density::hitfile::HitFileError;
use crate::methods::density::hits::{from_fixed, Hit, HitSource};
use crate::methods::density::surfaces::{Kind, Surface, SurfaceId, Surfaces};
use crate::world::World;

/// Which hits a texel may use: a planar surface side, or one side of a
/// curved shape.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub(super) enum Key {
    Planar(u32, bool),
    Curved(u32, bool),
}

impl Key {
    /// The group of surface side `id`.
    fn of(surf: &Surface, id: SurfaceId) -> Key {
        match surf.kind {
            Kind::Planar => Key::Planar(id.index, id.back),
            Kind::Curved => Key::Curved(surf.shape, id.back),
        }
    }
}

/// A group's decoded hits: points, normals (curved shapes only), powers.
type Decoded = (Vec<Vec3>, Vec<Vec3>, Vec<u32>);

/// The hits of one group, in a kd-tree.
pub(super) struct Group {
    pub(super) tree: ImmutableKdTree<f32, 3>,
    pub(super) pos: Vec<Vec3>,
    /// The geometric normal at each hit (curved shapes only), on the side
    /// the hits are for.
    pub(super) normal: Vec<Vec3>,
    pub(super) rgb: Vec<u32>,
    /// The group's hits in the whole bake (`pos.len()` unless this is a
    /// worker's part of it).
    pub(super) total: u64,
}

impl Group {
    /// True when every hit of the group is held.
    pub(super) fn whole(&self) -> bool {
        self.pos.len() as u64 >= self.total
    }
}

/// Every hit of a bake (or a worker's part of them), decoded to world
/// points and grouped for the texels' queries.
pub struct HitIndex {
    keys: HashMap<Key, usize>,
    pub(super) groups: Vec<Group>,
    /// Every group's hits in the whole bake, held or not.
    totals: HashMap<Key, u64>,
    hits: u64,
}

/// Decodes hits of side `id` into `e`.
fn decode(world: &World, surf: &Surface, back: bool, hits: &[Hit], e: &mut Decoded) {
    for h in hits {
        let (u, v) = (from_fixed(h.u), from_fixed(h.v));
        match surf.kind {
            Kind::Planar => e.0.push(surf.to_world(Vec2::new(u, v) * surf.size)),
            Kind::Curved => {
                let sp = world.scene.surface_point(surf.tris[0], u, v);
                e.0.push(sp.p);
                e.1.push(if back { -sp.ng } else { sp.ng });
            }
        }
        e.2.push(h.rgb);
    }
}

impl HitIndex {
    /// Reads every hit of `source` (at most `chunk` records at a time) and
    /// builds a kd-tree per group.
    pub fn build(
        world: &World,
        surfaces: &Surfaces,
        source: &impl HitSource,
        chunk: u64,
    ) -> Result<HitIndex, HitFileError> {
        Self::build_with(world, surfaces, source, &[], chunk)
    }

    /// [`HitIndex::build`] of the hits of `source` and those of `extra`
    /// (per surface side, hits held in memory: a dataflow worker's halo).
    pub fn build_with(
        world: &World,
        surfaces: &Surfaces,
        source: &impl HitSource,
        extra: &[(SurfaceId, Vec<Hit>)],
        chunk: u64,
    ) -> Result<HitIndex, HitFileError> {
        let mut parts: BTreeMap<Key, Decoded> = Default::default();
        for run in source.runs() {
            let Some(surf) = surfaces.get(run.surface) else {
                continue;
            };
            let e = parts.entry(Key::of(surf, run.surface)).or_default();
            let mut done = 0;
            while done < run.count {
                let m = (run.count - done).min(chunk.max(1));
                let hits = source.read(run.start + done, m)?;
                decode(world, surf, run.surface.back, &hits, e);
                done += m;
            }
        }
        for (id, hits) in extra {
            let Some(surf) = surfaces.get(*id) else {
                continue;
            };
            let e = parts.entry(Key::of(surf, *id)).or_default();
            decode(world, surf, id.back, hits, e);
        }
        let mut keys = HashMap::new();
        let mut totals = HashMap::new();
        let mut groups = Vec::with_capacity(parts.len());
        let mut hits = 0;
        for (key, (pos, normal, rgb)) in parts {
            if pos.is_empty() {
                continue;
            }
            let (pos, normal, rgb) = morton_order(pos, normal, rgb);
            let pts: Vec<[f32; 3]> = pos.iter().map(|p| p.to_array()).collect();
            let tree = ImmutableKdTree::<f32, 3>::new_from_slice(&pts);
            drop(pts);
            let Ok(tree) = tree else {
                continue;
            };
            hits += pos.len() as u64;
            keys.insert(key, groups.len());
            totals.insert(key, pos.len() as u64);
            groups.push(Group {
                tree,
                total: pos.len() as u64,
                pos,
                normal,
                rgb,
            });
        }
        Ok(HitIndex {
            keys,
            groups,
            totals,
            hits,
        })
    }

    /// Tells a worker's index the hits of every surface side in the whole
    /// bake (`totals`: per side, its count; a side's sides of one curved
    /// shape add up), so that it picks each texel's side as one process
    /// does and knows which of its groups it holds whole.
    pub fn set_totals(&mut self, surfaces: &Surfaces, totals: &[(SurfaceId, u64)]) {
        let mut t: HashMap<Key, u64> = HashMap::new();
        for &(id, n) in totals {
            if let Some(surf) = surfaces.get(id) {
                *t.entry(Key::of(surf, id)).or_default() += n;
            }
        }
        for (key, &g) in &self.keys {
            let held = self.groups[g].pos.len() as u64;
            self.groups[g].total = t.get(key).copied().unwrap_or(held).max(held);
        }
        self.totals = t;
    }

    /// Hits held.
    pub fn hit_count(&self) -> u64 {
        self.hits
    }

    fn count(&self, key: Key) -> u64 {
        self.totals.get(&key).copied().unwrap_or(0)
    }

    /// The group a texel on surface `sid` reads (None: this index holds
    /// none of its hits), and whether it is the back side: the front (the
    /// triangles' winding), unless only the back side is lit (a two-sided
    /// material seen from behind): a texel holds one value, that of the
    /// side with more hits. None when neither side took a hit.
    pub(super) fn group_of(&self, surf: &Surface, sid: u32) -> Option<(Option<usize>, bool)> {
        let key = |back| Key::of(surf, SurfaceId { index: sid, back });
        let (nb, nf) = (self.count(key(true)), self.count(key(false)));
        if nb == 0 && nf == 0 {
            return None;
        }
        let back = nb > nf;
        Some((self.keys.get(&key(back)).copied(), back))
    }

    /// The group of one given side of surface `sid`: None when that side
    /// took no hit, Some(None) when this index holds none of them.
    pub(super) fn group_on(&self, surf: &Surface, sid: u32, back: bool) -> Option<Option<usize>> {
        let key = Key::of(surf, SurfaceId { index: sid, back });
        (self.count(key) > 0).then(|| self.keys.get(&key).copied())
    }
}

/// The hits of a group in Morton order of their points, so that the hits
/// a texel gathers lie together in memory (the kd-tree's items index
/// these arrays; in the order of tracing, every gathered hit was a cache
/// miss).
fn morton_order(
    pos: Vec<Vec3>,
    normal: Vec<Vec3>,
    rgb: Vec<u32>,
) -> (Vec<Vec3>, Vec<Vec3>, Vec<u32>) {
    let (mut lo, mut hi) = (Vec3::splat(f32::INFINITY), Vec3::splat(f32::NEG_INFINITY));
    for p in &pos {
        lo = lo.min(*p);
        hi = hi.max(*p);
    }
    let scale = 1023.0 / (hi - lo).max_element().max(1e-30);
    let spread = |v: u32| {
        // 10 bits to every third of 30
        let mut x = v & 0x3ff;
        x = (x | (x << 16)) & 0x030000ff;
        x = (x | (x << 8)) & 0x0300f00f;
        x = (x | (x << 4)) & 0x030c30c3;
        (x | (x << 2)) & 0x09249249
    };
    let mut order: Vec<(u32, u32)> = pos
        .iter()
        .enumerate()
        .map(|(i, p)| {
            let q = ((*p - lo) * scale).max(Vec3::ZERO);
            let code = spread(q.x as u32) | (spread(q.y as u32) << 1) | (spread(q.z as u32) << 2);
            (code, i as u32)
        })
        .collect();
    order.sort_unstable();
    let pos2 = order.iter().map(|&(_, i)| pos[i as usize]).collect();
    let normal2 = if normal.is_empty() {
        normal
    } else {
        order.iter().map(|&(_, i)| normal[i as usize]).collect()
    };
    let rgb2 = order.iter().map(|&(_, i)| rgb[i as usize]).collect();
    (pos2, normal2, rgb2)
}
