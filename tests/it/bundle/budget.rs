//! The patch budgets (`--patch-budget area|projected`): the count they give,
//! every triangle meshed, the two-level `locate`, and the projected budget
//! spending more patches per unit area on near surfaces than on far ones.

use glam::Vec3;
use kalos::geometry::look_at;
use kalos::methods::bundle::budget;
use kalos::methods::bundle::patches::{edge_for_count, Layout, Patches};
use kalos::sampling::Pcg32;
use kalos::scene::{self, CameraDesc, Material, Scene, Texture};
use kalos::world::World;

use super::root;

/// A long grey floor strip (one quad, x in ±1, z from 2 to −30) with a
/// small light above its near end, seen from above the near end looking
/// down the strip: the near part covers many pixels per unit area, the far
/// part few.
fn corridor() -> Scene {
    let mut s = Scene::empty("corridor");
    let grey = s.add_material(Material::Diffuse {
        reflectance: Texture::Constant(Vec3::splat(0.5)),
    });
    let floor = [
        Vec3::new(-1.0, 0.0, 2.0),
        Vec3::new(1.0, 0.0, 2.0),
        Vec3::new(1.0, 0.0, -30.0),
        Vec3::new(-1.0, 0.0, -30.0),
    ];
    s.add_mesh(
        "floor",
        &floor,
        None,
        None,
        &[[0, 1, 2], [0, 2, 3]],
        grey,
        None,
    );
    let light = [
        Vec3::new(-0.2, 3.0, -0.2),
        Vec3::new(-0.2, 3.0, 0.2),
        Vec3::new(0.2, 3.0, 0.2),
        Vec3::new(0.2, 3.0, -0.2),
    ];
    s.add_mesh(
        "light",
        &light,
        None,
        None,
        &[[0, 1, 2], [0, 2, 3]],
        grey,
        Some(Vec3::splat(10.0)),
    );
    s.camera = CameraDesc {
        to_world: look_at(Vec3::new(0.0, 1.0, 2.0), Vec3::new(0.0, 0.0, -4.0), Vec3::Y),
        fov_x_deg: 60.0,
        width: 64,
        height: 64,
        near_clip: 1e-3,
    };
    s
}

/// Patches per unit area of the floor's near (z > −6) and far (z < −14)
/// parts, by patch centroid.
fn near_far_density(p: &Patches) -> (f64, f64) {
    let (mut near, mut far) = ((0usize, 0f64), (0usize, 0f64));
    for q in
        p.p.iter()
            .filter(|q| q.ng.y.abs() > 0.5 && q.centroid().y < 1.0)
    {
        let z = q.centroid().z;
        if z > -6.0 {
            near.0 += 1;
            near.1 += q.area as f64;
        } else if z < -14.0 {
            far.0 += 1;
            far.1 += q.area as f64;
        }
    }
    (near.0 as f64 / near.1, far.0 as f64 / far.1)
}

/// The projected budget gives the area budget's count, less by at most the
/// documented shortfall (2 k + 1 for the smallest k still splittable; the
/// cells of the corridor's small light stay whole, so at most 2), every
/// triangle has patches, and the patches are those the layout says.
#[test]
fn projected_count_and_coverage() {
    for (name, scene, n) in [
        ("corridor", corridor(), 3000),
        (
            "cbox",
            scene::load(&root().join("scenes/cbox/cbox.xml")).expect("cbox"),
            5000,
        ),
    ] {
        let world = World::new(scene);
        let edge = edge_for_count(&world.scene, n);
        let target = Layout::area(&world.scene, edge).patch_count();
        let (layout, rays) = budget::projected(&world, edge, true);
        assert!(rays > 0, "the footprints trace camera rays");
        let count = layout.patch_count();
        let k_min = layout.k.iter().copied().min().expect("cells") as usize;
        assert!(
            count <= target && target - count < 2 * k_min + 1,
            "{name}: {count} patches for a target of {target} (smallest k {k_min})"
        );
        let patches = Patches::with_layout(&world.scene, &world.lights, layout, edge);
        assert_eq!(patches.len(), count);
        // every triangle: at least one cell, each of at least one patch,
        // and the patches of a triangle cover its area
        let layout = patches.layout();
        for t in 0..world.scene.triangles.len() as u32 {
            let m = layout.m[t as usize] as usize;
            assert!(m >= 1, "triangle {t} has no cell");
            let c0 = layout.cell0[t as usize] as usize;
            let area: f64 = (c0..c0 + m * m)
                .map(|c| {
                    assert!(layout.k[c] >= 1, "cell {c} of triangle {t} has no patch");
                    patches
                        .cell_patches(c)
                        .map(|i| patches.p[i].area as f64)
                        .sum::<f64>()
                })
                .sum();
            let a = world.scene.tri_area(t) as f64;
            assert!(
                (area - a).abs() <= 1e-4 * a,
                "triangle {t}: {area} against {a}"
            );
        }
    }
}

