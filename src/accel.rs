//! The ray core: a BVH over every triangle of the scene, with closest-hit and
//! occlusion queries. This is the only module that knows how rays meet
//! geometry. obvhs (pinned to an exact version in Cargo.toml) builds a binary
//! BVH in parallel by PLOC with rayon; `accel/wide.rs` collapses it into a
//! 4-wide BVH whose nodes and triangles the kernels of `accel/traverse.rs`
//! test four at a time (SSE2 on x86_64, `accel/simd.rs`).
//!
//! PLOC clusters triangles by their centroids' Morton order, and where
//! large triangles (walls, floors) sit among many small ones it makes
//! trees that rays walk twice as deep as a top-down SAH tree. So the
//! default build builds the tree top-down instead (`accel/sah.rs`, then
//! obvhs's reinsertion) where that one's surface area heuristic cost is
//! clearly lower, as judged on a sample of the triangles ([`Builder::Best`];
//! `accel/quality.rs` prices the trees).
//!
//! PLOC merges only pairs of clusters that are each other's nearest
//! neighbour, and some inputs have almost no such pairs: many copies of one
//! triangle (every candidate ties), or a fan of thin triangles around one
//! vertex (every box holds the shared vertex). Each of its passes then merges
//! a handful of clusters while searching all of them, and the build takes
//! time quadratic in the triangle count. [`Accel::build_reporting`] tries
//! PLOC on a sample of the triangles first and, when the sample shows that
//! behaviour, builds the tree top-down instead (`accel/sah.rs`), which takes
//! O(n log n) time whatever the input.

mod quality;
mod sah;
mod simd;
mod traverse;
mod wide;

use glam::Vec3;
use obvhs::bvh2::reinsertion::ReinsertionOptimizer;
use obvhs::bvh2::Bvh2;
use obvhs::ploc::PlocBuilder;
use obvhs::triangle::Triangle;
use obvhs::BvhBuildParams;

use crate::geometry::Ray;
use crate::scene::Scene;
use wide::Wide;

pub use quality::{TreeStats, Visits};

/// A closest hit.
#[derive(Clone, Copy, Debug)]
pub struct Hit {
    /// Distance along the ray (in units of the ray direction's length).
    pub t: f32,
    /// Triangle index in the scene.
    pub tri: u32,
    /// Barycentric weight of the triangle's second vertex.
    pub b1: f32,
    /// Barycentric weight of the triangle's third vertex.
    pub b2: f32,
}

/// The acceleration structure.
pub struct Accel {
    /// `None` for a scene without triangles.
    wide: Option<Wide>,
}

/// The builder of the binary BVH that is collapsed into the wide one.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Builder {
    /// PLOC with obvhs's `fast_build` search and reinsertion settings.
    PlocFast,
    /// PLOC with obvhs's `medium_build` settings.
    PlocMedium,
    /// PLOC with obvhs's `slow_build` settings, without its spatial
    /// pre-splits (the wide BVH references whole triangles).
    PlocSlow,
    /// PLOC with obvhs's `very_slow_build` settings, without pre-splits.
    PlocVerySlow,
    /// The top-down binned SAH build of `accel/sah.rs`.
    Sah,
    /// [`Builder::Sah`], then obvhs's reinsertion with `medium_build`'s
    /// batch ratio.
    SahReinsert,
    /// Both [`Builder::PlocMedium`] and [`Builder::SahReinsert`] over every
    /// triangle, keeping the top-down tree where its SAH cost is clearly
    /// lower.
    Both,
    /// [`Builder::Both`]'s choice made on an evenly strided sample of
    /// [`CHOICE_SAMPLE`] triangles, then only the chosen tree built over
    /// them all (the default). A strided sample keeps the mix of large and
    /// small triangles that decides between the two.
    Best,
}

/// Triangles of the sample on which [`Builder::Best`] chooses; a scene
/// with no more is built both ways in full.
const CHOICE_SAMPLE: usize = 32768;

/// [`Builder::Both`] keeps the top-down tree when its SAH cost is below
/// this fraction of PLOC's. The SAH prices rays that cross the whole scene
/// and never stop early, so a few per cent either way say nothing about
/// the rays a render traces; a large scene where PLOC clusters its big
/// triangles badly differs by far more (BENCHMARKS.md, "BVH quality on
/// large scenes").
const SWITCH_MARGIN: f64 = 0.95;

