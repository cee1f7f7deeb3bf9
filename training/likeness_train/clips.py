"""Held-out synthetic video clips with their complete truth, for the tracker's accuracy
tests and benchmarks (the Rust side reads them; nothing here trains on them).

`python -m likeness_train.clips --out DIR [--seed 9001] [--clips 3] [--frames 48] [--width
640] [--height 480]` writes, per clip XX:

- `DIR/clip_XX/frame_0000.png`, ...: one synthetic person of `--seed` (person XX; seed 9001
  by default, which no training (1), evaluation (1000), framing calibration (0) or fixture
  (9002) uses), rendered by the training renderer (scene.py) with one fixed camera
  (horizontal field of view drawn in `--fov`, principal point at the frame centre), one
  light (the training sampler's), a static background (one of the training procedural
  kinds), and the training degradations at mild, per-clip settings (blur fixed per clip,
  sensor noise drawn per frame, JPEG at a fixed high quality);
- the motion: keyframes every 8-12 frames of expression weights (the training sampler's
  distribution, `SyntheticPeople.weights`), head pose (a random walk from near frontal,
  `POSE_STEP_DEG` per keyframe, within `POSE_LIMIT_DEG`), face position and size (the
  template face part `--face-px` pixels tall, as SyntheticConfig.face_fill measures it;
  the whole face kept inside the frame), interpolated with smoothstep between keyframes:
  continuous with continuous velocity, stopping at each keyframe. Per frame the change is
  bounded: |dw| <= 1.5 / 8, |d euler| <= 1.5 * 2.5 * step / 8 (`max_frame_change`);
- `DIR/clip_XX/truth.json`: {"seed", "clip", "person_index", "fps", "width", "height",
  "focal_px", "principal": [cx, cy], "horizontal_fov_deg", "blendshape_names" (the 53 ICT
  names, manifest order), "keyframes", "compose", "conventions", "frames": [{"index",
  "time_s", "weights" [53], "euler_rad" [yaw, pitch, roll], "rotation_deg" (the same in
  degrees), "translation" [x, y, z] (cm, this camera; not TrackNet's reference camera),
  "gamma" [27], "landmarks_68" [[x, y], ...] (frame pixels), "landmarks_68_camera" [[x, y,
  z], ...] (cm), "face_box" [x, y, w, h] (bounding box of the 68), "face_px"}]};
- `DIR/clip_XX/person.safetensors`: the person's true `dS0` [3, 128, 128] (the UV
  projection of the identity offset; the frames use the exact offset, `identity_coeffs`
  [100]), `dS` [53, 3, 128, 128] (cm), `dR0` [3, 128, 128], `dR` [53, 3, 128, 128]: ModelNet's
  output shapes without the batch axis, same layout (row 0 at v = 1);
- `DIR/clips.json`: the index, written last (removed first while writing).

Camera (face/src/camera.rs): p_cam = R p + t, R = Rz(roll) Ry(yaw) Rx(pitch), camera looking
down -z, u = cx + f X / (-Z), v = cy - f Y / (-Z), pixel centres at +0.5.
"""

from __future__ import annotations

import argparse
import json
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from .fixtures import check_out_dir, one_key_metadata, write_png

CLIPS_SEED = 9001  # held out: training 1, evaluation 1000, calibration 0, fixture 9002
FPS = 30
KEYFRAME_INTERVAL = (8, 12)  # frames between keyframes, inclusive
# Head pose: keyframe 0 near frontal (N(0, START) clipped at the limits), then a random walk
# with steps N(0, STEP) clipped at 2.5 STEP (yaw, pitch, roll degrees). Real heads turn
# ~20-100 degrees/s; the largest step over the shortest interval is ~140 degrees/s at 30 fps.
POSE_START_DEG = np.array([15.0, 8.0, 5.0])
POSE_STEP_DEG = np.array([12.0, 7.0, 5.0])
POSE_LIMIT_DEG = np.array([45.0, 25.0, 15.0])
STEP_CLIP = 2.5
# Face position: random-walk steps of this fraction of the frame size; face size: log steps.
POSITION_STEP = 0.12
SIZE_LOG_STEP = 0.15
FACE_MARGIN_PX = 8.0


def smoothstep(t: np.ndarray) -> np.ndarray:
    return t * t * (3.0 - 2.0 * t)


def max_frame_change(interval_min: int = KEYFRAME_INTERVAL[0]) -> dict[str, float]:
    """Upper bounds of the frame-to-frame change: smoothstep's slope peaks at 1.5 / interval
    times the keyframe difference."""
    slope = 1.5 / interval_min
    return {"weights": slope * 1.0, "euler_deg": slope * float((STEP_CLIP * POSE_STEP_DEG).max())}


