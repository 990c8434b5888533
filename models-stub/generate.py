#!/usr/bin/env python3
"""Generates the tiny ONNX stub models in this folder (reproducibly: same bytes every run).

Each stub shares one drbokeh preset's input/output signature (names, ranks, fixed or dynamic
dims; see src/onnx/contract.rs) and computes a simple known function with real operators, so
the Rust tests can check pre-processing, the session and post-processing against a Rust-side
computation of the same function:

  saliency / matting / depth:  y = W . x + B per pixel (a 1x1 convolution over the three input
                               channels in tensor order, W = (0.8, -0.5, 0.3), B = 0.1), then a
                               Sigmoid where the real model ends in one (U^2-Net, ISNet, MODNet,
                               MediaPipe); BiRefNet emits the logits; depth stubs emit y itself.
  inverse tone mapping:        half the sRGB-decoded input plus a ramp above 0.96 (see
                               itm_stub).
  inpainting:                  every masked pixel (mask > 0.5) gets the mean colour of the
                               unmasked pixels, unmasked pixels are kept; `lama` scales the
                               result to 0..255 like the public LaMa export.

Usage: python3 models-stub/generate.py [OUT_DIR]   (default: the folder of this script)
Needs the `onnx` package (pinned in scripts/requirements-test.txt).
"""

import os
import sys

import numpy as np
import onnx
from onnx import TensorProto, helper, numpy_helper

W = [0.8, -0.5, 0.3]
B = 0.1
OPSET = 17
IR_VERSION = 8
F = TensorProto.FLOAT


def const(name, values, shape=None):
    arr = np.asarray(values, dtype=np.float32)
    if shape is not None:
        arr = arr.reshape(shape)
    return numpy_helper.from_array(arr, name)


def save(graph, path):
    model = helper.make_model(
        graph,
        opset_imports=[helper.make_opsetid("", OPSET)],
        producer_name="drbokeh-models-stub",
        producer_version="1",
    )
    model.ir_version = IR_VERSION
    onnx.checker.check_model(model)
    with open(path, "wb") as f:
        f.write(model.SerializeToString(deterministic=True))


def conv_stub(path, inp, out, h, w, sigmoid, extra_outputs=(), squeeze=False, nan=False):
    """NCHW: input [1,3,h,w] -> 1x1 Conv -> (Sigmoid) -> [1,1,h,w] (or [1,h,w] when squeeze)."""
    nodes = [helper.make_node("Conv", [inp, "W", "B"], ["logits"], kernel_shape=[1, 1])]
    inits = [const("W", W, [1, 3, 1, 1]), const("B", [B])]
    last = "logits"
    if sigmoid:
        nodes.append(helper.make_node("Sigmoid", [last], ["s"]))
        last = "s"
    if nan:
        inits.append(const("nan", [float("nan")]))
        nodes.append(helper.make_node("Add", [last, "nan"], ["n"]))
        last = "n"
    if squeeze:
        inits.append(numpy_helper.from_array(np.array([1], dtype=np.int64), "axis1"))
        nodes.append(helper.make_node("Squeeze", [last, "axis1"], [out]))
        out_shape = [1, h, w]
    else:
        nodes.append(helper.make_node("Identity", [last], [out]))
        out_shape = [1, 1, h, w]
    outputs = [helper.make_tensor_value_info(out, F, out_shape)]
    for name in extra_outputs:
        # Side outputs (U^2-Net has seven): half the logits through a Sigmoid.
        inits.append(const(name + "_k", [0.5]))
        nodes.append(helper.make_node("Mul", ["logits", name + "_k"], [name + "_h"]))
        nodes.append(helper.make_node("Sigmoid", [name + "_h"], [name]))
        outputs.append(helper.make_tensor_value_info(name, F, [1, 1, h, w]))
    graph = helper.make_graph(nodes, os.path.basename(path)[:-5], [helper.make_tensor_value_info(inp, F, [1, 3, h, w])], outputs, inits)
    save(graph, path)


def nhwc_stub(path, inp, out, h, w):
    """NHWC: input [1,h,w,3] -> MatMul [3,1] + B -> Sigmoid -> [1,h,w,1]."""
    nodes = [
        helper.make_node("MatMul", [inp, "Wt"], ["m"]),
        helper.make_node("Add", ["m", "B"], ["y"]),
        helper.make_node("Sigmoid", ["y"], [out]),
    ]
    inits = [const("Wt", W, [3, 1]), const("B", [B])]
    graph = helper.make_graph(
        nodes,
        os.path.basename(path)[:-5],
        [helper.make_tensor_value_info(inp, F, [1, h, w, 3])],
        [helper.make_tensor_value_info(out, F, [1, h, w, 1])],
        inits,
    )
    save(graph, path)


