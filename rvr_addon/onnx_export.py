"""Export the shipped networks to ONNX (needs torch and the ``onnx`` package; inference then needs
neither: :mod:`rvr_addon.onnxrun`). Run by ``scripts/export_onnx.py``; the test
``tests/engine/test_onnx.py`` checks the files against torch and against a fresh export.

Graphs (each file's metadata: ``rvr_graph``, ``rvr_source_hash``, ``rvr_header``):

* ``estimator.onnx``: the estimator's U-Net trunk (:meth:`EstimatorNet.trunk`) on an sRGB frame
  already padded to a multiple of the stride (32): input ``srgb`` (1, 3, Hp, Wp) in [0, 1],
  outputs ``grid`` (1, bins, Hp/8, Wp/8) and ``e_logits`` (1, 3, Hp/4, Wp/4); height and width
  are dynamic. The padding, the grid's soft bound, the bilateral slicing and the E gate run in
  numpy (:mod:`rvr_addon.estimate.onnx_infer`).
* ``afnet_unit.onnx``: AF-Net's CNN-1 on one unit: ``x`` (N, f_T * (C + audio), H, W) ->
  ``feat`` (N, C1, H/8, W/8), ``map`` (N, 1, H/4, W/4).
* ``afnet_head.onnx``: CNN-2: ``feats`` (B, s * C1, H/8, W/8) (and ``audio`` (B, audio, span)
  with an audio branch) -> ``logit`` (B,).
"""
from __future__ import annotations

import io
import json
import warnings
from pathlib import Path

import torch

OPSET = 17


def export_graph(module: torch.nn.Module, args: tuple, names_in: list[str], names_out: list[str],
            dynamic: dict, meta: dict[str, str]) -> bytes:
    """ONNX bytes of ``module`` traced on ``args`` (TorchScript exporter, deterministic), with metadata."""
    import onnx

    buf = io.BytesIO()
    with torch.no_grad(), warnings.catch_warnings():
        warnings.simplefilter("ignore")  # tracer notes on shape checks the padded input never takes
        torch.onnx.export(module, args, buf, dynamo=False, input_names=names_in, output_names=names_out,
                          dynamic_axes=dynamic, opset_version=OPSET, do_constant_folding=True)
    model = onnx.load_from_string(buf.getvalue())
    del model.metadata_props[:]
    for key, value in sorted(meta.items()):
        entry = model.metadata_props.add()
        entry.key, entry.value = key, value
    model.producer_name, model.producer_version = "rvr-laaf", ""
    onnx.checker.check_model(model)
    return model.SerializeToString()


class _Trunk(torch.nn.Module):
    """The estimator's trunk on a padded frame (no padding branch is traced)."""

    def __init__(self, net: torch.nn.Module) -> None:
        super().__init__()
        self.net = net

    def forward(self, srgb: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        grid, e_logits, _ = self.net.trunk(srgb)
        return grid, e_logits


def export_estimator(weights: str | Path) -> bytes:
    """``estimator.onnx`` bytes from an estimator weights file (module docstring)."""
    from .estimate.infer import load_estimator

    model = load_estimator(weights, backend="torch")
    net = model.net
    s = net.config.stride
    meta = {"rvr_graph": "estimator_trunk", "rvr_source_hash": model.model_hash,
            "rvr_header": json.dumps(model.header, sort_keys=True)}
    if net.config.row_prior:
        # the row coordinate depends on the unpadded height, which the padded graph never sees: the
        # graph gets the grid head without its row column, and the column's weights (the grid gains
        # head_gain * w_row[k] * row(y), the head being a 1x1 conv) go into the metadata, added in numpy
        # (estimate.onnx_infer)
        import copy
        from dataclasses import replace

        plain = copy.deepcopy(net)
        plain.config = replace(net.config, row_prior=False)
        weight = net.grid_head.weight.detach()
        plain.grid_head = torch.nn.Conv2d(weight.shape[1] - 1, weight.shape[0], 1)
        with torch.no_grad():
            plain.grid_head.weight.copy_(weight[:, :-1])
            plain.grid_head.bias.copy_(net.grid_head.bias.detach())
        meta["rvr_row_weights"] = json.dumps([float(v) for v in weight[:, -1, 0, 0]])
        net = plain
    return export_graph(_Trunk(net).eval(), (torch.zeros(1, 3, 2 * s, 3 * s),), ["srgb"], ["grid", "e_logits"],
                   {"srgb": {2: "height", 3: "width"}, "grid": {2: "gh", 3: "gw"}, "e_logits": {2: "eh", 3: "ew"}},
                   meta)


class _Head(torch.nn.Module):
    def __init__(self, cnn2: torch.nn.Module, audio: bool) -> None:
        super().__init__()
        self.cnn2, self.audio = cnn2, audio

    def forward(self, feats: torch.Tensor, audio: torch.Tensor | None = None) -> torch.Tensor:
        return self.cnn2(feats, audio if self.audio else None)


def export_afnet(weights: str | Path) -> tuple[bytes, bytes]:
    """(``afnet_unit.onnx``, ``afnet_head.onnx``) bytes from AF-Net weights (module docstring)."""
    from .afnet.infer import load_afnet

    model, header = load_afnet(weights, backend="torch")
    cfg = model.config
    head = {k: v for k, v in header.items() if k != "file_id"}
    base = {"rvr_source_hash": header["file_id"], "rvr_header": json.dumps(head, sort_keys=True)}
    cin = cfg.f_t * (cfg.channels + cfg.audio)
    unit = export_graph(model.cnn1.eval(), (torch.zeros(2, cin, cfg.height, cfg.width),), ["x"], ["feat", "map"],
                   {"x": {0: "n"}, "feat": {0: "n"}, "map": {0: "n"}}, {**base, "rvr_graph": "afnet_unit"})
    fh, fw = cfg.height // 8, cfg.width // 8
    feats = torch.zeros(1, cfg.s * cfg.widths1[3], fh, fw)
    if cfg.audio:
        args, names = (feats, torch.zeros(1, cfg.audio, cfg.span)), ["feats", "audio"]
        dyn = {"feats": {0: "b"}, "audio": {0: "b"}, "logit": {0: "b"}}
    else:
        args, names, dyn = (feats,), ["feats"], {"feats": {0: "b"}, "logit": {0: "b"}}
    headg = export_graph(_Head(model.cnn2, bool(cfg.audio)).eval(), args, names, ["logit"], dyn,
                    {**base, "rvr_graph": "afnet_head"})
    return unit, headg


def export_all(out_dir: str | Path | None = None) -> list[Path]:
    """Export the shipped estimator and AF-Net next to their weights (or into ``out_dir``); returns
    the paths written."""
    from .afnet.infer import DEFAULT_WEIGHTS as AFNET_PT
    from .estimate.infer import SHIPPED_WEIGHTS as ESTIMATOR_PT

    written = []
    est_dir = Path(out_dir) if out_dir else ESTIMATOR_PT.parent
    af_dir = Path(out_dir) if out_dir else AFNET_PT.parent
    for folder, name, data in [(est_dir, "estimator.onnx", export_estimator(ESTIMATOR_PT)),
                               *zip([af_dir] * 2, ["afnet_unit.onnx", "afnet_head.onnx"], export_afnet(AFNET_PT))]:
        folder.mkdir(parents=True, exist_ok=True)
        path = folder / name
        tmp = path.with_suffix(".onnx.part")
        tmp.write_bytes(data)
        tmp.replace(path)
        written.append(path)
    return written
