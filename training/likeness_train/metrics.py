"""Evaluation metrics on synthetic people whose ground truth is known (issue 3, item 6)."""

from __future__ import annotations

import torch

# Outer eye corners of the 68-point layout: the usual inter-ocular normaliser of NME.
OUTER_EYE_CORNERS = (36, 45)


def vertex_error_mm(predicted: torch.Tensor, truth: torch.Tensor, vertices: torch.Tensor | None = None) -> torch.Tensor:
    """Mean per-vertex distance in millimetres between meshes [B, V, 3] in centimetres,
    after removing each mesh pair's mean offset (a translation the camera cannot see apart
    from depth), over `vertices` (the face region) if given."""
    if vertices is not None:
        predicted, truth = predicted[:, vertices], truth[:, vertices]
    offset = (truth - predicted).mean(dim=1, keepdim=True)
    return 10.0 * (predicted + offset - truth).norm(dim=-1).mean()


def landmark_nme(predicted: torch.Tensor, truth: torch.Tensor) -> torch.Tensor:
    """Mean landmark distance divided by the outer inter-ocular distance, [B, 68, 2]."""
    a, b = OUTER_EYE_CORNERS
    iod = (truth[:, a] - truth[:, b]).norm(dim=-1).clamp_min(1e-6)
    return ((predicted - truth).norm(dim=-1).mean(dim=-1) / iod).mean()


def photometric_error(images: torch.Tensor, rendered: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
    """Mean colour distance (RGB in [0, 1]) over the masked pixels, [B, H, W, 3]."""
    per_pixel = (images - rendered).norm(dim=-1) * mask
    return per_pixel.sum() / mask.sum().clamp_min(1.0)


def expression_mae(predicted: torch.Tensor, truth: torch.Tensor) -> torch.Tensor:
    """Mean absolute error of the expression weights w, [B, 53]."""
    return (predicted - truth).abs().mean()


def per_channel_mae(predicted: torch.Tensor, truth: torch.Tensor) -> torch.Tensor:
    """Mean absolute error of each weight channel [53]: shapes stuck near zero show here."""
    return (predicted - truth).abs().mean(dim=0)


def personalization_recovery(predicted_deltas: torch.Tensor, true_deltas: torch.Tensor, template_deltas: torch.Tensor, vertices: torch.Tensor | None = None) -> torch.Tensor:
    """Error of the predicted personal blendshapes S_i + F(A_i dS_i) against the person's
    true ones, relative to the template's error (1 = no better than the template, 0 = exact).
    Deltas are [P, 53, V, 3] (template deltas may omit P)."""
    if vertices is not None:
        predicted_deltas = predicted_deltas[..., vertices, :]
        true_deltas = true_deltas[..., vertices, :]
        template_deltas = template_deltas[..., vertices, :]
    predicted_error = (predicted_deltas - true_deltas).norm(dim=-1).mean()
    template_error = (template_deltas - true_deltas).norm(dim=-1).mean().clamp_min(1e-9)
    return predicted_error / template_error


def albedo_error(predicted: torch.Tensor, truth: torch.Tensor, coverage: torch.Tensor | None = None) -> torch.Tensor:
    """Mean absolute albedo error over UV texels [B, 3, H, W] (optionally where `coverage`
    [H, W] marks texels the face covers)."""
    diff = (predicted - truth).abs().mean(dim=1)
    if coverage is None:
        return diff.mean()
    return (diff * coverage).sum() / (coverage.sum() * diff.shape[0]).clamp_min(1.0)


def per_channel_correlation(predicted: torch.Tensor, truth: torch.Tensor) -> torch.Tensor:
    """Pearson correlation of predicted and true w per channel over frames [F, 53] -> [53]
    (0 where either side is constant): near 0 means the channel does not track at all,
    whatever its mean error."""
    a = predicted - predicted.mean(0)
    b = truth - truth.mean(0)
    denominator = (a.pow(2).sum(0) * b.pow(2).sum(0)).sqrt()
    return torch.where(denominator > 0, (a * b).sum(0) / denominator.clamp_min(1e-12), torch.zeros_like(denominator))


def pose_mae_deg(predicted_euler: torch.Tensor, true_euler: torch.Tensor) -> dict[str, float]:
    """Mean absolute yaw, pitch and roll error in degrees for Euler angles [F, 3] in radians."""
    err = (predicted_euler - true_euler).abs().mean(0) * (180.0 / torch.pi)
    return {"yaw": float(err[0]), "pitch": float(err[1]), "roll": float(err[2])}
