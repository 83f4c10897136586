"""ONNX Runtime for `OneShotFCN.predict`: the same graph as the torch model, with far less per-layer overhead.

An episode segments one frame at a time, and at batch 1 eager torch spends most of the FCN's time in
per-layer overhead (14 small convolutions, several on its slow unfused path; docs/vision.md, Latency). ONNX
Runtime's CPU kernels, with convolution + ReLU fused, run the same graph 2-4x faster. The torch model stays
the source of truth: the graph is exported from `OneShotFCN.scene_mask` (the scene's part of `predict`:
normalise, resize, segment, scores back, mask) with the model's current weights, lazily, once per input
shape, and rebuilt when any weight changes (`OneShotFCN._weights_key`, which keys the target cache too).
The target's features stay torch's, cached per target image, and are inputs of the graph; its outputs are
the mask and the presence probability.

The exporter is torch's TorchScript-based one (`dynamo=False`): ~0.1 s per export, where the torch.export
one takes ~8 s and needs onnxscript besides. It is deprecated; if a later torch drops it, `predict` under
runtime="auto" warns once and runs the torch model.
"""

from __future__ import annotations

import io
import warnings

import numpy as np
import torch
import torch.nn as nn

try:
    import onnx  # noqa: F401  (torch's exporter serialises with it)
    import onnxruntime
except ImportError:  # declared dependencies; without them predict(runtime="auto") runs the torch model
    onnxruntime = None


def available() -> bool:
    """Whether onnxruntime (and onnx, which the export needs) can be imported."""
    return onnxruntime is not None


class _SceneMask(nn.Module):
    """`model.scene_mask` as a module with one tensor argument per target feature map, for the exporter."""

    def __init__(self, model: nn.Module):
        super().__init__()
        self.model = model

    def forward(self, scene: torch.Tensor, *target_features: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        return self.model.scene_mask(scene, list(target_features))


def export_graph(model: nn.Module, scene_shape: tuple, feature_shapes: list[tuple], free_batch: bool = True) -> bytes:
    """The ONNX graph of `model.scene_mask` for uint8 scenes of `scene_shape` (N, H, W, 3) and target features
    of `feature_shapes`, with the model's current weights; with `free_batch`, for any batch size."""
    names = [f"target_features_{i}" for i in range(len(feature_shapes))]
    example = (torch.zeros(scene_shape, dtype=torch.uint8), *(torch.zeros(shape) for shape in feature_shapes))
    graph = io.BytesIO()
    with torch.inference_mode(False), torch.no_grad(), warnings.catch_warnings():
        warnings.simplefilter("ignore", DeprecationWarning)  # the TorchScript-based exporter's notice
        warnings.simplefilter("ignore", torch.jit.TracerWarning)  # sizes are constants: one graph per input shape
        torch.onnx.export(
            _SceneMask(model).train(model.training),  # the exporter restores the wrapper's mode, recursively
            example,
            graph,
            dynamo=False,
            input_names=["scene", *names],
            output_names=["mask", "presence"],
            dynamic_axes={name: {0: "batch"} for name in ["scene", *names, "mask", "presence"]} if free_batch else None,
        )
    return graph.getvalue()


def session_options(threads: int):
    """ONNX Runtime's options for `predict`: `threads` intra-op threads, all graph optimisations (convolution
    + activation fusion among them), no busy-waiting (the cores are shared)."""
    options = onnxruntime.SessionOptions()
    options.intra_op_num_threads = threads
    options.inter_op_num_threads = 1
    options.add_session_config_entry("session.intra_op.allow_spinning", "0")
    return options


def build_session(model: nn.Module, scene_shape: tuple, feature_shapes: list[tuple], threads: int):
    """An ONNX Runtime session of `export_graph(model, scene_shape, feature_shapes)` on `threads` threads."""
    graph = export_graph(model, scene_shape, feature_shapes)
    return onnxruntime.InferenceSession(graph, session_options(threads), providers=["CPUExecutionProvider"])


def scene_mask(
    model: nn.Module, scene: torch.Tensor, target_features: list[torch.Tensor], weights: tuple, required: bool
) -> tuple[torch.Tensor, torch.Tensor] | None:
    """`model.scene_mask(scene, target_features)` (mask, presence) run by ONNX Runtime; `weights` is
    `model._weights_key()`.

    Sessions are cached on the model per input shape and torch's thread count, all dropped when `weights`
    changes. When the export or session fails: raise if `required`, else warn once and return None (the
    caller runs the torch model)."""
    if not available():
        if required:
            raise RuntimeError("runtime='onnxruntime' needs the onnxruntime and onnx packages (pip install them)")
        return None
    if model._runtime_cache is None or model._runtime_cache[0] != weights:
        model._runtime_cache = (weights, {})
    sessions = model._runtime_cache[1]
    feature_shapes = [tuple(t.shape[1:]) for t in target_features]
    key = (tuple(scene.shape[1:]), tuple(feature_shapes), torch.get_num_threads())
    if key not in sessions:
        try:
            sessions[key] = build_session(model, (1, *key[0]), [(1, *s) for s in feature_shapes], key[2])
        except Exception as error:
            if required:
                raise
            warnings.warn(f"FCN: ONNX Runtime export failed, running the torch model instead: {error}", stacklevel=3)
            sessions[key] = None
    if sessions[key] is None:
        return None
    feeds = {"scene": np.ascontiguousarray(scene.cpu().numpy())}
    feeds.update((f"target_features_{i}", t.cpu().numpy()) for i, t in enumerate(target_features))
    mask, presence = sessions[key].run(None, feeds)
    return torch.from_numpy(mask), torch.from_numpy(presence)
