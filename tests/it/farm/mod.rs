//! Shards, merge, checkpoints and the farm recipe (issue 14): merged
//! shards and resumed renders give the bytes of one run (`path`, `light`),
//! merged chains converge to the known answer (`plb`, `bundle`), parts and
//! checkpoints of another render are refused, and the Slurm script and the
//! Kubernetes job in `farm/` run as written.

mod chains;
mod netns;
mod recipe;
mod tiles;

use crate::common::kalos;
use std::path::{Path, PathBuf};
use std::process::Command;

/// Runs kalos and fails the test, with its stderr, unless it succeeds.
fn ok(args: &[&str]) {
    let o = kalos(args);
    assert!(
        o.status.success(),
        "kalos {args:?} failed: {}",
        String::from_utf8_lossy(&o.stderr)
    );
}

/// Runs kalos expecting a failure; returns its stderr.
fn refused(args: &[&str]) -> String {
    let o = kalos(args);
    assert!(!o.status.success(), "kalos {args:?} was accepted");
    String::from_utf8_lossy(&o.stderr).into_owned()
}

fn s(p: &Path) -> &str {
    p.to_str().expect("utf-8 path")
}

/// Fails unless the files at `a` and `b` hold the same bytes.
fn same_bytes(a: &Path, b: &Path) {
    let (x, y) = (
        std::fs::read(a).expect("read"),
        std::fs::read(b).expect("read"),
    );
    assert!(
        x == y,
        "{} and {} differ ({} and {} bytes)",
        a.display(),
        b.display(),
        x.len(),
        y.len()
    );
}

/// The scene of these tests: a mirror and glass, so that light's camera
/// pass (which is split by rows) runs too.
const SCENE: &str = "scenes/glass-mirror/scene.xml";
const RES: &str = "40x32";

/// The flags of one render of the tests' scene with `method`'s flags.
fn render_args<'a>(method: &[&'a str], spp: &'a str) -> Vec<&'a str> {
    let mut v = vec!["render", SCENE, "-q", "--res", RES, "--spp", spp];
    v.extend_from_slice(method);
    v
}

const EXACT: [&[&str]; 5] = [
    &["--method", "path", "--sampler", "independent"],
    &["--method", "path"],
    &["--method", "light", "--sampler", "independent"],
    &["--method", "light", "--sampler", "sobol"],
    &["--method", "light", "--variant", "iteration"],
];

#[test]
fn shards_merged_give_the_bytes_of_one_run() {
    let dir = tempfile::tempdir().expect("tempdir");
    for (i, method) in EXACT.iter().enumerate() {
        // one run on 2 threads; 3 shards on 1 thread each, merged in a
        // shuffled order
        let one = dir.path().join(format!("one-{i}.pfm"));
        let mut a = render_args(method, "5");
        a.extend(["--threads", "2", "-o", s(&one)]);
        ok(&a);
        let parts: Vec<PathBuf> = (0..3)
            .map(|k| dir.path().join(format!("part-{i}-{k}.kpart")))
            .collect();
        for (k, p) in parts.iter().enumerate() {
            let shard = format!("{k}/3");
            let mut a = render_args(method, "5");
            a.extend(["--threads", "1", "--shard", &shard, "-o", s(p)]);
            ok(&a);
        }
        let merged = dir.path().join(format!("merged-{i}.pfm"));
        ok(&[
            "merge",
            s(&parts[2]),
            s(&parts[0]),
            s(&parts[1]),
            "-o",
            s(&merged),
        ]);
        same_bytes(&one, &merged);
    }
}

#[test]
fn a_render_resumed_from_its_checkpoint_gives_the_bytes_of_one_run() {
    let dir = tempfile::tempdir().expect("tempdir");
    for (i, method) in EXACT[..4].iter().enumerate() {
        let one = dir.path().join(format!("one-{i}.pfm"));
        let mut a = render_args(method, "7");
        a.extend(["-o", s(&one)]);
        ok(&a);
        // Interrupted after 3 of 7 passes (a pass budget: deterministic),
        // then resumed with the whole budget
        let ck = dir.path().join(format!("ck-{i}.kpart"));
        let first = dir.path().join(format!("first-{i}.pfm"));
        let mut a = render_args(method, "3");
        a.extend(["--checkpoint", s(&ck), "-o", s(&first)]);
        ok(&a);
        let part = kalos::partial::read(&ck).expect("the checkpoint reads");
        assert_eq!(
            part.state.passes, 3,
            "the checkpoint is the state at the end"
        );
        let resumed = dir.path().join(format!("resumed-{i}.pfm"));
        let mut a = render_args(method, "7");
        a.extend(["--resume", s(&ck), "-o", s(&resumed)]);
        ok(&a);
        same_bytes(&one, &resumed);
    }
}

