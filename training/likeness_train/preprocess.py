"""The crop and input tensor the networks see at inference, and the framing calibration
that makes a crop of real footage look like a training image.

Training images were rendered directly at 128 px (`SyntheticPeople.camera`: the face fills
~0.85 of the image height, principal point at the centre with 1 % jitter, field of view
25-40 degrees): there was no crop. Footage needs one, placed around the face's landmarks so
that the face sits in it as it sat in the training images. Two halves, the same here and in
the Rust tracker (`tracking/src/preprocess.rs`; a parity test compares them on the fixture
`python -m likeness_train.fixtures` writes):

- `sample_rect` (the sampling rule). Image HxWx3 uint8 RGB; pixel (row i, col j) covers
  [j, j+1) x [i, i+1), its centre is (j + 0.5, i + 0.5). Output pixel (r, c) of an out_w x
  out_h tensor taken from the rectangle (x0, y0, w, h) (float32 values; all arithmetic in
  float64 on them) averages kx * ky bilinear samples at
  x = x0 + (c + (a + 0.5) / kx) * w / out_w, y = y0 + (r + (b + 0.5) / ky) * h / out_h,
  a < kx, b < ky, with kx = max(1, ceil(w / out_w)), ky = max(1, ceil(h / out_h)): a box
  prefilter, so a face larger than the input is not aliased. A bilinear sample at (x, y)
  uses t = x - 0.5 clamped to [0, n - 1], i0 = floor(t), f = t - i0, i1 = min(i0 + 1, n - 1)
  (taps outside the image repeat the edge). Value = mean of the samples / 255, then
  (v - mean[ch]) / std[ch], as float32 NCHW [1, 3, out_h, out_w]. The samples are summed in
  the Rust loop's order (b outer, a inner, starting from 0) and every operation is the same
  IEEE one, so both sides produce the same bits, not merely close values.
- `crop_for_landmarks` (the framing). The first 60 of the iBUG 68 landmarks (jaw, brows,
  nose, eyes, outer lips: the points both the template's 68 and OpenSeeFace's 66 share),
  their bounding box, size = max(width, height), centre = box centre + centre_offset * size,
  side = scale * size; the crop is that square. In float32, operation for operation as the
  Rust `CropFraming::crop_for_landmarks`.

The framing constants (`centre_offset`, `scale`) are measured on the training distribution
by `python -m likeness_train.preprocess --calibrate --manifest assets/models/manifest.json`
and stored in the manifest's `crop` key (export.py writes the same key).
"""

from __future__ import annotations

import argparse
import json
import math
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

# TrackNet's and ModelNet's normalisation (the manifest's `normalisation`, export.IMAGE_MEAN).
HALF_MEAN = (0.5, 0.5, 0.5)
HALF_STD = (0.5, 0.5, 0.5)
# The OpenSeeFace detector and landmark models (tracking/src/preprocess.rs, IMAGENET).
IMAGENET_MEAN = (0.485, 0.456, 0.406)
IMAGENET_STD = (0.229, 0.224, 0.225)

# The landmarks that define the crop: the first 60 of the iBUG 68-point layout.
CROP_LANDMARKS = 60

# The calibration's sample: people 0..499 of seed 0 with their training group of 4 frames
# (`SyntheticData.batch` draws exactly these), 2,000 frames. Seed 0 is not a training seed
# (training used 1, evaluation 1000), but the distribution is the training one.
CALIBRATION_SEED = 0
CALIBRATION_PEOPLE = 500
CALIBRATION_FRAMES_PER_PERSON = 4


