#!/bin/bash
# kalos on Slurm: merges the shards of farm/slurm.sh into one image, once
# they have all finished:
#
#   jobid=$(sbatch --parsable farm/slurm.sh)
#   sbatch --dependency=afterok:$jobid farm/slurm-merge.sh
#
# kalos merge refuses parts of different renders or a shard given twice,
# and lists the missing shards. See docs/farm.md.
#SBATCH --job-name=kalos-merge
#SBATCH --cpus-per-task=1
#SBATCH --time=00:30:00
#SBATCH --output=kalos-merge-%j.log
set -euo pipefail

KALOS=${KALOS:-kalos}
PARTS=${PARTS:-parts}
IMAGE=${IMAGE:-out.exr}

"$KALOS" merge "$PARTS"/shard-[0-9]*.kpart -o "$IMAGE"
