"""Synthetic personalized people whose ground truth is known (issue 3, deliverable 2).

The paper trains on 94k real videos; we train on people drawn from the ICT template, each
with a *personal* face model we know exactly, so that every claim can be measured:

- identity: coefficients alpha_k of the 100 ICT identity components (a true per-vertex
  offset), plus its UV-space projection dS_0^true for evaluating ModelNet's dS_0;
- static albedo dR_0^true: skin tone, low-frequency blotches, freckles, lip and brow colour;
- expression corrections dS_i^true, zero wherever A_i is zero: a scaled copy of the
  template's own motion (how far this person's mouth opens, an asymmetric smile) plus
  smooth Gaussian-bump fields (brow shape, cheek bulges), a few mm, more around the mouth;
- dynamic albedo dR_i^true: folds and wrinkles that appear with the expression, inside A_i;
- per frame: sparse weights w in [0, 1] (gaze, which turns the eyeballs as
  `face.FaceModel.turn_eyes` says; blinks; correlated L/R pairs; mouthClose only as the
  corrective of an open jaw), head pose (yaw +-60, pitch +-30, roll +-20 degrees), SH
  lighting gamma (ambient + one directional light, nearly monochromatic), the camera's
  field of view and distance (the principal point at the centre, as inference assumes);
- `compose_image`: what happens after rendering (background, blur, sensor noise, JPEG).

Everything is deterministic in a seed: `SyntheticPeople(model, seed).person(k)` and
`.group(k, g, n)` derive their numpy Generators from (seed, k[, g]) with SeedSequence, so
people and groups can be drawn in any order, in parallel workers, and held-out sets are
just other seeds.

Map layout as in face.py: UV maps are torch tensors [C, 128, 128], row 0 at v = 1; shape in
centimetres, albedo in display-encoded RGB in [0, 1].
"""

from __future__ import annotations

import io
import math
from dataclasses import dataclass

import numpy as np
import torch
import torch.nn.functional as F

from . import render as R
from .face import CORRECTION_SIZE, NUM_BLENDSHAPES, NUM_IDENTITY, FaceModel

# --- configuration -------------------------------------------------------------------


@dataclass
class SyntheticConfig:
    """Ranges of the synthetic people and frames (units: cm, degrees, display RGB)."""

    # Identity. ICT's identity deltas are PCA components already scaled by their standard
    # deviation (RMS over the face falls from 3.9 mm for component 0 to ~0.1 mm for 99;
    # upstream `randomize_identity` draws N(0, 1)), so sigma ~1 is the realistic spread.
    # The tail is damped further (sigma 1 -> 0.5) because the last components are mostly
    # noise-like detail; clipping at 2.5 sigma avoids implausible extremes.
    identity_sigma_head: float = 1.0
    identity_sigma_tail: float = 0.5
    identity_clip: float = 2.5
    # Expression corrections: cap on |dS_i^true| per texel. The paper's motivation (how far
    # the mouth opens, smile asymmetry, brow shape) is a few mm; mouth and jaw shapes move
    # up to 4 cm in the template, so their personal deviation is allowed to be larger.
    max_correction_cm: float = 0.5
    max_correction_mouth_cm: float = 0.8
    # Scale of the template's own motion in dS_i (person moves 1 + s times as far).
    motion_scale_sigma: float = 0.12
    motion_scale_clip: float = 0.3
    # Albedo.
    skin_tone_range: tuple[float, float] = (0.45, 1.15)  # multiplies R_0
    max_dynamic_albedo: float = 0.15  # |dR_i^true| cap (folds darken skin by up to ~0.15)
    freckle_probability: float = 0.35
    # Frames.
    max_yaw_deg: float = 60.0
    max_pitch_deg: float = 30.0
    max_roll_deg: float = 20.0
    # Expression density. Version 1 drew 0-5 groups of 45 candidates per frame: each shape
    # active in ~5 % of frames, jawOpen > 0.3 in 3.4 %. A network from scratch then learnt
    # to predict w = 0: TrackNet supervised directly on w for 800 steps reached a jawOpen
    # correlation of 0.08, on a jaw-balanced subset 0.70 in 200 (training README, "Where it
    # stands"). Real footage is denser (people talk), so: 1-7 groups, and the jaw drawn on
    # its own in `talking_probability` of the frames.
    min_expression_groups: int = 1
    max_expression_groups: int = 7
    talking_probability: float = 0.4
    # mouthClose is a corrective (ICT and ARKit): it closes the lips of an open jaw, so it is
    # drawn only with jawOpen and at most jawOpen; alone it pushes the lower lip through the
    # upper one. Version 2 drew it as any other shape.
    mouth_close_probability: float = 0.25  # of the frames with the jaw open
    fov_deg_range: tuple[float, float] = (25.0, 40.0)
    # Principal point jitter (standard deviation, a fraction of the image size). 0: at the
    # centre, which is what the inference crop assumes (tracking/src/params.rs); the image
    # cannot show it, so version 2's 0.01 was a landmark-loss floor of ~3.3 px^2 per image.
    principal_jitter: float = 0.0
    image_size: int = 128
    # Face height / image height at nominal distance (the template's face part, forehead to
    # neck). Version 3's 0.85 framed the whole head: the landmark box (jaw to brows) was
    # ~52 px of the 128 (the crop scale 2.44 x box), an eye ~10 px wide, and the subtle
    # channels (lip rolls, squints, jaw forward) moved a pixel or two. Version 4 frames the
    # face as a face detector's crop does (box ~80 px, crop scale ~1.6): 1.5x the pixels on
    # every shape for the same network cost.
    face_fill: float = 1.3


