//! The kernels against brute force: every triangle tested in f64 by a
//! separate Möller–Trumbore. Coordinates are snapped to a coarse grid so that
//! rays run along box faces and start in the planes of triangles, and soups
//! include exactly degenerate triangles (repeated or collinear corners).
//!
//! f32 and f64 disagree on grazing hits, so the brute force classes each
//! triangle as a clear hit, a clear miss (beyond a margin) or too close to
//! call; the kernels must find every clear hit, never report a clear miss,
//! and return the nearest hit up to the margin.
//!
//! Every test runs each kernel this CPU can run ([`kernels`]): the 4-wide
//! one always, the 8-wide AVX2 one where AVX2 is present. As both do the
//! same arithmetic on the same triangles, they must also agree with each
//! other on the distance of every closest hit and on every occlusion.

use glam::{DVec3, Vec3};
use proptest::prelude::*;

use super::{Accel, BuildOptions, Builder, CollapseRule, Hit, Kernel, Visits};
use crate::geometry::Ray;
use crate::scene::{Material, Scene, Texture};

/// Margin on barycentric weights and (relative) on distances.
const MARGIN: f64 = 1e-4;

enum Class {
    Hit(f64),
    Miss,
    Unsure,
}

/// Classes triangle `[a, b, c]` against `o + t d` in `[tmin, tmax)`.
///
/// The margins are [`MARGIN`] plus a first-order bound on the kernels' f32
/// error ([`f32_error`]): near edge-on triangles the f32 distance and
/// weights are ill-conditioned, so such a triangle is too close to call
/// even when f64 places it clearly outside.
fn classify(tri: [Vec3; 3], o: Vec3, d: Vec3, tmin: f32, tmax: f32) -> Class {
    let [a, b, c] = tri.map(DVec3::from);
    let (o, d) = (DVec3::from(o), DVec3::from(d));
    let (e1, e2) = (b - a, c - a);
    let p = d.cross(e2);
    let det = e1.dot(p);
    // Relative to the sizes involved: near zero, the plane is edge-on
    let scale = e1.length() * e2.length() * d.length();
    if det.abs() <= 1e-9 * scale {
        return if e1.cross(e2).length() == 0.0 {
            Class::Miss
        } else {
            Class::Unsure
        };
    }
    let s = o - a;
    let u = s.dot(p) / det;
    let q = s.cross(e1);
    let v = d.dot(q) / det;
    let t = e2.dot(q) / det;
    let w = 1.0 - u - v;
    let err = f32_error([a, b, c], o, d, det, [u, v, t]);
    let (tmin, tmax) = (f64::from(tmin), f64::from(tmax));
    let tm = MARGIN * (1.0 + t.abs()) / d.length().min(1.0) + err[2];
    let bm = [MARGIN + err[0], MARGIN + err[1], MARGIN + err[0] + err[1]];
    let outside = u < -bm[0] || v < -bm[1] || w < -bm[2];
    let inside = u > bm[0] && v > bm[1] && w > bm[2];
    if outside || t < tmin - tm || t > tmax + tm {
        Class::Miss
    } else if inside && t > tmin + tm && t < tmax - tm {
        Class::Hit(t)
    } else {
        Class::Unsure
    }
}

