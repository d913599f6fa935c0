//! The end of a phase (§5) and the random purge of the hit population (§4).

use super::importance::compute_importance;
use super::iterate::{Form, Hit, Lane, NO_PARENT};
use super::Settings;

/// Buffers the purge reuses from phase to phase.
#[derive(Clone, Debug, Default)]
pub(super) struct Scratch {
    /// The hits' positive importances, in order.
    positive: Vec<f64>,
    /// Each hit's index after the purge, or [`NO_PARENT`] when killed.
    new_index: Vec<u32>,
}
use crate::sampling::Pcg32;
use crate::scene::Rgb;

/// The end of a phase (§5): the image estimate (unless the hits are
/// measured at birth), `ComputeImportance`, and the random purge.
#[inline(always)]
pub(super) fn end_phase(s: &Settings, form: Form, rng: &mut Pcg32, lane: &mut Lane) {
    lane.in_phase = 0;
    lane.phases += 1;

    // The phase image: every hit's camera contribution at its current power
    if lane.phases > s.discard && !form.birth {
        lane.counted += 1;
        let sigma = lane.sigma as f32;
        for h in &lane.hits {
            if h.contrib != Rgb::ZERO {
                lane.hit_film.splat(h.pix.x, h.pix.y, h.contrib * sigma);
            }
        }
    }

    match &lane.grid {
        Some(g) => {
            let weight = g.weights();
            for h in lane.hits.iter_mut() {
                h.s = h.out_lum as f64 * weight(h.cell);
            }
        }
        None => compute_importance(&mut lane.hits, s.lambda as f64),
    }
    purge(
        &mut lane.hits,
        lane.sigma,
        s.population,
        rng,
        &mut lane.scratch,
    );
    lane.sigma = 1.0;
    lane.rebuild();
    // The survivors carry the estimate with the weight of one phase (see the
    // module docs): the next phase runs m = P+1 … 2P
    lane.m = s.phase_len as u64;
}

/// The random purge of §4: hit i survives with k_i = min(1, c s_i), c chosen
/// so that Σk_i = `cap` (when more than `cap` hits have s_i > 0); survivors'
/// power and importance are divided by k_i, and σ is folded into the stored
/// powers. Parent links to killed hits are cut.
///
/// The survivors are compacted in place, in order, so the population keeps
/// its allocation from phase to phase (building a new vector each phase
/// reallocated the whole population whenever the next phase outgrew it;
/// the cost is measured in docs/notebook/plb.md). The positive importances
/// are first copied into a dense list, so that the iterations of
/// [`survival_scale`] read 8 bytes per hit, not a whole hit record each.
#[inline]
fn purge(hits: &mut Vec<Hit>, sigma: f64, cap: usize, rng: &mut Pcg32, scratch: &mut Scratch) {
    let n = hits.len();
    scratch.positive.clear();
    scratch
        .positive
        .extend(hits.iter().map(|h| h.s).filter(|x| *x > 0.0));
    let c = survival_scale(scratch.positive.iter().copied(), cap);
    let new_index = &mut scratch.new_index;
    new_index.clear();
    new_index.resize(n, NO_PARENT);
    let (mut i, mut kept) = (0, 0);
    // retain_mut visits the hits once each, in order
    hits.retain_mut(|h| {
        let index = i;
        i += 1;
        let k = match c {
            None => 1.0,
            Some(c) => (c * h.s).min(1.0),
        };
        if k <= 0.0 || (k < 1.0 && rng.next_f64() >= k) {
            return false;
        }
        let f = (sigma / k) as f32;
        h.phi *= f;
        h.contrib *= f;
        h.out_lum *= f;
        h.s *= sigma / k;
        new_index[index] = kept;
        kept += 1;
        true
    });
    for h in hits.iter_mut() {
        if h.parent != NO_PARENT {
            h.parent = new_index[h.parent as usize];
        }
    }
}

/// The c with Σ min(1, c s_i) = `cap`, or None when every hit with s_i > 0
/// can survive (then all hits are kept with k_i = 1). Found by the
/// fixed-point iteration c ← (cap − #saturated) / Σ_unsaturated s_i from
/// c = cap / Σs_i, which increases monotonically to the root (no sort: the
/// purge runs once per phase over the whole population).
#[inline]
fn survival_scale(s: impl Iterator<Item = f64> + Clone, cap: usize) -> Option<f64> {
    let (n, total) = s
        .clone()
        .filter(|x| *x > 0.0)
        .fold((0usize, 0.0f64), |(n, t), x| (n + 1, t + x));
    if n <= cap || total <= 0.0 {
        return None;
    }
    let mut c = cap as f64 / total;
    for _ in 0..64 {
        let (sat, rest) = s
            .clone()
            .filter(|x| *x > 0.0)
            .fold((0usize, 0.0f64), |(k, r), x| {
                if c * x >= 1.0 {
                    (k + 1, r)
                } else {
                    (k, r + x)
                }
            });
        if sat >= cap || rest <= 0.0 {
            return Some(c);
        }
        let next = (cap - sat) as f64 / rest;
        if next <= c * (1.0 + 1e-12) {
            return Some(next.max(c));
        }
        c = next;
    }
    Some(c)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// c against Σ min(1, c s_i) = cap on populations with many saturated
    /// hits, over a range of caps.
    #[test]
    fn survival_scale_solves_the_cap_equation() {
        let mut rng = Pcg32::keyed(&[7]);
        for n in [5usize, 50, 1400] {
            for cap in [1usize, 3, n / 2, n - 1] {
                let s: Vec<f64> = (0..n)
                    .map(|_| {
                        let u = rng.next_f64();
                        if u < 0.1 {
                            0.0
                        } else {
                            u.powi(8) * 1e3
                        }
                    })
                    .collect();
                let Some(c) = survival_scale(s.iter().copied(), cap) else {
                    assert!(s.iter().filter(|x| **x > 0.0).count() <= cap);
                    continue;
                };
                let sum: f64 = s.iter().map(|x| (c * x).min(1.0)).sum();
                assert!(
                    (sum - cap as f64).abs() < 1e-6 * cap as f64,
                    "n {n} cap {cap}: Σk = {sum}"
                );
            }
        }
    }

    #[test]
    fn survival_scale_sums_to_cap() {
        let s = [10.0, 1.0, 1.0, 1.0, 0.5, 0.0, 0.25];
        let c = survival_scale(s.iter().copied(), 3).unwrap();
        let sum: f64 = s.iter().map(|x| (c * x).min(1.0)).sum();
        assert!((sum - 3.0).abs() < 1e-9, "{sum}");
        assert!(survival_scale(s.iter().copied(), 6).is_none());
    }
}
