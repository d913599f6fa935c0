//! Mutation fuzzing of the four loaders (Mitsuba XML with its includes and
//! mesh files, OBJ with its MTL, PLY in ASCII and binary, glTF and GLB), and
//! of every method's setup on what they accept.
//!
//! Each case damages one file of a small valid scene (`fuzz/cases.rs`),
//! loads it, and when it loads renders a tiny image with one of the five
//! methods in turn. A case passes when loading or rendering returns an
//! error, or when the image is finite; it fails on a panic or a NaN/Inf
//! pixel. Aborts (a failed allocation) and hangs end the test process
//! itself, which fails it too; `examples/fuzz_loaders.rs` runs the same cases
//! in child processes with a time limit to count those separately.
//!
//! `KALOS_FUZZ_CASES=N` runs N cases (default 3000, well under a minute on CI's
//! 2 cores); `KALOS_FUZZ_SEED=S` draws a fresh set.

mod cases;

use std::panic::{catch_unwind, AssertUnwindSafe};

use kalos::methods::{self, Budget, Common, MethodConfig};
use kalos::render::Render;
use kalos::scene;
use kalos::world::World;

fn env_u64(name: &str, default: u64) -> u64 {
    std::env::var(name)
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(default)
}

/// What one case ended in.
#[derive(Debug, PartialEq)]
enum Outcome {
    LoadError,
    RenderError,
    Rendered,
    Panic(String),
    NonFinite(usize),
}

fn panic_text(p: Box<dyn std::any::Any + Send>) -> String {
    if let Some(s) = p.downcast_ref::<&str>() {
        s.to_string()
    } else if let Some(s) = p.downcast_ref::<String>() {
        s.clone()
    } else {
        "non-string panic".into()
    }
}

fn run_case(dir: &std::path::Path, c: &cases::Case, index: u64) -> Outcome {
    let path = dir.join(&c.main);
    let loaded = catch_unwind(AssertUnwindSafe(|| scene::load(&path)));
    let mut s = match loaded {
        Err(p) => return Outcome::Panic(format!("loading: {}", panic_text(p))),
        Ok(Err(_)) => return Outcome::LoadError,
        Ok(Ok(s)) => s,
    };
    // a tiny film: the loaders' own film limits are tested elsewhere, and
    // a case should cost milliseconds
    s.set_resolution(8, 6);
    let info = &methods::all()[(index % methods::all().len() as u64) as usize];
    let mut method: MethodConfig = (info.default)();
    if let MethodConfig::Density(d) = &mut method {
        d.particles = cases::DENSITY_PARTICLES;
    }
    let common = Common {
        seed: index,
        // a mutated albedo above one must not make a case run forever
        max_depth: if info.max_depth { Some(6) } else { None },
    };
    let rendered = catch_unwind(AssertUnwindSafe(|| {
        let world = World::new(s);
        Render::new(&world)
            .method(method)
            .common(common)
            .budget(Budget {
                passes: Some(1),
                ..Default::default()
            })
            .run(|_| {})
    }));
    match rendered {
        Err(p) => Outcome::Panic(format!("rendering with {}: {}", info.name, panic_text(p))),
        Ok(Err(_)) => Outcome::RenderError,
        Ok(Ok(r)) => {
            let bad = r.image.data.iter().filter(|p| !p.is_finite()).count();
            if bad > 0 {
                Outcome::NonFinite(bad)
            } else {
                Outcome::Rendered
            }
        }
    }
}

