//! The dataflow bake with work split below the surface: a scene whose
//! floor receives nearly every hit is cut into tiles, and 4 workers share
//! the estimate evenly (`balance` of `--stats`), with the bytes of one
//! process for 1 to 4 workers, for the display mesh and for lightmaps.

use std::path::Path;
use std::process::{Command, Output};

/// A 10 m × 10 m floor under a small lamp near one corner (a bright spot
/// on one side of the floor), and a 0.5 m cube on the floor: the floor
/// receives about all the hits.
const SCENE: &str = r#"<scene version="3.0.0">
    <bsdf type="diffuse" id="floor">
        <rgb name="reflectance" value="0.6, 0.55, 0.5"/>
    </bsdf>
    <bsdf type="diffuse" id="black">
        <rgb name="reflectance" value="0, 0, 0"/>
    </bsdf>
    <shape type="rectangle">
        <transform name="to_world">
            <rotate x="1" angle="-90"/>
            <scale x="5" y="1" z="5"/>
        </transform>
        <ref id="floor"/>
    </shape>
    <shape type="cube">
        <transform name="to_world">
            <scale x="0.25" y="0.25" z="0.25"/>
            <translate x="1" y="0.25" z="1"/>
        </transform>
        <ref id="floor"/>
    </shape>
    <shape type="rectangle">
        <transform name="to_world">
            <rotate x="1" angle="90"/>
            <scale x="0.2" y="1" z="0.2"/>
            <translate x="-2.5" y="1.5" z="-2"/>
        </transform>
        <ref id="black"/>
        <emitter type="area">
            <rgb name="radiance" value="300, 300, 300"/>
        </emitter>
    </shape>
</scene>
"#;

fn bake(scene: &Path, out: &Path, extra: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_kalos"))
        .arg("bake")
        .arg(scene)
        .args(["-q", "--stats", "--particles", "300k", "-o"])
        .arg(out)
        .args(extra)
        .output()
        .expect("kalos runs")
}

fn ok(o: &Output) -> String {
    let text = format!(
        "{}{}",
        String::from_utf8_lossy(&o.stdout),
        String::from_utf8_lossy(&o.stderr)
    );
    assert!(o.status.success(), "{text}");
    text
}

/// The `balance: X` of `--stats`.
fn balance(stats: &str) -> f64 {
    let line = stats
        .lines()
        .find_map(|l| l.strip_prefix("balance: "))
        .unwrap_or_else(|| panic!("no balance line in: {stats}"));
    line.split_whitespace()
        .next()
        .and_then(|x| x.parse().ok())
        .unwrap_or_else(|| panic!("bad balance line: {line}"))
}

/// The floor's hits and vertices, split into tiles dealt to 4 workers,
/// give a balance ≤ 1.15, and 1 to 4 workers give the single-process
/// bytes.
///
/// The margin. The floor is 98 % of the planar area, so with 16 tiles a
/// worker it is cut into 8 × 8 tiles. The lamp lights one corner of the
/// floor far more than the rest: owned whole, the floor would put about
/// all the work on one worker (balance near 4). The tiles are dealt by a
/// pilot (the first 32,768 particles, about 29,000 hits, traced alike by
/// every worker), largest first to the least loaded worker, so the
/// predicted loads differ by at most one tile's share, and the pilot's
/// error on a worker's quarter (about 7,000 pilot hits) is about 1 %
/// (Poisson). What the pilot does not predict is the halo: at 300k
/// particles the kernel width (0.39 m) is a third of a tile (1.25 m), so
/// the halo is about 1.3 times a worker's own hits here, and how much of
/// it a worker gets depends on how its tiles border other workers'. On
/// this machine the figure is 1.015 (balances of 1.01 to 1.13 were seen
/// on this scene, the Cornell box and the big room with other tile
/// sizes); the bake is deterministic, so the test is too, and it fails
/// if a change to the deal pushes it past the issue's 1.15.
#[test]
fn one_dominant_surface_is_shared_evenly_by_4_workers() {
    let dir = tempfile::tempdir().expect("temp dir");
    let scene = dir.path().join("floor.xml");
    std::fs::write(&scene, SCENE).expect("scene");
    let one = dir.path().join("one.glb");
    ok(&bake(&scene, &one, &[]));
    let want = std::fs::read(&one).expect("single-process bake");
    for workers in ["1", "2", "3", "4"] {
        let out = dir.path().join(format!("w{workers}.glb"));
        let stats = ok(&bake(&scene, &out, &["--workers", workers]));
        let got = std::fs::read(&out).expect("dataflow bake");
        assert!(got == want, "--workers {workers} changed the .glb");
        if workers == "4" {
            let b = balance(&stats);
            eprintln!("balance at 4 workers: {b}");
            assert!((1.0..=1.15).contains(&b), "balance {b} > 1.15: {stats}");
        }
    }
}

