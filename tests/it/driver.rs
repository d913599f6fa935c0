//! The driver's promises: budgets stop the render, and a cancelled render
//! returns what it has. (Determinism across thread counts is checked for
//! every method in `tests/methods.rs`.)

use std::sync::atomic::AtomicBool;

use kalos::methods::{Budget, Common, Driver, MethodConfig, World};
use kalos::scene::{self, Scene};

fn cbox() -> Scene {
    let root = std::path::PathBuf::from(env!("CARGO_MANIFEST_DIR"));
    let mut s = scene::load(&root.join("scenes/cbox/cbox.xml")).expect("scene");
    s.set_resolution(48, 48);
    s
}

/// A driver with `budget`, no cancel flag and no log.
fn with_budget(budget: Budget) -> Driver<'static> {
    Driver {
        budget,
        cancel: None,
        reference: None,
        log_every: 0.0,
    }
}

#[test]
fn budgets_stop_the_render() {
    let scene = cbox();
    let world = World::new(scene);
    let mut m = MethodConfig::Path(Default::default())
        .create(&world, &Common::default())
        .expect("method");
    let spp = with_budget(Budget {
        spp: Some(5.0),
        ..Default::default()
    })
    .run(m.as_mut(), &world, |_| {})
    .expect("render");
    assert_eq!(spp.passes, 5);
    let mut m = MethodConfig::Light(Default::default())
        .create(&world, &Common::default())
        .expect("method");
    let rays = with_budget(Budget {
        rays: Some(200_000),
        ..Default::default()
    })
    .run(m.as_mut(), &world, |_| {})
    .expect("render");
    assert!(rays.rays >= 200_000);
    // it stopped at the first pass that reached the budget
    let per_pass = rays.rays as f64 / rays.passes as f64;
    assert!((rays.rays as f64) < 200_000.0 + per_pass + 1.0);
}

/// `path` takes its passes several at a time from the driver (one meeting
/// of its threads per call): the image is the one of single passes to the
/// bit, and the spp budget is met exactly. The progress is reported once
/// per call, so fewer reports than passes show that the passes were
/// batched.
#[test]
fn passes_taken_together_give_the_image_of_single_passes() {
    let world = World::new(cbox());
    let create = || {
        MethodConfig::Path(Default::default())
            .create(&world, &Common::default())
            .expect("method")
    };
    let mut m = create();
    let mut reports = 0;
    let r = with_budget(Budget {
        spp: Some(40.0),
        ..Default::default()
    })
    .run(m.as_mut(), &world, |_| reports += 1)
    .expect("render");
    assert_eq!(r.passes, 40);
    assert!(reports < 40, "{reports} progress reports for 40 passes");
    let mut one = create();
    for p in 0..40 {
        one.step(&world, p);
    }
    let (a, b) = (r.image, one.image(&world));
    assert_eq!(a.data.len(), b.data.len());
    for (x, y) in a.data.iter().zip(&b.data) {
        assert_eq!(
            x.to_array().map(f32::to_bits),
            y.to_array().map(f32::to_bits)
        );
    }
}

#[test]
fn a_cancelled_render_returns_what_it_has() {
    let world = World::new(cbox());
    let mut m = MethodConfig::Path(Default::default())
        .create(&world, &Common::default())
        .expect("method");
    let cancel = AtomicBool::new(false);
    // `path` takes its passes several at a time after the first: the
    // render stops after the call during which the flag was set
    let mut at = None;
    let r = Driver {
        budget: Budget {
            spp: Some(1000.0),
            ..Default::default()
        },
        cancel: Some(&cancel),
        reference: None,
        log_every: 0.0,
    }
    .run(m.as_mut(), &world, |p| {
        if p.passes >= 2 && at.is_none() {
            at = Some(p.passes);
            cancel.store(true, std::sync::atomic::Ordering::SeqCst);
        }
    })
    .expect("render");
    assert!(r.interrupted);
    assert_eq!(Some(r.passes), at);
    assert!(r.passes < 1000);
    assert!(r.image.data.iter().any(|p| p.x > 0.0));
    assert!(r.image.data.iter().all(|p| p.is_finite()));
}