/// `locate` finds, for any point of a triangle, a patch of that triangle
/// whose corners, weighted by the returned barycentrics, give the point
/// back: on the projected layout's cells of different k, and on the area
/// layout.
#[test]
fn locate_on_cells() {
    let world = World::new(corridor());
    let edge = edge_for_count(&world.scene, 3000);
    let (layout, _) = budget::projected(&world, edge, true);
    assert!(layout.m[0] > 1, "the floor is cut into cells");
    let ks: std::collections::BTreeSet<u16> = layout.k.iter().copied().collect();
    assert!(ks.len() > 2, "cells of several subdivisions: {ks:?}");
    let projected = Patches::with_layout(&world.scene, &world.lights, layout, edge);
    let area = Patches::build(&world.scene, &world.lights, edge);
    let size = 32.0f32;
    for patches in [&projected, &area] {
        let mut rng = Pcg32::keyed(&[3, 0xB0D6]);
        for k in 0..4000 {
            let t = (k % 2) as u32;
            let u = rng.next_2d();
            let (b1, b2) = if u.x + u.y > 1.0 {
                (1.0 - u.x, 1.0 - u.y)
            } else {
                (u.x, u.y)
            };
            let [a, b, c] = world.scene.tri_vertices(t);
            let x = a + (b - a) * b1 + (c - a) * b2;
            let (i, w) = patches.locate(t, b1, b2);
            let v = patches.p[i as usize].v;
            let y = v[0] * w.x + v[1] * w.y + v[2] * w.z;
            assert!(
                (x - y).length() < 1e-4 * size,
                "triangle {t} at ({b1}, {b2}): patch {i} gives {y}, not {x}"
            );
        }
    }
}

/// The projected budget puts more patches per unit area on the near part
/// of the floor than on the far part; the area budget, uniform, does not
/// (this test fails on it).
#[test]
fn projected_is_finer_near_the_camera() {
    let world = World::new(corridor());
    let edge = edge_for_count(&world.scene, 3000);
    let (layout, _) = budget::projected(&world, edge, true);
    let projected = Patches::with_layout(&world.scene, &world.lights, layout, edge);
    let area = Patches::build(&world.scene, &world.lights, edge);
    let (pn, pf) = near_far_density(&projected);
    let (an, af) = near_far_density(&area);
    // the area budget is uniform: the same density near and far
    assert!((an / af - 1.0).abs() < 0.01, "area: near {an}, far {af}");
    // the projected one is at least twice as dense near (the footprint per
    // unit area differs by far more than that here)
    assert!(pn > 2.0 * pf, "projected: near {pn}, far {pf}");
}

/// The default is the paper's area budget, in the paper's form and ours.
#[test]
fn default_budget_is_area() {
    use kalos::methods::bundle::{PatchBudget, Settings};
    assert_eq!(Settings::default().budget, PatchBudget::Area);
}

/// `--patches n` gives at most `n` patches, and as many as the uniform mesh
/// can come to: a slightly shorter edge would pass `n`. On cbox the old
/// rescaling gave 5,012 patches for 5,000. A scene of more triangles than
/// `n` keeps one patch per triangle.
#[test]
fn area_count_is_at_most_the_target_and_closest() {
    let cbox = scene::load(&root().join("scenes/cbox/cbox.xml")).expect("cbox");
    for n in [100, 500, 5000, 20_000] {
        let edge = edge_for_count(&cbox, n);
        let count = Layout::area(&cbox, edge).patch_count();
        let finer = Layout::area(&cbox, edge * (1.0 - 1e-4)).patch_count();
        assert!(
            count <= n && finer > n,
            "cbox, target {n}: {count} patches at edge {edge}, {finer} at a slightly shorter edge"
        );
    }
    let triangles = cbox.triangles.len();
    let edge = edge_for_count(&cbox, triangles / 2);
    assert_eq!(Layout::area(&cbox, edge).patch_count(), triangles);
}

/// The patches meshed in parallel runs of triangles are those of one
/// sequential pass, bit for bit and in the same order, whatever the run
/// length; their shared corners are numbered in order of first use, and
/// two corners share a number only where they coincide. On cbox's area and
/// projected layouts (cells of several k), and on the corridor's.
#[test]
fn layout_in_parallel_runs_is_the_sequential_one() {
    let cbox = scene::load(&root().join("scenes/cbox/cbox.xml")).expect("cbox");
    for (name, world) in [
        ("cbox", World::new(cbox)),
        ("corridor", World::new(corridor())),
    ] {
        let nt = world.scene.triangles.len();
        let edge = edge_for_count(&world.scene, 5000);
        let (projected, _) = budget::projected(&world, edge, true);
        for layout in [Layout::area(&world.scene, edge), projected] {
            let build = |chunk: usize| {
                Patches::with_layout_in(&world.scene, &world.lights, layout.clone(), edge, chunk)
            };
            // one run of every triangle: the sequential pass
            let one = build(nt);
            let size = {
                let (lo, hi) = world.scene.bounds();
                (hi - lo).max_element()
            };
            for chunk in [1, 3, 64] {
                let runs = build(chunk);
                assert_eq!(runs.len(), one.len(), "{name}, runs of {chunk}");
                for (i, (a, b)) in runs.p.iter().zip(&one.p).enumerate() {
                    // Debug prints each float's shortest round-trip form:
                    // equal strings, equal bits
                    assert_eq!(
                        format!("{a:?}"),
                        format!("{b:?}"),
                        "{name}, runs of {chunk}: patch {i}"
                    );
                }
                assert_eq!(runs.vid, one.vid, "{name}, runs of {chunk}");
                assert_eq!(runs.vertex_count, one.vertex_count);
                for c in 0..layout.cell_count() {
                    assert_eq!(runs.cell_patches(c), one.cell_patches(c));
                }
            }
            // first use order: each corner's number is at most one past the
            // largest before it; shared numbers are coinciding corners
            let mut next = 0u32;
            let mut at = vec![None; one.vertex_count];
            for (i, ids) in one.vid.iter().enumerate() {
                for (k, &id) in ids.iter().enumerate() {
                    assert!(id <= next, "{name}: corner {k} of patch {i} numbered {id}");
                    next = next.max(id + 1);
                    let x = one.p[i].v[k];
                    let first = *at[id as usize].get_or_insert(x);
                    assert!(
                        (first - x).length() <= 1e-4 * size,
                        "{name}: vertex {id} at {first} and at {x}"
                    );
                }
            }
            assert_eq!(next as usize, one.vertex_count);
        }
    }
}
