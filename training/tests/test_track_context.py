"""The context TrackNet (networks.TrackNet(context=True), issue 31 probe): each frame's
context is the mean of its person's other frames, the branch starts as the plain network,
and it learns (its last layer gets a gradient)."""

import pytest
import torch

from likeness_train.networks import TrackNet, leave_one_out_context


def test_each_frames_context_is_the_mean_of_its_persons_other_frames():
    features = torch.arange(2 * 3 * 2, dtype=torch.float32).view(6, 2)  # 2 people x 3 frames
    context = leave_one_out_context(features, people=2, frames=3)
    expected = torch.stack([(features[[1, 2]].mean(0)), features[[0, 2]].mean(0), features[[0, 1]].mean(0),
                            features[[4, 5]].mean(0), features[[3, 5]].mean(0), features[[3, 4]].mean(0)])
    assert torch.allclose(context, expected)
    with pytest.raises(ValueError, match="2 frames"):
        leave_one_out_context(features, people=6, frames=1)
    with pytest.raises(ValueError, match="people"):
        leave_one_out_context(features, people=4, frames=2)


def test_a_context_tracknet_starts_as_the_plain_one_and_its_branch_learns():
    torch.manual_seed(0)
    plain = TrackNet(width=0.25, pool="flatten", w_head="own").eval()
    with torch.no_grad():  # a plain network that is not at its initial zero head
        for p in plain.parameters():
            p.add_(0.05 * torch.randn_like(p))
    context = TrackNet(width=0.25, pool="flatten", w_head="own", context=True)
    missing, unexpected = context.load_state_dict(plain.state_dict(), strict=False)
    assert not unexpected and missing and all(k.startswith("context_net.") for k in missing)
    context.eval()
    images = torch.rand(8, 3, 128, 128)
    with torch.no_grad():
        a, b = plain(images), context.forward_people(images, people=2, frames=4)
    for name in ("w", "euler", "translation", "gamma"):
        assert torch.allclose(getattr(a, name), getattr(b, name), atol=1e-6), name
    with pytest.raises(ValueError, match="context"):
        context(images)
    context.train()
    context.forward_people(images, people=2, frames=4).w.sum().backward()
    assert context.context_net[2].weight.grad.abs().sum() > 0
    # Pose and light do not read the context.
    assert context.fc[0].weight.grad is not None


def test_a_context_tracknet_needs_its_own_w_head():
    with pytest.raises(ValueError, match="w_head"):
        TrackNet(width=0.25, w_head="shared", context=True)


def test_the_context_probe_is_refused_outside_the_warm_up(tmp_path):
    from likeness_train.train import TrainConfig, Trainer

    with pytest.raises(ValueError, match="warm-up probe"):
        Trainer(TrainConfig(track_width=0.25, model_width=0.25, track_pool="flatten", track_context=True, stage1_steps=1, stage2_steps=0), tmp_path)
