//! `plb` and `bundle` split into independent chains: the merge averages
//! them, and the average converges to the furnace's known answer.

use kalos::methods::{bundle, plb, Budget, Common, MethodConfig};
use kalos::partial::{self, Meta, Partial, Shard};
use kalos::render::Render;
use kalos::world::World;

use crate::common;

/// Chains per method: the tolerance below comes from their spread.
const CHAINS: u32 = 8;
/// Two-sided 99.9 % quantile of Student's t with CHAINS − 1 = 7 degrees of
/// freedom: the spread of 8 chain means estimates the standard error with
/// 7 degrees of freedom, so this, not the normal 3.29, bounds |t|.
const T_999_7: f64 = 5.41;

/// Renders the chains of `method` as shards K/CHAINS, merges their partial
/// results, and checks the merged furnace (a = 0.5, Le = 1: L = 2) against
/// the closed form, with a tolerance from the measured spread of the
/// chains' means (plus `bias`, the method's own bound, relative).
fn merged_chains_converge(method: MethodConfig, passes: u64, bias: f64) {
    let scene = common::furnace(0.5, 1.0, 16);
    let world = World::new(scene.clone());
    let mut parts = Vec::new();
    let mut means = Vec::new();
    let mut spps = Vec::new();
    for k in 0..CHAINS {
        let shard = Shard {
            index: k,
            count: CHAINS,
        };
        let r = Render::new(&world)
            .method(method.clone())
            .budget(Budget {
                passes: Some(passes),
                ..Default::default()
            })
            .shard(shard)
            .keep_state()
            .run(|_| {})
            .expect("a chain renders");
        means.push(image_mean(&r.image));
        let state = r.state.expect("a chain keeps its image");
        spps.push(state.spp);
        let meta =
            Meta::new(&scene, &method, &Common::default(), shard).expect("the method shards");
        parts.push((format!("chain-{k}").into(), Partial { meta, state }));
    }
    // Independent chains: different seeds give different images
    assert!(
        means.windows(2).any(|w| w[0] != w[1]),
        "the chains are copies"
    );
    let merged = partial::merge(&parts).expect("the chains merge");
    let m = image_mean(&merged.image);
    let n = CHAINS as f64;
    let avg = means.iter().sum::<f64>() / n;
    let sd = (means.iter().map(|x| (x - avg).powi(2)).sum::<f64>() / (n - 1.0)).sqrt();
    let se = sd / n.sqrt();
    let tol = T_999_7 * se + bias * 2.0;
    assert!(
        (m - 2.0).abs() <= tol,
        "{}: merged mean {m}, expected 2 ± {tol} (chain means {means:?})",
        method.name()
    );
    // The merge is the chains' average weighted by their samples per pixel
    // (equal for most methods at equal passes; plb's differ a little, its
    // mixture's split being measured per chain), up to the images' f32
    let total: f64 = spps.iter().sum();
    let weighted = means.iter().zip(&spps).map(|(m, s)| m * s).sum::<f64>() / total;
    assert!(
        (m - weighted).abs() <= 1e-6 * weighted,
        "merge {m} is not the spp-weighted average {weighted} (spp {spps:?})"
    );
}

fn image_mean(img: &kalos::film::Image) -> f64 {
    img.data
        .iter()
        .map(|p| p.to_array().iter().map(|&c| c as f64).sum::<f64>() / 3.0)
        .sum::<f64>()
        / img.data.len() as f64
}

#[test]
fn plb_chains_merged_converge_to_the_furnace() {
    merged_chains_converge(MethodConfig::Plb(plb::Settings::default()), 128, 0.0);
}

#[test]
fn bundle_chains_merged_converge_to_the_furnace() {
    let passes = 100;
    merged_chains_converge(
        MethodConfig::Bundle(bundle::Settings {
            patches: 600,
            map_res: Some(256),
            ..Default::default()
        }),
        passes,
        // eq. (18) of the 1999 paper: |ΔP| ≤ (1/M) λ²/(1 − λ)² ‖Le‖ = 1/M
        // for λ = 0.5, relative to L = 2
        0.5 / passes as f64,
    );
}
