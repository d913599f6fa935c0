//! The dataflow bake across real network hosts: three network namespaces
//! joined by veth links, one `kalos bake --process I` in each. Needs root
//! and `ip` (iproute2); skipped with the reason otherwise. The namespaces
//! (and with them their links) are deleted however the test ends.
//!
//! Each namespace i has the address 10.213.0.(i+1)/32 on its loopback and
//! a veth link to each other namespace, with a route to that host's
//! address through it; nothing else is reachable (no default route).

use std::path::{Path, PathBuf};
use std::process::{Child, Command, Output, Stdio};
use std::time::{Duration, Instant};

const HOSTS: usize = 3;
const PORT: u16 = 24_731;

fn kalos_bin() -> &'static str {
    env!("CARGO_BIN_EXE_kalos")
}

/// One namespaced test at a time: they share the addresses, the port and
/// the veth names (each in its own namespaces, but one host's bakes at a
/// time keep the timeouts honest on a 2-core machine).
fn serial() -> std::sync::MutexGuard<'static, ()> {
    static LOCK: std::sync::Mutex<()> = std::sync::Mutex::new(());
    LOCK.lock().unwrap_or_else(|e| e.into_inner())
}

/// Why the test cannot run here, if it cannot.
fn unavailable() -> Option<String> {
    let status = std::fs::read_to_string("/proc/self/status").unwrap_or_default();
    let euid = status
        .lines()
        .find(|l| l.starts_with("Uid:"))
        .and_then(|l| l.split_whitespace().nth(2))
        .unwrap_or("unknown");
    if euid != "0" {
        return Some(format!("not running as root (euid {euid})"));
    }
    match Command::new("ip").arg("-V").output() {
        Ok(o) if o.status.success() => {}
        Ok(o) => {
            return Some(format!(
                "`ip -V` failed: {}",
                String::from_utf8_lossy(&o.stderr)
            ))
        }
        Err(e) => return Some(format!("no `ip` command (iproute2): {e}")),
    }
    // Root in a container may still lack the right to make namespaces
    // (CAP_SYS_ADMIN, CAP_NET_ADMIN): try one
    static PROBES: std::sync::atomic::AtomicUsize = std::sync::atomic::AtomicUsize::new(0);
    let n = PROBES.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
    let probe = format!("kalos-probe-{}-{n}", std::process::id());
    match Command::new("ip").args(["netns", "add", &probe]).output() {
        Ok(o) if o.status.success() => {
            let _ = Command::new("ip").args(["netns", "del", &probe]).output();
            None
        }
        Ok(o) => Some(format!(
            "cannot make a network namespace: {}",
            String::from_utf8_lossy(&o.stderr).trim()
        )),
        Err(e) => Some(format!("`ip netns add` did not run: {e}")),
    }
}

/// Runs `ip ARGS`, failing the test with its stderr unless it succeeds.
fn ip(args: &[&str]) {
    let o = Command::new("ip").args(args).output().expect("ip runs");
    assert!(
        o.status.success(),
        "ip {}: {}",
        args.join(" "),
        String::from_utf8_lossy(&o.stderr)
    );
}

/// Three namespaces joined pairwise by veth links; deleted on drop.
struct Hosts {
    names: Vec<String>,
}

impl Hosts {
    fn new(tag: &str) -> Hosts {
        let pid = std::process::id();
        let mut h = Hosts { names: Vec::new() };
        for i in 0..HOSTS {
            let name = format!("kalos-{tag}-{pid}-{i}");
            ip(&["netns", "add", &name]);
            h.names.push(name);
            let n = &h.names[i];
            ip(&["-n", n, "link", "set", "lo", "up"]);
            ip(&[
                "-n",
                n,
                "addr",
                "add",
                &format!("{}/32", addr(i)),
                "dev",
                "lo",
            ]);
        }
        for i in 0..HOSTS {
            for j in i + 1..HOSTS {
                let (a, b) = (format!("kv{i}{j}"), format!("kv{j}{i}"));
                let (na, nb) = (&h.names[i], &h.names[j]);
                ip(&[
                    "link", "add", &a, "netns", na, "type", "veth", "peer", "name", &b, "netns", nb,
                ]);
                ip(&["-n", na, "link", "set", &a, "up"]);
                ip(&["-n", nb, "link", "set", &b, "up"]);
                ip(&[
                    "-n",
                    na,
                    "route",
                    "add",
                    &format!("{}/32", addr(j)),
                    "dev",
                    &a,
                ]);
                ip(&[
                    "-n",
                    nb,
                    "route",
                    "add",
                    &format!("{}/32", addr(i)),
                    "dev",
                    &b,
                ]);
            }
        }
        h
    }

