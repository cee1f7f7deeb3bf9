"""Synthetic people rendered with an arbitrary camera into frames of any size: what the
tracking fixture (fixtures.py) and the held-out clips (clips.py) are made of.

Training renders square 128 px images whose camera frames the face (`SyntheticPeople.camera`);
footage instead has a fixed camera and a face anywhere in it at any size. This module keeps
the training renderer (`data.SyntheticData`'s full head: the person's true shape and albedo,
eyes, teeth, mouth interior, SH light with the display renderer's clamp) and only replaces
the camera: a focal length and principal point for a width x height frame, and a
translation that puts the face centre at a chosen pixel with a chosen height in pixels.

Conventions (render.py, face/src/camera.rs): p_cam = R p + t, R = Rz(roll) Ry(yaw) Rx(pitch)
for euler = (yaw, pitch, roll) radians, camera looking down -z, pixels
u = cx + f X / (-Z), v = cy - f Y / (-Z); model space and translation in cm.
"""

from __future__ import annotations

import copy
import weakref
from dataclasses import dataclass

import numpy as np
import torch

from . import render as R
from .data import SyntheticData
from .face import FaceModel
from .synthetic import Person, SyntheticConfig, SyntheticPeople, euler_to_matrix

# Frames rendered at once: the texture atlas is copied per frame (~19 MB each) and the
# z-buffer is float64 per pixel, so large batches of 640 x 480 frames cost memory, not time.
CHUNK = 6


@dataclass
class Camera:
    """A pinhole camera for a width x height frame (pixels)."""

    width: int
    height: int
    focal: float
    cx: float
    cy: float

    @classmethod
    def centred(cls, width: int, height: int, horizontal_fov_deg: float) -> "Camera":
        """Principal point at the frame centre, focal length from the horizontal field of
        view (face/src/camera.rs `Intrinsics::centered` with `focal_length_px(width, fov)`)."""
        focal = 0.5 * width / np.tan(np.radians(0.5 * horizontal_fov_deg))
        return cls(int(width), int(height), float(focal), 0.5 * width, 0.5 * height)

    def project(self, p_cam: np.ndarray) -> np.ndarray:
        """Camera-space points [..., 3] (cm) -> pixels [..., 2]."""
        p = np.asarray(p_cam, dtype=np.float64)
        depth = -p[..., 2]
        return np.stack([self.cx + self.focal * p[..., 0] / depth, self.cy - self.focal * p[..., 1] / depth], -1)


@dataclass
class Rendered:
    """A batch of frames: the face rendered over nothing, and its truth in the frame."""

    image: np.ndarray  # [N, H, W, 3] float in [0, 1], 0 where no triangle is visible
    coverage: np.ndarray  # [N, H, W] 1 where a triangle is visible
    landmarks: np.ndarray  # [N, 68, 2] true landmarks, frame pixels
    landmarks_camera: np.ndarray  # [N, 68, 3] the same points in camera space (cm)


# The per-template part of SyntheticData / SyntheticPeople (UV rasterisation of the template's
# motion and identity bases, the albedo atlas; ~5 s) does not depend on the seed: built once
# per FaceModel and shared, with the seed (and config) set on a shallow copy. Nothing in
# SyntheticPeople mutates that state after __init__.
_TEMPLATE_STATE: "weakref.WeakKeyDictionary[FaceModel, SyntheticData]" = weakref.WeakKeyDictionary()


def _template_state(model: FaceModel) -> SyntheticData:
    data = _TEMPLATE_STATE.get(model)
    if data is None:
        data = _TEMPLATE_STATE[model] = SyntheticData(model, model, seed=0, image_size=128, frames=1)
    return data


def synthetic_people(model: FaceModel, seed: int, config: SyntheticConfig | None = None) -> SyntheticPeople:
    """`SyntheticPeople(model, seed, config)`, the same people, without recomputing the
    per-template state each time."""
    people = copy.copy(_template_state(model).people)
    people.seed = int(seed)
    people.config = config or SyntheticConfig()
    return people