/// A first-order bound on how far the kernels' f32 Möller–Trumbore (edges
/// `b − a`, `c − a` and normal `e1 × e2` rounded at build, then `det = ng·d`,
/// `u, v = (d × (a − o))·e2, e1 / det`, `t = ng·(a − o) / det`) can put
/// `[u, v, t]` from their exact values, four times over. Each rounded
/// difference, product and sum adds a relative error of at most 2⁻²⁴ of
/// the magnitudes it combines; the errors of the numerators and of `det`
/// are divided by `|det|`.
fn f32_error(tri: [DVec3; 3], o: DVec3, d: DVec3, det: f64, uvt: [f64; 3]) -> [f64; 3] {
    let eps = f64::from(f32::EPSILON) / 2.0;
    let [a, b, c] = tri;
    let (e1, e2, ca) = ((b - a).length(), (c - a).length(), (a - o).length());
    let dl = d.length();
    // Rounding of the edges, of a − o, of the normal
    let de = eps * (a.length() + b.length() + c.length());
    let dc = eps * (a.length() + o.length());
    let dng = 2.0 * eps * e1 * e2 + de * (e1 + e2);
    let ng = e1 * e2;
    let ddet = (dng + 3.0 * eps * ng) * dl;
    let du = dl * (dc * e2 + ca * de) + 5.0 * eps * dl * ca * e2;
    let dv = dl * (dc * e1 + ca * de) + 5.0 * eps * dl * ca * e1;
    let dt = dng * ca + ng * dc + 3.0 * eps * ng * ca;
    let [u, v, t] = uvt;
    let safety = 4.0;
    [
        safety * (du + u.abs() * ddet) / det.abs(),
        safety * (dv + v.abs() * ddet) / det.abs(),
        safety * (dt + t.abs() * ddet) / det.abs(),
    ]
}

/// A coordinate on a grid of quarters in [−2, 2], or anywhere in it.
fn coord() -> impl Strategy<Value = f32> {
    prop_oneof![(-8i32..=8).prop_map(|k| k as f32 * 0.25), -2.0f32..2.0,]
}

fn point() -> impl Strategy<Value = Vec3> {
    (coord(), coord(), coord()).prop_map(|(x, y, z)| Vec3::new(x, y, z))
}

/// A point on the grid, where sums and products of coordinates are exact.
fn grid_point() -> impl Strategy<Value = Vec3> {
    (-4i32..=4, -4i32..=4, -4i32..=4)
        .prop_map(|(x, y, z)| Vec3::new(x as f32, y as f32, z as f32) * 0.25)
}

/// A triangle: three points, or an exactly degenerate one (a repeated
/// corner, or three corners on a line, on the grid so that its normal
/// computes to zero in f32).
fn triangle() -> impl Strategy<Value = [Vec3; 3]> {
    prop_oneof![
        8 => (point(), point(), point()).prop_map(|(a, b, c)| [a, b, c]),
        1 => (point(), point()).prop_map(|(a, b)| [a, b, a]),
        1 => (grid_point(), grid_point()).prop_map(|(a, b)| [a, b, b + (b - a)]),
    ]
}

/// A direction: random (not unit: occlusion passes `b − a`), or along an
/// axis with the other components +0 or −0.
fn direction() -> impl Strategy<Value = Vec3> {
    let axis = (0usize..3, any::<bool>(), any::<[bool; 3]>()).prop_map(|(k, neg, zs)| {
        let mut d = zs.map(|n| if n { -0.0 } else { 0.0 });
        d[k] = if neg { -1.0 } else { 1.0 };
        Vec3::from(d)
    });
    prop_oneof![
        (-1.0f32..1.0, -1.0f32..1.0, -1.0f32..1.0, 0.1f32..3.0)
            .prop_filter_map("zero", |(x, y, z, s)| {
                Vec3::new(x, y, z).try_normalize().map(|d| d * s)
            }),
        axis,
    ]
}

/// A scene of `tris` as given, degenerate ones included (`add_mesh` would
/// drop those).
fn soup(tris: &[[Vec3; 3]]) -> Scene {
    let mut scene = Scene::empty("soup");
    let m = scene.add_material(Material::Diffuse {
        reflectance: Texture::Constant(Vec3::ONE),
    });
    scene.add_mesh("soup", &[], None, None, &[], m, None);
    for t in tris {
        let base = scene.positions.len() as u32;
        scene.positions.extend_from_slice(t);
        scene.normals.extend([Vec3::Z; 3]);
        scene.uvs.extend([glam::Vec2::ZERO; 3]);
        scene.triangles.push([base, base + 1, base + 2]);
        scene.tri_shape.push(0);
    }
    scene.shapes[0].tri_count = tris.len() as u32;
    scene
}

