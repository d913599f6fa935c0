//! The command line as a user meets it: each method's help lists only its
//! own settings, a flag of another method is an error naming both, a method
//! that cannot honour `--max-depth` says so, and a failed setup exits
//! non-zero with the reason.

use crate::common::{kalos, stderr};
use std::process::{Command, Output};

fn stdout(o: &Output) -> String {
    String::from_utf8_lossy(&o.stdout).into_owned()
}

#[test]
fn a_flag_of_another_method_is_an_error_naming_both() {
    let dir = tempfile::tempdir().expect("tempdir");
    let out = dir.path().join("x.pfm");
    let out = out.to_str().expect("utf-8 path");
    for (method, flag, owner) in [
        ("path", "--lambda", "plb"),
        ("path", "--discard", "light"),
        ("light", "--patches", "bundle"),
        ("bundle", "--c1", "density"),
        ("density", "--population", "plb"),
    ] {
        let o = kalos(&[
            "render", "--method", method, flag, "3", "--res", "8x8", "--spp", "1", "-o", out,
        ]);
        assert!(!o.status.success(), "{method} {flag} was accepted");
        let e = stderr(&o);
        assert!(
            e.contains(flag) && e.contains(&format!("'{method}'")) && e.contains(owner),
            "{method} {flag}: {e}"
        );
    }
    assert!(!dir.path().join("x.pfm").exists(), "nothing is rendered");
}

#[test]
fn each_method_help_lists_only_its_own_flags() {
    // every method's own flags, complete: a flag listed for another method
    // and not for this one must not show in this one's help
    let own: [(&str, &[&str]); 5] = [
        ("path", &["--rr-depth", "--light-selection"]),
        ("light", &["--variant", "--discard", "--camera-pass"]),
        (
            "plb",
            &[
                "--lambda",
                "--phase-len",
                "--population",
                "--discard",
                "--camera-pass",
                "--variant",
                "--measure",
            ],
        ),
        (
            "bundle",
            &[
                "--patches",
                "--patch-edge",
                "--patch-budget",
                "--map-res",
                "--sequence",
                "--bundle-image",
                "--visibility",
                "--discard",
                "--subpixel",
                "--positions",
                "--direct",
                "--gather",
            ],
        ),
        (
            "density",
            &[
                "--particles",
                "--c1",
                "--c2",
                "--epsilon",
                "--no-decimate",
                "--variant",
                "--max-verts",
                "--scratch",
                "--hits",
                "--chunk-hits",
            ],
        ),
    ];
    for (method, flags) in own {
        let o = kalos(&["render", "--method", method, "--help"]);
        assert!(o.status.success(), "{method} --help failed");
        let help = stdout(&o);
        for f in flags {
            assert!(help.contains(f), "{method} --help lacks {f}");
        }
        for (other, oflags) in own {
            if other == method {
                continue;
            }
            for f in oflags.iter().filter(|f| !flags.contains(f)) {
                assert!(
                    !help.contains(&format!("{f} ")),
                    "{method} --help shows {other}'s {f}"
                );
            }
        }
        // the shared flags are there for every method
        for f in ["--spp", "--seed", "--max-depth", "--output"] {
            assert!(help.contains(f), "{method} --help lacks {f}");
        }
    }
}

#[test]
fn a_method_that_cannot_honour_max_depth_says_so() {
    let dir = tempfile::tempdir().expect("tempdir");
    let out = dir.path().join("x.pfm");
    let o = kalos(&[
        "render",
        "--method",
        "bundle",
        "--max-depth",
        "2",
        "--res",
        "8x8",
        "-o",
        out.to_str().expect("utf-8"),
    ]);
    assert!(!o.status.success());
    let e = stderr(&o);
    assert!(e.contains("bundle") && e.contains("--max-depth"), "{e}");
}

