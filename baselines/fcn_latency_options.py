"""FCN latency one frame at a time: where `predict`'s time goes, and what each speed-up option buys.

Every option runs `predict` end to end on the same rendered 128² frame and its target (uint8 in, bool mask
out, largest component kept, as BoxState calls it), with only the scene's network part
(`OneShotFCN.scene_mask`) run another way, on one thread. The machine is shared, so the options are timed
in alternating blocks of calls (each sees the same load); medians and minima, with the load average.

  python baselines/fcn_latency_options.py              # the options and the non-network parts (verifier's too)
  python baselines/fcn_latency_options.py --profile    # + torch's layers timed alone, ONNX Runtime per node
  python baselines/fcn_latency_options.py --compile    # + torch.compile (about a minute to compile)
"""

from __future__ import annotations

import copy
import json
import os
import time
import warnings
from collections import defaultdict
from dataclasses import dataclass

import benchmark_fcn  # a sibling script: this runs as `python baselines/fcn_latency_options.py`
import numpy as np
import onnxruntime
import torch
import torch.nn as nn
import torch.nn.functional as F
import tyro
from torch.profiler import ProfilerActivity, profile

from mani_active_vision.agents import fcn_runtime
from mani_active_vision.agents.fcn import load_pretrained, normalize_images, target_pixels, uint8_images
from mani_active_vision.agents.verifier import (
    candidate_crops,
    keep_verified,
    region_boxes,
    square_crops,
    target_crops,
)
from mani_active_vision.boxes import largest_component
from mani_active_vision.segmentation_data import SegmentationDataConfig, make_data_env, render_scene_views


@dataclass
class Args:
    size: int = 128
    """wrist frame side"""
    repeats: int = 300
    """timed calls per option, in blocks of 10"""
    profile: bool = False
    """also time the torch path's layers alone and profile the ONNX Runtime graph per node"""
    compile: bool = False
    """also time torch.compile (inductor; compiling takes about a minute here)"""


def rendered_frame(size: int) -> tuple[np.ndarray, np.ndarray]:
    """One wrist view aimed at the target (unseen objects, held-out seed) and the target's image, uint8."""
    config = SegmentationDataConfig(
        object_set="unseen", views_per_scene=1, image_size=size, view_mode_probs=(1, 0, 0, 0)
    )
    env = make_data_env(config)
    data = render_scene_views(env, 900001, np.random.default_rng(0), config)
    env.close()
    return data["scene"], data["target"]


def with_scene_mask(model, scene_mask):
    """A copy of `model` whose `predict` (runtime="torch") runs `scene_mask(scene, features)` instead."""
    variant = copy.deepcopy(model)
    variant.scene_mask = scene_mask
    return variant


def traced(model, scene, features, optimize: bool = False):
    """`model.scene_mask` traced by torch.jit and frozen (optionally `optimize_for_inference`: oneDNN)."""
    with torch.no_grad(), warnings.catch_warnings():
        warnings.simplefilter("ignore", torch.jit.TracerWarning)  # sizes are constants: traced for this shape
        module = torch.jit.freeze(torch.jit.trace(fcn_runtime._SceneMask(model).eval(), (scene, *features)))
        if optimize:
            module = torch.jit.optimize_for_inference(module)
    return lambda s, f: module(s, *f)


def ort_scene_mask(model, scene, features, level=None, threads: int = 1, free_batch: bool = True):
    """`model.scene_mask` as an ONNX Runtime session with other options than `predict`'s."""
    options = fcn_runtime.session_options(threads)
    if level is not None:
        options.graph_optimization_level = level
    graph = fcn_runtime.export_graph(model, tuple(scene.shape), [tuple(f.shape) for f in features], free_batch)
    session = onnxruntime.InferenceSession(graph, options, providers=["CPUExecutionProvider"])
    names = [i.name for i in session.get_inputs()]
    return lambda s, f: tuple(
        torch.from_numpy(out) for out in session.run(None, dict(zip(names, [s.numpy(), *(t.numpy() for t in f)])))
    )


