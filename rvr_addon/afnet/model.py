"""AF-Net (paper section 5.3, Fig. 8): focus-region maps and the New Focus Target probability.

Time. The clip is sampled every ``sample_step`` frames (paper: 5). A query at clip frame ``q``
sees ``L = s * f_T`` sampled frames at ``q + j * sample_step``, ``j = -(L-1)/2 .. (L-1)/2``
(frames outside the clip repeat the first/last frame: padding). They form ``s`` temporal
units of ``f_T`` consecutive sampled frames; unit ``u`` is centred on clip frame
``q + (u - (s-1)/2) * f_T * sample_step``.

- **CNN-1** (ResNet-10-like: a stem and four basic blocks) sees one unit (temporal receptive
  field ``f_T`` sampled frames, stacked as channels: early fusion) and predicts the
  focus-region map ``M`` of the unit's centre frame (logits at 1/4 of the input size; a
  spatial softmax makes it a distribution) and a feature map at 1/8.
- **CNN-2** (ResNet-10-like, then global average pooling and a linear layer) takes the ``s``
  feature maps of CNN-1 and predicts the logit of ``P``, the probability that the centre
  frame ``q`` is a New Focus Target; it sees ``s * f_T`` sampled frames.

At inference, queries are taken every ``stride`` clip frames (paper: 5) and CNN-1's output of
a unit is cached by its centre frame, so each new query costs one CNN-1 pass and one CNN-2
pass (:mod:`.infer`).

Input per sampled frame (``input_channels``): RGB (or gray) in [-0.5, 0.5] at
``width x height`` px (default 128x72; multiples of 8) and, with ``disparity``, one channel
of the frame's disparity normalised per frame (:func:`normalise_disparity`: median removed,
divided by the 10-90 % spread, clipped to +-3), so the offset and scale of an estimated
disparity do not matter.

Audio (beyond the paper; ``audio`` > 0, :mod:`.audio_features`): ``audio`` numbers per clip
frame. CNN-1 gets those of its unit's sampled frames as constant input planes (it can tell a
moving mouth while a voice sounds from one in silence); CNN-2 gets those of every clip frame
of the query's span (``span`` columns: speech onsets are sharper than the sampling step)
through a small 1-D convolution, joined to its pooled features before the linear layer. A
network with ``audio = 0`` is the paper's and has the same weights as before audio existed.
"""
from __future__ import annotations

from dataclasses import replace

import numpy as np
import torch
import torch.nn.functional as F
from torch import nn

from .config import AFNetConfig, Frames  # noqa: F401 - re-exported: rvr_addon.afnet.model.AFNetConfig
from .encoding import DISPARITY_CODE_SCALE, encode_frame, normalise_disparity  # noqa: F401 - re-exported


def decode_frames(codes: np.ndarray | torch.Tensor, config: AFNetConfig) -> torch.Tensor:
    """Bytes of :func:`encode_frame`, shape (..., C, H, W), -> float32 network input: image in
    [-0.5, 0.5], disparity channel in [-3, 3]."""
    x = torch.as_tensor(codes).to(torch.float32)
    n_img = 3 if config.rgb else 1
    img = x[..., :n_img, :, :] / 255.0 - 0.5
    if not config.disparity:
        return img
    return torch.cat([img, (x[..., n_img:, :, :] - 128.0) / DISPARITY_CODE_SCALE], dim=-3)


class BasicBlock(nn.Module):
    """ResNet basic block: two 3x3 conv + BN, ReLU, identity or 1x1 projection shortcut."""

    def __init__(self, cin: int, cout: int, stride: int = 1) -> None:
        super().__init__()
        self.conv1 = nn.Conv2d(cin, cout, 3, stride, 1, bias=False)
        self.bn1 = nn.BatchNorm2d(cout)
        self.conv2 = nn.Conv2d(cout, cout, 3, 1, 1, bias=False)
        self.bn2 = nn.BatchNorm2d(cout)
        self.short = None
        if stride != 1 or cin != cout:
            self.short = nn.Sequential(nn.Conv2d(cin, cout, 1, stride, bias=False), nn.BatchNorm2d(cout))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        y = F.relu(self.bn1(self.conv1(x)))
        y = self.bn2(self.conv2(y))
        return F.relu(y + (x if self.short is None else self.short(x)))


