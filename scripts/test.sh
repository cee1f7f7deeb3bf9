#!/usr/bin/env bash
# Runs every test of the workspace, installing what the tests need first.
set -euo pipefail
cd "$(dirname "$0")/.."
scripts/setup.sh
export XDG_RUNTIME_DIR="${XDG_RUNTIME_DIR:-/tmp/likeness-xdg}"
cargo test --workspace --all-targets "$@"
# Doc tests are not part of --all-targets.
cargo test --workspace --doc
# The training code (Python): its venv and the Rust-exported fixture, then its tests,
# which include a smoke training, the ONNX export and the parity checks.
training/setup.sh
training/.venv/bin/python -m pytest training/tests -q
