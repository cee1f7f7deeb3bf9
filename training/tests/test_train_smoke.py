"""A smoke training: a few steps of both stages on tiny networks, a resume after an
interruption, and the export with its ONNX Runtime parity check (CI runs this, not a full
training)."""

import json
import math

import pytest
import torch

from likeness_train.export import main as export_main
from likeness_train.train import TrainConfig, Trainer


def _config(**overrides):
    # No mirroring and no pose term unless a test asks: the tests recompute terms from the
    # unmirrored batch.
    base = dict(
        people_per_batch=1, frames=2, landmark_warmup_steps=0, stage1_track_frozen_steps=0, stage1_supervision=False, stage1_steps=2, stage2_steps=1,
        track_width=0.25, model_width=0.25, checkpoint_every_s=1e9, flip_probability=0.0, warmup_pose_supervision=0.0,
    )
    base.update(overrides)
    return TrainConfig(**base)


def test_smoke_training_resumes_and_exports(tmp_path, capsys):
    out = tmp_path / "run"
    trainer = Trainer(_config(stage1_steps=1, stage2_steps=0), out)
    trainer.run(log_every=1)
    assert trainer.checkpoint_path.exists()
    first = torch.load(trainer.checkpoint_path, weights_only=False)
    assert first["step"] == 1

    # "Interrupted" after step 1: a new trainer with more stage-1 steps picks up from there.
    stage1 = Trainer(_config(stage2_steps=0), out)
    assert stage1.resume() and stage1.step == 1
    stage1.run(log_every=1)
    assert stage1.step == 2
    track_after_stage1 = {k: v.clone() for k, v in stage1.track.state_dict().items()}
    model_after_stage1 = {k: v.clone() for k, v in stage1.modelnet.state_dict().items()}

    # Stage 2 freezes TrackNet (weights and batch-norm statistics) and fine-tunes ModelNet.
    resumed = Trainer(_config(), out)
    assert resumed.resume() and resumed.step == 2
    resumed.run(log_every=1)
    assert resumed.step == 3 and resumed.stage == 2
    for k, v in resumed.track.state_dict().items():
        assert torch.equal(v, track_after_stage1[k]), f"TrackNet {k} changed in stage 2"
    assert any(not torch.equal(v, model_after_stage1[k]) for k, v in resumed.modelnet.state_dict().items())
    lines = (out / "log.jsonl").read_text().splitlines()
    assert len(lines) == 3
    for line in lines:
        assert all(math.isfinite(v) for v in json.loads(line).values() if isinstance(v, float))

    export_main(["--checkpoint", str(resumed.checkpoint_path), "--out", str(tmp_path / "models")])
    printed = capsys.readouterr().out
    assert "max abs difference" in printed
    manifest = json.loads((tmp_path / "models" / "manifest.json").read_text())
    assert manifest["parity_max_abs_diff"]["track_net"] < 1e-4 and manifest["parity_max_abs_diff"]["model_net"] < 1e-4
    assert manifest["training"]["step"] == 3
    assert set(manifest["latency_ms"]) == {"track_net_1_thread", "track_net_2_threads", "model_net_1_thread", "model_net_2_threads"}
    assert all(v > 0 for v in manifest["latency_ms"].values())
    # The trained R_0^t round-trips through the float16 file (half precision: 1e-3 at 1).
    from safetensors.torch import load_file

    albedo = load_file(str(tmp_path / "models" / manifest["mean_albedo"]["file"]))["mean_albedo_face"]
    assert albedo.dtype == torch.float16 and list(albedo.shape) == manifest["mean_albedo"]["shape"]
    assert torch.allclose(albedo.float(), resumed.mean_albedo.detach(), atol=1e-3)
    assert not torch.equal(resumed.mean_albedo.detach(), resumed.region.mean_albedo_face), "R_0^t was trained"


def test_ablation_flags_switch_terms_off(tmp_path):
    trainer = Trainer(_config(parsing_loss=False, gradient_loss=False, expression_corrections=False, stage1_steps=1, stage2_steps=0), tmp_path / "a")
    values = trainer.train_step()
    assert "pa" not in values and "bg" not in values
    assert {"ph", "lm", "sd", "reg"} <= set(values)


