//! The bake on timely dataflow (`kalos bake --workers N`, and across
//! processes with `--process I --processes N --hostfile FILE`): the same
//! .glb bytes as the single-process bake, and clear errors for a bad host
//! file or process index.

use std::net::TcpListener;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Output, Stdio};
use std::time::{Duration, Instant};

fn kalos() -> Command {
    Command::new(env!("CARGO_BIN_EXE_kalos"))
}

fn root() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

/// `kalos bake -q` of `scene` (None: the built-in Cornell box) with
/// `particles`, to `out`, with `extra` flags.
fn bake(scene: Option<&Path>, particles: &str, out: &Path, extra: &[&str]) -> Output {
    let mut c = kalos();
    c.arg("bake");
    if let Some(s) = scene {
        c.arg(s);
    }
    c.args(["-q", "--particles", particles, "-o"])
        .arg(out)
        .args(extra)
        .output()
        .expect("kalos runs")
}

fn ok(o: &Output) {
    assert!(
        o.status.success(),
        "{}{}",
        String::from_utf8_lossy(&o.stdout),
        String::from_utf8_lossy(&o.stderr)
    );
}

/// The .glb of 2 and 3 worker threads is byte for byte that of the
/// single-process bake: on the Cornell box (planar surfaces only) and on a
/// scene with spheres (curved shapes, estimated over the whole shape by
/// one worker), with the paper's per-channel runs on the latter (three
/// channel runs interleaved in each batch). 3 workers do not divide a
/// batch of chunks evenly.
#[test]
fn worker_threads_give_the_single_process_bytes() {
    let dir = tempfile::tempdir().expect("temp dir");
    let spheres = root().join("scenes/glass-mirror/scene.xml");
    let cases: [(Option<&Path>, &str, &[&str]); 2] = [
        (None, "200k", &[]),
        (Some(&spheres), "100k", &["--variant", "per-channel"]),
    ];
    for (i, (scene, n, extra)) in cases.into_iter().enumerate() {
        let one = dir.path().join(format!("one-{i}.glb"));
        ok(&bake(scene, n, &one, extra));
        let want = std::fs::read(&one).expect("single-process bake");
        for workers in ["2", "3"] {
            let out = dir.path().join(format!("w{workers}-{i}.glb"));
            let mut args = extra.to_vec();
            args.extend(["--workers", workers]);
            ok(&bake(scene, n, &out, &args));
            let got = std::fs::read(&out).expect("dataflow bake");
            assert!(
                got == want,
                "case {i}: --workers {workers} changed the .glb"
            );
        }
    }
}

/// A port on 127.0.0.1 that was free a moment ago.
fn free_port() -> u16 {
    let l = TcpListener::bind("127.0.0.1:0").expect("bind");
    l.local_addr().expect("addr").port()
}

/// Waits for `child` at most `limit`; kills it past that.
fn wait_bounded(child: &mut Child, limit: Duration) -> Option<std::process::ExitStatus> {
    let t0 = Instant::now();
    loop {
        if let Ok(Some(s)) = child.try_wait() {
            return Some(s);
        }
        if t0.elapsed() > limit {
            let _ = child.kill();
            let _ = child.wait();
            return None;
        }
        std::thread::sleep(Duration::from_millis(50));
    }
}

/// Two `kalos bake` processes talking over 127.0.0.1 (ports chosen free at
/// test time, both children killed if they take more than two minutes)
/// give the single-process bytes; only process 0 writes the output.
#[test]
fn two_processes_on_loopback_give_the_single_process_bytes() {
    let dir = tempfile::tempdir().expect("temp dir");
    let one = dir.path().join("one.glb");
    ok(&bake(None, "200k", &one, &[]));
    let hosts = dir.path().join("hosts.txt");
    std::fs::write(
        &hosts,
        format!("127.0.0.1:{}\n127.0.0.1:{}\n", free_port(), free_port()),
    )
    .expect("host file");
    let outs = [dir.path().join("p0.glb"), dir.path().join("p1.glb")];
    let mut children: Vec<Child> = (0..2)
        .map(|p| {
            kalos()
                .args(["bake", "-q", "--particles", "200k", "-o"])
                .arg(&outs[p])
                .args([
                    "--processes",
                    "2",
                    "--process",
                    &p.to_string(),
                    "--hostfile",
                ])
                .arg(&hosts)
                .stdout(Stdio::null())
                .stderr(Stdio::piped())
                .spawn()
                .expect("kalos runs")
        })
        .collect();
    let status: Vec<_> = children
        .iter_mut()
        .map(|c| wait_bounded(c, Duration::from_secs(120)))
        .collect();
    for (p, s) in status.iter().enumerate() {
        assert!(s.is_some_and(|s| s.success()), "process {p}: {s:?}");
    }
    let want = std::fs::read(&one).expect("single-process bake");
    let got = std::fs::read(&outs[0]).expect("process 0 wrote the bake");
    assert!(got == want, "two processes changed the .glb");
    assert!(!outs[1].exists(), "process 1 wrote an output");
}