    /// `kalos bake ARGS` as every process, process i writing `dir`/pI.glb,
    /// with the host file in `dir`: the outputs and the running children.
    fn bake_all(&self, args: &[&str], dir: &Path) -> (Vec<PathBuf>, Children) {
        let file = hostfile(dir);
        let outs: Vec<PathBuf> = (0..HOSTS).map(|i| dir.join(format!("p{i}.glb"))).collect();
        let kids = (0..HOSTS)
            .map(|i| self.bake(i, args, &file, &outs[i]))
            .collect();
        (outs, Children(kids))
    }

    /// `kalos bake ARGS` as process `i`, in namespace `i`.
    fn bake(&self, i: usize, args: &[&str], hostfile: &Path, out: &Path) -> Child {
        Command::new("ip")
            .args(["netns", "exec", &self.names[i], kalos_bin(), "bake", "-q"])
            .args(args)
            .args([
                "--processes",
                &HOSTS.to_string(),
                "--process",
                &i.to_string(),
            ])
            .arg("--hostfile")
            .arg(hostfile)
            .arg("-o")
            .arg(out)
            .stdout(Stdio::null())
            .stderr(Stdio::piped())
            .spawn()
            .expect("ip netns exec kalos")
    }
}

impl Drop for Hosts {
    fn drop(&mut self) {
        for n in &self.names {
            let _ = Command::new("ip").args(["netns", "del", n]).status();
        }
    }
}

fn addr(i: usize) -> String {
    format!("10.213.0.{}", i + 1)
}

/// The host file of the three namespaces.
fn hostfile(dir: &Path) -> PathBuf {
    let p = dir.join("hosts.txt");
    let text: String = (0..HOSTS)
        .map(|i| format!("{}:{PORT}\n", addr(i)))
        .collect();
    std::fs::write(&p, text).expect("host file");
    p
}

/// Children killed (and reaped) on drop, so that a failed assert leaves
/// no process behind in a namespace being deleted.
struct Children(Vec<Child>);

impl Drop for Children {
    fn drop(&mut self) {
        for c in &mut self.0 {
            let _ = c.kill();
            let _ = c.wait();
        }
    }
}

/// Waits for `child` at most until `deadline`; None past it.
fn wait_until(child: &mut Child, deadline: Instant) -> Option<std::process::ExitStatus> {
    loop {
        if let Ok(Some(s)) = child.try_wait() {
            return Some(s);
        }
        if Instant::now() > deadline {
            return None;
        }
        std::thread::sleep(Duration::from_millis(50));
    }
}

fn stderr_of(c: &mut Child) -> String {
    use std::io::Read;
    let mut s = String::new();
    if let Some(e) = c.stderr.as_mut() {
        let _ = e.read_to_string(&mut s);
    }
    s
}

fn single(args: &[&str], out: &Path) -> Output {
    Command::new(kalos_bin())
        .args(["bake", "-q"])
        .args(args)
        .arg("-o")
        .arg(out)
        .output()
        .expect("kalos runs")
}

/// Three processes in three namespaces bake the Cornell box (its walls
/// tiled): the .glb of process 0 is that of the single-process bake.
#[test]
#[ignore = "needs root and iproute2: cargo test --release --test it -- --ignored netns"]
fn three_namespaced_hosts_give_the_single_process_bytes() {
    let _one_at_a_time = serial();
    if let Some(why) = unavailable() {
        eprintln!("skipped: {why}");
        return;
    }
    let dir = tempfile::tempdir().expect("temp dir");
    let args = ["--particles", "300k"];
    let one = dir.path().join("one.glb");
    let o = single(&args, &one);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let hosts = Hosts::new("same");
    let (outs, mut kids) = hosts.bake_all(&args, dir.path());
    let deadline = Instant::now() + Duration::from_secs(180);
    for (i, c) in kids.0.iter_mut().enumerate() {
        let s = wait_until(c, deadline);
        let err = stderr_of(c);
        assert!(s.is_some_and(|s| s.success()), "process {i}: {s:?}: {err}");
    }
    let want = std::fs::read(&one).expect("single-process bake");
    let got = std::fs::read(&outs[0]).expect("process 0 wrote the bake");
    assert!(got == want, "three namespaced hosts changed the .glb");
    for o in &outs[1..] {
        assert!(!o.exists(), "{} was written", o.display());
    }
}

