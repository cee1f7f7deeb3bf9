"""Differentiable renderer R of the paper (section 3.3), on the CPU.

Two passes, because a z-buffer is not differentiable but what it selects is:
1. `rasterize`: a numba z-buffer decides, per pixel, which triangle is visible (no
   gradients; visibility is piecewise constant in the vertex positions anyway).
2. `interpolate` / `Fragments`: torch recomputes the perspective-correct barycentrics of
   that triangle at the pixel centre from the projected vertices, so every interpolated
   quantity (position, normal, UV, hence albedo and parsing labels) is a differentiable
   function of the vertex positions, the per-vertex attributes and the UV maps.
   As with the paper's TF mesh renderer there are no silhouette-edge gradients; the
   landmark and parsing losses carry the contour (docs/training.md).

Conventions (identical to the Rust `face` crate):
- camera (face/src/camera.rs): camera at the origin looking down -z, +y up, +x right;
  p_cam = R p + t with R = Rz(roll) Ry(yaw) Rx(pitch) for euler = (yaw, pitch, roll)
  in radians; pixels u = cx + f X / (-Z), v = cy - f Y / (-Z); depth = -Z > 0.
  Pixel (x, y) covers [x, x+1) x [y, y+1), its centre is (x + 0.5, y + 0.5).
- winding: ICT triangles are counter-clockwise seen from outside (their cross products
  point out of the face). Because image rows go down, a front-facing triangle has a
  negative signed area (p1 - p0) x (p2 - p0) in pixel coordinates; back-face culling
  drops the others.
- SH (face/src/sh.rs): 27 coefficients [r_0..r_8, g_0..g_8, b_0..b_8], colour = albedo *
  sum_k gamma_ck Y_k(n), normals in camera space (as renderer/src/face.wgsl).
- UV (face/src/uv.rs): texel row 0 at v = 1; bilinear sampling equals
  grid_sample(align_corners=False, padding_mode="border") with grid (2u - 1, 1 - 2v).

Images are channels-last [B, H, W, C], like the losses in `losses.py`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numba
import numpy as np
import torch
import torch.nn.functional as F

# ----------------------------------------------------------------------------- camera


def _rot_x(a: torch.Tensor) -> torch.Tensor:
    c, s = torch.cos(a), torch.sin(a)
    o, z = torch.ones_like(a), torch.zeros_like(a)
    return torch.stack([o, z, z, z, c, -s, z, s, c], -1).reshape(*a.shape, 3, 3)


def _rot_y(a: torch.Tensor) -> torch.Tensor:
    c, s = torch.cos(a), torch.sin(a)
    o, z = torch.ones_like(a), torch.zeros_like(a)
    return torch.stack([c, z, s, z, o, z, -s, z, c], -1).reshape(*a.shape, 3, 3)


def _rot_z(a: torch.Tensor) -> torch.Tensor:
    c, s = torch.cos(a), torch.sin(a)
    o, z = torch.ones_like(a), torch.zeros_like(a)
    return torch.stack([c, -s, z, s, c, z, z, z, o], -1).reshape(*a.shape, 3, 3)


def euler_to_matrix(euler: torch.Tensor) -> torch.Tensor:
    """[B, 3] (yaw, pitch, roll) in radians -> R = Rz(roll) Ry(yaw) Rx(pitch), [B, 3, 3]
    (right-handed rotations about +y, +x, +z, exactly glam's from_rotation_* in camera.rs)."""
    yaw, pitch, roll = euler.unbind(-1)
    return _rot_z(roll) @ _rot_y(yaw) @ _rot_x(pitch)


def _per_batch(x, like: torch.Tensor) -> torch.Tensor:
    """A float or [B] tensor of intrinsics as a [B, 1] tensor broadcasting over vertices."""
    x = torch.as_tensor(x, dtype=like.dtype, device=like.device)
    return x.reshape(-1, 1) if x.dim() > 0 else x


def transform(points: torch.Tensor, rotation: torch.Tensor, translation: torch.Tensor) -> torch.Tensor:
    """Model space [B, V, 3] -> camera space R p + t."""
    return points @ rotation.transpose(1, 2) + translation.unsqueeze(1)


def project_camera(p_cam: torch.Tensor, focal, cx, cy) -> tuple[torch.Tensor, torch.Tensor]:
    """Camera-space points [B, V, 3] -> (pixels [B, V, 2], depth = -Z [B, V])."""
    depth = -p_cam[..., 2]
    # Clamping only guards against division by ~0 for points behind the camera; the
    # rasterizer discards triangles with a vertex at depth <= near anyway.
    inv = 1.0 / depth.clamp_min(1e-6)
    f, cx, cy = (_per_batch(a, p_cam) for a in (focal, cx, cy))
    u = cx + f * p_cam[..., 0] * inv
    v = cy - f * p_cam[..., 1] * inv
    return torch.stack([u, v], -1), depth


def project(points, rotation, translation, focal, cx, cy) -> tuple[torch.Tensor, torch.Tensor]:
    """Model-space points [B, V, 3] -> (pixels [B, V, 2], depth [B, V]); the camera Phi
    applied to R p + t. focal, cx, cy: floats or [B] tensors (pixels)."""
    return project_camera(transform(points, rotation, translation), focal, cx, cy)


# ----------------------------------------------------------------------------- rasterizer

# Triangles with a vertex closer than this (same units as depth) are not drawn: there is
# no clipping, and a vertex at or behind the camera plane has no meaningful projection.
NEAR = 1e-3


@numba.njit(parallel=True, cache=True, nogil=True)
def _raster_kernel(pix, depth, tris, height, width, cull, near, tri_id, bary, zbuf):
    n_batch = pix.shape[0]
    n_tri = tris.shape[0]
    # One image per thread: images are independent, so no locking on the z-buffer.
    for b in numba.prange(n_batch):
        for f in range(n_tri):
            i0, i1, i2 = tris[f, 0], tris[f, 1], tris[f, 2]
            z0, z1, z2 = depth[b, i0], depth[b, i1], depth[b, i2]
            if not (z0 > near and z1 > near and z2 > near):  # also rejects NaN
                continue
            x0, y0 = pix[b, i0, 0], pix[b, i0, 1]
            x1, y1 = pix[b, i1, 0], pix[b, i1, 1]
            x2, y2 = pix[b, i2, 0], pix[b, i2, 1]
            area = (x1 - x0) * (y2 - y0) - (y1 - y0) * (x2 - x0)
            if not (area != 0.0 and math.isfinite(area)):
                continue
            if cull and area > 0.0:  # front faces have negative area (rows go down)
                continue
            # Pixel centres (x + 0.5) inside the bounding box, clipped to the image.
            xmin = max(int(math.ceil(min(x0, x1, x2) - 0.5)), 0)
            xmax = min(int(math.floor(max(x0, x1, x2) - 0.5)), width - 1)
            ymin = max(int(math.ceil(min(y0, y1, y2) - 0.5)), 0)
            ymax = min(int(math.floor(max(y0, y1, y2) - 0.5)), height - 1)
            if xmin > xmax or ymin > ymax:
                continue
            iz0, iz1, iz2 = 1.0 / z0, 1.0 / z1, 1.0 / z2
            inv_area = 1.0 / area
            for y in range(ymin, ymax + 1):
                py = y + 0.5
                for x in range(xmin, xmax + 1):
                    px = x + 0.5
                    # Screen-space barycentrics from the edge functions; edges inclusive
                    # so that neighbouring triangles leave no cracks.
                    w0 = ((x1 - px) * (y2 - py) - (y1 - py) * (x2 - px)) * inv_area
                    w1 = ((x2 - px) * (y0 - py) - (y2 - py) * (x0 - px)) * inv_area
                    w2 = 1.0 - w0 - w1
                    if w0 < 0.0 or w1 < 0.0 or w2 < 0.0:
                        continue
                    # 1/depth is affine in screen space: the exact depth at the pixel
                    # centre, compared as "larger 1/depth is nearer".
                    iz = w0 * iz0 + w1 * iz1 + w2 * iz2
                    if iz > zbuf[b, y, x]:
                        zbuf[b, y, x] = iz
                        tri_id[b, y, x] = f
                        # Perspective-correct barycentrics (informative only; the
                        # differentiable ones come from `Fragments`).
                        bary[b, y, x, 0] = w0 * iz0 / iz
                        bary[b, y, x, 1] = w1 * iz1 / iz
                        bary[b, y, x, 2] = w2 * iz2 / iz


def rasterize(
    pixels: torch.Tensor,
    depth: torch.Tensor,
    triangles: torch.Tensor,
    height: int,
    width: int,
    cull_backfaces: bool = False,
) -> tuple[torch.Tensor, torch.Tensor]:
    """Z-buffer visibility (not differentiable).

    pixels [B, V, 2], depth [B, V] (positive in front of the camera), triangles [T, 3].
    Returns tri_id [B, H, W] int32 (-1 = background) and perspective-correct barycentrics
    [B, H, W, 3] (zero in the background). With `cull_backfaces`, triangles whose pixel-space
    signed area is positive (clockwise on screen = facing away for CCW meshes such as ICT)
    are skipped.
    """
    pix = np.ascontiguousarray(pixels.detach().cpu().numpy(), dtype=np.float64)
    dep = np.ascontiguousarray(depth.detach().cpu().numpy(), dtype=np.float64)
    tris = np.ascontiguousarray(torch.as_tensor(triangles).cpu().numpy(), dtype=np.int64)
    n_batch = pix.shape[0]
    tri_id = np.full((n_batch, height, width), -1, dtype=np.int32)
    bary = np.zeros((n_batch, height, width, 3), dtype=np.float64)
    zbuf = np.zeros((n_batch, height, width), dtype=np.float64)  # 1/depth; 0 = infinitely far
    _raster_kernel(pix, dep, tris, height, width, bool(cull_backfaces), NEAR, tri_id, bary, zbuf)
    return (
        torch.from_numpy(tri_id).to(pixels.device),
        torch.from_numpy(bary).to(device=pixels.device, dtype=pixels.dtype),
    )


# ----------------------------------------------------------------------------- interpolation


@dataclass
class Fragments:
    """The visible pixels of a batch and their differentiable barycentrics.

    Only visible pixels are stored (N of them), so per-pixel work scales with the face's
    coverage, not with H * W.
    """

    tri_id: torch.Tensor  # [B, H, W] int, -1 = background
    flat: torch.Tensor  # [N] index of each visible pixel in B * H * W
    batch: torch.Tensor  # [N] image index
    face: torch.Tensor  # [N] triangle index
    vertex: torch.Tensor  # [N, 3] vertex indices of that triangle
    bary: torch.Tensor  # [N, 3] perspective-correct barycentrics (differentiable)

    @property
    def shape(self) -> tuple[int, int, int]:
        return tuple(self.tri_id.shape)

    def to_image(self, values: torch.Tensor) -> torch.Tensor:
        """[N, C] per visible pixel -> [B, H, W, C], zero in the background."""
        b, h, w = self.shape
        out = values.new_zeros(b * h * w, values.shape[-1])
        return out.index_copy(0, self.flat, values).reshape(b, h, w, -1)

    def vertex_values(self, attr: torch.Tensor) -> torch.Tensor:
        """Per-vertex attribute [B, V, C] -> interpolated [N, C]."""
        n_vert = attr.shape[1]
        corners = attr.reshape(-1, attr.shape[-1])[self.batch.unsqueeze(1) * n_vert + self.vertex]
        return (self.bary.unsqueeze(-1) * corners).sum(1)

    def corner_values(self, corner_attr: torch.Tensor) -> torch.Tensor:
        """Per-corner attribute [T, 3, C] (or [B, T, 3, C]) -> interpolated [N, C]; for
        quantities with seams, such as the ICT UVs, that differ between the triangles
        sharing a vertex."""
        if corner_attr.dim() == 3:
            corners = corner_attr[self.face]
        else:
            corners = corner_attr[self.batch, self.face]
        return (self.bary.unsqueeze(-1) * corners).sum(1)

    def interpolate(self, attr: torch.Tensor) -> torch.Tensor:
        """[B, V, C] -> [B, H, W, C], zero in the background."""
        return self.to_image(self.vertex_values(attr))


def fragments(
    pixels: torch.Tensor, depth: torch.Tensor, triangles: torch.Tensor, tri_id: torch.Tensor
) -> Fragments:
    """Recomputes the barycentrics of the visible triangle at every covered pixel centre
    in torch, from the projected vertices, so that they carry gradients to `pixels` and
    `depth` (hence to the vertex positions)."""
    b, h, w = tri_id.shape
    n_vert = pixels.shape[1]
    flat_id = tri_id.reshape(-1).long()
    flat = torch.nonzero(flat_id >= 0).squeeze(1)
    face = flat_id[flat]
    batch = torch.div(flat, h * w, rounding_mode="floor")
    rem = flat - batch * (h * w)
    py = torch.div(rem, w, rounding_mode="floor")
    px = rem - py * w
    vertex = torch.as_tensor(triangles, device=pixels.device).long()[face]  # [N, 3]
    gidx = batch.unsqueeze(1) * n_vert + vertex
    p = pixels.reshape(-1, 2)[gidx]  # [N, 3, 2]
    z = depth.reshape(-1)[gidx]  # [N, 3]
    c = torch.stack([px, py], -1).to(pixels.dtype) + 0.5  # pixel centres [N, 2]

    def cross(a, b_):
        return a[..., 0] * b_[..., 1] - a[..., 1] * b_[..., 0]

    d = p - c.unsqueeze(1)  # vertices relative to the pixel centre
    area = cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])
    # Screen-space barycentrics: sub-triangle areas opposite each vertex over the area.
    screen = torch.stack([cross(d[:, 1], d[:, 2]), cross(d[:, 2], d[:, 0]), cross(d[:, 0], d[:, 1])], -1)
    screen = screen / area.unsqueeze(1)
    # Perspective correction: attributes are affine in 3D, so in screen space lambda_i / z_i
    # (normalised) are the weights.
    persp = screen / z
    bary = persp / persp.sum(1, keepdim=True)
    return Fragments(tri_id=tri_id, flat=flat, batch=batch, face=face, vertex=vertex, bary=bary)


