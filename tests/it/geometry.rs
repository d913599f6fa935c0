//! Geometry at scale: spheres tessellated by their size in the scene, within
//! a total budget; sphere emitters; exact duplicate triangles removed; BVH
//! builds that stay fast on fans and copies (the reproducers r3, r5 and r5b
//! of issue 18), with hits still exact.

use std::path::Path;
use std::time::{Duration, Instant};

use glam::Vec3;
use kalos::geometry::Ray;
use kalos::sampling::{uniform_sphere, Pcg32};
use kalos::scene::shapes::{
    sphere_rings, sphere_triangles, SPHERE_MIN_RINGS, SPHERE_RINGS, SPHERE_TOLERANCE,
    SPHERE_TRIANGLE_BUDGET,
};
use kalos::scene::{self, Material, Scene, Texture};
use kalos::world::{BuildEvent, World};

fn load(xml_body: &str) -> Scene {
    let xml = format!("<scene version=\"3.0.0\">\n{xml_body}\n</scene>");
    scene::load_str(&xml, Path::new("."), "test.xml").unwrap_or_else(|e| panic!("{e}"))
}

/// `n` spheres of radius `r` at seeded random places in [-10, 10]³ (the
/// reproducer r3 has 1,000 of radius 0.3).
fn spheres_xml(n: usize, r: f32) -> String {
    let mut rng = Pcg32::new(2, 0);
    let mut s = String::from("<emitter type=\"constant\"/>\n");
    for _ in 0..n {
        let c = (Vec3::new(rng.next_f32(), rng.next_f32(), rng.next_f32()) - 0.5) * 20.0;
        s += &format!(
            "<shape type=\"sphere\"><point name=\"center\" x=\"{}\" y=\"{}\" z=\"{}\"/><float name=\"radius\" value=\"{r}\"/></shape>\n",
            c.x, c.y, c.z
        );
    }
    s
}

fn diffuse(scene: &mut Scene) -> u32 {
    scene.add_material(Material::Diffuse {
        reflectance: Texture::Constant(Vec3::splat(0.5)),
    })
}

// ---------------------------------------------------------------------------
// Spheres

/// r3: 1,000 small spheres. The old loader gave each 9,024 triangles (9 M
/// in all, 2.8 GB); now each gets the rings its size asks for, and the
/// world builds.
#[test]
fn many_small_spheres_are_coarse() {
    let s = load(&spheres_xml(1000, 0.3));
    assert_eq!(s.shapes.len(), 1000);
    let per = s.triangles.len() / 1000;
    assert!(
        (per as u64) < sphere_triangles(SPHERE_RINGS) / 4,
        "{per} triangles per sphere"
    );
    assert!(per as u64 >= sphere_triangles(SPHERE_MIN_RINGS));
    let w = World::new(s);
    let hit = w
        .accel
        .intersect(&Ray::new(Vec3::splat(-30.0), Vec3::ONE.normalize()));
    // a ray along the diagonal need not hit, but must not be NaN
    assert!(hit.is_none_or(|h| h.t.is_finite()));
}

/// A sphere as large as the scene keeps the finest tessellation; a tiny
/// one the coarsest; in between, fewer rings for smaller spheres.
#[test]
fn rings_follow_size() {
    let r = sphere_rings(&[1.0, 0.1, 0.01, 1e-6], 2.0);
    assert_eq!(r[0], SPHERE_RINGS);
    assert_eq!(r[3], SPHERE_MIN_RINGS);
    assert!(r[0] > r[1] && r[1] > r[2] && r[2] >= r[3], "{r:?}");
    // non-finite input falls back to the finest, never a panic or zero
    let r = sphere_rings(&[f32::NAN, f32::INFINITY], 0.0);
    assert!(r
        .iter()
        .all(|&n| (SPHERE_MIN_RINGS..=SPHERE_RINGS).contains(&n)));
}

/// 20,000 spheres (the count that aborted) stay within the triangle budget;
/// so do 200,000, at the coarsest tessellation.
#[test]
fn sphere_triangles_are_bounded() {
    for n in [20_000usize, 200_000] {
        let r = sphere_rings(&vec![0.3; n], 35.0);
        let total: u64 = r.iter().map(|&k| sphere_triangles(k)).sum();
        let floor = n as u64 * sphere_triangles(SPHERE_MIN_RINGS);
        assert!(total <= SPHERE_TRIANGLE_BUDGET.max(floor), "{n}: {total}");
    }
    // and through the loader (2,000 of them, so that the XML stays small)
    let s = load(&spheres_xml(2000, 0.3));
    assert!(s.triangles.len() as u64 <= SPHERE_TRIANGLE_BUDGET);
}

