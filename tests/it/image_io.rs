//! Image files, metrics and plots: round trips, pixel order, atomic writes,
//! hand-computed metric values.

use std::fs;
use std::path::{Path, PathBuf};

use glam::{DVec3, Vec3};
use kalos::film::Image;
use kalos::image_io::{read_image, write_atomic, write_image, ImageIoError, PngOptions, Tonemap};
use kalos::metrics::{
    channel_means, false_color_error, mean_abs_rel_error, rel_l1, rel_mse, rel_mse_pair, rmse,
    MetricsError, PixelStats,
};
use kalos::plot::{
    plot_convergence, read_convergence_csv, series_from_csv, PlotError, PlotOptions, Series, XAxis,
};

/// A fresh, empty scratch directory for one test, under Cargo's per-target
/// temporary directory.
fn scratch(name: &str) -> PathBuf {
    let dir = Path::new(env!("CARGO_TARGET_TMPDIR"))
        .join("image_io")
        .join(name);
    let _ = fs::remove_dir_all(&dir);
    fs::create_dir_all(&dir).unwrap();
    dir
}

/// The names in `dir`, sorted.
fn names_in(dir: &Path) -> Vec<String> {
    let mut v: Vec<String> = fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    v.sort();
    v
}

/// A w×h image whose every channel of every pixel differs, with values
/// that are not round in binary (so a bit-exact comparison means something).
fn gradient(w: u32, h: u32) -> Image {
    let mut data = Vec::new();
    for y in 0..h {
        for x in 0..w {
            let base = (y * w + x) as f32;
            data.push(Vec3::new(
                base / 7.0,
                -base / 3.0 - 0.1,
                1e-3 * base + 1e-30,
            ));
        }
    }
    Image {
        width: w,
        height: h,
        data,
    }
}

fn assert_bit_exact(a: &Image, b: &Image) {
    assert_eq!((a.width, a.height), (b.width, b.height));
    for (i, (p, q)) in a.data.iter().zip(&b.data).enumerate() {
        for c in 0..3 {
            assert_eq!(p[c].to_bits(), q[c].to_bits(), "pixel {i} channel {c}");
        }
    }
}

// ---------------------------------------------------------------- PFM, EXR

#[test]
fn pfm_round_trip_is_bit_exact_and_stores_the_bottom_row_first() {
    let dir = scratch("pfm");
    let path = dir.join("g.pfm");
    let img = gradient(4, 3);
    write_image(&path, &img, &PngOptions::default()).unwrap();

    // The header, then the bottom row (y = 2) first, little-endian.
    let bytes = fs::read(&path).unwrap();
    let header = b"PF\n4 3\n-1.0\n";
    assert_eq!(&bytes[..header.len()], header);
    assert_eq!(bytes.len(), header.len() + 4 * 3 * 3 * 4);
    let first_row = &bytes[header.len()..header.len() + 4 * 12];
    let mut expected = Vec::new();
    for x in 0..4 {
        for c in img.get(x, 2).to_array() {
            expected.extend_from_slice(&c.to_le_bytes());
        }
    }
    assert_eq!(
        first_row,
        &expected[..],
        "first row in the file is the bottom row"
    );

    let back = read_image(&path).unwrap();
    assert_bit_exact(&img, &back);
    assert_eq!(names_in(&dir), vec!["g.pfm"], "no temporary file left");
}

#[test]
fn exr_round_trip_is_exact() {
    let dir = scratch("exr");
    let path = dir.join("g.exr");
    let img = gradient(5, 4);
    write_image(&path, &img, &PngOptions::default()).unwrap();
    let back = read_image(&path).unwrap();
    assert_bit_exact(&img, &back);
    assert_eq!(names_in(&dir), vec!["g.exr"]);
}

// ---------------------------------------------------------------- PNG

