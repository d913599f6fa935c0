#!/usr/bin/env bash
# Convergence of plb, light and path on two-rooms (issue #6), against a
# Mitsuba 3 reference (scalar_rgb path, 4096 spp) rendered here.
# Usage: bash bench/two_rooms.sh [SECONDS] [SCENE]   (default 30, scenes/two-rooms/scene.xml)
set -euo pipefail
cd "$(dirname "$0")/.."
T=${1:-30}
S=${2:-scenes/two-rooms/scene.xml}
name=$(basename "$S" .xml)
K=target/release/kalos
[ -x $K ] || cargo build --release
out=target/bench-out; res=bench/results/plb; mkdir -p $out $res
ref=$out/two-rooms-$name-ref.exr
if [ ! -f "$ref" ]; then
  python3 bench/mitsuba_compare.py --ensure-only >/dev/null   # installs Mitsuba into bench/.venv if missing
  bench/.venv/bin/python bench/results/density/mi_ref.py "$S" "$ref" 4096
fi
for m in plb light path; do
  $K render "$S" --method $m --time "$T" --seed 7 --ref "$ref" \
    --log $res/two-rooms-$name-$m.csv --log-every 1 -o $out/two-rooms-$name-$m.png -q
done
$K plot plb=$res/two-rooms-$name-plb.csv light=$res/two-rooms-$name-light.csv path=$res/two-rooms-$name-path.csv \
  -o $res/two-rooms-$name-convergence.png --x time --title "two-rooms ($name): relMSE vs time"
