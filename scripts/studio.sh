#!/usr/bin/env bash
# Runs the studio on its built-in demo. Without a display it writes the same views to
# likeness-demo/ (or the folder given with --out).
set -euo pipefail
cd "$(dirname "$0")/.."
scripts/setup.sh
export XDG_RUNTIME_DIR="${XDG_RUNTIME_DIR:-/tmp/likeness-xdg}"
exec cargo run --quiet -p likeness -- studio "$@"
