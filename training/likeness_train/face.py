"""The template face and the paper's equations (2) and (3) in PyTorch, batched and
differentiable, sharing every derived quantity with the Rust `face` crate.

Two files are read:
- the ICT FaceKit template (`ict_face_model.safetensors`, the same file Rust reads; layout in
  /work/shared/facemodel/README.md and face/src/template.rs): S_0, the 53 expression deltas
  S_i - S_0 in ICT order, the 100 identity deltas, triangles, UVs, landmarks, parts;
- the fixture Rust exports (`likeness export-fixture`, app/src/fixture.rs): the attention
  masks A_i, where every vertex samples the UV maps (F), the mean albedo R_0, the parsing
  map T and a reference evaluation of equations (2) and (3). Masks, F, R_0 and T are not
  rebuilt here on purpose: one implementation (Rust) and a parity test keep the two sides
  from drifting apart.

Map layout: UV maps are channels-first torch tensors [B, C, H, W] with row 0 at v = 1
(face/src/uv.rs), so `grid_sample(align_corners=False, padding_mode="border")` with grid
(2u - 1, 1 - 2v) is exactly Rust's clamped bilinear sampling. Units are centimetres.
"""

from __future__ import annotations

import json
import math
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F

from .render import euler_to_matrix

#: Number of expression blendshapes S_i (ICT FaceKit; the paper's template has 56).
NUM_BLENDSHAPES = 53
#: Number of identity components of the ICT template.
NUM_IDENTITY = 100
#: Side of the UV correction maps dS_0, dS_i, dR_0, dR_i and masks A_i (the paper's 128).
CORRECTION_SIZE = 128
#: The fixture layout this code understands (app/src/fixture.rs FIXTURE_VERSION).
FIXTURE_VERSION = 1
# Gaze: ICT's 53 shapes leave the eyeballs where they are (the eyeLook shapes move the lids
# by < 1 px at 128 px), so the eyeballs are turned by these angles per unit of the eyeLook
# weights, the same in Rust (`face::gaze`, which the renderer and the Live Link export use):
# yaw = (look towards the subject's left) x 30 degrees, pitch = (down - up) x 25 degrees,
# each eye about its own centre, with the signs of the head's yaw and pitch.
GAZE_YAW_DEG_PER_UNIT = 30.0
GAZE_PITCH_DEG_PER_UNIT = 25.0
EYEBALL_PARTS = ("eyeball_left", "eyeball_right")  # the subject's left (+x), right
FIXTURE_FILE = "face_fixture.safetensors"
TEMPLATE_FILE = "ict_face_model.safetensors"

#: Repository root (training/likeness_train/face.py -> ../..).
REPO_ROOT = Path(__file__).resolve().parents[2]
DEFAULT_CACHE = REPO_ROOT / "training" / ".cache"
EXPORT_COMMAND = "cargo run -q -p likeness -- export-fixture --out training/.cache"


class FixtureError(RuntimeError):
    """The fixture is missing, stale or of another layout version."""


def template_path(path: str | os.PathLike | None = None) -> Path:
    """Where the template is, in the same order as Rust (README "The face template"):
    `path`, `$LIKENESS_FACEMODEL`, then ../shared/facemodel/ beside the repository."""
    if path is None:
        env = os.environ.get("LIKENESS_FACEMODEL")
        path = env if env else REPO_ROOT.parent / "shared" / "facemodel" / TEMPLATE_FILE
    p = Path(path)
    if p.is_dir():
        if (p / TEMPLATE_FILE).is_file():
            return p / TEMPLATE_FILE
        # Rust can import the upstream OBJ folder; Python only reads the converted file,
        # which keeps one importer (Rust) for the OBJ format.
        raise FileNotFoundError(
            f"{p} holds no {TEMPLATE_FILE}; the Python side reads only the converted "
            "safetensors template (see README, 'The face template')"
        )
    if not p.is_file():
        raise FileNotFoundError(
            f"face template not found at {p}; set LIKENESS_FACEMODEL to "
            f"{TEMPLATE_FILE} (see README, 'The face template')"
        )
    return p