def test_oracle_identity_uses_the_true_identity_offset(tmp_path):
    """The diagnostic `--oracle-identity`: L_sd is then the smoothness of each person's true
    dS_0, computed here independently from the synthetic people."""
    from likeness_train import losses as L

    trainer = Trainer(_config(oracle_identity=True, stage1_steps=1, stage2_steps=0), tmp_path / "o")
    values = trainer.train_step()
    people = trainer.cfg.people_per_batch
    true_dS0 = torch.stack([trainer.synthetic.people.person(p).dS0 for p in range(people)])
    expected = L.smoothness_loss(trainer.region.sample_uv(true_dS0), trainer.edges, reduction=trainer.cfg.sd_reduction) / people
    assert values["sd"] == pytest.approx(float(expected), rel=1e-5)
    assert float(expected) > 0


def test_landmark_warmup_trains_tracknet_alone_then_runs_the_two_stages(tmp_path):
    """Stage 0 changes TrackNet only and its loss is L_lm + L_reg with the template shape:
    recomputed here from the template's landmark vertices directly."""
    from likeness_train import losses as L
    from likeness_train import render as R
    from likeness_train.train import camera_translation, normalise

    trainer = Trainer(_config(landmark_warmup_steps=2, warmup_supervision=0.0, warmup_light_supervision=0.0, stage1_steps=1, stage2_steps=1), tmp_path / "w")
    assert trainer.stage == 0 and trainer.data_index() == 0
    model_before = {k: v.clone() for k, v in trainer.modelnet.state_dict().items()}
    track_before = {k: v.clone() for k, v in trainer.track.state_dict().items()}
    batch = trainer.data.batch(0, 1)
    trainer.track.train()
    with torch.no_grad():
        p = trainer.track(normalise(batch.images))
        shape = trainer.region.shape(p.w)  # equation (2) without corrections
        translation = camera_translation(p.translation, batch.focal, trainer.cfg.input_size)
        lm, _ = R.project(trainer.region.landmarks(shape), R.euler_to_matrix(p.euler), translation, batch.focal, batch.principal[:, 0], batch.principal[:, 1])
        expected = float(L.landmark_loss(batch.landmarks, lm)) / 2
    trainer.track.load_state_dict(track_before)  # undo the batch-norm statistics update
    values = trainer.train_step()
    assert set(values) == {"total", "lm", "reg"}
    assert values["lm"] == pytest.approx(expected, rel=1e-4)
    assert all(torch.equal(v, model_before[k]) for k, v in trainer.modelnet.state_dict().items())
    assert any(not torch.equal(v, track_before[k]) for k, v in trainer.track.state_dict().items())
    trainer.run(log_every=1)
    assert trainer.step == 4 and trainer.stage == 2
    # The warm-up's end is kept for the ablation rows.
    warmup = torch.load(tmp_path / "w" / "warmup.pt", weights_only=False)
    assert (warmup["stage"], warmup["step"]) == (0, 2)
    # Stage 1 reads batch 0 again: its data do not depend on the warm-up length.
    assert trainer.data_index() == 2
    assert any(not torch.equal(v, model_before[k]) for k, v in trainer.modelnet.state_dict().items())


def _squared(p, t):
    return (p - t).pow(2).sum()


def _l1(p, t):
    return (p - t).abs().sum()


def _cross_entropy_l1(p, t):
    # From the probabilities, not the logits the training uses.
    return -(t * p.log() + (1 - t) * (1 - p).log()).sum() + _l1(p, t)


@pytest.mark.parametrize("term, output, truth, flags, loss", [
    ("sup", "w", "weights", dict(warmup_supervision=7.0, warmup_light_supervision=0.0, w_loss="sq"), _squared),
    ("sup", "w", "weights", dict(warmup_supervision=7.0, warmup_light_supervision=0.0, w_loss="l1"), _l1),
    ("sup", "w", "weights", dict(warmup_supervision=7.0, warmup_light_supervision=0.0, w_loss="bce_l1"), _cross_entropy_l1),
    ("sup_light", "gamma", "gamma", dict(warmup_supervision=0.0, warmup_light_supervision=7.0), _squared),
])
def test_warmup_supervision_adds_its_error_against_the_truth(tmp_path, term, output, truth, flags, loss):
    """--warmup-supervision lambda adds the --w-loss of w, --warmup-light-supervision lambda
    sum (gamma - gamma^true)^2, per image, with weight lambda to the warm-up only; stage 1
    never sees them unless --stage1-supervision."""
    from likeness_train.train import normalise

    trainer = Trainer(_config(landmark_warmup_steps=1, stage1_steps=1, stage2_steps=0, **flags), tmp_path / term)
    batch = trainer.data.batch(0, 1)
    state = {k: v.clone() for k, v in trainer.track.state_dict().items()}
    trainer.track.train()
    with torch.no_grad():
        predicted = getattr(trainer.track(normalise(batch.images)), output).double()
    trainer.track.load_state_dict(state)  # undo the batch-norm statistics update
    values = trainer.train_step()
    expected = float(loss(predicted, getattr(batch, truth).double())) / 2
    assert expected > 0
    assert values[term] == pytest.approx(expected, rel=1e-4)
    assert values["total"] == pytest.approx(values["lm"] * trainer.cfg.weights["lm"] + values["reg"] * trainer.cfg.weights["reg"] + 7.0 * expected, rel=1e-4)
    trainer.run(log_every=1)
    assert trainer.stage == 1
    assert term not in trainer.train_step(), "stage 1 is self-supervised unless --stage1-supervision"


