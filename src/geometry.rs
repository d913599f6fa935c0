//! Rays, shading frames and robust ray origins.

use glam::Vec3;

/// A ray `o + t d` for `t` in `[tmin, tmax)`.
#[derive(Clone, Copy, Debug)]
pub struct Ray {
    /// Origin.
    pub o: Vec3,
    /// Direction (unit length unless stated otherwise).
    pub d: Vec3,
    /// Smallest accepted distance.
    pub tmin: f32,
    /// Largest accepted distance.
    pub tmax: f32,
}

impl Ray {
    /// A ray with an unbounded far end.
    pub fn new(o: Vec3, d: Vec3) -> Self {
        Ray {
            o,
            d,
            tmin: 0.0,
            tmax: f32::INFINITY,
        }
    }

    /// The point at distance `t`.
    pub fn at(&self, t: f32) -> Vec3 {
        self.o + self.d * t
    }
}

/// An orthonormal frame whose `n` axis is the (shading) normal; local
/// coordinates put the normal on +z, as in pbrt and Mitsuba.
#[derive(Clone, Copy, Debug)]
pub struct Frame {
    /// First tangent.
    pub s: Vec3,
    /// Second tangent.
    pub t: Vec3,
    /// Normal.
    pub n: Vec3,
}

impl Frame {
    /// A frame around the unit vector `n` (Duff et al. 2017, "Building an
    /// orthonormal basis, revisited": branchless and continuous almost everywhere).
    pub fn from_normal(n: Vec3) -> Self {
        let sign = 1.0f32.copysign(n.z);
        let a = -1.0 / (sign + n.z);
        let b = n.x * n.y * a;
        let s = Vec3::new(1.0 + sign * n.x * n.x * a, sign * b, -sign * n.x);
        let t = Vec3::new(b, sign + n.y * n.y * a, -n.y);
        Frame { s, t, n }
    }

    /// World to local.
    #[inline]
    pub fn to_local(&self, v: Vec3) -> Vec3 {
        Vec3::new(v.dot(self.s), v.dot(self.t), v.dot(self.n))
    }

    /// Local to world.
    #[inline]
    pub fn to_world(&self, v: Vec3) -> Vec3 {
        self.s * v.x + self.t * v.y + self.n * v.z
    }
}

/// Moves a surface point off its surface along the geometric normal `ng`, to the
/// side that `dir` points into, so that a ray leaving it cannot hit the
/// surface it starts on. Integer-ULP offset of Wächter and Binder ("A fast and
/// robust method for avoiding self-intersection", Ray Tracing Gems, ch. 6):
/// the step scales with the magnitude of the coordinates, so it works for
/// scenes in millimetres and in metres alike.
#[inline]
pub fn offset_point(p: Vec3, ng: Vec3, dir: Vec3) -> Vec3 {
    let n = if ng.dot(dir) < 0.0 { -ng } else { ng };
    #[cfg(target_arch = "x86_64")]
    {
        offset_point_sse2(p, n)
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        offset_point_scalar(p, n)
    }
}

/// [`offset_point`]'s constants: below `ORIGIN` a coordinate moves by
/// `FLOAT_SCALE · n` (its ULPs are too small there), above it by
/// `INT_SCALE · n` ULPs.
const ORIGIN: f32 = 1.0 / 32.0;
const FLOAT_SCALE: f32 = 1.0 / 65536.0;
const INT_SCALE: f32 = 256.0;

/// [`offset_point`] for a normal `n` already facing the side to move to,
/// one coordinate at a time: the definition that the SSE2 copy reproduces
/// bit for bit.
#[cfg_attr(target_arch = "x86_64", allow(dead_code))]
#[inline]
fn offset_point_scalar(p: Vec3, n: Vec3) -> Vec3 {
    let step = |pc: f32, nc: f32| -> f32 {
        if pc.abs() < ORIGIN {
            pc + FLOAT_SCALE * nc
        } else {
            let oi = (INT_SCALE * nc) as i32;
            let bits = pc.to_bits() as i32;
            let moved = if pc < 0.0 {
                bits.wrapping_sub(oi)
            } else {
                bits.wrapping_add(oi)
            };
            f32::from_bits(moved as u32)
        }
    };
    Vec3::new(step(p.x, n.x), step(p.y, n.y), step(p.z, n.z))
}