@dataclass
class ClipSpec:
    seed: int = CLIPS_SEED
    clips: int = 3
    frames: int = 48
    width: int = 640
    height: int = 480
    face_px: tuple[float, float] = (150.0, 300.0)
    fov_deg: tuple[float, float] = (45.0, 60.0)
    fps: int = FPS

    def validate(self) -> None:
        checks = (
            ("clips", self.clips, 1, 100), ("frames", self.frames, 1, 10_000), ("width", self.width, 32, 4096),
            ("height", self.height, 32, 4096), ("fps", self.fps, 1, 240),
        )
        for name, value, low, high in checks:
            if not (low <= value <= high):
                raise ValueError(f"{name} {value}: must be within [{low}, {high}]")
        if not (0 <= self.seed < 2**32):
            raise ValueError(f"seed {self.seed}: must be within [0, 2^32)")
        if self.seed in (1, 1000):
            raise ValueError(f"seed {self.seed} is a training or evaluation seed; clips must be held out")
        lo, hi = self.face_px
        if not (8.0 <= lo <= hi <= 0.8 * min(self.width, self.height)):
            raise ValueError(f"face size {lo}-{hi} px: needs 8 <= min <= max <= 0.8 x the frame's smaller side ({0.8 * min(self.width, self.height):.0f})")
        lo, hi = self.fov_deg
        if not (10.0 <= lo <= hi <= 120.0):
            raise ValueError(f"field of view {lo}-{hi} degrees: needs 10 <= min <= max <= 120")


@dataclass
class Motion:
    """Per-frame values of one clip."""

    keyframes: list[int]
    weights: np.ndarray  # [N, 53]
    euler: np.ndarray  # [N, 3] radians
    centre_px: np.ndarray  # [N, 2] where the face centre projects
    face_px: np.ndarray  # [N]


def _centre_range(face_px: float, width: int, height: int) -> tuple[np.ndarray, np.ndarray]:
    """Face-centre positions that keep the face (about 0.8 x 1.1 of its height wide and tall
    with the pose) inside the frame."""
    half = np.array([0.45 * face_px, 0.55 * face_px]) + FACE_MARGIN_PX
    size = np.array([width, height], dtype=np.float64)
    lo, hi = half, size - half
    mid = 0.5 * size
    return np.minimum(lo, mid), np.maximum(hi, mid)


def draw_motion(people, rng: np.random.Generator, spec: ClipSpec) -> Motion:
    """Keyframes drawn in order (each: interval, weights, pose, position, size), so the first
    frames do not depend on the clip's length; interpolated with smoothstep."""
    keys, values = [0], []
    size_lo, size_hi = spec.face_px
    pose = np.clip(rng.normal(0.0, POSE_START_DEG), -POSE_LIMIT_DEG, POSE_LIMIT_DEG)
    face = float(np.exp(rng.uniform(np.log(size_lo), np.log(size_hi))))
    lo, hi = _centre_range(face, spec.width, spec.height)
    centre = rng.uniform(lo, hi)
    while True:
        values.append((people.weights(rng).astype(np.float64), np.radians(pose), centre.copy(), face))
        if keys[-1] >= spec.frames - 1:
            break
        keys.append(keys[-1] + int(rng.integers(KEYFRAME_INTERVAL[0], KEYFRAME_INTERVAL[1] + 1)))
        step = np.clip(rng.normal(0.0, POSE_STEP_DEG), -STEP_CLIP * POSE_STEP_DEG, STEP_CLIP * POSE_STEP_DEG)
        pose = np.clip(pose + step, -POSE_LIMIT_DEG, POSE_LIMIT_DEG)
        face = float(np.clip(face * np.exp(np.clip(rng.normal(0.0, SIZE_LOG_STEP), -2.5 * SIZE_LOG_STEP, 2.5 * SIZE_LOG_STEP)), size_lo, size_hi))
        lo, hi = _centre_range(face, spec.width, spec.height)
        centre = np.clip(centre + rng.normal(0.0, POSITION_STEP) * np.array([spec.width, spec.height]), lo, hi)
    n = np.arange(spec.frames)
    seg = np.clip(np.searchsorted(keys, n, side="right") - 1, 0, len(keys) - 2) if len(keys) > 1 else np.zeros(spec.frames, int)
    out = []
    for j in range(4):
        a = np.stack([np.atleast_1d(values[i][j]) for i in range(len(values))]).astype(np.float64)
        if len(keys) == 1:
            out.append(np.repeat(a[:1], spec.frames, 0))
            continue
        k0, k1 = np.asarray(keys)[seg], np.asarray(keys)[seg + 1]
        s = smoothstep((n - k0) / (k1 - k0))[:, None]
        out.append(a[seg] + (a[seg + 1] - a[seg]) * s)
    return Motion(keys, out[0].astype(np.float32), out[1].astype(np.float32), out[2], out[3][:, 0])


