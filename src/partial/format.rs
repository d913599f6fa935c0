//! The partial-result file (`.kpart`): a text header that `head` shows,
//! then the sums as raw little-endian f64, so that they round-trip exactly
//! (an EXR holds f32 at most, which would lose the exactness of a merge).
//!
//! ```text
//! kalos-partial 2
//! method path
//! kind exact
//! settings {"path":{"seed":0,"max_depth":null,"rr_depth":5,"light_selection":"spatial"}}
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
//!
//! `settings` is the [`MethodConfig`] as one line of JSON (serde's form:
//! an object keyed by the method's name, holding every field of its
//! `Settings`), read back into the equal value, so that the parts of one
//! render are recognised by their settings and a misspelt or foreign
//! field is an error. `method` repeats the name for `head` and must agree.
//! Version 1 stored the settings as Rust `Debug` text, which cannot be
//! read back: such a file is refused with the advice to re-render it.

use std::io::Write;
use std::path::Path;

use glam::DVec3;

use super::{Meta, Partial, PartialError, Shard, ShardKind, State};
use crate::image_io::{write_atomic, ImageIoError};
use crate::methods::MethodConfig;

/// The first line's key and the format's version.
const MAGIC_KEY: &str = "kalos-partial";
const VERSION: u32 = 2;

/// Writes the partial result of `state` in the render `meta` to `path`,
/// atomically (a temporary file, then a rename).
pub fn write(path: &Path, meta: &Meta, state: &State) -> Result<(), PartialError> {
    let head = header(meta, state).map_err(|reason| PartialError::Malformed {
        path: path.to_path_buf(),
        reason,
    })?;
    write_atomic(path, |w| {
        encode(&head, state, w).map_err(|source| ImageIoError::Io {
            path: path.to_path_buf(),
            source,
        })
    })?;
    Ok(())
}

/// The text header of a partial result, up to and with its `end` line, or
/// why the settings cannot be written (a path that is not UTF-8).
fn header(m: &Meta, s: &State) -> Result<String, String> {
    let settings = serde_json::to_string(&m.settings)
        .map_err(|e| format!("cannot write the method's settings: {e}"))?;
    let mut head = String::new();
    let mut line = |k: &str, v: String| {
        head += k;
        head += " ";
        head += &v;
        head += "\n";
    };
    line(MAGIC_KEY, VERSION.to_string());
    line("method", m.method().into());
    line("kind", m.kind.word().into());
    // serde_json escapes line breaks inside strings: the JSON is one line
    line("settings", settings);
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
    Ok(head)
}

/// Writes the header `head` and the buffers of `state` to `w`, a buffer at
/// a time (a film is not copied whole).
fn encode(head: &str, state: &State, w: &mut impl Write) -> std::io::Result<()> {
    w.write_all(head.as_bytes())?;
    for (_, b) in &state.buffers {
        for rows in b.chunks(4096) {
            let bytes: Vec<u8> = rows
                .iter()
                .flat_map(|v| v.to_array())
                .flat_map(f64::to_le_bytes)
                .collect();
            w.write_all(&bytes)?;
        }
    }
    Ok(())
}

/// Text without line breaks (a header field is one line).
fn one_line(s: &str) -> String {
    s.replace(['\n', '\r'], " ")
}

/// Reads a partial result written by [`write()`].
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
    check_version(bytes)?;
    let end = find(bytes, b"\nend\n").ok_or("the header has no 'end' line (truncated file?)")?;
    let head = std::str::from_utf8(&bytes[..end]).map_err(|_| "the header is not UTF-8")?;
    let mut header = Header::parse(head)?;
    let meta = header.meta()?;
    let buffers = std::mem::take(&mut header.buffers);
    let buffers = read_buffers(&bytes[end + 5..], buffers, meta.width, meta.height)?;
    let get = |k: &str| header.get(k);
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
            counters: header.counters,
            buffers,
        },
    })
}