/// A test ray: on which triangle it starts (index, two barycentric
/// coordinates) if any, origin otherwise, direction, tmin, tmax.
type TestRay = (Option<(usize, f32, f32)>, Vec3, Vec3, f32, f32);

/// A ray: an origin anywhere, or on one of the triangles (then starting at
/// 0 on its surface), a direction, and a range.
fn rays(n_tris: usize) -> impl Strategy<Value = Vec<TestRay>> {
    let range = prop_oneof![
        Just((0.0f32, f32::INFINITY)),
        (0.0f32..1.0, 0.0f32..4.0).prop_map(|(a, len)| (a, a + len)),
    ];
    let on = prop_oneof![
        Just(None),
        (0..n_tris, 0.0f32..1.0, 0.0f32..1.0).prop_map(Some),
    ];
    prop::collection::vec(
        (on, point(), direction(), range).prop_map(|(on, o, d, (a, b))| (on, o, d, a, b)),
        1..40,
    )
}

/// The kernels this CPU runs: [`Kernel::Bvh8`] only where it has AVX2 (on
/// other CPUs its build would run the 4-wide kernel again).
pub(super) fn kernels() -> Vec<Kernel> {
    let mut k = vec![Kernel::Bvh4];
    #[cfg(target_arch = "x86_64")]
    if std::arch::is_x86_feature_detected!("avx2") {
        k.push(Kernel::Bvh8);
    }
    k
}

/// The default build options with `kernel`.
pub(super) fn with_kernel(kernel: Kernel) -> BuildOptions {
    BuildOptions {
        kernel,
        ..BuildOptions::default()
    }
}

/// A build of `scene` with each of [`kernels`], checked to run the kernel
/// asked for.
pub(super) fn builds(scene: &Scene) -> Vec<Accel> {
    kernels()
        .into_iter()
        .map(|k| {
            let accel = Accel::build_with(scene, &with_kernel(k), &mut |_| {});
            if !scene.triangles.is_empty() {
                assert_eq!(accel.kernel(), Some(k));
            }
            accel
        })
        .collect()
}

/// Checks each build of `accels` against the brute force on one ray, and
/// the builds against each other.
fn check_all(
    accels: &[Accel],
    tris: &[[Vec3; 3]],
    o: Vec3,
    d: Vec3,
    tmin: f32,
    tmax: f32,
) -> Result<(), TestCaseError> {
    for accel in accels {
        check(accel, tris, o, d, tmin, tmax)?;
    }
    let ray = Ray { o, d, tmin, tmax };
    let first = accels[0].intersect(&ray).map(|h| h.t.to_bits());
    for accel in &accels[1..] {
        prop_assert_eq!(
            accel.intersect(&ray).map(|h| h.t.to_bits()),
            first,
            "the kernels disagree on the closest distance"
        );
    }
    Ok(())
}

