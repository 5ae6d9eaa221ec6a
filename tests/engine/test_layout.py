"""D's layout head (issue 20): the TFJS trunk interpreter, the shipped ONNX head, the estimator's merge."""
from __future__ import annotations

import base64
import json

import numpy as np
import pytest

from rvr_addon.estimate.infer import SHIPPED_LAYOUT, Estimator, default_weights, load_estimator
from rvr_addon.estimate.layout import LayoutModel, input_size, layout_input

needs_layout = pytest.mark.skipif(not SHIPPED_LAYOUT.is_file(), reason="layout.onnx not shipped in this checkout")


def _b64(s: str) -> str:
    return base64.b64encode(s.encode()).decode()


def _graph(tmp_path, w: np.ndarray, b: np.ndarray, dw: np.ndarray) -> str:
    """A 3-node TFJS graph model: fused conv (bias + relu6, stride 2, SAME), depthwise 3x3 SAME, mean."""
    nodes = [
        {"name": "in", "op": "Placeholder", "attr": {}},
        {"name": "w", "op": "Const", "attr": {}}, {"name": "b", "op": "Const", "attr": {}},
        {"name": "dw", "op": "Const", "attr": {}}, {"name": "ax", "op": "Const", "attr": {}},
        {"name": "conv", "op": "_FusedConv2D", "input": ["in", "w", "b"],
         "attr": {"strides": {"list": {"i": ["1", "2", "2", "1"]}}, "padding": {"s": _b64("SAME")},
                  "fused_ops": {"list": {"s": [_b64("BiasAdd"), _b64("Relu6")]}}}},
        {"name": "dwc", "op": "DepthwiseConv2dNative", "input": ["conv", "dw"],
         "attr": {"strides": {"list": {"i": ["1", "1", "1", "1"]}}, "padding": {"s": _b64("SAME")}}},
        {"name": "mean", "op": "Mean", "input": ["dwc", "ax"], "attr": {"keep_dims": {"b": True}}},
    ]
    arrays = [("w", w.astype(np.float16)), ("b", b.astype(np.float16)), ("dw", dw.astype(np.float16))]
    weights = [{"name": n, "shape": list(a.shape), "dtype": "float32",
                "quantization": {"dtype": "float16", "original_dtype": "float32"}} for n, a in arrays]
    weights.append({"name": "ax", "shape": [2], "dtype": "int32"})
    blob = b"".join(a.tobytes() for _n, a in arrays) + np.array([1, 2], np.int32).tobytes()
    (tmp_path / "g.bin").write_bytes(blob)
    (tmp_path / "g.json").write_text(json.dumps({
        "format": "graph-model", "modelTopology": {"node": nodes},
        "weightsManifest": [{"paths": ["g.bin"], "weights": weights}]}))
    return str(tmp_path / "g.json")


def test_the_tfjs_interpreter_matches_tensorflows_same_padding_and_fused_ops(tmp_path):
    """A stride-2 SAME convolution pads the extra pixel at the bottom/right (TensorFlow's rule, not
    torch's symmetric one); float16 weights are read; the fused bias and ReLU6 apply; a depthwise
    kernel acts per channel. Checked against a direct numpy evaluation."""
    torch = pytest.importorskip("torch")
    from rvr_addon.estimate.tfjs_graph import TfjsGraph

    rng = np.random.default_rng(3)
    w = rng.normal(size=(3, 3, 2, 4)).astype(np.float16).astype(np.float32)  # HWIO
    b = rng.normal(size=4).astype(np.float16).astype(np.float32)
    dw = rng.normal(size=(3, 3, 4, 1)).astype(np.float16).astype(np.float32)
    g = TfjsGraph(_graph(tmp_path, w, b, dw), "in", ["conv", "dwc", "mean"])
    x = rng.normal(size=(1, 2, 8, 6)).astype(np.float32) * 3
    conv, dwc, mean = (t.numpy() for t in g(torch.from_numpy(x)))

    # numpy: SAME for n=8/6, k=3, s=2 pads 0 before and 1 after
    xp = np.pad(x[0], ((0, 0), (0, 1), (0, 1)))
    ref = np.zeros((4, 4, 3), np.float32)
    for o in range(4):
        for i in range(4):
            for j in range(3):
                ref[o, i, j] = np.sum(xp[:, 2 * i:2 * i + 3, 2 * j:2 * j + 3] * w[:, :, :, o].transpose(2, 0, 1)) + b[o]
    ref = np.clip(ref, 0, 6)
    assert conv.shape == (1, 4, 4, 3)
    np.testing.assert_allclose(conv[0], ref, atol=1e-4)
    rp = np.pad(ref, ((0, 0), (1, 1), (1, 1)))
    ref_dw = np.zeros_like(ref)
    for c in range(4):
        for i in range(4):
            for j in range(3):
                ref_dw[c, i, j] = np.sum(rp[c, i:i + 3, j:j + 3] * dw[:, :, c, 0])
    np.testing.assert_allclose(dwc[0], ref_dw, atol=1e-4)
    np.testing.assert_allclose(mean[0, :, 0, 0], ref_dw.mean(axis=(1, 2)), atol=1e-5)


