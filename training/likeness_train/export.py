"""ONNX export of TrackNet and ModelNet, with the manifest the Rust inference reads.

`python -m likeness_train.export --checkpoint CKPT --out assets/models [--metrics
results.json]` writes `track_net.onnx` ([B,3,H,W] -> w, euler, translation, gamma),
`model_net.onnx` ([N,3,H,W] -> dS0, dS, dR0, dR for one person), `mean_albedo.safetensors`
(the trained R_0^t of equation (3), float16 [3,512,512] under `mean_albedo_face`: inference
must add dR_0 and dR_i to this, not to the procedural R_0 it started from) and
`manifest.json`. It checks ONNX Runtime against PyTorch and prints the batch-1 ONNX
Runtime latency of each model with 1 and 2 threads (median of 30 runs after 5 warm-ups).
Weights are stored as float16 (the arithmetic stays float32; `store_weights_fp16`) unless
`--fp32-weights`; the manifest records what the rounding changed.
`--model-net-from DIR` exports TrackNet alone and keeps DIR's ModelNet and R_0^t (a
landmark warm-up trains TrackNet only; a float32 ModelNet is stored as float16 unless
`--fp32-weights`); the manifest records where they came from.
The manifest's `crop` (where inference puts the square crop around the landmarks,
preprocess.py) is kept from the manifest it replaces or the committed one when calibrated
on the same synthetic distribution, and measured again otherwise or with `--recalibrate-crop`.
"""

from __future__ import annotations

import argparse
import json
import statistics
import subprocess
import time
import warnings
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np
import torch
from torch import nn

from .networks import CalibratedTrackNet, ModelNet, TrackNet, calibration_summary, load_networks

# Input normalisation shared by training and inference: RGB in [0, 1], then (x - mean) / std.
IMAGE_MEAN = (0.5, 0.5, 0.5)
IMAGE_STD = (0.5, 0.5, 0.5)


@dataclass
class Manifest:
    # ModelNet's square input in pixels (and, for manifests written before
    # `track_input_size`, TrackNet's too).
    input_size: int
    # TrackNet's square input in pixels: both networks read the same crop rectangle,
    # each sampled at its own size (a 160 px TrackNet beside a 128 px ModelNet, issue 31).
    track_input_size: int
    track_width: float
    model_width: float
    blendshape_names: list[str]
    uv_size: int = 128
    normalisation: dict = field(default_factory=lambda: {"mean": list(IMAGE_MEAN), "std": list(IMAGE_STD), "range": "RGB in [0, 1] before normalising"})
    outputs: dict = field(
        default_factory=lambda: {
            "track_net": {"w": "[B,53] sigmoid", "euler": "[B,3] yaw, pitch, roll radians", "translation": "[B,3] cm, camera space", "gamma": "[B,27] SH r0..r8 g0..g8 b0..b8"},
            "model_net": {"dS0": "[1,3,128,128] cm", "dS": "[1,53,3,128,128] cm", "dR0": "[1,3,128,128]", "dR": "[1,53,3,128,128]"},
        }
    )
    camera: dict = field(default_factory=dict)
    # The TrackNet the browser runs (`web_track_net`): its file and input size.
    web_track_net: dict = field(default_factory=dict)
    # Where the crop goes around the landmarks (preprocess.py; measured on the training
    # distribution, so it depends on the synthetic camera, not on the checkpoint).
    crop: dict = field(default_factory=dict)
    mean_albedo: dict = field(
        default_factory=lambda: {"file": "mean_albedo.safetensors", "tensor": "mean_albedo_face", "shape": [3, 512, 512], "dtype": "float16", "what": "trained R_0^t (face layer, row 0 at v = 1)"}
    )
    training_commit: str = ""
    training: dict = field(default_factory=dict)
    parity_max_abs_diff: dict = field(default_factory=dict)
    # Per network and output, what storing the weights as float16 changed (None: float32
    # weights, `--fp32-weights`); parity_max_abs_diff is measured before, on float32 files.
    fp16_storage_max_abs_diff: dict | None = None
    latency_ms: dict = field(default_factory=dict)
    metrics: dict = field(default_factory=dict)


