//! The particle hits of §4.1 and where they are kept between phase 1 and
//! phase 2: a [`HitSink`] that phase 1 writes into, in the order the
//! particles are traced, and that [`HitSink::finish`] turns into a
//! [`HitSource`] holding every surface side's records together (the sort
//! "by surface id" of §4.2), which phase 2 reads back in chunks.
//!
//! Two stores: the hit file of [`super::hitfile`] (the paper's: bounded
//! memory whatever the particle count), and [`MemoryWriter`] /
//! [`MemoryHits`], every hit in one vector, for tests and small runs. Both
//! keep a side's records in the order they were pushed, and phase 2 does
//! not depend on the order of the sides, so a bake gives the same bytes
//! with either.
//!
//! Record: the surface side ([`SurfaceId`]), u and v in 16-bit fixed point
//! over the surface's chart (barycentrics for curved triangles), and the
//! particle's RGB power relative to φ = Φ/n in the shared-exponent RGB9E5
//! format: 12 bytes on disk (see `mod.rs` for why one RGB pass rather than
//! the paper's per-channel runs of 8 bytes).

use std::borrow::Cow;

use glam::Vec3;

use super::hitfile::HitFileError;
use super::surfaces::SurfaceId;

/// Bytes per hit record.
pub const HIT_BYTES: usize = 12;

/// One particle hit.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Hit {
    /// The surface side that was hit.
    pub surface: SurfaceId,
    /// Chart coordinate u in 1/65535 of the chart's width.
    pub u: u16,
    /// Chart coordinate v.
    pub v: u16,
    /// RGB9E5 power relative to φ.
    pub rgb: u32,
}

impl Hit {
    /// The 12 bytes of the record (little-endian: encoded surface id, u, v,
    /// power).
    pub fn to_bytes(self) -> [u8; HIT_BYTES] {
        let mut b = [0u8; HIT_BYTES];
        b[0..4].copy_from_slice(&self.surface.encode().to_le_bytes());
        b[4..6].copy_from_slice(&self.u.to_le_bytes());
        b[6..8].copy_from_slice(&self.v.to_le_bytes());
        b[8..12].copy_from_slice(&self.rgb.to_le_bytes());
        b
    }

    /// Reads a record.
    pub fn from_bytes(b: &[u8]) -> Hit {
        let w = |i: usize| u32::from_le_bytes([b[i], b[i + 1], b[i + 2], b[i + 3]]);
        Hit {
            surface: SurfaceId::decode(w(0)),
            u: u16::from_le_bytes([b[4], b[5]]),
            v: u16::from_le_bytes([b[6], b[7]]),
            rgb: w(8),
        }
    }
}

/// Fixed point of a coordinate in [0, 1] (clamped), rounded to nearest.
#[inline]
pub fn to_fixed(x: f32) -> u16 {
    (x.clamp(0.0, 1.0) * 65535.0 + 0.5) as u16
}

/// The coordinate of a fixed-point value (cell-exact inverse of [`to_fixed`]).
#[inline]
pub fn from_fixed(x: u16) -> f32 {
    x as f32 / 65535.0
}

/// Encodes non-negative RGB in RGB9E5 (9-bit mantissas, shared 5-bit
/// exponent, as OpenGL's GL_RGB9_E5), rounding to nearest.
pub fn encode_rgb9e5(c: Vec3) -> u32 {
    const MAX: f32 = 65408.0;
    let c = c.max(Vec3::ZERO).min(Vec3::splat(MAX));
    let c = Vec3::new(
        if c.x.is_finite() { c.x } else { 0.0 },
        if c.y.is_finite() { c.y } else { 0.0 },
        if c.z.is_finite() { c.z } else { 0.0 },
    );
    let m = c.max_element();
    if m <= 0.0 {
        return 0;
    }
    let mut e = (m.log2().floor() as i32).max(-16) + 1 + 15;
    let mut denom = 2f32.powi(e - 15 - 9);
    if (m / denom + 0.5).floor() >= 512.0 {
        e += 1;
        denom *= 2.0;
    }
    let e = e.clamp(0, 31);
    let q = |x: f32| ((x / denom + 0.5).floor() as u32).min(511);
    q(c.x) | (q(c.y) << 9) | (q(c.z) << 18) | ((e as u32) << 27)
}

/// Decodes RGB9E5.
pub fn decode_rgb9e5(v: u32) -> Vec3 {
    let e = (v >> 27) as i32;
    let s = 2f32.powi(e - 15 - 9);
    Vec3::new(
        (v & 511) as f32 * s,
        ((v >> 9) & 511) as f32 * s,
        ((v >> 18) & 511) as f32 * s,
    )
}