def test_the_interpreter_names_an_op_it_does_not_know(tmp_path):
    torch = pytest.importorskip("torch")
    from rvr_addon.estimate.tfjs_graph import TfjsGraph

    p = tmp_path / "g.json"
    p.write_text(json.dumps({"format": "graph-model", "modelTopology": {"node": [
        {"name": "in", "op": "Placeholder"}, {"name": "t", "op": "Tanh", "input": ["in"]}]}, "weightsManifest": []}))
    with pytest.raises(NotImplementedError, match="Tanh"):
        TfjsGraph(p, "in", ["t"])(torch.zeros(1, 1, 4, 4))


def test_layout_input_keeps_the_aspect_in_multiples_of_32():
    assert input_size(1920, 1080) == (512, 288)
    assert input_size(1080, 1920) == (288, 512)
    assert input_size(1, 1) == (512, 512)
    assert input_size(3000, 10) == (512, 32)
    x = layout_input(np.full((37, 53, 3), 200, np.uint8))
    assert x.shape == (1, 3, 352, 512) and x.dtype == np.float32 and np.allclose(x, 200)


@needs_layout
def test_the_shipped_layout_head_orders_a_real_picture_it_never_saw():
    """Middlebury 2014 Motorcycle (never trained on): the layout head's map is better than the
    "nearer toward the bottom" ramp (0.703) and than the network's own context pass (0.777)."""
    pytest.importorskip("onnxruntime")
    pytest.importorskip("skimage")
    import cv2

    from rvr_addon.estimate.evaluate import affine_invariant_error, motorcycle

    img, q = motorcycle()
    m = LayoutModel(SHIPPED_LAYOUT)(img)
    assert m.shape == (352 // 8, 512 // 8)  # 741 x 500 -> 512 x 352 at the trunk, stride 8
    up = cv2.resize(m, (img.shape[1], img.shape[0]), interpolation=cv2.INTER_LINEAR)
    assert affine_invariant_error(up, q, np.isfinite(q)) < 0.69


@needs_layout
def test_the_estimator_takes_d_layout_from_the_head_and_keeps_e():
    """With the layout head D changes, E is bit-identical (the main pass's), and without the head
    (or onnxruntime) the network's own context pass still gives a layout."""
    pytest.importorskip("onnxruntime")
    model = load_estimator(default_weights())
    rng = np.random.default_rng(0)
    frame = np.zeros((180, 320, 3), np.uint8)
    frame[:90] = (90, 140, 200)  # sky
    frame[90:] = (80, 110, 60)  # ground
    frame += rng.integers(0, 20, frame.shape, dtype=np.uint8)
    with_head = Estimator(model)
    assert with_head.layout is not None
    d_h, e_h = with_head(frame)
    d_c, e_c = Estimator(model, layout=None)(frame)
    assert np.array_equal(e_h, e_c)
    assert not np.allclose(d_h, d_c)
    assert np.isfinite(d_h).all() and d_h.shape == (180, 320)
