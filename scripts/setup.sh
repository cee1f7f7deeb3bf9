#!/usr/bin/env bash
# Installs what building, running and testing Likeness needs on Debian 12 (run as root, or
# with sudo available). Idempotent: installs only what is missing.
set -euo pipefail

# --web: also what the browser build and its test need (wasm-bindgen, Chromium,
# playwright-core); scripts/test.sh and scripts/web.sh ask for it, the studio does not.
web=0
[ "${1:-}" = "--web" ] && web=1

need=()
# Mesa's lavapipe: the Vulkan driver headless rendering and the screenshot tests run on;
# Xvfb: the display the software-window test opens its window on.
for pkg in mesa-vulkan-drivers libvulkan1 \
           xvfb libx11-6 libxkbcommon0 libxkbcommon-x11-0 libxcursor1 libxrandr2 libxi6 libwayland-client0 libegl1; do
  dpkg-query -W -f='${Status}' "$pkg" 2>/dev/null | grep -q "install ok installed" || need+=("$pkg")
done
# The training tests make a Python venv; Debian's own python3 needs python3-venv for that.
if ! python3 -c "import ensurepip, venv" >/dev/null 2>&1; then
  need+=(python3-venv python3-pip)
fi
# pip fetches the ONNX Runtime wheel below (Debian's python3 ships without it).
python3 -m pip --version >/dev/null 2>&1 || need+=(python3-pip)
# ffmpeg decodes video files and webcams for `likeness track` / `personalize`.
command -v ffmpeg >/dev/null 2>&1 || need+=(ffmpeg)
# The browser build's end-to-end test runs Debian's Chromium (headless, WebGL2 on SwiftShader).
if [ "$web" -eq 1 ]; then
  command -v chromium >/dev/null 2>&1 || need+=(chromium)
fi
# Node runs the Khronos glTF validator in retarget's tests (npm package gltf-validator).
command -v node >/dev/null 2>&1 || need+=(nodejs)
command -v npm >/dev/null 2>&1 || need+=(npm)
if [ "${#need[@]}" -gt 0 ]; then
  echo "setup: installing ${need[*]}"
  SUDO=""
  [ "$(id -u)" -eq 0 ] || SUDO="sudo"
  $SUDO apt-get update -qq
  DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq --no-install-recommends "${need[@]}" >/dev/null
fi

if command -v rustup >/dev/null 2>&1; then
  rustup component list --installed | grep -q '^clippy' || rustup component add clippy
  rustup component list --installed | grep -q '^rustfmt' || rustup component add rustfmt
  rustup target list --installed | grep -q '^wasm32-unknown-unknown$' || rustup target add wasm32-unknown-unknown
fi

# wgpu warns without a private runtime folder on headless machines.
if [ -z "${XDG_RUNTIME_DIR:-}" ]; then
  mkdir -p -m 700 /tmp/likeness-xdg
fi

# The Khronos glTF validator, pinned in tools/gltf-validator/package.json (from npm).
validator_dir="$(cd "$(dirname "$0")/.." && pwd)/tools/gltf-validator"
if [ ! -d "$validator_dir/node_modules/gltf-validator" ]; then
  echo "setup: installing the Khronos glTF validator (npm)"
  npm install --prefix "$validator_dir" --no-audit --no-fund --silent >/dev/null
fi

# ONNX Runtime for the `tracking` crate (loaded at run time through `ort`, whose build-time
# download cannot reach its server): the library from the PyPI wheel of the version `ort`
# wraps, unpacked to .cache/onnxruntime/. Override with ORT_DYLIB_PATH.
ort_version=1.31.1
ort_dir="$(cd "$(dirname "$0")/.." && pwd)/.cache/onnxruntime"
if [ ! -f "$ort_dir/libonnxruntime.so.$ort_version" ]; then
  echo "setup: fetching ONNX Runtime $ort_version (PyPI wheel)"
  mkdir -p "$ort_dir/wheel"
  python3 -m pip download --disable-pip-version-check -q --no-deps \
    --only-binary=:all: "onnxruntime==$ort_version" -d "$ort_dir/wheel" >/dev/null
  python3 - "$ort_dir" "$ort_version" <<'PY'
import pathlib, shutil, sys, zipfile
out, version = pathlib.Path(sys.argv[1]), sys.argv[2]
wheel = next((out / "wheel").glob(f"onnxruntime-{version}-*.whl"))
name = f"libonnxruntime.so.{version}"
with zipfile.ZipFile(wheel) as z:
    member = next(m for m in z.namelist() if m.endswith("/capi/" + name))
    tmp = out / (name + ".tmp")
    with z.open(member) as src, open(tmp, "wb") as dst:
        shutil.copyfileobj(src, dst)
    tmp.replace(out / name)
shutil.rmtree(out / "wheel")
PY
fi

# MediaPipe's own Face Mesh (PyPI, with scikit-image's public-domain test photographs) for
# the tracking crate's reference-parity test, in a venv of its own: its pins are not the
# training venv's. Reinstalled when tracking/tests/reference/requirements.txt changes.
# A venv moved here keeps its old paths inside, so it is made where it stays.
root_dir="$(cd "$(dirname "$0")/.." && pwd)"
mp_venv="$root_dir/.cache/mediapipe-venv"
mp_requirements="$root_dir/tracking/tests/reference/requirements.txt"
mp_want="$(sha256sum "$mp_requirements" | cut -d' ' -f1)"
if [ "$(cat "$mp_venv/.likeness-requirements.sha256" 2>/dev/null || true)" != "$mp_want" ]; then
  echo "setup: installing MediaPipe's reference Face Mesh (PyPI) into $mp_venv"
  [ -x "$mp_venv/bin/python" ] || python3 -m venv "$mp_venv"
  "$mp_venv/bin/python" -m pip install --disable-pip-version-check -q -r "$mp_requirements"
  echo "$mp_want" > "$mp_venv/.likeness-requirements.sha256"
fi

if [ "$web" -eq 0 ]; then
  exit 0
fi

# The browser build: wasm-bindgen's CLI at exactly the version of the wasm-bindgen crate in
# Cargo.lock (their formats must match), built from crates.io into .cache/tools/.
wbg_version="$(awk '/^name = "wasm-bindgen"$/ { getline; gsub(/version = |"/, ""); print; exit }' \
  "$(cd "$(dirname "$0")/.." && pwd)/Cargo.lock")"
tools_dir="$(cd "$(dirname "$0")/.." && pwd)/.cache/tools"
if ! "$tools_dir/bin/wasm-bindgen" --version 2>/dev/null | grep -qx "wasm-bindgen $wbg_version"; then
  echo "setup: building wasm-bindgen-cli $wbg_version (crates.io)"
  # Not --locked: one of its locked dependency versions is no longer on the registry.
  cargo install --quiet wasm-bindgen-cli --version "$wbg_version" --root "$tools_dir"
fi

# Playwright's library (no browser download) drives Chromium in the browser test; pinned in
# web/package.json.
web_dir="$(cd "$(dirname "$0")/.." && pwd)/web"
if [ ! -d "$web_dir/node_modules/playwright-core" ]; then
  echo "setup: installing playwright-core (npm)"
  npm install --prefix "$web_dir" --no-audit --no-fund --silent >/dev/null
fi