/// Three processes in three namespaces bake a lightmap of the Cornell box
/// (its walls tiled, the texels dealt with the tiles, each host's halo
/// grown over the network): process 0 writes the .glb and atlas of the
/// single-process bake, the others nothing.
#[test]
#[ignore = "needs root and iproute2: cargo test --release --test it -- --ignored netns"]
fn three_namespaced_hosts_bake_the_single_process_lightmap() {
    let _one_at_a_time = serial();
    if let Some(why) = unavailable() {
        eprintln!("skipped: {why}");
        return;
    }
    let dir = tempfile::tempdir().expect("temp dir");
    let args = [
        "--lightmap",
        "--particles",
        "300k",
        "--lightmap-size",
        "128",
        "--gather",
        "16",
    ];
    let one = dir.path().join("one.glb");
    let o = single(&args, &one);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let hosts = Hosts::new("lmap");
    let (outs, mut kids) = hosts.bake_all(&args, dir.path());
    let deadline = Instant::now() + Duration::from_secs(180);
    for (i, c) in kids.0.iter_mut().enumerate() {
        let s = wait_until(c, deadline);
        let err = stderr_of(c);
        assert!(s.is_some_and(|s| s.success()), "process {i}: {s:?}: {err}");
    }
    let atlas = |p: &Path| p.with_extension("lightmap.exr");
    for (what, a, b) in [
        (".glb", one.clone(), outs[0].clone()),
        ("atlas", atlas(&one), atlas(&outs[0])),
    ] {
        let want = std::fs::read(&a).expect("single-process bake");
        let got = std::fs::read(&b).expect("process 0 wrote the bake");
        assert!(got == want, "three namespaced hosts changed the {what}");
    }
    for o in &outs[1..] {
        assert!(!o.exists(), "{} was written", o.display());
        assert!(!atlas(o).exists(), "{} was written", atlas(o).display());
    }
}

/// A host killed mid-bake: the other two stop within a bounded time with
/// an error naming it (its process index and address), and process 0
/// writes nothing.
#[test]
#[ignore = "needs root and iproute2: cargo test --release --test it -- --ignored netns"]
fn a_host_killed_mid_bake_stops_the_others_naming_it() {
    let _one_at_a_time = serial();
    if let Some(why) = unavailable() {
        eprintln!("skipped: {why}");
        return;
    }
    let dir = tempfile::tempdir().expect("temp dir");
    let hosts = Hosts::new("kill");
    // Long enough that the kill lands while tracing; the scratch folders
    // inside the test's own, so that the killed process's hit files go
    // with it
    let scratch = dir.path().display().to_string();
    let args = ["--particles", "50M", "--scratch", &scratch];
    let (outs, mut kids) = hosts.bake_all(&args, dir.path());
    std::thread::sleep(Duration::from_secs(4));
    for (i, c) in kids.0.iter_mut().enumerate() {
        assert!(
            c.try_wait().expect("try_wait").is_none(),
            "process {i} ended before the kill: {}",
            stderr_of(c)
        );
    }
    // `ip netns exec` execs kalos, so the child is kalos itself
    kids.0[2].kill().expect("kill process 2");
    let _ = kids.0[2].wait();
    let killed = Instant::now();
    let bound = Duration::from_secs(30);
    for (i, c) in kids.0.iter_mut().take(2).enumerate() {
        let s = wait_until(c, killed + bound);
        let err = stderr_of(c);
        assert!(
            s.is_some(),
            "process {i} still runs {bound:?} after process 2 was killed"
        );
        assert!(!s.is_some_and(|s| s.success()), "process {i} succeeded");
        assert!(
            err.contains("process 2") && err.contains(&addr(2)),
            "process {i}'s error does not name process 2 ({}): {err}",
            addr(2)
        );
        assert!(!outs[i].exists(), "process {i} left {}", outs[i].display());
    }
    eprintln!(
        "the others stopped {:.1} s after the kill",
        killed.elapsed().as_secs_f64()
    );
}
