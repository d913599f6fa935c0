//! `kalos merge`: the image of a render from its shards' partial results.

use std::path::PathBuf;

use anyhow::Result;
use clap::Args;

use kalos::image_io::{self, PngOptions};
use kalos::partial;

use crate::{check_output, TonemapArg};

/// The flags of `kalos merge`.
#[derive(Args)]
pub struct MergeArgs {
    /// Partial results (.kpart) written by `kalos render --shard K/N`, in
    /// any order.
    #[arg(required = true)]
    parts: Vec<PathBuf>,
    /// Output image (.exr, .pfm or .png).
    #[arg(short, long)]
    output: PathBuf,
    /// PNG exposure in stops.
    #[arg(long, default_value_t = 0.0)]
    exposure: f32,
    /// PNG tone mapping.
    #[arg(long, value_enum, default_value = "clamp")]
    tonemap: TonemapArg,
}

/// Runs `kalos merge`.
pub fn run(a: MergeArgs) -> Result<()> {
    check_output(&a.output, &["exr", "pfm", "png"])?;
    let parts = a
        .parts
        .iter()
        .map(|p| Ok((p.clone(), partial::read(p)?)))
        .collect::<Result<Vec<_>>>()?;
    let m = partial::merge(&parts)?;
    let png = PngOptions {
        exposure: a.exposure,
        tonemap: a.tonemap.into(),
    };
    image_io::write_image(&a.output, &m.image, &png)?;
    if !m.missing.is_empty() {
        let list: Vec<String> = m
            .missing
            .iter()
            .map(|k| format!("{k}/{}", m.count))
            .collect();
        eprintln!(
            "note: {} of {} chains missing ({}): the image averages the {} given",
            m.missing.len(),
            m.count,
            list.join(", "),
            parts.len()
        );
    }
    if m.uneven {
        eprintln!(
            "note: the shards ran different numbers of passes (interrupted, or a --time or \
             --rays budget): the image is a correct estimate, but not the bytes of one run"
        );
    }
    crate::say!(
        "{}: {} {}x{}, {:.1} spp, {} of {} shards, {:.1} M rays, {:.2} s in all",
        a.output.display(),
        m.method,
        m.image.width,
        m.image.height,
        m.spp,
        parts.len(),
        m.count,
        m.rays as f64 / 1e6,
        m.seconds
    );
    Ok(())
}