impl Builder {
    /// Every builder, in the order of their names.
    pub const ALL: [Builder; 8] = [
        Builder::PlocFast,
        Builder::PlocMedium,
        Builder::PlocSlow,
        Builder::PlocVerySlow,
        Builder::Sah,
        Builder::SahReinsert,
        Builder::Both,
        Builder::Best,
    ];

    /// The name `kalos bench --bvh` takes.
    pub fn name(self) -> &'static str {
        match self {
            Builder::PlocFast => "ploc-fast",
            Builder::PlocMedium => "ploc-medium",
            Builder::PlocSlow => "ploc-slow",
            Builder::PlocVerySlow => "ploc-very-slow",
            Builder::Sah => "sah",
            Builder::SahReinsert => "sah-reinsert",
            Builder::Both => "both",
            Builder::Best => "best",
        }
    }

    /// obvhs's parameters of a PLOC builder, None for the top-down one.
    fn ploc_params(self) -> Option<BvhBuildParams> {
        match self {
            Builder::PlocFast => Some(BvhBuildParams::fast_build()),
            Builder::PlocMedium | Builder::Both | Builder::Best => {
                Some(BvhBuildParams::medium_build())
            }
            Builder::PlocSlow => Some(BvhBuildParams::slow_build()),
            Builder::PlocVerySlow => Some(BvhBuildParams::very_slow_build()),
            Builder::Sah | Builder::SahReinsert => None,
        }
    }
}

/// How [`Accel::build_with`] builds: the binary builder, then the leaf
/// choice of the collapse to the wide BVH.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct BuildOptions {
    /// The binary BVH's builder.
    pub builder: Builder,
    /// The cost of a binary node's box tests per unit area relative to one
    /// pack of four triangle tests, in the surface area heuristic that
    /// chooses the leaves.
    pub c_node: f32,
    /// The most triangles a leaf may hold (1 to 32).
    pub leaf_max: usize,
}

impl Default for BuildOptions {
    fn default() -> Self {
        BuildOptions {
            builder: Builder::Best,
            c_node: wide::C_NODE,
            leaf_max: wide::LEAF_MAX,
        }
    }
}

impl Accel {
    /// Builds the BVH over all triangles of `scene` (in parallel).
    pub fn build(scene: &Scene) -> Self {
        Self::build_reporting(scene, &mut |_| {})
    }

    /// [`Accel::build`], telling `on_phase` which builder it runs (a line
    /// for a progress display: building a BVH over millions of triangles
    /// takes seconds).
    pub fn build_reporting(scene: &Scene, on_phase: &mut dyn FnMut(String)) -> Self {
        Self::build_with(scene, &BuildOptions::default(), on_phase)
    }

