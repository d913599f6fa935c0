//! Recorded ray sets: the rays a renderer traces in its first bounce, taken
//! from a scene once with a fixed seed so that every ray core (kalos's
//! [`crate::accel::Accel`], and Embree behind the `embree` feature) answers
//! exactly the same queries.
//!
//! Three sets, as a path tracer meets them:
//! - camera rays, one per pixel (jittered within it), row by row: coherent;
//! - diffuse bounce rays, cosine-distributed about the geometric normal at
//!   each camera ray's first hit: incoherent, closest hit;
//! - shadow rays from those hits to a point sampled on the emitters
//!   ([`crate::emitter::Lights::sample_li`]): occlusion only.
//!
//! The `.krays` file (all little-endian): the magic `KALOSRAY`, the format
//! version (u32), a reserved u32 (0), the [`crate::partial::scene_hash`] of
//! the scene the rays were recorded from (u64), the seed (u64), the film
//! width and height (u32 each), the three set sizes (u64 each, camera,
//! bounce, shadow), then every ray as eight f32 (origin, direction, tmin,
//! tmax), and last an FNV-1a hash (u64) of every byte before it.

use std::fs::File;
use std::io::{Read, Write};
use std::path::{Path, PathBuf};

use glam::Vec3;
use rayon::prelude::*;

use crate::geometry::{offset_point, Frame, Ray};
use crate::image_io::{self, ImageIoError};
use crate::sampling::{cosine_hemisphere, Pcg32};
use crate::world::World;

/// The first eight bytes of a `.krays` file.
pub const MAGIC: &[u8; 8] = b"KALOSRAY";
/// The format version this kalos writes and reads.
pub const VERSION: u32 = 1;
/// Bytes before the first ray.
const HEADER_BYTES: u64 = 8 + 4 + 4 + 8 + 8 + 4 + 4 + 3 * 8;
/// Bytes of one ray.
const RAY_BYTES: u64 = 8 * 4;
/// Bytes of the closing hash.
const HASH_BYTES: u64 = 8;

/// The far end of a shadow segment from `a` to `b` stored as the ray
/// `a + t (b − a)`: short of 1, as [`crate::accel::Accel::occluded`] stops
/// short of `b`, so that the emitter's own surface never blocks it.
pub const SHADOW_TMAX: f32 = 1.0 - 1e-4;

/// Which set a ray belongs to, and so which query it asks.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum SetKind {
    /// Primary rays: closest hit.
    Camera,
    /// Diffuse bounces from the camera rays' hits: closest hit.
    Bounce,
    /// Segments from those hits to emitter points: occlusion.
    Shadow,
}

impl SetKind {
    /// The three sets, in file order.
    pub const ALL: [SetKind; 3] = [SetKind::Camera, SetKind::Bounce, SetKind::Shadow];

    /// The set's name as printed.
    pub fn name(self) -> &'static str {
        match self {
            SetKind::Camera => "camera",
            SetKind::Bounce => "bounce",
            SetKind::Shadow => "shadow",
        }
    }

    /// True for the sets that ask for the closest hit (false: occlusion).
    pub fn closest_hit(self) -> bool {
        !matches!(self, SetKind::Shadow)
    }
}

/// The three ray sets of one scene, and where they came from.
#[derive(Clone, Debug)]
pub struct RaySets {
    /// [`crate::partial::scene_hash`] of the scene (as built, with the film
    /// resolution below).
    pub scene_hash: u64,
    /// The seed they were recorded with.
    pub seed: u64,
    /// Film width in pixels.
    pub width: u32,
    /// Film height in pixels.
    pub height: u32,
    /// Camera, bounce and shadow rays, in [`SetKind::ALL`]'s order.
    pub sets: [Vec<Ray>; 3],
}

impl RaySets {
    /// The rays of one set.
    pub fn rays(&self, kind: SetKind) -> &[Ray] {
        &self.sets[kind as usize]
    }
}

