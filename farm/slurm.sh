#!/bin/bash
# kalos on Slurm: one array task per shard. Submit from the folder that
# holds the scene (it must be on a file system every node sees):
#
#   jobid=$(sbatch --parsable farm/slurm.sh)
#   sbatch --dependency=afterok:$jobid farm/slurm-merge.sh
#
# Change the shard count in --array (0-3 is 4 shards) and nothing else:
# the script reads it from Slurm. The render is set by the variables below;
# override them at submission (sbatch --export=ALL,SPP=4096 farm/slurm.sh).
# See docs/farm.md.
#SBATCH --job-name=kalos-shard
#SBATCH --array=0-3
#SBATCH --cpus-per-task=2
#SBATCH --time=04:00:00
#SBATCH --requeue
#SBATCH --output=kalos-shard-%A_%a.log
set -euo pipefail

KALOS=${KALOS:-kalos}          # the kalos binary
SCENE=${SCENE:-builtin}        # scene file; builtin = the built-in Cornell box
METHOD=${METHOD:-path}         # path or light: exact shards; plb, bundle: chains
SPP=${SPP:-1024}               # samples per pixel of the whole render
SEED=${SEED:-0}
PARTS=${PARTS:-parts}          # where the partial results go

K=${SLURM_ARRAY_TASK_ID:?run this as a Slurm array job: sbatch farm/slurm.sh}
N=${SLURM_ARRAY_TASK_COUNT:?run this as a Slurm array job: sbatch farm/slurm.sh}
mkdir -p "$PARTS"

# A checkpoint lets a requeued or preempted task go on where it stopped
# (Slurm sends SIGTERM first; kalos then saves it). plb and bundle cannot
# resume, so they start again.
extra=()
case "$METHOD" in
path | light)
    ckpt="$PARTS/ckpt-$K.kpart"
    extra+=(--checkpoint "$ckpt" --checkpoint-every 600)
    if [ -f "$ckpt" ]; then extra+=(--resume "$ckpt"); fi
    ;;
esac

"$KALOS" render "$SCENE" --method "$METHOD" --spp "$SPP" --seed "$SEED" \
    --threads "${SLURM_CPUS_PER_TASK:-1}" --shard "$K/$N" -q "${extra[@]}" \
    -o "$PARTS/shard-$K.kpart"
