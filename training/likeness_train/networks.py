"""ModelNet and TrackNet, as the paper's architecture tables describe them.

ModelNet (appendix, Table (a) and (b)): a shared encoder per image, Conv7x7 s2 -> maxpool
3x3 s2 -> pairs of 3x3 convs (s1 then s2) up to 512 channels; the per-image features of the
N images of one person are averaged; two decoders (shape and albedo) of four 4x4 stride-2
deconvolutions to 128x128x64, each followed by two 1x1 convs: one to the static correction
(128x128x3: dS_0 or dR_0) and one to the 53 per-blendshape corrections (128x128x(53*3):
dS_i or dR_i). Every conv and deconv is followed by BatchNorm and ReLU, except the output
1x1 convs, which must be able to produce negative corrections.

TrackNet: a ResNet-18 encoder and fully connected layers to w (53, sigmoid), Euler angles
(3), translation (3) and SH lighting gamma (27).

Deviations, both configurable and recorded in the model manifest:
- input size: the paper uses 224; at 128 the encoder ends at 4x4 instead of 7x7, so the
  first decoder deconvolution uses stride 4 (4 -> 16) instead of stride 2 with no padding
  (7 -> 16); the rest of the decoder is unchanged.
- channel width: `width` scales every channel count (1.0 = the paper's), because on two CPU
  cores the full-width networks train about 3x slower (see docs/training.md).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import torch
from torch import nn

NUM_BLENDSHAPES = 53
UV_SIZE = 128


def _ch(channels: int, width: float) -> int:
    return max(8, int(round(channels * width)))


def conv_bn_relu(cin: int, cout: int, kernel: int, stride: int) -> nn.Sequential:
    return nn.Sequential(
        nn.Conv2d(cin, cout, kernel, stride, padding=kernel // 2, bias=False),
        nn.BatchNorm2d(cout),
        nn.ReLU(inplace=True),
    )


def deconv_bn_relu(cin: int, cout: int, stride: int, padding: int) -> nn.Sequential:
    return nn.Sequential(
        nn.ConvTranspose2d(cin, cout, 4, stride, padding=padding, bias=False),
        nn.BatchNorm2d(cout),
        nn.ReLU(inplace=True),
    )


class ModelEncoder(nn.Module):
    """Table (a): 224 -> 7x7x512 (128 -> 4x4x512)."""

    def __init__(self, width: float = 1.0):
        super().__init__()
        c64, c128, c256, c512 = (_ch(c, width) for c in (64, 128, 256, 512))
        self.layers = nn.Sequential(
            conv_bn_relu(3, c64, 7, 2),
            nn.MaxPool2d(3, 2, padding=1),
            conv_bn_relu(c64, c128, 3, 1),
            conv_bn_relu(c128, c128, 3, 2),
            conv_bn_relu(c128, c256, 3, 1),
            conv_bn_relu(c256, c256, 3, 2),
            conv_bn_relu(c256, c512, 3, 1),
            conv_bn_relu(c512, c512, 3, 2),
        )
        self.out_channels = c512

    def forward(self, images: torch.Tensor) -> torch.Tensor:
        return self.layers(images)


class CorrectionDecoder(nn.Module):
    """Table (b): feature -> 128x128x64 -> (static [3], per-blendshape [53*3]) maps."""

    def __init__(self, in_channels: int, feature_size: int, width: float = 1.0):
        super().__init__()
        c512, c256, c128, c64 = (_ch(c, width) for c in (512, 256, 128, 64))
        # The paper's 7 -> 16 is a stride-2 deconvolution without padding; from a 4x4
        # feature (128 px input) the same 16x16 needs stride 4.
        if feature_size == 7:
            first = deconv_bn_relu(in_channels, c512, stride=2, padding=0)
        elif feature_size == 4:
            first = deconv_bn_relu(in_channels, c512, stride=4, padding=0)
        else:
            raise ValueError(f"ModelNet supports 224 or 128 px inputs (feature 7 or 4), got {feature_size}")
        self.trunk = nn.Sequential(
            first,
            deconv_bn_relu(c512, c256, 2, 1),
            deconv_bn_relu(c256, c128, 2, 1),
            deconv_bn_relu(c128, c64, 2, 1),
        )
        self.static_head = nn.Conv2d(c64, 3, 1)
        self.blendshape_head = nn.Conv2d(c64, 3 * NUM_BLENDSHAPES, 1)
        # Start from the template: zero corrections until the losses ask for them.
        for head in (self.static_head, self.blendshape_head):
            nn.init.zeros_(head.weight)
            nn.init.zeros_(head.bias)

    def forward(self, feature: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        x = self.trunk(feature)
        static = self.static_head(x)
        per_shape = self.blendshape_head(x)
        b = per_shape.shape[0]
        return static, per_shape.view(b, NUM_BLENDSHAPES, 3, UV_SIZE, UV_SIZE)


@dataclass
class Corrections:
    """ModelNet's output for a batch of people: UV maps [P, 3, 128, 128] and
    [P, 53, 3, 128, 128]. Shape corrections are in template units (cm) times `shape_scale`."""

    dS0: torch.Tensor
    dS: torch.Tensor
    dR0: torch.Tensor
    dR: torch.Tensor


# ModelNet's input sizes and the encoder's grid at each (its decoders are built for these).
MODEL_NET_SIZES = {224: 7, 128: 4}


class ModelNet(nn.Module):
    """Personal corrections from N images of one person (feature averaging makes N free)."""

    def __init__(self, input_size: int = 128, width: float = 1.0, shape_scale: float = 1.0, albedo_scale: float = 1.0):
        super().__init__()
        self.encoder = ModelEncoder(width)
        feature_size = MODEL_NET_SIZES.get(input_size)
        if feature_size is None:
            raise ValueError(f"input_size must be 224 or 128, got {input_size}")
        self.shape_decoder = CorrectionDecoder(self.encoder.out_channels, feature_size, width)
        self.albedo_decoder = CorrectionDecoder(self.encoder.out_channels, feature_size, width)
        self.shape_scale = shape_scale
        self.albedo_scale = albedo_scale
        self.input_size = input_size

    def forward(self, images: torch.Tensor) -> Corrections:
        """images: [P, N, 3, H, W] (P people, N images each) or [N, 3, H, W] (one person)."""
        if images.dim() == 4:
            images = images.unsqueeze(0)
        p, n = images.shape[:2]
        features = self.encoder(images.flatten(0, 1))
        # The person's common feature: the mean over their N images (paper, section 3.2).
        feature = features.view(p, n, *features.shape[1:]).mean(dim=1)
        dS0, dS = self.shape_decoder(feature)
        dR0, dR = self.albedo_decoder(feature)
        return Corrections(dS0 * self.shape_scale, dS * self.shape_scale, dR0 * self.albedo_scale, dR * self.albedo_scale)


class BasicBlock(nn.Module):
    def __init__(self, cin: int, cout: int, stride: int):
        super().__init__()
        self.conv1 = nn.Conv2d(cin, cout, 3, stride, 1, bias=False)
        self.bn1 = nn.BatchNorm2d(cout)
        self.conv2 = nn.Conv2d(cout, cout, 3, 1, 1, bias=False)
        self.bn2 = nn.BatchNorm2d(cout)
        self.relu = nn.ReLU(inplace=True)
        self.down = None
        if stride != 1 or cin != cout:
            self.down = nn.Sequential(nn.Conv2d(cin, cout, 1, stride, bias=False), nn.BatchNorm2d(cout))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        identity = x if self.down is None else self.down(x)
        out = self.relu(self.bn1(self.conv1(x)))
        out = self.bn2(self.conv2(out))
        return self.relu(out + identity)


TRACK_POOLS = ("avg", "flatten")
# Where TrackNet's expression weights come from: "shared", the one fully connected layer all
# outputs share (as first built: the trunk then learnt pose features only, and w came out as
# each channel's average); "own", a two-layer head of their own on the trunk's features.
TRACK_W_HEADS = ("shared", "own")


class ResNet18Encoder(nn.Module):
    """ResNet-18 (He et al.) with a width multiplier; torchvision's is fixed at full width.

    `pool="avg"` ends with ResNet's global average pool (the classification head's). Global
    pooling discards where things are, which pose and translation regression need, so
    `pool="flatten"` keeps the final (input/32)^2 grid and flattens it into the features."""

    def __init__(self, width: float = 1.0, pool: str = "avg", input_size: int = 128):
        super().__init__()
        if pool not in TRACK_POOLS:
            raise ValueError(f"pool must be one of {TRACK_POOLS}, got {pool!r}")
        if input_size % 32 != 0:
            raise ValueError(f"ResNet-18's input size must be a multiple of 32, got {input_size}")
        c = [_ch(x, width) for x in (64, 128, 256, 512)]
        self.stem = nn.Sequential(
            nn.Conv2d(3, c[0], 7, 2, 3, bias=False), nn.BatchNorm2d(c[0]), nn.ReLU(inplace=True), nn.MaxPool2d(3, 2, 1)
        )
        layers = []
        cin = c[0]
        for i, cout in enumerate(c):
            stride = 1 if i == 0 else 2
            layers += [BasicBlock(cin, cout, stride), BasicBlock(cout, cout, 1)]
            cin = cout
        self.layers = nn.Sequential(*layers)
        self.pool = nn.AdaptiveAvgPool2d(1) if pool == "avg" else nn.Identity()
        self.out_features = cin if pool == "avg" else cin * (input_size // 32) ** 2

    def forward(self, images: torch.Tensor) -> torch.Tensor:
        return self.pool(self.layers(self.stem(images))).flatten(1)


@dataclass
class TrackParams:
    """Per-image tracking parameters p_n = (w, R, t, gamma)."""

    w: torch.Tensor  # [B, 53] in [0, 1]
    euler: torch.Tensor  # [B, 3] (yaw, pitch, roll) radians
    translation: torch.Tensor  # [B, 3] cm, camera space
    gamma: torch.Tensor  # [B, 27]
    # The logits z of w = sigmoid(z), for losses that need them (cross-entropy); None where
    # w does not come from TrackNet.
    w_logits: torch.Tensor | None = None


class TrackNet(nn.Module):
    """ResNet-18 + fully connected layers -> w (sigmoid), Euler angles, translation, gamma.

    The raw outputs are offsets from a prior (mean translation, mean lighting) so that an
    untrained network starts at a face in front of the camera under ambient light.
    """

    def __init__(
        self,
        width: float = 1.0,
        hidden: int = 512,
        translation_prior: tuple[float, float, float] = (0.0, 0.0, -60.0),
        gamma_prior: torch.Tensor | None = None,
        rotation_scale: float = 1.0,
        translation_scale: float = 10.0,
        w_gain: float = 1.0,
        w_grad_scale: float = 1.0,
        pool: str = "avg",
        input_size: int = 128,
        w_head: str = "shared",
        w_hidden: int = 256,
        context: bool = False,
        context_hidden: int = 256,
    ):
        super().__init__()
        if w_head not in TRACK_W_HEADS:
            raise ValueError(f"w_head must be one of {TRACK_W_HEADS}, got {w_head!r}")
        self.w_grad_scale = w_grad_scale
        self.encoder = ResNet18Encoder(width, pool=pool, input_size=input_size)
        self.fc = nn.Sequential(nn.Linear(self.encoder.out_features, hidden), nn.ReLU(inplace=True))
        self.head = nn.Linear(hidden, NUM_BLENDSHAPES + 3 + 3 + 27)
        nn.init.zeros_(self.head.weight)
        nn.init.zeros_(self.head.bias)
        # The w logits of the "own" head replace the shared head's first 53 outputs.
        self.w_head = None
        if w_head == "own":
            self.w_head = nn.Sequential(
                nn.Linear(self.encoder.out_features, w_hidden), nn.ReLU(inplace=True), nn.Linear(w_hidden, NUM_BLENDSHAPES)
            )
            # Small, not zero: a zero last layer would block w's gradient to the trunk until
            # it had moved, and the outputs start near the bias anyway.
            with torch.no_grad():
                self.w_head[2].weight.mul_(0.1)
        # Not in the paper: the person's context for the w head (`context=True`, issue 31).
        # One image cannot tell a person's wide eyes from eyeWide or their lips from
        # mouthLowerDown (error_sources.py: the identity costs ~0.005 of the w MAE); the w
        # head also reads the mean trunk features of the person's other frames, through a
        # small MLP added to the frame's own features. Its last layer starts at zero, so a
        # context TrackNet starts as the TrackNet it was initialised from.
        self.context_net = None
        if context:
            if w_head != "own":
                raise ValueError("a context TrackNet needs w_head='own' (the context feeds the w head only)")
            features = self.encoder.out_features
            self.context_net = nn.Sequential(nn.Linear(features, context_hidden), nn.ReLU(inplace=True), nn.Linear(context_hidden, features))
            nn.init.zeros_(self.context_net[2].weight)
            nn.init.zeros_(self.context_net[2].bias)
        # w = sigmoid(x) starts at 0.5 with zero logits; start near 0 instead (sparse prior).
        # Output scales: euler = rotation_scale * raw (radians), translation = prior +
        # translation_scale * raw (cm), w = sigmoid(w_gain * raw). They set how strongly each
        # output's gradient reaches the shared trunk (train.TrainConfig says why they matter).
        self.rotation_scale = rotation_scale
        self.translation_scale = translation_scale
        self.w_gain = w_gain
        with torch.no_grad():
            self.head.bias[:NUM_BLENDSHAPES] = -4.0 / w_gain
            if self.w_head is not None:
                self.w_head[2].bias.fill_(-4.0 / w_gain)
        self.register_buffer("translation_prior", torch.tensor(translation_prior, dtype=torch.float32))
        if gamma_prior is None:
            gamma_prior = torch.zeros(27)
        self.register_buffer("gamma_prior", gamma_prior.float().clone())

    def forward(self, images: torch.Tensor, context: torch.Tensor | None = None) -> TrackParams:
        return self.heads(self.encoder(images), context)

    def forward_people(self, images: torch.Tensor, people: int, frames: int) -> TrackParams:
        """The outputs for P people x N frames (person-major), each frame's context the
        others of its person (`leave_one_out_context`); a TrackNet without a context
        branch just runs each image."""
        features = self.encoder(images)
        context = leave_one_out_context(features, people, frames) if self.context_net is not None else None
        return self.heads(features, context)

    def heads(self, features: torch.Tensor, context: torch.Tensor | None = None) -> TrackParams:
        """The outputs from the trunk's features [B, F] (`encoder(images)`) and, for a context
        TrackNet, the person's context features [B, F]; training measures each output's
        gradient at the features through this split."""
        if self.context_net is not None and context is None:
            raise ValueError("this TrackNet reads the person's context: run forward_people, or pass context features")
        hidden = self.fc(features)
        raw = self.head(hidden)
        if self.w_head is not None:
            w_features = features if self.context_net is None else features + self.context_net(context)
            raw = torch.cat([self.w_head(w_features), raw[:, NUM_BLENDSHAPES:]], dim=1)
        elif self.training and self.w_grad_scale != 1.0:
            # Same values; the gradient that w sends into the shared trunk is scaled (see
            # train.TrainConfig.track_w_grad_scale). Only training sees it, so exports do not.
            scaled = hidden.detach() + self.w_grad_scale * (hidden - hidden.detach())
            w_raw = nn.functional.linear(scaled, self.head.weight[:NUM_BLENDSHAPES], self.head.bias[:NUM_BLENDSHAPES])
            raw = torch.cat([w_raw, raw[:, NUM_BLENDSHAPES:]], dim=1)
        logits = self.w_gain * raw[:, :NUM_BLENDSHAPES]
        euler = self.rotation_scale * raw[:, NUM_BLENDSHAPES : NUM_BLENDSHAPES + 3]
        translation = self.translation_prior + self.translation_scale * raw[:, NUM_BLENDSHAPES + 3 : NUM_BLENDSHAPES + 6]
        gamma = self.gamma_prior + raw[:, NUM_BLENDSHAPES + 6 :]
        return TrackParams(torch.sigmoid(logits), euler, translation, gamma, w_logits=logits)


def leave_one_out_context(features: torch.Tensor, people: int, frames: int) -> torch.Tensor:
    """Each frame's context: the mean trunk features [B, F] of its person's other frames
    (B = people x frames, person-major). Leave-one-out, because at inference the context
    comes from a few chosen frames of the person, mostly not the frame tracked."""
    if frames < 2:
        raise ValueError(f"a person's context needs at least 2 frames per person, got {frames}")
    if features.shape[0] != people * frames:
        raise ValueError(f"{features.shape[0]} feature rows are not {people} people x {frames} frames")
    f = features.view(people, frames, -1)
    others = (f.sum(1, keepdim=True) - f) / (frames - 1)
    return others.reshape(features.shape)


# Where the pieces of a w calibration start (`WCalibration`): denser near 0, where the
# zero-inflated truth puts most frames and where the dead zone that makes zeros exact lies.
CALIBRATION_KNOTS = (0.0, 0.02, 0.05, 0.1, 0.15, 0.2, 0.3, 0.4, 0.5, 0.6, 0.7, 0.8, 0.9)


class WCalibration(nn.Module):
    """A per-channel monotone piecewise-linear map of TrackNet's w, g_i(w) =
    clamp(sum_k c_ik relu(w - t_k), 0, 1) with knots t_k (`CALIBRATION_KNOTS`, t_0 = 0, so
    g_i(0) = 0) and non-decreasing partial sums of c_i (`calibrate.py` fits them).

    Not in the paper, which reports no per-channel error. TrackNet's w term aims at each
    channel's conditional mean (the cross-entropy); the metric, MAE, is minimised by the
    conditional median, which is exactly 0 for a channel less likely on than off. g_i maps
    one into the other, fitted on people TrackNet never trained on; it is monotone, so it
    keeps the order of the frames (what correlation measures) up to ties in the dead zone.
    The identity map (c_i0 = 1, the rest 0) changes nothing."""

    def __init__(self, coefficients: torch.Tensor | None = None):
        super().__init__()
        knots = torch.tensor(CALIBRATION_KNOTS)
        if coefficients is None:
            coefficients = torch.zeros(NUM_BLENDSHAPES, len(knots))
            coefficients[:, 0] = 1.0
        if coefficients.shape != (NUM_BLENDSHAPES, len(knots)):
            raise ValueError(f"w calibration coefficients must be [{NUM_BLENDSHAPES}, {len(knots)}], got {list(coefficients.shape)}")
        if not torch.isfinite(coefficients).all():
            raise ValueError("w calibration coefficients must be finite")
        if (coefficients.cumsum(dim=1) < -1e-6).any():
            raise ValueError("w calibration must be monotone: every partial sum of a channel's coefficients >= 0")
        self.register_buffer("knots", knots)
        self.register_buffer("coefficients", coefficients.float().clone())

    def forward(self, w: torch.Tensor) -> torch.Tensor:
        return (torch.relu(w.unsqueeze(-1) - self.knots) * self.coefficients).sum(-1).clamp(0.0, 1.0)


class CalibratedTrackNet(nn.Module):
    """TrackNet with its w passed through a `WCalibration` (the exported and evaluated
    network of a calibrated checkpoint); pose and light unchanged."""

    def __init__(self, track: TrackNet, calibration: WCalibration):
        super().__init__()
        self.track = track
        self.calibration = calibration

    def forward(self, images: torch.Tensor) -> TrackParams:
        params = self.track(images)
        return dataclasses.replace(params, w=self.calibration(params.w), w_logits=None)


def calibration_summary(checkpoint: dict) -> dict | None:
    """A calibrated checkpoint's `w_calibration` (calibrate.py) without its coefficients, for
    results and manifests; None for TrackNet's raw w."""
    c = checkpoint.get("w_calibration")
    return None if c is None else {k: v for k, v in c.items() if k != "coefficients"}



