"""ONNX Runtime for `OneShotFCN.predict`: the same graphs as the torch model, with far less per-layer overhead.

An episode segments one frame at a time, and at batch 1 eager torch spends most of the FCN's time in
per-layer overhead (14 small convolutions, several on its slow unfused path; docs/vision.md, Latency). ONNX
Runtime's CPU kernels, with convolution + ReLU fused, run the same graph 2-4x faster. The torch model stays
the source of truth: the graph is exported from `OneShotFCN.scene_mask` (the scene's part of `predict`:
normalise, resize, segment, scores back, mask) with the model's current weights, lazily, once per input
shape, and rebuilt when any weight changes (`OneShotFCN._weights_key`, which keys the target cache too).
The target's features stay torch's, cached per target image, and are inputs of the graph; its outputs are
the mask and the presence probability.

With a verifier, its per-frame part runs the same way: a second graph, exported from the verifier's
`encoder` and `score`, takes the candidate regions' crops and their targets' encodings (the target crop's,
torch's, cached per target image) and gives the logits, for any number of candidates (none: no call). The
crops stay torch's (`verifier.candidate_crops`): cutting them inside the graph (`grid_sample`) would save
~0.12 ms on a frame with candidates, but `candidate_crops` would have to hand over boxes instead (docs/vision.md,
Latency). Both graphs' sessions share one cache, dropped together when a weight changes.

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


class _VerifierLogits(nn.Module):
    """The verifier's per-frame part as one module for the exporter: encode the candidates' crops and compare
    them with their targets' cached encodings."""

    def __init__(self, verifier: nn.Module):
        super().__init__()
        self.verifier = verifier

    def forward(self, target_encoded: torch.Tensor, scene_crops: torch.Tensor) -> torch.Tensor:
        return self.verifier.score(target_encoded, self.verifier.encoder(scene_crops))


def _export(module: nn.Module, example: tuple, inputs: list[str], outputs: list[str], free_batch: bool) -> bytes:
    """The ONNX graph of `module` traced on `example` (named `inputs`, `outputs`), with its current weights and
    mode; with `free_batch`, for any size of every tensor's first axis."""
    graph = io.BytesIO()
    with torch.inference_mode(False), torch.no_grad(), warnings.catch_warnings():
        warnings.simplefilter("ignore", DeprecationWarning)  # the TorchScript-based exporter's notice
        warnings.simplefilter("ignore", torch.jit.TracerWarning)  # sizes are constants: one graph per input shape
        torch.onnx.export(
            module,
            example,
            graph,
            dynamo=False,
            input_names=inputs,
            output_names=outputs,
            dynamic_axes={name: {0: "batch"} for name in inputs + outputs} if free_batch else None,
        )
    return graph.getvalue()


def export_graph(model: nn.Module, scene_shape: tuple, feature_shapes: list[tuple], free_batch: bool = True) -> bytes:
    """The ONNX graph of `model.scene_mask` for uint8 scenes of `scene_shape` (N, H, W, 3) and target features
    of `feature_shapes`, with the model's current weights; with `free_batch`, for any batch size."""
    example = (torch.zeros(scene_shape, dtype=torch.uint8), *(torch.zeros(shape) for shape in feature_shapes))
    names = [f"target_features_{i}" for i in range(len(feature_shapes))]
    module = _SceneMask(model).train(model.training)  # the exporter restores the wrapper's mode, recursively
    return _export(module, example, ["scene", *names], ["mask", "presence"], free_batch)


def export_verifier_graph(verifier: nn.Module, encoded_shape: tuple, crop_shape: tuple) -> bytes:
    """The ONNX graph of the verifier's logits (M,) from target encodings (M, *`encoded_shape`) and candidate
    crops (M, *`crop_shape`), for any number M of candidates, with the verifier's current weights."""
    example = (torch.zeros(1, *encoded_shape), torch.zeros(1, *crop_shape))
    module = _VerifierLogits(verifier).train(verifier.training)
    return _export(module, example, ["target_encoded", "scene_crops"], ["logits"], free_batch=True)