def fixture_path(path: str | os.PathLike | None = None) -> Path:
    """`path`, `$LIKENESS_FIXTURE`, then training/.cache/face_fixture.safetensors."""
    if path is None:
        path = os.environ.get("LIKENESS_FIXTURE") or DEFAULT_CACHE / FIXTURE_FILE
    p = Path(path)
    return p / FIXTURE_FILE if p.is_dir() else p


def _read_safetensors(path: Path) -> tuple[dict[str, np.ndarray], dict[str, str]]:
    from safetensors import safe_open

    with safe_open(str(path), framework="np") as f:
        meta = f.metadata() or {}
        tensors = {k: f.get_tensor(k) for k in f.keys()}
    return tensors, meta


def _json_list(value) -> list:
    # The template's metadata stores long lists as JSON strings inside the JSON object.
    return json.loads(value) if isinstance(value, str) else list(value)


@dataclass
class Template:
    """The ICT FaceKit template as numpy arrays (centimetres, +y up, +z to the viewer)."""

    neutral: np.ndarray  # [V, 3] S_0
    expression_deltas: np.ndarray  # [53, V, 3] S_i - S_0, ICT order
    identity_deltas: np.ndarray  # [100, V, 3] identity components minus S_0
    triangles: np.ndarray  # [T, 3] int64 vertex indices
    uvs: np.ndarray  # [U, 2] texture coordinates, origin bottom-left
    triangle_uvs: np.ndarray  # [T, 3] int64 indices into uvs
    landmarks_68: np.ndarray  # [68] int64 vertex indices
    parts: dict[str, tuple[int, int]]  # name -> half-open vertex range
    expression_names: list[str]
    identity_names: list[str]
    source: Path

    @property
    def vertex_count(self) -> int:
        return self.neutral.shape[0]

    def face_vertices(self) -> range:
        start, end = self.parts.get("face", (0, self.vertex_count))
        return range(start, end)


def load_template(path: str | os.PathLike | None = None) -> Template:
    p = template_path(path)
    t, meta = _read_safetensors(p)
    info = json.loads(meta["ict_facekit"])
    parts = {q["name"]: (int(q["vertices"][0]), int(q["vertices"][1])) for q in _json_list(info["parts"])}
    names = _json_list(info["expression_names"])
    if len(names) != NUM_BLENDSHAPES:
        raise ValueError(f"{p}: expected {NUM_BLENDSHAPES} expressions, found {len(names)}")
    return Template(
        neutral=t["neutral"].astype(np.float32),
        expression_deltas=t["expression_deltas"].astype(np.float32),
        identity_deltas=t["identity_deltas"].astype(np.float32),
        triangles=t["triangles"].astype(np.int64),
        uvs=t["uv"].astype(np.float32),
        triangle_uvs=t["triangle_uvs"].astype(np.int64),
        landmarks_68=np.asarray(_json_list(info["landmarks_68"]), dtype=np.int64),
        parts=parts,
        expression_names=names,
        identity_names=_json_list(info["identity_names"]),
        source=p,
    )


@dataclass
class Fixture:
    """What Rust exports for the training code (app/src/fixture.rs)."""

    attention_masks: np.ndarray  # [53, 128, 128] A_i
    sample_uv: np.ndarray  # [V, 2] where vertex v samples the maps (F)
    sample_weight: np.ndarray  # [V] 1 on the face, fading on stitched parts, 0 on rigid parts
    mean_albedo: np.ndarray  # [layers, 512, 512, 3] R_0 per UV tile (layer 0 = face)
    parsing_map: np.ndarray  # [layers, 512, 512] uint8 labels T
    triangle_layer: np.ndarray  # [T] albedo layer of each triangle, -1 for none
    triangle_corner_uv: np.ndarray  # [T, 3, 2] corner UVs inside the triangle's layer tile
    face_triangle_ids: np.ndarray  # [Tf] triangles of the face part (UV tile [0, 1]^2)
    ref_weights: np.ndarray  # [53]
    ref_shape_corrections: np.ndarray  # [54, 128, 128, 3] dS_0 then dS_1..dS_53 (channels-last)
    ref_albedo_corrections: np.ndarray  # [54, 128, 128, 3] dR_0 then dR_1..dR_53
    ref_shape: np.ndarray  # [V, 3] equation (2) at ref_weights
    ref_albedo: np.ndarray  # [512, 512, 3] equation (3) at ref_weights on the face layer
    metadata: dict
    source: Path

    @property
    def albedo_layers(self) -> list[str]:
        return list(self.metadata["albedo_layers"])

    @property
    def parsing_labels(self) -> list[str]:
        return list(self.metadata["parsing_labels"])


