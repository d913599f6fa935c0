//! The ray core: a BVH over every triangle of the scene, with closest-hit and
//! occlusion queries. This is the only module that knows how rays meet
//! geometry. obvhs (pinned to an exact version in Cargo.toml) builds a binary
//! BVH in parallel by PLOC with rayon; `accel/wide.rs` collapses it into a
//! 4-wide BVH whose nodes and triangles the kernels of `accel/traverse.rs`
//! test four at a time (SSE2 on x86_64, `crate::simd`'s `F4`).
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
//!
//! On a CPU with AVX2 the binary BVH is collapsed into an 8-wide BVH instead
//! (`accel/wide8.rs`), walked by AVX2 kernels (`accel/traverse8.rs`); the
//! choice is made once per build, at run time (`Kernel`), so that the
//! default build runs on any x86-64 and the 4-wide SSE2 kernel stays the
//! fallback. The environment variable `KALOS_ACCEL=bvh4` forces the
//! fallback (to compare the two, or to test it on an AVX2 machine).
//!
//! Either way the binary tree becomes the wide one by the collapse of
//! `accel/collapse.rs` that minimises the wide tree's SAH cost, and trees
//! are priced at the width the kernel will walk.

mod collapse;
#[cfg(target_arch = "x86_64")]
mod packet8;
mod quality;
mod sah;
mod traverse;
#[cfg(target_arch = "x86_64")]
mod traverse8;
mod wide;
#[cfg(target_arch = "x86_64")]
mod wide8;

use glam::Vec3;
use obvhs::bvh2::reinsertion::ReinsertionOptimizer;
use obvhs::bvh2::Bvh2;
use obvhs::ploc::PlocBuilder;
use obvhs::triangle::Triangle;
use obvhs::BvhBuildParams;

use crate::geometry::Ray;
use crate::scene::Scene;
use wide::Wide;

pub use collapse::CollapseRule;
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

/// Lane `i`'s vector of eight held by component.
#[inline(always)]
fn lane_vec(a: &[[f32; 8]; 3], i: usize) -> Vec3 {
    Vec3::new(a[0][i], a[1][i], a[2][i])
}

/// The far end of [`Accel::occluded`]'s segment, as a fraction of its
/// length: short of the end point, so that the surface there does not
/// block it.
const OCCLUDED_TMAX: f32 = 1.0 - 1e-4;

/// The acceleration structure.
pub struct Accel {
    /// `None` for a scene without triangles.
    core: Option<Core>,
}

/// The wide BVH a build produced, with the kernels that walk it.
enum Core {
    /// 4 wide, SSE2 (scalar off x86_64): runs anywhere.
    Bvh4(Wide),
    /// 8 wide, AVX2: built only where AVX2 was detected.
    #[cfg(target_arch = "x86_64")]
    Bvh8(wide8::Wide8),
}

/// The traversal kernel a build asks for.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Kernel {
    /// The 4-wide BVH with SSE2 kernels.
    Bvh4,
    /// The 8-wide BVH with AVX2 kernels where the CPU has AVX2, else
    /// [`Kernel::Bvh4`].
    Bvh8,
}

/// The environment variable that chooses the kernel.
const KERNEL_VAR: &str = "KALOS_ACCEL";

impl Kernel {
    /// The kernel `KALOS_ACCEL` asks for: `bvh4`, or `bvh8` (the default,
    /// when unset or empty). Any other value is reported on stderr and the
    /// default is used: the build has no error path, and the variable only
    /// chooses between two kernels that give the same answers. (A progress
    /// line would be overwritten by the next phase before anyone read it.)
    fn from_env() -> Kernel {
        match std::env::var(KERNEL_VAR) {
            Ok(v) if v == "bvh4" => Kernel::Bvh4,
            Ok(v) if v == "bvh8" || v.is_empty() => Kernel::Bvh8,
            Err(std::env::VarError::NotPresent) => Kernel::Bvh8,
            Ok(v) => {
                eprintln!(
                    "warning: ignoring {KERNEL_VAR}={v:?}: expected bvh4 or bvh8; using bvh8"
                );
                Kernel::Bvh8
            }
            Err(std::env::VarError::NotUnicode(v)) => {
                eprintln!(
                    "warning: ignoring {KERNEL_VAR}={v:?}: expected bvh4 or bvh8; using bvh8"
                );
                Kernel::Bvh8
            }
        }
    }
}

/// True when a build for `kernel` makes the 8-wide tree: the CPU has AVX2.
fn builds_wide8(kernel: Kernel) -> bool {
    #[cfg(target_arch = "x86_64")]
    if kernel == Kernel::Bvh8 {
        return wide8::Avx2::detect().is_some();
    }
    let _ = kernel;
    false
}

