//! White furnace: a closed box of albedo a, emitting Le everywhere, must
//! give L = Le / (1 − a) in every pixel, with every method.
//!
//! Tolerance: the image mean must lie within 4 standard errors of the exact
//! value, the standard error being measured from the spread of the pixel
//! values (independent estimates) of the same render. A 4σ test fails by
//! chance with probability 6e-5.

mod common;

use common::{furnace, mean_and_se, render};
use kalos::methods::Options;

fn check(method: &str, variant: Option<&str>, passes: u64) {
    let (a, le) = (0.5f32, 1.0f32);
    let expected = (le / (1.0 - a)) as f64;
    let scene = furnace(a, le, 32);
    let opts = Options {
        seed: 7,
        variant: variant.map(str::to_string),
        ..Default::default()
    };
    let (img, rays) = render(&scene, method, &opts, passes);
    assert!(rays > 0);
    for ch in 0..3 {
        let (mean, se) = mean_and_se(&img, ch);
        assert!(
            (mean - expected).abs() <= 4.0 * se + 1e-9,
            "{method}: channel {ch} mean {mean} vs {expected}, se {se}"
        );
        // and the test is sharp enough to see a 1% bias
        assert!(
            4.0 * se < 0.01 * expected,
            "{method}: se {se} too large to judge"
        );
    }
    assert!(img.data.iter().all(|p| p.is_finite()));
}

#[test]
fn path_tracer_furnace() {
    check("path", None, 64);
}

#[test]
fn light_tracer_furnace() {
    check("light", None, 1024);
}

#[test]
fn light_iteration_furnace() {
    // the iteration variant has the power defect of eq. (18): with chains of
    // 1024·128 steps its bound 1/M · λ²/(1−λ)² · Le is ~1e-4 of the value
    check("light", Some("iteration"), 1024);
}
