//! Phase 3, decimation of the illumination mesh (§4.3).
//!
//! The 2D over-mesh of a surface becomes a 3D height field: x, y are the
//! chart coordinates scaled so that the smallest important feature (taken to
//! be the kernel width h: narrower detail is not in the estimate) has width
//! ε, and z is Stevens-law brightness z = (R·H/π / w0)^(1/3) (luminance),
//! clamped at 1. Vertices are removed in the order of a priority queue keyed
//! by Schroeder's curvature measure (distance to the average plane of the
//! ring for interior vertices, distance to the boundary line for boundary
//! vertices), and the hole is re-triangulated by ear clipping in the chart.
//!
//! Constraints, checked before a removal is committed:
//! - height field: every new triangle is counter-clockwise with positive
//!   area in the chart (no overhanging ledges, no fold-over);
//! - the chart boundary is kept: a boundary vertex goes only when it is
//!   collinear with its two boundary neighbours (corners stay);
//! - the error bound: every removed vertex (this one and those removed
//!   before inside the hole) must stay within ε in z of the new piecewise-
//!   linear surface. Removed vertices are carried by the triangle that
//!   contains them, so the bound holds for the final mesh at every vertex of
//!   the over-mesh, not just at removal time.

use std::cmp::Reverse;
use std::collections::{BinaryHeap, HashMap};
use std::f32::consts::PI;

use glam::{Vec2, Vec3};

use super::kernel::barycentric;
use super::mesh::PlanarMesh;
use crate::scene::luminance;

/// What a decimation did.
#[derive(Clone, Copy, Debug, Default)]
pub struct Report {
    /// Vertices removed.
    pub removed: u64,
    /// Triangles before.
    pub tris_before: u64,
    /// Triangles after.
    pub tris_after: u64,
    /// Largest |Δz| at a removed vertex against the final mesh.
    pub max_error: f32,
    /// Sum of |Δz| over removed vertices.
    pub sum_error: f64,
}

/// Stevens-law brightness of irradiance `h` on reflectance `r`, white point `w0`.
#[inline]
pub fn brightness(h: Vec3, r: Vec3, w0: f32) -> f32 {
    (luminance(r * h / PI).max(0.0) / w0).cbrt().min(1.0)
}

struct Work {
    p: Vec<Vec3>,
    tris: Vec<[u32; 3]>,
    alive: Vec<bool>,
    vtris: Vec<Vec<u32>>,
    removed_v: Vec<bool>,
    carried: Vec<Vec<u32>>,
    version: Vec<u32>,
}

/// The ordered ring of `v`: neighbours counter-clockwise, and whether it is
/// open (a boundary vertex). None when the neighbourhood is not a disc or half-disc.
fn ring(w: &Work, v: u32) -> Option<(Vec<u32>, bool)> {
    let mut next: HashMap<u32, u32> = HashMap::new();
    for &t in &w.vtris[v as usize] {
        let tri = w.tris[t as usize];
        let k = tri.iter().position(|&x| x == v)?;
        let (x, y) = (tri[(k + 1) % 3], tri[(k + 2) % 3]);
        if next.insert(x, y).is_some() {
            return None;
        }
    }
    let values: std::collections::HashSet<u32> = next.values().copied().collect();
    let starts: Vec<u32> = next
        .keys()
        .copied()
        .filter(|k| !values.contains(k))
        .collect();
    let open = match starts.len() {
        0 => false,
        1 => true,
        _ => return None,
    };
    let first = if open { starts[0] } else { *next.keys().min()? };
    let mut out = vec![first];
    let mut cur = first;
    while let Some(&n) = next.get(&cur) {
        if n == first {
            break;
        }
        if out.len() > next.len() {
            return None;
        }
        out.push(n);
        cur = n;
    }
    let expected = if open { next.len() + 1 } else { next.len() };
    (out.len() == expected).then_some((out, open))
}

