"""The weights of the estimator's loss terms (:mod:`.losses`), importable without torch: ``rvr train
--help`` shows their defaults."""
from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class LossWeights:
    """Weights of the loss terms (paper: w1 = 10; the feature weights are ours, see module doc)."""

    pix: float = 1.0
    ssim: float = 0.5
    grad: float = 1.0
    vgg: float = 1.0
    smooth: float = 10.0
    supervised: float = 1.0
    """w_sup: weight of the supervised ground-truth terms (ours; 0 = the paper's loss)."""
    sup_disparity: float = 1.0
    sup_disparity_grad: float = 0.5
    sup_exponent: float = 1.0
    sup_exponent_zero: float = 0.1
    disparity_invariant: bool = False
    """Scale-and-shift-invariant L_D (only the shape of D is supervised)."""
