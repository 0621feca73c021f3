#!/usr/bin/env bash
# `vinebench score ape|rpe` against evo_ape / evo_rpe 1.38.1 on the trajectories of evo's
# own test data (TUM RGB-D, KITTI, EuRoC, a ROS 1 bag, a ROS 2 MCAP; shipped in evo's source
# distribution on PyPI): every option of issue #31, every statistic equal to evo's to 1e-6
# relative, every array element by element, the titles and names; both results are read
# by evo's own load_res_file (vinebench writes evo's zip format).
#
#   bash scripts/evo_drop_in_check.sh           # uses/creates target/evo-venv, downloads the data
#   bash scripts/evo_drop_in_check.sh --table   # also prints the comparison table (Markdown)
set -euo pipefail
cd "$(dirname "$0")/.."

WORK="target/evo-drop-in"
TOL="1e-6"
TABLE="${1:-}"

cargo build --release --locked --bin vinebench
source scripts/evo-venv.sh
DATA="$WORK/evo-$EVO_VERSION/test/data"
if [ ! -f "$DATA/KITTI_00_ORB.txt" ]; then
    mkdir -p "$WORK"
    "$VENV/bin/pip" download --quiet --disable-pip-version-check --no-deps --no-binary :all: \
        "evo==$EVO_VERSION" -d "$WORK"
    tar -xzf "$WORK/evo-$EVO_VERSION.tar.gz" -C "$WORK" "evo-$EVO_VERSION/test/data"
fi