/// Schroeder's decimation criterion for `v`, or None when `v` must stay.
fn cost(w: &Work, v: u32) -> Option<f32> {
    let (r, open) = ring(w, v)?;
    let p = w.p[v as usize];
    if open {
        let (s, e) = (w.p[r[0] as usize], w.p[*r.last()? as usize]);
        let (s2, e2, p2) = (s.truncate(), e.truncate(), p.truncate());
        let d = e2 - s2;
        let len = d.length();
        if len <= 0.0 || (p2 - s2).perp_dot(d).abs() > 1e-5 * len * len {
            return None; // a corner of the boundary
        }
        let dir = (e - s).normalize_or_zero();
        let q = p - s;
        return Some((q - dir * q.dot(dir)).length());
    }
    // distance to the average plane of the ring's triangles
    let mut n = Vec3::ZERO;
    let mut c = Vec3::ZERO;
    let mut a_sum = 0.0;
    for &t in &w.vtris[v as usize] {
        let [a, b, cc] = w.tris[t as usize].map(|i| w.p[i as usize]);
        let nn = (b - a).cross(cc - a);
        let area = nn.length() * 0.5;
        n += nn;
        c += (a + b + cc) / 3.0 * area;
        a_sum += area;
    }
    let n = n.normalize_or_zero();
    if a_sum <= 0.0 || n == Vec3::ZERO {
        return None;
    }
    Some((p - c / a_sum).dot(n).abs())
}

/// Ear clipping of the counter-clockwise polygon `poly` (chart positions),
/// taking at each step the ear whose smallest angle is largest.
fn triangulate(poly: &[u32], pos: &[Vec3]) -> Option<Vec<[u32; 3]>> {
    if poly.len() < 3 {
        return None;
    }
    let mut idx: Vec<u32> = poly.to_vec();
    let mut out = Vec::with_capacity(poly.len().saturating_sub(2));
    let p2 = |i: u32| pos[i as usize].truncate();
    while idx.len() > 3 {
        let n = idx.len();
        let mut best: Option<(f32, usize)> = None;
        for k in 0..n {
            let (a, b, c) = (idx[(k + n - 1) % n], idx[k], idx[(k + 1) % n]);
            let (pa, pb, pc) = (p2(a), p2(b), p2(c));
            let area = (pb - pa).perp_dot(pc - pa);
            let scale = (pb - pa)
                .length_squared()
                .max((pc - pb).length_squared())
                .max((pa - pc).length_squared());
            if area <= 1e-7 * scale {
                continue;
            }
            let blocked = idx.iter().any(|&o| {
                o != a && o != b && o != c && barycentric(pa, pb, pc, p2(o)).min_element() >= -1e-7
            });
            if blocked {
                continue;
            }
            let q = min_angle(pa, pb, pc);
            if best.is_none_or(|x| q > x.0) {
                best = Some((q, k));
            }
        }
        let (_, k) = best?;
        let n = idx.len();
        out.push([idx[(k + n - 1) % n], idx[k], idx[(k + 1) % n]]);
        idx.remove(k);
    }
    let (pa, pb, pc) = (p2(idx[0]), p2(idx[1]), p2(idx[2]));
    let scale = (pb - pa)
        .length_squared()
        .max((pc - pb).length_squared())
        .max((pa - pc).length_squared());
    if (pb - pa).perp_dot(pc - pa) <= 1e-7 * scale {
        return None;
    }
    out.push([idx[0], idx[1], idx[2]]);
    Some(out)
}

fn min_angle(a: Vec2, b: Vec2, c: Vec2) -> f32 {
    let ang =
        |p: Vec2, q: Vec2, r: Vec2| (q - p).normalize_or_zero().dot((r - p).normalize_or_zero());
    // the largest cosine is the smallest angle; return −cos so larger is better
    -ang(a, b, c).max(ang(b, c, a)).max(ang(c, a, b))
}

