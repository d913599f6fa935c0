"""Every kalos method on the Cornell box at equal time: relMSE against the
Mitsuba 3 reference as the render goes, plotted log-log with matplotlib.

    pip install ./python matplotlib       # or: cd python && maturin develop --release
    python examples/compare_methods.py --time 10 -o compare_methods.png

Each method gets the same time budget (its setup included: plb's camera
pre-pass, bundle's patches, density's bake) and logs its error every
--log-every seconds through the driver's convergence log, so one render per
method gives its whole curve.
"""

import argparse
from pathlib import Path

import matplotlib

matplotlib.use("Agg")  # a file, no window
import matplotlib.pyplot as plt

import kalos

ROOT = Path(__file__).resolve().parents[1]


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scene", default=ROOT / "scenes" / "cbox" / "cbox.xml", type=Path)
    ap.add_argument("--ref", default=ROOT / "refs" / "cbox.pfm", type=Path)
    ap.add_argument("--time", default=10.0, type=float, help="seconds per method")
    ap.add_argument("--log-every", default=0.25, type=float, help="seconds between log rows")
    ap.add_argument("--seed", default=1, type=int)
    ap.add_argument("-o", "--output", default="compare_methods.png", type=Path)
    args = ap.parse_args()

    scene = kalos.load(args.scene)
    ref = kalos.read_image(args.ref)
    fig, ax = plt.subplots(figsize=(7, 5))
    print(f"{'method':<8} {'passes':>7} {'Mrays':>8} {'relMSE':>10}")
    for method in kalos.methods():
        r = kalos.render(
            scene,
            method=method,
            time=args.time,
            seed=args.seed,
            reference=ref,
            log_every=args.log_every,
            full=True,
        )
        rows = [row for row in r.log if row["rel_mse"] is not None]
        ax.loglog(
            [row["time_s"] for row in rows],
            [row["rel_mse"] for row in rows],
            marker=".",
            label=method,
        )
        final = kalos.compare(r.image, ref)["rel_mse"]
        print(f"{method:<8} {r.passes:>7} {r.rays / 1e6:>8.1f} {final:>10.4e}")
    ax.set_xlabel("time (s)")
    ax.set_ylabel("relMSE against the Mitsuba 3 reference")
    ax.set_title(f"{args.scene.name}: every method, {args.time:g} s each")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend()
    fig.tight_layout()
    fig.savefig(args.output, dpi=120)
    print(f"plot written to {args.output}")


if __name__ == "__main__":
    main()
