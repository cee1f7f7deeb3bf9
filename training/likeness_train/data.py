"""Training and evaluation batches: synthetic people rendered into images with every
ground-truth value kept (the data the paper got from 94k real videos).

A batch is P people x N frames. Images are rendered on the full head (eyes, teeth and
mouth interior included, so the face looks like a face) with the person's true albedo
(equation (3) with their dR_0, dR_i) and composited over a background with blur, noise and
compression. The 2D landmarks and the parsing image come from the same render.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np
import torch
import torch.nn.functional as F

from . import render as R
from .face import FaceModel
from .synthetic import ComposeConfig, SyntheticConfig, SyntheticPeople, compose_image

# Layers of the fixture's mean albedo (face, head, gums+tongue, teeth, eyeball, eyelashes);
# eyelashes are alpha cards and are not drawn (as in the Rust renderer).
EYELASH_LAYER = 5


@dataclass
class Batch:
    """P people x N frames; per-frame tensors have a leading axis of P*N (person-major)."""

    images: torch.Tensor  # [P*N, 3, H, W] in [0, 1]
    landmarks: torch.Tensor  # [P*N, 68, 2] pixels
    parsing: torch.Tensor  # [P*N, H, W, K] soft one-hot
    weights: torch.Tensor  # [P*N, 53]
    euler: torch.Tensor  # [P*N, 3]
    translation: torch.Tensor  # [P*N, 3]
    gamma: torch.Tensor  # [P*N, 27]
    focal: torch.Tensor  # [P*N]
    principal: torch.Tensor  # [P*N, 2]
    # The person-level ground truth below is evaluation-only (training is self-supervised)
    # and large (~10 MB of maps per person), so a cached batch may leave it as None and
    # recompute it from the person index (`SyntheticData.person_truth`).
    vertices: torch.Tensor | None  # [P*N, Vf, 3] true model-space face-region vertices
    dS: torch.Tensor | None  # [P, 53, 3, 128, 128] true expression corrections
    dR0: torch.Tensor | None  # [P, 3, 128, 128]
    dR: torch.Tensor | None  # [P, 53, 3, 128, 128]
    identity_coeffs: torch.Tensor  # [P, 100]
    people: int
    frames: int
    index: int = -1  # batch index k (people k*P .. k*P + P - 1)


# --- photometric augmentation -------------------------------------------------------------

# At strength 1: the per-image, per-colour gain's log standard deviation, the largest
# sensor-noise standard deviation (of [0, 1] pixels), the probability of a blur and its
# range of Gaussian sigmas (px). Mild on purpose: the held-out frames are clean renders,
# so these only have to keep the network from learning the exact pixels of the ~4 views of
# each cached image it sees over a fine-tune (issue 31's seen/unseen gap, 0.041 / 0.0465).
AUGMENT_GAIN_LOG_SD = 0.15
AUGMENT_NOISE_MAX = 0.03
AUGMENT_BLUR_PROBABILITY = 0.3
AUGMENT_BLUR_SIGMA = (0.3, 0.9)


def photometric_batch(batch: Batch, strength: float, generator: torch.Generator) -> Batch:
    """The batch's images with a per-image colour gain, sensor noise and sometimes a slight
    blur, drawn from `generator` at `strength` in [0, 1] (0 returns the batch unchanged).

    The gain multiplies the whole image, which is what scaling that colour's SH lighting
    does to a Lambertian render (shading is linear in gamma), so the light target gamma is
    scaled by the same gain and stays the truth of the image; the background (not lit by
    gamma) is scaled too, as a camera's white balance would. Noise and blur change no
    label. Geometry is untouched: landmarks, pose and w stay exact."""
    if not 0.0 <= strength <= 1.0:
        raise ValueError(f"augmentation strength must be within [0, 1], got {strength}")
    if strength == 0.0:
        return batch
    images = batch.images
    n = images.shape[0]
    gain = torch.exp(torch.randn(n, 3, generator=generator) * (AUGMENT_GAIN_LOG_SD * strength))
    out = images * gain[:, :, None, None]
    sigma_noise = torch.rand(n, generator=generator) * (AUGMENT_NOISE_MAX * strength)
    out = out + torch.randn(out.shape, generator=generator) * sigma_noise[:, None, None, None]
    blur = torch.rand(n, generator=generator) < AUGMENT_BLUR_PROBABILITY * strength
    low, high = AUGMENT_BLUR_SIGMA
    sigma_blur = low + (high - low) * torch.rand(n, generator=generator)
    if bool(blur.any()):
        offsets = torch.arange(-2, 3, dtype=torch.float32)
        kernels = torch.exp(-0.5 * (offsets[None] / sigma_blur[:, None]) ** 2)
        kernels = kernels / kernels.sum(1, keepdim=True)  # [n, 5], separable
        blurred = []
        for i in torch.nonzero(blur).flatten().tolist():
            k = kernels[i]
            x = F.pad(out[i : i + 1], (2, 2, 2, 2), mode="replicate")
            x = F.conv2d(x, k.view(1, 1, 1, 5).expand(3, 1, 1, 5), groups=3)
            x = F.conv2d(x, k.view(1, 1, 5, 1).expand(3, 1, 5, 1), groups=3)
            blurred.append((i, x[0]))
        out = out.clone()
        for i, x in blurred:
            out[i] = x
    gamma = batch.gamma * gain.repeat_interleave(9, dim=1)
    return dataclasses.replace(batch, images=out.clamp(0.0, 1.0), gamma=gamma)


# --- mirrored batches ---------------------------------------------------------------------

# The iBUG 68-point scheme's left-right correspondence: landmark k of a face seen in a
# mirror is landmark MIRROR_68[k] of the face (jaw, brows, nose, eyes, lips).
MIRROR_68 = (
    list(range(16, -1, -1))
    + list(range(26, 16, -1))
    + [27, 28, 29, 30]
    + [35, 34, 33, 32, 31]
    + [45, 44, 43, 42, 47, 46, 39, 38, 37, 36, 41, 40]
    + [54, 53, 52, 51, 50, 49, 48, 59, 58, 57, 56, 55]
    + [64, 63, 62, 61, 60, 67, 66, 65]
)
# SH coefficients of basis functions odd in x (x, xy, xz; face/src/sh.rs order), per colour.
SH_ODD_IN_X = (3, 4, 7)


def mirror_channels(names: list[str]) -> list[int]:
    """For each blendshape, the one that does the same on the other side (`_L` <-> `_R`,
    jawLeft <-> jawRight, mouthLeft <-> mouthRight); itself when symmetric."""
    idx = {n: i for i, n in enumerate(names)}
    out = []
    for n in names:
        other = n
        for a, b in (("_L", "_R"), ("_R", "_L"), ("Left", "Right"), ("Right", "Left")):
            if n.endswith(a):
                other = n[: -len(a)] + b
                break
        out.append(idx.get(other, idx[n]))
    return out


def mirror_batch(batch: Batch, flip: torch.Tensor, channels: list[int]) -> Batch:
    """The batch with the images where `flip` [P*N] is set seen in a mirror: images and
    parsing flipped left-right, landmarks mirrored and renumbered (MIRROR_68), w with its
    left and right channels swapped (`mirror_channels`), yaw and roll negated, translation's
    x negated, the principal point mirrored, the light's x-odd SH terms negated. It is the
    truth of the mirrored person (an identity mirrored too), which supervised and
    self-supervised terms alike may use; the per-person maps and true vertices stay as they
    were (evaluation reads them from unflipped batches only)."""
    if not bool(flip.any()):
        return batch
    f = flip.view(-1)
    width = batch.images.shape[-1]
    images = torch.where(f[:, None, None, None], batch.images.flip(-1), batch.images)
    parsing = torch.where(f[:, None, None, None], batch.parsing.flip(2), batch.parsing)
    mirrored = batch.landmarks[:, MIRROR_68].clone()
    mirrored[..., 0] = width - mirrored[..., 0]
    landmarks = torch.where(f[:, None, None], mirrored, batch.landmarks)
    weights = torch.where(f[:, None], batch.weights[:, channels], batch.weights)
    euler = torch.where(f[:, None], batch.euler * torch.tensor([-1.0, 1.0, -1.0]), batch.euler)
    translation = torch.where(f[:, None], batch.translation * torch.tensor([-1.0, 1.0, 1.0]), batch.translation)
    principal = batch.principal.clone()
    principal[f, 0] = width - principal[f, 0]
    sign = torch.ones(27)
    for colour in range(3):
        sign[[9 * colour + k for k in SH_ODD_IN_X]] = -1.0
    gamma = torch.where(f[:, None], batch.gamma * sign, batch.gamma)
    return dataclasses.replace(
        batch, images=images, parsing=parsing, landmarks=landmarks, weights=weights, euler=euler,
        translation=translation, principal=principal, gamma=gamma,
    )


PER_FRAME = ("images", "landmarks", "parsing", "weights", "euler", "translation", "gamma", "focal", "principal")
PER_PERSON_TRUTH = ("vertices", "dS", "dR0", "dR")


def concat_batches(batches: list[Batch]) -> Batch:
    """One batch of all the people of `batches` (same N frames each), in order; the
    person-level truth is kept only when every batch has it. Its index is the first's."""
    if not batches:
        raise ValueError("concat_batches needs at least one batch")
    frames = {b.frames for b in batches}
    if len(frames) != 1:
        raise ValueError(f"batches of different frame counts cannot be joined: {sorted(frames)}")
    joined = {key: torch.cat([getattr(b, key) for b in batches]) for key in PER_FRAME + ("identity_coeffs",)}
    for key in PER_PERSON_TRUTH:
        parts = [getattr(b, key) for b in batches]
        joined[key] = torch.cat(parts) if all(p is not None for p in parts) else None
    return Batch(**joined, people=sum(b.people for b in batches), frames=batches[0].frames, index=batches[0].index)