# Which blendshapes count as mouth/jaw for the larger correction cap.
def _is_mouth(name: str) -> bool:
    return name.startswith(("jaw", "mouth", "cheekPuff"))


# Dynamic albedo kinds per blendshape name prefix: wrinkle bands perpendicular to the
# motion (forehead lines with raised brows, glabella lines with lowered ones, crow's feet
# with squints, bunny lines with sneers, lip lines with puckers), folds at the border of the
# moving region (nasolabial fold with smiles), flush (puffed cheeks), eyelid shading.
# Shapes not listed (gaze, jaw sideways, ...) change no albedo: dR_i^true = 0.
DYNAMIC_ALBEDO_KINDS = {
    "browInnerUp": "bands",
    "browOuterUp": "bands",
    "browDown": "bands",
    "eyeSquint": "bands",
    "cheekSquint": "fold",
    "noseSneer": "bands",
    "mouthPucker": "bands",
    "mouthFunnel": "bands",
    "mouthSmile": "fold",
    "mouthDimple": "fold",
    "mouthStretch": "fold",
    "mouthFrown": "fold",
    "mouthShrugLower": "fold",
    "jawOpen": "fold",
    "cheekPuff": "flush",
    "mouthPress": "flush",
    "eyeBlink": "shade",
}


def _kind(name: str) -> str | None:
    for prefix, kind in DYNAMIC_ALBEDO_KINDS.items():
        if name.startswith(prefix):
            return kind
    return None


def _pairs(names: list[str]) -> dict[int, int]:
    """Index of the other side of every `_L`/`_R` blendshape."""
    idx = {n: i for i, n in enumerate(names)}
    out = {}
    for n, i in idx.items():
        for a, b in (("_L", "_R"), ("_R", "_L")):
            if n.endswith(a) and n[: -len(a)] + b in idx:
                out[i] = idx[n[: -len(a)] + b]
    return out


# --- SH lighting (face/src/sh.rs, same constants and order) -------------------------

_A0, _A1, _A2 = math.pi, 2 * math.pi / math.sqrt(3), 2 * math.pi / math.sqrt(8)
_C0, _C1, _C2 = 1 / math.sqrt(4 * math.pi), math.sqrt(3) / math.sqrt(4 * math.pi), 3 * math.sqrt(5) / math.sqrt(12 * math.pi)


def sh_basis(n: np.ndarray) -> np.ndarray:
    """The 9 basis values (constants included) at unit normals [..., 3] -> [..., 9]; the
    renderer's definition, on numpy arrays."""
    return R.sh_basis(torch.as_tensor(np.asarray(n, dtype=np.float64))).numpy()


def irradiance(normals: np.ndarray, gamma: np.ndarray) -> np.ndarray:
    """Irradiance per colour channel: normals [..., 3], gamma [27] -> [..., 3]."""
    return sh_basis(normals) @ gamma.reshape(3, 9).T


def constant_light(rgb) -> np.ndarray:
    """gamma with irradiance exactly `rgb` in every direction (face/src/sh.rs)."""
    g = np.zeros(27)
    g[[0, 9, 18]] = np.asarray(rgb, dtype=np.float64) / (_A0 * _C0)
    return g


def directional_light(direction, rgb) -> np.ndarray:
    """Order-2 SH approximation of irradiance rgb * max(0, n . d) (face/src/sh.rs)."""
    d = np.asarray(direction, dtype=np.float64)
    d = d / np.linalg.norm(d)
    y = sh_basis(d)
    band = np.array([math.pi / _A0**2] + [(2 * math.pi / 3) / _A1**2] * 3 + [(math.pi / 4) / _A2**2] * 5)
    return np.concatenate([c * band * y for c in np.asarray(rgb, dtype=np.float64)])


# --- people --------------------------------------------------------------------------


