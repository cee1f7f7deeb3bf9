"""The held-out clips (clips.py): the truth is consistent with the frame camera, the motion
is smooth, the output is deterministic and bad arguments are refused."""

import json
from pathlib import Path

import numpy as np
import pytest
import torch

from likeness_train import clips as C
from likeness_train.fixtures import read_png
from likeness_train.scene import SceneRenderer

SPEC = C.ClipSpec(seed=9001, clips=1, frames=14, width=320, height=240, face_px=(70.0, 110.0))


@pytest.fixture(scope="module")
def clip_dir(tmp_path_factory, face_model):
    out = tmp_path_factory.mktemp("clips") / "clips"
    C.write_clips(out, SPEC, model=face_model, log=lambda *_: None)
    return out


@pytest.fixture(scope="module")
def truth(clip_dir):
    return json.loads((clip_dir / "clip_00" / "truth.json").read_text())


def _rotation(yaw, pitch, roll):
    """R = Rz(roll) Ry(yaw) Rx(pitch), written out independently of the renderer."""
    cy, sy, cp, sp, cr, sr = np.cos(yaw), np.sin(yaw), np.cos(pitch), np.sin(pitch), np.cos(roll), np.sin(roll)
    rz = np.array([[cr, -sr, 0], [sr, cr, 0], [0, 0, 1]])
    ry = np.array([[cy, 0, sy], [0, 1, 0], [-sy, 0, cy]])
    rx = np.array([[1, 0, 0], [0, cp, -sp], [0, sp, cp]])
    return rz @ ry @ rx


def test_clip_files_and_layout(clip_dir, truth, face_model):
    index = json.loads((clip_dir / "clips.json").read_text())
    assert index["clips"] == ["clip_00"] and index["seed"] == 9001
    d = clip_dir / "clip_00"
    assert sorted(p.name for p in d.glob("frame_*.png")) == [f"frame_{n:04d}.png" for n in range(SPEC.frames)]
    assert read_png(d / "frame_0000.png").shape == (240, 320, 3)
    assert (truth["seed"], truth["fps"], truth["width"], truth["height"]) == (9001, 30, 320, 240)
    assert truth["principal"] == [160.0, 120.0]
    fov = np.degrees(2 * np.arctan(0.5 * 320 / truth["focal_px"]))
    assert 45 <= fov <= 60 and fov == pytest.approx(truth["horizontal_fov_deg"])
    manifest = json.loads((Path(__file__).resolve().parents[2] / "assets" / "models" / "manifest.json").read_text())
    assert truth["blendshape_names"] == manifest["blendshape_names"]
    assert [f["index"] for f in truth["frames"]] == list(range(SPEC.frames))
    for f in truth["frames"]:
        assert f["time_s"] == pytest.approx(f["index"] / 30)
        assert len(f["weights"]) == 53 and len(f["gamma"]) == 27 and len(f["landmarks_68"]) == 68
        assert f["rotation_deg"] == pytest.approx(list(np.degrees(f["euler_rad"])))
        lm = np.array(f["landmarks_68"])
        assert f["face_box"] == pytest.approx([*lm.min(0), *(lm.max(0) - lm.min(0))])
        # The whole face is in the frame.
        assert (lm.min(0) >= 0).all() and (lm.max(0) <= [320, 240]).all()
    from safetensors.numpy import load_file

    person = load_file(str(d / "person.safetensors"))
    assert {k: v.shape for k, v in person.items()} == {"dS0": (3, 128, 128), "dS": (53, 3, 128, 128), "dR0": (3, 128, 128), "dR": (53, 3, 128, 128), "identity_coeffs": (100,)}