/// Checks the first line: this format's magic and version, or a message
/// that says which kalos wrote the file.
fn check_version(bytes: &[u8]) -> Result<(), String> {
    let first = bytes.split(|&b| b == b'\n').next().unwrap_or_default();
    let version = std::str::from_utf8(first)
        .ok()
        .and_then(|l| l.strip_prefix(MAGIC_KEY))
        .and_then(|v| v.strip_prefix(' '));
    match version.map(str::trim) {
        Some(v) if v == VERSION.to_string() => Ok(()),
        Some("1") => Err(
            "written by an older kalos (partial format 1, whose settings cannot be read \
             back): re-render the shard"
                .into(),
        ),
        Some(v) => Err(format!(
            "partial format '{v}', but this kalos reads format {VERSION} \
             (written by a newer kalos?)"
        )),
        None => Err(format!(
            "not a kalos partial result (expected a first line '{MAGIC_KEY} {VERSION}', as \
             `kalos render --shard` and `--checkpoint` write)"
        )),
    }
}

/// The header's lines after the first, read but not yet interpreted: each
/// field with the line it came from, the counters, and the buffers' names
/// and pixel counts in file order.
struct Header {
    field: std::collections::HashMap<String, (String, usize)>,
    counters: Vec<(String, u64)>,
    buffers: Vec<(String, usize)>,
}

impl Header {
    /// Splits the header text (up to its `end` line) into fields.
    fn parse(head: &str) -> Result<Header, String> {
        let mut h = Header {
            field: std::collections::HashMap::new(),
            counters: Vec::new(),
            buffers: Vec::new(),
        };
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
                    let num: u64 = num.parse().map_err(|_| {
                        format!("header line {line_no}: '{num}' is not a whole number")
                    })?;
                    if k == "counter" {
                        h.counters.push((name.to_string(), num));
                    } else {
                        h.buffers.push((name.to_string(), num as usize));
                    }
                }
                _ => {
                    if h.field
                        .insert(k.to_string(), (v.to_string(), line_no))
                        .is_some()
                    {
                        return Err(format!("header line {line_no}: '{k}' given twice"));
                    }
                }
            }
        }
        Ok(h)
    }

    /// The field `k` with its line number, or an error naming it.
    fn get(&self, k: &str) -> Result<(&str, usize), String> {
        self.field
            .get(k)
            .map(|(v, n)| (v.as_str(), *n))
            .ok_or_else(|| format!("the header has no '{k}' line"))
    }

    /// The render the file belongs to: size, shard, kind, depth, scene and
    /// the method's settings (read back with serde), checked against the
    /// `method` line.
    fn meta(&self) -> Result<Meta, String> {
        let get = |k: &str| self.get(k);
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
        let (settings, settings_line) = get("settings")?;
        let settings: MethodConfig = serde_json::from_str(settings).map_err(|e| {
            format!("header line {settings_line}: the method's settings do not parse: {e}")
        })?;
        let (method, method_line) = get("method")?;
        if method != settings.name() {
            return Err(format!(
                "header line {method_line}: 'method' is {method} but the settings are {}'s",
                settings.name()
            ));
        }
        Ok(Meta {
            settings,
            seed: num("seed", get("seed")?)?,
            max_depth,
            scene_hash,
            scene_source: get("scene_source")?.0.to_string(),
            width: w,
            height: h,
            shard,
            kind,
        })
    }
}

/// A header value `v` (on line `n`) of field `k` as a number.
fn num<T: std::str::FromStr>(k: &str, (v, n): (&str, usize)) -> Result<T, String> {
    v.parse()
        .map_err(|_| format!("header line {n}: '{k}' expects a number, got '{v}'"))
}

/// The sums after the header, each checked against the film's size `w` ×
/// `h`, with nothing left over.
fn read_buffers(
    mut data: &[u8],
    buffers: Vec<(String, usize)>,
    w: u32,
    h: u32,
) -> Result<Vec<(String, Vec<DVec3>)>, String> {
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
    Ok(out)
}

