//! The end of a phase (§5) and the random purge of the hit population (§4).

use super::importance::compute_importance;
use super::iterate::{Form, Lane, NO_PARENT};
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
        for h in &lane.measured {
            if h.contrib != Rgb::ZERO {
                lane.hit_film.splat(h.pix.x, h.pix.y, h.contrib * sigma);
            }
        }
    }

    // Importance, and the dense list of the positive importances that
    // [`survival_scale`] reads (8 bytes per hit, not a hit record)
    let positive = &mut lane.scratch.positive;
    positive.clear();
    match &lane.grid {
        Some(g) => {
            let weight = g.weights();
            for h in lane.hits.iter_mut() {
                h.s = h.out_lum as f64 * weight(h.cell);
                if h.s > 0.0 {
                    positive.push(h.s);
                }
            }
        }
        None => {
            compute_importance(&mut lane.hits, &mut lane.measured, s.lambda as f64);
            positive.extend(lane.hits.iter().map(|h| h.s).filter(|x| *x > 0.0));
        }
    }
    let c = survival_scale(positive, s.population);
    purge(lane, c, rng);
    lane.sigma = 1.0;
    // The survivors carry the estimate with the weight of one phase (see the
    // module docs): the next phase runs m = P+1 … 2P
    lane.m = s.phase_len as u64;
}

/// The random purge of §4: hit i survives with k_i = min(1, c s_i), c from
/// [`survival_scale`] (None: every hit survives); survivors' power and
/// importance are divided by k_i, and σ is folded into the stored powers.
/// Parent links to killed hits are cut.
///
/// One pass over the population, in order: the survivors are compacted in
/// place (so the population keeps its allocation from phase to phase), each
/// survivor's parent link is remapped as it is moved (a parent always
/// precedes its children, so its new index is known by then), and the
/// selection's prefix sums and Σ out_lum are rebuilt on the way. Inlined
/// into the lane's dispatched loop, so that the move of a record is a few
/// vector moves, not a call to `memcpy`. The buffers are not cleared first
/// (every entry read is written before, in this pass), and the parent
/// links and their new indices are kept only by the forms with
/// [`Measured`](super::iterate::Measured) records (no other form reads
/// them).
#[inline(always)]
fn purge(lane: &mut Lane, c: Option<f64>, rng: &mut Pcg32) {
    let sigma = lane.sigma;
    let n = lane.hits.len();
    // One prefix sum per hit already: overwritten below up to the survivors
    debug_assert_eq!(lane.cum.len(), n);
    lane.cum.resize(n, 0.0);
    let mut measured = (!lane.measured.is_empty()).then(|| {
        debug_assert_eq!(lane.measured.len(), n);
        lane.scratch.new_index.resize(n, NO_PARENT);
        (&mut lane.measured[..n], &mut lane.scratch.new_index[..n])
    });
    // Written out rather than with `retain_mut`, whose closure was not
    // inlined (its captures then live in memory, not registers)
    let cum = &mut lane.cum[..n];
    let hits = &mut lane.hits[..n];
    let (mut acc, mut reflected) = (0.0, 0.0);
    let mut kept = 0;
    for i in 0..n {
        let h = &mut hits[i];
        let k = match c {
            None => 1.0,
            Some(c) => (c * h.s).min(1.0),
        };
        if k <= 0.0 || (k < 1.0 && rng.next_f64() >= k) {
            if let Some((_, new_index)) = measured.as_mut() {
                new_index[i] = NO_PARENT;
            }
            continue;
        }
        let f = (sigma / k) as f32;
        h.phi *= f;
        h.out_lum *= f;
        h.s *= sigma / k;
        if h.spawn {
            acc += h.s;
            reflected += h.out_lum as f64;
        }
        cum[kept] = acc;
        // A survivor moves only once a hit before it was killed
        if kept != i {
            hits[kept] = hits[i];
        }
        if let Some((ms, new_index)) = measured.as_mut() {
            let m = &mut ms[i];
            m.contrib *= f;
            if m.parent != NO_PARENT {
                debug_assert!((m.parent as usize) < i, "a parent precedes its child");
                m.parent = new_index[m.parent as usize];
            }
            new_index[i] = kept as u32;
            if kept != i {
                ms[kept] = ms[i];
            }
        }
        kept += 1;
    }
    lane.hits.truncate(kept);
    lane.measured.truncate(kept);
    lane.cum.truncate(kept);
    lane.reflected = reflected;
}

