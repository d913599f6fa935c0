//! The hit stores (the hit file and memory) and the scratch directory:
//! what the bake keeps between its phases, and what it leaves behind.

use glam::Vec3;
use kalos::methods::density::hitfile::{HitFile, HitWriter};
use kalos::methods::density::hits::{Hit, HitSink, HitSource, MemoryWriter};
use kalos::methods::density::scratch::ScratchDir;
use kalos::methods::density::surfaces::SurfaceId;
use kalos::methods::density::{self, pipeline, Settings, Storage};
use kalos::methods::World;
use kalos::sampling::Pcg32;
use kalos::scene::{self, Material, Scene, Texture};

use super::{floor_scene, root, scratch, scratch_base, settings};

/// The hit file: records come back bit-exactly, grouped and sorted by
/// surface (stable), and a seed reproduces the traced file byte for byte
/// whatever the thread count.
#[test]
fn hit_file_round_trip_and_determinism() {
    let tmp = scratch("roundtrip");
    let dir = tmp.path().to_path_buf();
    let mut rng = Pcg32::new(5, 0);
    let hits: Vec<Hit> = (0..100_000)
        .map(|_| Hit {
            surface: SurfaceId {
                index: rng.next_u32() % 1000,
                back: rng.next_u32() & 1 == 1,
            },
            u: rng.next_u32() as u16,
            v: rng.next_u32() as u16,
            rgb: rng.next_u32(),
        })
        .collect();
    let mut w = HitWriter::new(&dir, &dir.join("hits.bin"), 1000, 7).expect("writer");
    for c in hits.chunks(3000) {
        w.push(c).expect("push");
    }
    let f = w.finish().expect("finish");
    let f = HitFile::open(&f.path).expect("open");
    assert_eq!(f.len(), hits.len() as u64);
    let back: Vec<Hit> = (0..f.buckets.len())
        .flat_map(|b| f.read_bucket(b).expect("read"))
        .collect();
    let mut expected = hits.clone();
    // bucket by surface id without the side bit, then stable sort by full id
    expected.sort_by_key(|h| (h.surface.index / 143, h.surface));
    assert_eq!(back, expected);

    // the bucket sort in chunks of 1 000 records (a bucket has ~14 000)
    // writes the same bytes, and the runs index every surface side
    let mut w = HitWriter::new(&dir.join("chunked"), &dir.join("hits-chunked.bin"), 1000, 7)
        .expect("writer");
    w.sort_chunk = 1000;
    for c in hits.chunks(3000) {
        w.push(c).expect("push");
    }
    let g = w.finish().expect("finish");
    assert_eq!(g.max_sort_records, 1000);
    assert_eq!(
        std::fs::read(&f.path).expect("read"),
        std::fs::read(&g.path).expect("read")
    );
    let reopened = HitFile::open(&g.path).expect("open");
    assert_eq!(reopened.runs, g.runs);
    for r in &g.runs {
        let rec = g.read_range(r.start, r.count).expect("range");
        assert!(rec.iter().all(|h| h.surface == r.surface));
    }
    assert_eq!(
        g.runs.iter().map(|r| r.count).sum::<u64>(),
        hits.len() as u64
    );

    // the in-memory store holds every side's records in the same order
    let mut m = MemoryWriter::new();
    for c in hits.chunks(3000) {
        m.push(c).expect("push");
    }
    let m = m.finish().expect("finish");
    assert_eq!(m.hit_count(), g.hit_count());
    let sorted = |runs: &[kalos::methods::density::hits::Run]| {
        let mut r = runs.to_vec();
        r.sort_by_key(|r| r.surface);
        r
    };
    let (mr, gr) = (sorted(m.runs()), sorted(g.runs()));
    assert_eq!(mr.len(), gr.len());
    for (a, b) in mr.iter().zip(&gr) {
        assert_eq!((a.surface, a.count), (b.surface, b.count));
        let (x, y) = (m.read(a.start, a.count), g.read(b.start, b.count));
        assert_eq!(*x.expect("memory"), *y.expect("file"));
    }

    // same seed, 1 thread and 2 threads: identical bytes
    let sc = scene::load(&root().join("scenes/cbox/cbox.xml")).expect("cbox");
    let world = World::new(sc);
    let surfaces = density::surfaces::build(&world.scene);
    let trace = |threads: usize, name: &str| {
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .expect("pool");
        let path = dir.join(format!("{name}.bin"));
        let st = Settings {
            scratch: Some(dir.clone()),
            keep_hits: Some(path.clone()),
            ..settings(60_000, 11)
        };
        pool.install(|| {
            let scratch = ScratchDir::new(&st).expect("scratch");
            let mut sink = pipeline::file_sink(&surfaces, &st, &scratch).expect("sink");
            pipeline::trace(&world, &surfaces, &st, &mut sink).expect("trace");
            pipeline::group(sink).expect("group");
        });
        std::fs::read(&path).expect("read")
    };
    let (a, b) = (trace(1, "t1"), trace(2, "t2"));
    assert!(a.len() > 100_000);
    assert!(a == b, "the hit file depends on the thread count");
}