@dataclass
class Person:
    """One synthetic person's true personal face model.

    The identity is a true per-vertex offset sum_k alpha_k I_k (`identity_coeffs`); `dS0` is
    its UV-space projection (face-part values rasterised into the 128 map), which is what a
    perfect ModelNet dS_0 would be up to F's bilinear resolution (mean round-trip error
    ~0.1 mm over the face). Ground truth shapes use the exact offset, not dS0.
    """

    index: int
    identity_coeffs: torch.Tensor  # [100] alpha_k
    dS0: torch.Tensor  # [3, 128, 128] UV projection of the identity offset (evaluation)
    dS: torch.Tensor  # [53, 3, 128, 128] dS_i^true, 0 where A_i == 0
    dR0: torch.Tensor  # [3, 128, 128] dR_0^true
    dR: torch.Tensor  # [53, 3, 128, 128] dR_i^true, 0 where A_i == 0
    motion_scale: np.ndarray  # [53] s_i: the structured part of dS_i is s_i (S_i - S_0) in UV
    skin_tone: float

    def identity_offset(self, model: FaceModel) -> torch.Tensor:
        """[V, 3] true identity offset on `model`'s vertices (full mesh or face region)."""
        return model.identity_offset(self.identity_coeffs[None])[0]

    def shape(self, model: FaceModel, weights: torch.Tensor) -> torch.Tensor:
        """True vertices [B, V, 3] for weights [B, 53] (before pose): identity offset +
        equation (2) with the true dS_i."""
        b = weights.shape[0]
        return model.shape(
            weights, None, self.dS[None].expand(b, -1, -1, -1, -1), self.identity_coeffs[None].expand(b, -1)
        )

    def blendshapes(self, model: FaceModel) -> torch.Tensor:
        """True corrected blendshape deltas [53, V, 3] (for the personalization metric)."""
        return model.blendshapes(self.dS[None])[0]

    def albedo(self, model: FaceModel, weights: torch.Tensor) -> torch.Tensor:
        """True albedo [B, 3, 512, 512] (equation (3) with dR_0^true, dR_i^true, R_0)."""
        b = weights.shape[0]
        return model.albedo(weights, self.dR0[None].expand(b, -1, -1, -1), self.dR[None].expand(b, -1, -1, -1, -1))


@dataclass
class Frame:
    """One frame's tracking parameters p_n = (w, R, t, gamma) plus the camera."""

    weights: np.ndarray  # [53] in [0, 1], ICT order
    euler: np.ndarray  # [3] (yaw, pitch, roll) radians, R = Rz(roll) Ry(yaw) Rx(pitch)
    translation: np.ndarray  # [3] cm, camera space (t.z < 0)
    gamma: np.ndarray  # [27] SH coefficients [r0..r8, g0..g8, b0..b8]
    focal: float  # pixels at `image_size`
    principal: np.ndarray  # [2] (cx, cy) pixels
    image_size: int

    @property
    def euler_degrees(self) -> np.ndarray:
        return np.degrees(self.euler)


def stack_frames(frames: list[Frame]) -> dict[str, torch.Tensor]:
    """A list of frames as batched float32 tensors (weights [N,53], euler [N,3],
    translation [N,3], gamma [N,27], focal [N], principal [N,2])."""
    t = lambda xs: torch.as_tensor(np.stack(xs), dtype=torch.float32)  # noqa: E731
    return {
        "weights": t([f.weights for f in frames]),
        "euler": t([f.euler for f in frames]),
        "translation": t([f.translation for f in frames]),
        "gamma": t([f.gamma for f in frames]),
        "focal": t([np.float32(f.focal) for f in frames]),
        "principal": t([f.principal for f in frames]),
    }