def interpolate(
    attr: torch.Tensor,
    pixels: torch.Tensor,
    depth: torch.Tensor,
    triangles: torch.Tensor,
    tri_id: torch.Tensor,
) -> torch.Tensor:
    """Per-vertex attributes [B, V, C] -> perspective-correct image [B, H, W, C] (zero in
    the background), differentiable w.r.t. attr, pixels and depth. To interpolate several
    attributes, build `fragments(...)` once and call its methods."""
    return fragments(pixels, depth, triangles, tri_id).interpolate(attr)


# ----------------------------------------------------------------------------- geometry


def vertex_normals(points: torch.Tensor, triangles: torch.Tensor, eps: float = 1e-12) -> torch.Tensor:
    """Area-weighted unit vertex normals [B, V, 3] (as face/src/geometry.rs): the sum of the
    unnormalised face normals (length = twice the area) around each vertex, normalised."""
    tri = torch.as_tensor(triangles, device=points.device).long()
    v0, v1, v2 = points[:, tri[:, 0]], points[:, tri[:, 1]], points[:, tri[:, 2]]
    face_n = torch.cross(v1 - v0, v2 - v0, dim=-1)  # [B, T, 3]
    acc = torch.zeros_like(points)
    for k in range(3):
        acc = acc.index_add(1, tri[:, k], face_n)
    # eps inside the sqrt keeps the gradient finite for vertices on no triangle.
    return acc / torch.sqrt((acc * acc).sum(-1, keepdim=True) + eps)