/// Checks one kernel against the brute force on one ray.
fn check(
    accel: &Accel,
    tris: &[[Vec3; 3]],
    o: Vec3,
    d: Vec3,
    tmin: f32,
    tmax: f32,
) -> Result<(), TestCaseError> {
    let classes: Vec<Class> = tris
        .iter()
        .map(|&t| classify(t, o, d, tmin, tmax))
        .collect();
    let nearest = classes
        .iter()
        .filter_map(|c| match c {
            Class::Hit(t) => Some(*t),
            _ => None,
        })
        .min_by(f64::total_cmp);
    let all_miss = classes.iter().all(|c| matches!(c, Class::Miss));
    let ray = Ray { o, d, tmin, tmax };
    let got: Option<Hit> = accel.intersect(&ray);
    match got {
        None => prop_assert!(nearest.is_none(), "missed a clear hit at {nearest:?}"),
        Some(h) => {
            prop_assert!(
                !matches!(classes[h.tri as usize], Class::Miss),
                "hit a clear miss"
            );
            prop_assert!(
                h.t >= tmin && h.t < tmax,
                "t {} outside [{tmin}, {tmax})",
                h.t
            );
            if let Some(n) = nearest {
                let tm = MARGIN * (1.0 + n.abs()) / f64::from(d.length()).min(1.0);
                prop_assert!(f64::from(h.t) <= n + tm, "t {} beyond the nearest {n}", h.t);
            }
            // The barycentrics rebuild the hit point (on a triangle that
            // is not too close to call: a sliver's are ill-conditioned)
            let [a, b, c] = tris[h.tri as usize];
            let p = a * (1.0 - h.b1 - h.b2) + b * h.b1 + c * h.b2;
            let err = (p - ray.at(h.t)).length();
            if matches!(classes[h.tri as usize], Class::Hit(_)) {
                prop_assert!(
                    err <= 1e-3 * (1.0 + ray.at(h.t).length()),
                    "barycentrics off by {err}"
                );
            }
        }
    }
    let occluded = accel.occluded_ray(&ray);
    if nearest.is_some() {
        prop_assert!(occluded, "occlusion missed a clear hit");
    }
    if all_miss {
        prop_assert!(!occluded, "occluded by clear misses");
    }
    prop_assert_eq!(
        occluded,
        got.is_some(),
        "occlusion disagrees with the closest hit"
    );
    Ok(())
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(256))]

    #[test]
    fn kernels_match_brute_force(
        (tris, rays) in prop::collection::vec(triangle(), 1..80)
            .prop_flat_map(|tris| { let n = tris.len(); (Just(tris), rays(n)) })
    ) {
        let accels = builds(&soup(&tris));
        for (on, o, d, tmin, tmax) in rays {
            // A ray leaving a triangle's surface starts on it
            let o = match on {
                Some((k, s, r)) => {
                    let [a, b, c] = tris[k];
                    let (s, r) = if s + r > 1.0 { (1.0 - s, 1.0 - r) } else { (s, r) };
                    a + (b - a) * s + (c - a) * r
                }
                None => o,
            };
            check_all(&accels, &tris, o, d, tmin, tmax)?;
        }
    }

    /// A large soup, so that the tree has several levels of wide nodes.
    #[test]
    fn kernels_match_brute_force_deep(
        seeds in prop::collection::vec(point(), 300..600),
        rays in rays(1),
    ) {
        let tris: Vec<[Vec3; 3]> = seeds
            .iter()
            .enumerate()
            .map(|(i, &c)| {
                let k = i as f32;
                [c, c + Vec3::new(0.3, 0.05 * (k % 3.0), 0.0), c + Vec3::new(0.0, 0.2, 0.1 * (k % 5.0))]
            })
            .collect();
        let accels = builds(&soup(&tris));
        for (_, o, d, tmin, tmax) in rays {
            check_all(&accels, &tris, o, d, tmin, tmax)?;
        }
    }
}

/// Every builder, collapse and leaf choice that `kalos bench` can compare.
fn options() -> impl Strategy<Value = BuildOptions> {
    (
        prop::sample::select(Builder::ALL.to_vec()),
        prop::sample::select(vec![CollapseRule::Greedy, CollapseRule::Sah]),
        prop::option::of(prop::sample::select(vec![0.25f32, 0.5, 1.0, 2.0])),
        prop::option::of(1usize..=32),
    )
        .prop_map(|(builder, collapse, c_node, leaf_max)| BuildOptions {
            builder,
            collapse,
            c_node,
            leaf_max,
            kernel: Kernel::Bvh4,
        })
}

