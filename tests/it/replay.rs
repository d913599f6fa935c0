//! The recorded ray sets of `kalos bench`: a `.krays` file reads back as
//! written, the same seed records the same rays whatever the thread count,
//! and a truncated, damaged, foreign or other scene's file is a clear error
//! naming it. Nothing here is timed.

use std::path::Path;

use kalos::bench::rayset::{self, RaySetError, SetKind};
use kalos::bench::replay::{self, KalosTracer};
use kalos::world::World;

use crate::common::{kalos, stderr};

fn cbox(res: u32) -> World {
    let mut scene = kalos::scene::builtin::cornell_box_with(&[]).expect("built-in box");
    scene.set_resolution(res, res);
    World::new(scene)
}

/// Every ray's eight floats, bit for bit.
fn bits(s: &rayset::RaySets) -> Vec<[u32; 8]> {
    s.sets
        .iter()
        .flatten()
        .map(|r| [r.o.x, r.o.y, r.o.z, r.d.x, r.d.y, r.d.z, r.tmin, r.tmax].map(f32::to_bits))
        .collect()
}

#[test]
fn a_record_file_reads_back_as_written() {
    let world = cbox(24);
    let sets = rayset::record(&world, 7);
    // one camera ray per pixel; the box is closed on five sides, so most
    // camera rays hit and make a bounce ray, and the light is seen from
    // most hits
    assert_eq!(sets.rays(SetKind::Camera).len(), 24 * 24);
    let bounce = sets.rays(SetKind::Bounce).len();
    assert!(bounce > 24 * 24 / 2, "{bounce} bounce rays");
    assert!(!sets.rays(SetKind::Shadow).is_empty());

    let dir = tempfile::tempdir().expect("tempdir");
    let path = dir.path().join("cbox.krays");
    rayset::write(&path, &sets).expect("write");
    let back = rayset::read(&path).expect("read");
    assert_eq!(bits(&back), bits(&sets));
    assert_eq!(
        (back.scene_hash, back.seed, back.width, back.height),
        (sets.scene_hash, 7, 24, 24)
    );
    // nothing else is left in the folder (the write is atomic)
    let names: Vec<_> = std::fs::read_dir(dir.path())
        .expect("list")
        .map(|e| e.expect("entry").file_name())
        .collect();
    assert_eq!(names, vec![std::ffi::OsString::from("cbox.krays")]);

    // the replayed bounce rays are answered as the recorded ones: kalos's
    // answers to both are the same
    let a = replay::answers(&KalosTracer(&world.accel), &sets, SetKind::Bounce);
    let b = replay::answers(&KalosTracer(&world.accel), &back, SetKind::Bounce);
    assert_eq!(a, b);
    assert!(a.hits() > 0);
}

#[test]
fn a_seed_records_the_same_rays_whatever_the_thread_count() {
    let world = cbox(20);
    let on = |n: usize| {
        rayon::ThreadPoolBuilder::new()
            .num_threads(n)
            .build()
            .expect("pool")
            .install(|| rayset::record(&world, 3))
    };
    let (one, two) = (on(1), on(2));
    assert_eq!(bits(&one), bits(&two));
    // and another seed records other rays
    let other = rayset::record(&world, 4);
    assert_ne!(bits(&one), bits(&other));
}

fn read_err(path: &Path) -> String {
    match rayset::read(path) {
        Ok(_) => panic!("{} was read", path.display()),
        Err(e) => e.to_string(),
    }
}

#[test]
fn a_truncated_damaged_or_foreign_file_is_an_error_naming_it() {
    let world = cbox(8);
    let sets = rayset::record(&world, 1);
    let dir = tempfile::tempdir().expect("tempdir");
    let good = dir.path().join("good.krays");
    rayset::write(&good, &sets).expect("write");
    let bytes = std::fs::read(&good).expect("read back");

    // Truncated anywhere: in the magic, in the header, in the rays, in the
    // checksum
    for keep in [0, 5, 20, 70, bytes.len() / 2, bytes.len() - 1] {
        let p = dir.path().join(format!("cut{keep}.krays"));
        std::fs::write(&p, &bytes[..keep]).expect("write");
        let e = read_err(&p);
        assert!(e.contains(&p.display().to_string()), "{keep}: {e}");
        let expected = if keep == 0 {
            "not a kalos ray-set file"
        } else {
            "truncated"
        };
        assert!(e.contains(expected), "{keep}: {e}");
    }

    // One ray's byte changed: the checksum says so
    let mut damaged = bytes.clone();
    damaged[100] ^= 0x40;
    let p = dir.path().join("damaged.krays");
    std::fs::write(&p, &damaged).expect("write");
    let e = read_err(&p);
    assert!(e.contains("damaged.krays") && e.contains("checksum"), "{e}");

    // Another format version
    let mut v2 = bytes.clone();
    v2[8] = 2;
    let p = dir.path().join("v2.krays");
    std::fs::write(&p, &v2).expect("write");
    let e = read_err(&p);
    assert!(e.contains("v2.krays") && e.contains("version 2"), "{e}");

    // A foreign file, of any size
    let p = dir.path().join("scene.krays");
    std::fs::write(&p, "<scene version=\"3.0.0\"/>\n".repeat(50)).expect("write");
    let e = read_err(&p);
    assert!(
        e.contains("scene.krays") && e.contains("not a kalos ray-set file"),
        "{e}"
    );

    // Header counts that overflow are refused before any allocation
    let mut huge = bytes.clone();
    huge[40..48].copy_from_slice(&u64::MAX.to_le_bytes());
    let p = dir.path().join("huge.krays");
    std::fs::write(&p, &huge).expect("write");
    assert!(matches!(rayset::read(&p), Err(RaySetError::Length { .. })));

    // A missing file
    let e = read_err(&dir.path().join("missing.krays"));
    assert!(e.contains("missing.krays"), "{e}");
}

