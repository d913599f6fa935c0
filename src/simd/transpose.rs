//! AVX2 helpers shared by the ray core's packets (`accel/packet8.rs`),
//! `path`'s lanes (`transport/lanes`) and bundle's projection
//! (`methods/bundle/visibility/lanes.rs`).

/// The 8 × 8 transpose: lane l of the result's row k is lane k of row l
/// (the ray core's packets by field, `path`'s lanes' records by field,
/// bundle's projections by patch).
#[inline]
#[target_feature(enable = "avx2")]
pub(crate) fn transpose8(r: [std::arch::x86_64::__m256; 8]) -> [std::arch::x86_64::__m256; 8] {
    use std::arch::x86_64::*;
    let t0 = _mm256_unpacklo_ps(r[0], r[1]);
    let t1 = _mm256_unpackhi_ps(r[0], r[1]);
    let t2 = _mm256_unpacklo_ps(r[2], r[3]);
    let t3 = _mm256_unpackhi_ps(r[2], r[3]);
    let t4 = _mm256_unpacklo_ps(r[4], r[5]);
    let t5 = _mm256_unpackhi_ps(r[4], r[5]);
    let t6 = _mm256_unpacklo_ps(r[6], r[7]);
    let t7 = _mm256_unpackhi_ps(r[6], r[7]);
    let u0 = _mm256_shuffle_ps::<0x44>(t0, t2);
    let u1 = _mm256_shuffle_ps::<0xEE>(t0, t2);
    let u2 = _mm256_shuffle_ps::<0x44>(t1, t3);
    let u3 = _mm256_shuffle_ps::<0xEE>(t1, t3);
    let u4 = _mm256_shuffle_ps::<0x44>(t4, t6);
    let u5 = _mm256_shuffle_ps::<0xEE>(t4, t6);
    let u6 = _mm256_shuffle_ps::<0x44>(t5, t7);
    let u7 = _mm256_shuffle_ps::<0xEE>(t5, t7);
    [
        _mm256_permute2f128_ps::<0x20>(u0, u4),
        _mm256_permute2f128_ps::<0x20>(u1, u5),
        _mm256_permute2f128_ps::<0x20>(u2, u6),
        _mm256_permute2f128_ps::<0x20>(u3, u7),
        _mm256_permute2f128_ps::<0x31>(u0, u4),
        _mm256_permute2f128_ps::<0x31>(u1, u5),
        _mm256_permute2f128_ps::<0x31>(u2, u6),
        _mm256_permute2f128_ps::<0x31>(u3, u7),
    ]
}

#[cfg(test)]
mod tests {
    use std::arch::x86_64::*;

    /// Row k, lane l of the result is row l, lane k of the input.
    #[target_feature(enable = "avx2")]
    fn check() {
        let rows: [[f32; 8]; 8] =
            std::array::from_fn(|r| std::array::from_fn(|l| (10 * r + l) as f32));
        // SAFETY: each row is eight readable f32s (no alignment needed)
        let t = transpose8(rows.map(|r| unsafe { _mm256_loadu_ps(r.as_ptr()) }));
        for (k, v) in t.iter().enumerate() {
            let mut out = [0.0f32; 8];
            // SAFETY: `out` is eight writable f32s (no alignment needed)
            unsafe { _mm256_storeu_ps(out.as_mut_ptr(), *v) };
            let want: [f32; 8] = std::array::from_fn(|l| (10 * l + k) as f32);
            assert_eq!(out, want, "row {k}");
        }
    }

    use super::transpose8;

    #[test]
    fn transposes() {
        if !super::super::has_v3() {
            eprintln!("no AVX2: the transpose is not used here");
            return;
        }
        // SAFETY: the CPU has AVX2 (has_v3 just said so)
        unsafe { check() }
    }
}
