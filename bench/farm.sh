#!/bin/bash
# Shard + merge overhead and checkpoint cost (issue 14), on the Cornell box:
#   bash bench/farm.sh [REPS] [SPP]
# (a) one render with 2 threads; (b) 2 shards as 2 processes of 1 thread
# each, run at once, then merged; wall times, median of REPS, and their
# ratio. (c) a render writing a checkpoint after every pass: the time per
# write as kalos reports it, and the checkpoint's size.
set -euo pipefail
REPS=${1:-5}
SPP=${2:-64}
K=${KALOS:-target/release/kalos}
S=scenes/cbox/cbox.xml
D=$(mktemp -d)
trap 'rm -rf "$D"' EXIT
now() { date +%s.%N; }
median() { sort -g | awk '{a[NR]=$1} END {print (NR%2 ? a[(NR+1)/2] : (a[NR/2]+a[NR/2+1])/2)}'; }
for r in $(seq "$REPS"); do
    t0=$(now)
    "$K" render $S --spp "$SPP" --threads 2 -q -o "$D/one.pfm" 2>/dev/null >/dev/null
    t1=$(now)
    "$K" render $S --spp "$SPP" --threads 1 -q --shard 0/2 -o "$D/p0.kpart" 2>/dev/null >/dev/null &
    "$K" render $S --spp "$SPP" --threads 1 -q --shard 1/2 -o "$D/p1.kpart" 2>/dev/null >/dev/null &
    wait
    t2=$(now)
    "$K" merge "$D/p0.kpart" "$D/p1.kpart" -o "$D/merged.pfm" >/dev/null
    t3=$(now)
    cmp -s "$D/one.pfm" "$D/merged.pfm" || { echo "merged image differs" >&2; exit 1; }
    "$K" render $S --spp "$SPP" --threads 2 -q --checkpoint "$D/ck.kpart" --checkpoint-every 1e-9 \
        -o "$D/ck.pfm" 2>/dev/null | sed -n 's/.* written during the render, \([0-9.]*\) ms each.*/\1/p' >>"$D/perwrite"
    echo "$t0 $t1 $t2 $t3" >>"$D/times"
done
awk '{print $2-$1}' "$D/times" | median >"$D/one"
awk '{print $3-$2}' "$D/times" | median >"$D/shards"
awk '{print $4-$3}' "$D/times" | median >"$D/merge"
awk '{print $4-$2}' "$D/times" | median >"$D/both"
echo "one run, 2 threads:             $(cat "$D/one") s (median of $REPS)"
echo "2 shards x 1 thread, at once:   $(cat "$D/shards") s"
echo "merge:                          $(cat "$D/merge") s"
echo "shards + merge / one run:       $(echo "$(cat "$D/both") / $(cat "$D/one")" | bc -l | cut -c1-5)"
echo "checkpoint cost per write:      $(median <"$D/perwrite") ms (a checkpoint after each of $SPP passes)"
echo "checkpoint size:                $(stat -c %s "$D/ck.kpart") bytes; a shard part: $(stat -c %s "$D/p0.kpart") bytes"
