"""A frame's depth carried into another frame along the optical flow: the piece the fuser's carry
(:mod:`.fuse`, into the next frame) and the refinement (:mod:`.refine`, both ways) share."""
from __future__ import annotations

import numpy as np


def flow_maps_into(dis, gray: np.ndarray, other: np.ndarray, size: tuple[int, int]) -> np.ndarray:
    """(h, w, 2) float32 maps at ``size`` = (w, h): where each pixel of ``gray`` lies in ``other``
    (absolute px). dis: an OpenCV DIS object; gray, other: uint8 luma at the flow size."""
    from ..temporal.flow import dis_calc, flow_maps, upsample_flow

    return flow_maps(upsample_flow(dis_calc(dis, gray, other), size))


def carry_along(maps: np.ndarray, d: np.ndarray, c: np.ndarray, luma: np.ndarray, own_luma: np.ndarray,
                photo: float, weight: float) -> tuple[np.ndarray, np.ndarray]:
    """Another frame's (d, c, luma) sampled at this frame's pixels through ``maps``
    (:func:`flow_maps_into`); returns (d, weight): the carried value and its weight, ``weight`` x
    exp(-|luma difference| / ``photo``) x its confidence c (0 outside the other frame). d: any
    per-pixel value (q or D); luma in 8-bit code values, float32."""
    import cv2

    q, c_in, then = cv2.split(cv2.remap(np.dstack([d, c, luma]), maps, None, cv2.INTER_LINEAR,
                                        borderMode=cv2.BORDER_CONSTANT, borderValue=0))
    photo_w = np.exp(np.abs(then - own_luma) * np.float32(-1.0 / photo))
    return q, np.float32(weight) * photo_w * c_in
