//! The partial-result file (`.kpart`): a text header that `head` shows,
//! then the sums as raw little-endian f64, so that they round-trip exactly
//! (an EXR holds f32 at most, which would lose the exactness of a merge).
//!
//! ```text
//! kalos-partial 1
//! method path
//! kind exact
//! settings Path(Settings { seed: 0, max_depth: None, rr_depth: 5 })
//! seed 0
//! max_depth none
//! scene 3f2a9c0d1b7e4410
//! scene_source builtin:cornell-box
//! size 256 256
//! shard 0/4
//! passes 16
//! rays 2466813
//! seconds 0.81
//! spp 16
//! counter NAME VALUE          (any number)
//! buffer NAME PIXELS          (any number)
//! end
//! <for each buffer in order: PIXELS × (r, g, b) as f64 little-endian>
//! ```

use std::io::Write;
use std::path::Path;

use glam::DVec3;

use super::{Meta, Partial, PartialError, Shard, ShardKind, State};
use crate::image_io::{write_atomic, ImageIoError};

const MAGIC: &str = "kalos-partial 1";

/// Writes the partial result of `state` in the render `meta` to `path`,
/// atomically (a temporary file, then a rename).
pub fn write(path: &Path, meta: &Meta, state: &State) -> Result<(), PartialError> {
    let m = meta;
    let s = state;
    let mut head = String::new();
    let mut line = |k: &str, v: String| {
        head += k;
        head += " ";
        head += &v;
        head += "\n";
    };
    line("kalos-partial", "1".into());
    line("method", m.method.clone());
    line("kind", m.kind.word().into());
    line("settings", one_line(&m.settings));
    line("seed", m.seed.to_string());
    line(
        "max_depth",
        m.max_depth.map_or("none".into(), |d| d.to_string()),
    );
    line("scene", format!("{:016x}", m.scene_hash));
    line("scene_source", one_line(&m.scene_source));
    line("size", format!("{} {}", m.width, m.height));
    line("shard", m.shard.to_string());
    line("passes", s.passes.to_string());
    line("rays", s.rays.to_string());
    line("seconds", s.seconds.to_string());
    line("spp", s.spp.to_string());
    for (k, v) in &s.counters {
        line("counter", format!("{k} {v}"));
    }
    for (k, b) in &s.buffers {
        line("buffer", format!("{k} {}", b.len()));
    }
    head += "end\n";
    write_atomic(path, |w| {
        let io = |source| ImageIoError::Io {
            path: path.to_path_buf(),
            source,
        };
        w.write_all(head.as_bytes()).map_err(io)?;
        for (_, b) in &s.buffers {
            let bytes: Vec<u8> = b
                .iter()
                .flat_map(|v| v.to_array())
                .flat_map(f64::to_le_bytes)
                .collect();
            w.write_all(&bytes).map_err(io)?;
        }
        Ok(())
    })?;
    Ok(())
}

/// Text without line breaks (a header field is one line).
fn one_line(s: &str) -> String {
    s.replace(['\n', '\r'], " ")
}

/// Reads a partial result written by [`write`].
pub fn read(path: &Path) -> Result<Partial, PartialError> {
    let bytes = std::fs::read(path).map_err(|source| PartialError::Io {
        path: path.to_path_buf(),
        source,
    })?;
    decode(&bytes).map_err(|reason| PartialError::Malformed {
        path: path.to_path_buf(),
        reason,
    })
}

