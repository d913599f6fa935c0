"""Shared fixtures: the repository's scenes and the `kalos` binary that
`cargo build --release` (or `cargo test --release`) makes, for the tests
that compare the package with the command line."""

import os
import subprocess
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="session")
def cbox():
    return ROOT / "scenes" / "cbox" / "cbox.xml"


@pytest.fixture(scope="session")
def kalos_bin():
    """The command line: $KALOS_BIN, else target/release/kalos."""
    path = Path(os.environ.get("KALOS_BIN", ROOT / "target" / "release" / "kalos"))
    if not path.is_file():
        pytest.fail(f"{path} is missing: build it with `cargo build --release` (or set KALOS_BIN)")
    return path


@pytest.fixture(scope="session")
def run_cli(kalos_bin):
    def run(*args, check=True):
        r = subprocess.run(
            [str(kalos_bin), *map(str, args)], capture_output=True, text=True, timeout=600
        )
        if check and r.returncode != 0:
            raise AssertionError(f"kalos {' '.join(map(str, args))} failed: {r.stderr}")
        return r

    return run


def read_pfm(path):
    """A PFM read with numpy alone (not through kalos), top row first."""
    data = Path(path).read_bytes()
    header, rest = data.split(b"\n", 1)
    assert header == b"PF"
    dims, rest = rest.split(b"\n", 1)
    w, h = map(int, dims.split())
    scale, rest = rest.split(b"\n", 1)
    dtype = "<f4" if float(scale) < 0 else ">f4"
    img = np.frombuffer(rest[: w * h * 12], dtype=dtype).reshape(h, w, 3)
    return img[::-1].astype(np.float32)
