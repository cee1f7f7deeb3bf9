"""Two-stage self-supervised training of ModelNet + TrackNet (paper, section 3 and 4).

Stage 0 (ours, not the paper's; `--landmark-warmup-steps`, 0 = off): TrackNet alone on
L_lm + L_reg with the template shape, plus, with `--warmup-supervision`, the squared error
of w and of the light gamma against the synthetic truth (TrainConfig says why). Stage 1:
both networks, all losses, Adam (the paper's lr 1e-4; TrainConfig says why ours differs),
TrackNet frozen for the first `--stage1-track-frozen-steps` and then, with
`--stage1-supervision`, still given the warm-up's supervised terms (ours, not the paper's).
Stage 2: TrackNet frozen, ModelNet fine-tuned at a tenth of the rate without the tracking
regulariser.

`python -m likeness_train.train --out runs/full` trains (and resumes from
`runs/full/checkpoint.pt` if it exists); the ablation rows use the same command with
`--no-expression-corrections`, `--no-dynamic-albedo`, `--no-parsing-loss`,
`--no-gradient-loss`. Progress goes to stdout and `runs/.../log.jsonl`. `--data DIR` reads
pre-rendered batches written by `python -m likeness_train.dataset` (same seed, size, N and
P); without it batches are rendered on the fly (~110 ms per 128 px image).
"""

from __future__ import annotations

import argparse
import json
import math
import pickle
import shutil
import sys
import time
import contextlib
import dataclasses
from dataclasses import asdict, dataclass, field
from pathlib import Path

import torch
from torch import nn

from . import losses as L
from . import render as R
from .data import Batch, SyntheticData, concat_batches, mirror_batch, mirror_channels, photometric_batch
from .dataset import CachedData, CacheUnion
from .export import IMAGE_MEAN, IMAGE_STD, git_commit
from .face import FaceModel
from .networks import TRACK_POOLS, TRACK_W_HEADS, Corrections, MODEL_NET_SIZES, ModelNet, TrackNet, TrackParams, build_track_net, leave_one_out_context
from .widen import resize_track_input, widen_track, widths_match


WARMUP_CHECKPOINT = "warmup.pt"  # the checkpoint at the end of stage 0, beside checkpoint.pt
# Configuration a resumed run must share with its checkpoint (Trainer.resume).
RESUME_KEYS = (
    "input_size", "track_width", "model_width", "track_pool", "track_w_head", "track_w_hidden", "people_per_batch", "frames",
    "landmark_warmup_steps", "warmup_batches_per_step", "seed", "track_context",
)
# What fixes TrackNet's shape: a checkpoint's TrackNet loads only into one built the same.
TRACK_SHAPE_KEYS = ("input_size", "track_width", "track_pool", "track_w_head", "track_w_hidden", "track_context")
# How the supervised w term compares w with the truth (TrainConfig.w_loss says why).
W_LOSSES = ("sq", "l1", "bce_l1")
# The networks' arithmetic (TrainConfig.precision says why).
PRECISIONS = ("fp32", "bf16")


