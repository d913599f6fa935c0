//! `kalos bench`: ray-core throughput. Incoherent closest hits, then the
//! recorded ray sets (camera, diffuse bounce, shadow) replayed through
//! kalos's BVH and, when built with the `embree` feature, through Embree on
//! the same rays, with the ratio and the answers compared.

use std::path::PathBuf;
use std::time::Instant;

use anyhow::{Context, Result};
use clap::Args;

use kalos::accel::{Accel, BuildOptions, Builder, CollapseRule, Visits};
use kalos::bench::rayset::{self, RaySets, SetKind};
use kalos::bench::replay::{self, KalosPacketTracer, KalosTracer, Timing, Tracer};
use kalos::scene::Scene;
use kalos::world::World;
use rayon::prelude::*;

use crate::{check_output, load_scene, parse_res, progress, say, Defines};

#[derive(Args)]
pub struct BenchArgs {
    /// Scene to trace (omit for a generated scene of about 1 M triangles).
    scene: Option<PathBuf>,
    /// Incoherent rays per measurement (0 skips that measurement).
    #[arg(long, default_value_t = 4_000_000)]
    rays: u64,
    #[command(flatten)]
    defines: Defines,
    /// Triangles in the generated scene.
    #[arg(long, default_value_t = 1_000_000)]
    triangles: u64,
    /// Film resolution of the recorded camera rays, WxH (default: the
    /// scene's).
    #[arg(long, value_parser = parse_res, conflicts_with = "replay")]
    res: Option<(u32, u32)>,
    /// Seed of the recorded ray sets.
    #[arg(long, default_value_t = 1, conflicts_with = "replay")]
    seed: u64,
    /// Save the recorded ray sets to FILE (.krays).
    #[arg(long, value_name = "FILE", conflicts_with = "replay")]
    record: Option<PathBuf>,
    /// Replay the ray sets of FILE (from `--record`) instead of recording
    /// them; the scene must be the one they were recorded from.
    #[arg(long, value_name = "FILE")]
    replay: Option<PathBuf>,
    /// Timed repetitions of each set (the median is reported).
    #[arg(long, default_value_t = 5, value_parser = clap::value_parser!(u64).range(1..=1000))]
    repeat: u64,
    /// Leave Embree out (in a build with the `embree` feature).
    #[arg(long)]
    no_embree: bool,
    /// Let Embree print its log, with its BVH's statistics (in a build
    /// with the `embree` feature).
    #[arg(long)]
    embree_stats: bool,
    /// Build kalos's BVH with this builder instead of the default, best
    /// (ploc-fast, ploc-medium, ploc-slow, ploc-very-slow, sah,
    /// sah-reinsert, both, best).
    #[arg(long, value_name = "BUILDER", value_parser = parse_builder)]
    bvh: Option<Builder>,
    /// How kalos's binary BVH becomes the wide one: sah (the default; the
    /// wide tree of least SAH cost) or greedy (open the largest child).
    #[arg(long, value_name = "RULE", value_parser = parse_collapse)]
    collapse: Option<CollapseRule>,
    /// The collapse's cost of a node relative to one pack test: of a wide
    /// node under sah (default 0.5), of a binary node under greedy (default
    /// 0.5 for 4 wide, 0.25 for 8 wide).
    #[arg(long, value_name = "C", value_parser = parse_c_node)]
    c_node: Option<f32>,
    /// The most triangles in a leaf of kalos's BVH (1 to 32; default one
    /// pack: the tree's width, 4 or 8).
    #[arg(long, value_name = "N", value_parser = clap::value_parser!(u64).range(1..=32))]
    leaf_max: Option<u64>,
}

fn parse_builder(s: &str) -> Result<Builder, String> {
    Builder::ALL
        .into_iter()
        .find(|b| b.name() == s)
        .ok_or_else(|| {
            let names: Vec<&str> = Builder::ALL.iter().map(|b| b.name()).collect();
            format!(
                "unknown BVH builder '{s}'; expected one of {}",
                names.join(", ")
            )
        })
}