# metric | format | reference | estimate | options
CASES=$(cat <<'LIST'
ape|kitti|KITTI_00_gt.txt|KITTI_00_ORB.txt|
ape|kitti|KITTI_00_gt.txt|KITTI_00_ORB.txt|-a
ape|kitti|KITTI_00_gt.txt|KITTI_00_ORB.txt|-as
ape|kitti|KITTI_00_gt.txt|KITTI_00_ORB.txt|-s
ape|kitti|KITTI_00_gt.txt|KITTI_00_ORB.txt|--align_origin
ape|kitti|KITTI_00_gt.txt|KITTI_00_ORB.txt|-a --n_to_align 100
ape|kitti|KITTI_00_gt.txt|KITTI_00_ORB.txt|-a -r full
ape|kitti|KITTI_00_gt.txt|KITTI_00_ORB.txt|-a -r rot_part
ape|kitti|KITTI_00_gt.txt|KITTI_00_ORB.txt|-a -r angle_rad
ape|kitti|KITTI_00_gt.txt|KITTI_00_ORB.txt|-a -r angle_deg
ape|kitti|KITTI_00_gt.txt|KITTI_00_ORB.txt|-a -r point_distance
ape|kitti|KITTI_00_gt.txt|KITTI_00_SPTAM.txt|-a
ape|tum|fr2_desk_groundtruth.txt|fr2_desk_ORB.txt|
ape|tum|fr2_desk_groundtruth.txt|fr2_desk_ORB.txt|-a
ape|tum|fr2_desk_groundtruth.txt|fr2_desk_ORB.txt|-as
ape|tum|fr2_desk_groundtruth.txt|fr2_desk_ORB.txt|-as --n_to_align 10
ape|tum|fr2_desk_groundtruth.txt|fr2_desk_ORB.txt|-a --t_offset -1.2
ape|tum|fr2_desk_groundtruth.txt|fr2_desk_ORB.txt|-a --t_max_diff 0.001
ape|tum|fr2_desk_groundtruth.txt|fr2_desk_ORB.txt|-a --t_max_diff 0.02 --t_offset 0.005
ape|tum|fr2_desk_groundtruth.txt|fr2_desk_ORB.txt|-a -r full
ape|tum|fr2_desk_groundtruth.txt|fr2_desk_ORB.txt|-a -r angle_deg
ape|tum|fr2_desk_groundtruth.txt|fr2_desk_ORB.txt|--align_origin -r rot_part
ape|tum|fr2_desk_groundtruth.txt|fr2_desk_ORB_kf_mono.txt|-as
ape|tum|freiburg1_xyz-groundtruth.txt|freiburg1_xyz-rgbdslam.txt|-a
ape|tum|freiburg1_xyz-groundtruth.txt|freiburg1_xyz-rgbdslam.txt|-r angle_deg
ape|tum|freiburg1_xyz-groundtruth.txt|freiburg1_xyz-rgbdslam_drift.txt|
ape|tum|freiburg1_xyz-groundtruth.txt|freiburg1_xyz-ORB_kf_mono.txt|-as
ape|euroc|V102_groundtruth.csv|V102.txt|-as
ape|euroc|V102_groundtruth.csv|V102.txt|-a -r angle_rad
rpe|kitti|KITTI_00_gt.txt|KITTI_00_ORB.txt|
rpe|kitti|KITTI_00_gt.txt|KITTI_00_ORB.txt|-r angle_deg
rpe|kitti|KITTI_00_gt.txt|KITTI_00_ORB.txt|-d 10 -u m
rpe|kitti|KITTI_00_gt.txt|KITTI_00_ORB.txt|-d 10 -u m -r angle_deg
rpe|kitti|KITTI_00_gt.txt|KITTI_00_ORB.txt|-d 100 -u m --all_pairs
rpe|kitti|KITTI_00_gt.txt|KITTI_00_ORB.txt|-d 100 -u m --all_pairs --pairs_from_reference -r point_distance_error_ratio
rpe|kitti|KITTI_00_gt.txt|KITTI_00_ORB.txt|-d 10 -u f --all_pairs
rpe|kitti|KITTI_00_gt.txt|KITTI_00_ORB.txt|-d 5 -u d
rpe|kitti|KITTI_00_gt.txt|KITTI_00_ORB.txt|-d 0.1 -u r -a -r full
rpe|tum|fr2_desk_groundtruth.txt|fr2_desk_ORB.txt|
rpe|tum|fr2_desk_groundtruth.txt|fr2_desk_ORB.txt|-as -r angle_deg
rpe|tum|fr2_desk_groundtruth.txt|fr2_desk_ORB.txt|-d 1 -u m -r rot_part
rpe|tum|fr2_desk_groundtruth.txt|fr2_desk_ORB.txt|-d 1 -u m --all_pairs -t 0.05 --pairs_from_reference
rpe|tum|fr2_desk_groundtruth.txt|fr2_desk_ORB.txt|-d 5 -u d --all_pairs -t 0.001 -r angle_rad
rpe|tum|fr2_desk_groundtruth.txt|fr2_desk_ORB.txt|-d 5 -u f -r point_distance
rpe|euroc|V102_groundtruth.csv|V102.txt|-d 1 -u m
rpe|euroc|V102_groundtruth.csv|V102.txt|-d 0.1 -u r --all_pairs -as -r angle_deg
ape|bag|ROS_example.bag|groundtruth S-PTAM|
ape|bag|ROS_example.bag|groundtruth S-PTAM|-a
ape|bag|ROS_example.bag|groundtruth ORB-SLAM|-as -r angle_deg
rpe|bag|ROS_example.bag|groundtruth S-PTAM|
rpe|bag|ROS_example.bag|groundtruth ORB-SLAM|-d 1 -u m -a
ape|bag2|nav2_turtlebot.mcap|/amcl_pose /odom|-a
ape|bag2|nav2_turtlebot.mcap|/amcl_pose /odom|-r angle_deg --t_max_diff 0.05
rpe|bag2|nav2_turtlebot.mcap|/amcl_pose /odom|-r angle_deg
rpe|mcap|nav2_turtlebot.mcap|/odom /amcl_pose|-d 0.5 -u m -a
LIST
)

rm -rf "$WORK/cases"
mkdir -p "$WORK/cases"
i=0
while IFS='|' read -r metric format ref est opts; do
    [ -n "$metric" ] || continue
    i=$((i + 1))
    dir="$WORK/cases/$i"
    mkdir -p "$dir"
    printf '%s\n' "$metric $format $ref $est $opts" > "$dir/case.txt"
    # Files are in the data folder; a recording's topics are names.
    case "$format" in
        bag|bag2|mcap) read -r -a inputs <<< "$est" ;;
        *) inputs=("$DATA/$est") ;;
    esac
    # shellcheck disable=SC2086 # options are words
    "$VENV/bin/evo_$metric" "$format" "$DATA/$ref" "${inputs[@]}" $opts \
        --save_results "$dir/evo.zip" --no_warnings > "$dir/evo.log" 2>&1 \
        || { echo "evo failed on case $i ($metric $format $est $opts):"; cat "$dir/evo.log"; exit 1; }
    # shellcheck disable=SC2086
    ./target/release/vinebench score "$metric" "$format" "$DATA/$ref" "${inputs[@]}" $opts \
        --save_results "$dir/ours.zip" > "$dir/ours.log" 2> "$dir/ours.err" \
        || { echo "vinebench failed on case $i:"; cat "$dir/ours.err"; exit 1; }