@dataclass
class TrainConfig:
    input_size: int = 128
    track_width: float = 0.5
    model_width: float = 0.5
    # TrackNet's output scales (networks.TrackNet): 1, 10, 1 as first built.
    track_rotation_scale: float = 1.0
    track_translation_scale: float = 10.0
    track_w_gain: float = 1.0
    # How much more the w outputs' gradient counts in TrackNet's shared trunk than it would.
    # At the truth a blendshape's gradient is ~1e-3 of the pose outputs' (README, "Expression
    # signal"), so the trunk learnt pose features only and w stayed uncorrelated with the truth.
    track_w_grad_scale: float = 1.0
    # How TrackNet's ResNet-18 turns its final feature grid into features (networks.TRACK_POOLS):
    # "flatten" keeps where things are; at equal warm-up steps it lowered the landmark loss
    # (9.9 against 10.5 px^2 over steps 2,600-3,000) and the NME (9.8 against 10.0 %).
    track_pool: str = "flatten"
    # Where w comes from (networks.TRACK_W_HEADS): "own", a head of its own on the trunk's
    # features. The shared head gave w a linear map of pose features: TrackNet output each
    # channel's average (issue 31).
    track_w_head: str = "own"
    track_w_hidden: int = 256
    # Not in the paper: the w head also reads the person's other frames (networks.TrackNet,
    # `context`). A warm-up probe so far (stages 1 and 2, the export and the Rust tracker do
    # not run it): initialised from a plain TrackNet, it starts as that network.
    track_context: bool = False
    # The supervised w term per image (weight `warmup_supervision`): "sq" = sum_i (w_i -
    # w_i^true)^2 as before: through the sigmoid at w ~ 0.08 its gradient is ~0.07 of the
    # error and it sat at the constant-mean floor; "l1" = sum_i |w_i - w_i^true|, the metric;
    # "bce_l1" = the cross-entropy of the logits against w^true (its gradient at the logits is
    # w - w^true, never saturating) plus the L1 term, which keeps the zeros of the
    # zero-inflated truth at zero (the median, where the cross-entropy alone aims at the mean).
    w_loss: str = "bce_l1"
    # Not in the paper: the warm-up also supervises the head pose where the data knows it,
    # lambda * (|euler - euler^true|^2 in radians + |t - t^true|^2 / 100 in cm, for the
    # reference camera) per image.
    warmup_pose_supervision: float = 10.0
    # Each person's frames are seen in a mirror with this probability (data.mirror_batch:
    # left and right channels swapped), in every stage: twice the distinct faces, and no
    # left-right bias for w to learn.
    flip_probability: float = 0.5
    # Not in the paper (0 = off): the warm-up's images get a colour gain (with the light
    # target scaled to match), sensor noise and sometimes a slight blur at this strength in
    # [0, 1] (data.photometric_batch), drawn from (seed, step) so a resumed run draws the
    # same. Warm-up only: stages 1 and 2 compare renders with the input image itself.
    photometric_augment: float = 0.0
    people_per_batch: int = 4
    frames: int = 4  # N, as the paper
    # Stage 0 (not in the paper, 0 = off): TrackNet alone on L_lm + L_reg with the template
    # shape, no rendering and no ModelNet (~8x cheaper per image), before stage 1. It gives
    # the expression outputs landmark-driven features before the photometric term joins.
    landmark_warmup_steps: int = 4000
    # The warm-up's rate decays like stage 1's (stage 1 then starts again from lr_stage1):
    # NME 9.8 -> 8.4 %, pose 3.1 / 4.0 / 3.0 -> 2.4 / 3.4 / 2.0 degrees at 3,000 steps.
    warmup_lr_decay: bool = True
    # The warm-up's rate rises linearly from 0 over its first K steps (0 = off): a higher
    # rate from a fresh BatchNorm network without it diverges in the first steps.
    warmup_lr_ramp_steps: int = 0
    # Cached batches (of P people x N frames) each warm-up step reads: B x P x N images per
    # step. The warm-up reads the cache in order and wraps around at its end (an epoch; the
    # mirroring differs per pass). 1,000 steps of 16 images did not generalise (issue 31).
    warmup_batches_per_step: int = 1
    # Not in the paper (0 = off): the warm-up also fits w to the synthetic truth,
    # lambda_sup * sum_i (w_i - w_i^true)^2 per image. The paper's TrackNet learnt w
    # self-supervised from 94k videos; from scratch on our budget it does not (README,
    # "Where it stands"), and only the warm-up may use it: stages 1 and 2 stay self-supervised.
    warmup_supervision: float = 10.0
    # Not in the paper (0 = off): the warm-up also fits the lighting gamma to the synthetic
    # truth, lambda * sum_k (gamma_k - gamma_k^true)^2 per image. Without it the warm-up
    # trains gamma through L_reg only, so at stage 1 the photometric error was ~0.7 and
    # ModelNet painted the missing shading into the albedo (README, "Where it stands").
    warmup_light_supervision: float = 10.0
    # Not in the paper: TrackNet stays frozen for the first K steps of stage 1, while ModelNet
    # and R_0^t learn to explain the appearance. At stage 1's start the corrections are zero
    # and the photometric term (~4x the landmark term) pushed TrackNet to explain what only
    # the person's model can: 150 steps took the warm-up's jawOpen correlation 0.70 -> 0.27.
    stage1_track_frozen_steps: int = 300
    # Not in the paper: the warm-up's supervised terms stay while TrackNet trains in stage 1.
    # Without them the self-supervised terms undid the warm-up's tracking within 200 steps
    # even after the frozen start (jawOpen correlation 0.74 -> 0.64, NME 8.5 -> 11.8 %, the
    # eyeBlink mean 0.11 -> 0.32; README, "Where it stands"). ModelNet never sees them.
    stage1_supervision: bool = True
    # TrackNet's learning rate in stage 1 relative to ModelNet's (1 = the paper's one rate).
    stage1_track_lr_ratio: float = 1.0
    stage1_steps: int = 2400
    stage2_steps: int = 600
    # The paper's are 1e-4 and 1e-5 (for a ResNet-18 it presumably initialised from
    # ImageNet); from scratch, at 500 steps, 3e-4 halves the held-out yaw error (15.3 ->
    # 7.8 degrees) and lowers the NME (20.0 -> 17.7 %) (training/README.md, "Loss balance").
    # Stage 2 keeps the paper's 10x drop.
    lr_stage1: float = 3e-4
    lr_stage2: float = 3e-5
    # Stage 1 keeps lr_stage1 until this fraction of its steps, then follows a cosine down to
    # lr_final_ratio x lr_stage1 (1.0 = constant, as the paper states it). A constant rate
    # left the landmark loss at a noise floor (~20 px^2, training/README.md, "Learning rate").
    lr_decay_from: float = 0.5
    lr_final_ratio: float = 0.02
    seed: int = 1
    expression_corrections: bool = True  # dS_i (row B of the ablation)
    dynamic_albedo: bool = True  # dR_i (row C)
    parsing_loss: bool = True  # L_pa (row D)
    gradient_loss: bool = True  # L_bg (final row)
    # How L_sd and L_bg are normalised (losses.REDUCTIONS says why); "sum" is the paper's
    # formula taken literally.
    sd_reduction: str = "sum"  # or "mean"
    bg_reduction: str = "shape_mean"  # or "sum", "mean"
    weights: dict = field(default_factory=lambda: dict(L.TRAINING_WEIGHTS))
    # Diagnostic only (never for shipped models): replace ModelNet's dS_0 by each person's
    # true identity offset, to see whether TrackNet's w tracks when identity is not in its way.
    oracle_identity: bool = False
    checkpoint_every_s: float = 300.0
    threads: int = 2
    data: str | None = None  # cache directory of pre-rendered batches (dataset.py)
    # Caches of other seeds' people that the warm-up reads too, interleaved with `data`'s
    # (dataset.CacheUnion); stages 1 and 2 read `data` only. 1,000 warm-up steps of 4
    # batches read the whole 4,000-batch cache once, and after 1.7 such epochs the jawOpen
    # correlation was 0.77 on seen people against 0.60 on held-out ones (issue 31).
    extra_data: list[str] = field(default_factory=list)
    # A checkpoint whose TrackNet (weights and BatchNorm statistics) this run starts from,
    # with a fresh optimiser and schedule: a longer warm-up continues a finished one instead
    # of repeating its steps. A resumed run keeps its own weights.
    init_track_from: str | None = None
    # "bf16": the networks' forward and backward passes run under bfloat16 autocast
    # (weights, optimiser, BatchNorm statistics, losses and the renderer stay float32).
    # `python -m likeness_train.bench_step` measures the speed; on this project's machine
    # (AMX) a TrackNet step is ~2.5x faster. It is not in RESUME_KEYS: it changes rounding,
    # not the networks' shapes or the schedule, so a run may switch on resume.
    precision: str = "fp32"