    /// [`Accel::build_reporting`] with another builder or leaf choice than
    /// the default, for `kalos bench` to compare trees on the same rays.
    pub fn build_with(
        scene: &Scene,
        options: &BuildOptions,
        on_phase: &mut dyn FnMut(String),
    ) -> Self {
        let tris: Vec<Triangle> = (0..scene.triangles.len() as u32)
            .map(|i| {
                let [a, b, c] = scene.tri_vertices(i);
                Triangle {
                    v0: a.into(),
                    v1: b.into(),
                    v2: c.into(),
                }
            })
            .collect();
        if tris.is_empty() {
            return Accel { wide: None };
        }
        let collapse = wide::Collapse {
            c_node: options.c_node,
            leaf_max: options.leaf_max,
        };
        let n = tris.len();
        let ploc = |tris: &[Triangle], params: BvhBuildParams| {
            let mut bvh2 = PlocBuilder::with_capacity(tris.len()).build(
                params.ploc_search_distance,
                tris,
                (0..tris.len() as u32).collect(),
                params.sort_precision,
                params.search_depth_threshold,
            );
            ReinsertionOptimizer::default().run(&mut bvh2, params.reinsertion_batch_ratio, None);
            Wide::from_bvh2(&bvh2, tris, &collapse)
        };
        let top_down = |tris: &[Triangle], reinsert: bool| {
            let mut bvh2: Bvh2 = sah::build(tris);
            if reinsert {
                let ratio = BvhBuildParams::medium_build().reinsertion_batch_ratio;
                ReinsertionOptimizer::default().run(&mut bvh2, ratio, None);
            }
            // The top-down tree's depth is bounded (see accel/sah.rs), so
            // its wide form always fits the traversal stack; the pack
            // indices run out only past a billion triangles, which would
            // not fit in memory
            Wide::from_bvh2(&bvh2, tris, &collapse)
                .expect("a scene of over a billion triangles exceeds the BVH's index range")
        };
        let cost = |w: &Wide| quality::tree_stats(w).sah();
        // True when the top-down tree of `tris` is clearly cheaper
        let top_down_wins = |tris: &[Triangle], params: BvhBuildParams| match ploc(tris, params) {
            Some(p) => cost(&top_down(tris, true)) < SWITCH_MARGIN * cost(&p),
            None => true,
        };
        // Both trees over every triangle, keeping the clearly cheaper
        let both = |params: BvhBuildParams| {
            let t = top_down(&tris, true);
            match ploc(&tris, params) {
                Some(p) if cost(&t) >= SWITCH_MARGIN * cost(&p) => p,
                _ => t,
            }
        };
        let safe = options
            .builder
            .ploc_params()
            .filter(|&params| ploc_is_safe(&tris, params));
        let wide = match (options.builder, safe) {
            (Builder::Both, Some(params)) => {
                on_phase(format!(
                    "building the BVH over {n} triangles, by PLOC and top-down, to keep the cheaper"
                ));
                both(params)
            }
            (Builder::Best, Some(params)) if n <= CHOICE_SAMPLE => {
                on_phase(format!(
                    "building the BVH over {n} triangles, by PLOC and top-down, to keep the cheaper"
                ));
                both(params)
            }
            (Builder::Best, Some(params)) => {
                on_phase(format!("building the BVH over {n} triangles"));
                let stride = n.div_ceil(CHOICE_SAMPLE);
                let sample: Vec<Triangle> = tris.iter().step_by(stride).copied().collect();
                if top_down_wins(&sample, params) {
                    top_down(&tris, true)
                } else {
                    ploc(&tris, params).unwrap_or_else(|| top_down(&tris, false))
                }
            }
            (_, Some(params)) => {
                on_phase(format!("building the BVH over {n} triangles"));
                ploc(&tris, params).unwrap_or_else(|| top_down(&tris, false))
            }
            (Builder::Sah | Builder::SahReinsert, None) => {
                on_phase(format!("building the BVH over {n} triangles top-down"));
                top_down(&tris, options.builder == Builder::SahReinsert)
            }
            // Reinsertion is left out here: on these inputs its search,
            // like PLOC's, finds no box to prune by
            (_, None) => {
                on_phase(format!(
                    "building the BVH over {n} triangles top-down (PLOC would take quadratic time on this input)"
                ));
                top_down(&tris, false)
            }
        };
        Accel { wide: Some(wide) }
    }

    /// The closest hit along `ray` in `[ray.tmin, ray.tmax)`.
    #[inline]
    pub fn intersect(&self, ray: &Ray) -> Option<Hit> {
        let w = self.wide.as_ref()?;
        let h = traverse::closest(w, ray.o, ray.d, ray.tmin, ray.tmax, &mut traverse::NoCount)?;
        Some(Hit {
            t: h.t,
            tri: w.ids[h.slot],
            b1: h.b1,
            b2: h.b2,
        })
    }

    /// True when something blocks the open segment from `a` to `b`. Both
    /// ends are expected to be already offset from their surfaces
    /// ([`crate::geometry::offset_point`]); the segment stops just short of `b`.
    #[inline]
    pub fn occluded(&self, a: Vec3, b: Vec3) -> bool {
        self.wide
            .as_ref()
            .is_some_and(|w| traverse::any(w, a, b - a, 0.0, 1.0 - 1e-4, &mut traverse::NoCount))
    }

    /// True when something blocks the ray within `[ray.tmin, ray.tmax)`.
    #[inline]
    pub fn occluded_ray(&self, ray: &Ray) -> bool {
        self.wide.as_ref().is_some_and(|w| {
            traverse::any(w, ray.o, ray.d, ray.tmin, ray.tmax, &mut traverse::NoCount)
        })
    }

    /// The shape of the tree and its surface area heuristic cost (for
    /// `kalos bench`).
    pub fn tree_stats(&self) -> TreeStats {
        self.wide
            .as_ref()
            .map(quality::tree_stats)
            .unwrap_or_default()
    }

    /// [`Accel::intersect`], adding the nodes and packs it tests to
    /// `visits` (for `kalos bench`; the uncounted query is the fast one).
    pub fn intersect_counted(&self, ray: &Ray, visits: &mut Visits) -> Option<Hit> {
        let w = self.wide.as_ref()?;
        let h = traverse::closest(w, ray.o, ray.d, ray.tmin, ray.tmax, visits)?;
        Some(Hit {
            t: h.t,
            tri: w.ids[h.slot],
            b1: h.b1,
            b2: h.b2,
        })
    }