class CroppingVerifier(nn.Module):
    """The verifier's per-frame part with the crops inside the graph too: the candidates' boxes (M, 4) cut
    from the normalised scenes (N, 3, H, W) by `grid_sample`, encoded and compared with their targets'
    encodings (M, C, h, w)."""

    def __init__(self, verifier: nn.Module):
        super().__init__()
        self.verifier = verifier

    def forward(self, scene, image, boxes, target_encoded):
        crops = square_crops(scene[image], boxes, self.verifier.crop)
        return self.verifier.score(target_encoded, self.verifier.encoder(crops))


def verifier_parts(model, scene: np.ndarray, target: np.ndarray, mask: torch.Tensor) -> dict:
    """The verifier's per-frame parts on `mask`'s candidate regions, each one call to time: as adopted (crops in
    torch, encoder and comparison on ONNX Runtime), as before (all in torch), and with the crops in the graph."""
    crop, verifier = model.config.verifier_crop, model.verifier
    normalized, masks = normalize_images(uint8_images(scene)), mask.numpy()
    target = normalize_images(uint8_images(target))
    candidates = candidate_crops(normalized, masks, model.config.verifier_regions, crop)
    image, crops = candidates["image"], candidates["scene_crops"]
    boxes = region_boxes(candidates["labels"][0], candidates["ids"][0])
    encoded = verifier.encoder(target_crops(target, target_pixels(target), crop))[image]
    weights = model._weights_key()
    cropping = CroppingVerifier(verifier).eval()
    example = (normalized, image, boxes, encoded)
    names = ["scene", "image", "boxes", "target_encoded"]
    graph = fcn_runtime._export(cropping, example, names, ["logits"], free_batch=True)
    session = onnxruntime.InferenceSession(graph, fcn_runtime.session_options(1), providers=["CPUExecutionProvider"])
    feeds = dict(zip(names, (t.numpy() for t in example)))
    probability = verifier.score(encoded, verifier.encoder(crops)).sigmoid()
    return {
        f"verifier: candidate_crops, {len(boxes)} region(s) (scipy label, boxes, crops)": lambda: candidate_crops(
            normalized, masks, model.config.verifier_regions, crop
        ),
        "verifier: square_crops alone (grid_sample)": lambda: square_crops(normalized, boxes, crop, image=image),
        "verifier: torch encoder + comparison (before)": lambda: verifier.score(encoded, verifier.encoder(crops)),
        "verifier: ONNX Runtime encoder + comparison (verifier_logits, adopted)": lambda: fcn_runtime.verifier_logits(
            model, encoded, crops, weights, True
        ),
        "verifier: square_crops + verifier_logits (adopted: crops in torch)": lambda: fcn_runtime.verifier_logits(
            model, encoded, square_crops(normalized, boxes, crop, image=image), weights, True
        ),
        "verifier: ONNX Runtime crops + encoder + comparison (crops in the graph)": lambda: torch.from_numpy(
            session.run(None, feeds)[0]
        ),
        "verifier: keep_verified": lambda: keep_verified(
            candidates, probability, model.config.verifier_threshold, 1, True
        ),
    }


def time_interleaved(calls: dict, repeats: int, block: int = 10) -> dict[str, np.ndarray]:
    """Milliseconds per call of each of `calls` in inference mode, timed in alternating blocks (the same load
    for each): `benchmark_fcn.time_interleaved`."""
    with torch.inference_mode():
        return {name: 1000 * t for name, t in benchmark_fcn.time_interleaved(calls, repeats, block).items()}


def print_table(title: str, times: dict[str, np.ndarray], baseline: str | None = None):
    print(f"\n{title} (load average {os.getloadavg()[0]:.2f})\n")
    print("| option | ms median | ms min |" + (" vs baseline (median) |" if baseline else ""))
    print("|---|---|---|" + ("---|" if baseline else ""))
    for name, t in times.items():
        ratio = f" {np.median(times[baseline]) / np.median(t):.2f}x |" if baseline else ""
        print(f"| {name} | {np.median(t):.3f} | {t.min():.3f} |{ratio}")


