#!/usr/bin/env bash
# A partitioned bake on Slurm (`make bake-slurm`):
#   bake.sh SRC OUT RECIPE PARTS
# submits PARTS array tasks (pipelines/slurm/part.sbatch) and an assemble
# job that depends on them (afterok), waits for the assemble job with
# `sbatch --wait`, and exits non-zero naming every failed part.
#
# Assumes what a cluster's batch work assumes: SRC, OUT's directory and the
# terrabake binary (TB, default target/release/terrabake) are on a file
# system every node sees at the same path. Extra sbatch flags (a partition,
# an account, time or memory limits) go in SBATCH_FLAGS.
set -euo pipefail

src=$(realpath "${1:?usage: bake.sh SRC OUT RECIPE PARTS}")
out=$(realpath -m "${2:?usage: bake.sh SRC OUT RECIPE PARTS}")
recipe=$(realpath "${3:?usage: bake.sh SRC OUT RECIPE PARTS}")
parts=${4:?usage: bake.sh SRC OUT RECIPE PARTS}
tb=$(realpath "${TB:-target/release/terrabake}")
here=$(dirname "$(realpath "$0")")
[[ $parts =~ ^[1-9][0-9]*$ ]] || { echo "bake.sh: PARTS=$parts is not a positive number" >&2; exit 2; }

status="$out.slurm"
rm -rf "$status"
mkdir -p "$status"
export TB="$tb" SRC="$src" OUT="$out" RECIPE="$recipe" PARTS="$parts" STATUS="$status"
# shellcheck disable=SC2086
array=$(sbatch --parsable ${SBATCH_FLAGS:-} --export=ALL --array="0-$((parts - 1))" \
    --output="$status/part-%a.log" "$here/part.sbatch")
array=${array%%;*}
# shellcheck disable=SC2086
join=$(sbatch --parsable ${SBATCH_FLAGS:-} --export=ALL --dependency="afterok:$array" \
    --kill-on-invalid-dep=yes --output="$status/assemble.log" "$here/assemble.sbatch")
join=${join%%;*}
echo "bake.sh: parts job $array (${parts} tasks), assemble job $join; logs in $status" >&2

failed_parts() {
    local failed=()
    for ((i = 0; i < parts; i++)); do
        if [[ -f $status/part-$i.rc && $(cat "$status/part-$i.rc") != 0 ]]; then
            failed+=("$i")
        fi
    done
    echo "${failed[*]}"
}

# A job that depends afterok on a failed task never runs; Slurm should cancel
# it (--kill-on-invalid-dep), and this watcher makes sure.
(
    while squeue -h -j "$join" 2>/dev/null | grep -q .; do
        if [[ -n $(failed_parts) ]]; then
            scancel "$join" 2>/dev/null || true
            break
        fi
        sleep 1
    done
) &
watcher=$!
# Waits for the assemble job however it ends (its own exit status is not
# trusted: a job cancelled while pending can report 0).
sbatch --wait --parsable ${SBATCH_FLAGS:-} --export=ALL --dependency="afterany:$join" \
    --output=/dev/null --wrap true >/dev/null 2>&1 ||
    while squeue -h -j "$join" 2>/dev/null | grep -q .; do sleep 1; done
kill "$watcher" 2>/dev/null || true
wait "$watcher" 2>/dev/null || true

failed=$(failed_parts)
missing=()
for ((i = 0; i < parts; i++)); do
    [[ -f $status/part-$i.rc ]] || missing+=("$i")
done
if [[ -n $failed || ${#missing[@]} -gt 0 ]]; then
    [[ -n $failed ]] && echo "bake.sh: part(s) $failed of $parts failed; see $status/part-I.log" >&2
    [[ ${#missing[@]} -gt 0 ]] && echo "bake.sh: part(s) ${missing[*]} of $parts never finished (cancelled or lost); see $status/" >&2
    exit 1
fi
if [[ ! -f $status/assemble.rc || $(cat "$status/assemble.rc") != 0 ]]; then
    echo "bake.sh: the assemble job failed or did not run; see $status/assemble.log" >&2
    exit 1
fi
echo "bake.sh: $out assembled from $parts parts" >&2