class Trainer:
    def __init__(self, config: TrainConfig, out_dir: Path):
        self.cfg = config
        self.out = out_dir
        torch.manual_seed(config.seed)
        self.model = FaceModel.load()
        self.region = self.model.restricted()
        self.synthetic = SyntheticData(self.model, self.region, seed=config.seed, image_size=config.input_size, frames=config.frames)
        # The cache holds exactly the batches `synthetic` renders; it renders what is missing.
        self.data = CachedData(Path(config.data), fallback=self.synthetic) if config.data else self.synthetic
        self.warmup_data = self.data
        if config.extra_data:
            if not config.data:
                raise ValueError("extra_data needs data: the extra caches are read beside the main one")
            self.warmup_data = CacheUnion([self.data] + [self.extra_cache(Path(d)) for d in config.extra_data])
        self.corner_uv = self.model.face_region().corner_uv.float()
        self.edges = L.unique_edges(self.region.triangles.long())
        template_shapes = self.region.neutral + self.region.expression_deltas  # S_i [53, Vf, 3]
        with torch.no_grad():
            support = self.region.sample_uv(self.region.masks[None])[0].T > 0  # [53, Vf]: F(A_i) > 0
        self.gradient_loss = L.SupportedGradientLoss(self.region.neutral, self.region.triangles.long(), template_shapes, support, reduction=config.bg_reduction)
        gamma_prior = torch.zeros(27)
        gamma_prior[[0, 9, 18]] = 0.7 / (torch.pi / (4 * torch.pi) ** 0.5)  # ambient 0.7
        self.track = TrackNet(
            width=config.track_width, gamma_prior=gamma_prior, rotation_scale=config.track_rotation_scale,
            translation_scale=config.track_translation_scale, w_gain=config.track_w_gain,
            w_grad_scale=config.track_w_grad_scale, pool=config.track_pool, input_size=config.input_size,
            w_head=config.track_w_head, w_hidden=config.track_w_hidden, context=config.track_context,
        )
        if config.track_context and (config.stage1_steps > 0 or config.stage2_steps > 0):
            raise ValueError("track_context is a warm-up probe so far: run it with stage1_steps = stage2_steps = 0")
        if config.init_track_from:
            self.init_track(Path(config.init_track_from))
        self.mirror = mirror_channels(self.model.expression_names)
        # Set by `run` on the steps it logs: the step then measures each term's gradient at
        # TrackNet's trunk (`trunk_gradients`).
        self.measure_trunk = False
        # ModelNet reads 128 or 224 px; a TrackNet for another input size (160 px, issue 31)
        # is trained in the warm-up alone and runs beside a ModelNet trained at 128 px, so
        # its run holds an untrained 128 px ModelNet that no stage trains.
        if config.input_size not in MODEL_NET_SIZES and (config.stage1_steps > 0 or config.stage2_steps > 0):
            raise ValueError(
                f"input_size {config.input_size}: ModelNet reads {' or '.join(map(str, MODEL_NET_SIZES))} px, so stages 1 and 2 cannot run; "
                "train this TrackNet in the warm-up alone (--stage1-steps 0 --stage2-steps 0)"
            )
        self.modelnet = ModelNet(input_size=config.input_size if config.input_size in MODEL_NET_SIZES else 128, width=config.model_width)
        if config.precision not in PRECISIONS:
            raise ValueError(f"precision must be one of {PRECISIONS}, got {config.precision!r}")
        # NHWC is the layout oneDNN's convolutions run fastest in on CPU (~1.2x in fp32,
        # needed for bf16's gain); it changes the memory order only, not one value.
        self.track.to(memory_format=torch.channels_last)
        self.modelnet.to(memory_format=torch.channels_last)
        # R_0^t: the trainable mean albedo, initialised with R_0 (paper, eq. (3)).
        self.mean_albedo = nn.Parameter(self.region.mean_albedo_face.clone())
        self.step = 0
        self.stage = 0 if config.landmark_warmup_steps > 0 else 1
        self.optimizer = self._optimizer()
        self.started = time.time()
        self.elapsed_before = 0.0

    def init_track(self, path: Path) -> None:
        """TrackNet's weights from another run's checkpoint (`init_track_from`); refused when
        that TrackNet was built otherwise."""
        if not path.is_file():
            raise FileNotFoundError(f"--init-track-from {path}: no such checkpoint")
        try:
            state = torch.load(path, map_location="cpu", weights_only=False)
        except (pickle.UnpicklingError, RuntimeError, EOFError, OSError) as e:
            raise ValueError(f"--init-track-from {path}: cannot be read as a checkpoint ({e})") from e
        if not isinstance(state, dict) or "track_net" not in state or "config" not in state:
            raise ValueError(f"--init-track-from {path}: not a training checkpoint (no track_net and config)")
        for key in TRACK_SHAPE_KEYS:
            theirs = state["config"].get(key)
            if key == "track_context":
                theirs = bool(theirs)  # checkpoints from before the option have none
            if key == "track_width" and isinstance(theirs, (int, float)) and widths_match(theirs, self.cfg.track_width):
                continue  # a narrower TrackNet is widened below
            if key == "track_context" and not theirs and self.cfg.track_context:
                continue  # a plain TrackNet: its context branch starts at zero, below
            if key == "input_size" and isinstance(theirs, int) and theirs != self.cfg.input_size and not self.cfg.track_context:
                continue  # resized below
            if theirs != getattr(self.cfg, key):
                raise ValueError(f"--init-track-from {path}: its TrackNet has {key} = {theirs!r}, this run builds {getattr(self.cfg, key)!r}")
        theirs = state["config"]["track_width"]
        if state["config"]["input_size"] != self.cfg.input_size:
            # A TrackNet for another input size: its trunk and heads moved to this one's
            # grid (widen.resize_track_input), then widened if it is also narrower.
            if state["config"].get("track_context"):
                raise ValueError(f"--init-track-from {path}: a context TrackNet is not resized to another input size")
            small = build_track_net(state["config"])
            small.load_state_dict(state["track_net"])
            resized = build_track_net({**state["config"], "input_size": self.cfg.input_size})
            resize_track_input(small, resized)
            print(f"TrackNet resized from {state['config']['input_size']} px to {self.cfg.input_size} px input", file=sys.stderr, flush=True)
            if theirs == self.cfg.track_width:
                self.track.load_state_dict(resized.state_dict())
            else:
                widen_track(resized, self.track, seed=self.cfg.seed)
            return
        if self.cfg.track_context and not state["config"].get("track_context"):
            if theirs != self.cfg.track_width:
                raise ValueError(f"--init-track-from {path}: a context TrackNet starts from a plain one of the same width only")
            missing, unexpected = self.track.load_state_dict(state["track_net"], strict=False)
            if unexpected or any(not k.startswith("context_net.") for k in missing):
                raise ValueError(f"--init-track-from {path}: weights do not match (missing {missing}, unexpected {unexpected})")
            return
        if theirs == self.cfg.track_width:
            self.track.load_state_dict(state["track_net"])
            return
        # A narrower TrackNet: the same function in the wider trunk (widen.py says how).
        narrow = build_track_net(state["config"])
        narrow.load_state_dict(state["track_net"])
        widen_track(narrow, self.track, seed=self.cfg.seed)
        print(f"TrackNet widened from width {theirs} to {self.cfg.track_width} (function kept)", file=sys.stderr, flush=True)

    def extra_cache(self, directory: Path) -> CachedData:
        """One `--extra-data` cache, with on-the-fly rendering of its seed for what it lacks;
        refused when its people are ones the evaluation, the clips or the fixtures hold out."""
        from .clips import CLIPS_SEED
        from .evaluate import HELD_OUT_SEED
        from .fixtures import FIXTURE_SEED
        from .preprocess import CALIBRATION_SEED

        cache = CachedData(directory)
        held_out = {HELD_OUT_SEED: "the held-out evaluation", CLIPS_SEED: "the tracking clips", FIXTURE_SEED: "the test fixtures", CALIBRATION_SEED: "the calibration"}
        if cache.spec.seed in held_out:
            raise ValueError(f"{directory} holds seed {cache.spec.seed}, the people of {held_out[cache.spec.seed]}; training on them would leak into what measures it")
        if cache.spec.seed == self.cfg.seed:
            raise ValueError(f"{directory} holds seed {cache.spec.seed}, the training's own (--data's) people")
        fallback = SyntheticData(self.model, self.region, seed=cache.spec.seed, image_size=self.cfg.input_size, frames=self.cfg.frames)
        return CachedData(directory, fallback=fallback)

    def _optimizer(self) -> torch.optim.Optimizer:
        if self.stage == 0:
            return torch.optim.Adam(self.track.parameters(), lr=self.cfg.lr_stage1)
        if self.stage == 1:
            # Two groups so TrackNet's rate can be a fixed ratio of ModelNet's (lr_scale, run()).
            groups = [
                {"params": list(self.track.parameters()), "lr_scale": self.cfg.stage1_track_lr_ratio},
                {"params": list(self.modelnet.parameters()) + [self.mean_albedo], "lr_scale": 1.0},
            ]
            return torch.optim.Adam(groups, lr=self.cfg.lr_stage1)
        return torch.optim.Adam(list(self.modelnet.parameters()) + [self.mean_albedo], lr=self.cfg.lr_stage2)

    # --- checkpoints -----------------------------------------------------------------

    @property
    def checkpoint_path(self) -> Path:
        return self.out / "checkpoint.pt"

    def save(self, metrics: dict | None = None) -> None:
        self.out.mkdir(parents=True, exist_ok=True)
        state = {
            "config": {**asdict(self.cfg), "blendshape_names": self.model.expression_names},
            "step": self.step,
            "stage": self.stage,
            "track_net": self.track.state_dict(),
            "model_net": self.modelnet.state_dict(),
            "mean_albedo": self.mean_albedo.detach(),
            "optimizer": self.optimizer.state_dict(),
            "elapsed_s": self.elapsed(),
            "commit": git_commit(),
            "metrics": metrics or {},
        }
        tmp = self.checkpoint_path.with_suffix(".tmp")
        torch.save(state, tmp)
        tmp.replace(self.checkpoint_path)  # atomic: an interruption never leaves half a file

    def resume(self) -> bool:
        if not self.checkpoint_path.exists():
            return False
        state = torch.load(self.checkpoint_path, map_location="cpu", weights_only=False)
        # These fix the networks' shapes and which batch and rate each step gets; resuming
        # with others would fail inside load_state_dict or silently train another schedule.
        saved = state.get("config", {})
        for key in RESUME_KEYS:
            if key in saved and saved[key] != getattr(self.cfg, key):
                raise SystemExit(
                    f"{self.checkpoint_path} was trained with {key} = {saved[key]!r}, this run asks for {getattr(self.cfg, key)!r}; "
                    "pass the same value to resume, or use another --out"
                )
        self.track.load_state_dict(state["track_net"])
        self.modelnet.load_state_dict(state["model_net"])
        with torch.no_grad():
            self.mean_albedo.copy_(state["mean_albedo"])
        self.step, self.stage = state["step"], state["stage"]
        self.optimizer = self._optimizer()
        self.optimizer.load_state_dict(state["optimizer"])
        if self.stage == 1:  # the saved groups carry the saved ratio; this run's config decides
            self.optimizer.param_groups[0]["lr_scale"] = self.cfg.stage1_track_lr_ratio
        self.elapsed_before = state.get("elapsed_s", 0.0)
        self.started = time.time()
        return True

    def learning_rate(self) -> float:
        """The stage's learning rate at the current step (a pure function of the step, so a
        resumed run follows the same schedule)."""
        if self.stage == 2:
            return self.cfg.lr_stage2
        if self.stage == 0:
            return warmup_learning_rate(self.step, self.cfg)
        return stage1_learning_rate(self.step - self.cfg.landmark_warmup_steps, self.cfg)

    def data_index(self) -> int:
        """Which batch the current step reads: stages 1 and 2 read the same batches with or
        without a warm-up (the warm-up re-reads the first ones)."""
        if self.stage == 0:
            return self.step
        return self.step - self.cfg.landmark_warmup_steps

    def warmup_indices(self) -> list[int]:
        """The batches a warm-up step reads: `warmup_batches_per_step` consecutive ones, in
        order over the cache and around again (on-the-fly data has no end)."""
        k = self.cfg.warmup_batches_per_step
        first = self.data_index() * k
        size = len(self.warmup_data) if isinstance(self.warmup_data, (CachedData, CacheUnion)) else None
        return [(first + j) % size if size else first + j for j in range(k)]

    def read_batch(self) -> Batch:
        if self.stage == 0 and self.cfg.warmup_batches_per_step > 1:
            return concat_batches([self.warmup_data.batch(k, self.cfg.people_per_batch) for k in self.warmup_indices()])
        if self.stage == 0:
            return self.warmup_data.batch(self.warmup_indices()[0], self.cfg.people_per_batch)
        return self.data.batch(self.data_index(), self.cfg.people_per_batch)

    def elapsed(self) -> float:
        return self.elapsed_before + time.time() - self.started

    # --- one step --------------------------------------------------------------------

    def normalise(self, images: torch.Tensor) -> torch.Tensor:
        return normalise(images).contiguous(memory_format=torch.channels_last)

    def autocast(self) -> contextlib.AbstractContextManager:
        """The context the networks run in (`precision`); their outputs leave it as float32."""
        return torch.autocast("cpu", dtype=torch.bfloat16, enabled=self.cfg.precision == "bf16")

    def track_forward(self, images: torch.Tensor) -> TrackParams:
        with self.autocast():
            return as_float(self.track(self.normalise(images)))

    def modelnet_forward(self, batch: Batch) -> Corrections:
        size = self.cfg.input_size
        x = self.normalise(batch.images)
        with self.autocast():
            return as_float(ablate(self.modelnet(x.view(batch.people, batch.frames, 3, size, size)), self.cfg))

    def predict(self, batch: Batch) -> tuple[TrackParams, Corrections]:
        return self.track_forward(batch.images), self.modelnet_forward(batch)

    def losses(self, batch: Batch, params: TrackParams, c: Corrections, with_reg: bool) -> dict[str, torch.Tensor]:
        p = render_prediction(
            self.region, self.corner_uv, batch, params, c, self.mean_albedo, self.cfg.input_size,
            parsing_texture=self.synthetic.parsing_face if self.cfg.parsing_loss else None,
        )
        shape, out, landmarks = p.shape, p.out, p.landmarks
        images = batch.images.permute(0, 2, 3, 1)
        terms = {
            "ph": L.photometric_loss(images, out.image, out.mask) + L.gradient_loss(images, out.image, out.mask),
            "lm": L.landmark_loss(batch.landmarks, landmarks),
            "sd": L.smoothness_loss(self.region.sample_uv(c.dS0), self.edges, reduction=self.cfg.sd_reduction),
        }
        if self.cfg.parsing_loss:
            terms["pa"] = L.parsing_loss(batch.parsing, out.parsing)
        if self.cfg.gradient_loss and self.cfg.expression_corrections:
            # S_i + F(A_i dS_i) for every blendshape of every person: [P, 53, Vf, 3].
            corrected = self.region.neutral + self.region.blendshapes(c.dS)
            terms["bg"] = self.gradient_loss(corrected)
        if with_reg:
            terms["reg"] = L.regularization_loss(params.w, params.gamma)
        # Per-image averages keep the paper's weights meaningful at any batch size.
        frames = batch.people * batch.frames
        return {k: v / (batch.people if k in ("sd", "bg") else frames) for k, v in terms.items()}

    def _optimise(self, terms: dict[str, torch.Tensor], weights: dict[str, float] | None = None) -> dict[str, float]:
        """One Adam step on the weighted sum of the loss terms; returns the logged values."""
        weights = self.cfg.weights if weights is None else weights
        total = sum(weights[k] * v for k, v in terms.items())
        self.optimizer.zero_grad(set_to_none=True)
        total.backward()
        self.optimizer.step()
        self.step += 1
        return {"total": float(total.detach()), **{k: float(v.detach()) for k, v in terms.items()}}

    def warmup_step(self, batch: Batch) -> dict[str, float]:
        """Stage 0: L_lm + L_reg of TrackNet's w and pose on the template shape
        S_0 + sum_i w_i (S_i - S_0) at the 68 landmark vertices only, plus the supervised
        terms."""
        self.track.train()
        with self.autocast():
            features = self.track.encoder(self.normalise(batch.images))
            context = leave_one_out_context(features, batch.people, batch.frames) if self.cfg.track_context else None
            params = as_float(self.track.heads(features, context))
        idx = self.region.landmarks_68
        neutral = self.region.neutral[idx]
        deltas = self.region.expression_deltas[:, idx]
        points = neutral + torch.einsum("bi,ivc->bvc", params.w, deltas)
        cx, cy = batch.principal[:, 0], batch.principal[:, 1]
        translation = camera_translation(params.translation, batch.focal, self.cfg.input_size)
        landmarks, _ = R.project(points, R.euler_to_matrix(params.euler), translation, batch.focal, cx, cy)
        frames = batch.people * batch.frames
        terms = {"lm": L.landmark_loss(batch.landmarks, landmarks) / frames, "reg": L.regularization_loss(params.w, params.gamma) / frames}
        sup_terms, sup_weights = self.supervision(params, batch, pose=True)
        terms, weights = {**terms, **sup_terms}, {**self.cfg.weights, **sup_weights}
        norms = trunk_gradients(features, terms, weights) if self.measure_trunk else {}
        return {**self._optimise(terms, weights), **norms}

    def supervision(self, params: TrackParams, batch: Batch, pose: bool = False) -> tuple[dict[str, torch.Tensor], dict[str, float]]:
        """The warm-up's supervised terms (TrainConfig says why): w (`w_loss`), gamma and,
        with `pose`, the head pose against the synthetic truth per image, with their
        weights; empty when off."""
        frames = batch.people * batch.frames
        terms, weights = {}, {}
        if self.cfg.warmup_supervision > 0:
            terms["sup"] = w_loss(params, batch.weights, self.cfg.w_loss) / frames
            weights["sup"] = self.cfg.warmup_supervision
        if pose and self.cfg.warmup_pose_supervision > 0:
            target = reference_translation(batch.translation, batch.focal, self.cfg.input_size)
            terms["sup_pose"] = ((params.euler - batch.euler).pow(2).sum() + (params.translation - target).pow(2).sum() / 100.0) / frames
            weights["sup_pose"] = self.cfg.warmup_pose_supervision
        if self.cfg.warmup_light_supervision > 0:
            terms["sup_light"] = (params.gamma - batch.gamma).pow(2).sum() / frames
            weights["sup_light"] = self.cfg.warmup_light_supervision
        return terms, weights

    def tracking_frozen(self) -> bool:
        """Stage 2 always; stage 1 for its first `stage1_track_frozen_steps` steps."""
        if self.stage == 2:
            return True
        return self.stage == 1 and self.step < self.cfg.landmark_warmup_steps + self.cfg.stage1_track_frozen_steps

    def train_step(self) -> dict[str, float]:
        batch = self.read_batch()
        batch = mirror_batch(batch, self.flips(batch), self.mirror)
        if self.stage == 0:
            if self.cfg.photometric_augment > 0:
                generator = torch.Generator().manual_seed(self.cfg.seed * 1_000_003 + self.step + 7_919_000_000)
                batch = photometric_batch(batch, self.cfg.photometric_augment, generator)
            return self.warmup_step(batch)
        frozen_tracking = self.tracking_frozen()
        self.track.train(not frozen_tracking)
        self.modelnet.train()
        if frozen_tracking:
            with torch.no_grad():
                params = self.track_forward(batch.images)
            corrections = self.modelnet_forward(batch)
        else:
            params, corrections = self.predict(batch)
        if self.cfg.oracle_identity:
            first = batch.index * batch.people
            corrections.dS0 = torch.stack([self.synthetic.people.person(first + p).dS0 for p in range(batch.people)])
        # Stage 2 drops the tracking regulariser (the paper); frozen stage-1 steps keep it
        # in the logged total (it has no gradient then) so stage 1's totals compare.
        terms = self.losses(batch, params, corrections, with_reg=self.stage == 1)
        if self.cfg.stage1_supervision and not frozen_tracking:
            sup_terms, sup_weights = self.supervision(params, batch)
            return self._optimise({**terms, **sup_terms}, {**self.cfg.weights, **sup_weights})
        return self._optimise(terms)

    def flips(self, batch: Batch) -> torch.Tensor:
        """Which images of the step's batch are mirrored: whole people (ModelNet sees one
        person in all N frames), drawn from (seed, step) so a resumed run draws the same."""
        if self.cfg.flip_probability <= 0:
            return torch.zeros(batch.people * batch.frames, dtype=torch.bool)
        generator = torch.Generator().manual_seed(self.cfg.seed * 1_000_003 + self.step)
        people = torch.rand(batch.people, generator=generator) < self.cfg.flip_probability
        return people.repeat_interleave(batch.frames)


    def run(self, log_every: int = 10) -> None:
        torch.set_num_threads(self.cfg.threads)
        # Denormal floats in the synthetic people's maps slow on-the-fly batches ~20x
        # (dataset._worker); flushing them to zero changes values below 1e-38 only.
        torch.set_flush_denormal(True)
        self.out.mkdir(parents=True, exist_ok=True)
        log = (self.out / "log.jsonl").open("a")
        last_save = time.time()
        warmup = self.cfg.landmark_warmup_steps
        total_steps = warmup + self.cfg.stage1_steps + self.cfg.stage2_steps
        while self.step < total_steps:
            if self.stage == 0 and self.step >= warmup:
                self.keep_warmup()
                self.stage = 1
                self.optimizer = self._optimizer()
                self.save()
            if self.stage == 1 and self.step >= warmup + self.cfg.stage1_steps:
                self.stage = 2
                self.optimizer = self._optimizer()
                self.save()
            t0 = time.time()
            lr = self.learning_rate()
            for group in self.optimizer.param_groups:
                group["lr"] = lr * group.get("lr_scale", 1.0)
            self.measure_trunk = (self.step + 1) % log_every == 0
            values = self.train_step()
            values.update(lr=lr, step=self.step, stage=self.stage, step_s=round(time.time() - t0, 3), elapsed_s=round(self.elapsed(), 1))
            if self.step % log_every == 0 or self.step == total_steps:
                line = json.dumps(values)
                print(line, flush=True)
                log.write(line + "\n")
                log.flush()
            if time.time() - last_save > self.cfg.checkpoint_every_s:
                self.save()
                last_save = time.time()
        if self.stage == 0 and warmup > 0:  # a warm-up-only run (no stage-1 steps) ends here
            self.keep_warmup()
        self.save()

    def keep_warmup(self) -> None:
        """Saves the warm-up's end beside the checkpoint: it does not depend on the stage-1
        flags, so the ablation rows start from it (`ablation --warmup-from`)."""
        self.save()
        shutil.copyfile(self.checkpoint_path, self.out / WARMUP_CHECKPOINT)