def profile_torch(model, scene, target) -> None:
    """Each convolution of `predict(runtime="torch")` timed alone on its own input (no profiler overhead), with
    the torch kernel that does its work (the profiler's operator with the most self time)."""
    inputs, hooks = {}, []

    def keep_input(module, args, name):
        inputs[name] = (module, args[0].clone())

    for name, module in model.named_modules():
        if isinstance(module, (nn.Conv2d, nn.ConvTranspose2d)):
            hooks.append(module.register_forward_pre_hook(lambda m, args, name=name: keep_input(m, args, name)))
    model.predict(scene, target, runtime="torch")
    for hook in hooks:
        hook.remove()
    times = time_interleaved({name: (lambda m=m, x=x: m(x)) for name, (m, x) in inputs.items()}, 200)
    print(f"\ntorch path per layer, each timed alone (load average {os.getloadavg()[0]:.2f})\n")
    print("| layer | input | ms median | ms min | torch kernel |")
    print("|---|---|---|---|---|")
    for name, (module, x) in sorted(inputs.items(), key=lambda kv: -np.median(times[kv[0]])):
        with torch.inference_mode(), profile(activities=[ProfilerActivity.CPU]) as prof:
            module(x)
        kernel = max(prof.key_averages(), key=lambda e: e.self_cpu_time_total).key
        t = times[name]
        print(f"| {name} | {tuple(x.shape)} | {np.median(t):.3f} | {t.min():.3f} | {kernel} |")
    total = sum(np.median(t) for t in times.values())
    print(f"| all {len(times)} convolutions | | {total:.3f} | {sum(t.min() for t in times.values()):.3f} | |")


def profile_onnxruntime(model, scene, target, calls: int = 200) -> None:
    """Per-node time of the adopted ONNX Runtime graph (ONNX Runtime's own profiler)."""
    with torch.inference_mode():
        features = model.target_features(normalize_images(uint8_images(target)))
    options = fcn_runtime.session_options(1)
    options.enable_profiling = True
    graph = fcn_runtime.export_graph(model, tuple(scene.shape), [tuple(f.shape) for f in features])
    session = onnxruntime.InferenceSession(graph, options, providers=["CPUExecutionProvider"])
    feeds = {"scene": scene, **{f"target_features_{i}": f.numpy() for i, f in enumerate(features)}}
    for _ in range(20):
        session.run(None, feeds)
    start = time.perf_counter()
    for _ in range(calls):
        session.run(None, feeds)
    wall = 1000 * (time.perf_counter() - start) / calls
    path = session.end_profiling()
    with open(path) as f:
        trace = json.load(f)
    os.remove(path)
    by_op, count = defaultdict(float), defaultdict(int)
    for event in trace:
        if event.get("cat") == "Node" and event["name"].endswith("_kernel_time"):
            by_op[event["args"]["op_name"]] += event["dur"] / 1000 / (calls + 20)
            count[event["args"]["op_name"]] += 1
    print(f"\nONNX Runtime graph, profiled: {wall:.3f} ms per run\n")
    print("| operator (after ONNX Runtime's fusions) | ms per run | nodes |")
    print("|---|---|---|")
    for op, ms in sorted(by_op.items(), key=lambda kv: -kv[1]):
        print(f"| {op} | {ms:.3f} | {count[op] // (calls + 20)} |")
    print(f"| all nodes | {sum(by_op.values()):.3f} | |")


