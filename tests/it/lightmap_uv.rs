//! The second uv set of lightmap bakes and the texels it gives: ranges,
//! overlaps with padding, texel density, the asset's own uv set kept or
//! refused, points on their triangles, dilation.

use std::path::PathBuf;

use glam::{Vec2, Vec3};
use kalos::bake::lightmap::raster::{self, chart_map, covered, dilate};
use kalos::bake::lightmap::uv::{lightmap_uv, UvError, UvOptions};
use kalos::bake::lightmap::{LightmapUv, UvSource};
use kalos::scene::{self, Scene};

fn repo(p: &str) -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join(p)
}

fn load(p: &str) -> Scene {
    scene::load(&repo(p)).unwrap_or_else(|e| panic!("{p}: {e}"))
}

fn cbox() -> Scene {
    load("scenes/cbox/cbox.xml")
}

fn size(n: u32) -> UvOptions {
    UvOptions {
        size: Some(n),
        ..UvOptions::default()
    }
}

/// Twice the area of a scene triangle.
fn world_area2(s: &Scene, t: [u32; 3]) -> f32 {
    let [a, b, c] = t.map(|v| s.positions[v as usize]);
    (b - a).cross(c - a).length()
}

/// The structure every uv set must have: one entry per shape, the shape's
/// triangles in order on vertices that copy the scene's, coordinates in
/// [0, 1].
fn check_structure(s: &Scene, uv: &LightmapUv) {
    assert_eq!(uv.shapes.len(), s.shapes.len());
    assert_eq!(uv.tri_chart.len(), s.triangles.len());
    for (shape, su) in s.shapes.iter().zip(&uv.shapes) {
        assert_eq!(su.triangles.len(), shape.tri_count as usize);
        assert_eq!(su.xref.len(), su.uv.len());
        for (k, t) in su.triangles.iter().enumerate() {
            let scene_tri = s.triangles[shape.first_tri as usize + k];
            for j in 0..3 {
                assert_eq!(su.xref[t[j] as usize], scene_tri[j], "{}", s.source);
            }
        }
        for p in &su.uv {
            assert!(
                (0.0..=1.0).contains(&p.x) && (0.0..=1.0).contains(&p.y),
                "{}: uv {p} outside [0, 1]",
                s.source
            );
        }
    }
}

/// Texels claimed by two charts when each chart claims every texel within
/// `pad` (Chebyshev distance) of a texel it touches, and touched texels
/// closer than `pad` to the atlas border.
fn padding_violations(s: &Scene, uv: &LightmapUv, pad: u32) -> (usize, usize) {
    let texels = raster::texels(s, uv);
    let charts = chart_map(uv, &texels);
    let (w, h) = (uv.width as i64, uv.height as i64);
    let mut claim = vec![u32::MAX; (w * h) as usize];
    let (mut clashes, mut border) = (0, 0);
    for t in &texels {
        let c = charts[(t.y * uv.width + t.x) as usize];
        let (x, y) = (t.x as i64, t.y as i64);
        let p = pad as i64;
        if x < p || y < p || x >= w - p || y >= h - p {
            border += 1;
        }
        for ny in (y - p).max(0)..(y + p + 1).min(h) {
            for nx in (x - p).max(0)..(x + p + 1).min(w) {
                let slot = &mut claim[(ny * w + nx) as usize];
                if *slot != u32::MAX && *slot != c {
                    clashes += 1;
                }
                *slot = c;
            }
        }
    }
    (clashes, border)
}

#[test]
fn generated_uv_is_in_range_and_charts_keep_their_padding() {
    for p in [
        "scenes/cbox/cbox.xml",
        "scenes/cornell-box-gltf/cornellBox-2.80-Eevee-gltf.gltf",
        "scenes/teapot-room/scene.xml",
    ] {
        let s = load(p);
        let uv = lightmap_uv(&s, None, &size(512)).unwrap();
        assert_eq!(uv.source, UvSource::Generated);
        charts_are_apart(p, &s, &uv);
    }
}

/// A 512² generated atlas of scene `p` holds every triangle, and no two
/// charts come within twice the padding (2 texels) nor a chart within the
/// padding of the border; and the check can fail: with a wider claim than
/// the packer's clearance (6 texels), neighbouring charts collide.
fn charts_are_apart(p: &str, s: &Scene, uv: &LightmapUv) {
    assert_eq!((uv.width, uv.height), (512, 512));
    assert!(uv.charts > 0);
    check_structure(s, uv);
    let (clashes, border) = padding_violations(s, uv, 2);
    assert_eq!(clashes, 0, "{p}: texels claimed by two charts");
    assert_eq!(
        border, 0,
        "{p}: charts closer than the padding to the border"
    );
    assert!(padding_violations(s, uv, 6).0 > 0, "{p}");
}