fn parse_collapse(s: &str) -> Result<CollapseRule, String> {
    match s {
        "sah" => Ok(CollapseRule::Sah),
        "greedy" => Ok(CollapseRule::Greedy),
        _ => Err(format!("unknown collapse '{s}'; expected sah or greedy")),
    }
}

fn parse_c_node(s: &str) -> Result<f32, String> {
    match s.parse::<f32>() {
        Ok(c) if c.is_finite() && c > 0.0 => Ok(c),
        _ => Err(format!("expected a positive number, got '{s}'")),
    }
}

/// The one-minute, five-minute and fifteen-minute load averages, for the
/// record (the machine may be shared).
fn load_average() -> String {
    std::fs::read_to_string("/proc/loadavg")
        .ok()
        .map(|s| s.split_whitespace().take(3).collect::<Vec<_>>().join(" "))
        .unwrap_or_else(|| "unknown".into())
}

pub fn run(a: BenchArgs) -> Result<()> {
    // Files first: a bad ray-set file or an unwritable --record fails
    // before the scene loads
    if let Some(p) = &a.record {
        check_output(p, &["krays"])?;
    }
    let replayed = match &a.replay {
        Some(p) => Some(rayset::read(p)?),
        None => None,
    };
    let mut scene = match &a.scene {
        Some(p) => load_scene(Some(p), &a.defines)?,
        None => kalos::scenegen::bench_scene(a.triangles),
    };
    if let Some(s) = &replayed {
        scene.set_resolution(s.width, s.height);
    } else if let Some((w, h)) = a.res {
        scene.set_resolution(w, h);
    }
    say!(
        "scene: {} ({} triangles); load average {}",
        scene.source,
        scene.triangles.len(),
        load_average()
    );
    let t = Instant::now();
    let mut world = progress::build_world(scene);
    say!("kalos BVH build: {:.2} s", t.elapsed().as_secs_f64());
    let defaults = BuildOptions::default();
    let options = BuildOptions {
        builder: a.bvh.unwrap_or(defaults.builder),
        collapse: a.collapse.unwrap_or(defaults.collapse),
        c_node: a.c_node.or(defaults.c_node),
        leaf_max: a.leaf_max.map(|n| n as usize).or(defaults.leaf_max),
        kernel: defaults.kernel,
    };
    if options != defaults {
        let t = Instant::now();
        world.accel = Accel::build_with(&world.scene, &options, &mut |_| {});
        let or_default = |x: Option<String>| x.unwrap_or_else(|| "default".into());
        say!(
            "kalos BVH rebuilt with {}, the {} collapse, C_node {}, at most {} triangles a leaf: {:.2} s",
            options.builder.name(),
            match options.collapse {
                CollapseRule::Sah => "sah",
                CollapseRule::Greedy => "greedy",
            },
            or_default(options.c_node.map(|c| c.to_string())),
            or_default(options.leaf_max.map(|n| n.to_string())),
            t.elapsed().as_secs_f64()
        );
    }
    let q = world.accel.tree_stats();
    say!(
        "kalos BVH, {} wide: {} nodes, {} leaves, {} packs ({:.2} triangles a pack); SAH cost {:.2} ({:.2} node tests + {:.2} pack tests a ray entering the root)",
        q.width,
        q.nodes,
        q.leaves,
        q.packs,
        q.triangles as f64 / q.packs.max(1) as f64,
        q.sah(),
        q.node_tests,
        q.pack_tests
    );

    let all_threads = rayon::current_num_threads();
    if a.rays > 0 {
        incoherent(&world, a.rays, all_threads);
    }

    // The ray sets: recorded now, or read from --replay
    let sets = match (replayed, &a.replay) {
        (Some(s), Some(p)) => {
            rayset::check_scene(p, &s, kalos::partial::scene_hash(&world.scene))?;
            s
        }
        _ => {
            let t = Instant::now();
            let s = rayset::record(&world, a.seed);
            say!(
                "recorded the ray sets in {:.2} s",
                t.elapsed().as_secs_f64()
            );
            s
        }
    };
    if let Some(p) = &a.record {
        rayset::write(p, &sets).with_context(|| "saving the ray sets".to_string())?;
        say!("ray sets written to {}", p.display());
    }
    say!(
        "ray sets ({}x{}, seed {}): {}",
        sets.width,
        sets.height,
        sets.seed,
        SetKind::ALL
            .map(|k| format!("{} {} rays", k.name(), sets.rays(k).len()))
            .join(", ")
    );
    let threads: Vec<usize> = if all_threads > 1 {
        vec![1, all_threads]
    } else {
        vec![1]
    };
    let kalos_core = KalosTracer(&world.accel);
    let kalos_packets = KalosPacketTracer(&world.accel);
    let repeat = a.repeat as usize;
    let run_with = |others: &[&dyn Tracer]| -> Result<()> {
        let mut tracers: Vec<&dyn Tracer> = vec![&kalos_core, &kalos_packets];
        tracers.extend_from_slice(others);
        report_answers(&world.scene, &sets, &tracers);
        report_visits(&world.accel, &sets);
        let timings =
            replay::measure(&sets, &tracers, &threads, repeat).context("making a thread pool")?;
        report_timings(&timings, repeat);
        Ok(())
    };
    embree_or_not(&world, a.no_embree, a.embree_stats, &run_with)?;
    say!("load average at the end: {}", load_average());
    Ok(())
}