# ----------------------------------------------------------------------------- shading

_A0 = math.pi
_A1 = 2.0 * math.pi / math.sqrt(3.0)
_A2 = 2.0 * math.pi / math.sqrt(8.0)
_C0 = 1.0 / math.sqrt(4.0 * math.pi)
_C1 = math.sqrt(3.0) / math.sqrt(4.0 * math.pi)
_C2 = 3.0 * math.sqrt(5.0) / math.sqrt(12.0 * math.pi)


def sh_basis(normals: torch.Tensor) -> torch.Tensor:
    """The 9 basis values with constants, exactly face/src/sh.rs `sh_basis`: [..., 3] ->
    [..., 9]."""
    x, y, z = normals.unbind(-1)
    a1c1, a2c2 = _A1 * _C1, _A2 * _C2
    return torch.stack(
        [
            torch.full_like(x, _A0 * _C0),
            -a1c1 * y,
            a1c1 * z,
            -a1c1 * x,
            a2c2 * x * y,
            -a2c2 * y * z,
            a2c2 * 0.5 / math.sqrt(3.0) * (3.0 * z * z - 1.0),
            -a2c2 * x * z,
            a2c2 * 0.5 * (x * x - y * y),
        ],
        -1,
    )


def sh_irradiance(normals: torch.Tensor, gamma: torch.Tensor) -> torch.Tensor:
    """Unit normals [B, ..., 3], gamma [B, 27] -> irradiance [B, ..., 3]."""
    basis = sh_basis(normals)  # [B, ..., 9]
    g = gamma.reshape(gamma.shape[0], *([1] * (normals.dim() - 2)), 3, 9)
    return (basis.unsqueeze(-2) * g).sum(-1)