def as_float(outputs):
    """TrackParams or Corrections with every tensor float32: under bf16 autocast the heads
    return bfloat16, and the losses, the renderer and the logged values stay float32."""
    return dataclasses.replace(outputs, **{
        f.name: value.float() for f in dataclasses.fields(outputs) if isinstance(value := getattr(outputs, f.name), torch.Tensor)
    })


def w_loss(params: TrackParams, truth: torch.Tensor, kind: str) -> torch.Tensor:
    """The supervised w term summed over the batch (TrainConfig.w_loss)."""
    if kind == "sq":
        return (params.w - truth).pow(2).sum()
    l1 = (params.w - truth).abs().sum()
    if kind == "l1":
        return l1
    if params.w_logits is None:
        raise ValueError("the cross-entropy w loss needs TrackNet's logits")
    return nn.functional.binary_cross_entropy_with_logits(params.w_logits, truth, reduction="sum") + l1


def trunk_gradients(features: torch.Tensor, terms: dict[str, torch.Tensor], weights: dict[str, float]) -> dict[str, float]:
    """The norm of each weighted term's gradient at TrackNet's trunk output (the features
    all heads read), as `grad_<term>`: whether w's term trains the trunk or pose's drowns it
    (issue 31). Costs one backward pass through the heads per term."""
    out = {}
    for name, value in terms.items():
        if not value.requires_grad:
            continue
        (grad,) = torch.autograd.grad(weights[name] * value, features, retain_graph=True, allow_unused=True)
        out[f"grad_{name}"] = 0.0 if grad is None else float(grad.norm())
    return out