/// The wide BVH of `options` for `bvh2` over `tris`: 8 wide where
/// `wide8` (see [`builds_wide8`]) and it fits the 8-wide kernel's limits,
/// else 4 wide; `None` when neither fits.
fn finish(bvh2: &Bvh2, tris: &[Triangle], options: &BuildOptions, wide8: bool) -> Option<Core> {
    #[cfg(target_arch = "x86_64")]
    if wide8 {
        if let Some(avx2) = wide8::Avx2::detect() {
            let c = collapse::Collapse::new(options.collapse, 8, options.c_node, options.leaf_max);
            if let Some(w) = wide8::Wide8::from_bvh2(bvh2, tris, &c, avx2) {
                return Some(Core::Bvh8(w));
            }
        }
    }
    let _ = wide8;
    let c = collapse::Collapse::new(options.collapse, 4, options.c_node, options.leaf_max);
    Wide::from_bvh2(bvh2, tris, &c).map(Core::Bvh4)
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
    /// 32 768 triangles (`CHOICE_SAMPLE`), then only the chosen tree built over
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
/// triangles badly differs by far more (docs/notebook/ray-core.md, "BVH quality on
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

/// How [`Accel::build_with`] builds: the binary builder, then the
/// collapse to the wide BVH.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct BuildOptions {
    /// The binary BVH's builder.
    pub builder: Builder,
    /// How the binary BVH becomes a wide one.
    pub collapse: CollapseRule,
    /// The collapse's cost of a node per unit area relative to one pack
    /// test (see [`CollapseRule`]); `None` for the default of the rule and
    /// the width.
    pub c_node: Option<f32>,
    /// The most triangles a leaf may hold (1 to 32); `None` for one pack
    /// (4 or 8, the tree's width).
    pub leaf_max: Option<usize>,
    /// The traversal kernel, and so the width of the tree.
    pub kernel: Kernel,
}

