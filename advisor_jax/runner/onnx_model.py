"""The actor MLP as a hand-built ONNX graph (paper §5.3), for onnxruntime / TensorRT on the car.

Built with ``onnx.helper`` from the runner's numpy ``Layer`` list, so it needs neither JAX
nor a converter, and only operators an old onnxruntime has (opset ≤ 13 for the Jetson)::

    obs [N, 20] ─ Gemm(hidden_0) ─ Relu ─ … ─ Gemm(head) → logits [N, 2]
    logits ─ Slice[:, 0:1] ─ Sigmoid ─┐
           └ Slice[:, 1:2] ─ Tanh ────┴─ Concat(axis=1) → action [N, 2] = (V, ω)

``build_onnx`` refuses to return a model that onnxruntime does not run to within
``GOLDEN_TOLERANCE`` of the given reference actions. onnx and onnxruntime are optional
(``pip install 'advisor-jax[onnx]'``) and imported only here, lazily.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from advisor_jax.contract import spec
from advisor_jax.runner.errors import RunnerError
from advisor_jax.runner.policy import GOLDEN_TOLERANCE, Layer

# IR version per opset (onnx's versioning table); an old runtime refuses newer IR versions.
_IR_FOR_OPSET = {10: 5, 11: 6, 12: 7, 13: 7}


def build_onnx(
    layers: Sequence[Layer], obs: np.ndarray, actions: np.ndarray, *, opset: int = 13
) -> bytes:
    """Serialized ONNX model of the MLP, verified on (obs [N, 20], actions [N, 2])."""
    if opset not in _IR_FOR_OPSET:
        raise RunnerError(f"opset {opset} is not supported; choose one of {sorted(_IR_FOR_OPSET)}")
    try:
        import onnx
        import onnxruntime
        from onnx import TensorProto, helper, numpy_helper
    except ImportError as e:
        raise RunnerError(
            f"onnx=True needs the optional packages onnx and onnxruntime ({e}); "
            "install them with: pip install 'advisor-jax[onnx]'"
        ) from None
    nodes, inits, x = [], [], "obs"
    for layer in layers:
        w, b = f"{layer.name}/kernel", f"{layer.name}/bias"
        inits += [numpy_helper.from_array(layer.kernel, w), numpy_helper.from_array(layer.bias, b)]
        out = "logits" if layer.name == "head" else f"{layer.name}/linear"
        nodes.append(helper.make_node("Gemm", [x, w, b], [out], name=f"{layer.name}/gemm"))
        if layer.name != "head":
            x = f"{layer.name}/relu"
            nodes.append(helper.make_node("Relu", [out], [x], name=x))
    for name, value in (("zero", 0), ("one", 1), ("two", 2)):
        inits.append(numpy_helper.from_array(np.array([value], np.int64), name))
    nodes += [  # Slice(data, starts, ends, axes): inputs since opset 10
        helper.make_node("Slice", ["logits", "zero", "one", "one"], ["v_logit"], name="slice_v"),
        helper.make_node("Slice", ["logits", "one", "two", "one"], ["w_logit"], name="slice_w"),
        helper.make_node("Sigmoid", ["v_logit"], ["V"], name="sigmoid_v"),
        helper.make_node("Tanh", ["w_logit"], ["omega"], name="tanh_w"),
        helper.make_node("Concat", ["V", "omega"], ["action"], axis=1, name="concat"),
    ]
    graph = helper.make_graph(
        nodes,
        "advisor_jax_actor",
        [helper.make_tensor_value_info("obs", TensorProto.FLOAT, ["N", spec.OBS_SIZE])],
        [helper.make_tensor_value_info("action", TensorProto.FLOAT, ["N", spec.ACTION_SIZE])],
        inits,
    )
    model = helper.make_model(
        graph, opset_imports=[helper.make_opsetid("", opset)], producer_name="advisor-jax"
    )
    model.ir_version = _IR_FOR_OPSET[opset]
    onnx.checker.check_model(model)
    data = model.SerializeToString()
    session = onnxruntime.InferenceSession(data, providers=["CPUExecutionProvider"])
    got = session.run(["action"], {"obs": np.asarray(obs, np.float32)})[0]
    err = float(np.abs(got - actions).max())
    if not err <= GOLDEN_TOLERANCE:
        raise RunnerError(f"ONNX model differs from the reference actions by {err:.3g}")
    return data