/// Ctrl-C writes the checkpoint, and resuming from wherever the render
/// stopped gives the bytes of one uninterrupted run of the same passes.
/// Where it stops depends on timing; the result must not.
#[cfg(unix)]
#[test]
fn ctrl_c_writes_a_checkpoint_that_resumes_to_the_same_bytes() {
    use std::time::{Duration, Instant};
    let dir = tempfile::tempdir().expect("tempdir");
    let ck = dir.path().join("ck.kpart");
    let first = dir.path().join("first.pfm");
    // checkpoints every 10 ms, so that one exists soon after the start
    let mut child = Command::new(env!("CARGO_BIN_EXE_kalos"))
        .args(render_args(
            &["--method", "path", "--threads", "1"],
            "100000",
        ))
        .args([
            "--checkpoint",
            s(&ck),
            "--checkpoint-every",
            "0.01",
            "-o",
            s(&first),
        ])
        .spawn()
        .expect("kalos starts");
    let give_up = Instant::now() + Duration::from_secs(120);
    while !ck.exists() {
        assert!(Instant::now() < give_up, "no checkpoint was written");
        std::thread::sleep(Duration::from_millis(20));
    }
    let pid = child.id().to_string();
    assert!(Command::new("kill")
        .args(["-INT", &pid])
        .status()
        .expect("kill runs")
        .success());
    let status = child.wait().expect("kalos ends");
    assert_eq!(status.code(), Some(130), "an interrupted render exits 130");
    let passes = kalos::partial::read(&ck).expect("checkpoint").state.passes;
    assert!(
        (1..100_000).contains(&passes),
        "stopped after {passes} passes"
    );
    let total = (passes + 2).to_string();
    let resumed = dir.path().join("resumed.pfm");
    let mut a = render_args(&["--method", "path"], &total);
    a.extend(["--resume", s(&ck), "-o", s(&resumed)]);
    ok(&a);
    let one = dir.path().join("one.pfm");
    let mut a = render_args(&["--method", "path"], &total);
    a.extend(["-o", s(&one)]);
    ok(&a);
    same_bytes(&one, &resumed);
}

#[test]
fn parts_and_checkpoints_of_another_render_are_refused() {
    let dir = tempfile::tempdir().expect("tempdir");
    let d = |n: &str| dir.path().join(n);
    let part = |name: &str, extra: &[&str]| {
        let p = d(name);
        let mut a = render_args(&["--method", "path"], "2");
        a.extend_from_slice(extra);
        a.extend(["-o", s(&p)]);
        ok(&a);
        p
    };
    let a0 = part("a0.kpart", &["--shard", "0/2"]);
    let a1 = part("a1.kpart", &["--shard", "1/2"]);
    let seed = part("seed.kpart", &["--shard", "1/2", "--seed", "9"]);
    let three = part("three.kpart", &["--shard", "1/3"]);
    let rr = part("rr.kpart", &["--shard", "1/2", "--rr-depth", "2"]);
    let out = d("out.pfm");
    for (other, words) in [
        (&seed, &["has seed 9", "has 0"][..]),
        (&three, &["shard count of 3"][..]),
        (&rr, &["rr_depth: 2", "rr_depth: 5"][..]),
    ] {
        let e = refused(&["merge", s(&a0), s(other), "-o", s(&out)]);
        for w in words {
            assert!(e.contains(w) && e.contains(s(other)), "{e}");
        }
    }
    let e = refused(&["merge", s(&a0), s(&a0), "-o", s(&out)]);
    assert!(e.contains("given twice"), "{e}");
    let e = refused(&["merge", s(&a1), "-o", s(&out)]);
    assert!(e.contains("missing (0/2)"), "{e}");
    let e = refused(&["merge", s(&a0), SCENE, "-o", s(&out)]);
    assert!(e.contains("not a kalos partial result"), "{e}");
    assert!(!out.exists(), "nothing is written");

    // A checkpoint of another scene, resolution, method or setting
    let ck = part("ck.kpart", &["--shard", "0/2"]);
    let r = d("r.kpart");
    let resume = |extra: &[&str]| {
        let mut a = vec!["render", "-q", "--spp", "4", "--resume", s(&ck)];
        a.extend_from_slice(extra);
        a.extend(["-o", s(&r)]);
        refused(&a)
    };
    let e = resume(&[SCENE, "--res", RES, "--shard", "0/2", "--method", "light"]);
    assert!(e.contains("method path") && e.contains("has light"), "{e}");
    let e = resume(&["--res", RES, "--shard", "0/2"]);
    assert!(e.contains("another scene") && e.contains("builtin"), "{e}");
    let e = resume(&[SCENE, "--res", "40x40", "--shard", "0/2"]);
    assert!(e.contains("another scene") && e.contains("40x32"), "{e}");
    let e = resume(&[SCENE, "--res", RES, "--shard", "1/2"]);
    assert!(e.contains("shard 0/2") && e.contains("1/2"), "{e}");
    let e = resume(&[SCENE, "--res", RES, "--shard", "0/2", "--method", "plb"]);
    assert!(e.contains("cannot write checkpoints or resume"), "{e}");

    // Methods and splits that cannot be sharded say so before any work
    let e = refused(&[
        "render",
        "--method",
        "density",
        "--shard",
        "0/2",
        "-o",
        s(&d("x.kpart")),
    ]);
    assert!(e.contains("cannot be split into shards"), "{e}");
    let e = refused(&[
        "render",
        "--method",
        "light",
        "--shard",
        "0/9",
        "-o",
        s(&d("x.kpart")),
    ]);
    assert!(e.contains("at most 8 shards"), "{e}");
    let e = refused(&["render", "--shard", "0/2", "-o", s(&d("x.exr"))]);
    assert!(e.contains(".kpart"), "{e}");
}
