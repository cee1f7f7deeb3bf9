#!/usr/bin/env bash
# Sets up the training environment; safe to run any number of times.
#   1. training/.venv with the pinned requirements (reinstalled only when requirements.txt
#      changes; a stamp in the venv records the last installed version);
#   2. training/.cache/face_fixture.safetensors, exported by the Rust `likeness` binary, if
#      it is missing or older than the Rust sources that define it (masks, F, R_0, T);
#   3. training/.cache/tracking-fixture (the Rust tracker's parity fixture,
#      `python -m likeness_train.fixtures`) and training/.cache/clips-s9001 (held-out clips,
#      `python -m likeness_train.clips`), if missing or older than what they are made of.
# Environment: PYTHON (default python3), LIKENESS_SKIP_TRITON=1 drops triton (CPU only),
# LIKENESS_FACEMODEL is honoured by both the Rust export and the Python loader.
set -euo pipefail

here="$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)"
root="$(dirname "$here")"
venv="$here/.venv"

if [ ! -x "$venv/bin/python" ]; then
    echo "setup: creating $venv"
    "${PYTHON:-python3}" -m venv "$venv"
fi

stamp="$venv/.likeness-requirements.sha256"
want="$(sha256sum "$here/requirements.txt" | cut -d' ' -f1)"
if [ "$(cat "$stamp" 2>/dev/null || true)" != "$want" ]; then
    echo "setup: installing requirements (torch is ~3 GB the first time)"
    "$venv/bin/python" -m pip install --disable-pip-version-check -q -r "$here/requirements.txt"
    if [ "${LIKENESS_SKIP_TRITON:-0}" = 1 ]; then
        "$venv/bin/python" -m pip uninstall -y -q triton || true
    fi
    echo "$want" > "$stamp"
fi

fixture="$here/.cache/face_fixture.safetensors"
stale=""
if [ ! -f "$fixture" ]; then
    stale="missing"
else
    # Anything that can change the exported tensors: the face crate, the exporter, the
    # lock file (dependency versions) and the template itself.
    newer="$(find "$root/face" "$root/app/src" "$root/Cargo.lock" \
        \( -name '*.rs' -o -name 'Cargo.toml' -o -name 'Cargo.lock' \) \
        -newer "$fixture" -print -quit 2>/dev/null || true)"
    template="${LIKENESS_FACEMODEL:-$root/../shared/facemodel/ict_face_model.safetensors}"
    if [ -z "$newer" ] && [ -f "$template" ] && [ "$template" -nt "$fixture" ]; then
        newer="$template"
    fi
    [ -n "$newer" ] && stale="older than $newer"
fi
if [ -n "$stale" ]; then
    echo "setup: exporting the face fixture ($stale)"
    (cd "$root" && cargo run -q -p likeness -- export-fixture --out training/.cache)
fi

# Generated data (3): each is complete once its index file exists (written last, removed
# first), and stale when any of its sources is newer than that file.
regenerate() {  # regenerate NAME INDEX_FILE COMMAND... (sources in the `sources` array)
    local name="$1" index="$2" why=""
    shift 2
    if [ ! -f "$index" ]; then
        why="missing"
    else
        local newer
        newer="$(find "${sources[@]}" -newer "$index" -print -quit 2>/dev/null || true)"
        [ -n "$newer" ] && why="older than $newer"
    fi
    if [ -n "$why" ]; then
        echo "setup: generating the $name ($why)"
        (cd "$here" && "$@")
    fi
}
pkg="$here/likeness_train"
render_sources=("$pkg/scene.py" "$pkg/synthetic.py" "$pkg/render.py" "$pkg/face.py" "$pkg/data.py" "$fixture")
sources=("$pkg/preprocess.py" "$pkg/fixtures.py" "${render_sources[@]}" "$root/assets/models")
regenerate "tracking fixture" "$here/.cache/tracking-fixture/fixture.json" \
    "$venv/bin/python" -m likeness_train.fixtures --out .cache/tracking-fixture
sources=("$pkg/clips.py" "$pkg/fixtures.py" "${render_sources[@]}")
regenerate "held-out clips" "$here/.cache/clips-s9001/clips.json" \
    "$venv/bin/python" -m likeness_train.clips --out .cache/clips-s9001 --seed 9001

"$venv/bin/python" -c "import torch, numba, safetensors, onnxruntime" \
    && echo "setup: ok ($venv, $fixture)"