class CNN1(nn.Module):
    """One temporal unit (f_T frames as channels) -> (features at 1/8, map logits at 1/4).

    Stem 3x3 stride 2 (1/2), blocks widths1[0] (1/2), [1] stride 2 (1/4), [2] stride 2 (1/8),
    [3] (1/8): ResNet-10-like. The map head adds the 1/8 features, upsampled, to the 1/4 ones.
    """

    def __init__(self, config: AFNetConfig) -> None:
        super().__init__()
        w = config.widths1
        self.stem = nn.Sequential(nn.Conv2d(config.f_t * (config.channels + config.audio), w[0], 3, 2, 1, bias=False),
                                  nn.BatchNorm2d(w[0]), nn.ReLU(inplace=True))
        self.b1 = BasicBlock(w[0], w[0])
        self.b2 = BasicBlock(w[0], w[1], 2)
        self.b3 = BasicBlock(w[1], w[2], 2)
        self.b4 = BasicBlock(w[2], w[3])
        self.lateral = nn.Conv2d(w[3], w[1], 1)
        self.map_head = nn.Sequential(nn.Conv2d(w[1], w[1], 3, 1, 1), nn.ReLU(inplace=True), nn.Conv2d(w[1], 1, 1))

    def forward(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """x: (N, f_T * C, H, W). Returns (features (N, widths1[3], H/8, W/8), map (N, 1, H/4, W/4))."""
        quarter = self.b2(self.b1(self.stem(x)))
        feat = self.b4(self.b3(quarter))
        up = F.interpolate(self.lateral(feat), size=quarter.shape[-2:], mode="bilinear", align_corners=False)
        return feat, self.map_head(F.relu(quarter + up))


class CNN2(nn.Module):
    """s unit feature maps -> NFT logit: 1x1 reduction, three basic blocks (two with stride 2),
    global average pooling, linear (ResNet-10-like). With audio, a 1-D convolution over the
    span's audio columns adds AUDIO_WIDTH numbers before the linear layer."""

    AUDIO_WIDTH = 32

    def __init__(self, config: AFNetConfig) -> None:
        super().__init__()
        w = config.widths2
        self.reduce = nn.Sequential(nn.Conv2d(config.s * config.widths1[3], w[0], 1, bias=False),
                                    nn.BatchNorm2d(w[0]), nn.ReLU(inplace=True))
        self.b1 = BasicBlock(w[0], w[1])
        self.b2 = BasicBlock(w[1], w[2], 2)
        self.b3 = BasicBlock(w[2], w[3], 2)
        self.audio = None
        self.span = config.span
        extra = 0
        if config.audio:
            a = self.AUDIO_WIDTH
            steps = ((config.span + 1) // 2 + 1) // 2  # two stride-2 convolutions
            self.audio = nn.Sequential(nn.Conv1d(config.audio, a, 5, 1, 2), nn.ReLU(inplace=True),
                                       nn.Conv1d(a, a, 5, 2, 2), nn.ReLU(inplace=True),
                                       nn.Conv1d(a, a, 5, 2, 2), nn.ReLU(inplace=True),
                                       nn.Flatten(), nn.Linear(a * steps, a), nn.ReLU(inplace=True))
            extra = a
        self.fc = nn.Linear(w[3] + extra, 1)

    def forward(self, feats: torch.Tensor, audio: torch.Tensor | None = None) -> torch.Tensor:
        """feats: (B, s * widths1[3], H/8, W/8); audio: (B, audio, span) or None (with an audio
        branch: silence). Returns (B,) logits."""
        y = self.b3(self.b2(self.b1(self.reduce(feats)))).mean(dim=(2, 3))
        if self.audio is not None:
            if audio is None:
                audio = feats.new_zeros(feats.shape[0], self.audio[0].in_channels, self.span)
            y = torch.cat([y, self.audio(audio.to(y))], dim=1)
        return self.fc(y)[:, 0]


class AFNet(nn.Module):
    """CNN-1 on each of the s temporal units, CNN-2 on their features (module docstring)."""

    def __init__(self, config: AFNetConfig | None = None) -> None:
        super().__init__()
        self.config = (config or AFNetConfig()).check()
        self.cnn1 = CNN1(self.config)
        self.cnn2 = CNN2(self.config)

    def parameter_count(self) -> int:
        """Number of trainable parameters."""
        return sum(p.numel() for p in self.parameters())

    def unit(self, x: torch.Tensor, audio: torch.Tensor | None = None) -> tuple[torch.Tensor, torch.Tensor]:
        """CNN-1 on units: x (N, f_T, C, H, W), audio (N, f_T, audio) of the unit's frames (None:
        silence; ignored without ``config.audio``) -> (features, map logits (N, H/4, W/4))."""
        n, f, c, h, w = x.shape
        x = x.reshape(n, f * c, h, w)
        if self.config.audio:
            a = self.config.audio
            planes = x.new_zeros(n, f * a, 1, 1) if audio is None else audio.reshape(n, f * a, 1, 1).to(x)
            x = torch.cat([x, planes.expand(n, f * a, h, w)], dim=1)
        feat, m = self.cnn1(x)
        return feat, m[:, 0]

    def head(self, feats: torch.Tensor, audio: torch.Tensor | None = None) -> torch.Tensor:
        """CNN-2: feats (B, s, C1, h, w), audio (B, audio, span) or None -> NFT logits (B,)."""
        b, s, c, h, w = feats.shape
        return self.cnn2(feats.reshape(b, s * c, h, w), audio)

    def forward(self, x: torch.Tensor, audio: torch.Tensor | None = None) -> tuple[torch.Tensor, torch.Tensor]:
        """x: (B, L, C, H, W), L = s * f_T sampled frames in time order; audio: (B, audio, span),
        the audio numbers of every clip frame of the query's span (None: silence; ignored
        without ``config.audio``).

        Returns (NFT logits (B,) of the centre frame, map logits (B, s, H/4, W/4) of the unit
        centres)."""
        cfg = self.config
        b, length, c, h, w = x.shape
        if length != cfg.frames_seen or c != cfg.channels or (w, h) != (cfg.width, cfg.height):
            raise ValueError(f"AF-Net input {tuple(x.shape)}: expected (B, {cfg.frames_seen}, {cfg.channels}, "
                             f"{cfg.height}, {cfg.width})")
        units = x.reshape(b * cfg.s, cfg.f_t, c, h, w)
        unit_audio = None
        if cfg.audio and audio is not None:
            if tuple(audio.shape) != (b, cfg.audio, cfg.span):
                raise ValueError(f"AF-Net audio {tuple(audio.shape)}: expected ({b}, {cfg.audio}, {cfg.span})")
            unit_audio = unit_audio_of(audio, cfg)
        feat, maps = self.unit(units, unit_audio)
        logits = self.head(feat.reshape(b, cfg.s, *feat.shape[1:]), audio if cfg.audio else None)
        return logits, maps.reshape(b, cfg.s, *maps.shape[1:])


def unit_audio_of(audio: torch.Tensor, config: AFNetConfig) -> torch.Tensor:
    """(B, audio, span) span columns -> (B * s, f_T, audio): the columns of each unit's sampled frames."""
    b = audio.shape[0]
    cols = torch.as_tensor(config.offsets + config.half_span)
    return audio[:, :, cols].permute(0, 2, 1).reshape(b * config.s, config.f_t, config.audio)


def map_to_prob(logits: torch.Tensor) -> torch.Tensor:
    """Spatial softmax of map logits (..., h, w) -> a distribution over the map cells."""
    shape = logits.shape
    return torch.softmax(logits.reshape(*shape[:-2], -1), dim=-1).reshape(shape)


def grow_state_dict(state: dict[str, torch.Tensor], old: AFNetConfig, new: AFNetConfig) -> dict[str, torch.Tensor]:
    """Weights of a network with config ``old`` mapped onto one with ``new``, which may differ
    only by the audio input switched on: CNN-1's stem and CNN-2's linear layer gain zero
    input columns, so the grown network predicts exactly what the old one did until training
    moves them; the audio branch keeps its fresh initialisation (missing from the result).
    Raises ValueError for any other difference."""
    if old == new:
        return dict(state)
    if old.audio or replace(old, audio=new.audio) != new:
        raise ValueError(f"cannot start an AF-Net with config {new.to_dict()} from weights with config "
                         f"{old.to_dict()}: only switching the audio input on is supported")
    grown = dict(state)
    stem = state["cnn1.stem.0.weight"]
    extra = new.f_t * new.audio
    grown["cnn1.stem.0.weight"] = torch.cat([stem, stem.new_zeros(stem.shape[0], extra, *stem.shape[2:])], dim=1)
    fc = state["cnn2.fc.weight"]
    grown["cnn2.fc.weight"] = torch.cat([fc, fc.new_zeros(fc.shape[0], CNN2.AUDIO_WIDTH)], dim=1)
    return grown
