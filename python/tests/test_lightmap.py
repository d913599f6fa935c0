"""kalos.bake(scene, lightmap=True): the atlas and its error map as numpy
arrays, and the atlas saved as the command line writes it."""

import numpy as np
import pytest

import kalos


def test_lightmap_arrays_and_save(tmp_path, run_cli):
    scene = kalos.load()
    out = tmp_path / "atlas.exr"
    lm = kalos.bake(scene, lightmap=True, lightmap_size=64, particles=100_000, seed=4, output=out)
    assert lm.atlas.shape == (64, 64, 3) and lm.atlas.dtype == np.float32
    assert lm.error.shape == (64, 64, 3) and lm.error.dtype == np.float32
    assert lm.covered.shape == (64, 64) and lm.covered.any()
    lit = lm.atlas[lm.covered]
    assert (lit > 0).any() and np.isfinite(lit).all()
    # error bars: positive where lit, and smaller than the value on average
    err = lm.error[lm.covered]
    assert (err[lit > 0] > 0).all()
    assert np.median(err[lit > 0] / lit[lit > 0]) < 0.5
    assert lm.stats["particles"] == 100_000
    assert out.is_file()
    # the command line's .glb, same seed and settings: its float atlas,
    # written beside it, holds the same texels
    cli = tmp_path / "cli.glb"
    run_cli("bake", "--lightmap", "--lightmap-size", "64", "--particles", "100000",
            "--seed", "4", "-q", "-o", cli)
    assert cli.read_bytes()[:4] == b"glTF"
    cli_atlas = tmp_path / "cli.lightmap.exr"
    assert np.array_equal(kalos.read_image(out), kalos.read_image(cli_atlas))
    assert np.array_equal(kalos.read_image(out), lm.atlas)
    # save() writes the asset with its lightmap as a .glb, and its atlas
    # beside it
    glb = tmp_path / "py.glb"
    lm.save(glb)
    assert glb.read_bytes()[:4] == b"glTF"
    assert np.array_equal(kalos.read_image(tmp_path / "py.lightmap.exr"), lm.atlas)


def test_lightmap_settings_need_lightmap():
    with pytest.raises(ValueError, match="lightmap=True"):
        kalos.bake(kalos.load(), lightmap_size=64)
    with pytest.raises(ValueError, match="lightmap-size"):
        kalos.bake(kalos.load(), lightmap=True, lightmap_size=0)