    /// [`Accel::occluded_ray`], adding the nodes and packs it tests to
    /// `visits`.
    pub fn occluded_ray_counted(&self, ray: &Ray, visits: &mut Visits) -> bool {
        self.wide
            .as_ref()
            .is_some_and(|w| traverse::any(w, ray.o, ray.d, ray.tmin, ray.tmax, visits))
    }
}

/// Triangles of the sample that [`ploc_is_safe`] builds PLOC on. PLOC takes
/// at most O(k²) on k triangles (a fraction of a second for this k), and
/// when the whole input is smaller it is built directly.
const PLOC_PROBE: usize = 2048;

/// False when PLOC would take quadratic time on `tris`: PLOC on an evenly
/// strided sample of them needed as many passes as obvhs's default
/// traversal stack depth (96). A healthy input merges a fixed fraction of
/// its clusters per pass, so its passes grow as log k for k clusters; the
/// inputs of the module doc merge a few per pass, and their passes grow
/// with k. A sample keeps either shape: a strided sample of a fan is a
/// fan, of copies is copies. A fan that is a small part of a large scene is
/// a small part of the sample too and goes undetected; PLOC's extra work is
/// then quadratic in the fan's size only.
fn ploc_is_safe(tris: &[Triangle], params: BvhBuildParams) -> bool {
    if tris.len() <= PLOC_PROBE {
        return true;
    }
    let stride = tris.len() / PLOC_PROBE;
    let sample: Vec<Triangle> = tris
        .iter()
        .step_by(stride)
        .take(PLOC_PROBE)
        .copied()
        .collect();
    let bvh2 = PlocBuilder::with_capacity(sample.len()).build(
        params.ploc_search_distance,
        &sample,
        (0..sample.len() as u32).collect(),
        params.sort_precision,
        params.search_depth_threshold,
    );
    // max_depth is max(96, passes + 1)
    bvh2.max_depth <= obvhs::bvh2::DEFAULT_MAX_STACK_DEPTH
}

#[cfg(test)]
mod proptests;

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sampling::{uniform_sphere, Pcg32};
    use crate::scene::{Material, Texture};
    use obvhs::ray::Ray as ORay;

    /// Random rays at a random triangle soup: the hit point rebuilt from the
    /// barycentrics equals o + t d, and a brute-force search finds the same
    /// closest triangle.
    #[test]
    fn closest_hit_matches_brute_force() {
        let mut rng = Pcg32::new(3, 3);
        let mut scene = Scene::empty("soup");
        let m = scene.add_material(Material::Diffuse {
            reflectance: Texture::Constant(Vec3::ONE),
        });
        let mut pos = Vec::new();
        let mut idx = Vec::new();
        for i in 0..300u32 {
            let c = Vec3::new(rng.next_f32(), rng.next_f32(), rng.next_f32()) * 4.0;
            for _ in 0..3 {
                pos.push(c + Vec3::new(rng.next_f32(), rng.next_f32(), rng.next_f32()) - 0.5);
            }
            idx.push([3 * i, 3 * i + 1, 3 * i + 2]);
        }
        scene.add_mesh("soup", &pos, None, None, &idx, m, None);
        let accel = Accel::build(&scene);
        let mut hits = 0;
        for _ in 0..2000 {
            let o = Vec3::new(rng.next_f32(), rng.next_f32(), rng.next_f32()) * 4.0;
            let ray = Ray::new(o, uniform_sphere(rng.next_2d()));
            let brute = (0..scene.triangles.len() as u32)
                .filter_map(|t| {
                    let [a, b, c] = scene.tri_vertices(t);
                    let tri = Triangle {
                        v0: a.into(),
                        v1: b.into(),
                        v2: c.into(),
                    };
                    let oray = ORay::new(o.into(), ray.d.into(), 0.0, f32::INFINITY);
                    let d = tri.intersect(&oray);
                    d.is_finite().then_some((d, t))
                })
                .min_by(|x, y| x.0.total_cmp(&y.0));
            let got = accel.intersect(&ray);
            assert_eq!(got.map(|h| h.tri), brute.map(|b| b.1));
            if let Some(h) = got {
                hits += 1;
                let sp = scene.surface_point(h.tri, h.b1, h.b2);
                assert!((sp.p - ray.at(h.t)).length() < 1e-4);
                assert!(accel.occluded(o, ray.at(h.t * 1.01)));
                assert!(!accel.occluded(o, ray.at(h.t * 0.99)));
            }
        }
        assert!(hits > 100);
    }
}