def test_warmup_pose_supervision_compares_with_the_reference_cameras_pose(tmp_path):
    """--warmup-pose-supervision lambda adds (|euler - euler^true|^2 + |t - t_ref^true|^2 /
    100) per image, t_ref^true the true translation for the reference camera."""
    from likeness_train.train import normalise, reference_focal

    trainer = Trainer(_config(landmark_warmup_steps=1, stage1_steps=0, stage2_steps=0, warmup_supervision=0.0, warmup_light_supervision=0.0, warmup_pose_supervision=3.0), tmp_path / "pose")
    batch = trainer.data.batch(0, 1)
    state = {k: v.clone() for k, v in trainer.track.state_dict().items()}
    trainer.track.train()
    with torch.no_grad():
        p = trainer.track(normalise(batch.images))
    trainer.track.load_state_dict(state)
    values = trainer.train_step()
    # For the reference camera the face is as large in the image: distance x f_ref / f.
    target = batch.translation.clone()
    target[:, 2] *= reference_focal(trainer.cfg.input_size) / batch.focal
    expected = float(((p.euler - batch.euler) ** 2).sum() + ((p.translation - target) ** 2).sum() / 100) / 2
    assert values["sup_pose"] == pytest.approx(expected, rel=1e-4)
    assert values["total"] == pytest.approx(values["lm"] * trainer.cfg.weights["lm"] + values["reg"] * trainer.cfg.weights["reg"] + 3.0 * expected, rel=1e-4)


def test_logged_steps_measure_each_terms_gradient_at_the_trunk(tmp_path):
    trainer = Trainer(_config(landmark_warmup_steps=2, stage1_steps=0, stage2_steps=0, warmup_supervision=1.0), tmp_path / "g")
    trainer.measure_trunk = True
    values = trainer.train_step()
    assert {"grad_lm", "grad_sup", "grad_sup_light", "grad_reg"} <= set(values)
    assert all(values[k] > 0 and math.isfinite(values[k]) for k in ("grad_lm", "grad_sup"))
    trainer.measure_trunk = False
    assert not any(k.startswith("grad_") for k in trainer.train_step())


def test_trunk_gradients_are_the_weighted_terms_gradient_norms():
    from likeness_train.train import trunk_gradients

    features = torch.randn(3, 5, requires_grad=True)
    a = torch.randn(3, 5)
    terms = {"linear": (features * a).sum(), "square": features.pow(2).sum(), "constant": torch.tensor(2.0)}
    norms = trunk_gradients(features, terms, {"linear": 2.0, "square": 0.5, "constant": 1.0})
    assert norms["grad_linear"] == pytest.approx(float(2.0 * a.norm()), rel=1e-6)
    assert norms["grad_square"] == pytest.approx(float(features.detach().norm()), rel=1e-6)  # 0.5 * 2 f
    assert "grad_constant" not in norms


def test_a_warmup_only_run_keeps_its_warmup_checkpoint(tmp_path):
    trainer = Trainer(_config(landmark_warmup_steps=2, stage1_steps=0, stage2_steps=0), tmp_path / "wo")
    trainer.run(log_every=1)
    warmup = torch.load(tmp_path / "wo" / "warmup.pt", weights_only=False)
    assert (warmup["stage"], warmup["step"]) == (0, 2)


def test_stage1_supervision_keeps_the_warmups_terms_while_tracknet_trains(tmp_path):
    trainer = Trainer(_config(stage1_steps=3, stage2_steps=1, stage1_track_frozen_steps=1, stage1_supervision=True, warmup_supervision=2.0, warmup_light_supervision=5.0), tmp_path / "s1")
    frozen = trainer.train_step()
    assert "sup" not in frozen and "sup_light" not in frozen, "nothing to supervise while TrackNet is frozen"
    values = trainer.train_step()
    paper = sum(trainer.cfg.weights[k] * values[k] for k in ("ph", "lm", "sd", "pa", "bg", "reg"))
    assert values["total"] == pytest.approx(paper + 2.0 * values["sup"] + 5.0 * values["sup_light"], rel=1e-4)
    trainer.run(log_every=1)
    assert trainer.stage == 2
    assert "sup" not in trainer.train_step(), "stage 2 freezes TrackNet"