/// Runs `run_with` with Embree's tracers when built with them and not
/// refused, else with none.
#[cfg(feature = "embree")]
fn embree_or_not(
    world: &World,
    no_embree: bool,
    verbose: bool,
    run_with: &dyn Fn(&[&dyn Tracer]) -> Result<()>,
) -> Result<()> {
    if no_embree || world.scene.triangles.is_empty() {
        return run_with(&[]);
    }
    kalos::bench::embree::with_tracers(&world.scene, verbose, |one, stream, secs| {
        say!("Embree BVH build: {secs:.2} s");
        run_with(&[one, stream])
    })
}

#[cfg(not(feature = "embree"))]
fn embree_or_not(
    _world: &World,
    no_embree: bool,
    _verbose: bool,
    run_with: &dyn Fn(&[&dyn Tracer]) -> Result<()>,
) -> Result<()> {
    if !no_embree {
        say!("Embree: not in this build (cargo build --release --features embree)");
    }
    run_with(&[])
}

/// The answers of each core to each set, untimed (this also warms the
/// caches): kalos's hit counts, and how far every other core agrees.
fn report_answers(scene: &Scene, sets: &RaySets, tracers: &[&dyn Tracer]) {
    for kind in SetKind::ALL {
        let Some((first, others)) = tracers.split_first() else {
            return;
        };
        let reference = replay::answers(*first, sets, kind);
        let what = if kind.closest_hit() {
            "hit"
        } else {
            "occluded"
        };
        say!(
            "{}: {} of {} rays {what} (kalos)",
            kind.name(),
            reference.hits(),
            sets.rays(kind).len()
        );
        for t in others.iter().filter(|t| t.traces(kind)) {
            let theirs = replay::answers(*t, sets, kind);
            let g = replay::agreement(&reference, &theirs);
            if kind.closest_hit() {
                say!(
                    "  {} differs from kalos on {} rays: {} ties (another triangle at the same distance), {} hit vs miss, {} other",
                    t.name(),
                    g.differ,
                    g.ties,
                    g.hit_vs_miss,
                    g.differ - g.ties - g.hit_vs_miss
                );
            } else {
                say!(
                    "  {} differs from kalos on {} occlusion flags",
                    t.name(),
                    g.differ
                );
            }
            if g.differ > 0 {
                let v = replay::judge(scene, sets.rays(kind), &reference, &theirs);
                say!(
                    "    brute force (f64, every triangle) on {} of them: kalos alone right {}, {} alone right {}, both {}, neither {}; {} within 1e-5 of an edge",
                    v.judged,
                    v.reference_right,
                    t.name(),
                    v.other_right,
                    v.both_right,
                    v.neither_right,
                    v.on_edge
                );
                let hit = |a: &replay::Answer| {
                    if a.is_hit() {
                        format!("triangle {} at t {:.6}", a.tri, a.t)
                    } else {
                        "a miss".to_string()
                    }
                };
                for e in &v.examples {
                    let search = match e.search {
                        Some((t, m)) => format!("a hit at t {t:.6}, smallest barycentric {m:.1e}"),
                        None => "a miss".into(),
                    };
                    say!(
                        "    e.g. {} ray {}: kalos {}, {} {}, the search {search}",
                        kind.name(),
                        e.index,
                        hit(&e.reference),
                        t.name(),
                        hit(&e.other)
                    );
                }
            }
        }
    }
}