def parameter_count(module: nn.Module) -> int:
    return sum(p.numel() for p in module.parameters())


class ExportedModelNet:
    """An exported `model_net.onnx` run by ONNX Runtime behind ModelNet's interface
    ([P, N, 3, H, W] -> Corrections), with the R_0^t exported beside it.

    Why: a landmark warm-up trains TrackNet alone, so its checkpoint's ModelNet and R_0^t
    are untrained; shipping its TrackNet keeps the shipped ModelNet, whose training
    checkpoint may be gone (only its export is in git). Evaluating that pair needs this."""

    def __init__(self, models_dir):
        import json
        from pathlib import Path

        import onnxruntime as ort
        from safetensors.torch import load_file

        models_dir = Path(models_dir)
        onnx_path, albedo_path = models_dir / "model_net.onnx", models_dir / "mean_albedo.safetensors"
        for path in (onnx_path, albedo_path):
            if not path.is_file():
                raise FileNotFoundError(f"{path}: no such file (--model-net-from wants an exported models directory)")
        options = ort.SessionOptions()
        options.intra_op_num_threads = max(1, torch.get_num_threads())
        try:
            self.session = ort.InferenceSession(str(onnx_path), options, providers=["CPUExecutionProvider"])
            tensors = load_file(str(albedo_path))
        except Exception as e:  # ONNX Runtime and safetensors raise their own types
            raise ValueError(f"{models_dir}: cannot load the exported ModelNet ({e})") from e
        if "mean_albedo_face" not in tensors:
            raise ValueError(f"{albedo_path}: no mean_albedo_face tensor")
        # The exporter's manifest says which crops this ModelNet reads (`input_size`; a
        # TrackNet beside it may read another size, `track_input_size`); callers resize
        # their crops to it, since ONNX Runtime would only fail person by person.
        manifest = models_dir / "manifest.json"
        self.input_size = 128
        if manifest.is_file():
            try:
                self.input_size = int(json.loads(manifest.read_text()).get("input_size", 128))
            except (json.JSONDecodeError, TypeError, ValueError) as e:
                raise ValueError(f"{manifest}: not a manifest with an integer input_size ({e})") from e
        if self.input_size not in MODEL_NET_SIZES:
            raise ValueError(f"{models_dir}: its ModelNet reads {self.input_size} px images; ModelNet reads {' or '.join(map(str, MODEL_NET_SIZES))} px")
        self.mean_albedo = tensors["mean_albedo_face"].float()
        self.directory = models_dir

    def eval(self):
        return self

    def __call__(self, images: torch.Tensor) -> Corrections:
        outputs = [self.session.run(None, {"images": person.numpy()}) for person in images.float()]
        return Corrections(*(torch.cat([torch.from_numpy(o[i]) for o in outputs]) for i in range(4)))