/// Every vertex lies on the sphere and no point of the tessellation is
/// farther inside than the tolerance allows: the deepest point of a
/// lat-long cell is at most twice a segment's sagitta (the sagitta in θ plus
/// the one in φ), and the sagitta is within SPHERE_TOLERANCE of the
/// scene's diagonal.
#[test]
fn tessellation_within_tolerance() {
    // a 10 m floor sets the scene's size; spheres of several radii on it
    let s = load(
        r#"<shape type="rectangle"><transform name="to_world"><scale value="5"/></transform></shape>
           <shape type="sphere"><point name="center" x="0" y="0" z="1"/><float name="radius" value="1"/></shape>
           <shape type="sphere"><point name="center" x="2" y="0" z="0.2"/><float name="radius" value="0.2"/></shape>
           <shape type="sphere"><point name="center" x="-2" y="0" z="0.02"/><float name="radius" value="0.02"/></shape>"#,
    );
    let (lo, hi) = s.bounds();
    let bound = 2.0 * SPHERE_TOLERANCE * (hi - lo).length();
    let mut counts = Vec::new();
    for shape in &s.shapes[1..] {
        let tris = shape.first_tri..shape.first_tri + shape.tri_count;
        // centre and radius from the vertices' extremes
        let (mut a, mut b) = (Vec3::INFINITY, Vec3::NEG_INFINITY);
        for t in tris.clone() {
            for p in s.tri_vertices(t) {
                a = a.min(p);
                b = b.max(p);
            }
        }
        let (c, r) = (0.5 * (a + b), 0.5 * (b.z - a.z));
        for t in tris {
            let [p0, p1, p2] = s.tri_vertices(t);
            assert!(((p0 - c).length() - r).abs() < 1e-4 * r.max(1.0));
            let centroid = (p0 + p1 + p2) / 3.0;
            assert!(
                r - (centroid - c).length() <= bound * 1.01,
                "{r} {centroid}"
            );
        }
        counts.push(shape.tri_count);
    }
    assert!(counts[0] > counts[1] && counts[1] > counts[2], "{counts:?}");
}

/// A sphere emitter, small against its scene (so coarsely tessellated):
/// the irradiance its light samples give at a point facing it is the
/// sphere's, π Le (r/d)², within the tessellation's error. The polyhedron's
/// silhouette lies inside the sphere's by at most one sagitta s, so its
/// projected area is short by at most 2s/r of the disk's; the estimate
/// has 40,000 samples whose relative standard error is below 1 % here,
/// so the bound adds 4 %.
#[test]
fn sphere_emitter_irradiance() {
    let (r, d, le) = (0.1f32, 2.0f32, 3.0f32);
    let s = load(&format!(
        r#"<shape type="rectangle"><transform name="to_world"><scale value="20"/><translate z="-5"/></transform></shape>
           <shape type="sphere"><point name="center" x="0" y="0" z="{d}"/><float name="radius" value="{r}"/>
             <emitter type="area"><rgb name="radiance" value="{le}"/></emitter></shape>"#
    ));
    let sphere = s.shapes.iter().find(|sh| sh.emitter.is_some()).unwrap();
    assert!(
        sphere.tri_count as u64 <= sphere_triangles(16),
        "{}",
        sphere.tri_count
    );
    let (lo, hi) = s.bounds();
    let sagitta = SPHERE_TOLERANCE * (hi - lo).length();
    let w = World::new(s);
    let p = Vec3::ZERO;
    let n = 40_000;
    let mut rng = Pcg32::new(9, 1);
    let mut sum = 0.0f64;
    for _ in 0..n {
        if let Some(ls) = w.lights.sample_li(p, rng.next_f32(), rng.next_2d()) {
            sum += (ls.le.x * ls.wi.z.max(0.0) / ls.pdf) as f64;
        }
    }
    let e = sum / n as f64;
    let exact = (std::f32::consts::PI * le * (r / d).powi(2)) as f64;
    let tol = 2.0 * sagitta as f64 / r as f64 + 0.04;
    assert!(
        (e / exact - 1.0).abs() < tol,
        "E {e}, exact {exact}, tol {tol}"
    );
}

// ---------------------------------------------------------------------------
// Duplicates and pathological BVH inputs