impl Default for BuildOptions {
    fn default() -> Self {
        BuildOptions {
            builder: Builder::Best,
            collapse: CollapseRule::Sah,
            c_node: None,
            leaf_max: None,
            kernel: Kernel::from_env(),
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

    /// [`Accel::build_reporting`] with another builder, collapse or kernel
    /// than the default, for `kalos bench` to compare trees on the same
    /// rays and for the tests to run both kernels.
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
            return Accel { core: None };
        }
        // Trees are priced, and built, at the width the kernel will walk
        let wide8 = builds_wide8(options.kernel);
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
            finish(&bvh2, tris, options, wide8)
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
            finish(&bvh2, tris, options, wide8)
                .expect("a scene of over a billion triangles exceeds the BVH's index range")
        };
        let cost = |c: &Core| quality::core_stats(c).sah();
        // True when the top-down tree of `tris` is clearly cheaper. The two
        // trees are built at once: each build has long serial stretches
        // (the collapse into the wide tree), which the other fills
        let top_down_wins = |tris: &[Triangle], params: BvhBuildParams| match rayon::join(
            || ploc(tris, params),
            || top_down(tris, true),
        ) {
            (Some(p), t) => cost(&t) < SWITCH_MARGIN * cost(&p),
            (None, _) => true,
        };
        // Both trees over every triangle, keeping the clearly cheaper
        let both = |params: BvhBuildParams| match rayon::join(
            || top_down(&tris, true),
            || ploc(&tris, params),
        ) {
            (t, Some(p)) if cost(&t) >= SWITCH_MARGIN * cost(&p) => p,
            (t, _) => t,
        };
        let safe = options
            .builder
            .ploc_params()
            .filter(|&params| ploc_is_safe(&tris, params));
        let core = match (options.builder, safe) {
            // A scene no larger than the sample is built both ways in full
            (b @ (Builder::Both | Builder::Best), Some(params))
                if b == Builder::Both || n <= CHOICE_SAMPLE =>
            {
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
        Accel { core: Some(core) }
    }

    /// The kernel this build runs (for the tests: [`Kernel::Bvh8`] falls
    /// back without AVX2); `None` for a scene without triangles.
    #[cfg(test)]
    pub(crate) fn kernel(&self) -> Option<Kernel> {
        match self.core.as_ref()? {
            Core::Bvh4(_) => Some(Kernel::Bvh4),
            #[cfg(target_arch = "x86_64")]
            Core::Bvh8(_) => Some(Kernel::Bvh8),
        }
    }

    /// The closest hit along `ray` in `[ray.tmin, ray.tmax)`.
    #[inline]
    pub fn intersect(&self, ray: &Ray) -> Option<Hit> {
        self.closest(ray, &mut traverse::NoCount)
    }

    /// [`Accel::intersect`], telling `count` the nodes and packs tested;
    /// with [`traverse::NoCount`] the counting inlines to nothing.
    #[inline(always)]
    fn closest(&self, ray: &Ray, count: &mut impl traverse::Count) -> Option<Hit> {
        let (h, ids) = match self.core.as_ref()? {
            Core::Bvh4(w) => (
                traverse::closest(w, ray.o, ray.d, ray.tmin, ray.tmax, count)?,
                &w.ids,
            ),
            #[cfg(target_arch = "x86_64")]
            Core::Bvh8(w) => (
                traverse8::closest(w, ray.o, ray.d, ray.tmin, ray.tmax, count)?,
                &w.ids,
            ),
        };
        Some(h.hit(ids))
    }

    /// The closest hit of each ray of `rays` into `out` (of the same
    /// length), each the one [`Accel::intersect`] gives, bit for bit. On
    /// the 8-wide tree the rays go down it in packets of eight, one ray in
    /// each lane of the AVX2 registers (`accel/packet8.rs`), which is
    /// faster where neighbours in `rays` start close together and point
    /// alike (camera rays of neighbouring pixels); elsewhere it is
    /// [`Accel::intersect`] ray by ray. Rays that are not alike get the
    /// same answers, more slowly: the packets walk nodes that only some of
    /// their rays enter, and test triangles in every lane.
    ///
    /// # Panics
    /// When `out` and `rays` differ in length.
    pub fn intersect_packet(&self, rays: &[Ray], out: &mut [Option<Hit>]) {
        assert_eq!(rays.len(), out.len(), "one answer per ray");
        match &self.core {
            #[cfg(target_arch = "x86_64")]
            Some(Core::Bvh8(w)) => {
                for (rs, os) in rays
                    .chunks(packet8::PACKET)
                    .zip(out.chunks_mut(packet8::PACKET))
                {
                    packet8::closest(w, rs, os);
                }
            }
            _ => {
                for (r, o) in rays.iter().zip(out) {
                    *o = self.intersect(r);
                }
            }
        }
    }

    /// True when something blocks the open segment from `a` to `b`. Both
    /// ends are expected to be already offset from their surfaces
    /// ([`crate::geometry::offset_point`]); the segment stops just short of `b`.
    #[inline]
    pub fn occluded(&self, a: Vec3, b: Vec3) -> bool {
        self.any(a, b - a, 0.0, OCCLUDED_TMAX, &mut traverse::NoCount)
    }

    /// [`Accel::intersect`] of the rays of the lanes of `mask` (bit i for
    /// lane i of eight): lane i's ray is `Ray::new(o[·][i], d[·][i])`, its
    /// answer goes to `out[i]`, bit for bit the one `intersect` gives;
    /// lanes outside `mask` are left as they were. For the AVX lanes of
    /// `transport::lanes`, which hold their rays by component: one call for
    /// up to eight rays, without the round trip of each ray and answer
    /// through memory that a call per ray costs.
    pub fn intersect_lanes(
        &self,
        o: &[[f32; 8]; 3],
        d: &[[f32; 8]; 3],
        mask: u32,
        out: &mut [Option<Hit>; 8],
    ) {
        match &self.core {
            #[cfg(target_arch = "x86_64")]
            Some(Core::Bvh8(w)) => {
                let _ = w.avx2;
                // SAFETY: a Wide8 holds an Avx2 token, made only where AVX2
                // was detected
                unsafe { traverse8::closest_lanes(w, o, d, mask, out) }
            }
            _ => {
                for i in (0..8).filter(|i| mask & (1 << i) != 0) {
                    out[i] = self.intersect(&Ray::new(lane_vec(o, i), lane_vec(d, i)));
                }
            }
        }
    }

    /// [`Accel::occluded`] of the segments of the lanes of `mask`, from
    /// `a[·][i]` to `b[·][i]`: the lanes whose segment is blocked, bit for
    /// bit as `occluded` answers. For the AVX lanes, as
    /// [`Accel::intersect_lanes`] is.
    pub fn occluded_lanes(&self, a: &[[f32; 8]; 3], b: &[[f32; 8]; 3], mask: u32) -> u32 {
        match &self.core {
            #[cfg(target_arch = "x86_64")]
            Some(Core::Bvh8(w)) => {
                let _ = w.avx2;
                // SAFETY: as in `intersect_lanes`
                unsafe { traverse8::occluded_lanes(w, a, b, mask) }
            }
            _ => (0..8)
                .filter(|i| mask & (1 << i) != 0)
                .map(|i| u32::from(self.occluded(lane_vec(a, i), lane_vec(b, i))) << i)
                .sum(),
        }
    }

    /// True when something blocks the ray within `[ray.tmin, ray.tmax)`.
    #[inline]
    pub fn occluded_ray(&self, ray: &Ray) -> bool {
        self.any(ray.o, ray.d, ray.tmin, ray.tmax, &mut traverse::NoCount)
    }

    #[inline(always)]
    fn any(
        &self,
        o: Vec3,
        d: Vec3,
        tmin: f32,
        tmax: f32,
        count: &mut impl traverse::Count,
    ) -> bool {
        match &self.core {
            None => false,
            Some(Core::Bvh4(w)) => traverse::any(w, o, d, tmin, tmax, count),
            #[cfg(target_arch = "x86_64")]
            Some(Core::Bvh8(w)) => traverse8::any(w, o, d, tmin, tmax, count),
        }
    }

    /// The shape of the wide tree and its surface area heuristic cost (for
    /// `kalos bench`); all zero for a scene without triangles.
    pub fn tree_stats(&self) -> TreeStats {
        self.core
            .as_ref()
            .map(quality::core_stats)
            .unwrap_or_default()
    }

    /// [`Accel::intersect`], adding the nodes and packs it tests to
    /// `visits` (for `kalos bench`; the uncounted query is the fast one).
    /// Either kernel counts itself, so the counts are of the nodes and
    /// packs the fast query tests.
    pub fn intersect_counted(&self, ray: &Ray, visits: &mut Visits) -> Option<Hit> {
        self.closest(ray, visits)
    }

    /// [`Accel::occluded_ray`], adding the nodes and packs it tests to
    /// `visits`.
    pub fn occluded_ray_counted(&self, ray: &Ray, visits: &mut Visits) -> bool {
        self.any(ray.o, ray.d, ray.tmin, ray.tmax, visits)
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
        for accel in proptests::builds(&scene) {
            soup_rays_match_brute_force(&scene, &accel, &mut rng);
            lanes_match_ray_by_ray(&accel, &mut rng);
        }
    }

    /// `intersect_lanes` and `occluded_lanes` give, lane by lane and bit for
    /// bit, what `intersect` and `occluded` give ray by ray, and leave the
    /// lanes outside the mask alone.
    fn lanes_match_ray_by_ray(accel: &Accel, rng: &mut Pcg32) {
        let (mut hits, mut blocked) = (0, 0);
        for _ in 0..300 {
            let mut o = [[0.0; 8]; 3];
            let mut d = [[0.0; 8]; 3];
            let mut b = [[0.0; 8]; 3];
            for i in 0..8 {
                let oi = Vec3::new(rng.next_f32(), rng.next_f32(), rng.next_f32()) * 4.0;
                let di = uniform_sphere(rng.next_2d());
                let bi = oi + di * (rng.next_f32() * 3.0);
                for c in 0..3 {
                    (o[c][i], d[c][i], b[c][i]) = (oi[c], di[c], bi[c]);
                }
            }
            let mask = rng.next_u32() & 0xff;
            let untouched = Some(Hit {
                t: -1.0,
                tri: u32::MAX,
                b1: 0.0,
                b2: 0.0,
            });
            let mut out = [untouched; 8];
            accel.intersect_lanes(&o, &d, mask, &mut out);
            let occ = accel.occluded_lanes(&o, &b, mask);
            assert_eq!(occ & !mask, 0);
            for (i, &got) in out.iter().enumerate() {
                let bits = |h: Option<Hit>| {
                    h.map(|h| (h.t.to_bits(), h.tri, h.b1.to_bits(), h.b2.to_bits()))
                };
                if mask & (1 << i) == 0 {
                    assert_eq!(bits(got), bits(untouched));
                    continue;
                }
                let want = accel.intersect(&Ray::new(lane_vec(&o, i), lane_vec(&d, i)));
                assert_eq!(bits(got), bits(want));
                let want_occ = accel.occluded(lane_vec(&o, i), lane_vec(&b, i));
                assert_eq!(occ & (1 << i) != 0, want_occ);
                hits += usize::from(want.is_some());
                blocked += usize::from(want_occ);
            }
        }
        // both answers seen, many times
        assert!(
            hits > 100 && blocked > 100,
            "{hits} hits, {blocked} blocked"
        );
    }

    fn soup_rays_match_brute_force(scene: &Scene, accel: &Accel, rng: &mut Pcg32) {
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