/// A soup of `n` small triangles around the points of a spiral, clustered
/// enough for PLOC and the binned SAH to make different trees.
fn spiral(n: usize) -> Vec<[Vec3; 3]> {
    (0..n)
        .map(|i| {
            let k = i as f32;
            let c = Vec3::new(
                (k * 0.37).sin() * (1.0 + k * 0.001),
                (k * 0.23).cos() * 2.0,
                (k * 0.011).fract() * 3.0 - 1.5,
            );
            [
                c,
                c + Vec3::new(0.05, 0.01 * (k % 3.0), 0.0),
                c + Vec3::new(0.0, 0.04, 0.02 * (k % 5.0)),
            ]
        })
        .collect()
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(64))]

    /// The trees of every builder, collapse and leaf choice answer as the
    /// brute force, and the counted queries as the uncounted ones, bit for
    /// bit, in both widths where this CPU has the 8-wide.
    #[test]
    fn every_build_matches_brute_force(
        (tris, rays) in prop::collection::vec(triangle(), 1..300)
            .prop_flat_map(|tris| { let n = tris.len(); (Just(tris), rays(n)) }),
        options in options(),
    ) {
        let accel = Accel::build_with(&soup(&tris), &options, &mut |_| {});
        let wider: Vec<Accel> = kernels()[1..]
            .iter()
            .map(|&kernel| Accel::build_with(&soup(&tris), &BuildOptions { kernel, ..options }, &mut |_| {}))
            .collect();
        for a in std::iter::once(&accel).chain(&wider) {
            let stats = a.tree_stats();
            prop_assert_eq!(stats.triangles, tris.len());
            prop_assert!(stats.sah().is_finite());
        }
        for (_, o, d, tmin, tmax) in rays {
            let ray = Ray { o, d, tmin, tmax };
            for a in std::iter::once(&accel).chain(&wider) {
                check(a, &tris, o, d, tmin, tmax)?;
                let mut v = Visits::default();
                let bits = |h: Hit| (h.tri, h.t.to_bits(), h.b1.to_bits(), h.b2.to_bits());
                let counted = a.intersect_counted(&ray, &mut v).map(bits);
                prop_assert_eq!(counted, a.intersect(&ray).map(bits));
                prop_assert_eq!(a.occluded_ray_counted(&ray, &mut v), a.occluded_ray(&ray));
            }
        }
    }
}

/// The binned SAH builder on a soup large enough for its parallel subtrees
/// (and their joined node lists), and the default builder on one large
/// enough to choose on a sample, answer as the brute force.
#[test]
fn large_builds_answer() {
    let tris = spiral(40_000);
    let scene = soup(&tris);
    for (builder, kernel) in [Builder::Sah, Builder::Best]
        .into_iter()
        .flat_map(|b| kernels().into_iter().map(move |k| (b, k)))
    {
        let options = BuildOptions {
            builder,
            kernel,
            ..BuildOptions::default()
        };
        let accel = Accel::build_with(&scene, &options, &mut |_| {});
        assert_eq!(accel.kernel(), Some(kernel));
        assert_eq!(accel.tree_stats().triangles, tris.len());
        let mut rng = crate::sampling::Pcg32::new(5, 5);
        for _ in 0..200 {
            let o = Vec3::new(rng.next_f32(), rng.next_f32(), rng.next_f32()) * 6.0 - 3.0;
            let d = crate::sampling::uniform_sphere(rng.next_2d());
            check(&accel, &tris, o, d, 0.0, f32::INFINITY).unwrap();
        }
    }
}

/// A scene without triangles: nothing is hit, nothing occludes.
#[test]
fn empty_scene() {
    for accel in builds(&soup(&[])) {
        let ray = Ray::new(Vec3::ZERO, Vec3::Z);
        assert!(accel.intersect(&ray).is_none());
        assert!(!accel.occluded_ray(&ray));
        assert!(!accel.occluded(Vec3::ZERO, Vec3::ONE));
    }
}