def decayed_learning_rate(step: int, steps: int, cfg: TrainConfig) -> float:
    """lr_stage1 until `lr_decay_from` of `steps`, then a cosine down to lr_final_ratio x it."""
    start = int(cfg.lr_decay_from * steps)
    if step < start or steps <= start:
        return cfg.lr_stage1
    progress = min(1.0, (step - start) / (steps - start))
    low = cfg.lr_stage1 * cfg.lr_final_ratio
    return low + 0.5 * (cfg.lr_stage1 - low) * (1.0 + math.cos(math.pi * progress))


def stage1_learning_rate(step: int, cfg: TrainConfig) -> float:
    return decayed_learning_rate(step, cfg.stage1_steps, cfg)


def warmup_learning_rate(step: int, cfg: TrainConfig) -> float:
    """The warm-up decays like stage 1 when `warmup_lr_decay` is set (stage 1 then starts
    again from lr_stage1)."""
    ramp = min(1.0, (step + 1) / cfg.warmup_lr_ramp_steps) if cfg.warmup_lr_ramp_steps > 0 else 1.0
    if not cfg.warmup_lr_decay:
        return ramp * cfg.lr_stage1
    return ramp * decayed_learning_rate(step, cfg.landmark_warmup_steps, cfg)


# TrackNet's translation is for a camera of this field of view (the middle of the synthetic
# cameras' 25-40 degrees). An image does not show its focal length: a face of the same pixel
# size is ~1.6x farther at 25 than at 40 degrees, so a translation predicted for the true
# camera is a guess whose error scales every projected landmark (by up to +-25 %; this was
# the ~4 px landmark floor of the first runs). For a camera of focal f the distance t_z is
# scaled by f / f_ref (t_x, t_y stay): the face's centre then projects to the same pixel
# under both cameras, every other point to first order in its depth / the distance.
REFERENCE_FOV_DEG = 32.5


