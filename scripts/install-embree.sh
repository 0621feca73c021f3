#!/usr/bin/env bash
# Installs Embree 3 (Debian/Ubuntu `libembree-dev`: libembree3.so and embree3/rtcore.h) for
# the optional `embree` feature of vinebench-sim. Non-interactive and idempotent: does
# nothing when the package is already installed. Uses sudo when not run as root.
set -euo pipefail

pkg=libembree-dev

if dpkg-query -W -f='${Status}' "$pkg" 2>/dev/null | grep -q "install ok installed"; then
    echo "$pkg already installed ($(dpkg-query -W -f='${Version}' "$pkg"))"
    exit 0
fi

if ! command -v apt-get >/dev/null 2>&1; then
    echo "install-embree.sh: apt-get not found; install Embree 3 (libembree3 and its headers) by hand" >&2
    exit 1
fi

if [ "$(id -u)" -eq 0 ]; then
    sudo=()
elif command -v sudo >/dev/null 2>&1; then
    sudo=(sudo -n)
else
    echo "install-embree.sh: not root and sudo not found" >&2
    exit 1
fi

export DEBIAN_FRONTEND=noninteractive
# Refresh the package lists only when the package is unknown to apt (first run on a fresh
# machine); retry the install once after an update in case the lists are stale.
if ! apt-cache show "$pkg" >/dev/null 2>&1; then
    "${sudo[@]}" apt-get update -q
fi
if ! "${sudo[@]}" apt-get install -y -q --no-install-recommends "$pkg"; then
    "${sudo[@]}" apt-get update -q
    "${sudo[@]}" apt-get install -y -q --no-install-recommends "$pkg"
fi
echo "$pkg installed ($(dpkg-query -W -f='${Version}' "$pkg"))"
