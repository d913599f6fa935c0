"""Bad settings and bad files are refused with the command line's messages
(naming the setting, the file and the line), never with a crash or a NaN."""

import numpy as np
import pytest

import kalos


@pytest.fixture(scope="module")
def scene():
    return kalos.load(res=(16, 16))


@pytest.mark.parametrize(
    "kwargs,message",
    [
        # a setting of another method: the CLI's message, naming both
        ({"lambda_": 3}, "--lambda does not apply to method 'path': it is a setting of 'plb'"),
        ({"method": "plb", "lambda_": "x"}, "invalid value 'x' for '--lambda <LAMBDA>'"),
        ({"method": "plb", "camera_pass": "maybe"}, "expected on or off, got 'maybe'"),
        ({"rr_depth": 0}, "--rr-depth must be at least 1"),
        ({"frobnicate": 1}, "unknown setting --frobnicate for method 'path'; its settings: --rr-depth"),
        ({"method": "density", "no_decimate": 3}, "--no-decimate is a switch"),
        ({"method": "density", "particles": "lots"}, "expected a count such as 1000000 or 30M"),
        ({"method": "nope"}, "unknown method 'nope'; known methods: path, light, plb, bundle, density"),
        ({"method": "bundle", "max_depth": 3}, "method 'bundle' cannot honour --max-depth"),
        ({"spp": -1}, "--spp must be a finite number > 0"),
        ({"time": float("nan")}, "--time must be a finite number > 0"),
        ({"rays": "0"}, "rays: expected a positive count"),
        ({"max_memory": "1k"}, "the limit is 1.0 kB (max_memory)"),
    ],
)
def test_bad_settings(scene, kwargs, message):
    kwargs.setdefault("spp", 1)
    err = ValueError if "max_memory" not in kwargs else kalos.RenderError
    with pytest.raises(err) as e:
        kalos.render(scene, **kwargs)
    assert message in str(e.value)


def test_bad_setting_types(scene):
    with pytest.raises(TypeError, match="setting rr-depth: expected a bool, number, string or path"):
        kalos.render(scene, spp=1, rr_depth=[3])
    with pytest.raises(ValueError, match="reference is 8x8 but the render is 16x16"):
        kalos.render(scene, spp=1, reference=np.zeros((8, 8, 3)))


def test_missing_scene_file(tmp_path):
    path = tmp_path / "nowhere.xml"
    with pytest.raises(kalos.SceneError, match=str(path)):
        kalos.load(path)


def test_scene_error_names_file_and_line(tmp_path):
    path = tmp_path / "bad.xml"
    path.write_text('<scene version="3.0.0">\n  <shape type="sphere">\n    <float name="radius" value="abc"/>\n  </shape>\n</scene>\n')
    with pytest.raises(kalos.SceneError) as e:
        kalos.load(path)
    assert str(e.value).startswith(f"{path}:3:"), str(e.value)


def test_unknown_scene_format(tmp_path):
    path = tmp_path / "scene.txt"
    path.write_text("hello")
    with pytest.raises(kalos.SceneError, match="unknown scene format"):
        kalos.load(path)


def test_bad_images(tmp_path):
    with pytest.raises(kalos.ImageError, match="missing.exr"):
        kalos.read_image(tmp_path / "missing.exr")
    (tmp_path / "broken.pfm").write_bytes(b"PF\n2 2\n-1\n\0\0")
    with pytest.raises(kalos.ImageError, match="broken.pfm: malformed PFM"):
        kalos.read_image(tmp_path / "broken.pfm")
    img = np.ones((4, 5, 3), np.float32)
    with pytest.raises(kalos.ImageError, match="unknown image format"):
        kalos.write_image(tmp_path / "x.bmp", img)
    with pytest.raises(kalos.ImageError, match="no-such-dir"):
        kalos.write_image(tmp_path / "no-such-dir" / "x.exr", img)
    with pytest.raises(ValueError, match=r"expected an RGB image.*\(4, 5\)"):
        kalos.write_image(tmp_path / "x.exr", img[..., 0])
    with pytest.raises(ValueError, match="tonemap: expected clamp, reinhard or aces"):
        kalos.write_image(tmp_path / "x.png", img, tonemap="filmic")
    assert list(tmp_path.iterdir()) == [tmp_path / "broken.pfm"]  # nothing half-written


def test_compare_refuses_mismatch_and_nan():
    a = np.ones((4, 4, 3), np.float32)
    with pytest.raises(ValueError, match="the image is 4x4 but the reference is 3x4"):
        kalos.compare(a, np.ones((4, 3, 3)))
    b = a.copy()
    b[1, 2, 0] = np.nan
    with pytest.raises(ValueError, match="the reference: 1 of its 16 pixels are NaN or infinite"):
        kalos.compare(a, b)


@pytest.mark.parametrize("ext", ["exr", "pfm", "png"])
def test_image_round_trip(tmp_path, ext):
    rng = np.random.default_rng(1)
    img = rng.uniform(0, 1, (6, 7, 3)).astype(np.float32)
    kalos.write_image(tmp_path / f"x.{ext}", img)
    back = kalos.read_image(tmp_path / f"x.{ext}")
    assert back.shape == img.shape and back.dtype == np.float32
    if ext == "png":  # 8-bit sRGB: within half a code value
        assert np.allclose(back, img, atol=0.01)
    else:
        assert np.array_equal(back, img)