class SceneRenderer:
    """The training renderer (data.SyntheticData's head, albedo atlas and triangles) for
    people of `seed`, with any camera."""

    def __init__(self, model: FaceModel, seed: int):
        self.model = model
        self.data = _template_state(model)
        self.people: SyntheticPeople = synthetic_people(model, seed)
        self.seed = seed

    def person(self, index: int) -> Person:
        return self.people.person(index)

    def translation_for(self, euler: np.ndarray, camera: Camera, centre_px, face_px: float) -> np.ndarray:
        """The translation that puts the template face's centre at pixel `centre_px` with
        the face (the template face part's height, as `SyntheticConfig.face_fill` measures
        it) `face_px` pixels tall at that depth; as `SyntheticPeople.camera` does for the
        training images."""
        depth = camera.focal * self.people.face_height / float(face_px)
        u, v = float(centre_px[0]), float(centre_px[1])
        target = np.array([(u - camera.cx) * depth / camera.focal, -(v - camera.cy) * depth / camera.focal, -depth])
        return (target - euler_to_matrix(euler) @ self.people.face_center).astype(np.float32)

    def render(self, person: Person, weights, euler, translation, gamma, camera: Camera) -> Rendered:
        """Frames of `person` with weights [N, 53], euler [N, 3], translation [N, 3] (cm,
        this camera's), gamma [N, 27], rendered at camera.width x camera.height."""
        t = lambda x: torch.as_tensor(np.asarray(x), dtype=torch.float32)  # noqa: E731
        weights, euler, translation, gamma = t(weights), t(euler), t(translation), t(gamma)
        parts = [self._render_chunk(person, weights[i : i + CHUNK], euler[i : i + CHUNK], translation[i : i + CHUNK], gamma[i : i + CHUNK], camera) for i in range(0, weights.shape[0], CHUNK)]
        return Rendered(*(np.concatenate([getattr(p, f) for p in parts]) for f in ("image", "coverage", "landmarks", "landmarks_camera")))

    def _render_chunk(self, person, weights, euler, translation, gamma, camera: Camera) -> Rendered:
        d = self.data
        n = weights.shape[0]
        rotation = R.euler_to_matrix(euler)
        image = np.zeros((n, camera.height, camera.width, 3), np.float32)
        coverage = np.zeros((n, camera.height, camera.width), np.float32)
        with torch.no_grad():
            vertices = person.shape(self.model, weights)
            lm_cam = R.transform(self.model.landmarks(vertices), rotation, translation)
            landmarks, _ = R.project_camera(lm_cam, camera.focal, camera.cx, camera.cy)
            # Only the window the head projects into is rendered (shading every pixel of a
            # 640 x 480 frame cost 3x more): the same camera with the principal point moved
            # by the window's integer origin, so pixel centres stay where they were.
            pixels, depth = R.project(vertices, rotation, translation, camera.focal, camera.cx, camera.cy)
            front = pixels[depth > R.NEAR]
            if front.numel():
                x0, y0 = (int(max(0, np.floor(v) - 2)) for v in front.min(0).values.tolist())
                x1 = int(min(camera.width, np.ceil(front[:, 0].max().item()) + 2))
                y1 = int(min(camera.height, np.ceil(front[:, 1].max().item()) + 2))
                if x1 > x0 and y1 > y0:
                    albedo = person.albedo(self.model, weights)
                    texture = d.atlas.expand(n, -1, -1, -1).clone()
                    texture[..., : d.layer_width] = albedo
                    out = R.render(
                        vertices, d.triangles, d.corner_uv, texture, gamma, rotation, translation,
                        camera.focal, camera.cx - x0, camera.cy - y0, y1 - y0, x1 - x0, clamp_irradiance=True,
                    )
                    image[:, y0:y1, x0:x1] = out.image.clamp(0, 1).numpy()
                    coverage[:, y0:y1, x0:x1] = out.coverage.numpy()
        return Rendered(image, coverage, landmarks.numpy(), lm_cam.numpy())


def to_uint8(image: np.ndarray) -> np.ndarray:
    """compose_image's float32 output (exact multiples of 1/255) back to its 8 bits."""
    return np.clip(np.rint(np.asarray(image, dtype=np.float64) * 255.0), 0, 255).astype(np.uint8)


def landmark_box(landmarks: np.ndarray) -> list[float]:
    """[x, y, w, h] bounding box of the 68 landmarks [68, 2]."""
    lo, hi = landmarks.min(0), landmarks.max(0)
    return [float(lo[0]), float(lo[1]), float(hi[0] - lo[0]), float(hi[1] - lo[1])]