/// Two shapes with the same triangle: the first (in file order) is kept
/// with its material and emission, the copy is removed and the build says
/// so; the same corners wound the other way are another surface and stay.
#[test]
fn duplicates_keep_the_first() {
    let mut s = Scene::empty("dups");
    let m0 = diffuse(&mut s);
    let m1 = diffuse(&mut s);
    let pos = [Vec3::ZERO, Vec3::X, Vec3::Y];
    let a = s.add_mesh("a", &pos, None, None, &[[0, 1, 2]], m0, Some(Vec3::ONE));
    let b = s.add_mesh("b", &pos, None, None, &[[0, 1, 2], [1, 2, 0]], m1, None);
    let c = s.add_mesh("c", &pos, None, None, &[[0, 2, 1]], m1, None);
    let mut events = Vec::new();
    let w = World::build(s, &mut |e| events.push(e));
    assert_eq!(w.scene.triangles.len(), 2);
    assert_eq!(w.scene.shapes[a as usize].tri_count, 1);
    assert_eq!(w.scene.shapes[b as usize].tri_count, 0);
    assert_eq!(w.scene.shapes[c as usize].tri_count, 1);
    assert_eq!(w.scene.tri_shape, vec![a, c]);
    let warn = events
        .iter()
        .find_map(|e| match e {
            BuildEvent::Warning(m) => Some(m.clone()),
            _ => None,
        })
        .expect("a warning");
    assert!(
        warn.contains("removed 2") && warn.contains("first"),
        "{warn}"
    );
    assert_eq!(w.scene.warnings.last(), Some(&warn));
    // a ray from above hits the kept triangle (the emitter) from its front
    let h = w
        .accel
        .intersect(&Ray::new(Vec3::new(0.2, 0.2, 1.0), -Vec3::Z))
        .expect("hit");
    assert!(w.lights.is_emitter(h.tri) || w.scene.tri_shape[h.tri as usize] == c);
    assert!(w.lights.is_emitter(0));
}

/// r5b: 100,000 copies of one triangle. PLOC merged one pair per pass
/// (over 300 s); now the copies are removed before the build. The time
/// bound is the issue's "bounded time" and is generous (the build takes
/// well under a second): it only tells a hang from a pass.
#[test]
fn many_copies_build_fast() {
    let mut s = Scene::empty("copies");
    let m = diffuse(&mut s);
    let idx = vec![[0u32, 1, 2]; 100_000];
    s.add_mesh(
        "copies",
        &[Vec3::ZERO, Vec3::X, Vec3::Y],
        None,
        None,
        &idx,
        m,
        None,
    );
    let t = Instant::now();
    let w = World::new(s);
    assert!(t.elapsed() < Duration::from_secs(60));
    assert_eq!(w.scene.triangles.len(), 1);
    assert!(w
        .accel
        .intersect(&Ray::new(Vec3::new(0.2, 0.2, 1.0), -Vec3::Z))
        .is_some());
}

/// A fan of `n` thin triangles around the origin in the z = 0 plane.
fn fan(scene: &mut Scene, n: u32, m: u32) {
    let mut pos = vec![Vec3::ZERO];
    for i in 0..n {
        let a = std::f32::consts::TAU * i as f32 / n as f32;
        pos.push(Vec3::new(a.cos(), a.sin(), 0.0));
    }
    let idx: Vec<[u32; 3]> = (0..n).map(|i| [0, i + 1, (i + 1) % n + 1]).collect();
    scene.add_mesh("fan", &pos, None, None, &idx, m, None);
}