/// The mean wide nodes and triangle packs kalos's kernels test per ray of
/// each set (untimed: the counted queries are not the timed ones).
fn report_visits(accel: &Accel, sets: &RaySets) {
    let line: Vec<String> = SetKind::ALL
        .into_iter()
        .filter(|&k| !sets.rays(k).is_empty())
        .map(|kind| {
            let rays = sets.rays(kind);
            let v = rays
                .par_chunks(1024)
                .map(|chunk| {
                    let mut v = Visits::default();
                    for r in chunk {
                        if kind.closest_hit() {
                            accel.intersect_counted(r, &mut v);
                        } else {
                            accel.occluded_ray_counted(r, &mut v);
                        }
                    }
                    v
                })
                .reduce(Visits::default, |mut a, b| {
                    a += b;
                    a
                });
            let n = rays.len() as f64;
            format!(
                "{} {:.2} nodes + {:.2} packs",
                kind.name(),
                v.nodes as f64 / n,
                v.packs as f64 / n
            )
        })
        .collect();
    say!("kalos tests per ray: {}", line.join(", "));
}

/// One line per set and thread count: each core's Mrays/s (median of the
/// repetitions) and, for the others, kalos's ratio to it.
fn report_timings(timings: &[Timing], repeat: usize) {
    say!("replay, Mrays/s (median of {repeat}; the cores alternate within each repetition):");
    let mut i = 0;
    while i < timings.len() {
        let (kind, threads) = (timings[i].kind, timings[i].threads);
        let group: Vec<&Timing> = timings[i..]
            .iter()
            .take_while(|t| t.kind == kind && t.threads == threads)
            .collect();
        i += group.len();
        let kalos = group[0].mrays_per_s();
        let mut line = format!(
            "  {:<6} {} thread{} {:>9} rays: {} {:.2}",
            kind.name(),
            threads,
            if threads == 1 { " " } else { "s" },
            group[0].rays,
            group[0].tracer,
            kalos
        );
        for t in &group[1..] {
            let m = t.mrays_per_s();
            line += &format!(
                ", {} {:.2} (kalos/{} {:.2})",
                t.tracer,
                m,
                t.tracer,
                kalos / m
            );
        }
        say!("{line}");
        // The packets against the others on the same rays
        if let Some(p) = group[1..].iter().find(|t| t.tracer == "kalos packets") {
            let pm = p.mrays_per_s();
            let mut line = format!("{:<23} kalos packets/kalos {:.2}", "", pm / kalos);
            for t in group[1..].iter().filter(|t| t.tracer != p.tracer) {
                line += &format!(", kalos packets/{} {:.2}", t.tracer, pm / t.mrays_per_s());
            }
            say!("{line}");
        }
    }
}

/// The incoherent closest-hit measurement (uniform origins in the scene's
/// bounds, uniform directions), one thread and all.
fn incoherent(world: &World, rays: u64, all_threads: usize) {
    let one = kalos::bench::incoherent_closest_hits(world, rays, 1);
    let all = kalos::bench::incoherent_closest_hits(world, rays, all_threads);
    say!(
        "incoherent closest hits, 1 thread:  {:.2} Mrays/s ({} hits of {} rays)",
        one.mrays_per_s,
        one.hits,
        one.rays
    );
    say!(
        "incoherent closest hits, {all_threads} threads: {:.2} Mrays/s (ratio {:.2}x)",
        all.mrays_per_s,
        all.mrays_per_s / one.mrays_per_s
    );
}
