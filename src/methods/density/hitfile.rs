//! The hit file of §4.1: one 12-byte record per particle hit on a
//! non-specular surface, streamed to disk in chunks and grouped by surface id.
//!
//! Record layout (little-endian): surface id (u32; bit 31 = back side), u and
//! v in 16-bit fixed point over the surface's chart (barycentrics for curved
//! triangles), and the particle's RGB power relative to φ = Φ/n in the
//! shared-exponent RGB9E5 format (4 bytes). 12 bytes per hit, one RGB pass
//! (see `mod.rs` for why one pass rather than the paper's per-channel runs).
//!
//! Grouping: hits go to `buckets` temporary files by surface-id range, as
//! they are produced (bounded buffers), and the writer counts the hits of
//! every surface side. [`HitWriter::finish`] then knows where each surface's
//! records go in the single hit file (after a header holding the bucket
//! offsets) and moves every bucket there by a stable counting sort, reading
//! it in chunks of at most [`HitWriter::sort_chunk`] records: memory stays
//! bounded however many hits a bucket or a surface receives. The order of the
//! records depends only on the seed (lanes are merged in order), so a seed
//! reproduces the file byte for byte.
//!
//! Reading: [`HitFile::runs`] lists the (surface, first record, count) of
//! every surface side in file order, and [`HitFile::read_range`] reads any
//! span of records, so that phase 2 can stream a surface's hits in chunks.

use std::fs::File;
use std::io::{BufReader, BufWriter, Read, Seek, SeekFrom, Write};
use std::path::{Path, PathBuf};

use glam::Vec3;

use super::surfaces::SurfaceId;

/// Bytes per hit record.
pub const HIT_BYTES: usize = 12;
const MAGIC: &[u8; 8] = b"KALOSHIT";

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
    /// The 12 bytes of the record.
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

/// An I/O error on the hit file.
#[derive(Debug, thiserror::Error)]
#[error("hit file {}: {source}", path.display())]
pub struct HitFileError {
    /// The file.
    pub path: PathBuf,
    /// What went wrong.
    #[source]
    pub source: std::io::Error,
}

fn io_err(path: &Path) -> impl Fn(std::io::Error) -> HitFileError + '_ {
    move |source| HitFileError {
        path: path.to_path_buf(),
        source,
    }
}

/// Streams hits into bucket files by surface-id range.
pub struct HitWriter {
    dir: PathBuf,
    /// Surface ids (without the side bit) per bucket.
    ids_per_bucket: u32,
    buffers: Vec<Vec<u8>>,
    files: Vec<Option<BufWriter<File>>>,
    counts: Vec<u64>,
    /// Hits per surface side: index 2·id + side.
    side_counts: Vec<u64>,
    buffer_bytes: usize,
    /// Largest number of records the bucket sort of [`HitWriter::finish`]
    /// holds in memory at once.
    pub sort_chunk: usize,
}

impl HitWriter {
    /// A writer that will put its bucket files in `dir` (created if needed);
    /// surface ids (side bit cleared) run over `0..surfaces`.
    pub fn new(dir: &Path, surfaces: u32, buckets: u32) -> Result<Self, HitFileError> {
        std::fs::create_dir_all(dir).map_err(io_err(dir))?;
        let buckets = buckets.clamp(1, 4096);
        let ids_per_bucket = surfaces.div_ceil(buckets).max(1);
        let n = surfaces.div_ceil(ids_per_bucket).max(1) as usize;
        Ok(HitWriter {
            dir: dir.to_path_buf(),
            ids_per_bucket,
            buffers: vec![Vec::new(); n],
            files: (0..n).map(|_| None).collect(),
            counts: vec![0; n],
            side_counts: vec![0; 2 * surfaces.max(1) as usize],
            // at most 64 MB of buffers in all, 1 MB each at most
            buffer_bytes: ((64usize << 20) / n).clamp(64 << 10, 1 << 20),
            sort_chunk: 1 << 21,
        })
    }

    fn bucket_path(&self, b: usize) -> PathBuf {
        self.dir.join(format!("bucket-{b:05}.bin"))
    }

    fn bucket_of(&self, surface: SurfaceId) -> usize {
        ((surface.index / self.ids_per_bucket) as usize).min(self.buffers.len() - 1)
    }

    /// Appends a chunk of hits, in order.
    pub fn push(&mut self, hits: &[Hit]) -> Result<(), HitFileError> {
        for h in hits {
            let b = self.bucket_of(h.surface);
            self.buffers[b].extend_from_slice(&h.to_bytes());
            self.counts[b] += 1;
            let k = h.surface.side_index();
            if k >= self.side_counts.len() {
                self.side_counts.resize(k + 1, 0);
            }
            self.side_counts[k] += 1;
            if self.buffers[b].len() >= self.buffer_bytes {
                self.flush_bucket(b)?;
            }
        }
        Ok(())
    }