@dataclass
class TrainedNetworks:
    """The networks of a training checkpoint (`train.Trainer.save`), in eval mode."""

    config: dict
    track: TrackNet | CalibratedTrackNet
    model: ModelNet | ExportedModelNet
    mean_albedo: torch.Tensor | None  # R_0^t [3, 512, 512]
    checkpoint: dict


def build_track_net(cfg: dict) -> TrackNet:
    """An untrained TrackNet built as a checkpoint's config says (its weights are loaded
    after; the priors are buffers, so they come with them)."""
    return TrackNet(
        width=cfg["track_width"],
        rotation_scale=cfg.get("track_rotation_scale", 1.0),
        translation_scale=cfg.get("track_translation_scale", 10.0),
        w_gain=cfg.get("track_w_gain", 1.0),
        pool=cfg.get("track_pool", "avg"),
        input_size=cfg["input_size"],
        w_head=cfg.get("track_w_head", "shared"),
        w_hidden=cfg.get("track_w_hidden", 256),
        context=cfg.get("track_context", False),
    )


def load_networks(path, model_net_from=None) -> TrainedNetworks:
    """Rebuilds TrackNet and ModelNet from a checkpoint's config and weights (shared by the
    export and the evaluation; the priors are buffers, so they come with the weights).
    `model_net_from`: an exported models directory whose ModelNet and R_0^t replace the
    checkpoint's (`ExportedModelNet`)."""
    ckpt = torch.load(path, map_location="cpu", weights_only=False)
    cfg = ckpt["config"]
    track = build_track_net(cfg)
    # A TrackNet of another input size (160 px) trained in the warm-up alone sits beside an
    # untrained 128 px ModelNet (train.Trainer).
    model_size = cfg["input_size"] if cfg["input_size"] in MODEL_NET_SIZES else 128
    model = ModelNet(input_size=model_size, width=cfg["model_width"])
    track.load_state_dict(ckpt["track_net"])
    # A kept warm-up checkpoint (keep.py) has no ModelNet: it was never trained, and a
    # fresh one is what the warm-up had.
    if "model_net" in ckpt:
        model.load_state_dict(ckpt["model_net"])
    if ckpt.get("w_calibration") is not None:
        track = CalibratedTrackNet(track, WCalibration(ckpt["w_calibration"]["coefficients"]))
    if model_net_from is not None:
        exported = ExportedModelNet(model_net_from)
        return TrainedNetworks(cfg, track.eval(), exported, exported.mean_albedo, ckpt)
    return TrainedNetworks(cfg, track.eval(), model.eval(), ckpt.get("mean_albedo"), ckpt)
