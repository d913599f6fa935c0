#!/usr/bin/env bash
# Equal-time error of `light` against `path` in kalos, on cbox (against the
# Mitsuba reference) and on glass-mirror (against a long `path` render made
# here, since no Mitsuba reference is shipped for it).
# Usage: bash bench/light_vs_path.sh [SECONDS]   (default 10)
set -euo pipefail
cd "$(dirname "$0")/.."
T=${1:-10}
K=target/release/kalos
[ -x $K ] || cargo build --release
out=target/bench-out; mkdir -p $out
if [ ! -f $out/glass-mirror-ref.exr ]; then
  $K render scenes/glass-mirror/scene.xml --method path --spp 8192 --seed 1000 -o $out/glass-mirror-ref.exr -q
fi
for scene in cbox glass-mirror; do
  if [ $scene = cbox ]; then f=scenes/cbox/cbox.xml; ref=refs/cbox.pfm; else f=scenes/glass-mirror/scene.xml; ref=$out/glass-mirror-ref.exr; fi
  for m in path light; do
    $K render $f --method $m --time $T --seed 7 --ref $ref --log $out/${scene}-$m.csv --log-every 1 -o $out/${scene}-$m.exr -q
  done
  $K plot path=$out/${scene}-path.csv light=$out/${scene}-light.csv -o $out/${scene}-light-vs-path.png --title "$scene: light vs path"
done
