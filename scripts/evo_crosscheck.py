#!/usr/bin/env python3
"""Print evo's APE and RPE statistics for two TUM files as JSON, to compare with vinebench.

Usage:
    python3 scripts/evo_crosscheck.py REFERENCE.tum ESTIMATE.tum [--t_max_diff 0.01] [--delta 1.0]

Needs evo (`python3 -m venv /tmp/evo && /tmp/evo/bin/pip install evo`). Computes, with
evo's Python API and the same steps as the `evo_ape` / `evo_rpe` command-line tools:

- "ape":         APE, translation part, not aligned   (evo_ape tum REF EST)
- "ape_aligned": APE, translation part, SE(3) Umeyama (evo_ape tum REF EST -a)
- "rpe":         RPE, translation part, delta in metres, consecutive pairs chosen on the
                 estimate's path (evo_rpe tum REF EST --delta 1 --delta_unit m)
- "rpe_pairs_from_reference": the same with --pairs_from_reference

each as {rmse, mean, median, std, min, max, sse, n}, plus "matched" (associated poses)
and "evo_version". The estimate is associated to the reference with
sync.associate_trajectories(ref, est, max_diff) before each metric, as the tools do.
"""

import argparse
import copy
import json
import sys

from evo import __version__ as evo_version
from evo.core import metrics, sync
from evo.core.metrics import PoseRelation, Unit
from evo.tools import file_interface


def stats(metric):
    s = metric.get_all_statistics()
    out = {k: float(s[k]) for k in ("rmse", "mean", "median", "std", "min", "max", "sse")}
    out["n"] = int(len(metric.error))
    return out


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("reference")
    parser.add_argument("estimate")
    parser.add_argument("--t_max_diff", type=float, default=0.01)
    parser.add_argument("--delta", type=float, default=1.0)
    args = parser.parse_args()

    traj_ref = file_interface.read_tum_trajectory_file(args.reference)
    traj_est = file_interface.read_tum_trajectory_file(args.estimate)
    ref, est = sync.associate_trajectories(traj_ref, traj_est, max_diff=args.t_max_diff)
    out = {"evo_version": evo_version, "matched": int(ref.num_poses)}

    def ape(align):
        r, e = copy.deepcopy(ref), copy.deepcopy(est)
        if align:
            e.align(r, correct_scale=False)
        m = metrics.APE(PoseRelation.translation_part)
        m.process_data((r, e))
        return stats(m)

    def rpe(pairs_from_reference):
        r, e = copy.deepcopy(ref), copy.deepcopy(est)
        m = metrics.RPE(
            PoseRelation.translation_part,
            delta=args.delta,
            delta_unit=Unit.meters,
            all_pairs=False,
            pairs_from_reference=pairs_from_reference,
        )
        m.process_data((r, e))
        return stats(m)

    for key, fn in (
        ("ape", lambda: ape(False)),
        ("ape_aligned", lambda: ape(True)),
        ("rpe", lambda: rpe(False)),
        ("rpe_pairs_from_reference", lambda: rpe(True)),
    ):
        try:
            out[key] = fn()
        except Exception as exc:  # evo raises its own exception types; report them
            out[key] = {"error": f"{type(exc).__name__}: {exc}"}

    json.dump(out, sys.stdout, indent=1, sort_keys=True)
    sys.stdout.write("\n")


if __name__ == "__main__":
    main()
