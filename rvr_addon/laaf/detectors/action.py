"""Action detector H_act: motion that is not camera motion.

The paper used optical flow with DeepMatching for action localisation. Here: dense DIS optical
flow (OpenCV) between consecutive frames at ``flow_width`` px, a homography fitted to a grid of
its vectors with RANSAC (the camera's pan/tilt/zoom and the far scene) and, since LAAF has the
disparity map, a plane + parallax refinement that also explains the parallax of a moving
(dollying, walking) camera (``residual``); the residual ``|flow - camera flow|`` is the
independent-motion magnitude, in px per frame at a 320 px analysis width. It is smoothed in space and kept with a short decay in time (a walker's
limbs pause between steps), then mapped to heat = 0.5 * residual / ``threshold_px``, clipped
to [0, 1] (moving = heat >= 0.5). A dolly's parallax leaves a small residual on near objects;
``threshold_px`` sits above it.
"""
from __future__ import annotations

import time

import numpy as np

from ..timebase import reference_frames_per_frame
from .base import AnalysisFrame, DetectorOutput, FocusDetector


def solve_spd(lhs: np.ndarray, rhs: np.ndarray) -> np.ndarray:
    """Solve ``lhs x = rhs`` for small symmetric positive definite systems, batched:
    lhs (..., k, k), rhs (..., k, c) -> x (..., k, c). Gaussian elimination without pivoting
    (stable for SPD) in plain numpy ufuncs, no BLAS/LAPACK threads."""
    m = np.array(lhs, dtype=np.float64)
    b = np.array(rhs, dtype=np.float64)
    k = m.shape[-1]
    for i in range(k - 1):
        f = m[..., i + 1:, i] / m[..., i, i][..., None]  # (..., k-i-1)
        m[..., i + 1:, i:] -= f[..., :, None] * m[..., i:i + 1, i:]
        b[..., i + 1:, :] -= f[..., :, None] * b[..., i:i + 1, :]
    x = np.zeros_like(b)
    for i in range(k - 1, -1, -1):
        rest = np.einsum("...j,...jc->...c", m[..., i, i + 1:], x[..., i + 1:, :])
        x[..., i, :] = (b[..., i, :] - rest) / m[..., i, i][..., None]
    return x


