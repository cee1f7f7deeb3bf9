#!/usr/bin/env bash
# Builds the studio for the browser into web/dist/ and serves it on http://127.0.0.1:PORT/.
#
#   scripts/web.sh [--port 8787] [--build-only] [--serve-only]
#
# The page fetches the template and the OpenSeeFace models from the served folder; they are
# linked (never copied into the repository) from LIKENESS_FACEMODEL (the template's
# safetensors file) and LIKENESS_MODELS (a folder with openseeface/), by default
# ../shared beside the repository. The networks and the demo puppet are the repository's
# assets/.
set -euo pipefail
cd "$(dirname "$0")/.."
root="$(pwd)"

port=8787
build=1
serve=1
while [ $# -gt 0 ]; do
  case "$1" in
    --port) port="$2"; shift 2 ;;
    --build-only) serve=0; shift ;;
    --serve-only) build=0; shift ;;
    *) echo "web.sh: unknown argument $1 (try --port N, --build-only, --serve-only)" >&2; exit 2 ;;
  esac
done

dist="$root/web/dist"
if [ "$build" -eq 1 ]; then
  scripts/setup.sh --web
  export PATH="$root/.cache/tools/bin:$PATH"
  cargo build --quiet -p likeness-web --target wasm32-unknown-unknown --release
  rm -rf "$dist"
  mkdir -p "$dist"
  # Without the function-name section (3.7 MB, 0.9 MB gzipped): panics still print their
  # message and source line; only stack traces lose Rust names.
  wasm-bindgen --target web --no-typescript --remove-name-section --remove-producers-section \
    --out-dir "$dist" \
    "$root/target/wasm32-unknown-unknown/release/likeness_web.wasm"
  cp web/index.html web/worker.js "$dist/"
  # Served by link: the project's own files from assets/, third-party data from where the
  # user keeps it.
  ln -s "$root/assets/models" "$dist/models"
  ln -s "$root/assets/puppets" "$dist/puppets"
  facemodel="${LIKENESS_FACEMODEL:-$root/../shared/facemodel/ict_face_model.safetensors}"
  models="${LIKENESS_MODELS:-$root/../shared/models}"
  if [ -f "$facemodel" ]; then
    mkdir -p "$dist/facemodel"
    ln -s "$(realpath "$facemodel")" "$dist/facemodel/ict_face_model.safetensors"
  else
    echo "web.sh: no template at $facemodel (set LIKENESS_FACEMODEL); the page will say what is missing" >&2
  fi
  if [ -d "$models/openseeface" ]; then
    ln -s "$(realpath "$models/openseeface")" "$dist/openseeface"
  else
    echo "web.sh: no OpenSeeFace models in $models/openseeface (set LIKENESS_MODELS); the page will say what is missing" >&2
  fi
  # Optional: MediaPipe's locator is offered when its folder is served.
  if [ -d "$models/mediapipe" ]; then
    ln -s "$(realpath "$models/mediapipe")" "$dist/mediapipe"
  else
    echo "web.sh: no MediaPipe models in $models/mediapipe; the page offers OpenSeeFace's locator only" >&2
  fi
  wasm="$dist/likeness_web_bg.wasm"
  echo "web.sh: built $dist ($(stat -c %s "$wasm") bytes of wasm, $(gzip -9 -c "$wasm" | wc -c) gzipped)"
fi

if [ "$serve" -eq 1 ]; then
  echo "web.sh: serving $dist on http://127.0.0.1:$port/ (Ctrl+C stops)"
  exec python3 "$root/web/serve.py" --port "$port" --directory "$dist"
fi