def sh_shade(
    albedo: torch.Tensor, normals: torch.Tensor, gamma: torch.Tensor, clamp: bool = False
) -> torch.Tensor:
    """colour = albedo * irradiance(n), [B, H, W, 3]; `normals` must be unit length.
    `clamp` clamps negative irradiance to 0 like the Rust display renderer (face.wgsl); the
    paper's model does not, and clamping zeroes gradients there, so training leaves it off."""
    irr = sh_irradiance(normals, gamma)
    if clamp:
        irr = irr.clamp_min(0.0)
    return albedo * irr


# ----------------------------------------------------------------------------- textures


def sample_texture(texture: torch.Tensor, uv: torch.Tensor, mode: str = "bilinear") -> torch.Tensor:
    """texture [B or 1, C, h, w] (row 0 at v = 1), uv [B, H, W, 2] -> [B, H, W, C].

    Bilinear, clamped to the edge: face/src/uv.rs's UvMap::sample. mode="nearest" returns
    the texel containing uv (for hard parsing labels); it has no gradient w.r.t. uv.
    """
    if texture.shape[0] == 1 and uv.shape[0] != 1:
        texture = texture.expand(uv.shape[0], -1, -1, -1)
    uv = uv.to(texture.dtype)
    grid = torch.stack([2.0 * uv[..., 0] - 1.0, 1.0 - 2.0 * uv[..., 1]], -1)
    out = F.grid_sample(texture, grid, mode=mode, padding_mode="border", align_corners=False)
    return out.permute(0, 2, 3, 1)


