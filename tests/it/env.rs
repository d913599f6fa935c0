//! `--env FILE [--env-scale S]` and `--env-constant R,G,B` on `kalos render`
//! and `kalos bake`: an environment for a scene that carries none.

use std::path::Path;

use kalos::film::Image;
use kalos::image_io::{read_image, write_image, PngOptions};
use kalos::scene::{self, EmitterDesc, Environment, Rgb};

use crate::common;

/// A diffuse sphere (albedo 0.6, radius 1) filling the middle of the view,
/// and no emitter.
const SPHERE: &str = r#"<scene version="3.0.0">
    <sensor type="perspective">
        <float name="fov" value="40"/>
        <transform name="to_world">
            <lookat origin="0, 0, 5" target="0, 0, 0" up="0, 1, 0"/>
        </transform>
        <film type="hdrfilm">
            <integer name="width" value="32"/>
            <integer name="height" value="32"/>
        </film>
    </sensor>
    <shape type="sphere">
        <float name="radius" value="1"/>
        <bsdf type="diffuse">
            <rgb name="reflectance" value="0.6, 0.6, 0.6"/>
        </bsdf>
    </shape>
    SKY
</scene>
"#;

/// Writes the sphere scene (with `sky` as its extra XML) into `dir`.
fn sphere_scene(dir: &Path, sky: &str) -> String {
    let p = dir.join("sphere.xml");
    std::fs::write(&p, SPHERE.replace("SKY", sky)).expect("write scene");
    p.to_string_lossy().into_owned()
}

/// Over a square of side `n` at the image's centre: the mean of the pixels'
/// channel means and its standard error from their spread (path's pixels
/// are independent); and the mean of the four corner pixels.
fn centre_and_corners(img: &Image, n: u32) -> (f64, f64, f64) {
    let (w, h) = (img.width, img.height);
    let grey = |x: u32, y: u32| {
        let p = img.get(x, y);
        (p[0] + p[1] + p[2]) as f64 / 3.0
    };
    let mut v = Vec::new();
    for y in (h - n) / 2..(h + n) / 2 {
        for x in (w - n) / 2..(w + n) / 2 {
            v.push(grey(x, y));
        }
    }
    let m = v.len() as f64;
    let mean = v.iter().sum::<f64>() / m;
    let var = v.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / (m - 1.0);
    let corners = [(0, 0), (w - 1, 0), (0, h - 1), (w - 1, h - 1)]
        .iter()
        .map(|&(x, y)| grey(x, y))
        .sum::<f64>()
        / 4.0;
    (mean, (var / m).sqrt(), corners)
}

/// White furnace: a convex diffuse body under a uniform sky of radiance L
/// sees only the sky, so it reflects L·a; the background, seen directly, is
/// L exactly. The 8 × 8 centre (all sphere) is held to a·L within 5
/// standard errors of its mean.
#[test]
fn diffuse_sphere_under_a_constant_sky_reflects_its_albedo() {
    let dir = tempfile::tempdir().expect("tmp");
    let scene = sphere_scene(dir.path(), "");
    let out = dir.path().join("furnace.pfm");
    let o = common::kalos(&[
        "render",
        &scene,
        "--env-constant",
        "1,1,1",
        "--spp",
        "64",
        "-q",
        "-o",
        out.to_str().expect("utf-8"),
    ]);
    assert!(o.status.success(), "{}", common::stderr(&o));
    let img = read_image(&out).expect("image");
    let (centre, se, corners) = centre_and_corners(&img, 8);
    eprintln!("centre {centre:.5} ± {se:.5} (albedo 0.6), corners {corners:.5} (sky 1)");
    assert!((centre - 0.6).abs() < 5.0 * se, "centre {centre} ± {se}");
    assert!(se < 0.01, "too noisy to tell: {se}");
    assert!((corners - 1.0).abs() < 1e-4, "corners {corners}");
}

