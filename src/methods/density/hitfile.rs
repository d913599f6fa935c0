//! The hit file of §4.1, the disk [`HitSink`] / [`HitSource`]: one 12-byte
//! record per particle hit on a surface with a diffuse part (layout:
//! [`Hit::to_bytes`]), streamed to disk in chunks and grouped by surface id.
//!
//! Grouping: hits go to `buckets` temporary files by surface-id range, as
//! they are produced (bounded buffers), and the writer counts the hits of
//! every surface side. [`HitSink::finish`] then knows where each surface's
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

use std::borrow::Cow;
use std::fs::File;
use std::io::{BufReader, BufWriter, Read, Seek, SeekFrom, Write};
use std::path::{Path, PathBuf};

use super::hits::{Hit, HitSink, HitSource, Run, HIT_BYTES};
use super::surfaces::SurfaceId;

const MAGIC: &[u8; 8] = b"KALOSHIT";

/// An I/O error on the hit file or its bucket files (the reason is the
/// error's source).
#[derive(Debug, thiserror::Error)]
#[error("hit file {}", path.display())]
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

/// Streams hits into bucket files by surface-id range; [`HitSink::finish`]
/// sorts them into the hit file.
pub struct HitWriter {
    dir: PathBuf,
    file: PathBuf,
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
    /// A writer that will put its bucket files in `dir` (created if needed)
    /// and the hit file at `file`; surface indices run over `0..surfaces`.
    pub fn new(dir: &Path, file: &Path, surfaces: u32, buckets: u32) -> Result<Self, HitFileError> {
        std::fs::create_dir_all(dir).map_err(io_err(dir))?;
        let buckets = buckets.clamp(1, 4096);
        let ids_per_bucket = surfaces.div_ceil(buckets).max(1);
        let n = surfaces.div_ceil(ids_per_bucket).max(1) as usize;
        Ok(HitWriter {
            dir: dir.to_path_buf(),
            file: file.to_path_buf(),
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

    /// Writes the header and every bucket, sorted, to `tmp`; returns the
    /// largest number of records held at once. `next[k]` is the next record
    /// of surface side k.
    fn write_sorted(
        &self,
        tmp: &Path,
        header: u64,
        offsets: &[(u64, u64)],
        next: &mut [u64],
    ) -> Result<u64, HitFileError> {
        let nb = offsets.len();
        let mut max_sort = 0u64;
        let mut f = File::create(tmp).map_err(io_err(tmp))?;
        let mut head = Vec::with_capacity(header as usize);
        head.extend_from_slice(MAGIC);
        head.extend_from_slice(&(nb as u64).to_le_bytes());
        for &(o, c) in offsets {
            head.extend_from_slice(&o.to_le_bytes());
            head.extend_from_slice(&c.to_le_bytes());
        }
        f.write_all(&head).map_err(io_err(tmp))?;
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
                        .map_err(io_err(tmp))?;
                    f.write_all(&out).map_err(io_err(tmp))?;
                    next[k] += (j - i) as u64;
                    i = j;
                }
                left -= m;
            }
            drop(r);
            std::fs::remove_file(&bp).map_err(io_err(&bp))?;
        }
        f.flush().map_err(io_err(tmp))?;
        Ok(max_sort)
    }
}

impl HitSink for HitWriter {
    type Source = HitFile;

    fn push(&mut self, hits: &[Hit]) -> Result<(), HitFileError> {
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

    /// Sorts every bucket by surface id (stable) and writes the hit file
    /// given to [`HitWriter::new`]: header `KALOSHIT`, bucket count, then (offset, count) per
    /// bucket, then the records. Written to a temporary name and renamed.
    ///
    /// The sort is a counting sort: the writer has counted every surface
    /// side's hits, so each side's first record is known, and a bucket is
    /// read in chunks of at most [`HitWriter::sort_chunk`] records, each
    /// chunk sorted stably and its runs written at their sides' next
    /// positions. The bytes are those of a stable sort of the whole bucket.
    fn finish(mut self) -> Result<HitFile, HitFileError> {
        let path = self.file.clone();
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
        // A failed write leaves no partial file (it may sit beside a kept
        // hit file, outside the scratch directory)
        let written = self
            .write_sorted(&tmp, header, &offsets, &mut next)
            .and_then(|m| {
                std::fs::rename(&tmp, &path).map_err(io_err(&path))?;
                Ok(m)
            });
        let max_sort = match written {
            Ok(m) => m,
            Err(e) => {
                let _ = std::fs::remove_file(&tmp);
                return Err(e);
            }
        };
        Ok(HitFile {
            path,
            buckets: offsets,
            runs,
            max_sort_records: max_sort,
        })
    }
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

impl HitSource for HitFile {
    fn runs(&self) -> &[Run] {
        &self.runs
    }

    fn read(&self, start: u64, count: u64) -> Result<Cow<'_, [Hit]>, HitFileError> {
        self.read_range(start, count).map(Cow::Owned)
    }

    fn hit_count(&self) -> u64 {
        self.len()
    }

    fn max_sort_records(&self) -> u64 {
        self.max_sort_records
    }
}