# ----------------------------------------------------------------------------- render


@dataclass
class RenderOutput:
    image: torch.Tensor  # [B, H, W, 3] shaded colour, 0 in the background
    mask: torch.Tensor  # [B, H, W] M_n: 1 where a masked-in triangle is visible
    coverage: torch.Tensor  # [B, H, W] 1 where any triangle is visible
    parsing: torch.Tensor | None  # [B, H, W, K] soft parsing image, 0 in the background
    albedo: torch.Tensor  # [B, H, W, 3]
    normals: torch.Tensor  # [B, H, W, 3] unit camera-space normals
    pixels: torch.Tensor  # [B, V, 2] projected vertices (for landmarks)
    depth: torch.Tensor  # [B, V]
    tri_id: torch.Tensor  # [B, H, W] int32


def render(
    points: torch.Tensor,
    triangles: torch.Tensor,
    uv: torch.Tensor,
    texture: torch.Tensor,
    gamma: torch.Tensor,
    rotation: torch.Tensor,
    translation: torch.Tensor,
    focal,
    cx,
    cy,
    height: int,
    width: int,
    mask_triangles: torch.Tensor | None = None,
    parsing_texture: torch.Tensor | None = None,
    parsing_mode: str = "bilinear",
    cull_backfaces: bool = True,
    clamp_irradiance: bool = False,
) -> RenderOutput:
    """Renders model-space shapes S_n [B, V, 3] posed by (R, t) through the camera Phi.

    triangles [T, 3]; uv per vertex [V, 2] or per corner [T, 3, 2] (ICT has UV seams);
    texture: albedo R [B or 1, 3, h, w]; gamma [B, 27]; rotation [B, 3, 3] (see
    `euler_to_matrix`), translation [B, 3]; focal, cx, cy floats or [B].
    mask_triangles: bool [T], False for triangles that occlude but are not in M_n
    (eyeballs, mouth interior); default all True. parsing_texture: the UV parsing map T as
    one-hot channels [1 or B, K, h, w]; sampled bilinearly by default so that the soft
    parsing image has gradients w.r.t. geometry through the UVs.
    """
    triangles = torch.as_tensor(triangles, device=points.device).long()
    p_cam = transform(points, rotation, translation)
    pixels, depth = project_camera(p_cam, focal, cx, cy)
    tri_id, _ = rasterize(pixels, depth, triangles, height, width, cull_backfaces)
    frag = fragments(pixels, depth, triangles, tri_id)

    # Normals of the posed mesh are the model normals rotated into camera space, the
    # frame in which gamma lights the face (as the Rust renderer).
    n = frag.vertex_values(vertex_normals(p_cam, triangles))
    n = n / torch.sqrt((n * n).sum(-1, keepdim=True) + 1e-12)  # interpolation shortens them
    uv = uv.to(points.dtype)
    if uv.dim() == 3:
        uv_pix = frag.corner_values(uv)
    else:
        uv_pix = frag.vertex_values(uv.unsqueeze(0).expand(points.shape[0], -1, -1))
    uv_img = frag.to_image(uv_pix)

    coverage = (tri_id >= 0).to(points.dtype)
    albedo = sample_texture(texture, uv_img) * coverage.unsqueeze(-1).to(texture.dtype)
    normals = frag.to_image(n)
    image = sh_shade(albedo, normals, gamma, clamp=clamp_irradiance)

    if mask_triangles is None:
        mask = coverage
    else:
        keep = torch.as_tensor(mask_triangles, device=points.device).bool()
        mask = (keep[tri_id.long().clamp_min(0)] & (tri_id >= 0)).to(points.dtype)

    parsing = None
    if parsing_texture is not None:
        parsing = sample_texture(parsing_texture, uv_img, mode=parsing_mode)
        parsing = parsing * coverage.unsqueeze(-1).to(parsing.dtype)

    return RenderOutput(
        image=image,
        mask=mask,
        coverage=coverage,
        parsing=parsing,
        albedo=albedo,
        normals=normals,
        pixels=pixels,
        depth=depth,
        tri_id=tri_id,
    )