def test_stage1_keeps_tracknet_frozen_for_its_first_steps_then_scales_its_rate(tmp_path):
    """With --stage1-track-frozen-steps K, stage 1's first K steps change ModelNet and R_0^t
    only; afterwards TrackNet trains at --stage1-track-lr-ratio times ModelNet's rate."""
    trainer = Trainer(_config(stage1_steps=3, stage2_steps=0, stage1_track_frozen_steps=2, stage1_track_lr_ratio=0.25), tmp_path / "f")
    track_before = {k: v.clone() for k, v in trainer.track.state_dict().items()}
    model_before = {k: v.clone() for k, v in trainer.modelnet.state_dict().items()}
    for _ in range(2):
        assert trainer.tracking_frozen()
        values = trainer.train_step()
        assert "reg" in values, "the stage-1 loss keeps its terms while TrackNet is frozen"
    # Frozen means eval mode too: not even the batch-norm statistics move.
    assert all(torch.equal(v, track_before[k]) for k, v in trainer.track.state_dict().items())
    assert any(not torch.equal(v, model_before[k]) for k, v in trainer.modelnet.state_dict().items())
    assert not trainer.tracking_frozen()
    trainer.run(log_every=1)
    assert trainer.step == 3
    assert any(not torch.equal(v, track_before[k]) for k, v in trainer.track.state_dict().items())
    track_group, model_group = trainer.optimizer.param_groups
    assert track_group["lr"] == pytest.approx(0.25 * model_group["lr"])


def test_resume_refuses_a_checkpoint_of_another_schedule(tmp_path):
    """A run without a warm-up resumed by a command with one would read batch step - K and
    another rate schedule: refused by name instead."""
    trainer = Trainer(_config(), tmp_path / "r")
    trainer.save()
    other = Trainer(_config(landmark_warmup_steps=3), tmp_path / "r")
    with pytest.raises(SystemExit, match="landmark_warmup_steps"):
        other.resume()
    assert Trainer(_config(), tmp_path / "r").resume()


def test_bf16_precision_matches_float32_and_trains(tmp_path):
    """bf16 autocast changes rounding only: from the same initial weights TrackNet's and
    ModelNet's outputs agree with float32 to bfloat16's precision (8 significant bits, some
    20 layers deep), every output leaves as float32, and both stages train with finite terms."""
    config = dict(landmark_warmup_steps=1, stage1_steps=1, stage2_steps=0, warmup_supervision=1.0)
    fp32 = Trainer(_config(**config), tmp_path / "fp32")
    bf16 = Trainer(_config(**config, precision="bf16"), tmp_path / "bf16")
    batch = bf16.read_batch()
    for trainer in (fp32, bf16):
        trainer.track.eval()
        trainer.modelnet.eval()
    with torch.no_grad():
        (p32, c32), (p16, c16) = fp32.predict(batch), bf16.predict(batch)
    assert not torch.equal(p32.w, p16.w), "bf16 ran in float32"
    for name in ("w", "euler", "translation", "gamma"):
        a, b = getattr(p32, name), getattr(p16, name)
        assert b.dtype == torch.float32
        scale = float(a.abs().max()) + 1e-3
        assert float((a - b).abs().max()) < 0.03 * scale, name
    for name in ("dS0", "dS", "dR0", "dR"):
        a, b = getattr(c32, name), getattr(c16, name)
        assert b.dtype == torch.float32
        assert float((a - b).abs().max()) < 0.03 * (float(a.abs().max()) + 1e-6), name
    before = {k: v.clone() for k, v in bf16.track.state_dict().items()}
    bf16.run(log_every=1)
    assert bf16.step == 2 and bf16.stage == 1
    assert any(not torch.equal(v, before[k]) for k, v in bf16.track.state_dict().items())
    for line in (tmp_path / "bf16" / "log.jsonl").read_text().splitlines():
        assert all(math.isfinite(v) for v in json.loads(line).values() if isinstance(v, float))


def test_an_unknown_precision_is_refused(tmp_path):
    with pytest.raises(ValueError, match="precision must be one of"):
        Trainer(_config(precision="fp16"), tmp_path / "x")