def reference_focal(size: int) -> float:
    """f_ref in pixels for a square input of `size` pixels."""
    return 0.5 * size / math.tan(math.radians(0.5 * REFERENCE_FOV_DEG))


def camera_translation(translation: torch.Tensor, focal: torch.Tensor, size: int) -> torch.Tensor:
    """TrackNet's translation [B, 3] (for f_ref) -> the translation for cameras of focal
    `focal` [B] pixels."""
    scale = torch.ones_like(translation)
    scale[:, 2] = focal / reference_focal(size)
    return translation * scale


def reference_translation(translation: torch.Tensor, focal: torch.Tensor, size: int) -> torch.Tensor:
    """The inverse of `camera_translation`: a camera's translation expressed for f_ref (what
    TrackNet should predict for a frame whose true translation is `translation`)."""
    scale = torch.ones_like(translation)
    scale[:, 2] = reference_focal(size) / focal
    return translation * scale


def normalise(images: torch.Tensor) -> torch.Tensor:
    """The networks' input normalisation (the manifest's), images [B, 3, H, W] in [0, 1]."""
    mean = torch.tensor(IMAGE_MEAN).view(1, 3, 1, 1)
    std = torch.tensor(IMAGE_STD).view(1, 3, 1, 1)
    return (images - mean) / std


