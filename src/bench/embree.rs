//! Embree 3 as a second ray core for the replay benchmark (cargo feature
//! `embree`, which links the system's `libembree3`; benchmark only, never
//! needed by the default build). The scene's triangles go into one Embree
//! triangle mesh in scene order, so that Embree's primitive id is kalos's
//! triangle index and the answers can be compared ray by ray.
//!
//! Two forms are measured: one ray at a time (`rtcIntersect1` and
//! `rtcOccluded1`, the incoherent context, as kalos traces), and, for the
//! coherent camera rays, a stream of each task's batch (`rtcIntersect1M`
//! with the coherent context), which Embree traces as packets.

use embree::{CommittedScene, Device, Geometry, IntersectContext, RayHit, TriangleMesh};

use super::rayset::SetKind;
use super::replay::{Answer, Tracer};
use crate::geometry::Ray;
use crate::scene::Scene;

/// Embree answering through one scene, one ray at a time or as streams.
pub struct EmbreeTracer<'a> {
    scene: &'a CommittedScene<'a>,
    stream: bool,
}

impl Tracer for EmbreeTracer<'_> {
    fn name(&self) -> &str {
        if self.stream {
            "Embree stream"
        } else {
            "Embree"
        }
    }

    fn closest(&self, rays: &[Ray], out: &mut [Answer]) {
        if self.stream {
            let mut ctx = IntersectContext::coherent();
            let mut batch: Vec<RayHit> = rays.iter().map(|r| RayHit::new(ray(r))).collect();
            self.scene.intersect_stream_aos(&mut ctx, &mut batch);
            for (h, o) in batch.iter().zip(out) {
                *o = answer(h);
            }
        } else {
            let mut ctx = IntersectContext::incoherent();
            for (r, o) in rays.iter().zip(out) {
                let mut h = RayHit::new(ray(r));
                self.scene.intersect(&mut ctx, &mut h);
                *o = answer(&h);
            }
        }
    }

    fn occluded(&self, rays: &[Ray], out: &mut [bool]) {
        let mut ctx = IntersectContext::incoherent();
        for (r, o) in rays.iter().zip(out) {
            let mut e = ray(r);
            self.scene.occluded(&mut ctx, &mut e);
            // Embree marks an occluded ray by setting tfar to −∞
            *o = e.tfar == f32::NEG_INFINITY;
        }
    }

    fn traces(&self, kind: SetKind) -> bool {
        !self.stream || kind == SetKind::Camera
    }
}

/// The Embree ray for `r`.
fn ray(r: &Ray) -> embree::Ray {
    embree::Ray {
        org_x: r.o.x,
        org_y: r.o.y,
        org_z: r.o.z,
        dir_x: r.d.x,
        dir_y: r.d.y,
        dir_z: r.d.z,
        tnear: r.tmin,
        tfar: r.tmax,
        time: 0.0,
        mask: u32::MAX,
        id: 0,
        flags: 0,
    }
}

fn answer(h: &RayHit) -> Answer {
    if h.hit.hit() {
        Answer {
            tri: h.hit.primID,
            t: h.ray.tfar,
        }
    } else {
        Answer::MISS
    }
}

/// Builds Embree's BVH over `scene`'s triangles (Embree's default build
/// quality, on Embree's own threads) and calls `f` with the one-ray and the
/// stream tracer, and the build time in seconds. With `verbose`, Embree
/// prints its own log, which includes its BVH's statistics (nodes, leaves,
/// SAH cost) after the build; its build time then includes the printing.
pub fn with_tracers<R>(
    scene: &Scene,
    verbose: bool,
    f: impl FnOnce(&EmbreeTracer<'_>, &EmbreeTracer<'_>, f64) -> R,
) -> R {
    let start = std::time::Instant::now();
    let device = if verbose {
        Device::debug()
    } else {
        Device::new()
    };
    let mut mesh = TriangleMesh::unanimated(&device, scene.triangles.len(), scene.positions.len());
    {
        let mut v = mesh.vertex_buffer.map();
        for (i, p) in scene.positions.iter().enumerate() {
            v[i] = [p.x, p.y, p.z, 0.0].into();
        }
    }
    {
        let mut t = mesh.index_buffer.map();
        for (i, tri) in scene.triangles.iter().enumerate() {
            t[i] = (*tri).into();
        }
    }
    let mut geometry = Geometry::Triangle(mesh);
    geometry.commit();
    let mut escene = embree::Scene::new(&device);
    escene.attach_geometry(geometry);
    let committed = escene.commit();
    let secs = start.elapsed().as_secs_f64();
    let one = EmbreeTracer {
        scene: &committed,
        stream: false,
    };
    let stream = EmbreeTracer {
        scene: &committed,
        stream: true,
    };
    f(&one, &stream, secs)
}