/// [`offset_point_scalar`] on the three coordinates at once with SSE2 (part
/// of baseline x86-64), without branches: a path vertex offsets two or three
/// points, and the scalar form's saturating float-to-int casts and
/// per-coordinate branches cost more than the arithmetic.
#[cfg(target_arch = "x86_64")]
#[inline]
fn offset_point_sse2(p: Vec3, n: Vec3) -> Vec3 {
    use std::arch::x86_64::*;
    // SAFETY: SSE2 is part of every x86-64 CPU; the intrinsics only read and
    // write their register arguments and the local array.
    unsafe {
        let pv = _mm_set_ps(0.0, p.z, p.y, p.x);
        let nv = _mm_set_ps(0.0, n.z, n.y, n.x);
        // (INT_SCALE n) as i32 with Rust's saturating semantics: the
        // truncating conversion gives i32::MIN for NaN and out-of-range
        // lanes; flip the ones at or above 2^31 to i32::MAX and zero NaN
        let sn = _mm_mul_ps(_mm_set1_ps(INT_SCALE), nv);
        let mut oi = _mm_cvttps_epi32(sn);
        oi = _mm_xor_si128(
            oi,
            _mm_castps_si128(_mm_cmpge_ps(sn, _mm_set1_ps(2_147_483_648.0))),
        );
        oi = _mm_and_si128(oi, _mm_castps_si128(_mm_cmpord_ps(sn, sn)));
        // bits ± oi: negate oi where p < 0 (two's complement: (oi ^ m) - m)
        let neg = _mm_castps_si128(_mm_cmplt_ps(pv, _mm_setzero_ps()));
        let signed = _mm_sub_epi32(_mm_xor_si128(oi, neg), neg);
        let pi = _mm_castsi128_ps(_mm_add_epi32(_mm_castps_si128(pv), signed));
        // near the origin, a fixed step along n instead
        let pf = _mm_add_ps(pv, _mm_mul_ps(_mm_set1_ps(FLOAT_SCALE), nv));
        let abs = _mm_and_ps(pv, _mm_castsi128_ps(_mm_set1_epi32(0x7fff_ffff)));
        let small = _mm_cmplt_ps(abs, _mm_set1_ps(ORIGIN));
        let r = _mm_or_ps(_mm_and_ps(small, pf), _mm_andnot_ps(small, pi));
        let mut out = [0.0f32; 4];
        _mm_storeu_ps(out.as_mut_ptr(), r);
        Vec3::new(out[0], out[1], out[2])
    }
}

/// `x.floor()`, bit for bit (the sign of zero included), without the libm
/// call that baseline x86-64 makes for it (it has no SSE4.1 `roundss`);
/// for texture lookups, which run in the baseline copy of the shading.
#[inline(always)]
pub fn floor(x: f32) -> f32 {
    // From 2^23 on every f32 is an integer; NaN and the infinities fail the
    // test too and are their own floor
    if x.abs() < 8_388_608.0 {
        // SAFETY: |x| < 2^23 fits in an i32 (the cast truncates toward 0)
        let t = unsafe { x.to_int_unchecked::<i32>() } as f32;
        let f = if t > x { t - 1.0 } else { t };
        // floor has the sign of x: -0.0 stays -0.0, (-1, 0) gives -1
        f.copysign(x)
    } else {
        x
    }
}

/// Reflects `v` about the +z axis of a local frame.
#[inline]
pub fn reflect_local(v: Vec3) -> Vec3 {
    Vec3::new(-v.x, -v.y, v.z)
}

/// Mitsuba's `lookat` camera-to-world transform: columns left, up, forward
/// and the origin, with left = normalize(up × dir).
pub fn look_at(origin: Vec3, target: Vec3, up: Vec3) -> glam::Mat4 {
    let dir = (target - origin).normalize_or(Vec3::Z);
    let left = up.cross(dir).normalize_or(Vec3::X);
    let new_up = dir.cross(left);
    glam::Mat4::from_cols(
        left.extend(0.0),
        new_up.extend(0.0),
        dir.extend(0.0),
        origin.extend(1.0),
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The SSE2 copy of `offset_point` must round exactly like the scalar
    /// definition, including the saturating casts (NaN, huge normals) and
    /// the switch at `ORIGIN`, so that images do not change.
    #[test]
    fn floor_matches_std() {
        let mut values = vec![
            0.0f32,
            -0.0,
            0.5,
            -0.5,
            1.0,
            -1.0,
            -1.5,
            8_388_607.5,
            -8_388_607.5,
            8_388_608.0,
            -8_388_609.0,
            1e30,
            -1e30,
            f32::INFINITY,
            f32::NEG_INFINITY,
            f32::MIN_POSITIVE,
            -f32::MIN_POSITIVE,
        ];
        let mut rng = crate::sampling::Pcg32::keyed(&[3]);
        for _ in 0..100_000 {
            let x = (rng.next_f32() - 0.5) * 2f32.powi((rng.next_f32() * 60.0) as i32 - 20);
            values.push(x);
        }
        for x in values {
            assert_eq!(floor(x).to_bits(), x.floor().to_bits(), "{x}");
        }
        assert!(floor(f32::NAN).is_nan());
    }

    #[test]
    #[cfg(target_arch = "x86_64")]
    fn offset_point_sse2_matches_scalar() {
        let special = [
            0.0,
            -0.0,
            1e-30,
            -1e-30,
            ORIGIN,
            -ORIGIN,
            ORIGIN * 0.999,
            1.0,
            -1.0,
            3.5e7,
            -2.0e9,
            f32::MAX,
            f32::INFINITY,
            f32::NEG_INFINITY,
            f32::NAN,
        ];
        let mut rng = crate::sampling::Pcg32::keyed(&[7]);
        let check = |p: Vec3, n: Vec3| {
            let a = offset_point_scalar(p, n);
            let b = offset_point_sse2(p, n);
            assert_eq!(
                a.to_array().map(f32::to_bits),
                b.to_array().map(f32::to_bits),
                "p {p:?} n {n:?}"
            );
        };
        for &x in &special {
            for &y in &special {
                check(Vec3::new(x, y, -x), Vec3::new(y, x, 0.5));
                check(Vec3::new(y, 1.0, x), Vec3::new(x * 1e-3, -y, x));
            }
        }
        for _ in 0..100_000 {
            let r = |rng: &mut crate::sampling::Pcg32| (rng.next_f32() - 0.5) * 200.0;
            let p = Vec3::new(r(&mut rng), r(&mut rng), r(&mut rng)) * rng.next_f32().powi(8);
            let n = Vec3::new(r(&mut rng), r(&mut rng), r(&mut rng)).normalize_or(Vec3::Z);
            check(p, n);
        }
    }
}
