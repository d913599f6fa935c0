#!/bin/sh
# Writes the seed corpora corpus/<target>/ of the five fuzz targets from the
# loader fuzz test's small scenes and the repository's scenes/. Run from
# anywhere; it needs only rustc (standard library).
set -eu
here=$(cd "$(dirname "$0")" && pwd)
tmp=$(mktemp -d)
trap 'rm -rf "$tmp"' EXIT
rustc --edition 2021 -O -o "$tmp/seed" "$here/seed.rs"
"$tmp/seed" "$here/.." "$here/corpus"
