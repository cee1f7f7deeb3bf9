#!/usr/bin/env bash
# Runs every test of the workspace, installing what the tests need first.
set -euo pipefail
cd "$(dirname "$0")/.."
scripts/setup.sh --web
export XDG_RUNTIME_DIR="${XDG_RUNTIME_DIR:-/tmp/likeness-xdg}"
# The training code's venv, the Rust-exported face fixture, and what the Rust tracking
# tests compare against: the parity fixture and the held-out synthetic clips it renders.
training/setup.sh
cargo test --workspace --all-targets "$@"
# Doc tests are not part of --all-targets.
cargo test --workspace --doc
# The training code (Python): a smoke training, the ONNX export and the parity checks.
training/.venv/bin/python -m pytest training/tests -q
# The browser build end to end: built into web/dist, served on 127.0.0.1, driven in
# headless Chromium (WebGL2 on SwiftShader); prints the browser budgets.
scripts/web.sh --build-only
node web/tests/e2e.mjs
