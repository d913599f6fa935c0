#!/bin/sh
# Runs fuzz targets concurrently for SECONDS each, at the lowest priority,
# and keeps going past findings (libFuzzer's fork mode with one job): each
# target's log, with `/usr/bin/time -v`'s CPU seconds at its end, goes to
# logs/<target>.log, its findings to artifacts/<target>/.
#
#   ./seed.sh                      # once: the seed corpora
#   cargo +nightly fuzz build -s none -a
#   ./run.sh 3600                  # all five targets for an hour
#   ./run.sh 300 ply gltf          # two of them for five minutes
set -eu
cd "$(dirname "$0")"
secs=${1:?usage: run.sh SECONDS [TARGET...]}
shift
[ $# -gt 0 ] || set -- mitsuba_xml obj_mtl ply gltf pbrt
# FUZZ_BIN: where the targets are (a copy, so that a rebuild during a run
# does not change what the run executes); FUZZ_LOGS: where the logs go
bin=${FUZZ_BIN:-target/x86_64-unknown-linux-gnu/release}
logs=${FUZZ_LOGS:-logs}
mkdir -p "$logs"
# the scene folders each input writes: on a RAM disk when there is one
[ -d /dev/shm ] && export TMPDIR=/dev/shm
for t in "$@"; do
    case $t in
        gltf) max_len=262144 ;;
        mitsuba_xml | obj_mtl) max_len=131072 ;;
        *) max_len=65536 ;;
    esac
    mkdir -p "corpus/$t" "artifacts/$t"
    nice -n 19 /usr/bin/time -v "$bin/$t" "corpus/$t" \
        -dict="dict/$t.dict" -max_len=$max_len \
        -rss_limit_mb=2048 -malloc_limit_mb=2048 -timeout=10 \
        -max_total_time="$secs" -print_final_stats=1 \
        -fork=1 -ignore_crashes=1 -ignore_ooms=1 -ignore_timeouts=1 \
        -artifact_prefix="artifacts/$t/" >"$logs/$t.log" 2>&1 &
done
wait