/// Copies of one triangle send the build to the top-down fallback (see the
/// parent module); its tree must answer like any other.
#[test]
fn top_down_fallback_answers() {
    let tri = [
        Vec3::new(-1.0, -1.0, 0.0),
        Vec3::new(1.0, -1.0, 0.0),
        Vec3::new(0.0, 1.0, 0.0),
    ];
    let mut tris = vec![tri; 5000];
    tris.push([
        Vec3::new(-1.0, -1.0, 2.0),
        Vec3::new(1.0, -1.0, 2.0),
        Vec3::new(0.0, 1.0, 2.0),
    ]);
    for kernel in kernels() {
        let mut phases = Vec::new();
        let accel = Accel::build_with(&soup(&tris), &with_kernel(kernel), &mut |p| phases.push(p));
        assert_eq!(accel.kernel(), Some(kernel));
        assert!(phases.iter().any(|p| p.contains("top-down")), "{phases:?}");
        let down = Ray::new(Vec3::new(0.0, 0.0, 3.0), Vec3::new(-0.0, -0.0, -1.0));
        let h = accel.intersect(&down).expect("hits the top triangle");
        assert_eq!(h.tri, 5000);
        assert!((h.t - 1.0).abs() < 1e-6);
        let below = Ray { tmin: 1.5, ..down };
        let h = accel.intersect(&below).expect("hits the copies");
        assert!(h.tri < 5000 && (h.t - 3.0).abs() < 1e-6);
        assert!(!accel.occluded(Vec3::new(0.0, 0.0, 1.0), Vec3::new(0.0, 0.0, 1.9)));
        assert!(accel.occluded(Vec3::new(0.0, 0.0, 1.0), Vec3::new(0.0, 0.0, -1.0)));
    }
}

/// Coordinates near `f32::MAX` overflow the boxes' areas to infinity (and
/// to NaN where an extent is zero), so every SAH cost ties. Every builder
/// and collapse rule must still place every triangle in a leaf it can
/// encode, and answer as the brute force (a mutated scene file once made
/// the SAH-optimal collapse choose an oversized leaf there).
#[test]
fn infinite_areas_still_build() {
    let n = 300;
    let at = |i: usize| (2.0 * i as f32 / n as f32 - 1.0) * 3e38;
    let tris: Vec<[Vec3; 3]> = (0..n)
        .map(|i| {
            let (x, w, z) = (at(i), 1e35, i as f32);
            [
                Vec3::new(x - w, -1.0, z),
                Vec3::new(x + w, -1.0, z),
                Vec3::new(x, 1.0, z),
            ]
        })
        .collect();
    let scene = soup(&tris);
    for builder in [Builder::Best, Builder::Sah, Builder::PlocMedium] {
        for collapse in [CollapseRule::Sah, CollapseRule::Greedy] {
            for kernel in kernels() {
                let options = BuildOptions {
                    builder,
                    collapse,
                    kernel,
                    ..BuildOptions::default()
                };
                let accel = Accel::build_with(&scene, &options, &mut |_| {});
                assert_eq!(accel.tree_stats().triangles, n, "{options:?}");
                for i in (0..n).step_by(7) {
                    let o = Vec3::new(at(i), 0.0, i as f32 + 0.5);
                    let h = accel.intersect(&Ray::new(o, -Vec3::Z));
                    assert_eq!(h.map(|h| h.tri), Some(i as u32), "{options:?}");
                    check(&accel, &tris, o, -Vec3::Z, 0.0, f32::INFINITY).unwrap();
                }
            }
        }
    }
}