    fn flush_bucket(&mut self, b: usize) -> Result<(), HitFileError> {
        if self.buffers[b].is_empty() {
            return Ok(());
        }
        let path = self.bucket_path(b);
        if self.files[b].is_none() {
            let f = File::create(&path).map_err(io_err(&path))?;
            self.files[b] = Some(BufWriter::new(f));
        }
        if let Some(f) = self.files[b].as_mut() {
            f.write_all(&self.buffers[b]).map_err(io_err(&path))?;
        }
        self.buffers[b].clear();
        Ok(())
    }

    /// Total hits pushed so far.
    pub fn count(&self) -> u64 {
        self.counts.iter().sum()
    }

    /// Sorts every bucket by surface id (stable) and writes the hit file
    /// `path`: header `KALOSHIT`, bucket count, then (offset, count) per
    /// bucket, then the records. Written to a temporary name and renamed.
    ///
    /// The sort is a counting sort: the writer has counted every surface
    /// side's hits, so each side's first record is known, and a bucket is
    /// read in chunks of at most [`HitWriter::sort_chunk`] records, each
    /// chunk sorted stably and its runs written at their sides' next
    /// positions. The bytes are those of a stable sort of the whole bucket.
    pub fn finish(mut self, path: &Path) -> Result<HitFile, HitFileError> {
        for b in 0..self.buffers.len() {
            self.flush_bucket(b)?;
            if let Some(mut f) = self.files[b].take() {
                f.flush().map_err(io_err(&self.bucket_path(b)))?;
            }
        }
        self.buffers = Vec::new();
        let tmp = path.with_extension("tmp");
        let nb = self.counts.len();
        let header = 8 + 8 + 16 * nb as u64;
        let mut offsets = Vec::with_capacity(nb);
        let mut off = header;
        for &c in &self.counts {
            offsets.push((off, c));
            off += c * HIT_BYTES as u64;
        }

        // Where each surface side starts: buckets in order, inside a bucket
        // the ids in the order of `SurfaceId` (front sides, then back)
        let ns = (self.side_counts.len() / 2) as u32;
        let mut runs: Vec<Run> = Vec::new();
        let mut next = vec![0u64; self.side_counts.len()];
        let mut rec = 0u64;
        for b in 0..nb {
            let lo = b as u32 * self.ids_per_bucket;
            let hi = if b + 1 == nb {
                ns
            } else {
                ((b as u32 + 1) * self.ids_per_bucket).min(ns)
            };
            for back in [false, true] {
                for index in lo..hi {
                    let surface = SurfaceId { index, back };
                    let k = surface.side_index();
                    let c = self.side_counts[k];
                    next[k] = rec;
                    if c > 0 {
                        runs.push(Run {
                            surface,
                            start: rec,
                            count: c,
                        });
                    }
                    rec += c;
                }
            }
        }
        let mut max_sort = 0u64;
        {
            let mut f = File::create(&tmp).map_err(io_err(&tmp))?;
            let mut head = Vec::with_capacity(header as usize);
            head.extend_from_slice(MAGIC);
            head.extend_from_slice(&(nb as u64).to_le_bytes());
            for &(o, c) in &offsets {
                head.extend_from_slice(&o.to_le_bytes());
                head.extend_from_slice(&c.to_le_bytes());
            }
            f.write_all(&head).map_err(io_err(&tmp))?;
            let chunk = self.sort_chunk.max(1);
            let mut out = Vec::new();
            for b in 0..nb {
                if self.counts[b] == 0 {
                    continue;
                }
                let bp = self.bucket_path(b);
                let mut r = BufReader::new(File::open(&bp).map_err(io_err(&bp))?);
                let mut left = self.counts[b];
                let mut bytes = Vec::new();
                while left > 0 {
                    let m = left.min(chunk as u64);
                    bytes.resize(m as usize * HIT_BYTES, 0);
                    r.read_exact(&mut bytes).map_err(io_err(&bp))?;
                    let mut hits: Vec<Hit> =
                        bytes.chunks_exact(HIT_BYTES).map(Hit::from_bytes).collect();
                    max_sort = max_sort.max(m);
                    hits.sort_by_key(|h| h.surface);
                    // each run of one side goes to that side's next records
                    let mut i = 0;
                    while i < hits.len() {
                        let id = hits[i].surface;
                        let j = i + hits[i..].partition_point(|h| h.surface == id);
                        let k = id.side_index();
                        out.clear();
                        for h in &hits[i..j] {
                            out.extend_from_slice(&h.to_bytes());
                        }
                        f.seek(SeekFrom::Start(header + next[k] * HIT_BYTES as u64))
                            .map_err(io_err(&tmp))?;
                        f.write_all(&out).map_err(io_err(&tmp))?;
                        next[k] += (j - i) as u64;
                        i = j;
                    }
                    left -= m;
                }
                drop(r);
                std::fs::remove_file(&bp).map_err(io_err(&bp))?;
            }
            f.flush().map_err(io_err(&tmp))?;
        }
        std::fs::rename(&tmp, path).map_err(io_err(path))?;
        Ok(HitFile {
            path: path.to_path_buf(),
            buckets: offsets,
            runs,
            max_sort_records: max_sort,
        })
    }
}

