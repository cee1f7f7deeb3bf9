"""The exported ONNX models compute what the PyTorch networks compute."""

import pytest
import torch

from likeness_train.export import export_onnx, parity
from likeness_train.networks import ModelNet, TrackNet


@pytest.mark.parametrize("pool", ["avg", "flatten"])
def test_onnx_runtime_matches_pytorch(tmp_path, pool):
    torch.manual_seed(1)
    track = TrackNet(width=0.25, pool=pool)
    model = ModelNet(input_size=128, width=0.25)
    # Non-trivial heads (they start at zero) so the parity check means something.
    with torch.no_grad():
        for head in (track.head, model.shape_decoder.blendshape_head, model.albedo_decoder.static_head):
            head.weight.normal_(0, 0.05)
    track_path, model_path = export_onnx(track, model, 128, tmp_path)
    diffs = parity(track, model, track_path, model_path, 128)
    print("ONNX Runtime vs PyTorch max abs difference:", diffs)
    assert diffs["track_net"] < 1e-4
    assert diffs["model_net"] < 1e-4