class ActionDetector(FocusDetector):
    """H_act (module docstring). threshold_px: residual motion (px/frame at 320 px width and 25 fps;
    scaled with the analysis width and the frame rate: the same px a second) that counts as
    action. decay: per-frame decay of the residual memory at 25 fps (the same time constant at
    any rate, :mod:`..timebase`).
    border_frac: a band this wide (fraction of the width) along the frame border is ignored:
    dense flow there has no support on one side and leaves false motion."""

    name = "action"

    def __init__(self, flow_width: int = 160, threshold_px: float = 1.2, decay: float = 0.4,
                 ransac_px: float = 0.7, grid_step: int = 4, use_disparity: bool = True,
                 border_frac: float = 0.02) -> None:
        import cv2

        self.flow_width = flow_width
        self.threshold_px = threshold_px
        self.decay = decay
        self.ransac_px = ransac_px
        self.grid_step = grid_step
        self.use_disparity = use_disparity
        self.border_frac = border_frac
        self._dis = cv2.DISOpticalFlow_create(cv2.DISOPTICAL_FLOW_PRESET_FAST)
        self._dis.setFinestScale(1)  # the preset stops at 1/4 resolution: a walker's flow came out halved
        self._prev: AnalysisFrame | None = None  # the frame before (process only)
        self._acc: np.ndarray | None = None
        self._heat: dict[int, np.ndarray] = {}
        self._seconds = 0.0
        self._n = 0
        self._homography_failures = 0

    @staticmethod
    def _design(x: np.ndarray, y: np.ndarray, d: np.ndarray | None) -> np.ndarray:
        cols = [np.ones_like(x), x, y, x * x, x * y, y * y]
        if d is not None:
            cols += [d, d * x, d * y]
        return np.stack(cols, axis=-1)

    def _ransac_fit(self, A: np.ndarray, y: np.ndarray, iterations: int = 60, sample: int = 14) -> np.ndarray:
        """Coefficients (k, 2) of the camera-motion model by RANSAC (ridge-regularised parallax
        terms, so a region whose disparity is unique cannot explain its own motion)."""
        n, k = A.shape
        ridge = np.zeros(k)
        ridge[6:] = 1e-2 * n / max(sample, 1)
        rng = np.random.default_rng(0)

        def solve(idx: np.ndarray) -> np.ndarray:
            a = A[idx]
            scale = len(idx) / n
            lhs = np.einsum("sk,sl->kl", a, a) + np.diag(ridge * scale) + 1e-9 * np.eye(k)
            return solve_spd(lhs, np.einsum("sk,sc->kc", a, y[idx]))

        # all hypotheses at once: one batched solve and one product (a Python loop of small
        # solves cost ~30 ms a frame). einsum and solve_spd, not matmul and np.linalg.solve:
        # BLAS/LAPACK threads on matrices this small took 0.1 s a call on a loaded 2-core machine.
        idx = np.stack([rng.choice(n, size=min(sample, n), replace=False) for _ in range(iterations)])
        a = A[idx]  # (it, s, k)
        lhs = np.einsum("isk,isl->ikl", a, a) + np.diag(ridge * (idx.shape[1] / n)) + 1e-9 * np.eye(k)
        coefs = solve_spd(lhs, np.einsum("isk,isc->ikc", a, y[idx]))  # (it, k, 2)
        pred = np.einsum("nk,kj->nj", A, coefs.transpose(1, 0, 2).reshape(k, -1))
        pred = pred.reshape(n, iterations, 2).transpose(1, 0, 2)  # (it, n, 2)
        counts = (np.linalg.norm(pred - y[None], axis=2) < self.ransac_px).sum(axis=1)
        j = int(np.argmax(counts))
        best, best_count = np.linalg.norm(pred[j] - y, axis=1) < self.ransac_px, int(counts[j])
        if best_count < k:
            return solve(np.arange(n))
        c = solve(np.flatnonzero(best))
        inl = np.linalg.norm(np.einsum("nk,kc->nc", A, c) - y, axis=1) < self.ransac_px
        return solve(np.flatnonzero(inl)) if inl.sum() >= k else c

    def camera_flow(self, prev: np.ndarray, cur: np.ndarray,
                    disparity: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """(flow, camera flow) of :meth:`camera_motion`, counting homography failures."""
        flow, cam, failed = self.camera_motion(prev, cur, disparity)
        self._homography_failures += failed
        return flow, cam

    def camera_motion(self, prev: np.ndarray, cur: np.ndarray,
                      disparity: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray, bool]:
        """(flow, camera flow, failed), flows (h, w, 2) float32 px/frame of these grey frames: the
        dense DIS flow from ``prev`` to ``cur`` (``prev(x) ~ cur(x + flow(x))``) and the part of it
        the camera explains; failed: no homography could be fitted (the median flow was used).

        disparity: (h, w) map of the current frame (any affine unit of inverse depth), or None.
        Camera motion model: a homography fitted with RANSAC to a grid of the DIS flow; with a
        disparity map, a plane + parallax model instead, per flow component
        ``[1, x, y, x^2, xy, y^2, D, D x, D y]`` (rotation = the quadratic terms of a
        homography; translation = parallax linear in inverse depth, which D is affine in),
        fitted by RANSAC with ridge-regularised parallax terms. Without a usable model, the
        median flow (a pure pan).
        """
        import cv2

        from ...temporal.flow import dis_calc

        flow = dis_calc(self._dis, prev, cur)  # padded: DIS crashes the process on thin frames
        h, w = prev.shape
        s = self.grid_step
        ys, xs = np.mgrid[s // 2:h:s, s // 2:w:s]
        gy, gx = np.mgrid[0:h, 0:w].astype(np.float32)
        fl = flow[ys.ravel(), xs.ravel()]
        if disparity is not None and np.isfinite(disparity).all() and float(disparity.std()) > 1e-6:
            dn = (disparity - float(disparity.mean())) / float(disparity.std())
            nx, ny = (gx - w / 2) / (w / 2), (gy - h / 2) / (w / 2)
            A = self._design(nx[ys, xs].ravel(), ny[ys, xs].ravel(), dn[ys, xs].ravel())
            coef = self._ransac_fit(A, fl)
            return flow, np.einsum("hwk,kc->hwc", self._design(nx, ny, dn), coef).astype(np.float32), False
        src = np.stack([xs.ravel(), ys.ravel()], 1).astype(np.float32)
        H, _ = cv2.findHomography(src, src + fl, cv2.RANSAC, self.ransac_px, maxIters=500)
        if H is None:
            cam = np.median(flow.reshape(-1, 2), axis=0)
            return flow, np.broadcast_to(cam.astype(np.float32), flow.shape).copy(), True
        den = H[2, 0] * gx + H[2, 1] * gy + H[2, 2]
        px = (H[0, 0] * gx + H[0, 1] * gy + H[0, 2]) / den - gx
        py = (H[1, 0] * gx + H[1, 1] * gy + H[1, 2]) / den - gy
        return flow, np.stack([px, py], axis=-1).astype(np.float32), False

    def residual(self, prev: np.ndarray, cur: np.ndarray, disparity: np.ndarray | None = None) -> np.ndarray:
        """Independent-motion magnitude (h, w) float32, px/frame of these grey frames:
        ``|flow - camera flow|`` (``camera_flow``)."""
        flow, cam = self.camera_flow(prev, cur, disparity)
        return np.hypot(flow[..., 0] - cam[..., 0], flow[..., 1] - cam[..., 1]).astype(np.float32)

    measures = True

    def _small(self, gray: np.ndarray) -> np.ndarray:
        """A grey frame at the flow width (INTER_AREA)."""
        import cv2

        h, w = gray.shape
        fw = min(self.flow_width, w)
        return cv2.resize(gray, (fw, max(int(round(h * fw / w)), 8)), interpolation=cv2.INTER_AREA)

    def measure(self, frame: AnalysisFrame, prev: AnalysisFrame | None, faces: list) -> tuple[np.ndarray, bool] | None:
        """(independent-motion residual from ``prev`` to ``frame``, (fh, fw) float32 px/frame at a
        320 px width, border zeroed, smoothed; homography failed), None at the first frame."""
        import cv2

        small = self._small(frame.gray)
        if prev is None:
            return None
        before = self._small(prev.gray)
        if before.shape != small.shape:
            return None
        fh, fw = small.shape
        disp = None
        if frame.disparity is not None and self.use_disparity:
            disp = cv2.resize(frame.disparity, (fw, fh), interpolation=cv2.INTER_AREA)
        flow, cam, failed = self.camera_motion(before, small, disp)
        res = np.hypot(flow[..., 0] - cam[..., 0], flow[..., 1] - cam[..., 1]).astype(np.float32) * (320.0 / fw)
        b = max(2, int(round(self.border_frac * fw)))  # flow is unreliable at the frame border
        res[:b], res[-b:], res[:, :b], res[:, -b:] = 0, 0, 0, 0
        return cv2.GaussianBlur(res, (0, 0), 1.0), failed

    def process(self, t: int, frame: AnalysisFrame) -> None:
        start = time.perf_counter()
        measured = self.measure(frame, self._prev, [])
        self._seconds += time.perf_counter() - start
        self.ingest(t, frame, measured)

    def ingest(self, t: int, frame: AnalysisFrame, measured: tuple[np.ndarray, bool] | None) -> None:
        """Fold the residual into the decaying motion memory; heat at the analysis size."""
        import cv2

        h, w = frame.gray.shape
        if measured is not None:
            res, failed = measured
            self._homography_failures += int(failed)
            # px a frame and a decay a frame at 25 fps: the same px a second and time constant at any rate
            per = reference_frames_per_frame(frame.fps)
            self._acc = res if self._acc is None else np.maximum(res, self.decay ** per * self._acc)
            heat = np.clip(0.5 * self._acc / (self.threshold_px * per), 0.0, 1.0)
            self._heat = {t: cv2.resize(heat, (w, h), interpolation=cv2.INTER_LINEAR)}
        else:
            self._heat = {t: np.zeros((h, w), np.float32)}
        self._prev = frame
        self._n += 1

    def output(self, t: int) -> DetectorOutput:
        return DetectorOutput(self._heat.get(t))

    def metrics(self) -> dict:
        return {"s_per_frame": self._seconds / max(self._n, 1), "homography_failures": self._homography_failures}
