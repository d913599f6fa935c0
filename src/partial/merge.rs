//! Merging the shards of one render into its image.

use std::path::PathBuf;

use super::{Partial, PartialError, ShardKind, State};
use crate::film::Image;

/// The outcome of a merge.
#[derive(Debug)]
pub struct Merged {
    /// The image.
    pub image: Image,
    /// The method's name.
    pub method: String,
    /// The shard count N of the parts.
    pub count: u32,
    /// The shards that were not given (allowed only for chain methods).
    pub missing: Vec<u32>,
    /// Samples per pixel of the merged image (for exact methods, those of
    /// one run; for chains, the sum over chains).
    pub spp: f64,
    /// Rays traced by all parts together.
    pub rays: u64,
    /// Seconds spent by all parts together.
    pub seconds: f64,
    /// True when the parts ran different numbers of passes (an interrupted
    /// shard, a time budget): the image is then a correct estimate, but
    /// not the bytes of one run.
    pub uneven: bool,
}

/// Merges `parts` (each with the file it came from, for messages), after
/// checking that they belong to one render: the same method, settings,
/// seed, scene (by hash) and shard count, no shard twice. An exact method
/// needs every shard (a missing one would leave rows or lanes black, and
/// the error lists them); a chain method may miss some (the average of
/// fewer chains is an estimate of the same image, with more variance), and
/// the merged result's `missing` lists them.
pub fn merge(parts: &[(PathBuf, Partial)]) -> Result<Merged, PartialError> {
    let Some((first_path, first)) = parts.first() else {
        return Err(PartialError::Incompatible("no parts to merge".into()));
    };
    let meta = &first.meta;
    let n = meta.shard.count;
    let mut owner: Vec<Option<usize>> = vec![None; n as usize];
    for (i, (p, part)) in parts.iter().enumerate() {
        let name = first_path.display().to_string();
        if let Some(d) = meta.difference(&name, &part.meta, &p.display().to_string()) {
            return Err(PartialError::Incompatible(format!(
                "{d}: parts of different renders cannot be merged"
            )));
        }
        let k = part.meta.shard.index as usize;
        if let Some(j) = owner[k] {
            return Err(PartialError::Incompatible(format!(
                "shard {} is given twice: {} and {}",
                part.meta.shard,
                parts[j].0.display(),
                p.display()
            )));
        }
        owner[k] = Some(i);
    }
    let missing: Vec<u32> = (0..n).filter(|&k| owner[k as usize].is_none()).collect();
    let rays = parts.iter().map(|p| p.1.state.rays).sum();
    let seconds = parts.iter().map(|p| p.1.state.seconds).sum();
    let fail = |e: crate::methods::MethodError| {
        PartialError::Incompatible(format!("{}: {e}", first_path.display()))
    };
    let (w, h) = (meta.width, meta.height);
    let (image, spp) = match meta.kind {
        ShardKind::Exact => {
            if !missing.is_empty() {
                let list: Vec<String> = missing.iter().map(|k| format!("{k}/{n}")).collect();
                return Err(PartialError::Incompatible(format!(
                    "{} of {n} shards are missing ({}): a '{}' render needs every shard, since \
                     each owns some pixels or lanes of every pass; render the missing ones with \
                     --shard",
                    missing.len(),
                    list.join(", "),
                    meta.method()
                )));
            }
            let states: Vec<&State> = owner
                .iter()
                .map(|i| &parts[i.expect("no shard is missing")].1.state)
                .collect();
            let image = meta.settings.merge_exact(&states, w, h).map_err(fail)?;
            (image, first.state.spp)
        }
        ShardKind::Chains => average(parts, w, h).map_err(fail)?,
    };
    let uneven = meta.kind == ShardKind::Exact
        && parts.iter().any(|p| p.1.state.passes != first.state.passes);
    Ok(Merged {
        uneven,
        image,
        method: meta.method().to_string(),
        count: n,
        missing,
        spp,
        rays,
        seconds,
    })
}

/// The average of the chains' images, weighted by their samples per pixel
/// (equal weights when none has any).
fn average(
    parts: &[(PathBuf, Partial)],
    w: u32,
    h: u32,
) -> Result<(Image, f64), crate::methods::MethodError> {
    let pixels = w as usize * h as usize;
    let total: f64 = parts.iter().map(|p| p.1.state.spp).sum();
    let mut sum = vec![glam::DVec3::ZERO; pixels];
    for (_, p) in parts {
        let weight = if total > 0.0 {
            p.state.spp / total
        } else {
            1.0 / parts.len() as f64
        };
        let img = p.state.need_buffer("image", pixels)?;
        for (s, v) in sum.iter_mut().zip(img) {
            *s += *v * weight;
        }
    }
    let image = Image {
        width: w,
        height: h,
        data: sum.iter().map(|v| v.as_vec3()).collect(),
    };
    Ok((image, total))
}