/// True when `a` and `b` are the same answer, bit for bit.
fn same(a: Option<Hit>, b: Option<Hit>) -> bool {
    let key = |h: Option<Hit>| h.map(|h| (h.tri, h.t.to_bits(), h.b1.to_bits(), h.b2.to_bits()));
    key(a) == key(b)
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(256))]

    /// Rays answered in packets get [`Accel::intersect`]'s answers ray by
    /// ray, bit for bit, on soups with shared grid corners (rays through
    /// shared edges and coincident triangles: ties), with rays in every
    /// octant in one packet, axis-parallel rays with ±0 components, rays
    /// that start on triangles and inside boxes, misses, finite ranges and
    /// partial packets (up to 40 rays: five packets, the last usually
    /// partial).
    #[test]
    fn packets_answer_as_single_rays(
        (tris, rays) in prop::collection::vec(triangle(), 1..200)
            .prop_flat_map(|tris| { let n = tris.len(); (Just(tris), rays(n)) }),
        copies in 1usize..3,
    ) {
        // Copies of the soup make coincident triangles, so exact ties
        packets_match_single_rays(&tris, copies, rays)?;
    }
}

/// Rays of one octant, as a camera's neighbouring pixels give: the sign of
/// each direction component is the octant's (zero components are +0 or −0
/// alike), its magnitude a base's times a jitter, or, with `zeros`, zero
/// (rays parallel to an axis or a plane); the origins one point shared by
/// all, or on one of the `n_tris` triangles, or (without `zeros`) each
/// ray's own; ranges as [`rays`]'s.
fn octant_rays(n_tris: usize, zeros: bool) -> impl Strategy<Value = Vec<TestRay>> {
    let range = prop_oneof![
        Just((0.0f32, f32::INFINITY)),
        (0.0f32..1.0, 0.0f32..4.0).prop_map(|(a, len)| (a, a + len)),
    ];
    let on = prop_oneof![
        3 => Just(None),
        1 => (0..n_tris, 0.0f32..1.0, 0.0f32..1.0).prop_map(Some),
    ];
    let own = if zeros {
        Just(None).boxed()
    } else {
        prop::option::of(point()).boxed()
    };
    let zero = prop_oneof![6 => Just(false), 1 => Just(zeros)];
    (
        any::<[bool; 3]>(),
        [0.05f32..1.0, 0.05f32..1.0, 0.05f32..1.0],
        point(),
        prop::collection::vec(
            (
                (on, own),
                [0.8f32..1.25, 0.8f32..1.25, 0.8f32..1.25],
                [zero.clone(), zero.clone(), zero],
                range,
            ),
            1..40,
        ),
    )
        .prop_map(|(neg, base, o, rays)| {
            rays.into_iter()
                .map(|((on, own), jitter, zero, (a, b))| {
                    let d: [f32; 3] = std::array::from_fn(|k| {
                        let m = if zero[k] { 0.0 } else { base[k] * jitter[k] };
                        if neg[k] {
                            -m
                        } else {
                            m
                        }
                    });
                    (on, own.unwrap_or(o), Vec3::from(d), a, b)
                })
                .collect()
        })
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(256))]

    /// [`packets_answer_as_single_rays`] for packets whose rays share an
    /// octant (the packets' kernel takes each axis's near plane once for
    /// all its rays), with a shared origin or origins on triangles.
    #[test]
    fn packets_of_one_octant_answer_as_single_rays(
        (tris, rays) in prop::collection::vec(triangle(), 1..200)
            .prop_flat_map(|tris| { let n = tris.len(); (Just(tris), octant_rays(n, true)) }),
        copies in 1usize..3,
    ) {
        packets_match_single_rays(&tris, copies, rays)?;
    }
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(256))]

    /// [`packets_of_one_octant_answer_as_single_rays`] with no zero
    /// direction components and origins spread out (a shared point, points
    /// on triangles, each ray's own), so that the packets' interval test
    /// (`packet8::Frustum`) drops children: it must drop none that a ray
    /// enters.
    #[test]
    fn packets_culled_by_their_bounds_answer_as_single_rays(
        (tris, rays) in prop::collection::vec(triangle(), 1..200)
            .prop_flat_map(|tris| { let n = tris.len(); (Just(tris), octant_rays(n, false)) }),
        copies in 1usize..3,
    ) {
        packets_match_single_rays(&tris, copies, rays)?;
    }
}