#[test]
fn bad_values_are_refused_before_rendering() {
    for (method, flag, value) in [
        ("plb", "--lambda", "-1"),
        ("plb", "--phase-len", "0"),
        ("bundle", "--patches", "0"),
        ("density", "--c1", "0"),
        ("light", "--variant", "nope"),
        ("light", "--camera-pass", "maybe"),
        // budgets that could never be reached: NaN compares false with
        // everything, so a NaN limit would run for ever
        ("path", "--spp", "nan"),
        ("path", "--time", "nan"),
        ("path", "--spp", "0"),
        ("plb", "--time", "-1"),
        ("light", "--spp", "inf"),
    ] {
        let o = kalos(&[
            "render",
            "--method",
            method,
            flag,
            value,
            "-o",
            "x.pfm",
            "--dry-run",
        ]);
        assert!(!o.status.success(), "{method} {flag} {value} was accepted");
        assert!(stderr(&o).contains(flag), "{}", stderr(&o));
    }
    // --discard is for light's iteration form only
    let o = kalos(&["render", "--method", "light", "--discard", "5", "--dry-run"]);
    assert!(!o.status.success());
    assert!(stderr(&o).contains("iteration"), "{}", stderr(&o));
    // and the same flags with valid values are accepted (the refusals above
    // are the values', not the command's)
    for args in [
        &["--method", "plb", "--lambda", "0.5", "--phase-len", "10"][..],
        &[
            "--method",
            "light",
            "--variant",
            "iteration",
            "--discard",
            "5",
        ],
        &["--method", "light", "--camera-pass", "off"],
        &["--method", "path", "--spp", "0.5", "--time", "2"],
    ] {
        let mut all = vec!["render"];
        all.extend_from_slice(args);
        all.push("--dry-run");
        let o = kalos(&all);
        assert!(o.status.success(), "{args:?}: {}", stderr(&o));
    }
}

