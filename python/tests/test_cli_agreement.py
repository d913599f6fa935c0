"""The package and the command line give the same bits for the same seed
and settings: one library under both."""

import re

import numpy as np
import pytest

import kalos
from conftest import read_pfm

RES = (48, 40)

# (method, keyword settings, the same settings as flags); small budgets
CASES = [
    ("path", {"rr_depth": 3}, ["--rr-depth", "3"]),
    ("light", {"camera_pass": False}, ["--camera-pass", "off"]),
    ("plb", {"lambda_": 2, "population": 2000}, ["--lambda", "2", "--population", "2000"]),
    ("bundle", {"patches": 200}, ["--patches", "200"]),
    ("density", {"particles": "20k", "no_decimate": True}, ["--particles", "20k", "--no-decimate"]),
]


@pytest.fixture(scope="module")
def scene(cbox):
    return kalos.load(cbox, res=RES)


@pytest.mark.parametrize("method,kwargs,flags", CASES, ids=[c[0] for c in CASES])
def test_render_is_bit_identical_to_the_cli(scene, cbox, run_cli, tmp_path, method, kwargs, flags):
    out = tmp_path / "cli.pfm"
    res = f"{RES[0]}x{RES[1]}"
    run_cli("render", cbox, "--method", method, "--spp", 2, "--seed", 11, "--res", res,
            "-q", "-o", out, *flags)
    cli = read_pfm(out)
    py = kalos.render(scene, method=method, spp=2, seed=11, **kwargs)
    assert py.dtype == np.float32 and py.shape == (RES[1], RES[0], 3)
    assert np.array_equal(py, cli)
    # another seed gives another image (so the equality above means something)
    other = kalos.render(scene, method=method, spp=2, seed=12, **kwargs)
    assert not np.array_equal(other, cli)


def test_scene_counts_match_kalos_info(cbox, run_cli):
    text = run_cli("info", cbox).stdout
    s = kalos.load(cbox)
    assert str(s).strip() == text.strip()
    field = lambda name: int(re.search(rf"^{name}\s+(\d+)", text, re.M).group(1))
    assert (s.triangles, s.vertices, s.shapes, s.materials, s.emitters) == tuple(
        field(n) for n in ["triangles", "vertices", "shapes", "materials", "emitters"]
    )
    lo, hi = s.bounds
    assert all(a < b for a, b in zip(lo, hi))
    assert s.resolution == (s.camera["width"], s.camera["height"])


def test_compare_matches_kalos_compare(scene, tmp_path, run_cli):
    a = kalos.render(scene, spp=1, seed=1)
    b = kalos.render(scene, spp=4, seed=2)
    kalos.write_image(tmp_path / "a.pfm", a)
    kalos.write_image(tmp_path / "b.pfm", b)
    text = run_cli("compare", tmp_path / "a.pfm", tmp_path / "b.pfm").stdout
    printed = {k: float(v) for k, v in re.findall(r"^(relMSE|RMSE|relL1)\s+(\S+)", text, re.M)}
    c = kalos.compare(a, b)
    # the CLI prints 7 significant digits
    assert c["rel_mse"] == pytest.approx(printed["relMSE"], rel=1e-6)
    assert c["rmse"] == pytest.approx(printed["RMSE"], rel=1e-6)
    assert c["rel_l1"] == pytest.approx(printed["relL1"], rel=1e-6)
    assert c["means"] == pytest.approx(tuple(a.reshape(-1, 3).mean(axis=0, dtype=np.float64)), rel=1e-6)


def test_bake_saves_the_same_glb_as_kalos_bake(cbox, tmp_path, run_cli):
    run_cli("bake", cbox, "--particles", "30k", "--seed", 3, "-q", "-o", tmp_path / "cli.glb")
    # the scene at its own resolution: the .glb carries the camera
    b = kalos.bake(kalos.load(cbox), particles=30_000, seed=3)
    b.save(tmp_path / "py.glb")
    assert (tmp_path / "py.glb").read_bytes() == (tmp_path / "cli.glb").read_bytes()
    n = len(b.positions)
    assert n > 0 and b.normals.shape == b.colours.shape == b.radiance.shape == (n, 3)
    assert b.indices.dtype == np.uint32 and b.indices.max() < n
    assert np.all((b.colours >= 0) & (b.colours <= 1)) and np.all(np.isfinite(b.radiance))
    assert b.stats["particles"] == 30_000
    b.save(tmp_path / "irr.ply")
    assert (tmp_path / "irr.ply").read_bytes().startswith(b"ply")
