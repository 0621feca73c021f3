#!/usr/bin/env python3
"""Decode every message of MCAP recordings with the independent ROS 2 reader.

Usage: python3 scripts/mcap_check.py runs/x/recording.mcap [more.mcap ...]

Uses the `mcap` and `mcap-ros2-support` packages (pip install mcap mcap-ros2-support),
which build their CDR decoders from the ros2msg schemas stored in the file, as Foxglove
does. Fails (exit 1) if a file is not profile ros2, has no summary, a message does not
decode, or a decoded field disagrees with what vinebench promises (NavSatFix status and
covariance filled, no fix with covariance type UNKNOWN, GPSFix satellite lists and status
consistent, /tf_static non-empty, ground truth present).
"""
import math
import sys

from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory


def check(path):
    problems = []
    counts = {}
    with open(path, "rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        header = reader.get_header()
        if header.profile != "ros2":
            problems.append(f"profile {header.profile!r}, expected 'ros2'")
        summary = reader.get_summary()
        if summary is None or summary.statistics is None:
            problems.append("no summary section")
        for schema, channel, message, decoded in reader.iter_decoded_messages():
            counts[channel.topic] = counts.get(channel.topic, 0) + 1
            if message.log_time != decoded_stamp(decoded, message.log_time):
                problems.append(f"{channel.topic}: log time != header stamp")
            if schema.name == "sensor_msgs/msg/NavSatFix":
                if decoded.status.status >= 0 and decoded.position_covariance_type != 3:
                    problems.append(f"{channel.topic}: covariance type {decoded.position_covariance_type}")
                if decoded.status.status >= 0 and not all(
                    math.isfinite(c) for c in decoded.position_covariance
                ):
                    problems.append(f"{channel.topic}: covariance not filled")
            if schema.name == "sensor_msgs/msg/NavSatFix" and decoded.status.status < 0:
                if decoded.position_covariance_type != 0:
                    problems.append(f"{channel.topic}: no fix with a known covariance")
            if schema.name == "gps_msgs/msg/GPSFix":
                st = decoded.status
                if st.satellites_used != len(st.satellite_used_prn):
                    problems.append(f"{channel.topic}: satellites_used != its PRN list")
                lists = (st.satellite_visible_prn, st.satellite_visible_z,
                         st.satellite_visible_azimuth, st.satellite_visible_snr)
                if st.satellites_visible != len(st.satellite_visible_prn) or len(
                    {len(x) for x in lists}
                ) != 1:
                    problems.append(f"{channel.topic}: visible satellite lists disagree")
                if not set(st.satellite_used_prn) <= set(st.satellite_visible_prn):
                    problems.append(f"{channel.topic}: a used satellite is not visible")
                if st.status not in (-1, 0, 19, 20):
                    problems.append(f"{channel.topic}: status {st.status}")
                if st.status >= 0 and not (0 < decoded.hdop < 50 and decoded.position_covariance_type == 3):
                    problems.append(f"{channel.topic}: a fix without its DOP or covariance")
            if schema.name == "tf2_msgs/msg/TFMessage" and not decoded.transforms:
                problems.append(f"{channel.topic}: empty TFMessage")
        if summary is not None and summary.statistics is not None:
            total = sum(counts.values())
            if total != summary.statistics.message_count:
                problems.append(
                    f"decoded {total} messages, summary says {summary.statistics.message_count}"
                )
    for required in ("/tf_static", "/ground_truth/odom", "/imu/data", "/gnss/fix"):
        if required not in counts:
            problems.append(f"no {required} messages")
    summary_line = ", ".join(f"{t} {n}" for t, n in sorted(counts.items()))
    return problems, summary_line


def decoded_stamp(decoded, default):
    header = getattr(decoded, "header", None)
    if header is None:
        return default
    return header.stamp.sec * 1_000_000_000 + header.stamp.nanosec


def main(paths):
    if not paths:
        print(__doc__, file=sys.stderr)
        return 2
    bad = False
    for p in paths:
        problems, line = check(p)
        if problems:
            bad = True
            print(f"FAIL {p}:", file=sys.stderr)
            for x in problems[:20]:
                print(f"  {x}", file=sys.stderr)
        else:
            print(f"ok {p}: {line}")
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
