//! The farm recipe in `farm/` runs as written: the Slurm array script for
//! every index, then its merge script, gives the bytes of one run; the
//! Kubernetes Indexed Job agrees with itself (completions, parallelism and
//! the shard count its command uses) and its command, run for every index,
//! does too.

use std::path::Path;
use std::process::Command;

use super::{ok, s, same_bytes};

const SHARDS: u32 = 3;

/// The folder of the kalos binary, for a script that calls `kalos`.
fn bin_dir() -> &'static Path {
    Path::new(env!("CARGO_BIN_EXE_kalos"))
        .parent()
        .expect("the binary has a folder")
}

fn run_script(mut cmd: Command, what: &str) {
    let o = cmd.output().expect("the shell runs");
    assert!(
        o.status.success(),
        "{what} failed: {}{}",
        String::from_utf8_lossy(&o.stdout),
        String::from_utf8_lossy(&o.stderr)
    );
}

/// The one-run reference of the recipes' default render at 2 spp, as
/// `one.EXT`.
fn one_run(dir: &Path, ext: &str) -> std::path::PathBuf {
    let one = dir.join(format!("one.{ext}"));
    ok(&["render", "builtin", "-q", "--spp", "2", "-o", s(&one)]);
    one
}

#[test]
fn the_slurm_array_script_and_its_merge_give_one_run() {
    let dir = tempfile::tempdir().expect("tempdir");
    let parts = dir.path().join("parts");
    for k in 0..SHARDS {
        let mut c = Command::new("bash");
        c.arg("farm/slurm.sh")
            .env("SLURM_ARRAY_TASK_ID", k.to_string())
            .env("SLURM_ARRAY_TASK_COUNT", SHARDS.to_string())
            .env("SLURM_CPUS_PER_TASK", "1")
            .env("KALOS", env!("CARGO_BIN_EXE_kalos"))
            .env("SPP", "2")
            .env("PARTS", &parts);
        run_script(c, &format!("farm/slurm.sh for index {k}"));
    }
    // the checkpoints the script asks for sit beside the parts and are not
    // taken for parts by the merge
    assert!(parts.join("ckpt-0.kpart").exists());
    let merged = dir.path().join("merged.pfm");
    let mut c = Command::new("bash");
    c.arg("farm/slurm-merge.sh")
        .env("KALOS", env!("CARGO_BIN_EXE_kalos"))
        .env("PARTS", &parts)
        .env("IMAGE", &merged);
    run_script(c, "farm/slurm-merge.sh");
    same_bytes(&one_run(dir.path(), "pfm"), &merged);

    // Run again, as a requeued task does: each resumes from its checkpoint
    for k in 0..SHARDS {
        let mut c = Command::new("bash");
        c.arg("farm/slurm.sh")
            .env("SLURM_ARRAY_TASK_ID", k.to_string())
            .env("SLURM_ARRAY_TASK_COUNT", SHARDS.to_string())
            .env("KALOS", env!("CARGO_BIN_EXE_kalos"))
            .env("SPP", "2")
            .env("PARTS", &parts);
        run_script(c, &format!("farm/slurm.sh again for index {k}"));
    }
    let again = dir.path().join("again.pfm");
    ok(&[
        "merge",
        s(&parts.join("shard-0.kpart")),
        s(&parts.join("shard-1.kpart")),
        s(&parts.join("shard-2.kpart")),
        "-o",
        s(&again),
    ]);
    same_bytes(&merged, &again);
}

/// The value of the first `key: value` line after `from` in `text`.
fn value_after<'a>(text: &'a str, from: &str, key: &str) -> &'a str {
    let start = text.find(from).unwrap_or_else(|| panic!("no '{from}'"));
    text[start..]
        .lines()
        .find_map(|l| {
            l.trim()
                .strip_prefix(key)
                .map(|v| v.trim().trim_matches('"'))
        })
        .unwrap_or_else(|| panic!("no '{key}' after '{from}'"))
}

/// The literal block (`- |`) of the job's container command.
fn command_block(text: &str) -> String {
    let mut lines = text.lines().skip_while(|l| !l.trim_end().ends_with("- |"));
    let head = lines.next().expect("the command is a literal block");
    let indent = head.len() - head.trim_start().len() + 2;
    lines
        .take_while(|l| l.trim().is_empty() || l.len() - l.trim_start().len() >= indent)
        .map(|l| l.get(indent..).unwrap_or(""))
        .collect::<Vec<_>>()
        .join("\n")
}

#[test]
fn the_kubernetes_indexed_job_agrees_with_itself_and_runs() {
    let yaml = std::fs::read_to_string("farm/k8s-job.yaml").expect("farm/k8s-job.yaml");
    let job = &yaml[yaml.find("kind: Job").expect("a Job")..];
    assert_eq!(value_after(job, "spec:", "completionMode:"), "Indexed");
    let completions = value_after(job, "spec:", "completions:");
    assert_eq!(value_after(job, "spec:", "parallelism:"), completions);
    assert_eq!(
        value_after(job, "- name: SHARDS", "value:"),
        completions,
        "SHARDS must equal completions: each index is one shard of SHARDS"
    );
    let script = command_block(job);
    assert!(
        script.contains("--shard \"$K/$SHARDS\"") && script.contains("JOB_COMPLETION_INDEX"),
        "{script}"
    );

    // Its command, for each index, with the job's shard count
    let dir = tempfile::tempdir().expect("tempdir");
    let shards: u32 = completions.parse().expect("completions is a number");
    let path = format!(
        "{}:{}",
        bin_dir().display(),
        std::env::var("PATH").unwrap_or_default()
    );
    for k in 0..shards {
        let mut c = Command::new("sh");
        c.args(["-c", &script])
            .env("JOB_COMPLETION_INDEX", k.to_string())
            .env("SHARDS", completions)
            .env("SCENE", value_after(job, "- name: SCENE", "value:"))
            .env("METHOD", value_after(job, "- name: METHOD", "value:"))
            .env("SEED", value_after(job, "- name: SEED", "value:"))
            .env("SPP", "2")
            .env("PARTS", dir.path())
            .env("PATH", &path);
        run_script(c, &format!("the job's command for index {k}"));
    }
    let merge = std::fs::read_to_string("farm/k8s-merge.yaml").expect("farm/k8s-merge.yaml");
    let merge_cmd = command_block(&merge).replace("/parts", s(dir.path()));
    let mut c = Command::new("sh");
    c.args(["-c", &merge_cmd]).env("PATH", &path);
    run_script(c, "the merge job's command");
    same_bytes(&one_run(dir.path(), "exr"), &dir.path().join("out.exr"));
}