/// Where a removed vertex sits among `new` triangles: (triangle, |Δz|).
fn place(pos: &[Vec3], new: &[[u32; 3]], q: Vec3) -> Option<(usize, f32)> {
    let mut best: Option<(f32, usize, Vec3)> = None;
    for (i, t) in new.iter().enumerate() {
        let [a, b, c] = t.map(|k| pos[k as usize]);
        let bc = barycentric(a.truncate(), b.truncate(), c.truncate(), q.truncate());
        let m = bc.min_element();
        if best.is_none_or(|x| m > x.0) {
            best = Some((m, i, bc));
        }
    }
    let (m, i, bc) = best?;
    if m < -1e-4 {
        return None;
    }
    let [a, b, c] = new[i].map(|k| pos[k as usize]);
    let bc = bc.max(Vec3::ZERO);
    let bc = bc / bc.element_sum().max(1e-12);
    Some((i, (a.z * bc.x + b.z * bc.y + c.z * bc.z - q.z).abs()))
}

/// Decimates one surface's mesh. `r` is the reflectance R(x, y) at each
/// vertex (one value: the same everywhere), `w0` the white point, `eps` the
/// error bound. Keeps the vertices' irradiance.
pub fn decimate_planar(m: PlanarMesh, r: &[Vec3], w0: f32, eps: f32) -> (PlanarMesh, Report) {
    let mut report = Report {
        tris_before: m.tris.len() as u64,
        ..Default::default()
    };
    let mut w = height_field(&m, r, w0, eps);

    // The priority queue of §4.3, smallest curvature change first
    let mut heap = BinaryHeap::new();
    for v in 0..w.p.len() as u32 {
        enqueue(&mut heap, &w, v, 0, eps);
    }
    while let Some(Reverse((_, v, ver))) = heap.pop() {
        if w.removed_v[v as usize] || w.version[v as usize] != ver {
            continue;
        }
        let Some(ring_v) = remove_vertex(&mut w, v, eps) else {
            continue;
        };
        // The ring's costs changed: queue them again, the old entries stale
        for &x in &ring_v {
            w.version[x as usize] += 1;
            enqueue(&mut heap, &w, x, w.version[x as usize], eps);
        }
    }

    let mesh = compact(m, &w, &mut report);
    (mesh, report)
}

/// The priority queue of the decimation: (cost bits, vertex, version),
/// smallest cost first.
type Queue = BinaryHeap<Reverse<(u32, u32, u32)>>;

/// Queues `v` at its current `version` if its cost is within `eps`.
fn enqueue(heap: &mut Queue, w: &Work, v: u32, version: u32, eps: f32) {
    if let Some(c) = cost(w, v) {
        if c <= eps {
            heap.push(Reverse((c.to_bits(), v, version)));
        }
    }
}

/// The over-mesh `m` as the height field of §4.3: chart coordinates scaled
/// so that the smallest feature (the kernel width h) is `eps` wide, z the
/// brightness of each vertex on reflectance `r` for white point `w0`.
fn height_field(m: &PlanarMesh, r: &[Vec3], w0: f32, eps: f32) -> Work {
    let (lo, hi) = m.verts.iter().fold(
        (Vec2::splat(f32::INFINITY), Vec2::splat(f32::NEG_INFINITY)),
        |(a, b), v| (a.min(*v), b.max(*v)),
    );
    let feature = if m.bandwidth > 0.0 {
        m.bandwidth
    } else {
        (hi - lo).max_element().max(1e-9)
    };
    let s = eps.max(1e-9) / feature;
    let r_at = |i: usize| if r.len() == 1 { r[0] } else { r[i] };
    let z: Vec<f32> =
        m.h.iter()
            .enumerate()
            .map(|(i, h)| brightness(*h, r_at(i), w0))
            .collect();
    let p: Vec<Vec3> = m
        .verts
        .iter()
        .zip(&z)
        .map(|(v, z)| (*v * s).extend(*z))
        .collect();
    let nv = p.len();
    let mut vtris = vec![Vec::new(); nv];
    for (t, tri) in m.tris.iter().enumerate() {
        for &v in tri {
            vtris[v as usize].push(t as u32);
        }
    }
    Work {
        p,
        alive: vec![true; m.tris.len()],
        carried: vec![Vec::new(); m.tris.len()],
        tris: m.tris.clone(),
        vtris,
        removed_v: vec![false; nv],
        version: vec![0; nv],
    }
}