def camera_assumptions() -> dict:
    """What the training images assumed about the camera, so inference can build the same
    intrinsics for a crop. TrackNet's translation is for the reference field of view: for a
    camera of focal f pixels at the input size, scale its z by f / reference_focal_px
    (train.camera_translation)."""
    from .synthetic import SyntheticConfig
    from .train import REFERENCE_FOV_DEG

    c = SyntheticConfig()
    lo, hi = c.fov_deg_range
    return {
        "fov_deg_range": [lo, hi],
        "nominal_fov_deg": 0.5 * (lo + hi),
        "translation_reference_fov_deg": REFERENCE_FOV_DEG,
        "translation_for_focal_f": "t_z * f / reference_focal_px, t_x and t_y unchanged; reference_focal_px = 0.5 * input_size / tan(fov / 2)",
        "principal_point": "crop centre (training jitter 1% of the size)",
        "face_fill": c.face_fill,
        "units": "translation in cm, camera looks down -z (OpenGL convention)",
    }


# The committed manifest: a source of the crop framing for exports elsewhere (tests, probes).
REPOSITORY_MANIFEST = Path(__file__).resolve().parents[2] / "assets" / "models" / "manifest.json"


def crop_framing(previous_manifests: list[Path], input_size: int, recalibrate: bool = False) -> dict:
    """The manifest's `crop` key: taken from the first of `previous_manifests` (the one
    being replaced, the committed one) calibrated on the same synthetic distribution (its
    `calibrated_on` says so), otherwise measured again (`preprocess.calibrate`, 2,000
    frames, ~1-2 min). The framing depends on the synthetic cameras, not on the checkpoint."""
    from .preprocess import calibrate, calibration_description

    want = calibration_description(image_size=input_size)
    for path in [] if recalibrate else previous_manifests:
        if path.is_file():
            old = json.loads(path.read_text()).get("crop")
            if old and old.get("calibrated_on") == want:
                return old
    print("calibrating the crop framing on synthetic training frames", flush=True)
    return calibrate(image_size=input_size).manifest_entry()


class _TrackWrapper(nn.Module):
    def __init__(self, net: TrackNet):
        super().__init__()
        self.net = net

    def forward(self, images):
        p = self.net(images)
        return p.w, p.euler, p.translation, p.gamma


class _ModelWrapper(nn.Module):
    """One person: [N,3,H,W] -> corrections with a leading person axis of 1."""

    def __init__(self, net: ModelNet):
        super().__init__()
        self.net = net

    def forward(self, images):
        c = self.net(images.unsqueeze(0))
        return c.dS0, c.dS, c.dR0, c.dR


def git_commit() -> str:
    try:
        return subprocess.run(["git", "rev-parse", "HEAD"], capture_output=True, text=True, check=True).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        return "unknown"


def export_onnx(track: TrackNet | CalibratedTrackNet, model: ModelNet | None, input_size: int, out_dir: Path, model_input_size: int | None = None) -> tuple[Path, Path]:
    """Writes track_net.onnx (for `input_size` px crops) and, unless `model` is None
    (ModelNet kept as it is), model_net.onnx (for `model_input_size` px, default the same);
    returns both paths."""
    model_input_size = model_input_size or input_size
    out_dir.mkdir(parents=True, exist_ok=True)
    track_path, model_path = out_dir / "track_net.onnx", out_dir / "model_net.onnx"
    track.eval()
    if model is not None:
        model.eval()
    with warnings.catch_warnings():
        # The legacy exporter writes one self-contained opset-17 file (no .onnx.data beside
        # it) and warns that it is deprecated; see docs/training.md.
        warnings.simplefilter("ignore")
        torch.onnx.export(
            _TrackWrapper(track),
            (torch.zeros(1, 3, input_size, input_size),),
            str(track_path),
            input_names=["images"],
            output_names=["w", "euler", "translation", "gamma"],
            dynamic_axes={"images": {0: "batch"}, "w": {0: "batch"}, "euler": {0: "batch"}, "translation": {0: "batch"}, "gamma": {0: "batch"}},
            opset_version=17,
            dynamo=False,
        )
        if model is None:
            return track_path, model_path
        torch.onnx.export(
            _ModelWrapper(model),
            (torch.zeros(4, 3, model_input_size, model_input_size),),
            str(model_path),
            input_names=["images"],
            output_names=["dS0", "dS", "dR0", "dR"],
            dynamic_axes={"images": {0: "frames"}},
            opset_version=17,
            dynamo=False,
        )
    return track_path, model_path