/// The rows packing (`--fast-packing`) keeps the same guarantees: every
/// triangle on the atlas, no two charts within twice the padding.
#[test]
fn fast_packing_keeps_the_charts_apart() {
    for p in ["scenes/cbox/cbox.xml", "scenes/teapot-room/scene.xml"] {
        let s = load(p);
        let opts = UvOptions {
            fast_packing: true,
            ..size(512)
        };
        let uv = lightmap_uv(&s, None, &opts).unwrap();
        charts_are_apart(p, &s, &uv);
    }
}

#[test]
fn generation_is_deterministic() {
    let s = load("scenes/teapot-room/scene.xml");
    let a = lightmap_uv(&s, None, &size(256)).unwrap();
    let b = lightmap_uv(&s, None, &size(256)).unwrap();
    for (x, y) in a.shapes.iter().zip(&b.shapes) {
        assert_eq!(x.xref, y.xref);
        assert_eq!(x.triangles, y.triangles);
        let bits = |v: &Vec<Vec2>| {
            v.iter()
                .map(|p| (p.x.to_bits(), p.y.to_bits()))
                .collect::<Vec<_>>()
        };
        assert_eq!(bits(&x.uv), bits(&y.uv));
    }
}

/// With a texel density D, a triangle of world area A covers A·D² texels of
/// uv area. cbox's charts are planar, so the unwrapper's flattening is an
/// isometry up to the scale D: the only error is f32 rounding of
/// coordinates of size ~300 texels (relative 1e-7, so 1e-5 on a sum), and
/// the test allows 1e-3. For the atlas side: it is the smallest multiple of
/// 4 holding the packed charts, so at least √(Σ A·D²) (charts cannot
/// overlap), and the padding and packing waste keep it within 2× that.
#[test]
fn texel_density_is_honoured() {
    let s = cbox();
    for d in [0.25f32, 0.5] {
        let opts = UvOptions {
            texel_density: Some(d),
            ..UvOptions::default()
        };
        let uv = lightmap_uv(&s, None, &opts).unwrap();
        check_structure(&s, &uv);
        assert_eq!(uv.width, uv.height);
        assert_eq!(uv.width % 4, 0);
        let side = uv.width as f32;
        let (mut world, mut texel) = (0.0f64, 0.0f64);
        for (shape, su) in s.shapes.iter().zip(&uv.shapes) {
            for (k, t) in su.triangles.iter().enumerate() {
                let [a, b, c] = t.map(|v| su.uv[v as usize] * side);
                let tw = 0.5 * world_area2(&s, s.triangles[shape.first_tri as usize + k]) as f64;
                let tt = 0.5 * (b - a).perp_dot(c - a).abs() as f64;
                // Per triangle too: planar charts are not distorted.
                assert!(
                    (tt - tw * (d * d) as f64).abs() <= 1e-3 * tw * (d * d) as f64 + 1e-3,
                    "density {d}: a triangle of {tw} units² has {tt} texels²"
                );
                world += tw;
                texel += tt;
            }
        }
        let want = world * (d * d) as f64;
        assert!(
            (texel / want - 1.0).abs() < 1e-3,
            "density {d}: {texel} texels² for {want}"
        );
        assert!(side as f64 >= want.sqrt() && (side as f64) < 2.0 * want.sqrt() + 16.0);
        // Texels a triangle touches, counted: at least the area.
        let n = raster::texels(&s, &uv).len() as f64;
        assert!(
            n >= want,
            "density {d}: {n} texels for {want} texels² of surface"
        );
    }
}

#[test]
fn a_density_whose_atlas_is_too_large_is_refused_with_its_size() {
    let s = cbox();
    let opts = UvOptions {
        texel_density: Some(1000.0),
        ..UvOptions::default()
    };
    match lightmap_uv(&s, None, &opts) {
        Err(UvError::TooLarge { side, .. }) => assert!(side > 16384, "{side}"),
        other => panic!("expected TooLarge, got {:?}", other.map(|u| u.width)),
    }
    let both = UvOptions {
        texel_density: Some(1.0),
        size: Some(256),
        ..UvOptions::default()
    };
    assert!(matches!(
        lightmap_uv(&s, None, &both),
        Err(UvError::Options(_))
    ));
}

