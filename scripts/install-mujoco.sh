#!/usr/bin/env bash
# Installs the MuJoCo 3.17.0 shared library for the optional `mujoco` feature (mujoco-rs
# 7.0.0 binds exactly this version). No system package ships it (Debian has only 2.2), so
# it is taken from the PyPI wheel `mujoco==3.17.0`, checked against a pinned sha256, and
# `mujoco/libmujoco.so.3.17.0` is extracted to `<repo>/.mujoco/lib/` with the link
# `libmujoco.so` beside it. `.cargo/config.toml` points MUJOCO_DYNAMIC_LINK_DIR there, and
# the build scripts of `vinebench` and `vinebench-sim` add it as an rpath, so binaries and
# tests run without LD_LIBRARY_PATH. Idempotent; needs python3 with pip (PyPI reachable).
set -euo pipefail

version=3.17.0
wheel=mujoco-3.17.0-cp311-cp311-manylinux_2_27_x86_64.manylinux_2_28_x86_64.whl
sha256=d66928d86a2d1b601bbaa4dc11db50214d17d5301bb8afd84721313b67ff0874

root="$(cd "$(dirname "$0")/.." && pwd)"
lib_dir="$root/.mujoco/lib"
so="$lib_dir/libmujoco.so.$version"

if [ -f "$so" ] && [ -L "$lib_dir/libmujoco.so" ]; then
    echo "MuJoCo $version already installed in $lib_dir"
    exit 0
fi

if [ "$(uname -m)" != "x86_64" ]; then
    echo "install-mujoco.sh: only x86_64 Linux is scripted (found $(uname -m)); put libmujoco.so $version in $lib_dir by hand" >&2
    exit 1
fi

tmp="$(mktemp -d)"
trap 'rm -rf "$tmp"' EXIT
python3 -m pip download --quiet --no-deps --only-binary=:all: \
    --platform manylinux_2_28_x86_64 --python-version 3.11 --implementation cp \
    --dest "$tmp" "mujoco==$version"
if [ ! -f "$tmp/$wheel" ]; then
    echo "install-mujoco.sh: pip did not fetch $wheel; got: $(ls "$tmp")" >&2
    exit 1
fi
echo "$sha256  $tmp/$wheel" | sha256sum --check --quiet - || {
    echo "install-mujoco.sh: sha256 of $wheel is not the pinned $sha256" >&2
    exit 1
}
python3 - "$tmp/$wheel" "$tmp" <<'PY'
import sys, zipfile
with zipfile.ZipFile(sys.argv[1]) as z:
    z.extract("mujoco/libmujoco.so.3.17.0", sys.argv[2])
PY
mkdir -p "$lib_dir"
mv "$tmp/mujoco/libmujoco.so.$version" "$so"
ln -sf "libmujoco.so.$version" "$lib_dir/libmujoco.so"
echo "MuJoCo $version installed in $lib_dir"