def ablate(corrections: Corrections, cfg: TrainConfig) -> Corrections:
    """Zeroes the corrections an ablation row leaves out (dS_i for row A, dR_i before row C),
    the same in training and evaluation."""
    if not cfg.expression_corrections:
        corrections.dS = torch.zeros_like(corrections.dS)
    if not cfg.dynamic_albedo:
        corrections.dR = torch.zeros_like(corrections.dR)
    return corrections


@dataclass
class Prediction:
    shape: torch.Tensor  # [P*N, Vf, 3] equation (2), model space
    albedo: torch.Tensor  # [P*N, 3, S, S] equation (3) on the face layer
    rotation: torch.Tensor  # [P*N, 3, 3]
    landmarks: torch.Tensor  # [P*N, 68, 2] projected, pixels
    out: R.RenderOutput


def render_prediction(
    region: FaceModel, corner_uv: torch.Tensor, batch: Batch, params: TrackParams, c: Corrections,
    mean_albedo: torch.Tensor, size: int, parsing_texture: torch.Tensor | None = None,
) -> Prediction:
    """Equations (2) and (3) with the predicted corrections (one set per person, applied to
    the person's N frames without copying them), rendered with the predicted pose and light
    and the batch's known camera: what the training losses and the evaluation compare with
    the images."""
    shape = region.shape(params.w, c.dS0, c.dS)
    albedo = region.albedo(params.w, c.dR0, c.dR, mean_albedo=mean_albedo)
    rotation = R.euler_to_matrix(params.euler)
    cx, cy = batch.principal[:, 0], batch.principal[:, 1]
    translation = camera_translation(params.translation, batch.focal, size)
    out = R.render(
        shape, region.triangles.long(), corner_uv, albedo, params.gamma, rotation, translation,
        batch.focal, cx, cy, size, size, parsing_texture=parsing_texture,
    )
    landmarks, _ = R.project(region.landmarks(shape), rotation, translation, batch.focal, cx, cy)
    return Prediction(shape, albedo, rotation, landmarks, out)