/// cbox with every triangle on its own three vertices (so that any uv1 can
/// be given), and a uv1 that the
/// generator made for it (valid by construction).
fn unshared_with_uv1() -> (Scene, Vec<Vec2>) {
    let mut s = cbox();
    let uv = lightmap_uv(&s, None, &size(256)).unwrap();
    let mut positions = Vec::new();
    let mut uv1 = Vec::new();
    let mut triangles = Vec::new();
    for su in &uv.shapes {
        for t in &su.triangles {
            let base = positions.len() as u32;
            positions.extend(t.map(|v| s.positions[su.xref[v as usize] as usize]));
            uv1.extend(t.map(|v| su.uv[v as usize]));
            triangles.push([base, base + 1, base + 2]);
        }
    }
    s.normals = vec![Vec3::Z; positions.len()];
    s.uvs = vec![Vec2::ZERO; positions.len()];
    s.positions = positions;
    s.triangles = triangles;
    (s, uv1)
}

#[test]
fn a_valid_asset_uv1_is_kept_bit_for_bit() {
    let (s, uv1) = unshared_with_uv1();
    let uv = lightmap_uv(&s, Some(&uv1), &size(256)).unwrap();
    assert_eq!(uv.source, UvSource::Asset);
    assert!(uv.warnings.is_empty(), "{:?}", uv.warnings);
    check_structure(&s, &uv);
    for su in &uv.shapes {
        for (k, &v) in su.xref.iter().enumerate() {
            assert_eq!(su.uv[k].x.to_bits(), uv1[v as usize].x.to_bits());
            assert_eq!(su.uv[k].y.to_bits(), uv1[v as usize].y.to_bits());
        }
    }
    // Charts: the generator's, found again from shared coordinates.
    let generated = lightmap_uv(&s, None, &size(256)).unwrap();
    assert_eq!(uv.charts, generated.charts);
}

#[test]
fn an_overlapping_or_out_of_range_uv1_warns_and_is_replaced() {
    let (s, good) = unshared_with_uv1();
    // Every triangle on the same uv triangle: all overlap.
    let corners = [
        Vec2::new(0.1, 0.1),
        Vec2::new(0.9, 0.1),
        Vec2::new(0.1, 0.9),
    ];
    let mut stacked = vec![Vec2::ZERO; s.positions.len()];
    for t in &s.triangles {
        for j in 0..3 {
            stacked[t[j] as usize] = corners[j];
        }
    }
    // One vertex out of [0, 1].
    let mut outside = good.clone();
    outside[s.triangles[3][1] as usize].x += 1.0;
    // One triangle moved onto another: a single overlap.
    let mut one = good.clone();
    let (t0, t1) = (s.triangles[0], s.triangles[s.triangles.len() - 1]);
    for j in 0..3 {
        one[t1[j] as usize] = good[t0[j] as usize];
    }
    for (name, uv1, why) in [
        ("stacked", stacked, "overlap"),
        ("outside", outside, "outside"),
        ("one", one, "overlap"),
    ] {
        let uv = lightmap_uv(&s, Some(&uv1), &size(256)).unwrap();
        assert_eq!(uv.source, UvSource::Generated, "{name}");
        assert_eq!(uv.warnings.len(), 1, "{name}: {:?}", uv.warnings);
        assert!(uv.warnings[0].contains(why), "{name}: {:?}", uv.warnings);
        check_structure(&s, &uv);
    }
}

#[test]
fn degenerate_triangles_are_counted_and_harmless() {
    let mut s = cbox();
    // Two degenerate triangles at the end of the last shape: a repeated
    // vertex and three collinear points.
    let t = s.triangles[s.triangles.len() - 1];
    let (a, b) = (s.positions[t[0] as usize], s.positions[t[1] as usize]);
    let n = s.positions.len() as u32;
    s.positions.extend([a, b, 0.5 * (a + b)]);
    s.normals.extend([Vec3::Z; 3]);
    s.uvs.extend([Vec2::ZERO; 3]);
    s.triangles.push([t[0], t[0], t[1]]);
    s.triangles.push([n, n + 1, n + 2]);
    let last = s.shapes.len() - 1;
    s.shapes[last].tri_count += 2;
    s.tri_shape.extend([last as u32; 2]);
    let uv = lightmap_uv(&s, None, &size(256)).unwrap();
    check_structure(&s, &uv);
    assert_eq!(uv.warnings.len(), 1, "{:?}", uv.warnings);
    assert!(uv.warnings[0].contains("2 degenerate"), "{:?}", uv.warnings);
    let nt = s.triangles.len();
    assert_eq!(&uv.tri_chart[nt - 2..], &[u32::MAX, u32::MAX]);
    let texels = raster::texels(&s, &uv);
    assert!(texels.iter().all(|t| (t.tri as usize) < nt - 2));
    assert!(texels.iter().all(|t| t.p.is_finite() && t.n.is_finite()));
}

