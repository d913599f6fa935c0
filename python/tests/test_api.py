"""The package's own surface: scene parameters, resolution, warnings,
render results and the settings listing."""

import numpy as np
import pytest

import kalos


def test_defines_and_resolution(cbox):
    s = kalos.load(cbox, defines={"spp": 4}, res=(40, 30))
    assert s.sample_count == 4
    assert s.resolution == (40, 30)
    # without a budget, the scene's own sample count, as `kalos render`
    r = kalos.render(s, full=True)
    assert r.image.shape == (30, 40, 3) and r.passes == 4
    with pytest.warns(UserWarning, match="-D nope"):
        kalos.load(cbox, defines={"nope": 1})
    with pytest.raises(ValueError, match="resolution out of range"):
        kalos.load(res=(0, 10))


def test_full_result_and_convergence_log():
    s = kalos.load(res=(32, 32))
    ref = kalos.render(s, spp=64, seed=99)
    r = kalos.render(s, spp=4, seed=1, reference=ref, full=True)
    assert r.method == "path" and r.passes == 4 and r.spp == 4 and r.rays > 0
    assert r.log[-1]["rel_mse"] == pytest.approx(kalos.compare(r.image, ref)["rel_mse"])
    assert np.array_equal(r.image, kalos.render(s, spp=4, seed=1))


def test_settings_listing_matches_the_methods():
    assert kalos.methods() == ["path", "light", "plb", "bundle", "density"]
    for m in kalos.methods():
        names = kalos.settings(m)
        assert all(isinstance(h, str) for h in names.values())
    assert "rr_depth" in kalos.settings("path") and "lambda" in kalos.settings("plb")
    with pytest.raises(ValueError, match="unknown method"):
        kalos.settings("nope")


def test_scene_without_light_is_refused(tmp_path):
    path = tmp_path / "dark.xml"
    path.write_text(
        '<scene version="3.0.0">\n'
        '  <emitter type="constant"><rgb name="radiance" value="0"/></emitter>\n'
        '  <shape type="sphere"/>\n'
        "</scene>\n"
    )
    s = kalos.load(path)
    with pytest.raises(kalos.RenderError, match="no emitters that emit light"):
        kalos.render(s, spp=1)


def test_threads_are_set_once():
    kalos.render(kalos.load(res=(8, 8)), spp=1)
    with pytest.raises(ValueError, match="only once"):
        kalos.set_threads(1)


def test_the_interpreter_is_released_while_rendering():
    """Another Python thread runs during a pass: the render holds no GIL
    between its progress calls."""
    import sys
    import threading
    import time

    scene = kalos.load(res=(256, 256))
    in_pass, done = threading.Event(), threading.Event()

    def progress(p):
        if p.passes == 0:
            in_pass.set()  # pass 0 starts when this returns
        else:
            done.set()

    # No forced switches: a thread that holds the interpreter keeps it until
    # it releases it itself (here: only if the render does)
    interval = sys.getswitchinterval()
    sys.setswitchinterval(100.0)
    try:
        t = threading.Thread(target=lambda: kalos.render(scene, spp=1, progress=progress))
        t.start()
        in_pass.wait()
        count = 0
        while not done.is_set():
            count += 1
            time.sleep(0)  # lets the render's next progress call in
        t.join()
    finally:
        sys.setswitchinterval(interval)
    # with the interpreter held through the pass, this thread would run only
    # once the render had ended, after `done` was set
    assert count > 0