@dataclass(frozen=True)
class Rect:
    """An axis-aligned rectangle in image pixels (x right, y down), float32 values."""

    x: float
    y: float
    width: float
    height: float

    def __post_init__(self):
        for name in ("x", "y", "width", "height"):
            object.__setattr__(self, name, float(np.float32(getattr(self, name))))

    def to_array(self) -> np.ndarray:
        return np.array([self.x, self.y, self.width, self.height], dtype=np.float32)

    def is_valid(self) -> bool:
        v = (self.x, self.y, self.width, self.height)
        return all(math.isfinite(a) for a in v) and self.width > 0 and self.height > 0

    def box_filter(self, out_w: int, out_h: int) -> tuple[int, int]:
        """(kx, ky): samples per output pixel and axis for an out_w x out_h output."""
        return max(1, math.ceil(self.width / out_w)), max(1, math.ceil(self.height / out_h))

    def inside(self, width: int, height: int) -> bool:
        """Whether the rectangle lies within a width x height image."""
        return self.x >= 0 and self.y >= 0 and self.x + self.width <= width and self.y + self.height <= height


@dataclass(frozen=True)
class CropFraming:
    """Where the square crop goes around a face's landmarks (the manifest's `crop`)."""

    centre_offset: tuple[float, float]  # crop centre - landmark-box centre, in box sizes
    scale: float  # crop side / landmark-box size

    def __post_init__(self):
        offset = tuple(float(v) for v in self.centre_offset)
        if len(offset) != 2 or not all(math.isfinite(v) for v in offset):
            raise ValueError(f"centre_offset must be 2 finite numbers, got {self.centre_offset!r}")
        if not (math.isfinite(self.scale) and self.scale > 0):
            raise ValueError(f"scale must be a positive finite number, got {self.scale!r}")
        object.__setattr__(self, "centre_offset", offset)
        object.__setattr__(self, "scale", float(self.scale))

    @classmethod
    def from_manifest(cls, manifest: dict | str | Path) -> "CropFraming":
        """From a manifest dict or the path of a manifest.json; a manifest without `crop`
        is refused with the command that adds it."""
        source = manifest
        if not isinstance(manifest, dict):
            manifest = json.loads(Path(manifest).read_text())
        crop = manifest.get("crop")
        if crop is None:
            raise ValueError(f"{source if not isinstance(source, dict) else 'the manifest'} has no `crop` framing (run `python -m likeness_train.preprocess --calibrate --manifest PATH`)")
        return cls(tuple(crop["centre_offset"]), crop["scale"])


def _f32(v) -> np.float32:
    return np.float32(v)


def crop_for_landmarks(landmarks, framing: CropFraming) -> Rect:
    """The square crop for `landmarks` ([>= 60, 2] image pixels, iBUG order), computed in
    float32 exactly as the Rust `CropFraming::crop_for_landmarks`. Raises ValueError for
    fewer than 60 points, non-finite points, or a box without width or height."""
    pts = np.asarray(landmarks)
    if pts.ndim != 2 or pts.shape[1] != 2:
        raise ValueError(f"landmarks must be [N, 2], got shape {pts.shape}")
    if pts.shape[0] < CROP_LANDMARKS:
        raise ValueError(f"a crop needs {CROP_LANDMARKS} landmarks, got {pts.shape[0]}")
    pts = pts[:CROP_LANDMARKS].astype(np.float32)
    if not np.isfinite(pts).all():
        raise ValueError("landmarks are not finite")
    lo, hi = pts.min(0), pts.max(0)
    width, height = _f32(hi[0] - lo[0]), _f32(hi[1] - lo[1])
    if not (width > 0 and height > 0):
        raise ValueError("landmarks are degenerate (their box has no width or height)")
    half = _f32(0.5)
    size = max(width, height)
    cx = _f32(lo[0] + half * width) + _f32(_f32(framing.centre_offset[0]) * size)
    cy = _f32(lo[1] + half * height) + _f32(_f32(framing.centre_offset[1]) * size)
    side = _f32(size * _f32(framing.scale))
    return Rect(_f32(cx - half * side), _f32(cy - half * side), side, side)


