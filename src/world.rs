//! The world a method reads: the scene and what is built from it once (the
//! BVH, the light distribution, the camera).

use std::hash::{DefaultHasher, Hash, Hasher};

use rayon::prelude::*;

use crate::accel::Accel;
use crate::camera::Camera;
use crate::emitter::Lights;
use crate::scene::{EmitterDesc, Scene, Shape, TriRecords};

/// Everything a method reads: the scene and what is built from it once.
pub struct World {
    /// The scene.
    pub scene: Scene,
    /// The BVH.
    pub accel: Accel,
    /// The lights, ready for sampling.
    pub lights: Lights,
    /// The camera.
    pub camera: Camera,
    /// One cache line per triangle for [`World::surface_point`].
    pub tris: TriRecords,
}

/// What [`World::build`] reports while it works, for a progress display.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum BuildEvent {
    /// A phase starts; the text says what it does, in a few words.
    Phase(String),
    /// The build changed the scene in a way the user should hear about (it
    /// is also added to [`Scene::warnings`]).
    Warning(String),
}

impl World {
    /// Builds the BVH, the light distribution and the camera.
    pub fn new(scene: Scene) -> Self {
        Self::build(scene, &mut |_| {})
    }

    /// [`World::new`], reporting each phase to `on_event` as it starts and
    /// each change to the scene as it is made. Exact copies of a triangle
    /// are removed first ([`remove_duplicate_triangles`]).
    pub fn build(mut scene: Scene, on_event: &mut dyn FnMut(BuildEvent)) -> Self {
        on_event(BuildEvent::Phase(format!(
            "looking for duplicate triangles among {}",
            scene.triangles.len()
        )));
        if let Some(w) = remove_duplicate_triangles(&mut scene) {
            scene.warnings.push(w.clone());
            on_event(BuildEvent::Warning(w));
        }
        let accel = Accel::build_reporting(&scene, &mut |p| on_event(BuildEvent::Phase(p)));
        on_event(BuildEvent::Phase("building the light distribution".into()));
        let lights = Lights::new(&scene);
        let camera = Camera::new(&scene.camera);
        let tris = TriRecords::new(&scene);
        // The tables of the materials some shape uses (a scene may define
        // materials nothing references: they cost nothing, as before)
        on_event(BuildEvent::Phase("building the materials' tables".into()));
        let mut used = vec![false; scene.materials.len()];
        for sh in scene.shapes.iter().filter(|sh| sh.tri_count > 0) {
            if let Some(u) = used.get_mut(sh.material as usize) {
                *u = true;
            }
        }
        scene
            .materials
            .par_iter()
            .zip(&used)
            .filter(|(_, &u)| u)
            .for_each(|(m, _)| m.prepare());
        World {
            scene,
            accel,
            lights,
            camera,
            tris,
        }
    }
}

/// Removes every triangle that repeats an earlier one exactly: the same
/// three corners (bit for bit) in the same cyclic order, so the same
/// surface facing the same way. Copies make a BVH builder's work grow
/// without limit and hide each other (a ray meets one of them
/// arbitrarily), while a light would still sample all of them. The first
/// in scene order (file order) is kept, with its shape's material and
/// emission; a triangle with the same corners wound the other way is a
/// different surface (the back of a one-sided emitter) and stays. Returns
/// the warning to show when something was removed.
pub fn remove_duplicate_triangles(scene: &mut Scene) -> Option<String> {
    // Key: the corners' bits, rotated so that the smallest comes first.
    // Sorting (hash, index) pairs finds the copies in O(n log n) time and
    // 16 bytes a triangle; equal hashes are confirmed on the keys.
    let key = |i: u32| -> [u32; 9] {
        let c = scene.triangles[i as usize].map(|v| {
            let p = scene.positions[v as usize];
            [p.x.to_bits(), p.y.to_bits(), p.z.to_bits()]
        });
        let r = (0..3).min_by_key(|&k| c[k]).unwrap_or(0);
        let (a, b, d) = (c[r], c[(r + 1) % 3], c[(r + 2) % 3]);
        [a[0], a[1], a[2], b[0], b[1], b[2], d[0], d[1], d[2]]
    };
    let mut order: Vec<(u64, u32)> = (0..scene.triangles.len() as u32)
        .into_par_iter()
        .map(|i| {
            let mut h = DefaultHasher::new();
            key(i).hash(&mut h);
            (h.finish(), i)
        })
        .collect();
    // the pairs are distinct, so any sort gives the one order
    order.par_sort_unstable();
    let emission = |s: &Shape| match s.emitter.map(|e| &scene.emitters[e as usize]) {
        Some(EmitterDesc::Area { radiance, .. }) => Some(*radiance),
        _ => None,
    };
    let mut keep = vec![true; scene.triangles.len()];
    let (mut removed, mut conflicting) = (0usize, 0usize);
    for run in order.chunk_by(|x, y| x.0 == y.0) {
        // the first triangle of each distinct key in the run (in index order)
        let mut firsts: Vec<(u32, [u32; 9])> = Vec::new();
        for &(_, i) in run {
            let k = key(i);
            let Some(&(j, _)) = firsts.iter().find(|f| f.1 == k) else {
                firsts.push((i, k));
                continue;
            };
            keep[i as usize] = false;
            removed += 1;
            let (a, b) = (
                &scene.shapes[scene.tri_shape[j as usize] as usize],
                &scene.shapes[scene.tri_shape[i as usize] as usize],
            );
            if a.material != b.material || emission(a) != emission(b) {
                conflicting += 1;
            }
        }
    }
    if removed == 0 {
        return None;
    }

    // Compact, and move each shape's range to the kept triangles' new indices
    let mut new_index = Vec::with_capacity(keep.len() + 1);
    let mut n = 0u32;
    for &k in &keep {
        new_index.push(n);
        n += k as u32;
    }
    new_index.push(n);
    for s in &mut scene.shapes {
        let (a, b) = (s.first_tri as usize, (s.first_tri + s.tri_count) as usize);
        s.first_tri = new_index[a];
        s.tri_count = new_index[b] - new_index[a];
    }
    let mut k = keep.iter();
    scene.triangles.retain(|_| *k.next().unwrap_or(&true));
    let mut k = keep.iter();
    scene.tri_shape.retain(|_| *k.next().unwrap_or(&true));

    let mut msg = format!(
        "{}: removed {removed} triangle(s) that repeat an earlier triangle exactly (same corners, same winding); the first in file order is kept",
        scene.source
    );
    if conflicting > 0 {
        msg += &format!(
            ", with its own material and emission ({conflicting} of the copies had another material or emission)"
        );
    }
    Some(msg)
}