class SyntheticData:
    """Deterministic batches: batch k of seed s is always the same, so training resumes
    exactly and held-out people are simply another seed."""

    def __init__(self, model: FaceModel, region: FaceModel, seed: int, image_size: int, frames: int, compose: ComposeConfig | None = None):
        self.model = model
        self.region = region
        self.image_size = image_size
        self.frames = frames
        self.people = SyntheticPeople(model, seed=seed, config=SyntheticConfig(image_size=image_size))
        self.compose = compose or ComposeConfig()
        self.seed = seed
        fixture = model.fixture
        layer = torch.from_numpy(np.asarray(fixture.triangle_layer)).long()
        drawn = (layer >= 0) & (layer != EYELASH_LAYER)
        self.triangles = model.triangles[drawn].long()
        layers = fixture.mean_albedo.shape[0]
        # One texture atlas, the layers side by side, so one texture lookup serves all parts.
        corner_uv = torch.from_numpy(np.asarray(fixture.triangle_corner_uv))[drawn].float()
        corner_layer = layer[drawn].float()[:, None]
        u = (corner_uv[..., 0].clamp(0, 1) + corner_layer) / layers
        self.corner_uv = torch.stack([u, corner_uv[..., 1]], dim=-1)
        atlas = torch.from_numpy(np.asarray(fixture.mean_albedo)).float()  # [L, h, w, 3]
        self.atlas = torch.cat(list(atlas.permute(0, 3, 1, 2)), dim=-1)  # [3, h, L*w]
        self.layer_width = atlas.shape[2]
        parsing = torch.from_numpy(np.asarray(fixture.parsing_map)).long()  # [L, h, w]
        k = len(fixture.parsing_labels)
        onehot = F.one_hot(parsing, k).permute(0, 3, 1, 2).float()  # [L, K, h, w]
        # The prediction is rendered on the face region only, so the target parsing image
        # labels only what that region can cover: other parts (back of the head, mouth
        # interior, eyeballs) parse as nothing. Otherwise their pixels would be a floor of
        # L_pa that no prediction can reduce, and its gradient would pull the face outline
        # over the neck and the back of the head.
        target = onehot.clone()
        target[1:] = 0
        self.parsing_atlas = torch.cat(list(target), dim=-1)[None]  # [1, K, h, L*w]
        # The face layer's parsing map T for rendering predictions on the face region.
        self.parsing_face = onehot[0][None]
        self.labels = k

    def batch(self, index: int, people: int) -> Batch:
        rng = np.random.default_rng([self.seed, 7, index])
        items = []
        for p in range(people):
            person = self.people.person(index * people + p)
            frames = self.people.group(index * people + p, 0, self.frames)
            items.append((person, self.people.truth(self.model, person, frames)))
        truth = {key: torch.cat([t[key] for _, t in items]) for key in ("weights", "euler", "translation", "gamma", "focal", "principal", "vertices", "landmarks_3d", "albedo", "rotation")}
        n = truth["weights"].shape[0]
        texture = self.atlas.expand(n, -1, -1, -1).clone()
        texture[..., : self.layer_width] = truth["albedo"]
        size = self.image_size
        with torch.no_grad():
            out = R.render(
                truth["vertices"], self.triangles, self.corner_uv, texture, truth["gamma"], truth["rotation"], truth["translation"],
                truth["focal"], truth["principal"][:, 0], truth["principal"][:, 1], size, size,
                parsing_texture=self.parsing_atlas, clamp_irradiance=True,
            )
            pixels, _ = R.project(truth["landmarks_3d"], truth["rotation"], truth["translation"], truth["focal"], truth["principal"][:, 0], truth["principal"][:, 1])
        rendered = out.image.clamp(0, 1).numpy()
        images = compose_image(rendered, out.coverage.numpy(), rng, self.compose)
        images = torch.as_tensor(np.asarray(images), dtype=torch.float32).permute(0, 3, 1, 2).contiguous()
        region_vertices = self.region_vertices(truth["vertices"])
        stack = lambda key: torch.stack([getattr(person, key) for person, _ in items])  # noqa: E731
        return Batch(
            images=images, landmarks=pixels, parsing=out.parsing, weights=truth["weights"], euler=truth["euler"],
            translation=truth["translation"], gamma=truth["gamma"], focal=truth["focal"], principal=truth["principal"],
            vertices=region_vertices, dS=stack("dS"), dR0=stack("dR0"), dR=stack("dR"), identity_coeffs=stack("identity_coeffs"),
            people=people, frames=self.frames, index=index,
        )

    def person_truth(self, index: int, people: int, weights: torch.Tensor) -> dict[str, torch.Tensor]:
        """The person-level ground truth of batch `index` recomputed from the person indices
        (deterministic, ~0.15 s per person): `vertices` [P*N, Vf, 3] for the true weights
        [P*N, 53] (on the face region directly, 3x cheaper than the full head and equal to
        `batch`'s to float rounding), `dS`, `dR0`, `dR`, `identity_coeffs`."""
        persons = [self.people.person(index * people + p) for p in range(people)]
        n = self.frames
        with torch.no_grad():
            vertices = torch.cat([person.shape(self.region, weights[p * n : (p + 1) * n]) for p, person in enumerate(persons)])
        out = {"vertices": vertices}
        for key in ("dS", "dR0", "dR", "identity_coeffs"):
            out[key] = torch.stack([getattr(person, key) for person in persons])
        return out

    def region_vertices(self, full_vertices: torch.Tensor) -> torch.Tensor:
        return full_vertices.index_select(1, self.region.vertex_ids)