/// Removes `v` if its hole re-triangulates and every removed vertex the
/// hole carries stays within `eps` of the new triangles; returns its ring.
fn remove_vertex(w: &mut Work, v: u32, eps: f32) -> Option<Vec<u32>> {
    let (ring_v, _open) = ring(w, v)?;
    let new = triangulate(&ring_v, &w.p)?;
    // height field: every new triangle counter-clockwise in the chart
    // (triangulate guarantees it); now the error bound
    let old: Vec<u32> = w.vtris[v as usize].clone();
    let mut pts: Vec<u32> = vec![v];
    for &t in &old {
        pts.extend_from_slice(&w.carried[t as usize]);
    }
    let mut assign = Vec::with_capacity(pts.len());
    for &q in &pts {
        match place(&w.p, &new, w.p[q as usize]) {
            Some((i, e)) if e <= eps => assign.push(i),
            _ => return None,
        }
    }

    // Commit: drop the old fan, add the new triangles
    for &t in &old {
        w.alive[t as usize] = false;
        w.carried[t as usize].clear();
        for &x in &w.tris[t as usize] {
            if x != v {
                w.vtris[x as usize].retain(|&y| y != t);
            }
        }
    }
    w.vtris[v as usize].clear();
    w.removed_v[v as usize] = true;
    let base = w.tris.len() as u32;
    for (i, t) in new.iter().enumerate() {
        w.tris.push(*t);
        w.alive.push(true);
        w.carried.push(Vec::new());
        for &x in t {
            w.vtris[x as usize].push(base + i as u32);
        }
    }
    for (q, i) in pts.into_iter().zip(assign) {
        w.carried[base as usize + i].push(q);
    }
    Some(ring_v)
}

/// The decimated mesh: the kept vertices (with their irradiance) and the
/// live triangles, renumbered; the error at every removed vertex against
/// the triangle that carries it, and the triangle count, go into `report`.
fn compact(m: PlanarMesh, w: &Work, report: &mut Report) -> PlanarMesh {
    let mut map = vec![u32::MAX; w.p.len()];
    let mut verts = Vec::new();
    let mut h = Vec::new();
    for (v, slot) in map.iter_mut().enumerate() {
        if !w.removed_v[v] {
            *slot = verts.len() as u32;
            verts.push(m.verts[v]);
            h.push(m.h[v]);
        }
    }
    let mut tris = Vec::new();
    for (t, tri) in w.tris.iter().enumerate() {
        if !w.alive[t] {
            continue;
        }
        let [a, b, c] = tri.map(|i| w.p[i as usize]);
        for &q in &w.carried[t] {
            let bc = barycentric(
                a.truncate(),
                b.truncate(),
                c.truncate(),
                w.p[q as usize].truncate(),
            )
            .max(Vec3::ZERO);
            let bc = bc / bc.element_sum().max(1e-12);
            let e = (a.z * bc.x + b.z * bc.y + c.z * bc.z - w.p[q as usize].z).abs();
            report.max_error = report.max_error.max(e);
            report.sum_error += e as f64;
            report.removed += 1;
        }
        tris.push(tri.map(|i| map[i as usize]));
    }
    report.tris_after = tris.len() as u64;
    PlanarMesh::new(m.surface, verts, tris, h, m.bandwidth, m.hits)
}