#[test]
fn texels_lie_on_their_triangles_once_each() {
    for p in ["scenes/cbox/cbox.xml", "scenes/teapot-room/scene.xml"] {
        let s = load(p);
        let uv = lightmap_uv(&s, None, &size(256)).unwrap();
        let texels = raster::texels(&s, &uv);
        assert!(!texels.is_empty());
        let extent = s
            .positions
            .iter()
            .fold(0.0f32, |m, p| m.max(p.abs().max_element()));
        let mut seen = vec![false; (uv.width * uv.height) as usize];
        let mut on_edge = 0;
        for t in &texels {
            let i = (t.y * uv.width + t.x) as usize;
            assert!(!seen[i], "{p}: texel ({}, {}) twice", t.x, t.y);
            seen[i] = true;
            let [a, b, c] = s.triangles[t.tri as usize].map(|v| s.positions[v as usize]);
            let n = (b - a).cross(c - a).normalize();
            assert!((t.n - n).length() < 1e-5, "{p}: normal {} for {n}", t.n);
            // In the plane, and inside the three edges (with f32 slack
            // relative to the scene's size).
            let eps = 1e-5 * extent;
            assert!((t.p - a).dot(n).abs() <= eps, "{p}: off the plane");
            for (e0, e1) in [(a, b), (b, c), (c, a)] {
                assert!(
                    (e1 - e0).cross(t.p - e0).dot(n) >= -eps * (e1 - e0).length(),
                    "{p}"
                );
            }
            // Is the texel's centre inside its triangle in uv? Then p is
            // strictly the surface point under it; else p is on an edge.
            let shape = s.tri_shape[t.tri as usize] as usize;
            let su = &uv.shapes[shape];
            let k = t.tri as usize - s.shapes[shape].first_tri as usize;
            let q = su.triangles[k].map(|v| su.uv[v as usize] * uv.width as f32);
            let centre = Vec2::new(t.x as f32 + 0.5, t.y as f32 + 0.5);
            let sgn = (q[1] - q[0]).perp_dot(q[2] - q[0]).signum();
            let inside =
                (0..3).all(|j| sgn * (q[(j + 1) % 3] - q[j]).perp_dot(centre - q[j]) >= 0.0);
            if !inside {
                on_edge += 1;
            }
        }
        // Conservative: more texels than centres covered, and every texel
        // whose centre a triangle contains is there.
        assert!(on_edge > 0, "{p}");
        for (shape, su) in s.shapes.iter().zip(&uv.shapes).take(3) {
            for t in su.triangles.iter().take(50) {
                let q = t.map(|v| su.uv[v as usize] * uv.width as f32);
                let c = (q[0] + q[1] + q[2]) / 3.0;
                let i = (c.y as u32 * uv.width + c.x as u32) as usize;
                assert!(
                    seen[i],
                    "{p}: {}: a triangle's centroid texel is missing",
                    shape.name
                );
            }
        }
        assert_eq!(
            covered(&uv, &texels).iter().filter(|&&c| c).count(),
            texels.len()
        );
    }
}

#[test]
fn dilation_fills_rings_around_charts_and_no_further() {
    let (w, h) = (9u32, 7u32);
    let mut values = vec![Vec3::ZERO; (w * h) as usize];
    let mut cov = vec![false; (w * h) as usize];
    let centre = (3 * w + 4) as usize;
    values[centre] = Vec3::new(1.0, 2.0, 3.0);
    cov[centre] = true;
    // A second covered texel in the corner, of another value.
    values[0] = Vec3::splat(4.0);
    cov[0] = true;
    dilate(&mut values, &cov, w, h, 2);
    for y in 0..h as i32 {
        for x in 0..w as i32 {
            let v = values[(y as u32 * w + x as u32) as usize];
            let d_centre = (x - 4).abs().max((y - 3).abs());
            let d_corner = x.max(y);
            if d_centre <= 2 && d_corner > 2 {
                assert_eq!(v, Vec3::new(1.0, 2.0, 3.0), "({x}, {y})");
            } else if d_corner <= 2 && d_centre > 2 {
                assert_eq!(v, Vec3::splat(4.0), "({x}, {y})");
            } else if d_centre > 2 && d_corner > 2 {
                assert_eq!(v, Vec3::ZERO, "({x}, {y}) beyond two rings");
            }
        }
    }
}
