"""The inference parity fixture for the Rust tracker (`tracking/src/preprocess.rs` and the
networks): frames, their crops, input tensors and ONNX Runtime outputs, all computed here.

`python -m likeness_train.fixtures --out training/.cache/tracking-fixture` writes

- `frames/frame_K.png`: synthetic people of a held-out seed (`FIXTURE_SEED`, used by no
  training, evaluation or calibration) rendered by the training renderer into canvases of
  several sizes (one portrait) at different positions and scales, composed by the training
  code's `compose_image` (background, blur, noise, JPEG). The frames are chosen so that the
  sampler's cases all occur: an upscaled crop (box filter k = 1), downscaled ones (k = 2 and
  k = 4) and crops that reach outside the canvas (edge repetition);
- `fixture.safetensors`, per frame K: `landmarks_K` [68, 2] f32 (true landmarks, canvas
  pixels), `crop_K` [4] f32 (x, y, w, h by `crop_for_landmarks` with the manifest's framing),
  `input_K` [1, 3, 128, 128] f32 (`sample_rect` of the PNG's pixels with the manifest's
  normalisation), and TrackNet's ONNX Runtime outputs for that input at batch 1: `w_K` [53],
  `euler_K` [3], `translation_K` [3], `gamma_K` [27]; plus ModelNet run once on the K inputs
  stacked in frame order ([K, 3, 128, 128]): `dS0` [1, 3, 128, 128], `dS` [1, 53, 3, 128,
  128], `dR0`, `dR` (its outputs as they are, batch axis kept). The frames are of different
  people: ModelNet's outputs are a parity reference, not a meaningful person;
- `fixture.json`: frame count, file names, canvas sizes, the framing, seed, normalisation,
  the sha256 of the model files and manifest, the ONNX Runtime version.

Deterministic: the same sources write the same bytes (one ONNX Runtime thread).
`fixture.json` is written last and removed first, so its presence means a complete fixture.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from .preprocess import CropFraming, crop_for_landmarks, sample_rect

# Held out: training used seed 1, evaluation 1000, the framing calibration 0, the clips 9001.
FIXTURE_SEED = 9002
LAYOUT_VERSION = 2  # 2: ModelNet's own inputs (model_input_K), TrackNet's at track_input_size
MODELS = Path(__file__).resolve().parents[2] / "assets" / "models"


@dataclass(frozen=True)
class FrameSpec:
    """One fixture frame: canvas size, where the face centre goes and how tall the face is
    (template face part, as SyntheticConfig.face_fill measures it), horizontal field of view."""

    width: int
    height: int
    centre: tuple[float, float]
    face_px: float
    fov_deg: float
    why: str


FRAMES = (
    FrameSpec(320, 256, (158.3, 131.7), 80.0, 50.0, "small face, crop inside the canvas and smaller than the input: upscaled, k = 1"),
    FrameSpec(640, 480, (402.6, 228.4), 300.0, 55.0, "large face: downscaled with k = 4"),
    FrameSpec(320, 256, (36.2, 196.9), 140.0, 50.0, "face near the bottom-left corner: the crop reaches outside the canvas, k = 2"),
    FrameSpec(640, 480, (251.1, 297.3), 185.0, 55.0, "medium face off-centre: k = 2"),
    FrameSpec(256, 320, (221.8, 52.5), 130.0, 45.0, "portrait canvas, face cut by the top-right corner: crop outside on two sides"),
)


def sha256(path: Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def write_png(path: Path, image: np.ndarray) -> None:
    """Lossless; zlib level 3 (a noisy 640 x 480 frame: 0.16 s and 450 kB, against 0.63 s
    and 400 kB at the default 6)."""
    from PIL import Image

    Image.fromarray(image).save(path, format="PNG", compress_level=3)


def one_key_metadata(key: str, value: dict) -> dict[str, str]:
    """safetensors metadata as one JSON string: the writer orders several keys at random (a
    hash map), which would make identical tensors different files."""
    return {key: json.dumps(value, sort_keys=True)}


def read_png(path: Path) -> np.ndarray:
    from PIL import Image

    with Image.open(path) as im:
        return np.asarray(im.convert("RGB"))


def check_out_dir(out: Path, ours) -> None:
    """`out` may be created (its parent must exist) or reused if everything in it is ours
    (`ours(name)` is true for each entry, e.g. a previous, possibly interrupted, run);
    anything else is refused rather than overwritten."""
    if not out.parent.is_dir():
        raise ValueError(f"{out}: the parent folder {out.parent} does not exist")
    if out.exists():
        if not out.is_dir():
            raise ValueError(f"{out} exists and is not a folder")
        foreign = sorted(p.name for p in out.iterdir() if not ours(p.name))
        if foreign:
            raise ValueError(f"{out} holds files this command did not write ({', '.join(foreign[:3])}): refusing to write into it")


def ort_session(path: Path):
    import onnxruntime as ort

    options = ort.SessionOptions()
    options.intra_op_num_threads = 1
    options.inter_op_num_threads = 1
    return ort.InferenceSession(str(path), options, providers=["CPUExecutionProvider"])


def make_frames(model, seed: int = FIXTURE_SEED, specs=FRAMES) -> list[dict]:
    """Renders and composes the fixture frames: per frame the uint8 image, the true 68
    landmarks (canvas pixels) and the camera."""
    from .scene import Camera, SceneRenderer, to_uint8
    from .synthetic import ComposeConfig, compose_image

    scene = SceneRenderer(model, seed)
    out = []
    for k, spec in enumerate(specs):
        rng = np.random.default_rng(np.random.SeedSequence([seed, 2, k]))
        person = scene.person(k)
        frame = scene.people.frame(rng)  # weights, pose and light of the training sampler
        camera = Camera.centred(spec.width, spec.height, spec.fov_deg)
        translation = scene.translation_for(frame.euler, camera, spec.centre, spec.face_px)
        r = scene.render(person, frame.weights[None], frame.euler[None], translation[None], frame.gamma[None], camera)
        image = to_uint8(compose_image(r.image[0], r.coverage[0], rng, ComposeConfig()))
        out.append({"image": image, "landmarks": r.landmarks[0].astype(np.float32), "camera": camera, "spec": spec})
    return out


def write_fixture(out: Path, seed: int = FIXTURE_SEED, models: Path = MODELS, model=None) -> dict:
    """Writes the fixture into `out` (see the module documentation); returns fixture.json."""
    from safetensors.numpy import save_file

    from .face import FaceModel

    check_out_dir(out, lambda name: name in ("frames", "fixture.safetensors", "fixture.json"))
    for name in ("manifest.json", "track_net.onnx", "model_net.onnx"):
        if not (models / name).is_file():
            raise FileNotFoundError(f"{models / name} is missing")
    manifest = json.loads((models / "manifest.json").read_text())
    framing = CropFraming.from_manifest(manifest)
    size = int(manifest.get("track_input_size", manifest["input_size"]))  # TrackNet's
    model_size = int(manifest["input_size"])  # ModelNet's
    mean, std = manifest["normalisation"]["mean"], manifest["normalisation"]["std"]
    model = model or FaceModel.load()
    out.mkdir(exist_ok=True)
    (out / "fixture.json").unlink(missing_ok=True)
    (out / "frames").mkdir(exist_ok=True)
    frames = make_frames(model, seed)
    track, model_net = ort_session(models / "track_net.onnx"), ort_session(models / "model_net.onnx")
    tensors: dict[str, np.ndarray] = {}
    inputs, per_frame = [], []
    for k, f in enumerate(frames):
        path = out / "frames" / f"frame_{k}.png"
        write_png(path, f["image"])
        image = read_png(path)  # what Rust will read
        assert np.array_equal(image, f["image"])
        rect = crop_for_landmarks(f["landmarks"], framing)
        x = sample_rect(image, rect, size, size, mean, std)
        w, euler, translation, gamma = track.run(None, {"images": x})
        model_x = x if model_size == size else sample_rect(image, rect, model_size, model_size, mean, std)
        tensors.update({f"landmarks_{k}": f["landmarks"], f"crop_{k}": rect.to_array(), f"input_{k}": x, f"model_input_{k}": model_x, f"w_{k}": w[0], f"euler_{k}": euler[0], f"translation_{k}": translation[0], f"gamma_{k}": gamma[0]})
        inputs.append(model_x[0])
        cam, spec = f["camera"], f["spec"]
        per_frame.append({
            "file": f"frames/{path.name}", "width": cam.width, "height": cam.height, "crop": [float(v) for v in rect.to_array()],
            "box_filter": list(rect.box_filter(size, size)), "crop_inside_canvas": rect.inside(cam.width, cam.height),
            "focal_px": cam.focal, "principal": [cam.cx, cam.cy], "what": spec.why,
        })
    dS0, dS, dR0, dR = model_net.run(None, {"images": np.stack(inputs)})
    tensors.update({"dS0": dS0, "dS": dS, "dR0": dR0, "dR": dR})
    tensors = {key: np.ascontiguousarray(v, dtype=np.float32) for key, v in tensors.items()}
    save_file(tensors, str(out / "fixture.safetensors"), metadata=one_key_metadata("fixture", {"layout_version": LAYOUT_VERSION, "seed": seed}))
    import onnxruntime

    info = {
        "layout_version": LAYOUT_VERSION,
        "frames": len(frames),
        "seed": seed,
        "files": [p["file"] for p in per_frame],
        "canvas_sizes": [[p["width"], p["height"]] for p in per_frame],
        "per_frame": per_frame,
        "framing": {"centre_offset": list(framing.centre_offset), "scale": framing.scale},
        "input_size": model_size,
        "track_input_size": size,
        "normalisation": {"mean": mean, "std": std},
        "tensors": {
            "per frame K": "landmarks_K [68,2], crop_K [4] (x, y, w, h), input_K [1,3,S,S] (S = track_input_size), model_input_K [1,3,M,M] (M = input_size), w_K [53], euler_K [3] (yaw, pitch, roll rad), translation_K [3] (cm, reference camera), gamma_K [27]: TrackNet at batch 1",
            "ModelNet": "dS0 [1,3,128,128], dS [1,53,3,128,128], dR0 [1,3,128,128], dR [1,53,3,128,128] for the K model_inputs stacked in frame order",
        },
        "models": {name: sha256(models / name) for name in ("track_net.onnx", "model_net.onnx", "manifest.json")},
        "onnxruntime": onnxruntime.__version__,
        "onnxruntime_threads": 1,
    }
    (out / "fixture.json").write_text(json.dumps(info, indent=2) + "\n")
    return info


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--out", type=Path, required=True, help="output folder (created; its parent must exist)")
    parser.add_argument("--seed", type=int, default=FIXTURE_SEED, help="synthetic people seed (not 1 or 1000: those are training and evaluation)")
    parser.add_argument("--models", type=Path, default=MODELS, help="folder of manifest.json, track_net.onnx, model_net.onnx")
    parser.add_argument("--threads", type=int, default=1, help="torch threads for rendering (one is faster: small tensor operations, spin-waiting)")
    args = parser.parse_args(argv)
    if args.seed in (1, 1000):
        parser.error(f"--seed {args.seed} is a training or evaluation seed; the fixture must be held out")
    if not (0 <= args.seed < 2**32):
        parser.error(f"--seed {args.seed}: must be within [0, 2^32)")
    if not (1 <= args.threads <= 64):
        parser.error(f"--threads {args.threads}: must be within [1, 64]")
    torch.set_num_threads(args.threads)
    t0 = time.perf_counter()
    try:
        info = write_fixture(args.out, args.seed, args.models)
    except (ValueError, FileNotFoundError) as e:
        parser.error(str(e))
    print(f"wrote {info['frames']} frames to {args.out} in {time.perf_counter() - t0:.1f} s")
    for p in info["per_frame"]:
        print(f"  {p['file']}: {p['width']}x{p['height']}, crop {[round(v, 1) for v in p['crop']]}, k = {p['box_filter']}, inside: {p['crop_inside_canvas']}")


if __name__ == "__main__":
    main()