def session_options(threads: int):
    """ONNX Runtime's options for `predict`: `threads` intra-op threads, all graph optimisations (convolution
    + activation fusion among them), no busy-waiting (the cores are shared)."""
    options = onnxruntime.SessionOptions()
    options.intra_op_num_threads = threads
    options.inter_op_num_threads = 1
    options.add_session_config_entry("session.intra_op.allow_spinning", "0")
    return options


def _session(model: nn.Module, weights: tuple, key: tuple, export, required: bool):
    """The ONNX Runtime session of graph `export()` on torch's thread count, cached on the model under `key`
    (an input shape) while `weights` (`model._weights_key()`) stay the same; None, remembered, where the
    export or session fails and not `required` (warned once: the caller runs the torch model)."""
    if model._runtime_cache is None or model._runtime_cache[0] != weights:
        model._runtime_cache = (weights, {})
    sessions = model._runtime_cache[1]
    key = (*key, torch.get_num_threads())
    if key not in sessions:
        try:
            options = session_options(key[-1])
            sessions[key] = onnxruntime.InferenceSession(export(), options, providers=["CPUExecutionProvider"])
        except Exception as error:
            if required:
                raise
            warnings.warn(f"FCN: ONNX Runtime export failed, running the torch model instead: {error}", stacklevel=4)
            sessions[key] = None
    return sessions[key]


def _check_available(required: bool) -> bool:
    """Whether the packages can be imported; raise if not and `required`."""
    if not available() and required:
        raise RuntimeError("runtime='onnxruntime' needs the onnxruntime and onnx packages (pip install them)")
    return available()


def scene_mask(
    model: nn.Module, scene: torch.Tensor, target_features: list[torch.Tensor], weights: tuple, required: bool
) -> tuple[torch.Tensor, torch.Tensor] | None:
    """`model.scene_mask(scene, target_features)` (mask, presence) run by ONNX Runtime; `weights` is
    `model._weights_key()`. None where ONNX Runtime cannot run it and not `required` (the caller runs torch)."""
    if not _check_available(required):
        return None
    feature_shapes = [tuple(t.shape[1:]) for t in target_features]
    session = _session(
        model,
        weights,
        (tuple(scene.shape[1:]), tuple(feature_shapes), model.config.segment_size),
        lambda: export_graph(model, (1, *scene.shape[1:]), [(1, *s) for s in feature_shapes]),
        required,
    )
    if session is None:
        return None
    feeds = {"scene": np.ascontiguousarray(scene.cpu().numpy())}
    feeds.update((f"target_features_{i}", t.cpu().numpy()) for i, t in enumerate(target_features))
    mask, presence = session.run(None, feeds)
    return torch.from_numpy(mask), torch.from_numpy(presence)


def verifier_logits(
    model: nn.Module, target_encoded: torch.Tensor, scene_crops: torch.Tensor, weights: tuple, required: bool
) -> torch.Tensor | None:
    """`model.verifier.score(target_encoded, model.verifier.encoder(scene_crops))`, logits (M,), run by ONNX
    Runtime (no call for M = 0); `weights` is `model._weights_key()`. None where ONNX Runtime cannot run it
    and not `required` (the caller runs torch)."""
    if not _check_available(required):
        return None
    if not len(scene_crops):
        return torch.zeros(0)
    shapes = (tuple(target_encoded.shape[1:]), tuple(scene_crops.shape[1:]))
    session = _session(
        model, weights, ("verifier", *shapes), lambda: export_verifier_graph(model.verifier, *shapes), required
    )
    if session is None:
        return None
    feeds = {"target_encoded": target_encoded.cpu().numpy(), "scene_crops": scene_crops.cpu().numpy()}
    return torch.from_numpy(session.run(None, feeds)[0])
