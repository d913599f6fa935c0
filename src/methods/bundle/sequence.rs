//! The global directions ω_1, ω_2, ... of the iteration: points of a 2D
//! sequence warped uniformly onto the sphere (z = 1 − 2u, φ = 2πv).
//!
//! §6.1 of the 1999 paper: the iteration uses subsequent pairs, triplets...
//! of randomization points at once, so a sequence must be k-uniform for all
//! k; Halton and Hammersley are only 1-uniform and should give wrong results
//! (Fig. 7). The four sequences here reproduce that experiment:
//!
//! - `random`: PCG32, a stream keyed by (seed, m);
//! - `halton`: radical inverses in bases 2 and 3 of m + 1 (+ the seed);
//! - `hammersley`: (m / N, Φ₂(m)) with N = [`HAMMERSLEY_N`], whose first
//!   coordinate increases along the walk (it restarts after N points);
//! - `frac`: the fractional part of q'_n = (π − 2) · q'_{n−1} mod 100000,
//!   q'_0 = π (+ the seed), the modification §6.1 used of the sequence
//!   {πⁿ}; subsequent values give (u, v) = (q'_{2m+1}, q'_{2m+2}) fractions.

use std::f64::consts::PI as PI64;

use glam::{Vec2, Vec3};

use crate::sampling::{uniform_sphere, Pcg32};

/// Points per Hammersley period.
pub const HAMMERSLEY_N: u64 = 4096;

/// Which sequence generates the directions.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "kebab-case")]
#[cfg_attr(feature = "cli", derive(clap::ValueEnum))]
pub enum Sequence {
    /// Pseudo-random (PCG32); the default.
    Random,
    /// Halton, bases 2 and 3.
    Halton,
    /// Hammersley with 4096 points (`HAMMERSLEY_N`), reused in turn.
    Hammersley,
    /// The fractional-part sequence of §6.1.
    Frac,
}

/// Radical inverse of `i` in base `b`.
pub fn radical_inverse(mut i: u64, b: u64) -> f64 {
    let inv = 1.0 / b as f64;
    let (mut f, mut r) = (inv, 0.0);
    while i > 0 {
        r += (i % b) as f64 * f;
        i /= b;
        f *= inv;
    }
    r
}

/// A generator of directions; `next_dir` must be called in order (the `frac`
/// recurrence has state), `direction(m)` is the m-th (0-based) direction.
#[derive(Clone, Debug)]
pub struct Directions {
    seq: Sequence,
    seed: u64,
    /// Current q' of the frac recurrence and how many directions it has given.
    q: f64,
    made: u64,
}

impl Directions {
    /// A generator for `seq` and `seed`.
    pub fn new(seq: Sequence, seed: u64) -> Self {
        Directions {
            seq,
            seed,
            q: PI64 + seed as f64,
            made: 0,
        }
    }

    /// The unit-square point of direction `m`; `m` must be the number of
    /// points made so far for `frac`, any value for the others.
    fn point(&mut self, m: u64) -> Vec2 {
        let s = self.seed;
        match self.seq {
            Sequence::Random => Pcg32::keyed(&[s, m, 0xD1]).next_2d(),
            Sequence::Halton => Vec2::new(
                radical_inverse(m + 1 + s, 2) as f32,
                radical_inverse(m + 1 + s, 3) as f32,
            ),
            Sequence::Hammersley => {
                let i = (m + s) % HAMMERSLEY_N;
                Vec2::new(
                    (i as f64 / HAMMERSLEY_N as f64) as f32,
                    radical_inverse(i, 2) as f32,
                )
            }
            Sequence::Frac => {
                debug_assert_eq!(m, self.made);
                let mut next = || {
                    self.q = ((PI64 - 2.0) * self.q) % 100_000.0;
                    self.q.fract()
                };
                let (u, v) = (next(), next());
                Vec2::new(u as f32, v as f32)
            }
        }
    }

    /// The next direction, uniform on the sphere.
    pub fn next_dir(&mut self) -> Vec3 {
        let m = self.made;
        let u = self.point(m);
        self.made += 1;
        // keep u strictly inside [0, 1) after the f32 rounding
        uniform_sphere(u.clamp(Vec2::ZERO, Vec2::splat(1.0 - f32::EPSILON)))
    }
}