#[test]
#[ignore = "slow tier: cargo test --release -- --ignored"]
fn mutated_scenes_never_panic_or_give_non_finite_pixels() {
    let n = env_u64("KALOS_FUZZ_CASES", 3000);
    let run_seed = env_u64("KALOS_FUZZ_SEED", cases::RUN_SEED);
    let seeds = cases::seeds();
    let dir = tempfile::tempdir().unwrap();
    let (mut load_err, mut render_err, mut rendered) = (0, 0, 0);
    let mut failures = Vec::new();
    let mut slowest = Vec::new();
    // per seed: cases, cases that loaded
    let mut per_seed = std::collections::BTreeMap::<&str, (u32, u32)>::new();
    for i in 0..n {
        let c = cases::case(&seeds, run_seed, i);
        c.write(dir.path()).unwrap();
        let t0 = std::time::Instant::now();
        let outcome = run_case(dir.path(), &c, i);
        slowest.push((
            t0.elapsed().as_secs_f64(),
            i,
            c.label,
            format!("{outcome:?}"),
        ));
        let row = per_seed.entry(c.label).or_default();
        row.0 += 1;
        row.1 += (outcome != Outcome::LoadError) as u32;
        match outcome {
            Outcome::LoadError => load_err += 1,
            Outcome::RenderError => render_err += 1,
            Outcome::Rendered => rendered += 1,
            bad => failures.push(format!(
                "case {i} (KALOS_FUZZ_SEED={run_seed}), seed '{}', ops {:?}: {bad:?}",
                c.label, c.ops
            )),
        }
    }
    eprintln!(
        "fuzz: {n} cases, {load_err} load errors, {render_err} render errors, \
         {rendered} rendered, {} failures",
        failures.len()
    );
    slowest.sort_by(|a, b| b.0.total_cmp(&a.0));
    eprintln!("slowest: {:?}", &slowest[..slowest.len().min(8)]);
    for (label, (cases, loaded)) in &per_seed {
        eprintln!("  {label:12} {cases:5} cases, {loaded:5} loaded");
    }
    assert!(failures.is_empty(), "{}", failures.join("\n"));
    // the operators must leave most files loadable, or the methods' setup
    // is never reached: a check on the fuzzer itself
    assert!(rendered > 0, "no mutated scene loaded and rendered");
}

/// The seeds themselves are valid: a failure here is a broken fuzzer, not
/// a broken loader.
#[test]
fn fuzz_seeds_load() {
    let dir = tempfile::tempdir().unwrap();
    for s in cases::seeds() {
        let c = cases::Case {
            label: s.label,
            main: s.main.clone(),
            files: s.files.clone(),
            ops: vec![],
        };
        c.write(dir.path()).unwrap();
        let scene = scene::load(&dir.path().join(&s.main))
            .unwrap_or_else(|e| panic!("seed '{}': {e}", s.label));
        assert!(
            !scene.triangles.is_empty(),
            "seed '{}' has no triangles",
            s.label
        );
    }
}

/// Found by the fuzzer: tobj 4 panicked on an MTL colour with fewer than
/// three numbers. The OBJ now loads with its materials refused, and the
/// warning names the MTL file and line.
#[test]
fn short_mtl_colour_is_a_warning_not_a_panic() {
    let dir = tempfile::tempdir().unwrap();
    let obj = "mtllib m.mtl\nv 0 0 0\nv 1 0 0\nv 0 1 0\nusemtl a\nf 1 2 3\n";
    std::fs::write(dir.path().join("t.obj"), obj).unwrap();
    std::fs::write(dir.path().join("m.mtl"), "newmtl a\nKd 0.5 0.5\n").unwrap();
    let s = scene::load(&dir.path().join("t.obj")).unwrap_or_else(|e| panic!("{e}"));
    let w = s.warnings.join("\n");
    assert!(
        w.contains("m.mtl:2") && w.contains("Kd expects three numbers"),
        "warnings: {w}"
    );
}

/// The glTF seed with `from` replaced by `to` in its JSON, loaded.
fn load_gltf_with(from: &str, to: &str) -> Result<scene::Scene, scene::SceneError> {
    let dir = tempfile::tempdir().unwrap();
    let seed = cases::seeds()
        .into_iter()
        .find(|s| s.label == "gltf")
        .unwrap();
    for f in &seed.files {
        let mut bytes = f.bytes.clone();
        if f.name == seed.main {
            let text = String::from_utf8(bytes).unwrap();
            assert!(text.contains(from), "the seed has no {from}");
            bytes = text.replace(from, to).into_bytes();
        }
        std::fs::write(dir.path().join(&f.name), bytes).unwrap();
    }
    scene::load(&dir.path().join(&seed.main))
}

/// Found by the fuzzer: gltf-json 1.4.1's validation indexed the accessor
/// list with a primitive's POSITION index unchecked, and panicked.
#[test]
fn gltf_attribute_naming_a_missing_accessor_is_an_error() {
    let e =
        load_gltf_with("\"POSITION\":0", "\"POSITION\":7").expect_err("accessor 7 does not exist");
    let msg = e.to_string();
    assert!(
        msg.contains("names accessor 7") && msg.contains("quad.gltf"),
        "{msg}"
    );
}

/// Found by the fuzzer: the gltf crate's index reader reached an
/// `unreachable!` on an index accessor of floats.
#[test]
fn gltf_float_indices_are_an_error() {
    let e = load_gltf_with("\"componentType\":5123", "\"componentType\":5126")
        .expect_err("float indices");
    let msg = e.to_string();
    assert!(msg.contains("indices must be unsigned integer"), "{msg}");
}