done <<< "$CASES"

# tf lookups (evo needs ROS's tf2_py for them, so no evo numbers here): the robot's
# odom -> base_footprint transform, looked up through /tf, must equal its /odom topic
# exactly wherever the 0.1 s lookup grid meets an odometry stamp.
./target/release/vinebench score ape bag2 "$DATA/nav2_turtlebot.mcap" /odom /tf:odom.base_footprint \
    -r full --t_max_diff 0 --save_results "$WORK/tf.json" > /dev/null 2>&1
"$VENV/bin/python" - "$WORK/tf.json" <<'PY'
import json, sys
r = json.load(open(sys.argv[1]))
n, worst = len(r["np_arrays"]["error_array"]), r["stats"]["max"]
print(f"tf lookup /tf:odom.base_footprint vs /odom at {n} common stamps: largest full-transformation error {worst:.1e}")
if n < 100 or worst > 1e-12:
    sys.exit(1)
PY

"$VENV/bin/python" - "$WORK/cases" "$TOL" "$TABLE" <<'PY'
import json, sys, os
import numpy as np
from evo.tools import file_interface
root, tol, table = sys.argv[1], float(sys.argv[2]), sys.argv[3] == "--table"
names = ["rmse", "mean", "median", "std", "min", "max", "sse"]
bad, rows, worst_all = [], [], 0.0
for case in sorted(os.listdir(root), key=int):
    d = os.path.join(root, case)
    what = open(os.path.join(d, "case.txt")).read().strip()
    # Both result files read by evo itself (ours is written in evo's zip format).
    theirs = file_interface.load_res_file(os.path.join(d, "evo.zip"))
    mine = file_interface.load_res_file(os.path.join(d, "ours.zip"))
    evo_stats, evo_info, evo_err = theirs.stats, theirs.info, theirs.np_arrays["error_array"]
    ours = {"stats": mine.stats, "info": mine.info}
    err = mine.np_arrays["error_array"]
    if sorted(mine.np_arrays) != sorted(theirs.np_arrays):
        bad.append(f"{what}: arrays {sorted(mine.np_arrays)} vs evo {sorted(theirs.np_arrays)}")
    for k, v in theirs.np_arrays.items():
        if k != "error_array" and k in mine.np_arrays:
            m = mine.np_arrays[k]
            sc = max(float(np.max(np.abs(v))) if v.size else 0.0, 1e-300)
            if m.shape != v.shape or float(np.max(np.abs(m - v), initial=0.0)) / sc > tol:
                bad.append(f"{what}: array {k} differs")
    worst = 0.0
    if len(err) != len(evo_err):
        bad.append(f"{what}: {len(err)} errors, evo {len(evo_err)}")
        continue
    # Element by element: relative to the largest error (a value that is rounding noise
    # in evo, such as the 4e-25 of a pose aligned onto itself, is compared at that scale).
    scale = max(float(np.max(np.abs(evo_err))), 1e-300)
    elem = float(np.max(np.abs(err - evo_err))) / scale
    for k in names:
        a, b = ours["stats"][k], evo_stats[k]
        rel = abs(a - b) / max(abs(b), 1e-300)
        if abs(a - b) <= 1e-12 * scale:
            rel = min(rel, abs(a - b) / scale)
        worst = max(worst, rel)
        if rel > tol:
            bad.append(f"{what}: {k} vinebench {a!r} evo {b!r} (rel {rel:.1e})")
    for k in ("title", "label", "ref_name", "est_name"):
        if ours["info"][k] != evo_info[k]:
            bad.append(f"{what}: {k} {ours['info'][k]!r} vs evo {evo_info[k]!r}")
    if elem > tol:
        bad.append(f"{what}: error arrays differ by {elem:.1e} of the largest error")
    worst = max(worst, elem)
    worst_all = max(worst_all, worst)
    rows.append((what, len(err), evo_stats["rmse"], ours["stats"]["rmse"], worst))
if table:
    print("| command (evo_<metric> / vinebench score <metric>) | errors | evo rmse | vinebench rmse | worst rel. diff |")
    print("|---|---:|---:|---:|---:|")
    for what, n, e, o, w in rows:
        print(f"| `{what}` | {n} | {e:.9g} | {o:.9g} | {w:.1e} |")
print(f"{len(rows)} cases, every statistic and error within {tol:g} of evo's: worst {worst_all:.1e}"
      if not bad else "")
if bad:
    print("\n".join(bad))
    sys.exit(1)
PY