/// The records of one surface side: a contiguous span of a [`HitSource`].
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Run {
    /// The surface side.
    pub surface: SurfaceId,
    /// Index of its first record.
    pub start: u64,
    /// Number of records.
    pub count: u64,
}

/// Where phase 1 writes its hits.
pub trait HitSink {
    /// What the hits become once grouped by surface side.
    type Source: HitSource;

    /// Appends a chunk of hits, in order.
    fn push(&mut self, hits: &[Hit]) -> Result<(), HitFileError>;

    /// Groups the hits by surface side, keeping each side's records in the
    /// order they were pushed (a stable sort by surface id, §4.2).
    fn finish(self) -> Result<Self::Source, HitFileError>;
}

/// Hits grouped by surface side, read back in chunks by phase 2.
pub trait HitSource {
    /// Every surface side that received hits, once, with its span of
    /// records. The order of the sides is the store's own.
    fn runs(&self) -> &[Run];

    /// `count` records from record index `start` (borrowed when the store
    /// holds them in memory).
    fn read(&self, start: u64, count: u64) -> Result<Cow<'_, [Hit]>, HitFileError>;

    /// Number of hits held.
    fn hit_count(&self) -> u64;

    /// Largest number of records the grouping held in memory at once.
    fn max_sort_records(&self) -> u64;
}

/// A [`HitSink`] that keeps every hit in memory.
#[derive(Clone, Debug, Default)]
pub struct MemoryWriter {
    hits: Vec<Hit>,
}

impl MemoryWriter {
    /// An empty store.
    pub fn new() -> Self {
        Self::default()
    }
}

impl HitSink for MemoryWriter {
    type Source = MemoryHits;

    fn push(&mut self, hits: &[Hit]) -> Result<(), HitFileError> {
        self.hits.extend_from_slice(hits);
        Ok(())
    }

    fn finish(mut self) -> Result<MemoryHits, HitFileError> {
        // stable: a side's records stay in the order they were traced
        self.hits.sort_by_key(|h| h.surface);
        let mut runs: Vec<Run> = Vec::new();
        for (i, h) in self.hits.iter().enumerate() {
            match runs.last_mut() {
                Some(r) if r.surface == h.surface => r.count += 1,
                _ => runs.push(Run {
                    surface: h.surface,
                    start: i as u64,
                    count: 1,
                }),
            }
        }
        Ok(MemoryHits {
            hits: self.hits,
            runs,
        })
    }
}

/// Hits grouped by surface side, in memory (from [`MemoryWriter`]).
#[derive(Clone, Debug, Default)]
pub struct MemoryHits {
    hits: Vec<Hit>,
    runs: Vec<Run>,
}

impl MemoryHits {
    /// Every record, grouped by surface side in the order of [`SurfaceId`].
    pub fn hits(&self) -> &[Hit] {
        &self.hits
    }
}

impl HitSource for MemoryHits {
    fn runs(&self) -> &[Run] {
        &self.runs
    }

    fn read(&self, start: u64, count: u64) -> Result<Cow<'_, [Hit]>, HitFileError> {
        Ok(Cow::Borrowed(
            &self.hits[start as usize..(start + count) as usize],
        ))
    }

    fn hit_count(&self) -> u64 {
        self.hits.len() as u64
    }

    fn max_sort_records(&self) -> u64 {
        self.hits.len() as u64
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rgb9e5_round_trip_is_close() {
        for c in [
            Vec3::new(1.0, 0.5, 0.25),
            Vec3::new(3.7, 0.01, 0.0),
            Vec3::new(1e-3, 2e-3, 3e-3),
        ] {
            let d = decode_rgb9e5(encode_rgb9e5(c));
            assert!(
                (d - c).abs().max_element() <= c.max_element() / 256.0,
                "{c} {d}"
            );
        }
        assert_eq!(decode_rgb9e5(encode_rgb9e5(Vec3::ZERO)), Vec3::ZERO);
    }

    #[test]
    fn surface_id_round_trips_and_orders_as_encoded() {
        let ids = [
            SurfaceId::front(0),
            SurfaceId::front(7),
            SurfaceId {
                index: 3,
                back: true,
            },
            SurfaceId {
                index: (1 << 31) - 1,
                back: true,
            },
        ];
        for id in ids {
            assert_eq!(SurfaceId::decode(id.encode()), id);
            let h = Hit {
                surface: id,
                u: 1,
                v: 2,
                rgb: 3,
            };
            assert_eq!(Hit::from_bytes(&h.to_bytes()), h);
        }
        for a in ids {
            for b in ids {
                assert_eq!(a.cmp(&b), a.encode().cmp(&b.encode()));
            }
        }
    }
}
