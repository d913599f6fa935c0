//! The ray core: a BVH over every triangle of the scene, with closest-hit and
//! occlusion queries. This is the only module that knows how rays meet
//! geometry. obvhs (pinned to an exact version in Cargo.toml) builds a binary
//! BVH in parallel by PLOC with rayon; `accel/wide.rs` collapses it into a
//! 4-wide BVH whose nodes and triangles the kernels of `accel/traverse.rs`
//! test four at a time (SSE2 on x86_64, `accel/simd.rs`).
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

mod sah;
mod simd;
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
pub(crate) enum Kernel {
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

/// Collapses `bvh2` into the wide BVH of `kernel`, or `None` when even the
/// 4-wide form would be too deep or too large (see [`Wide::from_bvh2`]).
/// The 8-wide form falls back to the 4-wide one on a CPU without AVX2, or
/// when it does not fit its own limits.
fn collapse(bvh2: &Bvh2, tris: &[Triangle], kernel: Kernel) -> Option<Core> {
    #[cfg(target_arch = "x86_64")]
    if kernel == Kernel::Bvh8 {
        if let Some(avx2) = wide8::Avx2::detect() {
            if let Some(w) = wide8::Wide8::from_bvh2(bvh2, tris, avx2) {
                return Some(Core::Bvh8(w));
            }
        }
    }
    #[cfg(not(target_arch = "x86_64"))]
    let _ = kernel;
    Wide::from_bvh2(bvh2, tris).map(Core::Bvh4)
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
        let kernel = Kernel::from_env();
        Self::build_kernel(scene, kernel, on_phase)
    }

    /// [`Accel::build_reporting`] with the kernel given.
    pub(crate) fn build_kernel(
        scene: &Scene,
        kernel: Kernel,
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
        let params = BvhBuildParams::medium_build();
        let ploc = if ploc_is_safe(&tris, params) {
            on_phase(format!("building the BVH over {} triangles", tris.len()));
            let mut bvh2 = PlocBuilder::with_capacity(tris.len()).build(
                params.ploc_search_distance,
                &tris,
                (0..tris.len() as u32).collect(),
                params.sort_precision,
                params.search_depth_threshold,
            );
            ReinsertionOptimizer::default().run(&mut bvh2, params.reinsertion_batch_ratio, None);
            collapse(&bvh2, &tris, kernel)
        } else {
            None
        };
        // The top-down tree's depth is bounded (see accel/sah.rs), so its
        // wide form always fits the traversal stack; the pack indices run
        // out only past a billion triangles, which would not fit in memory
        let wide = ploc.unwrap_or_else(|| {
            on_phase(format!(
                "building the BVH over {} triangles top-down (PLOC would take quadratic time on this input)",
                tris.len()
            ));
            let bvh2: Bvh2 = sah::build(&tris);
            collapse(&bvh2, &tris, kernel)
                .expect("a scene of over a billion triangles exceeds the BVH's index range")
        });
        Accel { core: Some(wide) }
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
        let (h, ids) = match self.core.as_ref()? {
            Core::Bvh4(w) => (
                traverse::closest(w, ray.o, ray.d, ray.tmin, ray.tmax)?,
                &w.ids,
            ),
            #[cfg(target_arch = "x86_64")]
            Core::Bvh8(w) => (
                traverse8::closest(w, ray.o, ray.d, ray.tmin, ray.tmax)?,
                &w.ids,
            ),
        };
        Some(Hit {
            t: h.t,
            tri: ids[h.slot],
            b1: h.b1,
            b2: h.b2,
        })
    }

    /// True when something blocks the open segment from `a` to `b`. Both
    /// ends are expected to be already offset from their surfaces
    /// ([`crate::geometry::offset_point`]); the segment stops just short of `b`.
    #[inline]
    pub fn occluded(&self, a: Vec3, b: Vec3) -> bool {
        self.any(a, b - a, 0.0, 1.0 - 1e-4)
    }

    /// True when something blocks the ray within `[ray.tmin, ray.tmax)`.
    #[inline]
    pub fn occluded_ray(&self, ray: &Ray) -> bool {
        self.any(ray.o, ray.d, ray.tmin, ray.tmax)
    }

    #[inline(always)]
    fn any(&self, o: Vec3, d: Vec3, tmin: f32, tmax: f32) -> bool {
        match &self.core {
            None => false,
            Some(Core::Bvh4(w)) => traverse::any(w, o, d, tmin, tmax),
            #[cfg(target_arch = "x86_64")]
            Some(Core::Bvh8(w)) => traverse8::any(w, o, d, tmin, tmax),
        }
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
        }
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