/// Limits that could never be reached are refused before anything runs:
/// a NaN sample count or time (no comparison with NaN is ever true, so the
/// render would never stop), zero, or a negative time.
#[test]
fn unreachable_budgets_are_refused() {
    let world = World::new(cbox());
    let bad = [
        Budget {
            spp: Some(f64::NAN),
            ..Default::default()
        },
        Budget {
            time: Some(f64::NAN),
            ..Default::default()
        },
        Budget {
            spp: Some(0.0),
            ..Default::default()
        },
        Budget {
            time: Some(-1.0),
            ..Default::default()
        },
        Budget {
            rays: Some(0),
            ..Default::default()
        },
    ];
    for budget in bad {
        let mut m = MethodConfig::Path(Default::default())
            .create(&world, &Common::default())
            .expect("method");
        let driver = Driver {
            budget,
            cancel: None,
            reference: None,
            log_every: 1.0,
        };
        let err = driver
            .run(m.as_mut(), &world, |_| {})
            .err()
            .unwrap_or_else(|| panic!("{budget:?} was accepted"));
        eprintln!("{budget:?}: {err}");
    }
    // and a reachable one runs
    let mut m = MethodConfig::Path(Default::default())
        .create(&world, &Common::default())
        .expect("method");
    let ok = Driver {
        budget: Budget {
            passes: Some(1),
            ..Default::default()
        },
        cancel: None,
        reference: None,
        log_every: 1.0,
    };
    assert!(ok.run(m.as_mut(), &world, |_| {}).is_ok());
}

/// The memory check refuses a render whose film alone cannot fit, before
/// the film is allocated (a failed allocation would abort the process),
/// naming what is too large, its estimate and the limit.
#[test]
fn a_render_past_the_memory_limit_is_refused_before_allocating() {
    use kalos::methods::{bundle, light};
    use kalos::render::{check_memory, mem_total, memory_estimate, Render};

    // 65536² pixels of f64 RGB alone are 103 GB: allocating it here would
    // abort the test process, so reaching the asserts shows nothing was.
    let mut scene = cbox();
    scene.set_resolution(65536, 65536);
    let world = World::new(scene);
    let err = Render::new(&world)
        .max_memory(8_000_000_000)
        .run(|_| {})
        .err()
        .expect("a 65536² film was accepted under 8 GB");
    let text = err.to_string();
    assert!(text.contains("65536×65536"), "{text}");
    assert!(text.contains("8.0 GB") && text.contains("--res"), "{text}");

    // The estimate counts every per-pixel buffer: one film per lane.
    let px = 512u64 * 512;
    let path = memory_estimate(&MethodConfig::Path(Default::default()), 512, 512);
    assert!(path[0].bytes >= px * 24, "{path:?}");
    let light8 = memory_estimate(&MethodConfig::Light(Default::default()), 512, 512);
    let one = light::Settings {
        lanes: 1,
        ..Default::default()
    };
    let light1 = memory_estimate(&MethodConfig::Light(one), 512, 512);
    assert!(
        light8[0].bytes >= light1[0].bytes + 7 * px * 24,
        "{light8:?} {light1:?}"
    );
    // bundle's map is scanned in tiles that fit a core's L2 cache, one per
    // thread, so its estimate stays at about 512 KB a thread (plus a row)
    // however large --map-res is
    let threads = rayon::current_num_threads() as u64;
    for res in [64, 1024, 16384] {
        let cfg = MethodConfig::Bundle(bundle::Settings {
            map_res: Some(res),
            ..Default::default()
        });
        let items = memory_estimate(&cfg, 64, 64);
        let map = items
            .iter()
            .find(|i| i.what.contains("visibility map"))
            .expect("the map is estimated");
        let row = (res as u64 + 1) * 20;
        assert!(
            map.bytes > 0 && map.bytes <= threads * (512 * 1024 + row),
            "{res}: {map:?}"
        );
    }
    // and a small render passes
    check_memory(&path, 1_000_000_000, "test").expect("512² fits in 1 GB");

    assert_eq!(
        mem_total("MemTotal:       24684096 kB\nMemFree: 1 kB\n"),
        Some(24684096 * 1024)
    );
    assert_eq!(mem_total("MemFree: 1 kB\n"), None);
    assert_eq!(mem_total("MemTotal: lots kB\n"), None);
}