def test_clip_truth_landmarks_are_the_projection_of_the_true_3d_landmarks(clip_dir, truth, face_model):
    from safetensors.torch import load_file

    person = load_file(str(clip_dir / "clip_00" / "person.safetensors"))
    weights = torch.tensor([f["weights"] for f in truth["frames"]])
    n = weights.shape[0]
    with torch.no_grad():
        vertices = face_model.shape(weights, None, person["dS"][None].expand(n, -1, -1, -1, -1), person["identity_coeffs"][None].expand(n, -1))
        model_points = face_model.landmarks(vertices).double().numpy()
    f, (cx, cy) = truth["focal_px"], truth["principal"]
    for i, frame in enumerate(truth["frames"]):
        p = model_points[i] @ _rotation(*frame["euler_rad"]).T + np.array(frame["translation"])
        assert np.abs(p - np.array(frame["landmarks_68_camera"])).max() < 1e-3  # cm
        assert (p[:, 2] < 0).all()
        uv = np.stack([cx + f * p[:, 0] / -p[:, 2], cy - f * p[:, 1] / -p[:, 2]], 1)
        assert np.abs(uv - np.array(frame["landmarks_68"])).max() < 0.02, i  # pixels


def test_clip_motion_is_smooth_and_keyframed(truth):
    bound = C.max_frame_change()
    w = np.array([f["weights"] for f in truth["frames"]])
    euler = np.degrees(np.array([f["euler_rad"] for f in truth["frames"]]))
    centre = np.array([np.array(f["landmarks_68"]).mean(0) for f in truth["frames"]])
    assert np.abs(np.diff(w, axis=0)).max() <= bound["weights"] + 1e-6
    assert np.abs(np.diff(euler, axis=0)).max() <= bound["euler_deg"] + 1e-4
    assert (np.abs(euler) <= C.POSE_LIMIT_DEG + 1e-4).all()
    # The face moves, but never jumps (a fraction of its size per frame).
    step = np.linalg.norm(np.diff(centre, axis=0), axis=1)
    assert step.max() < 0.25 * SPEC.face_px[0] and step.sum() > 1.0
    keys = truth["keyframes"]
    assert keys[0] == 0 and all(C.KEYFRAME_INTERVAL[0] <= b - a <= C.KEYFRAME_INTERVAL[1] for a, b in zip(keys, keys[1:]))
    # Smoothstep: the velocity vanishes at keyframes (second differences stay small too).
    assert np.abs(np.diff(euler, 2, axis=0)).max() <= 2 * bound["euler_deg"]


def test_clip_is_deterministic_and_prefix_stable(clip_dir, face_model):
    scene = SceneRenderer(face_model, SPEC.seed)
    shorter = C.ClipSpec(**{**SPEC.__dict__, "frames": 3})
    again = C.render_clip(scene, 0, shorter, frames=range(1))
    assert np.array_equal(again["images"][0], read_png(clip_dir / "clip_00" / "frame_0000.png"))
    full = json.loads((clip_dir / "clip_00" / "truth.json").read_text())["frames"][0]
    # Rendered alone instead of in a batch of 6: the same drawn values; the vertices (a
    # batched matrix product) may differ in the last float32 bit.
    got = again["truth"][0]
    for key in ("index", "time_s", "weights", "euler_rad", "rotation_deg", "translation", "gamma", "face_px"):
        assert got[key] == full[key], key
    for key in ("landmarks_68", "landmarks_68_camera", "face_box"):
        assert np.abs(np.array(got[key]) - np.array(full[key])).max() < 1e-3, key


def test_clip_bad_arguments_are_refused(tmp_path, face_model):
    for bad in ({"frames": 0}, {"clips": 0}, {"seed": 1}, {"face_px": (150.0, 300.0)}, {"face_px": (90.0, 80.0)}, {"fov_deg": (50.0, 40.0)}):
        with pytest.raises(ValueError):
            C.ClipSpec(**{**SPEC.__dict__, **bad}).validate()
    with pytest.raises(ValueError, match="parent folder"):
        C.write_clips(tmp_path / "missing" / "clips", SPEC, model=face_model)
    with pytest.raises(SystemExit):
        C.main(["--out", str(tmp_path / "c"), "--frames", "0"])
    with pytest.raises(SystemExit):
        C.main(["--out", str(tmp_path / "missing" / "c")])
    (tmp_path / "busy").mkdir()
    (tmp_path / "busy" / "data.bin").write_bytes(b"x")
    with pytest.raises(SystemExit):
        C.main(["--out", str(tmp_path / "busy")])