def compose_settings(rng: np.random.Generator) -> dict:
    """Mild per-clip degradations (training ranges: blur sigma 0.3-1.3 half the time, noise
    0-0.03, JPEG quality 30-95 70 % of the time)."""
    kinds = ("noise", "texture", "clutter")
    background = kinds[int(rng.integers(len(kinds)))]
    blur = float(rng.uniform(0.3, 0.8)) if rng.random() < 0.5 else 0.0
    noise = float(rng.uniform(0.003, 0.012))
    quality = int(rng.integers(80, 96))
    return {"background": background, "blur_sigma_px": blur, "noise_sigma": noise, "jpeg_quality": quality}


def _compose_config(settings: dict):
    from .synthetic import ComposeConfig

    blur = settings["blur_sigma_px"]
    return ComposeConfig(
        background_kinds=("flat",), blur_probability=1.0 if blur > 0 else 0.0, blur_sigma=(blur, blur),
        noise_sigma=(settings["noise_sigma"],) * 2, jpeg_probability=1.0, jpeg_quality=(settings["jpeg_quality"],) * 2,
    )


def render_clip(scene, clip: int, spec: ClipSpec, frames: range | None = None) -> dict:
    """One clip: per frame the uint8 image and truth, the camera, the person. `frames`
    renders a subset (the truth of every frame is still drawn: it is cheap)."""
    from .scene import Camera, landmark_box, to_uint8
    from .synthetic import _background, compose_image

    rng = np.random.default_rng(np.random.SeedSequence([spec.seed, 3, clip]))
    fov = float(rng.uniform(*spec.fov_deg))
    camera = Camera.centred(spec.width, spec.height, fov)
    gamma = scene.people.lighting(rng)
    settings = compose_settings(rng)
    background = np.clip(_background(settings["background"], spec.height, spec.width, rng), 0.0, 1.0)
    motion = draw_motion(scene.people, rng, spec)
    person = scene.person(clip)
    translation = np.stack([scene.translation_for(e, camera, c, f) for e, c, f in zip(motion.euler, motion.centre_px, motion.face_px)])
    indices = list(frames if frames is not None else range(spec.frames))
    gammas = np.repeat(gamma[None], len(indices), 0)
    r = scene.render(person, motion.weights[indices], motion.euler[indices], translation[indices], gammas, camera)
    config = _compose_config(settings)
    images, truth = [], []
    for j, n in enumerate(indices):
        m = r.coverage[j][..., None]
        scene_image = m * r.image[j] + (1.0 - m) * background
        frame_rng = np.random.default_rng(np.random.SeedSequence([spec.seed, 3, clip, 1, n]))
        # The background is already in: a full mask leaves compose_image only the blur,
        # noise, 8-bit quantisation and JPEG of the training pipeline.
        images.append(to_uint8(compose_image(scene_image, np.ones(m.shape[:2]), frame_rng, config)))
        euler = motion.euler[n].astype(np.float64)
        truth.append({
            "index": n,
            "time_s": n / spec.fps,
            "weights": [float(v) for v in motion.weights[n]],
            "euler_rad": [float(v) for v in motion.euler[n]],
            "rotation_deg": [float(v) for v in np.degrees(euler)],
            "translation": [float(v) for v in translation[n]],
            "gamma": [float(v) for v in gamma],
            "landmarks_68": [[float(x), float(y)] for x, y in r.landmarks[j]],
            "landmarks_68_camera": [[float(v) for v in p] for p in r.landmarks_camera[j]],
            "face_box": landmark_box(r.landmarks[j].astype(np.float64)),
            "face_px": float(motion.face_px[n]),
        })
    return {"images": images, "truth": truth, "camera": camera, "fov": fov, "person": person, "motion": motion, "compose": settings}