/// Ties across leaves: a floor of 24 × 24 quads on a grid of quarters,
/// each two triangles, and rays aimed exactly at its vertices from points
/// of the grid above it, so that every product in the triangle test is
/// exact and each triangle around the vertex (up to six, in different
/// leaves) computes the same distance. Packets mixing rays from different
/// origins visit those leaves in other orders than single rays; both must
/// answer alike, and the 8-wide kernel with the lowest-index triangle.
#[test]
fn packets_and_single_rays_break_ties_alike() {
    let n = 24;
    let v = |i: usize, j: usize| Vec3::new(i as f32 * 0.25 - 3.0, j as f32 * 0.25 - 3.0, 0.0);
    let mut tris = Vec::new();
    for i in 0..n {
        for j in 0..n {
            let (a, b, c, d) = (v(i, j), v(i + 1, j), v(i + 1, j + 1), v(i, j + 1));
            if (i + j) % 2 == 0 {
                tris.extend([[a, b, c], [a, c, d]]);
            } else {
                tris.extend([[a, b, d], [b, c, d]]);
            }
        }
    }
    let mut rng = crate::sampling::Pcg32::new(5, 7);
    let mut pick = |k: usize| (rng.next_f32() * k as f32) as usize;
    let (rays, targets): (Vec<Ray>, Vec<Vec3>) = (0..4000)
        .map(|_| {
            let o = Vec3::new(
                pick(33) as f32 * 0.25 - 4.0,
                pick(33) as f32 * 0.25 - 4.0,
                (1 + pick(8)) as f32 * 0.25,
            );
            let target = v(1 + pick(n - 1), 1 + pick(n - 1));
            (Ray::new(o, target - o), target)
        })
        .unzip();
    for accel in builds(&soup(&tris)) {
        let mut got = vec![None; rays.len()];
        accel.intersect_packet(&rays, &mut got);
        for ((r, g), target) in rays.iter().zip(&got).zip(&targets) {
            let want = accel.intersect(r);
            // The lowest-index triangle around the vertex aimed at (the
            // 8-wide kernel's tie rule; the 4-wide one keeps the first it
            // finds, and answers packets ray by ray)
            if accel.kernel() == Some(Kernel::Bvh8) {
                let first = tris.iter().position(|t| t.contains(target));
                assert_eq!(want.map(|h| h.tri as usize), first, "ray {r:?}");
            }
            assert!(same(*g, want), "packet {g:?}, single {want:?}, ray {r:?}");
        }
    }
}

/// `rays` (each with its origin on triangle k at (s, r), or its own)
/// traced as packets through every build of `tris` repeated `copies`
/// times, each answer against the single-ray kernel's, bit for bit.
fn packets_match_single_rays(
    tris: &[[Vec3; 3]],
    copies: usize,
    rays: Vec<TestRay>,
) -> Result<(), TestCaseError> {
    let tris: Vec<[Vec3; 3]> = tris
        .iter()
        .cycle()
        .take(tris.len() * copies)
        .copied()
        .collect();
    let rays: Vec<Ray> = rays
        .into_iter()
        .map(|(on, o, d, tmin, tmax)| {
            let o = match on {
                Some((k, s, r)) => {
                    let [a, b, c] = tris[k];
                    let (s, r) = if s + r > 1.0 {
                        (1.0 - s, 1.0 - r)
                    } else {
                        (s, r)
                    };
                    a + (b - a) * s + (c - a) * r
                }
                None => o,
            };
            Ray { o, d, tmin, tmax }
        })
        .collect();
    for accel in builds(&soup(&tris)) {
        let mut got = vec![None; rays.len()];
        accel.intersect_packet(&rays, &mut got);
        for (r, g) in rays.iter().zip(&got) {
            let want = accel.intersect(r);
            prop_assert!(
                same(*g, want),
                "packet {:?}, single {:?}, ray {:?}",
                g,
                want,
                r
            );
        }
    }
    Ok(())
}