fn find(hay: &[u8], needle: &[u8]) -> Option<usize> {
    hay.windows(needle.len()).position(|w| w == needle)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::methods::{bundle, density, light, path, plb};

    fn sample() -> (Meta, State) {
        let meta = Meta {
            settings: MethodConfig::Path(path::Settings {
                rr_depth: 3,
                ..Default::default()
            }),
            seed: 7,
            max_depth: Some(3),
            scene_hash: 0x0123_4567_89ab_cdef,
            scene_source: "builtin".into(),
            width: 3,
            height: 2,
            shard: Shard { index: 1, count: 4 },
            kind: ShardKind::Exact,
        };
        let state = State {
            passes: 5,
            rays: 1234,
            seconds: 0.1 + 0.2,
            spp: 5.0,
            counters: vec![("passes".into(), 5)],
            buffers: vec![(
                "film".into(),
                (0..6)
                    .map(|i| DVec3::new(i as f64 / 3.0, 1e-300, 1e300))
                    .collect(),
            )],
        };
        (meta, state)
    }

    fn bytes(meta: &Meta, state: &State) -> Vec<u8> {
        let mut v = Vec::new();
        let head = header(meta, state).expect("the settings serialise");
        encode(&head, state, &mut v).expect("in memory");
        v
    }

    #[test]
    fn a_partial_result_reads_back_exactly() {
        let (meta, state) = sample();
        let back = decode(&bytes(&meta, &state)).expect("decodes");
        assert_eq!(back, Partial { meta, state });
    }

    /// Every method's default settings, and some far from the defaults
    /// (every enum off its default, options set, floats that are not
    /// short decimals), read back into the equal settings.
    #[test]
    fn every_methods_settings_read_back_equal() {
        let mut configs: Vec<MethodConfig> = crate::methods::all()
            .iter()
            .map(|m| (m.default)())
            .collect();
        assert_eq!(configs.len(), crate::methods::names().len());
        configs.extend([
            MethodConfig::Path(path::Settings {
                seed: 42,
                max_depth: Some(4),
                rr_depth: 2,
                light_selection: crate::emitter::LightSelection::Power,
                sampler: crate::sampling::SamplerKind::Sobol,
            }),
            MethodConfig::Light(light::Settings {
                variant: light::Variant::Iteration,
                lanes: 3,
                paths_per_pass: 12345,
                discard: 2,
                camera_pass: false,
                ..Default::default()
            }),
            MethodConfig::Plb(plb::Settings {
                lambda: 0.1,
                phase_len: 17,
                variant: plb::Variant::Paper,
                measure: Some(plb::Measure::Birth),
                camera_pass: false,
                ..Default::default()
            }),
            MethodConfig::Bundle(bundle::Settings {
                edge: Some(1.0 / 3.0),
                map_res: Some(777),
                budget: bundle::PatchBudget::Projected,
                sequence: bundle::sequence::Sequence::Halton,
                image: bundle::image::ImageMode::Gouraud,
                visibility: bundle::visibility::Visibility::ZBuffer,
                centre_rr: false,
                positions: bundle::image::Positions::Fixed,
                direct: bundle::Direct::Bundles,
                gather: bundle::Gather::Off,
                glass: bundle::Glass::Off,
                ..Default::default()
            }),
            MethodConfig::Density(density::Settings {
                c1: std::f32::consts::PI,
                epsilon: 1e-7,
                decimate: false,
                per_channel: true,
                scratch: Some("a dir/with \"quotes\"\nand a line break".into()),
                keep_hits: Some("hits.bin".into()),
                ..Default::default()
            }),
        ]);
        for settings in configs {
            let (mut meta, state) = sample();
            meta.settings = settings.clone();
            let b = bytes(&meta, &state);
            let head = String::from_utf8_lossy(&b[..find(&b, b"\nend\n").expect("end")]);
            let line = head
                .lines()
                .find(|l| l.starts_with("settings "))
                .expect("a settings line");
            assert!(
                line.starts_with(&format!("settings {{\"{}\":{{", settings.name())),
                "{line}"
            );
            assert!(head.starts_with("kalos-partial 2\nmethod "), "{head}");
            let back = decode(&b).unwrap_or_else(|e| panic!("{}: {e}", settings.name()));
            assert_eq!(back.meta.settings, settings);
            assert_eq!(back, Partial { meta, state });
        }
    }

    #[test]
    fn a_file_reads_back_through_write_and_read() {
        let dir = tempfile::tempdir().expect("a temporary directory");
        let file = dir.path().join("part.kpart");
        let (mut meta, state) = sample();
        meta.settings = MethodConfig::Light(light::Settings {
            lanes: 5,
            ..Default::default()
        });
        write(&file, &meta, &state).expect("writes");
        assert_eq!(read(&file).expect("reads"), Partial { meta, state });
    }

    #[test]
    fn settings_that_do_not_parse_are_refused_naming_the_file_and_line() {
        let (meta, state) = sample();
        let good = String::from_utf8_lossy(&bytes(&meta, &state)[..]).into_owned();
        let e = decode(good.replace("\"rr_depth\"", "\"rr_dpth\"").as_bytes()).unwrap_err();
        assert!(
            e.contains("header line 4") && e.contains("rr_dpth") && e.contains("settings"),
            "{e}"
        );
        let e = decode(
            good.replace("settings {\"path\"", "settings {\"paths\"")
                .as_bytes(),
        )
        .unwrap_err();
        assert!(e.contains("header line 4") && e.contains("paths"), "{e}");
        let e = decode(good.replace("method path", "method light").as_bytes()).unwrap_err();
        assert!(e.contains("header line 2") && e.contains("light"), "{e}");

        // read() puts the file's name in front
        let dir = tempfile::tempdir().expect("a temporary directory");
        let file = dir.path().join("bad.kpart");
        std::fs::write(&file, good.replace("\"rr_depth\":3", "\"rr_depth\":\"3\"")).unwrap();
        let e = read(&file).unwrap_err().to_string();
        assert!(e.starts_with(&file.display().to_string()), "{e}");
        assert!(e.contains("do not parse"), "{e}");
    }

    #[test]
    fn a_version_1_file_is_refused_as_older() {
        let (meta, state) = sample();
        let good = String::from_utf8_lossy(&bytes(&meta, &state)[..]).into_owned();
        let old = good
            .replacen("kalos-partial 2", "kalos-partial 1", 1)
            .replace(
                good.lines().nth(3).expect("settings line"),
                "settings Path(Settings { seed: 0, max_depth: None, rr_depth: 5 })",
            );
        let e = decode(old.as_bytes()).unwrap_err();
        assert!(
            e.contains("older kalos") && e.contains("re-render the shard"),
            "{e}"
        );
        let e = decode(
            good.replacen("kalos-partial 2", "kalos-partial 3", 1)
                .as_bytes(),
        )
        .unwrap_err();
        assert!(e.contains("newer kalos"), "{e}");
    }

    #[test]
    fn damaged_files_are_refused_with_the_reason() {
        let (meta, state) = sample();
        let good = bytes(&meta, &state);
        let cut = decode(&good[..good.len() - 1]).unwrap_err();
        assert!(cut.contains("truncated"), "{cut}");
        let mut long = good.clone();
        long.push(0);
        assert!(decode(&long)
            .unwrap_err()
            .contains("follow the last buffer"));
        let text = String::from_utf8_lossy(&good[..good.len() - 144]).into_owned();
        let bad = text.replace("seed 7", "seed x");
        let e = decode(bad.as_bytes()).unwrap_err();
        assert!(e.contains("line 5") && e.contains("'seed'"), "{e}");
        let e = decode(b"P6\n").unwrap_err();
        assert!(e.contains("not a kalos partial result"), "{e}");
        let e = decode(text.replace("shard 1/4", "shard 4/4").as_bytes()).unwrap_err();
        assert!(e.contains("'shard'"), "{e}");
    }
}