#[test]
fn png_is_8_bit_srgb_with_exposure_and_tone_mapping() {
    let dir = scratch("png");
    let path = dir.join("p.png");
    // Row 0: black, white, 18 % grey, NaN; row 1: 0.5, 4.0 (over white),
    // -1 (negative), +inf.
    let img = Image {
        width: 4,
        height: 2,
        data: vec![
            Vec3::ZERO,
            Vec3::ONE,
            Vec3::splat(0.18),
            Vec3::new(f32::NAN, 0.5, 0.5),
            Vec3::new(0.5, 0.25, 1.0),
            Vec3::splat(4.0),
            Vec3::splat(-1.0),
            Vec3::new(0.5, f32::INFINITY, 0.5),
        ],
    };
    write_image(&path, &img, &PngOptions::default()).unwrap();
    let png = image::open(&path).unwrap().to_rgb8();
    assert_eq!(png.dimensions(), (4, 2));
    // sRGB(x) = 1.055 x^(1/2.4) − 0.055: 0.18 → 0.4613 → 118, 0.5 → 0.7354 →
    // 188, 0.25 → 0.5371 → 137.
    assert_eq!(png.get_pixel(0, 0).0, [0, 0, 0]);
    assert_eq!(png.get_pixel(1, 0).0, [255, 255, 255]);
    assert_eq!(png.get_pixel(2, 0).0, [118, 118, 118]);
    assert_eq!(png.get_pixel(3, 0).0, [0, 0, 0], "NaN pixel is black");
    assert_eq!(png.get_pixel(0, 1).0, [188, 137, 255]);
    assert_eq!(png.get_pixel(1, 1).0, [255, 255, 255], "clamped");
    assert_eq!(png.get_pixel(2, 1).0, [0, 0, 0], "negative clamps to 0");
    assert_eq!(png.get_pixel(3, 1).0, [0, 0, 0], "infinite pixel is black");

    // Exposure +1 stop on 0.25 gives 0.5; Reinhard maps 1 to 0.5.
    let opts = PngOptions {
        exposure: 1.0,
        tonemap: Tonemap::Clamp,
    };
    write_image(&path, &img, &opts).unwrap();
    let png = image::open(&path).unwrap().to_rgb8();
    assert_eq!(png.get_pixel(0, 1).0, [255, 188, 255]);
    let opts = PngOptions {
        exposure: 0.0,
        tonemap: Tonemap::Reinhard,
    };
    write_image(&path, &img, &opts).unwrap();
    let png = image::open(&path).unwrap().to_rgb8();
    assert_eq!(png.get_pixel(1, 0).0, [188, 188, 188]);
    // ACES (Narkowicz) at 1: 2.54 / 3.16 = 0.8038 → sRGB 0.9084 → 232.
    let opts = PngOptions {
        exposure: 0.0,
        tonemap: Tonemap::Aces,
    };
    write_image(&path, &img, &opts).unwrap();
    let png = image::open(&path).unwrap().to_rgb8();
    assert_eq!(png.get_pixel(1, 0).0, [232, 232, 232]);

    // Reading the PNG back converts sRGB to linear: 232/255 → 0.80695,
    // 0 → 0; ACES(4) = 0.9734 → 252.
    let back = read_image(&path).unwrap();
    assert!(
        (back.get(1, 0) - Vec3::splat(0.806_952))
            .abs()
            .max_element()
            < 1e-5
    );
    assert_eq!(back.get(0, 0), Vec3::ZERO);
    let png = image::open(&path).unwrap().to_rgb8();
    assert_eq!(png.get_pixel(1, 1).0, [252, 252, 252]);
    assert_eq!(names_in(&dir), vec!["p.png"]);
}