/// The records of one surface side: a contiguous span of the hit file.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Run {
    /// The surface side.
    pub surface: SurfaceId,
    /// Index of its first record.
    pub start: u64,
    /// Number of records.
    pub count: u64,
}

/// A finished hit file: records grouped and sorted by surface id, in buckets.
#[derive(Clone, Debug)]
pub struct HitFile {
    /// Where it is.
    pub path: PathBuf,
    /// (byte offset, record count) of each bucket.
    pub buckets: Vec<(u64, u64)>,
    /// Every surface side's span of records, in file order.
    pub runs: Vec<Run>,
    /// Largest number of records the bucket sort held in memory at once (0
    /// for a file opened from disk).
    pub max_sort_records: u64,
}

impl HitFile {
    /// Opens a hit file written by [`HitWriter::finish`].
    pub fn open(path: &Path) -> Result<Self, HitFileError> {
        let bad = |m: &str| HitFileError {
            path: path.to_path_buf(),
            source: std::io::Error::new(std::io::ErrorKind::InvalidData, m.to_string()),
        };
        let mut f = BufReader::new(File::open(path).map_err(io_err(path))?);
        let mut head = [0u8; 16];
        f.read_exact(&mut head).map_err(io_err(path))?;
        if &head[0..8] != MAGIC {
            return Err(bad("not a kalos hit file"));
        }
        let nb = u64::from_le_bytes(head[8..16].try_into().unwrap_or_default());
        if nb > 1 << 20 {
            return Err(bad("bad bucket count"));
        }
        let mut buckets = Vec::with_capacity(nb as usize);
        for _ in 0..nb {
            let mut e = [0u8; 16];
            f.read_exact(&mut e).map_err(io_err(path))?;
            buckets.push((
                u64::from_le_bytes(e[0..8].try_into().unwrap_or_default()),
                u64::from_le_bytes(e[8..16].try_into().unwrap_or_default()),
            ));
        }
        // The runs: one streaming pass over the records
        let total: u64 = buckets.iter().map(|b| b.1).sum();
        let first = 16 + 16 * nb;
        if buckets.first().is_some_and(|b| b.0 != first) {
            return Err(bad("bad bucket offsets"));
        }
        let mut runs: Vec<Run> = Vec::new();
        let mut bytes = vec![0u8; 65536 * HIT_BYTES];
        let mut rec = 0u64;
        while rec < total {
            let m = (total - rec).min(65536) as usize;
            f.read_exact(&mut bytes[..m * HIT_BYTES])
                .map_err(io_err(path))?;
            for b in bytes[..m * HIT_BYTES].chunks_exact(HIT_BYTES) {
                let id = Hit::from_bytes(b).surface;
                match runs.last_mut() {
                    Some(r) if r.surface == id => r.count += 1,
                    _ => runs.push(Run {
                        surface: id,
                        start: rec,
                        count: 1,
                    }),
                }
                rec += 1;
            }
        }
        Ok(HitFile {
            path: path.to_path_buf(),
            buckets,
            runs,
            max_sort_records: 0,
        })
    }

    /// Reads `count` records from record index `start` (file order).
    pub fn read_range(&self, start: u64, count: u64) -> Result<Vec<Hit>, HitFileError> {
        let header = 16 + 16 * self.buckets.len() as u64;
        let mut f = File::open(&self.path).map_err(io_err(&self.path))?;
        f.seek(SeekFrom::Start(header + start * HIT_BYTES as u64))
            .map_err(io_err(&self.path))?;
        let mut bytes = vec![0u8; count as usize * HIT_BYTES];
        f.read_exact(&mut bytes).map_err(io_err(&self.path))?;
        Ok(bytes.chunks_exact(HIT_BYTES).map(Hit::from_bytes).collect())
    }

    /// Total number of hits.
    pub fn len(&self) -> u64 {
        self.buckets.iter().map(|b| b.1).sum()
    }

    /// True when there are no hits.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Size in bytes of the records (header excluded).
    pub fn record_bytes(&self) -> u64 {
        self.len() * HIT_BYTES as u64
    }

    /// Reads bucket `b` (sorted by surface id).
    pub fn read_bucket(&self, b: usize) -> Result<Vec<Hit>, HitFileError> {
        let Some(&(off, count)) = self.buckets.get(b) else {
            return Ok(Vec::new());
        };
        let mut f = File::open(&self.path).map_err(io_err(&self.path))?;
        f.seek(SeekFrom::Start(off)).map_err(io_err(&self.path))?;
        let mut bytes = vec![0u8; count as usize * HIT_BYTES];
        f.read_exact(&mut bytes).map_err(io_err(&self.path))?;
        Ok(bytes.chunks_exact(HIT_BYTES).map(Hit::from_bytes).collect())
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
}