#[test]
fn bench_replays_what_it_recorded_and_refuses_another_scene() {
    let dir = tempfile::tempdir().expect("tempdir");
    let file = dir.path().join("rays.krays");
    let file_s = file.to_str().expect("utf-8 path");
    let common = ["--rays", "0", "--repeat", "1", "--no-embree"];
    let mut args = vec!["bench", "builtin", "--res", "16x12", "--record", file_s];
    args.extend(common);
    let o = kalos(&args);
    assert!(o.status.success(), "{}", stderr(&o));
    let out = String::from_utf8_lossy(&o.stdout).into_owned();
    let counts = |text: &str| {
        text.lines()
            .find(|l| l.starts_with("ray sets ("))
            .map(str::to_string)
            .unwrap_or_default()
    };
    assert!(counts(&out).contains("camera 192 rays"), "{out}");

    let mut args = vec!["bench", "builtin", "--replay", file_s];
    args.extend(common);
    let o = kalos(&args);
    assert!(o.status.success(), "{}", stderr(&o));
    let again = String::from_utf8_lossy(&o.stdout).into_owned();
    assert_eq!(counts(&again), counts(&out));
    assert!(again.contains("Mrays/s"), "{again}");

    // the same rays against another scene: refused, naming the file
    let mut args = vec!["bench", "--triangles", "2000", "--replay", file_s];
    args.extend(common);
    let o = kalos(&args);
    assert_eq!(o.status.code(), Some(1));
    let e = stderr(&o);
    assert!(
        e.contains("rays.krays") && e.contains("another scene"),
        "{e}"
    );
}

#[test]
fn the_brute_force_referee_sides_with_the_right_answer() {
    let world = cbox(16);
    let sets = rayset::record(&world, 5);
    let core = KalosTracer(&world.accel);
    let kind = SetKind::Camera;
    let right = replay::answers(&core, &sets, kind);
    let replay::Answers::Closest(answers) = &right else {
        panic!("camera rays ask for closest hits");
    };
    // a core that misses where kalos hits, on three rays
    let mut wrong = answers.clone();
    let hits: Vec<usize> = (0..wrong.len()).filter(|&i| wrong[i].is_hit()).collect();
    for &i in &hits[..3] {
        wrong[i] = replay::Answer::MISS;
    }
    let wrong = replay::Answers::Closest(wrong);
    let g = replay::agreement(&right, &wrong);
    assert_eq!((g.differ, g.hit_vs_miss), (3, 3));
    let v = replay::judge(&world.scene, sets.rays(kind), &right, &wrong);
    assert_eq!((v.judged, v.reference_right, v.other_right), (3, 3, 0));
    // and the other way round
    let v = replay::judge(&world.scene, sets.rays(kind), &wrong, &right);
    assert_eq!((v.reference_right, v.other_right), (0, 3));

    // occlusion: flipping one flag is caught the same way
    let kind = SetKind::Shadow;
    let right = replay::answers(&core, &sets, kind);
    let replay::Answers::Occluded(flags) = &right else {
        panic!("shadow rays ask for occlusion");
    };
    let mut flipped = flags.clone();
    flipped[0] = !flipped[0];
    let v = replay::judge(
        &world.scene,
        sets.rays(kind),
        &right,
        &replay::Answers::Occluded(flipped),
    );
    assert_eq!((v.judged, v.reference_right, v.other_right), (1, 1, 0));
}

/// `Accel::intersect_packet` answers every recorded ray as
/// `Accel::intersect` does, bit for bit (triangle, distance, barycentric
/// weights): the coherent camera rays of cbox and of a generated scene of
/// spheres, the incoherent bounce and shadow rays (as closest-hit rays),
/// and the same rays starting one past a packet's boundary, so that
/// packets straddle rows and the last is partial.
#[test]
fn packets_answer_as_single_rays_on_recorded_sets() {
    let cbox =
        kalos::scene::load(&Path::new(env!("CARGO_MANIFEST_DIR")).join("scenes/cbox/cbox.xml"))
            .expect("cbox");
    let spheres = kalos::scenegen::bench_scene(100_000);
    for mut scene in [cbox, spheres] {
        scene.set_resolution(96, 64);
        let world = World::new(scene);
        let sets = rayset::record(&world, 3);
        let key = |h: Option<kalos::accel::Hit>| {
            h.map(|h| (h.tri, h.t.to_bits(), h.b1.to_bits(), h.b2.to_bits()))
        };
        let mut hits = 0;
        for kind in SetKind::ALL {
            let all = sets.rays(kind);
            for rays in [all, &all[all.len().min(1)..]] {
                let mut got = vec![None; rays.len()];
                world.accel.intersect_packet(rays, &mut got);
                for (i, (r, g)) in rays.iter().zip(&got).enumerate() {
                    let want = world.accel.intersect(r);
                    assert_eq!(key(*g), key(want), "{} ray {i}", kind.name());
                    hits += usize::from(want.is_some());
                }
            }
        }
        // most camera and bounce rays hit (both scenes are closed rooms)
        assert!(hits > sets.rays(SetKind::Camera).len(), "{hits} hits");
    }
}