#[test]
fn unknown_extensions_and_bad_images_are_errors() {
    let dir = scratch("unknown");
    let img = gradient(2, 2);
    let err = write_image(&dir.join("x.tiff"), &img, &PngOptions::default()).unwrap_err();
    assert!(matches!(err, ImageIoError::UnknownFormat { .. }));
    assert!(err.to_string().contains("x.tiff"), "{err}");
    let err = write_image(&dir.join("noext"), &img, &PngOptions::default()).unwrap_err();
    assert!(matches!(err, ImageIoError::UnknownFormat { .. }));
    let bad = Image {
        width: 3,
        height: 3,
        data: vec![Vec3::ZERO; 2],
    };
    let err = write_image(&dir.join("bad.pfm"), &bad, &PngOptions::default()).unwrap_err();
    assert!(matches!(err, ImageIoError::BadImage { .. }));
    assert!(names_in(&dir).is_empty());

    let err = read_image(&dir.join("missing.pfm")).unwrap_err();
    assert!(matches!(err, ImageIoError::Io { .. }));
    fs::write(dir.join("trunc.pfm"), b"PF\n2 2\n-1.0\n\0\0\0\0").unwrap();
    let err = read_image(&dir.join("trunc.pfm")).unwrap_err();
    assert!(matches!(err, ImageIoError::Pfm { .. }), "{err}");
    assert!(err.to_string().contains("trunc.pfm"));
}

// ---------------------------------------------------------------- atomicity

#[test]
fn a_failed_write_leaves_the_old_file_and_no_temporary() {
    let dir = scratch("atomic");
    let path = dir.join("keep.pfm");
    let old = gradient(3, 2);
    write_image(&path, &old, &PngOptions::default()).unwrap();
    let old_bytes = fs::read(&path).unwrap();

    // The writer fails halfway through: the old file stays, the temporary
    // goes.
    let err = write_atomic(&path, |w| {
        use std::io::Write;
        w.write_all(b"PF\n9 9\n").unwrap();
        Err(ImageIoError::BadImage {
            path: path.clone(),
            reason: "simulated failure".into(),
        })
    })
    .unwrap_err();
    assert!(err.to_string().contains("simulated failure"));
    assert_eq!(fs::read(&path).unwrap(), old_bytes);
    assert_eq!(names_in(&dir), vec!["keep.pfm"]);

    // The rename fails (the destination is a non-empty directory): nothing
    // is replaced, the temporary goes.
    let blocker = dir.join("blocked.png");
    fs::create_dir(&blocker).unwrap();
    fs::write(blocker.join("inside"), b"x").unwrap();
    let err = write_image(&blocker, &old, &PngOptions::default()).unwrap_err();
    assert!(matches!(err, ImageIoError::Unwritable { .. }), "{err}");
    assert_eq!(names_in(&dir), vec!["blocked.png", "keep.pfm"]);
    assert_eq!(names_in(&blocker), vec!["inside"]);
}

#[cfg(unix)]
#[test]
fn an_unwritable_directory_is_an_error_and_keeps_the_existing_file() {
    use std::os::unix::fs::PermissionsExt;
    let dir = scratch("readonly");
    let path = dir.join("old.exr");
    let old = gradient(2, 2);
    write_image(&path, &old, &PngOptions::default()).unwrap();
    let old_bytes = fs::read(&path).unwrap();
    fs::set_permissions(&dir, fs::Permissions::from_mode(0o555)).unwrap();

    // A privileged user (root in a container) writes through the
    // permission bits, so the check only means something without privilege.
    let probe = dir.join("probe");
    let privileged = fs::write(&probe, b"").is_ok();
    let _ = fs::remove_file(&probe);
    if !privileged {
        let err = write_image(&path, &gradient(4, 4), &PngOptions::default()).unwrap_err();
        assert!(matches!(err, ImageIoError::Io { .. }), "{err}");
        assert_eq!(fs::read(&path).unwrap(), old_bytes);
        assert_eq!(names_in(&dir), vec!["old.exr"]);
    }
    fs::set_permissions(&dir, fs::Permissions::from_mode(0o755)).unwrap();

    // A directory that does not exist cannot be written either.
    let err =
        write_image(&dir.join("no/such/dir/x.png"), &old, &PngOptions::default()).unwrap_err();
    assert!(matches!(err, ImageIoError::Io { .. }), "{err}");
}