def inpaint_stub(path, h, w, scale):
    """LaMa signature: image [1,3,h,w] in [0,1], mask [1,1,h,w] in {0,1} -> output [1,3,h,w]."""
    nodes = [
        helper.make_node("Greater", ["mask", "half"], ["mb"]),
        helper.make_node("Cast", ["mb"], ["m"], to=F),
        helper.make_node("Sub", ["one", "m"], ["keep"]),
        helper.make_node("Mul", ["image", "keep"], ["kept"]),
        # Sums in double precision: a float32 sum over 512x512 pixels drifts by ~1e-5.
        helper.make_node("Cast", ["kept"], ["kept64"], to=TensorProto.DOUBLE),
        helper.make_node("Cast", ["keep"], ["keep64"], to=TensorProto.DOUBLE),
        helper.make_node("ReduceSum", ["kept64", "axes"], ["num"], keepdims=1),
        helper.make_node("ReduceSum", ["keep64", "axes"], ["cnt0"], keepdims=1),
        helper.make_node("Max", ["cnt0", "one64"], ["cnt"]),
        helper.make_node("Div", ["num", "cnt"], ["mean64"]),
        helper.make_node("Cast", ["mean64"], ["mean"], to=F),
        helper.make_node("Mul", ["mean", "m"], ["fill"]),
        helper.make_node("Add", ["kept", "fill"], ["res"]),
        helper.make_node("Mul", ["res", "scale"], ["output"]),
    ]
    inits = [
        const("half", [0.5]),
        const("one", [1.0]),
        numpy_helper.from_array(np.array([1.0], dtype=np.float64), "one64"),
        const("scale", [scale]),
        numpy_helper.from_array(np.array([2, 3], dtype=np.int64), "axes"),
    ]
    graph = helper.make_graph(
        nodes,
        os.path.basename(path)[:-5],
        [helper.make_tensor_value_info("image", F, [1, 3, h, w]), helper.make_tensor_value_info("mask", F, [1, 1, h, w])],
        [helper.make_tensor_value_info("output", F, [1, 3, h, w])],
        inits,
    )
    save(graph, path)


def itm_stub(path, inp, out, gain):
    """ExpandNet signature: input [1,3,H,W] (sRGB-encoded colours in [0,1]) -> output [1,3,H,W],
    per sample 0.5 * srgb_to_linear(x) + 0.5 * gain * relu(x - 0.96) / 0.04: half the photo's
    linear light, plus a ramp above 0.96 that reaches 0.5 * (1 + gain) at white. Scaled to the
    photo (factor 2), a clipped sample becomes a light of radiance 1 + gain."""
    nodes = [
        helper.make_node("Div", [inp, "k1292"], ["lin_lo"]),
        helper.make_node("Add", [inp, "k0055"], ["t0"]),
        helper.make_node("Div", ["t0", "k1055"], ["t1"]),
        helper.make_node("Pow", ["t1", "k24"], ["lin_hi"]),
        helper.make_node("LessOrEqual", [inp, "k04045"], ["is_lo"]),
        helper.make_node("Where", ["is_lo", "lin_lo", "lin_hi"], ["lin"]),
        helper.make_node("Mul", ["lin", "half"], ["base"]),
        helper.make_node("Sub", [inp, "k096"], ["over"]),
        helper.make_node("Relu", ["over"], ["over_pos"]),
        helper.make_node("Mul", ["over_pos", "ramp"], ["lift"]),
        helper.make_node("Add", ["base", "lift"], [out]),
    ]
    inits = [
        const("k1292", [12.92]),
        const("k0055", [0.055]),
        const("k1055", [1.055]),
        const("k24", [2.4]),
        const("k04045", [0.04045]),
        const("half", [0.5]),
        const("k096", [0.96]),
        const("ramp", [0.5 * gain / 0.04]),
    ]
    graph = helper.make_graph(
        nodes,
        os.path.basename(path)[:-5],
        [helper.make_tensor_value_info(inp, F, [1, 3, "height", "width"])],
        [helper.make_tensor_value_info(out, F, [1, 3, "height", "width"])],
        inits,
    )
    save(graph, path)


def main():
    out = sys.argv[1] if len(sys.argv) > 1 else os.path.dirname(os.path.abspath(__file__))
    os.makedirs(out, exist_ok=True)
    p = lambda name: os.path.join(out, name)
    # Saliency / matting presets.
    conv_stub(p("u2net.onnx"), "input.1", "d0", 320, 320, sigmoid=True, extra_outputs=["d1"])
    conv_stub(p("isnet.onnx"), "input", "output", 1024, 1024, sigmoid=True)
    conv_stub(p("birefnet.onnx"), "input_image", "output_image", 1024, 1024, sigmoid=False)
    conv_stub(p("modnet.onnx"), "input", "output", "height", "width", sigmoid=True)
    nhwc_stub(p("mediapipe_selfie.onnx"), "input_1", "activation_10", 256, 256)
    # Depth presets (relative disparity, rank-3 output).
    conv_stub(p("midas_small.onnx"), "image", "depth", 256, 256, sigmoid=False, squeeze=True)
    conv_stub(p("depth_anything_v2.onnx"), "image", "depth", "height", "width", sigmoid=False, squeeze=True)
    # fabio-sim/Depth-Anything-ONNX's default export (`dynamo.py export`, opset 18): a fixed
    # 1x3x518x518 input whose name the exporter picks, output 1x518x518 (docs/guide.md).
    conv_stub(p("depth_anything_v2_vits_18.onnx"), "x", "depth", 518, 518, sigmoid=False, squeeze=True)
    # Inpainting presets.
    inpaint_stub(p("lama.onnx"), 512, 512, 255.0)
    inpaint_stub(p("lama_dynamic.onnx"), "height", "width", 1.0)
    # Inverse tone mapping (highlights): a light of radiance 10 behind every clipped sample.
    itm_stub(p("expandnet.onnx"), "input", "output", 9.0)
    # Broken models for the negative tests.
    conv_stub(p("bad_nan.onnx"), "input.1", "d0", 320, 320, sigmoid=True, nan=True)
    conv_stub(p("bad_names.onnx"), "x", "y", "height", "width", sigmoid=True)


if __name__ == "__main__":
    main()