def write_clips(out: Path, spec: ClipSpec, model=None, log=print) -> dict:
    """Writes `spec.clips` clips into `out` (see the module documentation); returns the
    index written to clips.json."""
    from safetensors.numpy import save_file

    from .face import FaceModel
    from .scene import SceneRenderer

    spec.validate()
    check_out_dir(out, lambda name: name == "clips.json" or (name.startswith("clip_") and name[5:].isdigit()))
    model = model or FaceModel.load()
    out.mkdir(exist_ok=True)
    (out / "clips.json").unlink(missing_ok=True)
    scene = SceneRenderer(model, spec.seed)
    names = []
    for c in range(spec.clips):
        t0 = time.perf_counter()
        clip = render_clip(scene, c, spec)
        d = out / f"clip_{c:02d}"
        d.mkdir(exist_ok=True)
        for old in d.glob("frame_*.png"):
            old.unlink()
        for truth, image in zip(clip["truth"], clip["images"]):
            write_png(d / f"frame_{truth['index']:04d}.png", image)
        cam, person = clip["camera"], clip["person"]
        save_file(
            {k: np.ascontiguousarray(getattr(person, k).numpy(), dtype=np.float32) for k in ("dS0", "dS", "dR0", "dR", "identity_coeffs")},
            str(d / "person.safetensors"),
            metadata=one_key_metadata("person", {"seed": spec.seed, "person_index": person.index, "layout": "dS0 [3,128,128] cm, dS [53,3,128,128] cm, dR0 [3,128,128], dR [53,3,128,128], identity_coeffs [100]; no batch axis; row 0 at v = 1"}),
        )
        info = {
            "seed": spec.seed, "clip": c, "person_index": person.index, "fps": spec.fps, "width": spec.width, "height": spec.height,
            "focal_px": cam.focal, "principal": [cam.cx, cam.cy], "horizontal_fov_deg": clip["fov"],
            "blendshape_names": list(model.expression_names),
            "keyframes": [k for k in clip["motion"].keyframes if k < spec.frames],
            "compose": clip["compose"],
            "conventions": "p_cam = R p_model + t (cm, ICT model space), R = Rz(roll) Ry(yaw) Rx(pitch), camera looking down -z (OpenGL); "
            "u = cx + f X / (-Z), v = cy - f Y / (-Z), pixel (i, j) covers [j, j+1) x [i, i+1); translation is for this camera, "
            "not TrackNet's reference camera; face_px = height in pixels of the template face part at the face centre's depth",
            "frames": clip["truth"],
        }
        (d / "truth.json").write_text(json.dumps(info, indent=1) + "\n")
        names.append(d.name)
        log(f"clip {c}: {spec.frames} frames in {time.perf_counter() - t0:.1f} s ({d})")
    index = {
        "seed": spec.seed, "clips": names, "frames": spec.frames, "width": spec.width, "height": spec.height, "fps": spec.fps,
        "face_px": list(spec.face_px), "fov_deg": list(spec.fov_deg), "generator": "python -m likeness_train.clips",
    }
    (out / "clips.json").write_text(json.dumps(index, indent=2) + "\n")
    return index


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--out", type=Path, required=True, help="output folder (created; its parent must exist)")
    parser.add_argument("--seed", type=int, default=CLIPS_SEED)
    parser.add_argument("--clips", type=int, default=3)
    parser.add_argument("--frames", type=int, default=48)
    parser.add_argument("--width", type=int, default=640)
    parser.add_argument("--height", type=int, default=480)
    parser.add_argument("--face-px", type=float, nargs=2, default=(150.0, 300.0), metavar=("MIN", "MAX"), help="template face height in pixels")
    parser.add_argument("--fov", type=float, nargs=2, default=(45.0, 60.0), metavar=("MIN", "MAX"), help="horizontal field of view, degrees")
    parser.add_argument("--threads", type=int, default=1, help="torch threads (one is faster on 2 cores: many small tensor operations)")
    args = parser.parse_args(argv)
    spec = ClipSpec(seed=args.seed, clips=args.clips, frames=args.frames, width=args.width, height=args.height, face_px=tuple(args.face_px), fov_deg=tuple(args.fov))
    if not (1 <= args.threads <= 64):
        parser.error(f"--threads {args.threads}: must be within [1, 64]")
    try:
        spec.validate()
        check_out_dir(args.out, lambda name: name == "clips.json" or (name.startswith("clip_") and name[5:].isdigit()))
    except ValueError as e:
        parser.error(str(e))
    torch.set_num_threads(args.threads)
    t0 = time.perf_counter()
    write_clips(args.out, spec)
    print(f"wrote {spec.clips} clips of {spec.frames} frames ({spec.width}x{spec.height}) to {args.out} in {time.perf_counter() - t0:.1f} s")


if __name__ == "__main__":
    main()
