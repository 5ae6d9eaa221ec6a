"""AF-Net's hyper-parameters (:class:`AFNetConfig`), importable without torch or NumPy: ``rvr
train-afnet --help`` shows their defaults. The network itself is :mod:`.model`."""
from __future__ import annotations

from dataclasses import asdict, dataclass, fields
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    import numpy as np

Frames = int


@dataclass(frozen=True)
class AFNetConfig:
    """Hyper-parameters of AF-Net (see :mod:`.model`'s docstring).

    width, height: network input size in px (multiples of 8). rgb: colour (3 channels) or
    gray (1). disparity: add the normalised disparity channel. f_t: sampled frames per
    temporal unit (odd). s: temporal units (odd). sample_step: clip frames between sampled
    frames. stride: clip frames between queries at inference. widths1: CNN-1 channels of its
    four blocks. widths2: CNN-2 channels (reduction, then three blocks). audio: audio numbers per
    clip frame (0: none, the paper's network; :data:`.audio_features.AUDIO_FEATURES` with sound).
    """

    width: int = 128
    height: int = 72
    rgb: bool = True
    disparity: bool = True
    f_t: int = 3
    s: int = 3
    sample_step: int = 5
    stride: int = 5
    widths1: tuple[int, ...] = (32, 48, 64, 96)
    widths2: tuple[int, ...] = (64, 64, 96, 128)
    audio: int = 0

    def check(self) -> "AFNetConfig":
        """Raise ValueError naming the bad hyper-parameter; returns self."""
        if self.width % 8 or self.height % 8 or self.width < 16 or self.height < 16:
            raise ValueError(f"AF-Net input {self.width}x{self.height}: width and height must be multiples of 8, >= 16")
        if self.f_t < 1 or self.f_t % 2 == 0 or self.s < 1 or self.s % 2 == 0:
            raise ValueError(f"AF-Net f_t={self.f_t}, s={self.s}: both must be odd and >= 1 (a centre frame)")
        if self.sample_step < 1 or self.stride < 1:
            raise ValueError(f"AF-Net sample_step={self.sample_step}, stride={self.stride}: must be >= 1")
        if self.audio < 0:
            raise ValueError(f"AF-Net audio={self.audio}: must be >= 0 (0: no audio input)")
        if len(self.widths1) != 4 or len(self.widths2) != 4 or min(self.widths1 + self.widths2) < 1:
            raise ValueError("AF-Net widths1 and widths2 need 4 positive channel counts each")
        return self

    @property
    def channels(self) -> int:
        """Input channels of one sampled frame."""
        return (3 if self.rgb else 1) + (1 if self.disparity else 0)

    @property
    def frames_seen(self) -> int:
        """L = s * f_T sampled frames seen by one query."""
        return self.s * self.f_t

    @property
    def offsets(self) -> np.ndarray:
        """(L,) clip-frame offsets of the sampled frames of a query, relative to the query."""
        import numpy as np

        half = (self.frames_seen - 1) // 2
        return (np.arange(self.frames_seen) - half) * self.sample_step

    @property
    def unit_offsets(self) -> np.ndarray:
        """(s,) clip-frame offsets of the unit centres relative to the query."""
        import numpy as np

        return (np.arange(self.s) - (self.s - 1) // 2) * self.f_t * self.sample_step

    @property
    def span(self) -> Frames:
        """Temporal receptive field of a query in clip frames: (L - 1) * sample_step + 1."""
        return (self.frames_seen - 1) * self.sample_step + 1

    @property
    def half_span(self) -> Frames:
        """Clip frames a query looks ahead (and back)."""
        return (self.span - 1) // 2

    @property
    def map_size(self) -> tuple[int, int]:
        """(w, h) of the focus-region map: 1/4 of the input."""
        return self.width // 4, self.height // 4

    def to_dict(self) -> dict:
        """JSON-ready dict (tuples become lists)."""
        d = asdict(self)
        d["widths1"], d["widths2"] = list(self.widths1), list(self.widths2)
        return d

    @classmethod
    def from_dict(cls, data: dict) -> "AFNetConfig":
        """Inverse of :meth:`to_dict`; unknown keys are a ValueError (another architecture)."""
        known = {f.name for f in fields(cls)}
        extra = set(data) - known
        if extra:
            raise ValueError(f"unknown AF-Net hyper-parameters {sorted(extra)}")
        d = dict(data)
        for key in ("widths1", "widths2"):
            if key in d:
                d[key] = tuple(int(v) for v in d[key])
        return cls(**d).check()
