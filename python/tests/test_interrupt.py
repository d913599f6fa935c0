"""Ctrl-C and exceptions from the progress callback stop a render or a bake
cleanly: the exception is raised, scratch files are gone, and the next call
works."""

import os
import signal
import subprocess
import sys
import textwrap

import numpy as np
import pytest

import kalos


@pytest.fixture(scope="module")
def scene():
    return kalos.load(res=(32, 32))


def test_progress_reports_the_passes(scene):
    seen = []
    kalos.render(scene, spp=3, progress=seen.append)
    passes = [p.passes for p in seen]
    # path takes its passes several at a time once the first has been
    # timed (up to a quarter of a second of them): 0, 1, then the last two
    assert passes[:2] == [0, 1] and passes[-1] == 3, passes
    assert all(a < b for a, b in zip(passes, passes[1:])), passes
    assert seen[-1].fraction == 1.0 and seen[-1].rays > 0 and seen[-1].phase is None


def test_keyboard_interrupt_from_the_callback_stops_the_render(scene):
    calls = []

    def progress(p):
        calls.append(p.passes)
        if p.passes >= 2:
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        kalos.render(scene, spp=1000, progress=progress)
    # stopped at once, not after 1000 passes (the third call comes after a
    # batch of passes, at most 64)
    assert len(calls) == 3 and calls[:2] == [0, 1] and 2 <= calls[2] <= 65, calls
    # the package is usable afterwards
    assert np.isfinite(kalos.render(scene, spp=1)).all()


def test_other_exceptions_from_the_callback_are_raised(scene):
    def progress(p):
        raise RuntimeError("stop here")

    with pytest.raises(RuntimeError, match="stop here"):
        kalos.render(scene, spp=1000, progress=progress)


def test_interrupted_bake_leaves_no_scratch_files(scene, tmp_path):
    phases = []

    def progress(p):
        phases.append(p.phase)
        raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        kalos.bake(scene, particles="2M", scratch=tmp_path, progress=progress)
    assert phases == ["tracing particles"]
    assert list(tmp_path.iterdir()) == []


CHILD = textwrap.dedent(
    """
    import sys, kalos
    scene = kalos.load(res=(32, 32))
    def progress(p):
        if p.passes == 1:
            print("rendering", flush=True)
    try:
        kalos.render(scene, method=sys.argv[1], time=300, progress=progress)
        print("finished")
    except KeyboardInterrupt:
        print("KeyboardInterrupt")
    """
)


@pytest.mark.parametrize("method", ["path", "plb"])
def test_sigint_raises_keyboard_interrupt(method):
    """A real SIGINT while the render runs with the interpreter released."""
    child = subprocess.Popen(
        [sys.executable, "-c", CHILD, method], stdout=subprocess.PIPE, text=True
    )
    try:
        assert child.stdout.readline().strip() == "rendering"
        child.send_signal(signal.SIGINT)
        # the 300 s budget is far off: only the interrupt ends the render
        out, _ = child.communicate(timeout=120)
    finally:
        if child.poll() is None:
            child.kill()
    assert out.strip() == "KeyboardInterrupt"
    assert child.returncode == 0