/// Hits in several chunks per surface (`--chunk-hits`, far below a
/// surface's hits): the tiles' sums are exact, so the bytes are still
/// those of one process.
#[test]
fn chunked_estimates_keep_the_single_process_bytes() {
    let dir = tempfile::tempdir().expect("temp dir");
    let scene = dir.path().join("floor.xml");
    std::fs::write(&scene, SCENE).expect("scene");
    let one = dir.path().join("one.glb");
    ok(&bake(&scene, &one, &["--chunk-hits", "20000"]));
    let unchunked = dir.path().join("unchunked.glb");
    ok(&bake(&scene, &unchunked, &[]));
    let want = std::fs::read(&one).expect("single-process bake");
    assert!(
        std::fs::read(&unchunked).expect("bake") == want,
        "the chunk size changed the .glb"
    );
    let out = dir.path().join("w3.glb");
    ok(&bake(
        &scene,
        &out,
        &["--workers", "3", "--chunk-hits", "20000"],
    ));
    assert!(
        std::fs::read(&out).expect("dataflow bake") == want,
        "3 workers with small chunks changed the .glb"
    );
}

/// The halo hits of `--stats`'s worker lines, summed.
fn halo_hits(stats: &str) -> u64 {
    stats
        .lines()
        .filter_map(|l| l.split_once("(halo ")?.1.split_whitespace().next())
        .map(|x| x.parse::<u64>().unwrap_or_else(|_| panic!("bad halo: {x}")))
        .sum()
}

/// A lightmap bake across 1 to 4 workers gives the single-process atlas
/// and .glb, byte for byte, with and without the final gather: the floor's
/// texels are dealt with its tiles, and each worker's halo grows until it
/// holds every hit within its texels' reach (which the bytes would betray
/// otherwise: with the halo test dropped, 4 workers gave another atlas).
#[test]
fn lightmaps_keep_the_single_process_bytes() {
    let dir = tempfile::tempdir().expect("temp dir");
    let scene = dir.path().join("floor.xml");
    std::fs::write(&scene, SCENE).expect("scene");
    let small = ["--lightmap", "--lightmap-size", "96"];
    for gather in [["--gather", "16"], ["--gather", "0"]] {
        let args = |w: &[&'static str]| {
            let mut a = small.to_vec();
            a.extend(gather);
            if gather[1] == "0" {
                a.extend(["--gather-lights", "0"]);
            }
            a.extend(w);
            a
        };
        let one = dir.path().join("one.glb");
        ok(&bake(&scene, &one, &args(&[])));
        let want = std::fs::read(&one).expect("single-process bake");
        let atlas = std::fs::read(dir.path().join("one.lightmap.exr")).expect("atlas");
        for workers in ["1", "2", "3", "4"] {
            let out = dir.path().join(format!("w{workers}.glb"));
            let stats = ok(&bake(&scene, &out, &args(&["--workers", workers])));
            let got = std::fs::read(&out).expect("dataflow bake");
            let got_atlas = dir.path().join(format!("w{workers}.lightmap.exr"));
            let what = format!("--workers {workers} {}", gather.join(" "));
            assert!(got == want, "{what} changed the .glb");
            assert!(
                std::fs::read(got_atlas).expect("atlas") == atlas,
                "{what} changed the atlas"
            );
            if workers != "1" {
                assert!(halo_hits(&stats) > 0, "{what}: no halo: {stats}");
                eprintln!("{what}: balance {}", balance(&stats));
            }
        }
    }
}