def main(args: Args):
    torch.set_num_threads(1)
    model = load_pretrained()
    scene, target = rendered_frame(args.size)
    print(f"frame {args.size}², target pixels {int(model.predict(scene, target, runtime='torch').sum())}")
    scene_t = uint8_images(scene)
    with torch.no_grad():  # not inference_mode: torch.jit.trace takes these as inputs
        features = model.target_features(normalize_images(uint8_images(target)))
    levels = onnxruntime.GraphOptimizationLevel
    variants = {
        "torch eager (before)": (model, "torch"),
        "torch, channels-last weights": (copy.deepcopy(model).to(memory_format=torch.channels_last), "torch"),
        "torch.jit.trace + freeze": (
            with_scene_mask(model, traced(model, scene_t, features)),
            "torch",
        ),
        "torch.jit.trace + freeze + optimize_for_inference (oneDNN)": (
            with_scene_mask(model, traced(model, scene_t, features, optimize=True)),
            "torch",
        ),
        "ONNX Runtime, basic graph optimisations (no conv+ReLU fusion)": (
            with_scene_mask(model, ort_scene_mask(model, scene_t, features, levels.ORT_ENABLE_BASIC)),
            "torch",
        ),
        "ONNX Runtime, extended (conv+ReLU fused)": (
            with_scene_mask(model, ort_scene_mask(model, scene_t, features, levels.ORT_ENABLE_EXTENDED)),
            "torch",
        ),
        "ONNX Runtime, all, 2 intra-op threads": (
            with_scene_mask(model, ort_scene_mask(model, scene_t, features, threads=2)),
            "torch",
        ),
        "ONNX Runtime, all, graph for batch 1 only (shapes constant-folded)": (
            with_scene_mask(model, ort_scene_mask(model, scene_t, features, free_batch=False)),
            "torch",
        ),
        "ONNX Runtime, all, 1 thread (adopted: predict's default)": (model, "onnxruntime"),
    }
    if model.verifier is not None:  # the variants above but the last run it in torch
        variants["ONNX Runtime, verifier on torch (before)"] = (benchmark_fcn.verifier_on_torch(model), "onnxruntime")
    if args.compile:
        start = time.perf_counter()
        compiled = torch.compile(model.scene_mask)
        with torch.inference_mode():
            compiled(scene_t, features)
        print(f"torch.compile: first call {time.perf_counter() - start:.0f} s")
        variants["torch.compile (inductor)"] = (with_scene_mask(model, compiled), "torch")
    calls = {
        name: lambda m=m, r=r: m.predict(scene, target, largest_component=True, runtime=r)
        for name, (m, r) in variants.items()
    }
    print_table(
        f"predict end to end, {args.size}², batch 1, same target, largest component",
        time_interleaved(calls, args.repeats),
        "torch eager (before)",
    )

    with torch.inference_mode():
        normalized = normalize_images(scene_t)
        small = F.avg_pool2d(normalized, args.size // model.config.image_size)
        scores64 = model.segment(small, features)
        scores = F.interpolate(scores64, size=(args.size, args.size), mode="bilinear")
        mask = scores[:, 1] > scores[:, 0]
    session = next(iter(model._runtime_cache[1].values()))
    feeds = {"scene": scene, **{f"target_features_{i}": f.numpy() for i, f in enumerate(features)}}
    weights = model._weights_key()
    target_in = normalize_images(uint8_images(target))
    parts = {
        "check + normalise the scene (uint8_images, normalize_images)": lambda: normalize_images(uint8_images(scene)),
        "weights' key (_weights_key)": model._weights_key,
        "target features, cached (_target_features_cached)": lambda: model._target_features_cached(target_in, weights),
        "target features, new target (target_features)": lambda: model.target_features(target_in),
        f"torch: avg_pool2d {args.size}² -> {model.config.image_size}²": lambda: F.avg_pool2d(normalized, 2),
        "torch: segment (the network)": lambda: model.segment(small, features),
        f"torch: bilinear scores -> {args.size}²": lambda: F.interpolate(
            scores64, size=scene.shape[1:3], mode="bilinear"
        ),
        "torch: scores[:, 1] > scores[:, 0]": lambda: scores[:, 1] > scores[:, 0],
        "ONNX Runtime: session.run (normalise ... mask)": lambda: session.run(None, feeds),
        "largest_component (scipy.ndimage.label)": lambda: largest_component(mask),
    }
    if model.verifier is not None:
        with torch.no_grad():  # the exporter's inputs may not be inference tensors
            parts.update(verifier_parts(model, scene, target, mask))
    print_table("the parts, timed alone", time_interleaved(parts, args.repeats))
    if args.profile:
        profile_torch(model, scene, target)
        profile_onnxruntime(model, scene, target)


if __name__ == "__main__":
    main(tyro.cli(Args))