/// A malformed host file, one with the wrong number of hosts, a missing
/// one and a process index out of range each fail at once (before any
/// connection is tried) with a message naming the file (and line) or the
/// flag.
#[test]
fn a_bad_hostfile_or_process_index_is_a_clear_error() {
    let dir = tempfile::tempdir().expect("temp dir");
    let out = dir.path().join("o.glb");
    let bad = dir.path().join("bad.txt");
    std::fs::write(&bad, "# hosts\n127.0.0.1:2101\nlocalhost\n").expect("host file");
    let short = dir.path().join("short.txt");
    std::fs::write(&short, "127.0.0.1:2101\n").expect("host file");
    let missing = dir.path().join("missing.txt");
    let run = |p: &str, n: &str, file: &Path| {
        let o = kalos()
            .args(["bake", "-q", "--particles", "10k", "-o"])
            .arg(&out)
            .args(["--process", p, "--processes", n, "--hostfile"])
            .arg(file)
            .output()
            .expect("kalos runs");
        assert!(!o.status.success());
        String::from_utf8_lossy(&o.stderr).into_owned()
    };
    let err = run("0", "2", &bad);
    assert!(err.contains(&format!("{}:3", bad.display())), "{err}");
    assert!(
        err.contains("host:port") && err.contains("'localhost'"),
        "{err}"
    );
    let err = run("0", "2", &short);
    assert!(
        err.contains(&short.display().to_string()) && err.contains("lists 1 hosts"),
        "{err}"
    );
    let err = run("0", "2", &missing);
    assert!(err.contains(&missing.display().to_string()), "{err}");
    let err = run("2", "2", &short);
    assert!(err.contains("--process 2 is out of range"), "{err}");
    // --process alone is a usage error (clap's exit code 2)
    let o = kalos()
        .args(["bake", "-q", "-o"])
        .arg(&out)
        .args(["--process", "0"])
        .output()
        .expect("kalos runs");
    assert_eq!(o.status.code(), Some(2));
    let o = kalos()
        .args(["bake", "-q", "-o"])
        .arg(&out)
        .args(["--workers", "0"])
        .output()
        .expect("kalos runs");
    assert!(!o.status.success());
    assert!(String::from_utf8_lossy(&o.stderr).contains("--workers must be at least 1"));
    assert!(!out.exists());
}

/// Ctrl-C stops a bake of 2 worker threads as it stops a single-process
/// one: exit code 130, every worker's scratch directory removed, nothing
/// written. The signal is sent once a worker's scratch directory holds
/// files, so the handler is set.
#[cfg(unix)]
#[test]
fn sigint_stops_a_two_worker_bake_and_removes_its_scratch_files() {
    let dir = tempfile::tempdir().expect("temp dir");
    let base = dir.path().join("scratch");
    std::fs::create_dir(&base).expect("scratch base");
    let out = dir.path().join("o.glb");
    let mut child = kalos()
        .args(["bake", "-q", "--particles", "400M", "--workers", "2", "-o"])
        .arg(&out)
        .arg("--scratch")
        .arg(&base)
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .spawn()
        .expect("kalos runs");
    let entries = || -> Vec<PathBuf> {
        std::fs::read_dir(&base)
            .map(|d| d.filter_map(|e| e.ok().map(|e| e.path())).collect())
            .unwrap_or_default()
    };
    let has_files = || {
        entries()
            .iter()
            .any(|d| std::fs::read_dir(d).is_ok_and(|mut e| e.next().is_some()))
    };
    let t0 = Instant::now();
    while !has_files() && t0.elapsed() < Duration::from_secs(60) {
        std::thread::sleep(Duration::from_millis(20));
    }
    assert!(has_files(), "the bake wrote no scratch files");
    let sent = Command::new("kill")
        .args(["-INT", &child.id().to_string()])
        .status()
        .expect("kill runs");
    assert!(sent.success());
    let status = wait_bounded(&mut child, Duration::from_secs(60));
    assert_eq!(status.and_then(|s| s.code()), Some(130));
    assert_eq!(entries(), Vec::<PathBuf>::new());
    assert!(!out.exists());
}