def load_fixture(path: str | os.PathLike | None = None) -> Fixture:
    p = fixture_path(path)
    if not p.is_file():
        raise FixtureError(f"fixture {p} not found; write it with `{EXPORT_COMMAND}` (or training/setup.sh)")
    t, meta = _read_safetensors(p)
    if "likeness_fixture" not in meta:
        raise FixtureError(f"{p} is not a Likeness fixture (no `likeness_fixture` metadata); regenerate it with `{EXPORT_COMMAND}`")
    info = json.loads(meta["likeness_fixture"])
    version = info.get("version")
    if version != FIXTURE_VERSION:
        raise FixtureError(
            f"{p} has fixture layout version {version}, this code reads version {FIXTURE_VERSION}; "
            f"regenerate it with `{EXPORT_COMMAND}` (and update the training code if Rust changed the layout)"
        )
    info["blendshape_names"] = _json_list(info["blendshape_names"])
    return Fixture(
        attention_masks=t["attention_masks"],
        sample_uv=t["sample_uv"],
        sample_weight=t["sample_weight"],
        mean_albedo=t["mean_albedo"],
        parsing_map=t["parsing_map"],
        triangle_layer=t["triangle_layer"].astype(np.int64),
        triangle_corner_uv=t["triangle_corner_uv"],
        face_triangle_ids=t["face_triangle_ids"].astype(np.int64),
        ref_weights=t["ref_weights"],
        ref_shape_corrections=t["ref_shape_corrections"],
        ref_albedo_corrections=t["ref_albedo_corrections"],
        ref_shape=t["ref_shape"],
        ref_albedo=t["ref_albedo"],
        metadata=info,
        source=p,
    )


def uv_grid(uv: torch.Tensor) -> torch.Tensor:
    """grid_sample coordinates of UV points [..., 2]: x = 2u - 1, y = 1 - 2v (row 0 at v = 1)."""
    return torch.stack([2.0 * uv[..., 0] - 1.0, 1.0 - 2.0 * uv[..., 1]], dim=-1)


def texel_centers(size: int, device=None, dtype=torch.float32) -> torch.Tensor:
    """[size, size, 2] UV of every texel centre: u = (x + 0.5) / W, v = 1 - (y + 0.5) / H."""
    c = (torch.arange(size, device=device, dtype=dtype) + 0.5) / size
    v, u = torch.meshgrid(1.0 - c, c, indexing="ij")
    return torch.stack([u, v], dim=-1)


def resample_uv(maps: torch.Tensor, size: int) -> torch.Tensor:
    """Bilinear resampling of [B, C, h, w] maps at the texel centres of a size x size grid,
    clamped at the edge: what Rust's `UvMap::sample` does at `texel_center_uv`. Equal to
    `F.interpolate(bilinear, align_corners=False)`, which is cheaper than grid_sample."""
    if maps.shape[-1] == size and maps.shape[-2] == size:
        return maps
    return F.interpolate(maps, size=(size, size), mode="bilinear", align_corners=False)