/// Parses the bytes of a partial-result file.
fn decode(bytes: &[u8]) -> Result<Partial, String> {
    if !bytes.starts_with(MAGIC.as_bytes()) {
        return Err(format!(
            "not a kalos partial result (expected a first line '{MAGIC}', as `kalos render --shard` \
             and `--checkpoint` write)"
        ));
    }
    let end = find(bytes, b"\nend\n").ok_or("the header has no 'end' line (truncated file?)")?;
    let head = std::str::from_utf8(&bytes[..end]).map_err(|_| "the header is not UTF-8")?;
    let mut data = &bytes[end + 5..];

    let mut field = std::collections::HashMap::new();
    let mut counters = Vec::new();
    let mut buffers: Vec<(String, usize)> = Vec::new();
    for (n, l) in head.lines().enumerate().skip(1) {
        let line_no = n + 1;
        let (k, v) = l
            .split_once(' ')
            .ok_or_else(|| format!("header line {line_no}: expected 'KEY VALUE', got '{l}'"))?;
        match k {
            "counter" | "buffer" => {
                let (name, num) = v.rsplit_once(' ').ok_or_else(|| {
                    format!("header line {line_no}: expected '{k} NAME NUMBER', got '{l}'")
                })?;
                let num: u64 = num
                    .parse()
                    .map_err(|_| format!("header line {line_no}: '{num}' is not a whole number"))?;
                if k == "counter" {
                    counters.push((name.to_string(), num));
                } else {
                    buffers.push((name.to_string(), num as usize));
                }
            }
            _ => {
                if field
                    .insert(k.to_string(), (v.to_string(), line_no))
                    .is_some()
                {
                    return Err(format!("header line {line_no}: '{k}' given twice"));
                }
            }
        }
    }
    let get = |k: &str| {
        field
            .get(k)
            .map(|(v, n)| (v.as_str(), *n))
            .ok_or_else(|| format!("the header has no '{k}' line"))
    };
    fn num<T: std::str::FromStr>(k: &str, (v, n): (&str, usize)) -> Result<T, String> {
        v.parse()
            .map_err(|_| format!("header line {n}: '{k}' expects a number, got '{v}'"))
    }
    let (size, size_line) = get("size")?;
    let (w, h) = size
        .split_once(' ')
        .ok_or_else(|| format!("header line {size_line}: 'size' expects 'W H'"))?;
    let (w, h): (u32, u32) = (num("size", (w, size_line))?, num("size", (h, size_line))?);
    let (shard, shard_line) = get("shard")?;
    let shard =
        Shard::parse(shard).map_err(|e| format!("header line {shard_line}: 'shard': {e}"))?;
    let kind = match get("kind")? {
        ("exact", _) => ShardKind::Exact,
        ("chains", _) => ShardKind::Chains,
        (v, n) => {
            return Err(format!(
                "header line {n}: 'kind' expects exact or chains, got '{v}'"
            ))
        }
    };
    let max_depth = match get("max_depth")? {
        ("none", _) => None,
        v => Some(num("max_depth", v)?),
    };
    let (scene, scene_line) = get("scene")?;
    let scene_hash = u64::from_str_radix(scene, 16)
        .map_err(|_| format!("header line {scene_line}: 'scene' expects 16 hex digits"))?;
    let meta = Meta {
        method: get("method")?.0.to_string(),
        settings: get("settings")?.0.to_string(),
        seed: num("seed", get("seed")?)?,
        max_depth,
        scene_hash,
        scene_source: get("scene_source")?.0.to_string(),
        width: w,
        height: h,
        shard,
        kind,
    };

    // The sums, each checked against the size the header gives
    let pixels = w as usize * h as usize;
    let mut out = Vec::new();
    for (name, len) in buffers {
        if len != pixels {
            return Err(format!(
                "buffer '{name}' has {len} pixels but the film is {w}x{h}"
            ));
        }
        let need = len * 24;
        if data.len() < need {
            return Err(format!(
                "buffer '{name}' needs {need} bytes but the file has {} left (truncated file?)",
                data.len()
            ));
        }
        let (b, rest) = data.split_at(need);
        data = rest;
        let f = |i: usize| f64::from_le_bytes(b[i * 8..i * 8 + 8].try_into().expect("8 bytes"));
        let v: Vec<DVec3> = (0..len)
            .map(|i| DVec3::new(f(3 * i), f(3 * i + 1), f(3 * i + 2)))
            .collect();
        if v.iter().any(|p| !p.is_finite()) {
            return Err(format!("buffer '{name}' holds a NaN or infinite sum"));
        }
        out.push((name, v));
    }
    if !data.is_empty() {
        return Err(format!(
            "{} bytes follow the last buffer (a damaged file?)",
            data.len()
        ));
    }
    let seconds: f64 = num("seconds", get("seconds")?)?;
    let spp: f64 = num("spp", get("spp")?)?;
    if !(seconds.is_finite() && seconds >= 0.0 && spp.is_finite() && spp >= 0.0) {
        return Err("'seconds' and 'spp' must be finite and ≥ 0".into());
    }
    Ok(Partial {
        meta,
        state: State {
            passes: num("passes", get("passes")?)?,
            rays: num("rays", get("rays")?)?,
            seconds,
            spp,
            counters,
            buffers: out,
        },
    })
}

fn find(hay: &[u8], needle: &[u8]) -> Option<usize> {
    hay.windows(needle.len()).position(|w| w == needle)
}
