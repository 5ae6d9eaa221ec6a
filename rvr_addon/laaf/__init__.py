"""Look-Ahead Autofocus (paper section 5): New Focus Targets, tracking, AI-assist detectors,
focus pulls. No bpy here.

Modules (one job each): ``nft`` (targets), ``tracking`` (KCF with loss reporting),
``focus_reading`` (robust disparity of a box), ``puller`` (pull schedule and profiles),
``keyframes`` (sparse linear keys for F-curves), ``detectors/`` (face, saliency, action,
speech), ``combine`` (the paper's intersection + K-means + discontinuities), ``lookahead``
(the streaming driver, look-ahead or causal), ``analysis`` (its per-frame part, measurable in
chunks by ``rvr batch``), ``focusfile`` (the JSON ``rvr render`` reads),
``evaluate`` (``rvr eval-focus``: paper section 6.2 metrics on harness clips).
"""
from __future__ import annotations

from ..lazy_exports import lazy_getattr

from .presets import PROFILES

__all__ = ["NFT", "load_nfts", "save_nfts", "validate_nfts", "Key", "keyframes", "evaluate_keys", "PROFILES",
           "PullSettings", "PullTarget", "compose_track", "pull_weight"]

_LAZY = {"Key": ".keyframes", "evaluate_keys": ".keyframes", "keyframes": ".keyframes", "NFT": ".nft",
         "load_nfts": ".nft", "save_nfts": ".nft", "validate_nfts": ".nft", "PullSettings": ".puller",
         "PullTarget": ".puller", "compose_track": ".puller", "pull_weight": ".puller"}
"""Exports imported on first use (NumPy and the engine load then; ``rvr --help`` needs none of them)."""

__getattr__ = lazy_getattr(__name__, _LAZY, globals())