/// Why a `.krays` file could not be read or written.
#[derive(Debug, thiserror::Error)]
pub enum RaySetError {
    /// The operating system refused (open, read).
    #[error("{path}: {source}", path = .path.display())]
    Io {
        /// The file.
        path: PathBuf,
        /// The underlying error.
        #[source]
        source: std::io::Error,
    },
    /// Writing failed (the file is left as it was).
    #[error(transparent)]
    Write(#[from] ImageIoError),
    /// The file does not start with [`MAGIC`].
    #[error("{path}: not a kalos ray-set file (expected a .krays file from `kalos bench --record`)", path = .path.display())]
    Foreign {
        /// The file.
        path: PathBuf,
    },
    /// Another format version.
    #[error("{path}: ray-set format version {found}; this kalos reads version {VERSION}", path = .path.display())]
    Version {
        /// The file.
        path: PathBuf,
        /// The version in the file.
        found: u32,
    },
    /// Shorter or longer than its header says.
    #[error("{path}: {found} bytes, but its header promises {expected} (the file is truncated or damaged)", path = .path.display())]
    Length {
        /// The file.
        path: PathBuf,
        /// Bytes the header's counts imply (none when they overflow).
        expected: String,
        /// Bytes in the file.
        found: u64,
    },
    /// The closing hash does not match the bytes before it.
    #[error("{path}: the checksum does not match its contents (the file is damaged)", path = .path.display())]
    Checksum {
        /// The file.
        path: PathBuf,
    },
    /// A ray that no recorder writes: non-finite, or an empty interval.
    #[error("{path}: {set} ray {index} is invalid (non-finite origin or direction, or tmax <= tmin)", path = .path.display())]
    BadRay {
        /// The file.
        path: PathBuf,
        /// The set's name.
        set: &'static str,
        /// Index within the set.
        index: usize,
    },
    /// The rays belong to another scene.
    #[error("{path}: recorded from another scene (scene hash {file:016x}; this scene, at {width}x{height}, hashes to {scene:016x})", path = .path.display())]
    OtherScene {
        /// The file.
        path: PathBuf,
        /// The hash in the file.
        file: u64,
        /// The hash of the scene given.
        scene: u64,
        /// The film width both were hashed at.
        width: u32,
        /// The film height.
        height: u32,
    },
}

/// Records the three sets from `world` with `seed`: one camera ray per pixel
/// of `world.camera`'s film, and a bounce and a shadow ray at each camera
/// ray's first hit (no shadow ray where the sampled light point is behind the
/// surface, as a renderer would not trace one). Each pixel draws from its own
/// stream, so the sets are the same whatever the thread count.
pub fn record(world: &World, seed: u64) -> RaySets {
    let (w, h) = (world.camera.width, world.camera.height);
    let rows: Vec<[Vec<Ray>; 3]> = (0..h)
        .into_par_iter()
        .map(|y| {
            let mut out: [Vec<Ray>; 3] = Default::default();
            for x in 0..w {
                record_pixel(world, seed, x, y, &mut out);
            }
            out
        })
        .collect();
    let mut sets: [Vec<Ray>; 3] = Default::default();
    for (k, set) in sets.iter_mut().enumerate() {
        set.reserve(rows.iter().map(|r| r[k].len()).sum());
        for r in &rows {
            set.extend_from_slice(&r[k]);
        }
    }
    RaySets {
        scene_hash: crate::partial::scene_hash(&world.scene),
        seed,
        width: w,
        height: h,
        sets,
    }
}

/// The camera ray of pixel (`x`, `y`), and its bounce and shadow rays.
fn record_pixel(world: &World, seed: u64, x: u32, y: u32, out: &mut [Vec<Ray>; 3]) {
    let index = y as u64 * world.camera.width as u64 + x as u64;
    let mut rng = Pcg32::keyed(&[seed, 0x7261_7973, index]);
    let ray = world
        .camera
        .ray(x as f32 + rng.next_f32(), y as f32 + rng.next_f32());
    out[0].push(ray);
    let Some(hit) = world.accel.intersect(&ray) else {
        return;
    };
    let sp = world.scene.surface_point(hit.tri, hit.b1, hit.b2);
    // The geometric normal on the viewer's side: a diffuse bounce stays on
    // that side whatever the shading normal says, and the ray core is what
    // is measured here, not the BSDF.
    let ng = if sp.ng.dot(ray.d) > 0.0 {
        -sp.ng
    } else {
        sp.ng
    };

    // Diffuse bounce: cosine-distributed about ng
    let wi = Frame::from_normal(ng).to_world(cosine_hemisphere(rng.next_2d()));
    out[1].push(Ray::new(offset_point(sp.p, ng, wi), wi));

    // Shadow ray to a point on an emitter, as next-event estimation makes it
    let (u_sel, u) = (rng.next_f32(), rng.next_2d());
    let Some(ls) = world.lights.sample_li(sp.p, u_sel, u) else {
        return;
    };
    if ls.pdf.is_nan() || ls.pdf <= 0.0 || ls.wi.dot(ng) <= 0.0 {
        return;
    }
    let o = offset_point(sp.p, ng, ls.wi);
    out[2].push(if ls.is_env {
        Ray::new(o, ls.wi)
    } else {
        Ray {
            o,
            d: offset_point(ls.p, ls.n, -ls.wi) - o,
            tmin: 0.0,
            tmax: SHADOW_TMAX,
        }
    });
}

/// FNV-1a, 64 bits, continued from `h`.
fn fnv(mut h: u64, bytes: &[u8]) -> u64 {
    for &b in bytes {
        h = (h ^ b as u64).wrapping_mul(0x0000_0100_0000_01b3);
    }
    h
}

const FNV_START: u64 = 0xcbf2_9ce4_8422_2325;

/// The file's bytes, checksum included.
fn encode(sets: &RaySets) -> Vec<u8> {
    let n: u64 = sets.sets.iter().map(|s| s.len() as u64).sum();
    let mut b = Vec::with_capacity((HEADER_BYTES + n * RAY_BYTES + HASH_BYTES) as usize);
    b.extend_from_slice(MAGIC);
    b.extend_from_slice(&VERSION.to_le_bytes());
    b.extend_from_slice(&0u32.to_le_bytes());
    b.extend_from_slice(&sets.scene_hash.to_le_bytes());
    b.extend_from_slice(&sets.seed.to_le_bytes());
    b.extend_from_slice(&sets.width.to_le_bytes());
    b.extend_from_slice(&sets.height.to_le_bytes());
    for s in &sets.sets {
        b.extend_from_slice(&(s.len() as u64).to_le_bytes());
    }
    for r in sets.sets.iter().flatten() {
        for v in [r.o.x, r.o.y, r.o.z, r.d.x, r.d.y, r.d.z, r.tmin, r.tmax] {
            b.extend_from_slice(&v.to_le_bytes());
        }
    }
    let h = fnv(FNV_START, &b);
    b.extend_from_slice(&h.to_le_bytes());
    b
}

/// Writes `sets` to `path` atomically (a temporary file, then a rename).
pub fn write(path: &Path, sets: &RaySets) -> Result<(), RaySetError> {
    let bytes = encode(sets);
    image_io::write_atomic(path, |w| {
        w.write_all(&bytes).map_err(|source| ImageIoError::Io {
            path: path.to_path_buf(),
            source,
        })
    })?;
    Ok(())
}

/// The header of a `.krays` file.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Header {
    /// The recorded scene's hash.
    pub scene_hash: u64,
    /// The seed.
    pub seed: u64,
    /// Film width.
    pub width: u32,
    /// Film height.
    pub height: u32,
    /// Rays in each set.
    pub counts: [u64; 3],
}