#[test]
fn a_method_renders_with_its_own_flags() {
    let dir = tempfile::tempdir().expect("tempdir");
    let out = dir.path().join("plb.pfm");
    let o = kalos(&[
        "render",
        "--method=plb",
        "--lambda",
        "2",
        "--variant",
        "pooled",
        "--camera-pass",
        "off",
        "--res",
        "16x16",
        "--spp",
        "1",
        "-q",
        "-o",
        out.to_str().expect("utf-8"),
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(out.exists());
    assert!(stdout(&o).contains("plb"));
}

#[test]
fn a_failed_density_bake_exits_non_zero_with_the_reason() {
    let dir = tempfile::tempdir().expect("tempdir");
    // a directory under a regular file cannot be made, even by root
    let file = dir.path().join("file");
    std::fs::write(&file, b"x").expect("write");
    let scratch = file.join("scratch");
    let out = dir.path().join("d.pfm");
    let o = kalos(&[
        "render",
        "--method",
        "density",
        "--particles",
        "1000",
        "--scratch",
        scratch.to_str().expect("utf-8"),
        "--res",
        "8x8",
        "-q",
        "-o",
        out.to_str().expect("utf-8"),
    ]);
    assert!(!o.status.success(), "a failed bake must not exit 0");
    let e = stderr(&o);
    assert!(e.contains("scratch directory"), "{e}");
    assert!(
        e.contains(scratch.to_str().expect("utf-8")) || e.contains(file.to_str().expect("utf-8")),
        "{e}"
    );
    assert!(!out.exists(), "no image from a failed bake");
}

/// A scene file that does not exist: an error that mentions it shows that
/// kalos got as far as loading.
const NO_SCENE: &str = "/nonexistent/kalos-test-scene.xml";

#[test]
fn a_bad_output_fails_before_the_scene_is_loaded() {
    let dir = tempfile::tempdir().expect("tempdir");
    let file = dir.path().join("file");
    std::fs::write(&file, b"x").expect("write");
    let missing = dir.path().join("no-such-folder").join("x.exr");
    let under_file = file.join("x.png");
    let log = dir.path().join("no-such-folder").join("log.csv");
    let ok = dir.path().join("ok.exr");
    for (args, words) in [
        (
            vec!["-o", missing.to_str().expect("utf-8")],
            "does not exist",
        ),
        (
            vec!["-o", under_file.to_str().expect("utf-8")],
            "not a folder",
        ),
        (vec!["-o", "x.tiff"], ".exr, .pfm or .png"),
        (
            vec![
                "-o",
                ok.to_str().expect("utf-8"),
                "--log",
                log.to_str().expect("utf-8"),
            ],
            "does not exist",
        ),
    ] {
        let mut all = vec!["render", NO_SCENE];
        all.extend_from_slice(&args);
        let o = kalos(&all);
        assert!(!o.status.success(), "{args:?} was accepted");
        let e = stderr(&o);
        assert!(e.contains(words), "{args:?}: {e}");
        assert!(!e.contains("kalos-test-scene"), "loaded first: {e}");
        assert!(!e.contains(".tmp-"), "names a temporary file: {e}");
    }
    // bake checks its output the same way
    let o = kalos(&[
        "bake",
        NO_SCENE,
        "-o",
        missing.with_extension("glb").to_str().expect("utf-8"),
    ]);
    assert!(!o.status.success());
    assert!(stderr(&o).contains("does not exist"), "{}", stderr(&o));
    assert_eq!(
        std::fs::read_dir(dir.path()).expect("read_dir").count(),
        1,
        "only 'file' is left"
    );
}

#[test]
fn bad_budgets_fail_before_the_scene_is_loaded() {
    // without --dry-run too: the budget is refused before the (missing)
    // scene is looked at
    for (flag, value) in [
        ("--spp", "nan"),
        ("--time", "nan"),
        ("--spp", "0"),
        ("--rays", "0"),
    ] {
        let o = kalos(&["render", NO_SCENE, flag, value, "-o", "x.pfm"]);
        assert!(!o.status.success(), "{flag} {value} was accepted");
        let e = stderr(&o);
        assert!(e.contains(flag) && !e.contains("kalos-test-scene"), "{e}");
    }
    let o = kalos(&["render", "--res", "0x10", "-o", "x.pfm", "--dry-run"]);
    assert!(!o.status.success());
    assert!(stderr(&o).contains("--res"), "{}", stderr(&o));
}

#[test]
fn an_os_error_is_reported_once() {
    let dir = tempfile::tempdir().expect("tempdir");
    let missing = dir.path().join("missing.pfm");
    let out = dir.path().join("x.pfm");
    let o = kalos(&[
        "render",
        "--ref",
        missing.to_str().expect("utf-8"),
        "-o",
        out.to_str().expect("utf-8"),
    ]);
    assert!(!o.status.success());
    let e = stderr(&o);
    assert!(e.contains("missing.pfm"), "{e}");
    assert_eq!(e.matches("os error").count(), 1, "{e}");
}

#[test]
fn a_read_only_output_is_refused_and_kept() {
    let dir = tempfile::tempdir().expect("tempdir");
    let out = dir.path().join("keep.pfm");
    std::fs::write(&out, b"not replaced").expect("write");
    let mut perm = std::fs::metadata(&out).expect("meta").permissions();
    perm.set_readonly(true);
    std::fs::set_permissions(&out, perm).expect("chmod");
    let o = kalos(&[
        "render",
        "--res",
        "8x8",
        "--spp",
        "1",
        "-q",
        "-o",
        out.to_str().expect("utf-8"),
    ]);
    assert!(!o.status.success(), "a read-only output was replaced");
    let e = stderr(&o);
    assert!(e.contains("keep.pfm") && e.contains("read-only"), "{e}");
    assert_eq!(std::fs::read(&out).expect("read"), b"not replaced");
}

#[test]
fn a_film_past_the_memory_limit_is_an_error_not_an_abort() {
    let dir = tempfile::tempdir().expect("tempdir");
    // the r6 reproducer: a 65536 × 65536 film, past any machine's memory
    let scene = dir.path().join("r6.xml");
    std::fs::write(
        &scene,
        r#"<scene version="3.0.0"><sensor type="perspective"><film type="hdrfilm">
        <integer name="width" value="65536"/><integer name="height" value="65536"/>
        </film></sensor><shape type="sphere"><emitter type="area"/></shape></scene>"#,
    )
    .expect("write");
    let out = dir.path().join("x.exr");
    let out = out.to_str().expect("utf-8");
    let o = kalos(&["render", scene.to_str().expect("utf-8"), "-o", out]);
    assert_eq!(o.status.code(), Some(1), "{}", stderr(&o));
    let e = stderr(&o);
    assert!(
        e.contains("65536×65536") && e.contains("--max-memory"),
        "{e}"
    );
    // --res 16384x16384 under an 8 GB limit, for the path tracer and bundle
    for method in ["path", "bundle"] {
        let o = kalos(&[
            "render",
            "--method",
            method,
            "--res",
            "16384x16384",
            "--max-memory",
            "8G",
            "-o",
            out,
        ]);
        assert_eq!(o.status.code(), Some(1), "{method}: {}", stderr(&o));
        let e = stderr(&o);
        assert!(e.contains("16384×16384") && e.contains("8.0 GB"), "{e}");
    }
    assert!(!dir.path().join("x.exr").exists());
}

/// Starts a render on a long budget, sends it `signal` with the `kill`
/// command once it has had time to start, and returns its exit code and
/// whether it wrote a valid image. A signal that arrives before the
/// handler is installed (the process ends by the signal, without a code)
/// or before the first pass (nothing written) is retried with a longer
/// wait, so that a slow start on a loaded machine does not fail the test.
#[cfg(unix)]
fn interrupt_render(signal: &str) -> (Option<i32>, Option<kalos::film::Image>) {
    use std::time::{Duration, Instant};
    let mut last = (None, None);
    for wait_s in [1.0, 3.0, 8.0] {
        let dir = tempfile::tempdir().expect("tempdir");
        let out = dir.path().join("s.pfm");
        let mut child = Command::new(env!("CARGO_BIN_EXE_kalos"))
            .args(["render", "--res", "16x16", "--time", "600", "-q", "-o"])
            .arg(&out)
            .stdout(std::process::Stdio::null())
            .stderr(std::process::Stdio::null())
            .spawn()
            .expect("kalos starts");
        std::thread::sleep(Duration::from_secs_f64(wait_s));
        let sent = Command::new("kill")
            .args([signal, &child.id().to_string()])
            .status()
            .expect("kill runs");
        assert!(sent.success(), "kill {signal} failed");
        // Generous bound, only so that a render that ignores the signal
        // fails the test instead of hanging it (the budget is 600 s).
        let deadline = Instant::now() + Duration::from_secs(60);
        let status = loop {
            if let Some(s) = child.try_wait().expect("wait") {
                break s;
            }
            if Instant::now() > deadline {
                let _ = child.kill();
                let _ = child.wait();
                panic!("kalos did not stop within 60 s of {signal}");
            }
            std::thread::sleep(Duration::from_millis(50));
        };
        let image = kalos::image_io::read_image(&out).ok();
        last = (status.code(), image);
        if last.0.is_some() && last.1.is_some() {
            break;
        }
    }
    last
}

#[cfg(unix)]
#[test]
fn sigterm_and_sigint_save_the_image_and_exit_143_and_130() {
    for (signal, code) in [("-TERM", 143), ("-INT", 130)] {
        let (exit, image) = interrupt_render(signal);
        assert_eq!(exit, Some(code), "{signal}");
        let image = image.unwrap_or_else(|| panic!("{signal}: no valid image"));
        assert_eq!((image.width, image.height), (16, 16));
        assert!(image.data.iter().all(|p| p.is_finite()), "{signal}");
        assert!(image.data.iter().any(|p| p.x > 0.0), "{signal}: black");
    }
}

#[test]
fn compare_refuses_display_images_mismatched_sizes_and_nan() {
    use glam::Vec3;
    use kalos::film::Image;
    use kalos::image_io::{write_image, PngOptions};
    let dir = tempfile::tempdir().expect("tempdir");
    let p = |name: &str| dir.path().join(name).to_str().expect("utf-8").to_string();
    let flat = |w: u32, h: u32, v: f32| Image {
        width: w,
        height: h,
        data: vec![Vec3::splat(v); (w * h) as usize],
    };
    let o = PngOptions::default();
    write_image(dir.path().join("ref.pfm").as_path(), &flat(4, 4, 0.5), &o).expect("write");
    write_image(dir.path().join("a.pfm").as_path(), &flat(4, 4, 0.4), &o).expect("write");
    write_image(dir.path().join("a.png").as_path(), &flat(4, 4, 0.4), &o).expect("write");
    write_image(dir.path().join("big.pfm").as_path(), &flat(8, 8, 0.4), &o).expect("write");
    let mut nan = flat(4, 4, 0.4);
    nan.data[3] = Vec3::new(f32::NAN, 0.0, 0.0);
    nan.data[7] = Vec3::splat(f32::INFINITY);
    write_image(dir.path().join("nan.pfm").as_path(), &nan, &o).expect("write");

    // a fine pair is compared
    let ok = kalos(&["compare", &p("a.pfm"), &p("ref.pfm")]);
    assert!(ok.status.success(), "{}", stderr(&ok));
    assert!(stdout(&ok).contains("relMSE"));
    for (image, reference, words) in [
        ("a.png", "ref.pfm", vec!["a.png", "HDR"]),
        ("ref.pfm", "a.png", vec!["a.png", "HDR"]),
        (
            "big.pfm",
            "ref.pfm",
            vec!["big.pfm", "8x8", "ref.pfm", "4x4"],
        ),
        ("nan.pfm", "ref.pfm", vec!["nan.pfm", "2 of its 16"]),
        ("a.pfm", "nan.pfm", vec!["nan.pfm", "2 of its 16"]),
    ] {
        let o = kalos(&["compare", &p(image), &p(reference)]);
        assert_eq!(o.status.code(), Some(1), "{image} {reference}");
        let e = stderr(&o);
        for w in words {
            assert!(e.contains(w), "{image} {reference}: {e}");
        }
        assert!(!stdout(&o).contains("NaN"), "{}", stdout(&o));
    }
}

#[test]
fn a_bake_past_the_memory_limit_is_refused_before_it_starts() {
    let dir = tempfile::tempdir().expect("tempdir");
    let out = dir.path().join("x.glb");
    let o = kalos(&[
        "bake",
        NO_SCENE,
        "--chunk-hits",
        "5M",
        "--max-memory",
        "10M",
        "-o",
        out.to_str().expect("utf-8"),
    ]);
    assert_eq!(o.status.code(), Some(1));
    let e = stderr(&o);
    assert!(e.contains("hit chunk") && e.contains("--chunk-hits"), "{e}");
    assert!(!e.contains("kalos-test-scene"), "loaded first: {e}");
}
