#!/usr/bin/env bash
# Fig. 10 on teapot-room and the equal-time comparison of bundle, path and
# light there, against a long path reference rendered here.
# Usage: bash bench/teapot_room.sh [SECONDS]   (default 10)
set -euo pipefail
cd "$(dirname "$0")/.."
T=${1:-10}
K=target/release/kalos
[ -x $K ] || cargo build --release
out=target/bench-out; res=bench/results/bundle; mkdir -p $out $res
S=scenes/teapot-room/scene.xml
if [ ! -f $out/teapot-room-ref.exr ]; then
  $K render $S --method path --time 120 --seed 1000 -o $out/teapot-room-ref.exr -q
fi
for m in bundle path light; do
  $K render $S --method $m --time $T --seed 7 --ref $out/teapot-room-ref.exr \
    --log $res/teapot-room-$m.csv --log-every 0.5 -o $out/teapot-room-$m.exr -q
done
$K plot bundle=$res/teapot-room-bundle.csv -o $res/fig10-teapot-room-iter.png --x spp --title "teapot-room: bundle, error vs iterations"
$K plot bundle=$res/teapot-room-bundle.csv -o $res/fig10-teapot-room-time.png --x time --title "teapot-room: bundle, error vs time"
$K plot bundle=$res/teapot-room-bundle.csv path=$res/teapot-room-path.csv light=$res/teapot-room-light.csv \
  -o $res/teapot-room-equal-time.png --x time --title "teapot-room: equal time"