fn u32_at(b: &[u8], at: usize) -> u32 {
    let mut a = [0u8; 4];
    a.copy_from_slice(&b[at..at + 4]);
    u32::from_le_bytes(a)
}

fn u64_at(b: &[u8], at: usize) -> u64 {
    let mut a = [0u8; 8];
    a.copy_from_slice(&b[at..at + 8]);
    u64::from_le_bytes(a)
}

/// Reads and checks the header of `path` (magic, version, and that the
/// file's length is what the counts imply), without reading the rays.
pub fn read_header(path: &Path) -> Result<Header, RaySetError> {
    let io = |source| RaySetError::Io {
        path: path.to_path_buf(),
        source,
    };
    let mut f = File::open(path).map_err(io)?;
    let len = f.metadata().map_err(io)?.len();
    let mut b = Vec::with_capacity(HEADER_BYTES as usize);
    Read::by_ref(&mut f)
        .take(HEADER_BYTES)
        .read_to_end(&mut b)
        .map_err(io)?;
    parse_header(path, &b, len)
}

/// The header in `b` (at least its first bytes) of a file of `len` bytes.
fn parse_header(path: &Path, b: &[u8], len: u64) -> Result<Header, RaySetError> {
    let p = || path.to_path_buf();
    if b.len() < MAGIC.len() || &b[..MAGIC.len()] != MAGIC {
        // a file shorter than the magic that starts like it is truncated
        if !b.is_empty() && b.len() < MAGIC.len() && MAGIC.starts_with(b) {
            return Err(RaySetError::Length {
                path: p(),
                expected: format!("at least {HEADER_BYTES}"),
                found: len,
            });
        }
        return Err(RaySetError::Foreign { path: p() });
    }
    if b.len() < 12 {
        return Err(RaySetError::Length {
            path: p(),
            expected: format!("at least {HEADER_BYTES}"),
            found: len,
        });
    }
    let version = u32_at(b, 8);
    if version != VERSION {
        return Err(RaySetError::Version {
            path: p(),
            found: version,
        });
    }
    if (b.len() as u64) < HEADER_BYTES {
        return Err(RaySetError::Length {
            path: p(),
            expected: format!("at least {HEADER_BYTES}"),
            found: len,
        });
    }
    let counts = [u64_at(b, 40), u64_at(b, 48), u64_at(b, 56)];
    let expected = counts
        .iter()
        .try_fold(0u64, |acc, &c| acc.checked_add(c))
        .and_then(|n| n.checked_mul(RAY_BYTES))
        .and_then(|n| n.checked_add(HEADER_BYTES + HASH_BYTES));
    if expected != Some(len) {
        return Err(RaySetError::Length {
            path: p(),
            expected: expected.map_or_else(|| "more than 2^64".into(), |e| e.to_string()),
            found: len,
        });
    }
    Ok(Header {
        scene_hash: u64_at(b, 16),
        seed: u64_at(b, 24),
        width: u32_at(b, 32),
        height: u32_at(b, 36),
        counts,
    })
}

