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

#[test]
fn budgets_stop_the_render() {
    let scene = cbox();
    let world = World::new(scene);
    let mut m = MethodConfig::Path(Default::default())
        .create(&world, &Common::default())
        .expect("method");
    let spp = Driver {
        budget: Budget {
            spp: Some(5.0),
            ..Default::default()
        },
        cancel: None,
        reference: None,
        log_every: 0.0,
    }
    .run(m.as_mut(), &world, |_| {})
    .expect("render");
    assert_eq!(spp.passes, 5);
    let mut m = MethodConfig::Light(Default::default())
        .create(&world, &Common::default())
        .expect("method");
    let rays = Driver {
        budget: Budget {
            rays: Some(200_000),
            ..Default::default()
        },
        cancel: None,
        reference: None,
        log_every: 0.0,
    }
    .run(m.as_mut(), &world, |_| {})
    .expect("render");
    assert!(rays.rays >= 200_000);
    // it stopped at the first pass that reached the budget
    let per_pass = rays.rays as f64 / rays.passes as f64;
    assert!((rays.rays as f64) < 200_000.0 + per_pass + 1.0);
}

#[test]
fn a_cancelled_render_returns_what_it_has() {
    let world = World::new(cbox());
    let mut m = MethodConfig::Path(Default::default())
        .create(&world, &Common::default())
        .expect("method");
    let cancel = AtomicBool::new(false);
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
        if p.passes == 2 {
            cancel.store(true, std::sync::atomic::Ordering::SeqCst);
        }
    })
    .expect("render");
    assert!(r.interrupted);
    assert_eq!(r.passes, 2);
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
