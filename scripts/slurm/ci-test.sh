#!/usr/bin/env bash
# CI's proof of the Slurm path: a single-node Slurm cluster on this machine
# (ci-cluster.sh), the CI-sized sweep tests/data/ci-sweep.toml submitted as a 3-task job
# array plus a dependent merge job (submit.sh), and the merged table compared byte for
# byte with a single-process run of the same sweep. The merged JUnit file is read by two
# independent JUnit readers (scripts/junit_check.py). Stops the daemons it started.
#
#   bash scripts/slurm/ci-test.sh        # as root; installs Slurm and munge if missing
set -euo pipefail
cd "$(dirname "$0")/../.."

cargo build --release --locked --bin vinebench
bin=$PWD/target/release/vinebench
work=$(mktemp -d)
bash scripts/slurm/ci-cluster.sh start
trap 'bash scripts/slurm/ci-cluster.sh stop; rm -rf "$work"' EXIT

echo "-- single process"
"$bin" sweep tests/data/ci-sweep.toml --out "$work/single" --jobs 1 --quiet

echo "-- Slurm: 3-task array + dependent merge"
VINEBENCH=$bin bash scripts/slurm/submit.sh tests/data/ci-sweep.toml "$work/slurm" 3 --wait
ls "$work/slurm/rows"
test "$(ls "$work/slurm/rows" | wc -l)" -eq 3 || { echo "expected 3 shards' rows files"; exit 1; }
for f in results.csv summary.json sweep.md; do
    cmp "$work/single/$f" "$work/slurm/$f"
done
python3 scripts/junit_check.py "$work/slurm/junit.xml" --tests 10 --suites 3
echo "Slurm sweep: merged results equal the single-process run byte for byte"
