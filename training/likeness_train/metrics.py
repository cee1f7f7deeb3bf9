"""Evaluation metrics on synthetic people whose ground truth is known (issue 3, item 6)."""

from __future__ import annotations

import numpy as np
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


# A channel counts as visible when, at w = 1 on the template, some vertex of the face or an
# eyeball moves at least this many pixels at 128 px and the reference framing below: below
# it the image cannot show the channel whatever the network does.
VISIBLE_MIN_PX = 1.0
# The framing of "visible": synthetic version 3's face_fill, kept when version 4 framed the
# face tighter so that held-out tables of both versions average over the same channels.
VISIBLE_REFERENCE_FACE_FILL = 0.85
ACTIVE_THRESHOLD = 0.3  # w above this counts as "the shape is shown" (activation F1)


def channel_motion_px(model, image_size: int = 128, face_fill: float = VISIBLE_REFERENCE_FACE_FILL) -> torch.Tensor:
    """Largest image motion [53] in pixels of each blendshape at w = 1 on the template (face
    and eyeballs, the eyes turned by the gaze), at a framing of `face_fill`.
    `model` is a full-mesh `face.FaceModel`."""
    t = model.template
    face_end = t.parts["face"][1]
    pixels_per_cm = face_fill * image_size / float(np.ptp(t.neutral[:face_end, 1]))
    with torch.no_grad():
        one_hot = torch.eye(len(model.expression_names))
        moved = model.turn_eyes(model.shape(one_hot), one_hot)
        distance = (moved - model.neutral[None]).norm(dim=-1)  # [53, V]
    shown = torch.zeros(model.vertex_count, dtype=torch.bool)
    shown[:face_end] = True
    for part in ("eyeball_left", "eyeball_right"):
        start, end = t.parts.get(part, (0, 0))
        shown[start:end] = True
    return distance[:, shown].max(dim=1).values * pixels_per_cm


def visible_channels(model, image_size: int = 128) -> torch.Tensor:
    """[53] bool: the channels an image can show (`VISIBLE_MIN_PX`)."""
    return channel_motion_px(model, image_size) >= VISIBLE_MIN_PX


def activation_f1(predicted: torch.Tensor, truth: torch.Tensor, threshold: float = ACTIVE_THRESHOLD) -> torch.Tensor:
    """F1 of "w > threshold" per channel over frames [F, 53] -> [53] (NaN where neither side
    is ever active: nothing to find)."""
    p, t = predicted > threshold, truth > threshold
    tp = (p & t).sum(0).float()
    denominator = p.sum(0).float() + t.sum(0).float()
    return torch.where(denominator > 0, 2 * tp / denominator.clamp_min(1), torch.full_like(tp, float("nan")))


def landmark_nme_box(predicted: torch.Tensor, truth: torch.Tensor) -> torch.Tensor:
    """Mean landmark distance divided by sqrt(w h) of the true landmarks' bounding box,
    [B, 68, 2] (the normaliser that does not shrink in profile views, unlike the
    inter-ocular distance)."""
    size = truth.max(dim=1).values - truth.min(dim=1).values
    box = (size[:, 0] * size[:, 1]).clamp_min(1e-6).sqrt()
    return ((predicted - truth).norm(dim=-1).mean(dim=-1) / box).mean()


def expression_report(predicted: torch.Tensor, truth: torch.Tensor, visible: torch.Tensor, names: list[str]) -> dict:
    """Everything issue 31 asks of w, side by side with the trivial predictors on the same
    frames [F, 53]: MAE over all channels and over the visible ones for the prediction,
    w = 0 and w = each channel's mean over these frames; per channel MAE (and the two
    baselines'), correlation and activation F1."""
    mean = truth.mean(0, keepdim=True).expand_as(truth)
    predictors = {"predicted": predicted, "zero": torch.zeros_like(truth), "constant_mean": mean}
    per_channel = {k: (v - truth).abs().mean(0) for k, v in predictors.items()}
    correlation = per_channel_correlation(predicted, truth)
    f1 = activation_f1(predicted, truth)
    vis = visible.bool()
    report = {
        "mae_all": {k: float(v.mean()) for k, v in per_channel.items()},
        "mae_visible": {k: float(v[vis].mean()) for k, v in per_channel.items()},
        "visible_channels": int(vis.sum()),
        "channels_beating_zero": int((per_channel["predicted"] < per_channel["zero"]).sum()),
        "visible_channels_beating_zero": int(((per_channel["predicted"] < per_channel["zero"]) & vis).sum()),
        "median_visible_correlation": float(correlation[vis].median()),
        "per_channel": {
            name: {
                "mae": float(per_channel["predicted"][i]),
                "mae_zero": float(per_channel["zero"][i]),
                "mae_constant_mean": float(per_channel["constant_mean"][i]),
                "correlation": float(correlation[i]),
                "f1": float(f1[i]),
                "predicted_mean": float(predicted[:, i].mean()),
                "true_mean": float(truth[:, i].mean()),
                "visible": bool(vis[i]),
            }
            for i, name in enumerate(names)
        },
    }
    return report


def format_expression_report(report: dict) -> str:
    """The report as a text table (one line per channel after the summary)."""
    lines = [
        f"w MAE        all {report['mae_all']['predicted']:.4f} (zero {report['mae_all']['zero']:.4f}, constant mean {report['mae_all']['constant_mean']:.4f})",
        f"w MAE    visible {report['mae_visible']['predicted']:.4f} (zero {report['mae_visible']['zero']:.4f}, constant mean {report['mae_visible']['constant_mean']:.4f}) over {report['visible_channels']} channels",
        f"channels beating zero: {report['channels_beating_zero']} of 53 ({report['visible_channels_beating_zero']} of the {report['visible_channels']} visible); median visible correlation {report['median_visible_correlation']:.3f}",
        f"{'channel':<18} {'MAE':>6} {'zero':>6} {'mean':>6} {'corr':>6} {'F1':>5} {'pred':>5} {'true':>5}",
    ]
    for name, c in report["per_channel"].items():
        mark = "" if c["visible"] else "  (not visible)"
        lines.append(
            f"{name:<18} {c['mae']:6.3f} {c['mae_zero']:6.3f} {c['mae_constant_mean']:6.3f} {c['correlation']:6.2f} {c['f1']:5.2f} {c['predicted_mean']:5.2f} {c['true_mean']:5.2f}{mark}"
        )
    return "\n".join(lines)