# Initializers at least this large are stored as float16 (`store_weights_fp16`); the small
# ones (biases, the w calibration's coefficients) stay float32, they weigh nothing.
FP16_MIN_ELEMENTS = 1024


def store_weights_fp16(path: Path, min_elements: int = FP16_MIN_ELEMENTS) -> int:
    """Rewrites the ONNX file at `path` with every float32 initializer of at least
    `min_elements` values stored as float16 and a Cast back to float32 in front of its
    users: the file is half the size (what a browser downloads) and the arithmetic stays
    float32, since ONNX Runtime and tract fold the Casts of constants when they load the
    model. Returns how many initializers were converted.

    Written here rather than with onnxconverter-common's `convert_float_to_float16`: that
    converts the computation to float16 too (slow on CPUs without float16 arithmetic, and
    tract's float16 kernels differ from ONNX Runtime's), and it is not otherwise a
    dependency."""
    import onnx
    from onnx import TensorProto, helper, numpy_helper

    model = onnx.load(str(path))
    graph = model.graph
    casts, kept = [], []
    for init in graph.initializer:
        values = numpy_helper.to_array(init)
        if init.data_type != TensorProto.FLOAT or values.size < min_elements:
            kept.append(init)
            continue
        stored = f"{init.name}__fp16"
        kept.append(numpy_helper.from_array(values.astype(np.float16), stored))
        casts.append(helper.make_node("Cast", [stored], [init.name], name=f"{init.name}__to_fp32", to=TensorProto.FLOAT))
    if not casts:
        return 0
    del graph.initializer[:]
    graph.initializer.extend(kept)
    nodes = casts + list(graph.node)
    del graph.node[:]
    graph.node.extend(nodes)
    onnx.checker.check_model(model)
    tmp = path.with_suffix(".fp16.tmp")
    onnx.save(model, str(tmp))
    tmp.replace(path)
    return len(casts)


def onnx_outputs_max_abs_diff(a: Path, b: Path, input_size: int, batch: int, seed: int = 0) -> dict[str, float]:
    """Max abs difference of each output between two ONNX files of the same network (ONNX
    Runtime, the same random images in [-1, 1])."""
    import onnxruntime as ort

    images = (np.random.default_rng(seed).random((batch, 3, input_size, input_size), dtype=np.float32) * 2 - 1).astype(np.float32)
    sessions = [ort.InferenceSession(str(p), providers=["CPUExecutionProvider"]) for p in (a, b)]
    names = [o.name for o in sessions[0].get_outputs()]
    outputs = [s.run(names, {"images": images}) for s in sessions]
    return {n: float(np.abs(x - y).max()) for n, x, y in zip(names, *outputs)}


def to_fp16_storage(path: Path, input_size: int, batch: int) -> dict[str, float]:
    """`store_weights_fp16` on an exported file, returning what the rounding of the stored
    weights changed in each output (against the float32 file it replaces); refused when w
    moves by more than `FP16_W_TOLERANCE`."""
    import shutil

    reference = path.with_suffix(".fp32.tmp")
    shutil.copyfile(path, reference)
    try:
        store_weights_fp16(path)
        diffs = onnx_outputs_max_abs_diff(reference, path, input_size, batch)
    finally:
        reference.unlink(missing_ok=True)
    if diffs.get("w", 0.0) > FP16_W_TOLERANCE:
        raise SystemExit(f"{path}: float16 weights move w by {diffs['w']:.4f} (> {FP16_W_TOLERANCE}); export with --fp32-weights")
    return diffs


# How far float16 weights may move a blendshape weight (of [0, 1]): a tenth of the smallest
# MAE difference any table in training/README.md reports.
FP16_W_TOLERANCE = 2e-3