/// The floor scene with a grey ball of `rings` rings on it: planar and
/// curved receivers.
fn floor_with_ball(rings: u32) -> Scene {
    let mut sc = floor_scene(0.2, 1.0);
    let grey = sc.add_material(Material::Diffuse {
        reflectance: Texture::Constant(Vec3::splat(0.5)),
    });
    let m = scene::shapes::sphere(Vec3::new(0.6, 0.3, 0.0), 0.3, rings);
    sc.add_mesh(
        "ball",
        &m.positions,
        m.normals.as_deref(),
        None,
        &m.indices,
        grey,
        None,
    );
    sc
}

/// Phase 2 holds at most `chunk_hits` hit records in memory, whatever the
/// particle count: the floor scene (with a sphere, for the curved path)
/// baked at n and 4n particles with a 20 000-record chunk, the largest
/// surface (the floor) receiving more than 4 chunks at 4n. The counters are
/// the largest in-memory hit buffers of phase 2 and of the bucket sort of
/// phase 1 (`BakeStats::max_hits_in_memory`, `max_sort_records`).
///
/// Streaming changes nothing but the order of f32 additions: the same bake
/// with one chunk for everything gives the same irradiance at every vertex
/// to a relative 1e-5 (the sum of up to ~10⁴ kernel terms per vertex in f32
/// in another order: its rounding is ~1e-7 per addition, so 1e-5 is far
/// above rounding and far below any real change, which would be of the
/// order of one kernel term, ≥ 1e-3 of the sum).
#[test]
#[ignore = "slow tier: cargo test --release -- --ignored"]
fn phase_two_hit_memory_does_not_grow_with_n() {
    let world = World::new(floor_with_ball(16));
    let chunk = 20_000usize;
    let bake = |n: u64, chunk_hits: usize| {
        let st = Settings {
            decimate: false,
            chunk_hits,
            ..settings(n, 9)
        };
        density::bake(&world, &st).expect("bake")
    };
    let mut peaks = Vec::new();
    for n in [100_000u64, 400_000] {
        let b = bake(n, chunk);
        let floor_hits = b.mesh.planar[0].hits;
        eprintln!(
            "n {n}: hits {}, floor {floor_hits}, largest hit buffer in phase 2 {}, in the bucket sort {}",
            b.stats.hits, b.stats.max_hits_in_memory, b.stats.max_sort_records
        );
        assert!(b.stats.max_hits_in_memory <= chunk as u64);
        assert!(b.stats.max_sort_records <= chunk as u64);
        assert!(b.stats.max_hits_in_memory > 0);
        peaks.push((floor_hits, b.stats.max_hits_in_memory));
    }
    assert!(peaks[1].0 > 4 * chunk as u64, "the floor is streamed");
    assert!(
        peaks[1].0 > 3 * peaks[0].0,
        "4n gives the floor ~4× the hits"
    );

    // streaming in chunks against one chunk: the same estimate
    let a = bake(400_000, chunk);
    let b = bake(400_000, usize::MAX / 2);
    // one chunk: the whole floor was in memory at once
    assert!(b.stats.max_hits_in_memory >= b.mesh.planar[0].hits);
    assert_eq!(a.mesh.planar.len(), b.mesh.planar.len());
    let close = |x: Vec3, y: Vec3| (x - y).abs().max_element() <= 1e-5 * y.max_element() + 1e-30;
    for (ma, mb) in a.mesh.planar.iter().zip(&b.mesh.planar) {
        assert_eq!(ma.surface, mb.surface);
        assert_eq!(ma.verts, mb.verts);
        for (x, y) in ma.h.iter().zip(&mb.h) {
            assert!(close(*x, *y), "surface {:?}: {x} vs {y}", ma.surface);
        }
    }
    assert_eq!(a.mesh.curved.len(), b.mesh.curved.len());
    assert!(!a.mesh.curved.is_empty());
    for (ca, cb) in a.mesh.curved.iter().zip(&b.mesh.curved) {
        for (x, y) in ca.h.iter().flatten().zip(cb.h.iter().flatten()) {
            assert!(close(*x, *y), "ball: {x} vs {y}");
        }
    }
}