/// Reads a `.krays` file written by [`write()`]: a file of another kind, of
/// another version, truncated, damaged or holding an invalid ray is an
/// error naming it.
pub fn read(path: &Path) -> Result<RaySets, RaySetError> {
    let io = |source| RaySetError::Io {
        path: path.to_path_buf(),
        source,
    };
    // The header first, so that a foreign file's "counts" never size an
    // allocation: the length check bounds the read by the file's size.
    let header = read_header(path)?;
    let b = std::fs::read(path).map_err(io)?;
    let header2 = parse_header(path, &b, b.len() as u64)?;
    if header2 != header {
        // the file changed between the two reads
        return Err(RaySetError::Checksum {
            path: path.to_path_buf(),
        });
    }
    let body = b.len() - HASH_BYTES as usize;
    if fnv(FNV_START, &b[..body]) != u64_at(&b, body) {
        return Err(RaySetError::Checksum {
            path: path.to_path_buf(),
        });
    }
    let mut at = HEADER_BYTES as usize;
    let mut sets: [Vec<Ray>; 3] = Default::default();
    for (k, set) in sets.iter_mut().enumerate() {
        let n = header.counts[k] as usize;
        set.reserve(n);
        for index in 0..n {
            let f = |i: usize| {
                f32::from_le_bytes([
                    b[at + 4 * i],
                    b[at + 4 * i + 1],
                    b[at + 4 * i + 2],
                    b[at + 4 * i + 3],
                ])
            };
            let r = Ray {
                o: Vec3::new(f(0), f(1), f(2)),
                d: Vec3::new(f(3), f(4), f(5)),
                tmin: f(6),
                tmax: f(7),
            };
            at += RAY_BYTES as usize;
            let ok = r.o.is_finite()
                && r.d.is_finite()
                && r.d != Vec3::ZERO
                && r.tmin.is_finite()
                && r.tmin >= 0.0
                && r.tmax > r.tmin;
            if !ok {
                return Err(RaySetError::BadRay {
                    path: path.to_path_buf(),
                    set: SetKind::ALL[k].name(),
                    index,
                });
            }
            set.push(r);
        }
    }
    Ok(RaySets {
        scene_hash: header.scene_hash,
        seed: header.seed,
        width: header.width,
        height: header.height,
        sets,
    })
}

/// Checks that `sets`, read from `path`, were recorded from the scene whose
/// [`crate::partial::scene_hash`] is `scene_hash`.
pub fn check_scene(path: &Path, sets: &RaySets, scene_hash: u64) -> Result<(), RaySetError> {
    if sets.scene_hash == scene_hash {
        return Ok(());
    }
    Err(RaySetError::OtherScene {
        path: path.to_path_buf(),
        file: sets.scene_hash,
        scene: scene_hash,
        width: sets.width,
        height: sets.height,
    })
}