def _taps(t: np.ndarray, n: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Bilinear taps of continuous indices `t` on an axis of `n` pixels, edges repeated."""
    t = np.clip(t, 0.0, float(n - 1))
    i0 = np.floor(t)
    f = t - i0
    i0 = i0.astype(np.int64)
    return i0, np.minimum(i0 + 1, n - 1), f


def sample_rect(image, rect: Rect, out_w: int, out_h: int, mean=HALF_MEAN, std=HALF_STD) -> np.ndarray:
    """Resamples `rect` of `image` (HxWx3 uint8 RGB) into a float32 [1, 3, out_h, out_w]
    tensor by the rule in the module documentation. `mean` and `std` are per channel, on
    values in [0, 1] (taken as float32, as the Rust `Normalisation`)."""
    img = np.asarray(image)
    if img.dtype != np.uint8 or img.ndim != 3 or img.shape[2] != 3:
        raise ValueError(f"image must be HxWx3 uint8 RGB, got {img.dtype} {img.shape}")
    ih, iw = img.shape[:2]
    if ih == 0 or iw == 0:
        raise ValueError("the image is empty")
    if not isinstance(rect, Rect):
        rect = Rect(*rect)
    if not rect.is_valid():
        raise ValueError(f"crop rectangle {rect} is empty or not finite")
    if int(out_w) != out_w or int(out_h) != out_h or out_w < 1 or out_h < 1:
        raise ValueError(f"output size {out_w}x{out_h} must be positive integers")
    mean = np.asarray(mean, dtype=np.float32).astype(np.float64)
    std = np.asarray(std, dtype=np.float32).astype(np.float64)
    if mean.shape != (3,) or std.shape != (3,) or not (np.isfinite(mean).all() and (std > 0).all()):
        raise ValueError("mean and std must be 3 finite values, std > 0")
    step_x = rect.width / out_w
    step_y = rect.height / out_h
    kx, ky = rect.box_filter(out_w, out_h)
    pixels = img.astype(np.float64)
    cols, rows = np.arange(out_w, dtype=np.float64), np.arange(out_h, dtype=np.float64)
    acc = np.zeros((out_h, out_w, 3))
    # Same order as the Rust loops: sample rows b outer, sample columns a inner.
    for b in range(ky):
        y0, y1, fy = _taps(rect.y + (rows + (b + 0.5) / ky) * step_y - 0.5, ih)
        fy = fy[:, None, None]
        for a in range(kx):
            x0, x1, fx = _taps(rect.x + (cols + (a + 0.5) / kx) * step_x - 0.5, iw)
            fx = fx[None, :, None]
            p00, p10 = pixels[y0[:, None], x0[None, :]], pixels[y0[:, None], x1[None, :]]
            p01, p11 = pixels[y1[:, None], x0[None, :]], pixels[y1[:, None], x1[None, :]]
            top = p00 + (p10 - p00) * fx
            bottom = p01 + (p11 - p01) * fx
            acc += top + (bottom - top) * fy
    v = acc * (1.0 / (kx * ky)) / 255.0
    out = ((v - mean) / std).astype(np.float32)
    return np.ascontiguousarray(out.transpose(2, 0, 1)[None])


def preprocess(image, landmarks, framing: CropFraming, size: int = 128, mean=HALF_MEAN, std=HALF_STD) -> tuple[np.ndarray, Rect]:
    """TrackNet's / ModelNet's input for a face: the crop around its landmarks, resampled
    and normalised. Returns ([1, 3, size, size] float32, the crop)."""
    rect = crop_for_landmarks(landmarks, framing)
    return sample_rect(image, rect, size, size, mean, std), rect


# ----------------------------------------------------------------------------- calibration


@dataclass
class Calibration:
    framing: CropFraming
    frames: int
    # Spread of the per-frame values the medians summarise (the training framing's own
    # variation: fill 0.85 x U(0.9, 1.25) distance, +-6 % centre offset, pose).
    scale_quartiles: tuple[float, float]
    offset_quartiles: tuple[tuple[float, float], tuple[float, float]]
    description: str

    def manifest_entry(self) -> dict:
        return {
            "landmarks": "first 60 of the iBUG 68",
            "box_size": "max(width, height)",
            "centre_offset": [round(v, 6) for v in self.framing.centre_offset],
            "scale": round(self.framing.scale, 6),
            "calibrated_on": self.description,
        }


def calibration_description(people: int = CALIBRATION_PEOPLE, frames_per_person: int = CALIBRATION_FRAMES_PER_PERSON, seed: int = CALIBRATION_SEED, image_size: int = 128) -> str:
    from .dataset import SYNTHETIC_VERSION

    return (
        f"{people * frames_per_person} synthetic training frames ({people} people x {frames_per_person}, "
        f"seed {seed}, synthetic version {SYNTHETIC_VERSION}, {image_size} px): medians of "
        f"{image_size} / size and ((c, c) - box centre) / size, c = {image_size // 2}"
    )


def training_landmark_boxes(model, seed: int, people: int, frames_per_person: int, image_size: int = 128) -> np.ndarray:
    """[people * frames, 4] (x_min, y_min, width, height) of the first 60 true landmarks as
    the training images show them: person k of `seed` with their group 0 of frames (what
    `SyntheticData.batch` renders), projected with each frame's camera (data.py)."""
    from . import render as R
    from .scene import synthetic_people
    from .synthetic import SyntheticConfig

    region = model.restricted()
    source = synthetic_people(model, seed, SyntheticConfig(image_size=image_size))
    boxes = []
    with torch.no_grad():
        for k in range(people):
            person = source.person(k)
            frames = source.group(k, 0, frames_per_person)
            truth = {key: torch.as_tensor(np.stack([getattr(f, key) for f in frames]), dtype=torch.float32) for key in ("weights", "translation", "principal")}
            rotation = torch.as_tensor(np.stack([_euler_matrix(f.euler) for f in frames]), dtype=torch.float32)
            focal = torch.tensor([f.focal for f in frames], dtype=torch.float32)
            landmarks_3d = region.landmarks(person.shape(region, truth["weights"]))
            pixels, _ = R.project(landmarks_3d, rotation, truth["translation"], focal, truth["principal"][:, 0], truth["principal"][:, 1])
            pts = pixels[:, :CROP_LANDMARKS].numpy().astype(np.float64)
            lo, hi = pts.min(1), pts.max(1)
            boxes.append(np.concatenate([lo, hi - lo], 1))
    return np.concatenate(boxes)


def _euler_matrix(euler) -> np.ndarray:
    from .synthetic import euler_to_matrix

    return euler_to_matrix(euler)


def framing_from_boxes(boxes: np.ndarray, image_size: int = 128) -> tuple[CropFraming, dict]:
    """The framing that maps landmark boxes onto the whole training image [0, S]^2.

    Per frame, the crop that reproduces that frame exactly has side S and centre (S/2, S/2):
    scale = S / size, offset = ((S/2, S/2) - box centre) / size. The training images vary
    around one framing (distance x U(0.9, 1.25), centre within +-6 %, pose), so one value
    must summarise them; the median is used because
    - it is the value the networks saw most: half the training faces were framed tighter,
      half looser, and TrackNet is least extrapolating in the middle of its distribution;
    - it commutes with monotone maps (median of S / size = S / median of size), so the
      framing does not depend on whether one averages the scale or the face's fill;
    - it is robust to the tails (yaw near 60 degrees narrows the box, pitch changes its
      height) that would pull a mean.
    Returns the framing and the quartiles of the per-frame values."""
    boxes = np.asarray(boxes, dtype=np.float64)
    size = np.maximum(boxes[:, 2], boxes[:, 3])
    centre = boxes[:, :2] + 0.5 * boxes[:, 2:]
    scale = image_size / size
    offset = (0.5 * image_size - centre) / size[:, None]
    framing = CropFraming((float(np.median(offset[:, 0])), float(np.median(offset[:, 1]))), float(np.median(scale)))
    q = lambda v: tuple(float(x) for x in np.percentile(v, [25, 75]))  # noqa: E731
    return framing, {"scale": q(scale), "offset": (q(offset[:, 0]), q(offset[:, 1]))}


def calibrate(model=None, people: int = CALIBRATION_PEOPLE, frames_per_person: int = CALIBRATION_FRAMES_PER_PERSON, seed: int = CALIBRATION_SEED, image_size: int = 128) -> Calibration:
    """Measures the framing on `people` x `frames_per_person` training-distribution frames."""
    from .face import FaceModel

    model = model or FaceModel.load()
    boxes = training_landmark_boxes(model, seed, people, frames_per_person, image_size)
    framing, spread = framing_from_boxes(boxes, image_size)
    return Calibration(
        framing=framing, frames=len(boxes), scale_quartiles=spread["scale"], offset_quartiles=spread["offset"],
        description=calibration_description(people, frames_per_person, seed, image_size),
    )


def with_crop(manifest: dict, entry: dict) -> dict:
    """The manifest with `crop` set to `entry`: replaced in place if present, otherwise
    inserted after `camera` (or at the end), every other key in its order."""
    out = {}
    for key, value in manifest.items():
        if key == "crop":
            continue
        out[key] = value
        if key == "camera":
            out["crop"] = entry
    out.setdefault("crop", entry)
    return out


def write_manifest_crop(path: Path, entry: dict) -> None:
    """Adds or replaces the `crop` key of the manifest at `path`, keeping the rest of the
    file byte for byte (it is written with indent 2, as export.py writes it; a manifest that
    would not survive that round trip is refused rather than reformatted)."""
    text = path.read_text()
    manifest = json.loads(text)
    if json.dumps(manifest, indent=2) + "\n" != text:
        raise ValueError(f"{path} is not formatted as export.py writes it (json indent 2); refusing to reformat it")
    new = json.dumps(with_crop(manifest, entry), indent=2) + "\n"
    tmp = path.with_suffix(".json.tmp")
    tmp.write_text(new)
    tmp.chmod(path.stat().st_mode & 0o777)
    tmp.replace(path)


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--calibrate", action="store_true", help="measure the crop framing on synthetic training frames")
    parser.add_argument("--manifest", type=Path, default=None, help="manifest.json to write the `crop` key into (default: only print it)")
    parser.add_argument("--people", type=int, default=CALIBRATION_PEOPLE, help="people of the calibration seed, each with their training group of frames")
    parser.add_argument("--frames-per-person", type=int, default=CALIBRATION_FRAMES_PER_PERSON)
    parser.add_argument("--seed", type=int, default=CALIBRATION_SEED)
    parser.add_argument("--image-size", type=int, default=128, help="the training image size (the manifest's input_size)")
    # One thread: drawing a person is many small tensor operations, which a second thread
    # slows down (OpenMP spin-waiting; ~0.3 s per person with one, 2-5 s with two on a busy
    # machine).
    parser.add_argument("--threads", type=int, default=1)
    args = parser.parse_args(argv)
    if not args.calibrate:
        parser.error("nothing to do: pass --calibrate")
    for name, low, high in (("people", 1, 100_000), ("frames_per_person", 1, 64), ("image_size", 16, 1024), ("threads", 1, 64)):
        if not (low <= getattr(args, name) <= high):
            parser.error(f"--{name.replace('_', '-')} {getattr(args, name)}: must be within [{low}, {high}]")
    if args.manifest is not None:
        if not args.manifest.is_file():
            parser.error(f"--manifest {args.manifest}: no such file")
        size = json.loads(args.manifest.read_text()).get("input_size")
        if size is not None and size != args.image_size:
            parser.error(f"--image-size {args.image_size} but {args.manifest} has input_size {size}")
    torch.set_num_threads(args.threads)
    t0 = time.perf_counter()
    result = calibrate(people=args.people, frames_per_person=args.frames_per_person, seed=args.seed, image_size=args.image_size)
    entry = result.manifest_entry()
    print(json.dumps({"crop": entry}, indent=2))
    print(f"{result.frames} frames in {time.perf_counter() - t0:.1f} s; interquartile range of the per-frame values: scale {result.scale_quartiles}, centre offset x {result.offset_quartiles[0]}, y {result.offset_quartiles[1]}")
    if args.manifest is not None:
        write_manifest_crop(args.manifest, entry)
        print(f"wrote `crop` into {args.manifest}")


if __name__ == "__main__":
    main()
