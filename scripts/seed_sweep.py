#!/usr/bin/env python3
"""Runs scenarios over a range of seeds and tabulates their metrics and expectations.

    python3 scripts/seed_sweep.py scenarios/row-loop-rtk.toml scenarios/slope-row.toml \
        --seeds 1-20 [--jobs 2] [--vinebench target/release/vinebench]

Each run is the scenario file with only its `seed` replaced (written next to the original
so relative paths still resolve). Prints, per scenario, the mean and worst of the main
metrics over the seeds and how many seeds met every expectation: the figures behind
"Scenario outcomes over seeds" in docs/PERFORMANCE.md. Build first:
`cargo build --release`.
"""

import argparse
import concurrent.futures
import json
import os
import re
import subprocess
import sys
import tempfile

METRICS = [
    ("ate_rmse_m", "eif"),
    ("ate_rmse_m", "gnss"),
    ("ate_rmse_m", "tracking_camera"),
    ("outage_max_error_m", "eif"),
    ("sigma_u_m", "eif"),
    ("sigma_u_m", "gnss"),
]
ROBOT = ["max_cross_track_m", "max_heading_error_deg", "max_tilt_deg"]


def seeds(spec):
    lo, _, hi = spec.partition("-")
    return range(int(lo), int(hi or lo) + 1)


def run_one(vinebench, scenario, seed, tmp):
    text = open(scenario).read()
    if re.search(r"^seed\s*=", text, re.M):
        text = re.sub(r"^seed\s*=.*$", f"seed = {seed}", text, count=1, flags=re.M)
    else:
        text = f"seed = {seed}\n" + text
    base = os.path.dirname(os.path.abspath(scenario))
    fd, path = tempfile.mkstemp(suffix=".toml", prefix=".sweep-", dir=base)
    with os.fdopen(fd, "w") as f:
        f.write(text)
    out = os.path.join(tmp, f"{os.path.basename(scenario)}-{seed}")
    try:
        subprocess.run(
            [vinebench, "run", "--quiet", "--out", out, path],
            check=False,
            stdout=subprocess.DEVNULL,
        )
    finally:
        os.unlink(path)
    report = json.load(open(os.path.join(out, "report.json")))
    values = {}
    for src in report["sources"]:
        for m, s in METRICS:
            if s == src["name"] and src["score"].get(m) is not None:
                values[(m, s)] = src["score"][m]
    for m in ROBOT:
        values[(m, "robot")] = report["robot"]["metrics"][m]
    values[("collisions", "robot")] = len(report["robot"]["collisions"])
    return seed, report["passed"], values


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("scenarios", nargs="+")
    ap.add_argument("--seeds", default="1-20")
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--vinebench", default="target/release/vinebench")
    a = ap.parse_args()
    keys = METRICS + [(m, "robot") for m in ROBOT] + [("collisions", "robot")]
    print("| scenario | " + " | ".join(f"{m}.{s} mean / max" for m, s in keys) + " | expectations hold |")
    print("|---|" + "---:|" * (len(keys) + 1))
    with tempfile.TemporaryDirectory() as tmp, concurrent.futures.ThreadPoolExecutor(a.jobs) as pool:
        for sc in a.scenarios:
            results = list(pool.map(lambda s: run_one(a.vinebench, sc, s, tmp), seeds(a.seeds)))
            cells = []
            for k in keys:
                v = [r[2][k] for r in results if k in r[2]]
                cells.append(f"{sum(v) / len(v):.3f} / {max(v):.3f}" if v else "–")
            passed = sum(1 for r in results if r[1])
            failed = [str(r[0]) for r in results if not r[1]]
            note = f" (fails: seeds {', '.join(failed)})" if failed else ""
            print(f"| `{os.path.basename(sc)}` | " + " | ".join(cells) + f" | {passed}/{len(results)}{note} |")
            sys.stdout.flush()


if __name__ == "__main__":
    main()
