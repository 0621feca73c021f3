#!/usr/bin/env bash
# A robot's ROS 1 bag, and a rosbag2 folder with sqlite3 storage, replay like the MCAP they
# were converted from: a short simulated run's recording.mcap is converted by rosbags (an
# independent implementation, `rosbags-convert`) to ROS 1 bags (chunks uncompressed, bz2
# and lz4) and to a rosbag2 .db3 folder; `vinebench replay` of each must give
# byte-identical estimates to the replay of the MCAP with the same topic mapping, and
# `vinebench score ape bag|bag2` the same numbers as on the MCAP.
#
#   bash scripts/ros1_bag_check.sh        # uses/creates target/evo-venv (evo brings rosbags)
set -euo pipefail
cd "$(dirname "$0")/.."

WORK="target/ros1-bag-check"
cargo build --release --locked --bin vinebench
source scripts/evo-venv.sh
B=./target/release/vinebench
rm -rf "$WORK"
mkdir -p "$WORK"
$B run tests/data/short-loop.toml --quiet --out "$WORK/run" || test $? -eq 1
cat > "$WORK/map.toml" <<'TOML'
name = "ros1-bag-check"
body_frame = "base_link"
[topics]
imu = "/imu/data"
gnss_fix = "/gnss/fix"
gnss_velocity = "/gnss/fix_velocity"
tracking_odom = "/tracking_camera/odom/sample"
ground_truth = "/ground_truth/odom"
[estimators]
run = ["eif", "gnss", "tracking_camera"]
TOML
$B replay "$WORK/run/recording.mcap" --config "$WORK/map.toml" --out "$WORK/from-mcap" > /dev/null
mcap_score=$($B score ape bag2 "$WORK/run/recording.mcap" /ground_truth/odom /estimate/eif/odom -a 2> /dev/null)

# same_as_mcap RECORDING FORMAT NAME: replay and score of RECORDING equal the MCAP's.
same_as_mcap() {
    $B replay "$1" --config "$WORK/map.toml" --out "$WORK/from-$3" > /dev/null
    for f in estimate_eif.tum estimate_gnss.tum estimate_tracking_camera.tum ground_truth.tum; do
        cmp "$WORK/from-mcap/$f" "$WORK/from-$3/$f"
    done
    [ "$($B score ape "$2" "$1" /ground_truth/odom /estimate/eif/odom -a 2> /dev/null)" = "$mcap_score" ]
}

for compress in none bz2 lz4; do
    bag="$WORK/run-$compress.bag"
    "$VENV/bin/rosbags-convert" --src "$WORK/run/recording.mcap" --dst "$bag" --compress "$compress" > /dev/null
    same_as_mcap "$bag" bag "$compress"
    echo "ROS 1 bag ($compress chunks, written by rosbags): replay and score equal the MCAP's"
done
db3="$WORK/run-db3"
"$VENV/bin/rosbags-convert" --src "$WORK/run/recording.mcap" --dst "$db3" --dst-storage sqlite3 > /dev/null
same_as_mcap "$db3" bag2 db3
echo "rosbag2 folder (sqlite3 storage, written by rosbags): replay and score equal the MCAP's"