def config_from_args(argv: list[str] | None = None) -> tuple[TrainConfig, Path]:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--out", type=Path, required=True)
    defaults = TrainConfig()
    for name in ("input_size", "people_per_batch", "frames", "landmark_warmup_steps", "stage1_track_frozen_steps", "stage1_steps", "stage2_steps", "seed", "threads", "track_w_hidden", "warmup_lr_ramp_steps", "warmup_batches_per_step"):
        parser.add_argument("--" + name.replace("_", "-"), type=int, default=getattr(defaults, name))
    for name in ("track_width", "model_width", "lr_stage1", "lr_stage2", "lr_decay_from", "lr_final_ratio", "checkpoint_every_s", "warmup_supervision", "warmup_light_supervision", "stage1_track_lr_ratio", "track_rotation_scale", "track_translation_scale", "track_w_gain", "track_w_grad_scale", "warmup_pose_supervision", "flip_probability", "photometric_augment"):
        parser.add_argument("--" + name.replace("_", "-"), type=float, default=getattr(defaults, name))
    for name in ("expression_corrections", "dynamic_albedo", "parsing_loss", "gradient_loss"):
        parser.add_argument("--no-" + name.replace("_", "-"), dest=name, action="store_false")
    parser.add_argument("--data", type=str, default=None, help="cache directory written by `python -m likeness_train.dataset`")
    parser.add_argument(
        "--extra-data", action="append", default=[], metavar="DIR",
        help="a cache of another seed's people that the warm-up also reads (TrainConfig.extra_data); repeatable",
    )
    parser.add_argument("--oracle-identity", action="store_true", help="diagnostic: use each person's true dS_0 instead of ModelNet's")
    parser.add_argument(
        "--warmup-lr-decay", action=argparse.BooleanOptionalAction, default=defaults.warmup_lr_decay,
        help="the warm-up's learning rate follows stage 1's schedule shape",
    )
    parser.add_argument(
        "--stage1-supervision", action=argparse.BooleanOptionalAction, default=defaults.stage1_supervision,
        help="keep the warm-up's supervised terms for TrackNet in stage 1",
    )
    parser.add_argument("--track-pool", choices=TRACK_POOLS, default=defaults.track_pool)
    parser.add_argument("--track-w-head", choices=TRACK_W_HEADS, default=defaults.track_w_head)
    parser.add_argument("--track-context", action="store_true", help="the w head also reads the person's other frames (TrainConfig.track_context; a warm-up probe)")
    parser.add_argument("--w-loss", choices=W_LOSSES, default=defaults.w_loss)
    parser.add_argument("--init-track-from", default=None, metavar="CHECKPOINT", help="start TrackNet from this checkpoint's (TrainConfig.init_track_from)")
    parser.add_argument("--precision", choices=PRECISIONS, default=defaults.precision, help="the networks' arithmetic (TrainConfig.precision)")
    parser.add_argument("--sd-reduction", choices=("sum", "mean"), default=defaults.sd_reduction)
    parser.add_argument("--bg-reduction", choices=("sum", "shape_mean", "mean"), default=defaults.bg_reduction)
    parser.add_argument(
        "--weight", action="append", default=[], metavar="TERM=VALUE",
        help=f"override one loss weight lambda (terms: {', '.join(L.PAPER_WEIGHTS)}; defaults: losses.TRAINING_WEIGHTS); repeatable",
    )
    args = vars(parser.parse_args(argv))
    out = args.pop("out")
    # `not (a <= x <= b)` also rejects NaN.
    checks = {
        "landmark_warmup_steps": (0, float("inf")), "stage1_steps": (0, float("inf")), "stage2_steps": (0, float("inf")),
        "lr_decay_from": (0.0, 1.0), "lr_final_ratio": (0.0, 1.0), "track_w_grad_scale": (1e-6, 1e6), "warmup_supervision": (0.0, 1e6),
        "warmup_light_supervision": (0.0, 1e6), "stage1_track_frozen_steps": (0, float("inf")), "stage1_track_lr_ratio": (0.0, 1e3),
        "warmup_pose_supervision": (0.0, 1e6), "flip_probability": (0.0, 1.0), "photometric_augment": (0.0, 1.0), "track_w_hidden": (1, 8192),
        "warmup_lr_ramp_steps": (0, float("inf")), "warmup_batches_per_step": (1, 64),
    }
    for name, (low, high) in checks.items():
        if not (low <= args[name] <= high):
            parser.error(f"--{name.replace('_', '-')} {args[name]}: must be within [{low}, {high}]")
    if args["extra_data"] and not args["data"]:
        parser.error("--extra-data needs --data: the extra caches are read beside the main one")
    weights = dict(defaults.weights)
    for item in args.pop("weight"):
        term, _, value = item.partition("=")
        if term not in weights:
            parser.error(f"--weight {item!r}: unknown term {term!r} (terms: {', '.join(weights)})")
        try:
            weights[term] = float(value)
        except ValueError:
            parser.error(f"--weight {item!r}: {value!r} is not a number")
        if not weights[term] >= 0.0:  # also rejects NaN
            parser.error(f"--weight {item!r}: a loss weight must be a non-negative number")
    return TrainConfig(**args, weights=weights), out


def cpu_has_bf16() -> bool:
    """Whether oneDNN runs bfloat16 in hardware here (AVX512-BF16 or AMX). Without it
    autocast emulates bf16 and a step is ~10x slower than float32, not ~2.5x faster: on a
    2-core AVX2 EPYC (2026-12-07) a warm-up step took 17 s in bf16 and ~1.2 s in fp32."""
    try:
        return bool(torch.ops.mkldnn._is_mkldnn_bf16_supported())
    except (AttributeError, RuntimeError):  # a build without oneDNN: no fast bf16 either
        return False


def main(argv: list[str] | None = None) -> None:
    config, out = config_from_args(argv)
    if config.precision == "bf16" and not cpu_has_bf16():
        print("warning: --precision bf16 on a CPU without AVX512-BF16 or AMX: bfloat16 is emulated and steps run ~10x slower than --precision fp32", file=sys.stderr, flush=True)
    try:
        trainer = Trainer(config, out)
    except (FileNotFoundError, ValueError) as e:  # a missing or unusable cache, named
        raise SystemExit(f"error: {e}") from e
    if trainer.resume():
        print(f"resumed from {trainer.checkpoint_path} at step {trainer.step} (stage {trainer.stage})", flush=True)
    trainer.run()


if __name__ == "__main__":
    main()