def parity(track: TrackNet | CalibratedTrackNet, model: ModelNet | None, track_path: Path, model_path: Path, input_size: int, seed: int = 0, model_input_size: int | None = None) -> dict:
    """Max abs difference between PyTorch and ONNX Runtime on random inputs (TrackNet only
    when `model` is None; ModelNet's at `model_input_size`, default TrackNet's)."""
    import onnxruntime as ort

    g = torch.Generator().manual_seed(seed)
    images = torch.rand(3, 3, input_size, input_size, generator=g) * 2 - 1
    model_images = images if not model_input_size or model_input_size == input_size else torch.rand(3, 3, model_input_size, model_input_size, generator=g) * 2 - 1
    result = {}
    with torch.no_grad():
        ref_track = [t.numpy() for t in _TrackWrapper(track.eval())(images)]
        ref_model = None if model is None else [t.numpy() for t in _ModelWrapper(model.eval())(model_images)]
    for name, path, ref, x in (("track_net", track_path, ref_track, images), ("model_net", model_path, ref_model, model_images)):
        if ref is None:
            continue
        session = ort.InferenceSession(str(path), providers=["CPUExecutionProvider"])
        got = session.run(None, {"images": x.numpy()})
        result[name] = float(max(np.abs(a - b).max() for a, b in zip(got, ref)))
    return result


def latency(track_path: Path, model_path: Path, input_size: int, frames: int = 4, runs: int = 30, model_input_size: int | None = None) -> dict:
    """Median ONNX Runtime latency in ms at batch 1 (TrackNet: one image; ModelNet: one
    person's N frames, at `model_input_size`, default TrackNet's), with 1 and 2 intra-op
    threads."""
    import onnxruntime as ort

    result: dict = {}
    m = model_input_size or input_size
    inputs = {"track_net": np.random.default_rng(0).random((1, 3, input_size, input_size), dtype=np.float32), "model_net": np.random.default_rng(1).random((frames, 3, m, m), dtype=np.float32)}
    for name, path in (("track_net", track_path), ("model_net", model_path)):
        for threads in (1, 2):
            options = ort.SessionOptions()
            options.intra_op_num_threads = threads
            options.inter_op_num_threads = 1
            session = ort.InferenceSession(str(path), options, providers=["CPUExecutionProvider"])
            feed = {"images": inputs[name]}
            for _ in range(5):
                session.run(None, feed)
            times = []
            for _ in range(runs):
                t0 = time.perf_counter()
                session.run(None, feed)
                times.append((time.perf_counter() - t0) * 1e3)
            result[f"{name}_{threads}_thread{'s' if threads > 1 else ''}"] = round(statistics.median(times), 2)
    return result


def save_mean_albedo(mean_albedo: torch.Tensor, out_dir: Path) -> Path:
    from safetensors.torch import save_file

    path = out_dir / "mean_albedo.safetensors"
    tmp = path.with_suffix(".tmp")
    save_file({"mean_albedo_face": mean_albedo.detach().to(torch.float16).contiguous()}, str(tmp), metadata={"what": "trained R_0^t", "layout": "[3,512,512] RGB, row 0 at v = 1"})
    tmp.chmod(0o644)  # safetensors creates it owner-only; it is a shipped asset
    tmp.replace(path)
    return path


def kept_model_net(source: Path, out: Path) -> dict:
    """`--model-net-from SOURCE`: SOURCE's model_net.onnx and mean_albedo.safetensors go to
    `out` unchanged (copied unless SOURCE is `out`); returns SOURCE's manifest, which says
    how they were trained and which crops its ModelNet reads (`input_size`; TrackNet may
    read another size). Refuses a directory that is not an export of a ModelNet size."""
    from .networks import MODEL_NET_SIZES

    import shutil

    manifest_path = source / "manifest.json"
    names = ("model_net.onnx", "mean_albedo.safetensors")
    missing = [str(source / n) for n in (*names, "manifest.json") if not (source / n).is_file()]
    if missing:
        raise SystemExit(f"--model-net-from {source}: not an exported models directory (missing {', '.join(missing)})")
    try:
        old = json.loads(manifest_path.read_text())
    except json.JSONDecodeError as e:
        raise SystemExit(f"--model-net-from {source}: manifest.json is not JSON ({e})") from e
    if old.get("input_size") not in MODEL_NET_SIZES:
        raise SystemExit(f"--model-net-from {source}: its ModelNet reads {old.get('input_size')} px images; ModelNet reads {' or '.join(map(str, MODEL_NET_SIZES))} px")
    out.mkdir(parents=True, exist_ok=True)
    if source.resolve() != out.resolve():
        for name in names:
            shutil.copyfile(source / name, out / name)
    return old


# The TrackNet file the browser fetches (web/src/lib.rs), beside track_net.onnx.
WEB_TRACK_NET = "track_net_web.onnx"