#[test]
fn a_read_only_existing_file_is_not_replaced() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("keep.pfm");
    write_image(&path, &gradient(3, 2), &PngOptions::default()).unwrap();
    let old_bytes = fs::read(&path).unwrap();
    let mut perm = fs::metadata(&path).unwrap().permissions();
    perm.set_readonly(true);
    fs::set_permissions(&path, perm).unwrap();

    // Refused before any work, and by the writer itself at the rename (the
    // file may turn read-only while a render runs); the rename would
    // replace it otherwise, whatever its permissions, even for root.
    let err = kalos::image_io::check_writable(&path).unwrap_err();
    assert!(matches!(err, ImageIoError::Unwritable { .. }), "{err}");
    assert!(err.to_string().contains("read-only"), "{err}");
    let err = write_image(&path, &gradient(4, 4), &PngOptions::default()).unwrap_err();
    assert!(matches!(err, ImageIoError::Unwritable { .. }), "{err}");
    assert!(err.to_string().contains("keep.pfm"), "{err}");
    assert!(
        !err.to_string().contains(".tmp-"),
        "names the temporary: {err}"
    );
    assert_eq!(fs::read(&path).unwrap(), old_bytes);
    assert_eq!(names_in(dir.path()), vec!["keep.pfm"]);
}

#[test]
fn check_writable_names_the_users_path_and_leaves_nothing() {
    let dir = tempfile::tempdir().unwrap();
    // a fine place: accepted, and the probe file is gone
    let ok = dir.path().join("a.exr");
    kalos::image_io::check_writable(&ok).unwrap();
    assert!(names_in(dir.path()).is_empty());
    // a missing folder, a file where the folder should be
    let file = dir.path().join("file");
    fs::write(&file, b"x").unwrap();
    for (path, words) in [
        (dir.path().join("no/such/x.exr"), "does not exist"),
        (file.join("x.exr"), "not a folder"),
    ] {
        let err = kalos::image_io::check_writable(&path).unwrap_err();
        let text = err.to_string();
        assert!(text.contains(&*path.to_string_lossy()), "{text}");
        assert!(text.contains(words), "{text}");
    }
    assert_eq!(names_in(dir.path()), vec!["file"]);
}

// ---------------------------------------------------------------- metrics

fn img2(a: [f32; 3], b: [f32; 3]) -> Image {
    Image {
        width: 2,
        height: 1,
        data: vec![Vec3::from(a), Vec3::from(b)],
    }
}

#[test]
fn rel_mse_of_identical_images_is_zero() {
    let img = gradient(6, 5);
    assert_eq!(rel_mse(&img, &img).unwrap(), 0.0);
    assert_eq!(rel_mse_pair(&img, &img).unwrap(), 0.0);
    assert_eq!(rmse(&img, &img).unwrap(), 0.0);
    assert_eq!(rel_l1(&img, &img).unwrap(), 0.0);
}

#[test]
fn rel_mse_matches_a_hand_computed_2x1_example() {
    let a = img2([1.0, 0.0, 2.0], [0.5, 0.5, 0.5]);
    let r = img2([1.0, 0.25, 1.0], [0.0, 0.5, 1.0]);
    // Terms (a − r)² / (r² + 0.01), pixel by pixel, channel by channel:
    //   0, 0.0625/0.0725, 1/1.01, 0.25/0.01 = 25, 0, 0.25/1.01
    // mean over the six = 4.516615454648913.
    let got = rel_mse(&a, &r).unwrap();
    assert!((got - 4.516_615_454_648_913).abs() < 1e-12, "{got}");

    // rmse: squared errors 0, 0.0625, 1, 0.25, 0, 0.25; mean 1.5625/6.
    let got = rmse(&a, &r).unwrap();
    assert!((got - (1.5625f64 / 6.0).sqrt()).abs() < 1e-12, "{got}");

    // rel_l1: |a − r| / (|r| + 0.01): 0, 0.25/0.26, 1/1.01, 0.5/0.01, 0, 0.5/1.01.
    let want = (0.25 / 0.26 + 1.0 / 1.01 + 50.0 + 0.5 / 1.01) / 6.0;
    assert!((rel_l1(&a, &r).unwrap() - want).abs() < 1e-12);

    // Plain relative error skips the zero reference: 0, 1, 1, 0, 0.5 over 5.
    assert!((mean_abs_rel_error(&a, &r).unwrap() - 2.5 / 5.0).abs() < 1e-12);

    // Half against half: one channel pair (1, 3), mean 2: 4 / 4.01.
    let b1 = img2([1.0; 3], [1.0; 3]);
    let b2 = img2([3.0; 3], [1.0; 3]);
    let got = rel_mse_pair(&b1, &b2).unwrap();
    assert!((got - 0.997_506_234_413_965_1 / 2.0).abs() < 1e-12, "{got}");
}

