//! The loader fuzz cases of `tests/it/fuzz.rs`, each run through the
//! `kalos render` command in its own process with a time limit, so that
//! aborts (a failed allocation ends the process) and hangs are counted
//! instead of ending the run.
//!
//! ```text
//! cargo build --release
//! cargo run --release --example fuzz_loaders -- --cases 10000 --seed 1
//! ```
//!
//! Each case renders 16×12 pixels at 1 spp with the five methods in turn
//! and is classified: a clean error (exit status 1 or 2 with an `error:`
//! line), an image (read back and checked for NaN/Inf), a panic (exit
//! status 101), an abort or other signal, or a hang (killed after
//! `--timeout` seconds). Two cases run at a time, each on one thread.

#![allow(clippy::disallowed_methods)] // std::fs is denied only in the scene loaders (clippy.toml)
#[path = "../tests/it/fuzz/cases.rs"]
mod cases;

use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::sync::Mutex;
use std::time::{Duration, Instant};

use anyhow::{bail, Context, Result};
use rayon::prelude::*;

#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord)]
enum Outcome {
    Error,
    Image,
    Panic,
    Signal,
    Hang,
    NonFinite,
    OtherExit,
}

struct Args {
    cases: u64,
    seed: u64,
    timeout: f64,
    kalos: PathBuf,
    keep: Option<PathBuf>,
}

fn args() -> Result<Args> {
    let mut a = Args {
        cases: 1000,
        seed: cases::RUN_SEED,
        timeout: 20.0,
        kalos: Path::new(env!("CARGO_MANIFEST_DIR")).join("target/release/kalos"),
        keep: None,
    };
    let mut it = std::env::args().skip(1);
    while let Some(k) = it.next() {
        let mut v = || it.next().with_context(|| format!("{k} needs a value"));
        match k.as_str() {
            "--cases" => a.cases = v()?.parse()?,
            "--seed" => a.seed = v()?.parse()?,
            "--timeout" => a.timeout = v()?.parse()?,
            "--kalos" => a.kalos = v()?.into(),
            // a folder into which every failing case is copied
            "--keep" => a.keep = Some(v()?.into()),
            _ => {
                bail!("unknown argument {k} (expected --cases, --seed, --timeout, --kalos, --keep)")
            }
        }
    }
    if !a.kalos.exists() {
        bail!(
            "{} does not exist: build it with cargo build --release",
            a.kalos.display()
        );
    }
    Ok(a)
}

fn run(a: &Args, seeds: &[cases::Seed], i: u64) -> Result<(Outcome, String, f64)> {
    let c = cases::case(seeds, a.seed, i);
    let dir = tempfile::tempdir()?;
    c.write(dir.path())?;
    let out = dir.path().join("out.pfm");
    // the methods in turn, as the in-process test does
    let all = kalos::methods::all();
    let info = &all[(i % all.len() as u64) as usize];
    let method = info.name;
    let mut cmd = Command::new(&a.kalos);
    cmd.args([
        "render",
        "--method",
        method,
        "--res",
        "16x12",
        "--spp",
        "1",
        "--threads",
        "1",
        "-q",
    ])
    .arg(dir.path().join(&c.main))
    .arg("-o")
    .arg(&out)
    .stdout(Stdio::null())
    .stderr(Stdio::piped());
    if info.max_depth {
        cmd.args(["--max-depth", "6"]);
    }
    if method == "density" {
        cmd.arg("--particles")
            .arg(cases::DENSITY_PARTICLES.to_string());
    }
    let t0 = Instant::now();
    let mut child = cmd.spawn()?;
    let status = loop {
        if let Some(s) = child.try_wait()? {
            break Some(s);
        }
        if t0.elapsed().as_secs_f64() > a.timeout {
            child.kill()?;
            child.wait()?;
            break None;
        }
        std::thread::sleep(Duration::from_millis(5));
    };
    let secs = t0.elapsed().as_secs_f64();
    let mut stderr = String::new();
    if let Some(mut e) = child.stderr.take() {
        use std::io::Read;
        e.read_to_string(&mut stderr)?;
    }
    let outcome = match status.map(|s| s.code()) {
        None => Outcome::Hang,
        Some(None) => Outcome::Signal,
        Some(Some(0)) => {
            let img = kalos::image_io::read_image(&out)?;
            if img.data.iter().all(|p| p.is_finite()) {
                Outcome::Image
            } else {
                Outcome::NonFinite
            }
        }
        Some(Some(101)) => Outcome::Panic,
        Some(Some(1 | 2)) if stderr.contains("error") => Outcome::Error,
        Some(Some(_)) => Outcome::OtherExit,
    };
    if !matches!(outcome, Outcome::Error | Outcome::Image) {
        if let Some(keep) = &a.keep {
            let to = keep.join(format!("case-{i}"));
            std::fs::create_dir_all(&to)?;
            c.write(&to)?;
            std::fs::write(to.join("stderr.txt"), &stderr)?;
        }
    }
    let what = format!(
        "case {i} ({}, {method}, {:?}): {}",
        c.label,
        c.ops,
        stderr.lines().last().unwrap_or("")
    );
    Ok((outcome, what, secs))
}

fn main() -> Result<()> {
    let a = args()?;
    let seeds = cases::seeds();
    let counts = Mutex::new(std::collections::BTreeMap::<Outcome, u64>::new());
    let slowest = Mutex::new((0.0f64, String::new()));
    let bad = Mutex::new(Vec::new());
    let pool = rayon::ThreadPoolBuilder::new().num_threads(2).build()?;
    let t0 = Instant::now();
    pool.install(|| {
        (0..a.cases)
            .into_par_iter()
            .try_for_each(|i| -> Result<()> {
                let (o, what, secs) = run(&a, &seeds, i)?;
                *counts.lock().unwrap().entry(o).or_default() += 1;
                let mut s = slowest.lock().unwrap();
                if secs > s.0 {
                    *s = (secs, what.clone());
                }
                if !matches!(o, Outcome::Error | Outcome::Image) {
                    eprintln!("{o:?}: {what}");
                    bad.lock().unwrap().push(what);
                }
                Ok(())
            })
    })?;
    let counts = counts.into_inner().unwrap();
    println!(
        "{} cases (seed {}) in {:.0} s: {:?}",
        a.cases,
        a.seed,
        t0.elapsed().as_secs_f64(),
        counts
    );
    let (s, what) = slowest.into_inner().unwrap();
    println!("slowest case: {s:.2} s, {what}");
    if !bad.into_inner().unwrap().is_empty() {
        std::process::exit(1);
    }
    Ok(())
}
