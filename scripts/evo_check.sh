#!/usr/bin/env bash
# Runs the README's main scenario end to end and checks that vinebench's ATE and RPE on
# the TUM files it wrote equal evo's (github.com/MichaelGrupp/evo) to 1e-6 relative.
#
#   bash scripts/evo_check.sh            # uses/creates a venv in target/evo-venv
#
# evo is installed from PyPI (pinned) into a private virtual environment.
set -euo pipefail
cd "$(dirname "$0")/.."

RUN="target/evo-check-run"
TOL="1e-6"

cargo build --release --locked --bin vinebench
rm -rf "$RUN"
./target/release/vinebench run scenarios/row-loop-rtk-outage.toml --quiet --out "$RUN"

source scripts/evo-venv.sh

TMAX=$(python3 -c "import tomllib; print(tomllib.load(open('$RUN/scenario.resolved.toml','rb'))['scoring']['t_max_diff_s'])")
status=0
for est in "$RUN"/estimate_*.tum; do
    src=$(basename "$est" .tum); src=${src#estimate_}
    ./target/release/vinebench score --ref "$RUN/ground_truth.tum" "$est" --t-max-diff "$TMAX" > "$RUN/ours_$src.json"
    ./target/release/vinebench score --ref "$RUN/ground_truth.tum" "$est" --t-max-diff "$TMAX" --align > "$RUN/ours_aligned_$src.json"
    "$VENV/bin/python" scripts/evo_crosscheck.py "$RUN/ground_truth.tum" "$est" --t_max_diff "$TMAX" > "$RUN/evo_$src.json"
    python3 - "$RUN" "$src" "$TOL" <<'PY' || status=1
import json, sys
run, src, tol = sys.argv[1], sys.argv[2], float(sys.argv[3])
ours = json.load(open(f"{run}/ours_{src}.json"))
ours_al = json.load(open(f"{run}/ours_aligned_{src}.json"))
evo = json.load(open(f"{run}/evo_{src}.json"))
report = {s["name"]: s["score"] for s in json.load(open(f"{run}/report.json"))["sources"]}[src]
pairs = []
for k in ("rmse", "mean", "median", "std", "min", "max"):
    pairs.append((f"ape.{k}", ours["ape_translation_m"][k], evo["ape"][k]))
    pairs.append((f"ape_aligned.{k}", ours_al["ape_translation_m"][k], evo["ape_aligned"][k]))
    pairs.append((f"rpe.{k}", ours["rpe_translation_m"]["stats"][k], evo["rpe"][k]))
pairs.append(("report ate_rmse_m", report["ate_rmse_m"], evo["ape"]["rmse"]))
pairs.append(("report ate_rmse_aligned_m", report["ate_rmse_aligned_m"], evo["ape_aligned"]["rmse"]))
pairs.append(("report ate_max_m", report["ate_max_m"], evo["ape"]["max"]))
worst = 0.0
bad = []
for name, a, b in pairs:
    rel = abs(a - b) / max(abs(b), 1e-300)
    worst = max(worst, rel)
    if rel > tol:
        bad.append(f"  {name}: vinebench {a!r} evo {b!r} (rel {rel:.2e})")
print(f"{src:16s} {evo['matched']} poses matched, ATE {evo['ape']['rmse']:.6f} m "
      f"(aligned {evo['ape_aligned']['rmse']:.6f} m), worst relative difference to evo "
      f"{evo['evo_version']}: {worst:.1e}")
if bad or ours["matched_poses"] != evo["matched"]:
    print("\n".join(bad) or f"  matched poses differ: {ours['matched_poses']} vs {evo['matched']}")
    sys.exit(1)
PY
done
if [ "$status" -ne 0 ]; then
    echo "vinebench and evo disagree beyond $TOL relative" >&2
    exit 1
fi
echo "ATE/RPE equal evo $EVO_VERSION to $TOL relative for every source."
