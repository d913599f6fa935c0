#!/bin/sh
# Prints a markdown table of a run.sh run from its logs: for each target
# the wall and CPU seconds (`/usr/bin/time -v`, libFuzzer's fork-mode parent
# and its jobs), executions, executions per wall and per CPU second, and
# libFuzzer's last coverage line (cov: edges, ft: features, corp: inputs),
# and the findings saved in artifacts/<target>/.
#   ./stats.sh [LOGDIR]        (default logs)
set -eu
cd "$(dirname "$0")"
logs=${1:-logs}
echo "| target | wall s | CPU s | executions | exec/s (wall) | exec/s (CPU) | cov | ft | corpus | crash/oom/timeout |"
echo "|---|---|---|---|---|---|---|---|---|---|"
for f in "$logs"/*.log; do
    t=$(basename "$f" .log)
    last=$(grep -E '^#[0-9]+:' "$f" | tail -1)
    awk -v t="$t" -v last="$last" '
        /User time \(seconds\)/ { user = $4 }
        /System time \(seconds\)/ { sys = $4 }
        /Elapsed \(wall clock\)/ { n = split($8, p, ":"); wall = 0; for (i = 1; i <= n; i++) wall = wall * 60 + p[i] }
        END {
            nw = split(last, w, " ")
            execs = substr(w[1], 2) + 0
            for (i = 1; i <= nw; i++) {
                if (w[i] == "cov:") cov = w[i + 1]
                if (w[i] == "ft:") ft = w[i + 1]
                if (w[i] == "corp:") corp = w[i + 1]
                if (w[i] == "oom/timeout/crash:") { split(w[i + 1], o, "/"); found = o[3] "/" o[1] "/" o[2] }
            }
            cpu = user + sys
            printf "| `%s` | %.0f | %.0f | %d | %.0f | %.0f | %s | %s | %s | %s |\n", t, wall, cpu, execs, (wall > 0 ? execs / wall : 0), (cpu > 0 ? execs / cpu : 0), cov, ft, corp, found
        }' "$f"
done