/// r5: a 100,000-triangle fan (16–21 s with PLOC) is recognised and built
/// top-down; its hits equal a brute-force search, as do those of a soup of
/// random triangles around it (built by the same fallback).
#[test]
fn fan_builds_top_down_with_exact_hits() {
    let mut s = Scene::empty("fan");
    let m = diffuse(&mut s);
    fan(&mut s, 100_000, m);
    let mut rng = Pcg32::new(5, 5);
    let mut pos = Vec::new();
    let mut idx = Vec::new();
    for i in 0..300u32 {
        let c = (Vec3::new(rng.next_f32(), rng.next_f32(), rng.next_f32()) - 0.5) * 3.0;
        for _ in 0..3 {
            pos.push(c + (Vec3::new(rng.next_f32(), rng.next_f32(), rng.next_f32()) - 0.5) * 0.5);
        }
        idx.push([3 * i, 3 * i + 1, 3 * i + 2]);
    }
    s.add_mesh("soup", &pos, None, None, &idx, m, None);
    let mut phases = Vec::new();
    let w = World::build(s, &mut |e| {
        if let BuildEvent::Phase(p) = e {
            phases.push(p)
        }
    });
    assert!(phases.iter().any(|p| p.contains("top-down")), "{phases:?}");
    let scene = &w.scene;
    let brute = |ray: &Ray| -> Option<(f32, u32)> {
        (0..scene.triangles.len() as u32)
            .filter_map(|t| {
                let [a, b, c] = scene.tri_vertices(t);
                moller_trumbore(ray, a, b, c).map(|d| (d, t))
            })
            .min_by(|x, y| x.0.total_cmp(&y.0))
    };
    let mut hits = 0;
    for k in 0..300 {
        let o = (Vec3::new(rng.next_f32(), rng.next_f32(), rng.next_f32()) - 0.5) * 3.0;
        // half the rays aimed at the fan's plane, half anywhere
        let d = if k % 2 == 0 {
            let q = Vec3::new(rng.next_f32() - 0.5, rng.next_f32() - 0.5, 0.0) * 1.8;
            (q - o).normalize()
        } else {
            uniform_sphere(rng.next_2d())
        };
        let ray = Ray::new(o, d);
        let got = w.accel.intersect(&ray);
        let want = brute(&ray);
        match (got, want) {
            (Some(g), Some((t, tri))) => {
                // the same triangle, or (the fan's neighbours share edges)
                // the same distance; a sliver 6e-5 wide gives Möller–Trumbore's
                // t to about 1e-3, so the triangle is the check there
                hits += 1;
                assert!(
                    g.tri == tri || (g.t - t).abs() <= 1e-4 * t.max(1.0),
                    "{} vs {t}, triangle {} vs {tri}",
                    g.t,
                    g.tri
                );
            }
            (None, None) => {}
            (g, b) => panic!("accel {g:?} brute {b:?}"),
        }
    }
    assert!(hits > 100, "{hits}");
}

/// Ordinary inputs are not sent to the fallback for inputs where PLOC
/// would take quadratic time (the default build may still choose its
/// top-down tree by SAH cost, and says so in another phase line).
#[test]
fn ordinary_scene_is_not_sent_to_the_fallback() {
    let s = scene::load(&Path::new(env!("CARGO_MANIFEST_DIR")).join("scenes/cbox/cbox.xml"))
        .unwrap_or_else(|e| panic!("{e}"));
    let mut phases = Vec::new();
    World::build(s, &mut |e| {
        if let BuildEvent::Phase(p) = e {
            phases.push(p)
        }
    });
    assert!(phases.iter().any(|p| p.contains("BVH")), "{phases:?}");
    assert!(
        !phases.iter().any(|p| p.contains("quadratic")),
        "{phases:?}"
    );
}

/// Rays along the axes hit: obvhs missed every node along a direction with
/// a −0 component (as `-Vec3::Z` has), which `Accel` now turns into +0.
#[test]
fn axis_aligned_rays_hit() {
    let mut s = Scene::empty("axes");
    let m = diffuse(&mut s);
    s.add_mesh(
        "t",
        &[Vec3::ZERO, Vec3::X, Vec3::Y],
        None,
        None,
        &[[0, 1, 2]],
        m,
        None,
    );
    let w = World::new(s);
    let o = Vec3::new(0.2, 0.2, 1.0);
    for d in [
        -Vec3::Z,
        Vec3::new(0.0, 0.0, -1.0),
        Vec3::new(-0.0, 0.0, -1.0),
    ] {
        let h = w.accel.intersect(&Ray::new(o, d)).expect("hit");
        assert!((h.t - 1.0).abs() < 1e-6);
        assert!(w.accel.occluded(o, o + 2.0 * d));
        assert!(w.accel.occluded_ray(&Ray::new(o, d)));
    }
}

/// Distance along `ray` to triangle (a, b, c), both faces.
fn moller_trumbore(ray: &Ray, a: Vec3, b: Vec3, c: Vec3) -> Option<f32> {
    let (e1, e2) = (b - a, c - a);
    let p = ray.d.cross(e2);
    let det = e1.dot(p);
    if det.abs() < 1e-12 {
        return None;
    }
    let inv = 1.0 / det;
    let s = ray.o - a;
    let u = s.dot(p) * inv;
    let q = s.cross(e1);
    let v = ray.d.dot(q) * inv;
    let t = e2.dot(q) * inv;
    (u >= 0.0 && v >= 0.0 && u + v <= 1.0 && t > ray.tmin && t < ray.tmax).then_some(t)
}
