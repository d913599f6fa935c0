//! Worker 0's side of the last round: the meshes on the wire, and the
//! bake assembled from every worker's part.

use super::{CurvedWire, PartWire, PlanarWire};
use crate::methods::density::decimate::Report;
use crate::methods::density::hits::HIT_BYTES;
use crate::methods::density::mesh::{CurvedMesh, DisplayMesh, PlanarMesh};
use crate::methods::density::pipeline::Decimated;
use crate::methods::density::surfaces::{SurfaceId, Surfaces};
use crate::methods::density::{Bake, BakeStats, Settings, WorkerLoad};

pub(super) fn to_wire_planar(planar: Vec<PlanarMesh>, reports: Vec<Report>) -> Vec<PlanarWire> {
    planar
        .into_iter()
        .zip(reports)
        .map(|(m, r)| {
            (
                m.surface.encode(),
                m.verts.iter().flat_map(|v| [v.x, v.y]).collect(),
                m.tris,
                m.h.iter().flat_map(|h| [h.x, h.y, h.z]).collect(),
                m.bandwidth,
                m.hits,
                r.max_error,
                r.sum_error,
                r.removed,
            )
        })
        .collect()
}

pub(super) fn to_wire_curved(curved: Vec<CurvedMesh>) -> Vec<CurvedWire> {
    curved
        .into_iter()
        .map(|m| {
            let h = m.h.iter().flatten().flat_map(|h| [h.x, h.y, h.z]).collect();
            (m.shape, m.back, m.tris, h)
        })
        .collect()
}

/// Worker 0: the bake from every worker's part, in the order of the
/// single-process bake (planar meshes by surface side, curved ones by shape
/// and side; the error statistics summed in that order).
pub(super) fn assemble(surfaces: &Surfaces, s: &Settings, w0: f32, parts: Vec<PartWire>) -> Bake {
    use glam::{Vec2, Vec3};
    let mut stats = BakeStats {
        bytes_per_hit: HIT_BYTES,
        surfaces: surfaces.list.len(),
        ..Default::default()
    };
    let mut planar: Vec<(PlanarMesh, Report)> = Vec::new();
    let mut curved: Vec<CurvedMesh> = Vec::new();
    for (_, _, f, wp, wc) in parts {
        stats.hits += f.0;
        stats.rays += f.1;
        stats.tris_before += f.2;
        stats.max_sort_records = stats.max_sort_records.max(f.3);
        stats.max_hits_in_memory = stats.max_hits_in_memory.max(f.4);
        stats.workers.push(WorkerLoad {
            hits: f.5,
            verts: f.6,
            halo: f.7,
        });
        for (id, v, tris, h, bw, hits, max_e, sum_e, removed) in wp {
            let verts = v.chunks_exact(2).map(|c| Vec2::new(c[0], c[1])).collect();
            let h = h
                .chunks_exact(3)
                .map(|c| Vec3::new(c[0], c[1], c[2]))
                .collect();
            let m = PlanarMesh::unindexed(SurfaceId::decode(id), verts, tris, h, bw, hits);
            planar.push((
                m,
                Report {
                    max_error: max_e,
                    sum_error: sum_e,
                    removed,
                    ..Report::default()
                },
            ));
        }
        for (shape, back, tris, h) in wc {
            let h = h
                .chunks_exact(9)
                .map(|c| {
                    [
                        Vec3::new(c[0], c[1], c[2]),
                        Vec3::new(c[3], c[4], c[5]),
                        Vec3::new(c[6], c[7], c[8]),
                    ]
                })
                .collect();
            curved.push(CurvedMesh {
                shape,
                back,
                tris,
                h,
            });
        }
    }
    planar.sort_by_key(|p| p.0.surface);
    let (planar, reports): (Vec<PlanarMesh>, Vec<Report>) = planar.into_iter().unzip();
    curved.sort_by_key(|m| (m.shape, m.back));
    if s.decimate {
        let d = Decimated::of(&reports);
        stats.max_brightness_error = d.max_error;
        stats.mean_brightness_error = d.mean_error;
    }
    stats.hit_file_bytes = stats.hits * HIT_BYTES as u64;
    let mesh = DisplayMesh::new(planar, curved);
    stats.tris_after = mesh.triangle_count();
    Bake {
        surfaces: surfaces.clone(),
        mesh,
        w0,
        stats,
    }
}