#[test]
fn mismatched_sizes_are_errors() {
    let a = gradient(2, 2);
    let b = gradient(2, 3);
    let err = rel_mse(&a, &b).unwrap_err();
    assert!(matches!(err, MetricsError::SizeMismatch { .. }));
    assert!(rel_mse_pair(&a, &b).is_err());
    assert!(rmse(&a, &b).is_err());
    assert!(rel_l1(&a, &b).is_err());
    assert!(mean_abs_rel_error(&a, &b).is_err());
    assert!(false_color_error(&a, &b).is_err());
    let mut stats = PixelStats::new(2, 2);
    assert!(stats.add(&b).is_err());
    assert_eq!(stats.count(), 0);
}

#[test]
fn channel_means_and_false_colour() {
    let a = img2([1.0, 0.0, 2.0], [0.5, 0.5, 0.5]);
    assert_eq!(channel_means(&a), DVec3::new(0.75, 0.25, 1.25));
    let fc = false_color_error(&a, &a).unwrap();
    assert_eq!((fc.width, fc.height), (2, 1));
    // No error: both pixels at the low end of the ramp.
    assert_eq!(fc.data[0], fc.data[1]);
}

#[test]
fn pixel_stats_match_a_hand_computation() {
    // Three renders of a 2×1 image. Pixel 0, red: 1, 2, 4 → mean 7/3,
    // unbiased variance ((4/3)² + (1/3)² + (5/3)²) / 2 = 7/3.
    // Pixel 0, green: constant 5 → variance 0. Pixel 0, blue: 0, 0, 3 →
    // mean 1, variance (1 + 1 + 4)/2 = 3. Pixel 1: −1, 1, 0 on every channel
    // → mean 0, variance (1 + 1 + 0)/2 = 1.
    let renders = [
        img2([1.0, 5.0, 0.0], [-1.0; 3]),
        img2([2.0, 5.0, 0.0], [1.0; 3]),
        img2([4.0, 5.0, 3.0], [0.0; 3]),
    ];
    let mut stats = PixelStats::new(2, 1);
    assert!(stats.variance().is_err());
    stats.add(&renders[0]).unwrap();
    assert!(stats.mean_variance().is_err(), "one image has no variance");
    stats.add(&renders[1]).unwrap();
    stats.add(&renders[2]).unwrap();
    assert_eq!(stats.count(), 3);

    let mean = stats.mean();
    assert!(
        (mean.data[0] - Vec3::new(7.0 / 3.0, 5.0, 1.0))
            .abs()
            .max_element()
            < 1e-6
    );
    assert!(mean.data[1].abs().max_element() < 1e-7);
    let var = stats.variance().unwrap();
    assert!(
        (var.data[0] - Vec3::new(7.0 / 3.0, 0.0, 3.0))
            .abs()
            .max_element()
            < 1e-6
    );
    assert!((var.data[1] - Vec3::ONE).abs().max_element() < 1e-6);
    // Mean over the six channel variances: (7/3 + 0 + 3 + 1 + 1 + 1) / 6.
    let want = (7.0 / 3.0 + 3.0 + 3.0) / 6.0;
    assert!((stats.mean_variance().unwrap() - want).abs() < 1e-12);
}

// ---------------------------------------------------------------- plots

/// How many pixels differ from white, and how many are clearly coloured
/// (not grey: the lines, not the axes or text).
fn ink(path: &Path) -> (u32, u32, usize, usize) {
    let img = image::open(path).unwrap().to_rgb8();
    let (mut any, mut colour) = (0, 0);
    for p in img.pixels() {
        let [r, g, b] = p.0;
        if [r, g, b] != [255, 255, 255] {
            any += 1;
        }
        if r.max(g).max(b) - r.min(g).min(b) > 60 {
            colour += 1;
        }
    }
    (img.width(), img.height(), any, colour)
}

