#!/usr/bin/env bash
# Submits a vinebench sweep to Slurm: an array of TASKS shards, then a merge job that runs
# when the array has ended.
#
#   bash scripts/slurm/submit.sh SWEEP_FILE OUT_DIR TASKS [extra sbatch options...]
#   bash scripts/slurm/submit.sh scenarios/sweeps/occluder-width.toml /shared/ow 8 --partition=cpu
#
# Prints the two job ids. Add --wait to the options to block until the merge has ended
# (its exit code is then this script's).
set -euo pipefail
[ $# -ge 3 ] || { sed -n '2,9p' "$0"; exit 2; }
sweep=$1; out=$2; tasks=$3; shift 3
here=$(cd "$(dirname "$0")" && pwd)
wait_flag=()
opts=()
for o in "$@"; do
    if [ "$o" = --wait ]; then wait_flag=(--wait); else opts+=("$o"); fi
done
mkdir -p "$out"
export SWEEP=$sweep OUT=$out
array=$(sbatch --parsable --array=0-$((tasks - 1)) --export=ALL \
    --output="$out/slurm-%A_%a.out" "${opts[@]}" "$here/sweep.sbatch")
array=${array%%;*}
echo "array job $array: $tasks shard(s) of $sweep -> $out"
merge=$(sbatch --parsable --dependency=afterany:"$array" --export=ALL \
    --output="$out/slurm-merge-%j.out" "${opts[@]}" "${wait_flag[@]}" "$here/merge.sbatch") || status=$?
echo "merge job ${merge%%;*} (after the array)"
exit "${status:-0}"