def test_init_track_from_starts_from_another_runs_tracknet(tmp_path):
    """--init-track-from: TrackNet's weights and BatchNorm statistics come from the
    checkpoint, ModelNet's and the optimiser do not; a narrower TrackNet is widened with its
    function kept, a TrackNet built otherwise (or wider) is refused,
    and a run resumed from its own checkpoint keeps its own weights."""
    first = Trainer(_config(landmark_warmup_steps=1, stage1_steps=0, stage2_steps=0), tmp_path / "first")
    first.run(log_every=1)
    source = torch.load(first.checkpoint_path, weights_only=False)["track_net"]
    second = Trainer(_config(landmark_warmup_steps=2, stage1_steps=0, stage2_steps=0, seed=5, init_track_from=str(first.checkpoint_path)), tmp_path / "second")
    assert all(torch.equal(v, source[k]) for k, v in second.track.state_dict().items())
    fresh = Trainer(_config(seed=5), tmp_path / "fresh")
    assert any(not torch.equal(v, source[k]) for k, v in fresh.track.state_dict().items())
    assert second.step == 0 and not second.optimizer.state
    second.run(log_every=1)
    trained = {k: v.clone() for k, v in second.track.state_dict().items()}
    resumed = Trainer(_config(landmark_warmup_steps=2, stage1_steps=0, stage2_steps=0, seed=5, init_track_from=str(first.checkpoint_path)), tmp_path / "second")
    assert resumed.resume()
    assert all(torch.equal(v, trained[k]) for k, v in resumed.track.state_dict().items())
    # A wider TrackNet starts from the narrower one's function (widen.py), on the trainer's
    # own network, not just in widen_track's unit test.
    wide = Trainer(_config(track_width=0.5, init_track_from=str(first.checkpoint_path)), tmp_path / "wide")
    size = first.cfg.input_size
    images = torch.randn(2, 3, size, size, generator=torch.Generator().manual_seed(4))
    with torch.no_grad():
        first.track.eval()
        wide.track.eval()
        assert torch.allclose(first.track(images).w, wide.track(images).w, atol=2e-5)
    wide.save()  # and a wider TrackNet cannot start a narrower one
    with pytest.raises(ValueError, match="track_width"):
        Trainer(_config(init_track_from=str(wide.checkpoint_path)), tmp_path / "narrow")
    with pytest.raises(FileNotFoundError):
        Trainer(_config(init_track_from=str(tmp_path / "none.pt")), tmp_path / "none")
    (tmp_path / "junk.pt").write_bytes(b"not a checkpoint")
    with pytest.raises(ValueError, match="cannot be read"):
        Trainer(_config(init_track_from=str(tmp_path / "junk.pt")), tmp_path / "junk")


def test_bf16_on_a_cpu_without_it_is_warned_about(tmp_path, monkeypatch, capsys):
    """Emulated bfloat16 is ~10x slower than float32: the command line says so (and still
    runs, since a resumed run may be on another machine)."""
    import likeness_train.train as train

    ran = []

    class Stub:
        def __init__(self, config, out):
            self.config = config

        def resume(self):
            return False

        def run(self):
            ran.append(self.config.precision)

    monkeypatch.setattr(train, "Trainer", Stub)
    for has_bf16, warned in ((False, True), (True, False)):
        monkeypatch.setattr(train, "cpu_has_bf16", lambda has=has_bf16: has)
        train.main(["--out", str(tmp_path / "run"), "--precision", "bf16"])
        assert ("bfloat16 is emulated" in capsys.readouterr().err) == warned
    train.main(["--out", str(tmp_path / "run"), "--precision", "fp32"])
    assert "emulated" not in capsys.readouterr().err
    assert ran == ["bf16", "bf16", "fp32"]


def test_a_tracknet_for_more_pixels_starts_from_a_smaller_ones_trunk_in_the_warm_up_alone(tmp_path):
    """--input-size 160 with --init-track-from a 128 px run: the trunk's weights carried
    (widen.resize_track_input resamples the heads), the warm-up runs on 160 px images, and
    stages 1 and 2 are refused by name (ModelNet reads 128 or 224 px)."""
    first = Trainer(_config(landmark_warmup_steps=1, stage1_steps=0, stage2_steps=0), tmp_path / "first")
    first.save()
    large = Trainer(_config(input_size=160, landmark_warmup_steps=1, stage1_steps=0, stage2_steps=0, init_track_from=str(first.checkpoint_path)), tmp_path / "large")
    source = first.track.state_dict()
    assert all(torch.equal(v, source[k]) for k, v in large.track.state_dict().items() if k.startswith("encoder."))
    assert large.track.encoder.out_features == first.track.encoder.out_features * 25 // 16
    large.run(log_every=1)
    assert large.step == 1
    with pytest.raises(ValueError, match="stages 1 and 2"):
        Trainer(_config(input_size=160), tmp_path / "staged")
