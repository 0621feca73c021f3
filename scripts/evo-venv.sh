# Sourced (from the repository root) by the scripts that check vinebench against evo and
# rosbags: creates, or keeps, the private virtual environment target/evo-venv with evo
# pinned from PyPI (rosbags, with rosbags-convert, comes with it). Sets EVO_VERSION and VENV.
EVO_VERSION="1.38.1"
VENV="target/evo-venv"
if ! "$VENV/bin/python" -c "import evo, rosbags, sys; sys.exit(evo.__version__.lstrip('v') != '$EVO_VERSION')" 2>/dev/null; then
    python3 -m venv "$VENV"
    "$VENV/bin/pip" install --quiet --disable-pip-version-check "evo==$EVO_VERSION"
fi
