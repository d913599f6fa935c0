//! Tests of `--method bundle` (stochastic iteration with global ray bundles).

mod common;

use kalos::methods::Options;

fn opts(seed: u64) -> Options {
    Options {
        seed,
        patches: Some(2000),
        ..Default::default()
    }
}

#[test]
fn furnace() {
    let scene = common::furnace(0.5, 1.0, 16);
    for seed in 0..4 {
        let (img, _) = common::render(&scene, "bundle", &opts(seed), 200);
        let (m, se) = common::mean_and_se(&img, 0);
        eprintln!("seed {seed}: mean {m} se {se}");
    }
}