/// The c with Σ min(1, c s_i) = `cap` over the positive importances `s`, or
/// None when every hit with s_i > 0 can survive (then all hits are kept
/// with k_i = 1). Found by the fixed-point iteration c ← (cap − #saturated)
/// / Σ_unsaturated s_i from c = cap / Σs_i, which increases monotonically
/// to the root (no sort: the purge runs once per phase over the whole
/// population).
///
/// Since c only grows, a hit once saturated (c s_i ≥ 1) stays saturated, so
/// each iteration drops the newly saturated from `s` (which it leaves
/// holding the unsaturated ones, in order) and sums only the rest: the same
/// sums in the same order as summing over all of `s` each time, so the same
/// c to the bit.
#[inline(always)]
fn survival_scale(s: &mut Vec<f64>, cap: usize) -> Option<f64> {
    let n = s.len();
    let total = s.iter().fold(0.0f64, |t, x| t + x);
    if n <= cap || total <= 0.0 {
        return None;
    }
    let mut c = cap as f64 / total;
    let mut sat = 0usize;
    for _ in 0..64 {
        let mut rest = 0.0f64;
        s.retain(|&x| {
            let saturated = c * x >= 1.0;
            if saturated {
                sat += 1;
            } else {
                rest += x;
            }
            !saturated
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

    fn positives(s: &[f64]) -> Vec<f64> {
        s.iter().copied().filter(|x| *x > 0.0).collect()
    }

    /// The fixed-point iteration as first written, summing over every
    /// positive importance at each step.
    fn survival_scale_plain(s: &[f64], cap: usize) -> Option<f64> {
        let pos = || s.iter().copied().filter(|x| *x > 0.0);
        let (n, total) = pos().fold((0usize, 0.0f64), |(n, t), x| (n + 1, t + x));
        if n <= cap || total <= 0.0 {
            return None;
        }
        let mut c = cap as f64 / total;
        for _ in 0..64 {
            let (sat, rest) = pos().fold((0usize, 0.0f64), |(k, r), x| {
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

    /// Dropping the saturated importances as they saturate gives the c of
    /// the plain iteration to the bit (the purge's survivors, and so the
    /// images, depend on it).
    #[test]
    fn survival_scale_matches_the_plain_iteration() {
        let mut rng = Pcg32::keyed(&[11]);
        let mut saturating = 0;
        for trial in 0..400 {
            let n = 1 + (rng.next_f64() * 2000.0) as usize;
            let cap = 1 + (rng.next_f64() * n as f64) as usize;
            let power = 1 + trial % 12;
            let s: Vec<f64> = (0..n)
                .map(|_| {
                    let u = rng.next_f64();
                    if u < 0.05 {
                        0.0
                    } else {
                        u.powi(power) * 1e3
                    }
                })
                .collect();
            let plain = survival_scale_plain(&s, cap);
            let fast = survival_scale(&mut positives(&s), cap);
            assert_eq!(
                plain.map(f64::to_bits),
                fast.map(f64::to_bits),
                "n {n} cap {cap}"
            );
            if let Some(c) = fast {
                saturating += usize::from(s.iter().any(|x| c * x >= 1.0));
            }
        }
        // The populations exercise the saturated case, not only c = cap/Σs
        assert!(saturating > 100, "{saturating}");
    }

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
                let Some(c) = survival_scale(&mut positives(&s), cap) else {
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
        let c = survival_scale(&mut positives(&s), 3).unwrap();
        let sum: f64 = s.iter().map(|x| (c * x).min(1.0)).sum();
        assert!((sum - 3.0).abs() < 1e-9, "{sum}");
        assert!(survival_scale(&mut positives(&s), 6).is_none());
    }
}