@dataclass
class FaceRegion:
    """The face part of the template (the paper's ~12K-vertex template corresponds to it):
    a vertex subset and the face triangles re-indexed into it. Rendering and losses on this
    region are ~3x cheaper than on the full 26,719-vertex head (docs/training.md)."""

    vertices: torch.Tensor  # [Vf] indices into the full mesh, ascending
    triangles: torch.Tensor  # [Tf, 3] indices into `vertices`
    triangle_ids: torch.Tensor  # [Tf] indices of those triangles in the full mesh
    landmarks_68: torch.Tensor  # [68] indices into `vertices`
    corner_uv: torch.Tensor  # [Tf, 3, 2] corner UVs in the face tile (for texturing)

    def select(self, per_vertex: torch.Tensor, dim: int = -2) -> torch.Tensor:
        """Restricts a per-vertex tensor of the full mesh (vertex axis `dim`) to the region."""
        return per_vertex.index_select(dim, self.vertices.to(per_vertex.device))


class FaceModel(torch.nn.Module):
    """Equations (2) and (3) over a vertex set (the full mesh, or a `FaceRegion` via
    `restricted`). All tensors are buffers, so `.to(device)` moves everything; nothing is
    trainable here (the trainable mean albedo R_0^t belongs to the training model and is
    passed to `albedo`)."""

    def __init__(
        self,
        template: Template,
        fixture: Fixture,
        vertices: np.ndarray | None = None,
        triangles: np.ndarray | None = None,
        landmarks_68: np.ndarray | None = None,
    ):
        super().__init__()
        self.template = template
        self.fixture = fixture
        if template.vertex_count != fixture.sample_uv.shape[0]:
            raise FixtureError(
                f"fixture {fixture.source} was made for a {fixture.sample_uv.shape[0]}-vertex template, "
                f"{template.source} has {template.vertex_count}; regenerate it with `{EXPORT_COMMAND}`"
            )
        idx = np.arange(template.vertex_count) if vertices is None else np.asarray(vertices, dtype=np.int64)
        self.expression_names = list(template.expression_names)
        f32 = lambda a: torch.from_numpy(np.ascontiguousarray(a, dtype=np.float32))  # noqa: E731
        self.register_buffer("vertex_ids", torch.from_numpy(idx))
        self.register_buffer("neutral", f32(template.neutral[idx]))  # S_0
        self.register_buffer("expression_deltas", f32(template.expression_deltas[:, idx]))  # S_i - S_0
        self.register_buffer("identity_deltas", f32(template.identity_deltas[:, idx]))
        self.register_buffer("triangles", torch.from_numpy(template.triangles if triangles is None else triangles))
        self.register_buffer(
            "landmarks_68", torch.from_numpy(template.landmarks_68 if landmarks_68 is None else landmarks_68)
        )
        self.register_buffer("masks", f32(fixture.attention_masks))  # A_i [53, 128, 128]
        # F: grid [1, 1, V, 2] and weight [V, 1] of every vertex, precomputed once.
        self.register_buffer("sample_grid", uv_grid(f32(fixture.sample_uv[idx]))[None, None])
        self.register_buffer("sample_weight", f32(fixture.sample_weight[idx])[:, None])
        # Where each eyeball's vertices are in this vertex set (none on the face region).
        for k, part in enumerate(EYEBALL_PARTS):
            start, end = template.parts.get(part, (0, 0))
            self.register_buffer(f"eyeball_{k}", torch.from_numpy(np.nonzero((idx >= start) & (idx < end))[0]))
        names = {n: i for i, n in enumerate(self.expression_names)}
        # Per eye (left, right): the weights turning it towards +x, -x, down, up.
        self._gaze_channels = [
            [names[f"eyeLook{d}_{side}"] for d in directions]
            for side, directions in (("L", ("Out", "In", "Down", "Up")), ("R", ("In", "Out", "Down", "Up")))
        ]
        # R_0 of the face layer, channels-first [3, 512, 512]: the layer corrections apply to.
        self.register_buffer("mean_albedo_face", f32(fixture.mean_albedo[0]).permute(2, 0, 1).contiguous())

    @classmethod
    def load(cls, template: str | os.PathLike | None = None, fixture: str | os.PathLike | None = None) -> "FaceModel":
        return cls(load_template(template), load_fixture(fixture))

    @property
    def vertex_count(self) -> int:
        return self.neutral.shape[0]

    # --- the face region -------------------------------------------------------------

    def face_region(self) -> FaceRegion:
        """The face part as a `FaceRegion` of the full mesh (fixture `face_triangle_ids`)."""
        if self.vertex_count != self.template.vertex_count:
            raise ValueError("face_region is defined on the full mesh; this model is already restricted")
        tri_ids = self.fixture.face_triangle_ids
        tris = self.template.triangles[tri_ids]
        verts = np.unique(tris)
        remap = np.full(self.template.vertex_count, -1, dtype=np.int64)
        remap[verts] = np.arange(len(verts))
        lm = remap[self.template.landmarks_68]
        if (lm < 0).any():
            raise ValueError("a 68-point landmark lies outside the face part")
        return FaceRegion(
            vertices=torch.from_numpy(verts),
            triangles=torch.from_numpy(remap[tris]),
            triangle_ids=torch.from_numpy(tri_ids),
            landmarks_68=torch.from_numpy(lm),
            corner_uv=torch.from_numpy(np.ascontiguousarray(self.fixture.triangle_corner_uv[tri_ids])),
        )

    def restricted(self, region: FaceRegion | None = None) -> "FaceModel":
        """The same model on the face region only: every method then returns [B, Vf, ...]."""
        region = region or self.face_region()
        return FaceModel(
            self.template,
            self.fixture,
            vertices=region.vertices.numpy(),
            triangles=region.triangles.numpy(),
            landmarks_68=region.landmarks_68.numpy(),
        ).to(self.neutral.device)

    # --- F and equation (2) ----------------------------------------------------------

    def sample_uv(self, maps: torch.Tensor) -> torch.Tensor:
        """F: UV maps [B, C, H, W] -> per-vertex values [B, V, C], bilinear, clamped at the
        edge, times the vertex's sample weight (0 for rigid parts: teeth, eyeballs, ...)."""
        b = maps.shape[0]
        grid = self.sample_grid.to(maps.dtype).expand(b, -1, -1, -1)
        out = F.grid_sample(maps, grid, mode="bilinear", padding_mode="border", align_corners=False)
        return out[:, :, 0].transpose(1, 2) * self.sample_weight.to(maps.dtype)

    def identity_offset(self, identity_coeffs: torch.Tensor) -> torch.Tensor:
        """sum_k alpha_k (I_k - S_0): [B, 100] -> [B, V, 3] (the ICT identity model)."""
        return torch.einsum("bk,kvc->bvc", identity_coeffs, self.identity_deltas.to(identity_coeffs.dtype))

    def weighted_sum(self, weights: torch.Tensor, maps: torch.Tensor) -> torch.Tensor:
        """sum_i w_i A_i maps_i: weights [B, 53], maps [B or P, 53, C, H, W] -> [B, C, H, W].

        Maps may be per image (B) or per person (P, with the B images person-major in
        groups of B / P, as in training): ModelNet predicts one set per person, and
        expanding it to every image first would copy ~40 MB per image for nothing.
        """
        masked = self.masked(maps)
        b, p = weights.shape[0], maps.shape[0]
        if p == b:
            return torch.einsum("bi,bichw->bchw", weights, masked)
        if b % p:
            raise ValueError(f"{b} images cannot be split into groups for {p} people")
        out = torch.einsum("pni,pichw->pnchw", weights.view(p, b // p, -1), masked)
        return out.reshape(b, *out.shape[2:])

    @staticmethod
    def per_image(maps: torch.Tensor, images: int) -> torch.Tensor:
        """Per-person maps [P, ...] repeated for person-major groups of images."""
        return maps if maps.shape[0] == images else maps.repeat_interleave(images // maps.shape[0], dim=0)

    def masked(self, dS: torch.Tensor) -> torch.Tensor:
        """A_i dS_i: [B, 53, C, H, W] -> same shape."""
        return dS * self.masks.to(dS.dtype)[None, :, None]

    def shape(
        self,
        weights: torch.Tensor,
        dS0: torch.Tensor | None = None,
        dS: torch.Tensor | None = None,
        identity_coeffs: torch.Tensor | None = None,
    ) -> torch.Tensor:
        """Equation (2): S = w_0 S_0 + F(dS_0) + sum_i w_i [S_i + F(A_i dS_i)], w_0 = 1 - sum w_i,
        i.e. S_0 + F(dS_0) + sum_i w_i [(S_i - S_0) + F(A_i dS_i)].

        weights [B, 53]; dS0 [B, 3, 128, 128]; dS [B, 53, 3, 128, 128] (dS0 and dS may also
        be per person, see `weighted_sum`); identity_coeffs
        [B, 100] optionally replaces S_0 by the ICT identity S_0 + sum_k alpha_k I_k (the
        expression deltas are added unchanged, as in the ICT light model). Returns [B, V, 3].

        F is linear, so sum_i w_i F(A_i dS_i) = F(sum_i w_i A_i dS_i): the 53 maps are
        combined in UV space and sampled once instead of 53 times.
        """
        out = self.neutral.to(weights.dtype) + torch.einsum(
            "bi,ivc->bvc", weights, self.expression_deltas.to(weights.dtype)
        )
        if identity_coeffs is not None:
            out = out + self.identity_offset(identity_coeffs)
        uv = None
        if dS0 is not None:
            uv = self.per_image(dS0, weights.shape[0])
        if dS is not None:
            combined = self.weighted_sum(weights, dS)
            uv = combined if uv is None else uv + combined
        if uv is not None:
            out = out + self.sample_uv(uv)
        return out

    def gaze_angles(self, weights: torch.Tensor) -> torch.Tensor:
        """(yaw, pitch) radians of each eye for weights [B, 53]: [B, 2 (left, right), 2]
        (`GAZE_YAW_DEG_PER_UNIT`, `GAZE_PITCH_DEG_PER_UNIT`)."""
        eyes = []
        for plus_x, minus_x, down, up in self._gaze_channels:
            yaw = (weights[:, plus_x] - weights[:, minus_x]) * math.radians(GAZE_YAW_DEG_PER_UNIT)
            pitch = (weights[:, down] - weights[:, up]) * math.radians(GAZE_PITCH_DEG_PER_UNIT)
            eyes.append(torch.stack([yaw, pitch], dim=-1))
        return torch.stack(eyes, dim=1)

    def turn_eyes(self, vertices: torch.Tensor, weights: torch.Tensor) -> torch.Tensor:
        """Vertices [B, V, 3] with each eyeball turned by its gaze (`gaze_angles`) about its
        centre: R = Ry(yaw) Rx(pitch), as the head's. The centre is the middle of the
        eyeball's extent across and up, and one radius (half its width) in front of its back:
        its extent front to back includes the cornea's bulge. A vertex set without eyeballs
        (the face region) is returned as it is."""
        angles = self.gaze_angles(weights)
        out = vertices
        for k in range(len(EYEBALL_PARTS)):
            ids = getattr(self, f"eyeball_{k}")
            if ids.numel() == 0:
                continue
            if out is vertices:
                out = vertices.clone()
            eye = vertices.index_select(1, ids)  # [B, E, 3]
            low, high = eye.min(dim=1).values, eye.max(dim=1).values
            centre = 0.5 * (low + high)
            centre[:, 2] = low[:, 2] + 0.5 * (high[:, 0] - low[:, 0])
            rotation = euler_to_matrix(F.pad(angles[:, k], (0, 1)))  # roll 0
            turned = (eye - centre[:, None]) @ rotation.transpose(1, 2) + centre[:, None]
            out[:, ids] = turned
        return out

    def blendshapes(self, dS: torch.Tensor | None = None) -> torch.Tensor:
        """The person's corrected blendshape deltas (S_i - S_0) + F(A_i dS_i): [B, 53, V, 3]
        (what the blendshape gradient loss and the personalization metric compare)."""
        base = self.expression_deltas
        if dS is None:
            return base[None]
        b, n, c, h, w = dS.shape
        sampled = self.sample_uv(self.masked(dS).reshape(b, n * c, h, w))  # [B, V, 53*3]
        sampled = sampled.reshape(b, -1, n, c).permute(0, 2, 1, 3)
        return base.to(dS.dtype)[None] + sampled

    def landmarks(self, vertices: torch.Tensor) -> torch.Tensor:
        """The 68 landmarks of per-vertex positions [B, V, 3] -> [B, 68, 3]."""
        return vertices.index_select(1, self.landmarks_68.to(vertices.device))

    # --- equation (3) ----------------------------------------------------------------

    def albedo_correction(
        self, weights: torch.Tensor, dR0: torch.Tensor | None = None, dR: torch.Tensor | None = None
    ) -> torch.Tensor:
        """dR_0 + sum_i w_i A_i dR_i at 128 x 128: [B, 3, 128, 128]."""
        b = weights.shape[0]
        out = torch.zeros(b, 3, CORRECTION_SIZE, CORRECTION_SIZE, dtype=weights.dtype, device=weights.device)
        if dR0 is not None:
            out = out + self.per_image(dR0, b)
        if dR is not None:
            out = out + self.weighted_sum(weights, dR)
        return out

    def albedo(
        self,
        weights: torch.Tensor,
        dR0: torch.Tensor | None = None,
        dR: torch.Tensor | None = None,
        mean_albedo: torch.Tensor | None = None,
    ) -> torch.Tensor:
        """Equation (3): R = R_0^t + dR_0 + sum_i w_i A_i dR_i on the face layer's grid.

        `mean_albedo` is R_0^t [3, S, S] or [B, 3, S, S] (default: the fixture's R_0 face
        layer, 512 x 512). The 128 x 128 correction is summed first and then sampled at the
        S x S texel centres (bilinear is linear, as in Rust's `FaceModel::albedo`).
        Returns [B, 3, S, S].
        """
        r0 = self.mean_albedo_face.to(weights.dtype) if mean_albedo is None else mean_albedo
        correction = self.albedo_correction(weights, dR0, dR)
        return r0 + resample_uv(correction, r0.shape[-1])

    # --- helpers for UV-space ground truth ------------------------------------------

    def uv_rasterizer(self, size: int = CORRECTION_SIZE) -> "UvRasterizer":
        """A cached texel -> (face triangle, barycentrics) table, to turn per-vertex values
        into UV maps (F's approximate inverse). Built on the full mesh's face triangles."""
        key = f"_uv_rasterizer_{size}"
        if not hasattr(self, key):
            setattr(self, key, UvRasterizer(self.template, self.fixture, size))
        return getattr(self, key)


class UvRasterizer:
    """Per texel of a size x size map of the face tile: the face triangle covering its
    centre (or the nearest covered texel's triangle outside the charts, so bilinear samples
    near chart borders do not pull towards zero) and barycentrics of the per-vertex values.

    `to_uv(values [B, V, C]) -> [B, C, size, size]` is linear and differentiable. It is used
    for ground truth (e.g. the UV-space projection of a synthetic person's identity offset),
    not for the paper's F, which is the fixture's."""

    def __init__(self, template: Template, fixture: Fixture, size: int):
        self.size = size
        tri_ids = fixture.face_triangle_ids
        tris = template.triangles[tri_ids]
        uvs = template.uvs[template.triangle_uvs[tri_ids]]  # [Tf, 3, 2]
        # Rasterize into the texel grid with the corner UV of each triangle; seam vertices
        # have different UVs per triangle but one position, so values stay consistent.
        tri_of_texel, bary = _rasterize_uv(uvs.astype(np.float64), size)
        self.coverage = torch.from_numpy(tri_of_texel >= 0)  # [size, size]
        tri_of_texel, bary = _fill_uncovered(tri_of_texel, bary)
        self.corner_vertices = torch.from_numpy(tris[tri_of_texel.ravel()])  # [size*size, 3]
        self.bary = torch.from_numpy(bary.reshape(-1, 3).astype(np.float32))  # [size*size, 3]

    def to_uv(self, values: torch.Tensor) -> torch.Tensor:
        b, _, c = values.shape
        gathered = values[:, self.corner_vertices.to(values.device)]  # [B, T, 3, C]
        out = (gathered * self.bary.to(values)[None, :, :, None]).sum(2)  # [B, T, C]
        return out.transpose(1, 2).reshape(b, c, self.size, self.size)


def _rasterize_uv(uvs: np.ndarray, size: int) -> tuple[np.ndarray, np.ndarray]:
    """Texel-centre rasterization of UV triangles (face/src/uv.rs `rasterize_uv_triangle`
    convention: row 0 at v = 1, inclusive edges). Vectorised per triangle over its bounding
    box; ~18k small triangles at 128^2 take well under a second."""
    tri_of_texel = np.full((size, size), -1, dtype=np.int64)
    bary = np.zeros((size, size, 3), dtype=np.float64)
    p = np.stack([uvs[..., 0] * size, (1.0 - uvs[..., 1]) * size], axis=-1)  # [T, 3, 2]
    for t in range(p.shape[0]):
        a, b_, c = p[t]
        area = (b_[0] - a[0]) * (c[1] - a[1]) - (b_[1] - a[1]) * (c[0] - a[0])
        if abs(area) < 1e-12:
            continue
        lo = np.minimum(np.minimum(a, b_), c)
        hi = np.maximum(np.maximum(a, b_), c)
        x0, y0 = max(int(np.ceil(lo[0] - 0.5)), 0), max(int(np.ceil(lo[1] - 0.5)), 0)
        x1, y1 = min(int(np.floor(hi[0] - 0.5)), size - 1), min(int(np.floor(hi[1] - 0.5)), size - 1)
        if x1 < x0 or y1 < y0:
            continue
        xs, ys = np.meshgrid(np.arange(x0, x1 + 1) + 0.5, np.arange(y0, y1 + 1) + 0.5)
        w0 = ((b_[0] - xs) * (c[1] - ys) - (b_[1] - ys) * (c[0] - xs)) / area
        w1 = ((c[0] - xs) * (a[1] - ys) - (c[1] - ys) * (a[0] - xs)) / area
        w2 = 1.0 - w0 - w1
        inside = (w0 >= -1e-6) & (w1 >= -1e-6) & (w2 >= -1e-6)
        if not inside.any():
            continue
        iy = (ys[inside] - 0.5).astype(np.int64)
        ix = (xs[inside] - 0.5).astype(np.int64)
        tri_of_texel[iy, ix] = t
        bary[iy, ix] = np.stack([w0[inside], w1[inside], w2[inside]], axis=-1)
    return tri_of_texel, bary


def _fill_uncovered(tri_of_texel: np.ndarray, bary: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Every uncovered texel copies the triangle and barycentrics of its nearest covered
    texel (a nearest-neighbour extension of the charts)."""
    covered = tri_of_texel >= 0
    if covered.all():
        return tri_of_texel, bary
    size = tri_of_texel.shape[0]
    cy, cx = np.nonzero(covered)
    uy, ux = np.nonzero(~covered)
    tri = tri_of_texel.copy()
    out = bary.copy()
    # Chunked brute force: 16k x 16k distances in float32 chunks fit in a few MB at a time.
    for s in range(0, len(uy), 2048):
        d = (uy[s : s + 2048, None] - cy[None]) ** 2 + (ux[s : s + 2048, None] - cx[None]) ** 2
        k = d.argmin(1)
        tri[uy[s : s + 2048], ux[s : s + 2048]] = tri_of_texel[cy[k], cx[k]]
        out[uy[s : s + 2048], ux[s : s + 2048]] = bary[cy[k], cx[k]]
    assert (tri >= 0).all() and tri.shape == (size, size)
    return tri, out