/// `--env` with a constant map (radiance 2) and `--env-scale 0.25`: the
/// same furnace at L = 0.5, through the map's importance sampling; and
/// `kalos bake` takes the same flags.
#[test]
fn environment_map_with_scale_lights_render_and_bake() {
    let dir = tempfile::tempdir().expect("tmp");
    let scene = sphere_scene(dir.path(), "");
    let sky = dir.path().join("sky.exr");
    let map = Image {
        width: 16,
        height: 8,
        data: vec![Rgb::splat(2.0); 16 * 8],
    };
    write_image(&sky, &map, &PngOptions::default()).expect("write sky");
    let out = dir.path().join("map.pfm");
    let o = common::kalos(&[
        "render",
        &scene,
        "--env",
        sky.to_str().expect("utf-8"),
        "--env-scale",
        "0.25",
        "--spp",
        "64",
        "-q",
        "-o",
        out.to_str().expect("utf-8"),
    ]);
    assert!(o.status.success(), "{}", common::stderr(&o));
    let (centre, se, corners) = centre_and_corners(&read_image(&out).expect("image"), 8);
    eprintln!("centre {centre:.5} ± {se:.5} (0.3), corners {corners:.5} (0.5)");
    assert!((centre - 0.3).abs() < 5.0 * se, "centre {centre} ± {se}");
    assert!(se < 0.005, "too noisy to tell: {se}");
    assert!((corners - 0.5).abs() < 1e-4, "corners {corners}");

    let glb = dir.path().join("sphere.glb");
    let o = common::kalos(&[
        "bake",
        &scene,
        "--env-constant",
        "1",
        "--particles",
        "20000",
        "-q",
        "-o",
        glb.to_str().expect("utf-8"),
    ]);
    assert!(o.status.success(), "{}", common::stderr(&o));
    assert!(glb.metadata().expect("glb written").len() > 0);
}

/// A scene with its own sky is refused, naming the file and saying why;
/// `--env-scale` without `--env`, both kinds at once, and a bad constant are
/// refused by the argument parser.
#[test]
fn a_scene_with_a_sky_and_bad_flags_are_refused() {
    let dir = tempfile::tempdir().expect("tmp");
    let scene = sphere_scene(
        dir.path(),
        r#"<emitter type="constant"><rgb name="radiance" value="1"/></emitter>"#,
    );
    let (pfm, glb) = (dir.path().join("x.pfm"), dir.path().join("x.glb"));
    let out = pfm.to_str().expect("utf-8");
    for (cmd, o) in [("render", out), ("bake", glb.to_str().expect("utf-8"))] {
        let o = common::kalos(&[cmd, &scene, "--env-constant", "1,1,1", "-q", "-o", o]);
        let e = common::stderr(&o);
        assert!(!o.status.success(), "{cmd}: accepted");
        assert!(
            e.contains("sphere.xml") && e.contains("already has an environment"),
            "{cmd}: {e}"
        );
    }
    let no_sky = sphere_scene(dir.path(), "");
    for (args, why) in [
        (vec!["--env-scale", "2"], "--env"),
        (
            vec!["--env", "a.exr", "--env-constant", "1"],
            "cannot be used with",
        ),
        (vec!["--env-constant", "1,2"], "R,G,B"),
        (vec!["--env-constant", "-1,0,0"], "not negative"),
    ] {
        let mut a = vec!["render", &no_sky, "-q", "-o", out];
        a.extend(args.iter().copied());
        let o = common::kalos(&a);
        let e = common::stderr(&o);
        assert!(!o.status.success(), "{args:?}: accepted");
        assert!(e.contains(why), "{args:?}: {e}");
    }
}

/// Through the library: the environment is the emitter a Mitsuba scene
/// would declare.
#[test]
fn the_environment_is_a_mitsuba_emitter() {
    let dir = tempfile::tempdir().expect("tmp");
    let path = sphere_scene(dir.path(), "");
    let mut sc = scene::load(Path::new(&path)).expect("scene");
    assert!(sc.emitters.is_empty());
    sc.add_environment(&Environment::Constant(Rgb::new(1.0, 2.0, 3.0)))
        .expect("added");
    assert!(matches!(
        sc.emitters[..],
        [EmitterDesc::Constant { radiance }] if radiance == Rgb::new(1.0, 2.0, 3.0)
    ));
}