/// The bake's scratch directory is removed when a panic unwinds past it
/// (after a render and after a failed one: `scratch_directory_is_gone_after_a_render`
/// in `tests/it/density.rs`).
#[test]
fn scratch_directory_is_removed_when_a_panic_unwinds() {
    let (_tmp, base, _file) = scratch_base("removed");
    let st = Settings {
        scratch: Some(base.clone()),
        ..settings(20_000, 3)
    };
    let dir = ScratchDir::new(&st).expect("scratch dir");
    let path = dir.path().to_path_buf();
    std::fs::write(path.join("bucket"), b"hits").expect("write");
    let unwound = std::panic::catch_unwind(move || {
        let _dir = dir;
        panic!("unwinding past the scratch directory");
    });
    assert!(unwound.is_err());
    assert!(!path.exists(), "after a panic");
}

/// The in-memory hit store gives the bake of the hit file, bit for bit:
/// both hold each surface side's records in traced order and phase 2 sums
/// them in that order, whatever the order of the sides. The floor scene
/// with a sphere (planar and curved surfaces), streamed in small chunks so
/// that large surfaces are summed chunk by chunk.
#[test]
fn memory_and_disk_bakes_are_identical() {
    let world = World::new(floor_with_ball(12));
    let st = Settings {
        chunk_hits: 7_000,
        ..settings(100_000, 21)
    };
    let disk = density::bake_with(&world, &st, Storage::Disk).expect("disk");
    let memory = density::bake_with(&world, &st, Storage::Memory).expect("memory");
    assert!(disk.stats.hits > 4 * 7_000);
    assert_eq!(disk.w0.to_bits(), memory.w0.to_bits());
    assert_eq!(disk.mesh.planar.len(), memory.mesh.planar.len());
    for (a, b) in disk.mesh.planar.iter().zip(&memory.mesh.planar) {
        assert_eq!(a.surface, b.surface);
        assert_eq!(a.verts, b.verts);
        assert_eq!(a.tris, b.tris);
        assert_eq!(a.h, b.h);
    }
    assert!(!disk.mesh.curved.is_empty());
    assert_eq!(disk.mesh.curved.len(), memory.mesh.curved.len());
    for (a, b) in disk.mesh.curved.iter().zip(&memory.mesh.curved) {
        assert_eq!((a.shape, a.back), (b.shape, b.back));
        assert_eq!(a.h, b.h);
    }
    let keep = Settings {
        keep_hits: Some(std::env::temp_dir().join("never-written.bin")),
        ..st
    };
    let err = density::bake_with(&world, &keep, Storage::Memory).expect_err("nothing to keep");
    assert!(err.to_string().contains("never-written.bin"), "{err}");
}