class SyntheticPeople:
    """Deterministic source of synthetic people and frame groups for one template.

    Derived per-template quantities (A_i, the template deltas and neutral positions in UV,
    lip/brow masks) are computed once here; drawing a person then takes ~0.1 s."""

    def __init__(self, model: FaceModel, seed: int = 0, config: SyntheticConfig | None = None):
        self.seed = int(seed)
        self.config = config or SyntheticConfig()
        self.names = list(model.expression_names)
        self.pairs = _pairs(self.names)
        full = model if model.vertex_count == model.template.vertex_count else FaceModel(model.template, model.fixture)
        self.masks = full.masks.detach().cpu().float()  # A_i [53, 128, 128]
        raster = full.uv_rasterizer(CORRECTION_SIZE)
        with torch.no_grad():
            # Template motion and neutral positions as UV maps (face part only).
            self.delta_uv = raster.to_uv(full.expression_deltas.permute(1, 0, 2).reshape(1, -1, NUM_BLENDSHAPES * 3))
            self.delta_uv = self.delta_uv.reshape(NUM_BLENDSHAPES, 3, CORRECTION_SIZE, CORRECTION_SIZE)
            self.position_uv = raster.to_uv(full.neutral[None])[0]  # [3, 128, 128]
            ids = full.identity_deltas.permute(1, 0, 2).reshape(1, -1, NUM_IDENTITY * 3)
            self.identity_basis_uv = raster.to_uv(ids).reshape(NUM_IDENTITY, 3, CORRECTION_SIZE, CORRECTION_SIZE)
        self.coverage = raster.coverage
        # Mean displacement direction of each blendshape (magnitude-weighted), for the
        # orientation of its wrinkles.
        d = full.template.expression_deltas[:, : full.template.parts["face"][1]]
        mag = np.linalg.norm(d, axis=2, keepdims=True)
        direction = (d * mag).sum(1)
        self.motion_direction = direction / np.maximum(np.linalg.norm(direction, axis=1, keepdims=True), 1e-9)
        # R_0 and lip/brow masks at 128 (area average of the 512 maps).
        r0 = full.mean_albedo_face[None].float()
        self.mean_albedo_128 = F.avg_pool2d(r0, r0.shape[-1] // CORRECTION_SIZE)[0]
        labels = list(full.fixture.parsing_labels)
        t = torch.from_numpy(full.fixture.parsing_map[0].astype(np.int64))

        def label_mask(*names):
            m = sum((t == labels.index(n)).float() for n in names)[None, None]
            return F.avg_pool2d(m, m.shape[-1] // CORRECTION_SIZE)[0, 0]

        r0_512 = full.mean_albedo_face[None].float()
        block = r0_512.shape[-1] // CORRECTION_SIZE
        low = -F.max_pool2d(F.max_pool2d(-r0_512, block), 3, stride=1, padding=1)  # min over footprint
        high = F.max_pool2d(F.max_pool2d(r0_512, block), 3, stride=1, padding=1)
        self.albedo_footprint = (low[0], high[0])
        self.lip_mask = label_mask("upper_lip", "lower_lip")
        self.brow_mask = label_mask("brows")
        face_vertices = full.template.neutral[: full.template.parts["face"][1]]
        self.face_center = face_vertices.mean(0)
        self.face_height = float(np.ptp(face_vertices[:, 1]))
        self.uv_coords = torch.from_numpy(
            np.stack(np.meshgrid(np.arange(CORRECTION_SIZE), np.arange(CORRECTION_SIZE), indexing="xy"), 0)
        ).float()  # [2, 128, 128] (x, y) texel indices

    # -- randomness ----------------------------------------------------------------

    def _rng(self, *keys: int) -> np.random.Generator:
        return np.random.default_rng(np.random.SeedSequence([self.seed, *keys]))

    # -- people --------------------------------------------------------------------

    def person(self, index: int) -> Person:
        rng = self._rng(0, index)
        c = self.config
        k = np.arange(NUM_IDENTITY)
        sigma = c.identity_sigma_head + (c.identity_sigma_tail - c.identity_sigma_head) * k / (NUM_IDENTITY - 1)
        alpha = np.clip(rng.normal(0.0, sigma), -c.identity_clip * sigma, c.identity_clip * sigma)
        dS, scale = self._expression_corrections(rng)
        dR0, tone = self._static_albedo(rng)
        dR = self._dynamic_albedo(rng)
        return Person(
            index=index,
            identity_coeffs=torch.as_tensor(alpha, dtype=torch.float32),
            dS0=self._identity_uv(alpha),
            dS=dS,
            dR0=dR0,
            dR=dR,
            motion_scale=scale,
            skin_tone=tone,
        )

    def _identity_uv(self, alpha: np.ndarray) -> torch.Tensor:
        # The rasterised identity offset is linear in alpha: combine per-component maps.
        return torch.einsum("k,kchw->chw", torch.as_tensor(alpha, dtype=torch.float32), self.identity_basis_uv)

    def _bumps(self, rng, weights_map: torch.Tensor, count: int, sigma_range, channels: int = 3) -> torch.Tensor:
        """Sum of `count` Gaussian bumps with centres drawn with probability ~ weights_map
        and random vector amplitudes in [-1, 1]^channels: a smooth random field in UV."""
        p = weights_map.flatten().double().numpy()
        if p.sum() <= 0:
            return torch.zeros(channels, CORRECTION_SIZE, CORRECTION_SIZE)
        centres = rng.choice(p.size, size=count, p=p / p.sum())
        cy, cx = np.divmod(centres, CORRECTION_SIZE)
        s = rng.uniform(*sigma_range, size=count)
        amp = rng.uniform(-1, 1, size=(count, channels))
        x, y = self.uv_coords[0].numpy(), self.uv_coords[1].numpy()
        g = np.exp(-((x[None] - cx[:, None, None]) ** 2 + (y[None] - cy[:, None, None]) ** 2) / (2 * s[:, None, None] ** 2))
        return torch.from_numpy(np.einsum("kc,khw->chw", amp, g).astype(np.float32))

    def _expression_corrections(self, rng) -> tuple[torch.Tensor, np.ndarray]:
        c = self.config
        # How much further/less this person moves per shape; L/R halves share most of it
        # but differ a little (an asymmetric smile, one brow higher).
        scale = np.clip(rng.normal(0.0, c.motion_scale_sigma, NUM_BLENDSHAPES), -c.motion_scale_clip, c.motion_scale_clip)
        for i, j in self.pairs.items():
            if i < j:
                scale[j] = np.clip(scale[i] + rng.normal(0.0, 0.05), -c.motion_scale_clip, c.motion_scale_clip)
        out = torch.zeros(NUM_BLENDSHAPES, 3, CORRECTION_SIZE, CORRECTION_SIZE)
        for i, name in enumerate(self.names):
            a = self.masks[i]
            # Support: 0 exactly where A_i is 0, 1 once A_i > 0.05, smooth in between.
            t = (a / 0.05).clamp(0, 1)
            support = t * t * (3 - 2 * t)
            cap = c.max_correction_mouth_cm if _is_mouth(name) else c.max_correction_cm
            field = self._bumps(rng, a, int(rng.integers(2, 7)), (4.0, 12.0))
            # sqrt of the summed squares: torch's `norm(dim=0)` over the 3 strided channels
            # is ~80x slower here and was a third of a batch's time.
            field = field / field.square().sum(0).max().sqrt().clamp_min(1e-9) * cap * rng.uniform(0.1, 0.7)
            d = (float(scale[i]) * self.delta_uv[i] + field) * support
            peak = d.square().sum(0).max().sqrt().item()
            if peak > cap:
                d = d * (cap / peak)
            out[i] = d
        return out, scale

    def _static_albedo(self, rng) -> tuple[torch.Tensor, float]:
        c = self.config
        r0 = self.mean_albedo_128
        tone = float(rng.uniform(*c.skin_tone_range))
        # Darker skin is relatively redder/browner in display RGB; plus a small random hue.
        hue = 1.0 + np.array([0.0, -0.06, -0.12]) * (1.0 - tone) + rng.normal(0.0, 0.03, 3)
        target = r0 * torch.as_tensor(tone * hue, dtype=torch.float32)[:, None, None]
        # Low-frequency blotches: redness or brownish patches.
        face = self.coverage.float()
        blotch = self._bumps(rng, face, int(rng.integers(2, 8)), (6.0, 20.0), channels=1)[0]
        colour = np.array([0.04, -0.01, -0.01]) if rng.random() < 0.5 else np.array([-0.03, -0.04, -0.04])
        target = target + torch.as_tensor(colour * rng.uniform(0.2, 1.0), dtype=torch.float32)[:, None, None] * blotch
        # Freckles: small dark dots on the front of the face (nose, cheeks).
        if rng.random() < c.freckle_probability:
            front = ((self.position_uv[2] - 9.0) / 3.0).clamp(0, 1) * face
            n = int(rng.integers(40, 250))
            p = front.flatten().double().numpy()
            centres = rng.choice(p.size, size=n, p=p / p.sum())
            dots = torch.zeros(CORRECTION_SIZE * CORRECTION_SIZE)
            dots[torch.from_numpy(centres)] = torch.from_numpy(rng.uniform(0.3, 1.0, n)).float()
            dots = dots.reshape(1, 1, CORRECTION_SIZE, CORRECTION_SIZE)
            kernel = torch.tensor([[0.05, 0.12, 0.05], [0.12, 0.32, 0.12], [0.05, 0.12, 0.05]])[None, None]
            dots = F.conv2d(dots, kernel, padding=1)[0, 0].clamp(max=1.0)
            target = target + torch.tensor([-0.08, -0.1, -0.1])[:, None, None] * dots * rng.uniform(0.4, 1.0)
        # Lip colour (redder, darker or paler) and brow colour (darker or lighter hair).
        lip = torch.as_tensor([rng.uniform(-0.08, 0.1), rng.uniform(-0.08, 0.02), rng.uniform(-0.05, 0.05)], dtype=torch.float32)
        target = target + lip[:, None, None] * self.lip_mask
        target = target + float(rng.uniform(-0.2, 0.05)) * self.brow_mask
        # Equation (3) adds the 128 map, upsampled, to the 512 R_0, whose fine detail
        # (lash line, brow hairs) is darker or brighter than its 128 average. Bound the
        # correction by the extremes of R_0 under each texel's bilinear footprint (its 4x4
        # block and the neighbours') so the true albedo stays in [0.02, 0.98] at 512.
        d = (target - r0).float()
        low, high = self.albedo_footprint
        return torch.maximum(torch.minimum(d, 0.98 - high), 0.02 - low), tone

    def _dynamic_albedo(self, rng) -> torch.Tensor:
        c = self.config
        age = rng.uniform(0.4, 1.0)  # how pronounced this person's folds are
        out = torch.zeros(NUM_BLENDSHAPES, 3, CORRECTION_SIZE, CORRECTION_SIZE)
        # Folds darken blue/green more than red (blood under compressed skin).
        dark = torch.tensor([0.8, 1.0, 1.05])[:, None, None]
        pos = self.position_uv
        for i, name in enumerate(self.names):
            kind = _kind(name)
            if kind is None:
                continue
            a = self.masks[i]
            amp = c.max_dynamic_albedo * age * rng.uniform(0.5, 1.0)
            if kind == "bands":
                # Lines perpendicular to the motion: the phase runs along the mean
                # displacement direction in 3D, period 0.7-1.5 cm (>= ~5 texels, no aliasing at
                # 128), narrow dark troughs.
                d = torch.as_tensor(self.motion_direction[i], dtype=torch.float32)
                phase = torch.einsum("c,chw->hw", d, pos) * (2 * math.pi / rng.uniform(0.7, 1.5)) + rng.uniform(0, 2 * math.pi)
                band = (0.5 + 0.5 * torch.sin(phase)) ** 4
                # Lines concentrate where the skin moves (compresses) most.
                value = -amp * dark * band * a
            elif kind == "fold":
                # A crease where moving skin meets still skin: A_i in its middle range.
                value = -amp * dark * (4.0 * a * (1.0 - a)) ** 2
            elif kind == "flush":
                value = amp * 0.6 * torch.tensor([1.0, -0.3, -0.3])[:, None, None] * a
            else:  # shade
                value = -amp * 0.5 * dark * a
            out[i] = value.clamp(-c.max_dynamic_albedo, c.max_dynamic_albedo)
        return out

    # -- frames --------------------------------------------------------------------

    def weights(self, rng) -> np.ndarray:
        """Sparse weights in [0, 1]: gaze, blinks, an open jaw (speech), and 1-7 expression
        groups where an `_L`/`_R` shape usually comes with its other half at a similar value."""
        idx = {n: i for i, n in enumerate(self.names)}
        w = np.zeros(NUM_BLENDSHAPES)
        if rng.random() < 0.6:  # gaze: both eyes turn together
            h, v = rng.uniform(-0.8, 0.8), rng.uniform(-0.6, 0.6)
            if h > 0:  # towards the subject's left (+x): left eye out, right eye in
                w[idx["eyeLookOut_L"]], w[idx["eyeLookIn_R"]] = h, h
            else:
                w[idx["eyeLookIn_L"]], w[idx["eyeLookOut_R"]] = -h, -h
            w[idx["eyeLookUp_L" if v > 0 else "eyeLookDown_L"]] = abs(v)
            w[idx["eyeLookUp_R" if v > 0 else "eyeLookDown_R"]] = abs(v)
        r = rng.random()
        if r < 0.15:
            w[idx["eyeBlink_L"]] = w[idx["eyeBlink_R"]] = rng.uniform(0.5, 1.0)
        elif r < 0.2:
            w[idx["eyeBlink_L" if rng.random() < 0.5 else "eyeBlink_R"]] = rng.uniform(0.6, 1.0)
        if rng.random() < self.config.talking_probability:
            w[idx["jawOpen"]] = rng.beta(1.5, 2.0)
        candidates = [i for i, n in enumerate(self.names) if not n.startswith(("eyeLook", "eyeBlink")) and n != "mouthClose"]
        groups = int(rng.integers(self.config.min_expression_groups, self.config.max_expression_groups + 1))
        exclusive = [("jawLeft", "jawRight"), ("mouthLeft", "mouthRight"), ("eyeBlink_L", "eyeWide_L"), ("eyeBlink_R", "eyeWide_R")]
        for i in rng.choice(candidates, size=groups, replace=False):
            value = rng.beta(1.5, 1.5)
            w[i] = max(w[i], value)
            j = self.pairs.get(int(i))
            if j is not None and rng.random() < 0.75:
                w[j] = max(w[j], np.clip(value + rng.normal(0.0, 0.15), 0.0, 1.0))
        for a, b in exclusive:
            if w[idx[a]] > 0 and w[idx[b]] > 0:
                w[idx[b] if rng.random() < 0.5 else idx[a]] = 0.0
        jaw = w[idx["jawOpen"]]
        if jaw > 0 and rng.random() < self.config.mouth_close_probability:
            w[idx["mouthClose"]] = jaw * rng.uniform(0.3, 1.0)
        return np.clip(w, 0.0, 1.0).astype(np.float32)

    def pose(self, rng) -> np.ndarray:
        """(yaw, pitch, roll) radians: mostly near frontal, a third uniform over the range."""
        c = self.config
        limits = np.array([c.max_yaw_deg, c.max_pitch_deg, c.max_roll_deg])
        if rng.random() < 0.35:
            deg = rng.uniform(-limits, limits)
        else:
            deg = np.clip(rng.normal(0.0, limits / 2.5), -limits, limits)
        return np.radians(deg).astype(np.float32)

    def lighting(self, rng) -> np.ndarray:
        """gamma: ambient level 0.5-0.9 plus one directional light 0.1-0.7 from the camera's
        hemisphere, both nearly white (each channel within a few % of the others), as the
        paper's regulariser expects; about `face/src/sh.rs::studio_light`."""
        tint = lambda: np.clip(1.0 + rng.normal(0.0, 0.03, 3), 0.92, 1.08)  # noqa: E731
        ambient = rng.uniform(0.5, 0.9) * tint()
        d = rng.normal(size=3)
        d[2] = abs(d[2]) + 0.3  # light from in front of the face (camera side, +z)
        key = rng.uniform(0.1, 0.7) * tint()
        return (constant_light(ambient) + directional_light(d, key)).astype(np.float32)

    def camera(self, rng, euler: np.ndarray) -> tuple[float, np.ndarray, np.ndarray]:
        """Focal length (field of view 25-40 degrees), the principal point and a
        translation that puts the face centre near the image centre at a distance where
        the face part is ~1.05-1.45 times the image height (`face_fill`)."""
        c = self.config
        size = c.image_size
        fov = math.radians(rng.uniform(*c.fov_deg_range))
        focal = 0.5 * size / math.tan(0.5 * fov)
        principal = np.array([0.5 * size, 0.5 * size])
        if c.principal_jitter > 0:
            principal = principal + rng.normal(0.0, c.principal_jitter * size, 2)
        depth = focal * self.face_height / (c.face_fill * size) * rng.uniform(0.9, 1.25)
        offset = rng.uniform(-0.06, 0.06, 2) * size * depth / focal
        target = np.array([offset[0], offset[1], -depth])
        rot = euler_to_matrix(euler)
        translation = target - rot @ self.face_center
        return float(focal), principal.astype(np.float32), translation.astype(np.float32)

    def frame(self, rng) -> Frame:
        euler = self.pose(rng)
        focal, principal, translation = self.camera(rng, euler)
        return Frame(
            weights=self.weights(rng),
            euler=euler,
            translation=translation,
            gamma=self.lighting(rng),
            focal=focal,
            principal=principal,
            image_size=self.config.image_size,
        )

    def group(self, person_index: int, group_index: int, n: int = 4) -> list[Frame]:
        """N frames of person `person_index` (the paper's N = 4 in training); the same
        arguments always give the same frames."""
        rng = self._rng(1, person_index, group_index)
        return [self.frame(rng) for _ in range(n)]


    def truth(self, model: FaceModel, person: Person, frames: list[Frame]) -> dict[str, torch.Tensor]:
        """Every ground-truth value of one group, for rendering and evaluation: the stacked
        frame parameters (`stack_frames`), `rotation` [N, 3, 3], the person's maps
        (`identity_coeffs`, `dS0`, `dS`, `dR0`, `dR`), and per frame `vertices` [N, V, 3]
        (model space, on `model`'s vertex set), `landmarks_3d` [N, 68, 3] and `albedo`
        [N, 3, 512, 512]."""
        out = stack_frames(frames)
        out["rotation"] = torch.as_tensor(np.stack([euler_to_matrix(f.euler) for f in frames]), dtype=torch.float32)
        with torch.no_grad():
            vertices = model.turn_eyes(person.shape(model, out["weights"]), out["weights"])
            out["vertices"] = vertices
            out["landmarks_3d"] = model.landmarks(vertices)
            out["albedo"] = person.albedo(model, out["weights"])
        for name in ("identity_coeffs", "dS0", "dS", "dR0", "dR"):
            out[name] = getattr(person, name)
        return out


def euler_to_matrix(euler: np.ndarray) -> np.ndarray:
    """R = Rz(roll) Ry(yaw) Rx(pitch) for (yaw, pitch, roll) radians (face/src/camera.rs);
    the renderer's definition, on numpy arrays."""
    e = torch.as_tensor(np.asarray(euler, dtype=np.float64)).reshape(1, 3)
    return R.euler_to_matrix(e)[0].numpy()


# --- after rendering -------------------------------------------------------------------


@dataclass
class ComposeConfig:
    """Image degradations applied after rendering (probabilities and ranges)."""

    background_kinds: tuple[str, ...] = ("noise", "texture", "clutter", "flat")
    image_background_probability: float = 0.3  # when `backgrounds` are given
    blur_probability: float = 0.5
    blur_sigma: tuple[float, float] = (0.3, 1.3)  # pixels
    noise_sigma: tuple[float, float] = (0.0, 0.03)
    jpeg_probability: float = 0.7
    jpeg_quality: tuple[int, int] = (30, 95)


def _background(kind: str, h: int, w: int, rng: np.random.Generator) -> np.ndarray:
    from PIL import Image, ImageDraw

    if kind == "flat":
        return np.broadcast_to(rng.uniform(0, 1, 3), (h, w, 3)).copy()
    if kind == "noise":
        # Coloured noise at 1-3 random scales, upsampled smoothly.
        out = np.zeros((h, w, 3))
        for _ in range(int(rng.integers(1, 4))):
            cells = int(rng.integers(2, max(3, w // 2)))
            small = (rng.uniform(0, 255, (cells, cells, 3))).astype(np.uint8)
            out += np.asarray(Image.fromarray(small).resize((w, h), Image.BILINEAR), dtype=np.float64) / 255.0
        out /= out.max() + 1e-9
        return out * rng.uniform(0.4, 1.0) + rng.uniform(0, 0.3, 3)
    if kind == "texture":
        # Oriented stripes / checks / waves: sums of sinusoids with random colours.
        y, x = np.mgrid[0:h, 0:w] / max(h, w)
        out = np.broadcast_to(rng.uniform(0, 1, 3), (h, w, 3)).copy()
        for _ in range(int(rng.integers(1, 4))):
            theta = rng.uniform(0, math.pi)
            freq = rng.uniform(2, 25)
            wave = np.sin(2 * math.pi * freq * (x * math.cos(theta) + y * math.sin(theta)) + rng.uniform(0, 6.3))
            if rng.random() < 0.3:
                wave = np.sign(wave)
            out += 0.25 * wave[..., None] * rng.uniform(-1, 1, 3)
        return out
    if kind == "clutter":
        # A stand-in for non-face scenes: overlapping rectangles and ellipses.
        img = Image.new("RGB", (w, h), tuple(int(v) for v in rng.integers(0, 256, 3)))
        draw = ImageDraw.Draw(img)
        for _ in range(int(rng.integers(5, 25))):
            x0, y0 = rng.integers(-w // 4, w, 2)
            x1, y1 = x0 + rng.integers(4, w), y0 + rng.integers(4, h)
            colour = tuple(int(v) for v in rng.integers(0, 256, 3))
            (draw.rectangle if rng.random() < 0.5 else draw.ellipse)([int(x0), int(y0), int(x1), int(y1)], fill=colour)
        return np.asarray(img, dtype=np.float64) / 255.0
    raise ValueError(f"unknown background kind {kind!r}")


def _image_background(images, h: int, w: int, rng: np.random.Generator) -> np.ndarray:
    from PIL import Image

    src = np.asarray(images[int(rng.integers(len(images)))])
    if src.dtype != np.uint8:
        src = (np.clip(src, 0, 1) * 255).astype(np.uint8)
    sh, sw = src.shape[:2]
    side = int(rng.integers(max(1, min(sh, sw) // 3), min(sh, sw) + 1))
    y0, x0 = int(rng.integers(0, sh - side + 1)), int(rng.integers(0, sw - side + 1))
    crop = Image.fromarray(src[y0 : y0 + side, x0 : x0 + side, :3])
    return np.asarray(crop.resize((w, h), Image.BILINEAR), dtype=np.float64) / 255.0


def _compose_one(rendered: np.ndarray, mask: np.ndarray, rng, config: ComposeConfig, backgrounds) -> np.ndarray:
    from PIL import Image, ImageFilter

    h, w, _ = rendered.shape
    if backgrounds is not None and len(backgrounds) and rng.random() < config.image_background_probability:
        bg = _image_background(backgrounds, h, w, rng)
    else:
        bg = _background(config.background_kinds[int(rng.integers(len(config.background_kinds)))], h, w, rng)
    m = mask.reshape(h, w, 1)
    img = np.clip(m * rendered + (1.0 - m) * np.clip(bg, 0, 1), 0, 1)
    # Optics: blur; sensor: additive noise; pipeline: 8-bit quantisation and JPEG.
    if rng.random() < config.blur_probability:
        radius = float(rng.uniform(*config.blur_sigma))
        pil = Image.fromarray((img * 255 + 0.5).astype(np.uint8)).filter(ImageFilter.GaussianBlur(radius))
        img = np.asarray(pil, dtype=np.float64) / 255.0
    sigma = float(rng.uniform(*config.noise_sigma))
    img = img + rng.normal(0.0, sigma, img.shape)
    img8 = (np.clip(img, 0, 1) * 255 + 0.5).astype(np.uint8)
    if rng.random() < config.jpeg_probability:
        buf = io.BytesIO()
        Image.fromarray(img8).save(buf, format="JPEG", quality=int(rng.integers(config.jpeg_quality[0], config.jpeg_quality[1] + 1)))
        buf.seek(0)
        img8 = np.asarray(Image.open(buf).convert("RGB"))
    return img8.astype(np.float32) / 255.0


def compose_image(rendered, mask, rng: np.random.Generator, config: ComposeConfig | None = None, backgrounds=None):
    """Turns a rendered face into a training image: background where `mask` is 0 (noise,
    procedural textures, clutter, flat colour, or crops of `backgrounds`, a list of HxWx3
    non-face images), then blur, sensor noise, 8-bit quantisation and JPEG compression.

    rendered: [H, W, 3] or [B, H, W, 3] in [0, 1] (numpy or torch, channels-last like
    render.py); mask: [H, W], [H, W, 1] or batched, in [0, 1] (the face's coverage, soft
    edges allowed). Returns the same type and shape, float32 in [0, 1]. Not differentiable
    (it makes inputs, not predictions). Deterministic in `rng`."""
    config = config or ComposeConfig()
    is_torch = isinstance(rendered, torch.Tensor)
    r = rendered.detach().cpu().numpy() if is_torch else np.asarray(rendered)
    m = mask.detach().cpu().numpy() if isinstance(mask, torch.Tensor) else np.asarray(mask)
    batched = r.ndim == 4
    if not batched:
        r, m = r[None], m[None]
    m = m.reshape(r.shape[0], r.shape[1], r.shape[2]).astype(np.float64)
    out = np.stack([_compose_one(r[i].astype(np.float64), m[i], rng, config, backgrounds) for i in range(r.shape[0])])
    if not batched:
        out = out[0]
    return torch.from_numpy(out).to(rendered.device) if is_torch else out