def read_networks(path: Path, flag: str):
    """`load_networks` for a command-line argument: a missing or unreadable checkpoint is
    refused by the flag's name before anything is written."""
    import pickle

    if not path.is_file():
        raise SystemExit(f"{flag} {path}: no such checkpoint")
    try:
        return load_networks(path)
    except (pickle.UnpicklingError, RuntimeError, EOFError, KeyError, TypeError, ValueError) as e:
        raise SystemExit(f"{flag} {path}: not a training checkpoint ({e})") from e


def web_track_net(checkpoint: Path | None, nets, track_path: Path, track_size: int, out: Path, fp32: bool = False) -> dict:
    """Writes `WEB_TRACK_NET` and returns the manifest's `web_track_net` entry.

    Why a TrackNet of its own: the browser runs TrackNet with tract in wasm on the page's
    thread, where a 160 px TrackNet took ~26-31 ms a frame against ~15-17 for 128 px and
    held tracking below 30 fps (web/tests/e2e.mjs, 2026-12-08); the browser keeps a 128 px
    one there while native tracking gets the larger. Without `checkpoint` it is a copy of
    track_net.onnx."""
    import shutil
    import tempfile

    target = out / WEB_TRACK_NET
    if checkpoint is None:
        shutil.copyfile(track_path, target)
        return {"file": WEB_TRACK_NET, "input_size": track_size, "same_as": track_path.name}
    size = nets.config["input_size"]
    with tempfile.TemporaryDirectory(dir=out) as tmp:
        path, _ = export_onnx(nets.track, None, size, Path(tmp))
        diffs = parity(nets.track, None, path, path, size)
        rounding = None if fp32 else to_fp16_storage(path, size, batch=3)
        shutil.move(str(path), target)
    return {
        "file": WEB_TRACK_NET, "input_size": size, "checkpoint": checkpoint.name, "training_commit": nets.checkpoint.get("commit", ""),
        "w_calibration": calibration_summary(nets.checkpoint), "parity_max_abs_diff": diffs["track_net"], "fp16_storage_max_abs_diff": rounding,
        "why": "tract in the browser's wasm runs the 160 px TrackNet below 30 fps; the browser keeps this one",
    }


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--checkpoint", type=Path, required=True)
    parser.add_argument("--out", type=Path, default=Path("assets/models"))
    parser.add_argument("--metrics", type=Path, default=None, help="results.json of `python -m likeness_train.evaluate` for the manifest's `metrics`")
    parser.add_argument("--recalibrate-crop", action="store_true", help="measure the crop framing again instead of keeping a manifest's (preprocess.py)")
    parser.add_argument(
        "--model-net-from", type=Path, default=None, metavar="DIR",
        help="export TrackNet only and keep DIR's exported ModelNet and R_0^t (DIR may be --out): a warm-up checkpoint's are untrained",
    )
    parser.add_argument(
        "--web-track-net", type=Path, default=None, metavar="CKPT",
        help=f"the checkpoint whose TrackNet the browser runs ({WEB_TRACK_NET}); default: the same TrackNet as track_net.onnx",
    )
    parser.add_argument(
        "--fp32-weights", action="store_true",
        help="store the weights as float32 (default: float16 storage, float32 arithmetic; half the download)",
    )
    args = parser.parse_args(argv)
    nets = read_networks(args.checkpoint, "--checkpoint")
    # The browser's TrackNet is checked before anything is written.
    web_nets = read_networks(args.web_track_net, "--web-track-net") if args.web_track_net else None
    if web_nets is not None and not 32 <= web_nets.config["input_size"] <= nets.config["input_size"]:
        raise SystemExit(
            f"--web-track-net {args.web_track_net}: its TrackNet reads {web_nets.config['input_size']} px; "
            f"the browser's must read at most TrackNet's {nets.config['input_size']} px"
        )
    cfg, ckpt, track, model = nets.config, nets.checkpoint, nets.track, nets.model
    kept_from = kept_model_net(args.model_net_from, args.out) if args.model_net_from else None
    track_size = cfg["input_size"]
    if kept_from is not None:
        model = None
        model_size = kept_from["input_size"]
    elif nets.mean_albedo is None:
        raise SystemExit(f"{args.checkpoint} has no trained mean albedo R_0^t; it is not a training checkpoint")
    elif track_size != model.input_size:
        raise SystemExit(f"{args.checkpoint}: its TrackNet reads {track_size} px and its ModelNet was never trained; export it with --model-net-from DIR")
    else:
        model_size = track_size
    track_path, model_path = export_onnx(track, model, track_size, args.out, model_input_size=model_size)
    diffs = parity(track, model, track_path, model_path, track_size, model_input_size=model_size)
    if kept_from is not None:
        albedo_path = args.out / "mean_albedo.safetensors"
        diffs["model_net"] = kept_from.get("parity_max_abs_diff", {}).get("model_net")
    else:
        albedo_path = save_mean_albedo(nets.mean_albedo, args.out)
    rounding: dict = {}
    if not args.fp32_weights:
        rounding["track_net"] = to_fp16_storage(track_path, track_size, batch=3)
        if kept_from is None:
            rounding["model_net"] = to_fp16_storage(model_path, model_size, batch=cfg.get("frames", 4))
        else:
            # A kept ModelNet already stored as float16 keeps its record; a float32 one is
            # stored as float16 now (half its download), measured against itself.
            rounding["model_net"] = (kept_from.get("fp16_storage_max_abs_diff") or {}).get("model_net")
            if rounding["model_net"] is None:
                rounding["model_net"] = to_fp16_storage(model_path, model_size, batch=cfg.get("frames", 4))
    web = web_track_net(args.web_track_net, web_nets, track_path, track_size, args.out, fp32=args.fp32_weights)
    timings = latency(track_path, model_path, track_size, frames=cfg.get("frames", 4), model_input_size=model_size)
    # The framing is the landmark box's ratio to the image, the same at any input size (128
    # and 160 px agree to 1e-7), so one calibration serves both networks' crops.
    crop = crop_framing([args.out / "manifest.json", REPOSITORY_MANIFEST], model_size, args.recalibrate_crop)
    training = {
        "step": ckpt.get("step"), "stage": ckpt.get("stage"), "elapsed_s": round(ckpt.get("elapsed_s", 0.0), 1),
        "config": {k: v for k, v in cfg.items() if k != "blendshape_names"}, "w_calibration": calibration_summary(ckpt),
    }
    if kept_from is not None:
        # The kept ModelNet's own provenance (a chain of TrackNet-only exports keeps the first).
        previous = kept_from.get("training", {})
        training["model_net_from"] = previous.get("model_net_from") or {
            "training_commit": kept_from.get("training_commit"), "step": previous.get("step"), "stage": previous.get("stage"),
            "model_width": kept_from.get("model_width"),
        }
    manifest = Manifest(
        input_size=model_size,
        track_input_size=track_size,
        track_width=cfg["track_width"],
        model_width=kept_from.get("model_width", cfg["model_width"]) if kept_from is not None else cfg["model_width"],
        blendshape_names=list(cfg["blendshape_names"]),
        camera=camera_assumptions(),
        web_track_net=web,
        crop=crop,
        training_commit=ckpt.get("commit", git_commit()),
        training=training,
        parity_max_abs_diff=diffs,
        fp16_storage_max_abs_diff=rounding or None,
        latency_ms=timings,
        metrics=json.loads(args.metrics.read_text())["metrics"] if args.metrics else ckpt.get("metrics", {}),
    )
    (args.out / "manifest.json").write_text(json.dumps(asdict(manifest), indent=2) + "\n")
    for path in ((track_path,) if kept_from is not None else (track_path, model_path, albedo_path)) + (args.out / WEB_TRACK_NET,):
        print(f"wrote {path} ({path.stat().st_size / 1e6:.1f} MB)")
    if kept_from is not None:
        print(f"kept ModelNet and R_0^t from {args.model_net_from} (training commit {training['model_net_from']['training_commit']})")
    print(f"ONNX Runtime vs PyTorch max abs difference: {diffs}")
    if rounding:
        print(f"float16 weights vs float32, max abs difference per output: {rounding}")
    print("ONNX Runtime latency at batch 1, median ms (ModelNet: one person's N frames):")
    print("| model | 1 thread | 2 threads |\n|---|---|---|")
    for name in ("track_net", "model_net"):
        print(f"| {name} | {timings[name + '_1_thread']} | {timings[name + '_2_threads']} |")


if __name__ == "__main__":
    main()