#[test]
fn convergence_plot_is_a_png_with_lines() {
    let dir = scratch("plot");
    let out = dir.join("conv.png");
    let series = vec![
        Series {
            label: "path".into(),
            points: (0..8).map(|i| (2f64.powi(i), 0.1 / 2f64.powi(i))).collect(),
        },
        Series {
            label: "light".into(),
            // Points a log axis cannot show are dropped, not fatal.
            points: vec![
                (0.0, 1.0),
                (1.0, 0.3),
                (4.0, 0.05),
                (16.0, f64::NAN),
                (64.0, 0.004),
            ],
        },
    ];
    let opts = PlotOptions {
        title: "cbox".into(),
        width: 640,
        height: 480,
        ..PlotOptions::default()
    };
    plot_convergence(&series, &out, &opts).unwrap();
    let (w, h, any, colour) = ink(&out);
    assert_eq!((w, h), (640, 480));
    assert!(any > 2000, "{any} non-white pixels");
    assert!(colour > 300, "{colour} coloured pixels");
    assert_eq!(names_in(&dir), vec!["conv.png"], "no temporary file left");

    // Nothing plottable is an error, and writes nothing.
    let empty = vec![Series {
        label: "none".into(),
        points: vec![(0.0, 1.0), (1.0, -1.0)],
    }];
    let err = plot_convergence(&empty, &dir.join("empty.png"), &opts).unwrap_err();
    assert!(matches!(err, PlotError::NoData));
    assert_eq!(names_in(&dir), vec!["conv.png"]);
}

#[test]
fn convergence_csv_is_read_and_plotted() {
    let dir = scratch("csv");
    let csv = dir.join("log.csv");
    fs::write(
        &csv,
        "time_s,rays,spp,rel_mse\n\
         0.1,100000,1,\n\
         0.2,200000,2,0.5\n\
         0.4,400000,4,0.25\n\
         0.8,800000,8,0.125\n",
    )
    .unwrap();
    let rows = read_convergence_csv(&csv).unwrap();
    assert_eq!(rows.len(), 3, "the row without rel_mse is skipped");
    assert_eq!(rows[0].time_s, 0.2);
    assert_eq!(rows[2].rays, 800_000.0);
    let by_rays = series_from_csv(&csv, "path", XAxis::Rays).unwrap();
    assert_eq!(by_rays.points[1], (400_000.0, 0.25));

    let out = dir.join("rays.png");
    plot_convergence(&[by_rays], &out, &PlotOptions::for_axis(XAxis::Rays)).unwrap();
    let (_, _, any, colour) = ink(&out);
    assert!(any > 1000 && colour > 100, "{any} {colour}");

    fs::write(&csv, "time_s,rays,spp,rel_mse\n1,2,3,4\n1,2,oops,4\n").unwrap();
    match read_convergence_csv(&csv).unwrap_err() {
        PlotError::Csv { line, .. } => assert_eq!(line, 3),
        e => panic!("unexpected {e}"),
    }
}

#[test]
fn a_comparison_is_never_nan() {
    use kalos::metrics::{non_finite_pixels, Comparison};
    let r = img2([1.0, 1.0, 1.0], [0.5, 0.5, 0.5]);
    let nan = img2([f32::NAN, 1.0, 1.0], [0.5, 0.5, 0.5]);
    // the largest f32 squared still fits an f64 sum: finite figures
    let huge = img2([3e38, 1.0, 1.0], [0.5, 0.5, 0.5]);
    assert_eq!(non_finite_pixels(&nan), 1);
    assert_eq!(non_finite_pixels(&huge), 0);
    let err = Comparison::new(&nan, &r).unwrap_err();
    assert!(matches!(err, MetricsError::NotFinite(_)), "{err}");
    assert!(Comparison::new(&huge, &r).is_ok());
    assert!(Comparison::new(&r, &r).is_ok());
}
