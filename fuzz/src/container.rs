//! The container format that packs a scene's files into one fuzz input
//! (described in the crate's documentation). Standard library only: the
//! seed writer (`seed.rs`) includes this file by path.

/// What separates the files of one input.
pub const MARKER: &[u8] = b"\n@@file ";

/// Most side files an input writes besides its main file.
pub const MAX_FILES: usize = 16;

/// One file of an input: its path relative to the scene folder, and bytes.
pub struct Part<'a> {
    pub name: String,
    pub bytes: &'a [u8],
}

/// Splits an input into its main file's bytes and the side files.
pub fn split(data: &[u8]) -> (&[u8], Vec<Part<'_>>) {
    let mut cuts = Vec::new();
    let mut i = 0;
    while i + MARKER.len() <= data.len() {
        if &data[i..i + MARKER.len()] == MARKER {
            cuts.push(i);
            i += MARKER.len();
        } else {
            i += 1;
        }
    }
    let main = &data[..cuts.first().copied().unwrap_or(data.len())];
    let mut parts = Vec::new();
    for (k, &c) in cuts.iter().enumerate() {
        let end = cuts.get(k + 1).copied().unwrap_or(data.len());
        let body = &data[c + MARKER.len()..end];
        let nl = body.iter().position(|&b| b == b'\n').unwrap_or(body.len());
        let Some(name) = valid_name(&body[..nl]) else {
            continue;
        };
        let bytes = body.get(nl + 1..).unwrap_or(&[]);
        if parts.len() < MAX_FILES {
            parts.push(Part { name, bytes });
        }
    }
    (main, parts)
}

fn valid_name(raw: &[u8]) -> Option<String> {
    let s = std::str::from_utf8(raw).ok()?;
    if s.is_empty() || s.len() > 64 {
        return None;
    }
    let comps: Vec<&str> = s.split('/').collect();
    let ok = comps.len() <= 3
        && comps.iter().all(|c| {
            !c.is_empty()
                && *c != "."
                && *c != ".."
                && c.bytes()
                    .all(|b| b.is_ascii_alphanumeric() || matches!(b, b'.' | b'_' | b'-'))
        });
    ok.then(|| s.to_string())
}

/// Joins a main file and side files into one input (the seeds' writer and
/// the regression tests use the same layout).
pub fn join(main: &[u8], parts: &[(&str, &[u8])]) -> Vec<u8> {
    let mut out = main.to_vec();
    for (name, bytes) in parts {
        out.extend_from_slice(MARKER);
        out.extend_from_slice(name.as_bytes());
        out.push(b'\n');
        out.extend_from_slice(bytes);
    }
    out
}
