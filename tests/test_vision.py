"""The one-shot segmentation FCN, its data, its shipped weights and the box state built on it."""

import copy
import warnings

import numpy as np
import pytest
import torch
import torch.nn as nn
import torch.nn.functional as F
from conftest import cached_task

import mani_active_vision as mav
from mani_active_vision.agents.fcn import (
    FCNConfig,
    OneShotFCN,
    class_weights,
    flip_horizontally,
    images_to_input,
    load_checkpoint,
    load_pretrained,
    mask_counts,
    save_checkpoint,
    segmenting_at,
    soft_iou_loss,
    summarize_counts,
)
from mani_active_vision.agents.verifier import regions
from mani_active_vision.box_state import CANDIDATE_ACQUIRE, BoxState, _cleared, floor_anchor, moved_box
from mani_active_vision.envs import EnvConfig
from mani_active_vision.segmentation_data import (
    SegmentationDataConfig,
    collect_segmentation_data,
    load_segmentation_data,
    load_segmentation_sets,
    render_scene_views,
    sample_camera_position,
)

SHIPPED_UNSEEN_IOU = 0.65
"""Shipped weights' mean target IoU on a small fresh unseen-object batch of aimed 64² views must exceed this:
measured 0.732 on this batch (0.640 on the 1,000-sample unseen test split, docs/vision.md: the verifier,
deployed at 128², rejects some partial and far 64² views), less a margin for the batch's small size."""


def _render(object_set="train", scenes=(0,), views=6, mode_probs=(0.65, 0.2, 0.15, 0.0), image_size=64):
    config = SegmentationDataConfig(
        object_set=object_set, views_per_scene=views, view_mode_probs=mode_probs, image_size=image_size
    )
    env = cached_task(**EnvConfig(object_set=object_set, image_size=image_size).task_kwargs())
    parts = [render_scene_views(env, seed, np.random.default_rng([0, seed]), config) for seed in scenes]
    return {k: np.concatenate([p[k] for p in parts]) for k in parts[0]}


def test_rendered_samples_are_deterministic_and_match_the_segmentation():
    first, second = _render(scenes=(3,), views=4), _render(scenes=(3,), views=4)
    for key in first:
        np.testing.assert_array_equal(first[key], second[key])
    assert first["scene"].shape == (4, 64, 64, 3) and first["target"].shape == (4, 64, 64, 3)
    assert first["mask"].dtype == bool and first["mask"].shape == (4, 64, 64)
    target_mode = first["view_mode"] == 0
    assert first["mask"][target_mode].any((1, 2)).mean() >= 0.5  # aimed at the target: mostly in view


def test_data_sets_do_not_depend_on_the_number_of_workers(tmp_path):
    config = SegmentationDataConfig(num_scenes=3, views_per_scene=2, seed=7)
    one = collect_segmentation_data(str(tmp_path / "one"), config, scenes_per_shard=2, progress=False)
    two = collect_segmentation_data(str(tmp_path / "two"), config, scenes_per_shard=2, workers=2, progress=False)
    assert one["num_samples"] == two["num_samples"] == 6 and one["shards"] == two["shards"]
    first, second = load_segmentation_data(str(tmp_path / "one")), load_segmentation_data(str(tmp_path / "two"))
    for key in first:
        np.testing.assert_array_equal(first[key], second[key])
    np.testing.assert_array_equal(first["scene_seed"], [7, 7, 8, 8, 9, 9])


def test_model_shapes_and_predict_at_other_sizes():
    model = OneShotFCN(FCNConfig(channels=(8, 16, 16))).eval()
    scores = model(torch.zeros(2, 3, 64, 64), torch.zeros(2, 3, 64, 64))
    assert scores.shape == (2, 2, 64, 64)
    for size in (64, 128, 32):
        mask = model.predict(np.zeros((3, size, size, 3), np.uint8), torch.zeros(3, 64, 64, 3, dtype=torch.uint8))
        assert mask.dtype == torch.bool and mask.shape == (3, size, size)


@pytest.mark.parametrize("full_res_channels", [0, 4])
def test_predict_reuses_the_target_features_only_while_target_and_weights_are_the_same(full_res_channels):
    torch.manual_seed(0)
    model = OneShotFCN(FCNConfig(channels=(8, 8, 16), full_res_channels=full_res_channels)).eval()
    rng = np.random.default_rng(0)
    scene, target, other = (rng.integers(0, 256, (2, 64, 64, 3), dtype=np.uint8) for _ in range(3))

    def fresh(scene, target):  # no cache: the whole forward pass
        with torch.inference_mode():
            scores = model(images_to_input(scene), images_to_input(target))
        return scores[:, 1] > scores[:, 0]

    for t in (target, target, other, target):
        assert torch.equal(model.predict(scene, t), fresh(scene, t))
    with torch.no_grad():
        for p in model.parameters():
            p.add_(0.1 * torch.randn_like(p))  # in place, as an optimiser step
    assert torch.equal(model.predict(scene, target), fresh(scene, target))


def test_flips_and_soft_iou_loss():
    x = torch.arange(2 * 3 * 4, dtype=torch.float32).view(2, 3, 4)
    flipped, again = flip_horizontally(x, x.clone(), where=torch.tensor([True, False]))
    assert torch.equal(flipped[0], x[0].flip(-1)) and torch.equal(flipped[1], x[1]) and torch.equal(flipped, again)
    mask = torch.zeros(2, 4, 4, dtype=torch.bool)
    mask[0, 1:3, 1:3] = True  # sample 1 has no target: it does not count
    sure = torch.stack([~mask, mask], 1).float() * 20  # confident and right
    assert soft_iou_loss(sure, mask) < 1e-6
    assert soft_iou_loss(sure.flip(1), mask) > 0.99  # confident and wrong
    assert soft_iou_loss(sure, torch.zeros_like(mask)) == 0


def test_a_few_training_steps_lower_the_loss():
    torch.manual_seed(0)
    data = _render(scenes=(1, 2), views=6, mode_probs=(1.0, 0.0, 0.0, 0.0))
    scene, target = images_to_input(data["scene"]), images_to_input(data["target"])
    labels = torch.from_numpy(data["mask"]).long()
    weights = class_weights(float(data["mask"].mean()))
    model = OneShotFCN(FCNConfig(channels=(8, 16, 32)))
    optimizer = torch.optim.Adam(model.parameters(), lr=3e-3)
    losses = []
    for _ in range(30):
        loss = F.cross_entropy(model(scene, target), labels, weight=weights)
        optimizer.zero_grad()
        loss.backward()
        optimizer.step()
        losses.append(loss.item())
    assert np.mean(losses[-5:]) < 0.8 * np.mean(losses[:3]), losses


def test_shipped_weights_segment_unseen_objects():
    model = load_pretrained()
    data = _render(object_set="unseen", scenes=(900001, 900002, 900003), views=8, mode_probs=(1.0, 0.0, 0.0, 0.0))
    metrics = summarize_counts(
        mask_counts(model.predict(data["scene"], data["target"]), torch.from_numpy(data["mask"]))
    )
    assert metrics["samples_with_target"] >= 10
    assert metrics["target_iou"] > SHIPPED_UNSEEN_IOU, metrics


SHIPPED_ROLLOUT = dict(iou_20px=0.55, false_positive_rate=0.3, network_false_positive_rate=0.4)
"""Shipped weights on a small fresh set of rollout frames (one episode per source, unseen objects, 128², seeds
410,000+): target IoU on frames with >= 20 target pixels above, false-positive rate on target-absent frames below
these; and the segmentation network alone (the verifier taken off) marks more than this share of those frames
(measured 0.929).
Measured 0.724 and 0.000 on this set (69 and 14 frames); two other seeds' sets gave 0.688 / 0.000 and 0.349 /
0.095, the full 2,080-frame test set 0.702 / 0.026 (0.640 / 0.026 before the lower bar for large regions cut by
the border; docs/vision.md): a regression guard, loose because so few frames vary this much."""


def test_shipped_weights_on_frames_from_rollouts(tmp_path):
    from mani_active_vision.evaluation.rollout_frames import RolloutFramesConfig, collect_rollout_frames

    config = RolloutFramesConfig(episodes_per_source=1, frame_stride=4, seed=410_000)
    collect_rollout_frames(str(tmp_path), config, progress=False)
    data = load_segmentation_data(str(tmp_path))
    model = load_pretrained()
    counts = mask_counts(
        model.predict(data["scene"], data["target"], largest_component=True), torch.from_numpy(data["mask"])
    )
    visible = counts["true"] >= 20
    metrics = summarize_counts(counts)
    iou_20px = summarize_counts({k: v[visible] for k, v in counts.items()})["target_iou"]
    assert visible.sum() >= 10 and metrics["samples_without_target"] >= 10, metrics
    assert iou_20px > SHIPPED_ROLLOUT["iou_20px"], (iou_20px, metrics)
    assert metrics["false_positive_rate"] < SHIPPED_ROLLOUT["false_positive_rate"], metrics
    alone = summarize_counts(
        mask_counts(_shipped_network().predict(data["scene"], data["target"], True), torch.from_numpy(data["mask"]))
    )
    assert alone["false_positive_rate"] > SHIPPED_ROLLOUT["network_false_positive_rate"], alone


def test_the_deployed_dqn_source_walks_its_checkpoints_env(tmp_path):
    """The source that mines the deployed agent's hard negatives runs in its checkpoint's env (the FCN as
    deployed), with the collection's objects, size and panels, and records its frames like the others."""
    import dataclasses

    from mani_active_vision.agents.q_network import checkpoint_env_config
    from mani_active_vision.evaluation.rollout_frames import (
        DEPLOYED_DQN,
        SOURCES,
        RolloutFramesConfig,
        collect_rollout_frames,
        source_env_config,
    )

    config = RolloutFramesConfig(object_set="train", sources=("dqn_fcn_sky",), episodes_per_source=1, frame_stride=25)
    deployed = checkpoint_env_config(DEPLOYED_DQN["dqn_fcn_sky"])
    expected = dataclasses.replace(deployed, object_set="train", start_pose="sky", image_size=128, fcn_weights="")
    assert source_env_config("dqn_fcn_sky", config) == expected
    assert expected.box_hold_steps > 0 and source_env_config("servo_fcn_sky", config).box_hold_steps == 0
    collect_rollout_frames(str(tmp_path), config, progress=False)
    data = load_segmentation_data(str(tmp_path))
    assert (data["source"] == list(SOURCES).index("dqn_fcn_sky")).all()
    assert data["step"].tolist() == [0, 25, 50, 75, 100] and data["scene"].shape == (5, 128, 128, 3)


def _torch_margin(model, scene, target):
    """Score margin (target - background) of the torch model at the scene's size, as `predict` computes it."""
    with torch.inference_mode():
        scores = model.scene_scores(torch.as_tensor(scene), model.target_features(images_to_input(target)))
    return scores[:, 1] - scores[:, 0]


def _assert_masks_agree(fast, plain, margin):
    """ONNX Runtime's kernels sum in another order than torch's (scores differ by ~1e-5), so a mask may differ
    only where the torch model's score margin is that small, and on at most 0.1% of the pixels."""
    differ = fast != plain
    assert fast.shape == plain.shape and fast.dtype == torch.bool
    assert differ.float().mean() <= 1e-3, int(differ.sum())
    assert (margin[differ].abs() < 1e-3).all(), margin[differ]


def _shipped_network() -> OneShotFCN:
    """The shipped weights' segmentation network alone (the verifier taken off)."""
    return load_pretrained().network_alone()


@pytest.mark.parametrize("image_size", [64, 128])
def test_onnxruntime_gives_the_torch_models_masks_on_rendered_frames(image_size):
    model = _shipped_network()
    data = _render("unseen", scenes=(900004, 900005), views=6, mode_probs=(0.65, 0.2, 0.15, 0.0), image_size=image_size)
    plain = model.predict(data["scene"], data["target"], runtime="torch")
    margin = _torch_margin(model, data["scene"], data["target"])
    assert torch.equal(plain, margin > 0)
    assert plain.any((1, 2)).sum() >= 4 and (~plain).any()  # real masks: target pixels and background
    one_at_a_time = torch.cat(
        [model.predict(data["scene"][i : i + 1], data["target"][i : i + 1]) for i in range(len(plain))]
    )  # the default ("auto") runtime at batch 1, as BoxState calls it
    assert model._runtime_cache is not None and not model.training  # ... which is ONNX Runtime here, throughout
    assert len(model._runtime_cache[1]) == 1  # one graph for all the frames
    batched = model.predict(data["scene"], data["target"], runtime="onnxruntime")
    for fast in (one_at_a_time, batched):
        _assert_masks_agree(fast, plain, margin)


def test_segmenting_at_the_cameras_resolution_runs_the_network_on_the_whole_frame():
    data = _render("unseen", scenes=(900004,), views=4, image_size=128)
    scene, target = data["scene"], data["target"]
    sides = []

    def network_input_sides(model):
        sides.clear()
        model.encoder[0].register_forward_pre_hook(lambda module, inputs: sides.append(inputs[0].shape[-1]))
        return model

    native = network_input_sides(load_pretrained(segment_size=128).network_alone())  # network_alone keeps it
    plain = native.predict(scene, target, runtime="torch")
    assert sides == [64, 128] and plain.shape == (4, 128, 128)  # the 64² target image first, then the scene
    margin = _torch_margin(native, scene, target)
    assert torch.equal(plain, margin > 0) and plain.any((1, 2)).sum() >= 2
    _assert_masks_agree(native.predict(scene, target, runtime="onnxruntime"), plain, margin)
    default = network_input_sides(_shipped_network())
    pooled = default.predict(scene, target, runtime="torch")
    assert sides == [64, 64] and not torch.equal(pooled, plain)  # the frame average-pooled to the training size
    segmenting_at(native, 0)  # its ONNX graph is not reused
    _assert_masks_agree(
        native.predict(scene, target, runtime="onnxruntime"), pooled, _torch_margin(default, scene, target)
    )
    for bad in (8, 64.0):
        with pytest.raises(ValueError, match=f"segment_size={bad!r} must be 0"):
            load_pretrained(segment_size=bad)
        with pytest.raises(ValueError, match=f"segment_size={bad!r} must be 0"):
            segmenting_at(default, bad)
        with pytest.raises(ValueError, match=f"fcn_segment_size={bad!r} must be 0"):
            EnvConfig(box_source="fcn", fcn_segment_size=bad)


def test_onnxruntime_graph_is_rebuilt_when_the_weights_change():
    torch.manual_seed(0)
    model = _shipped_network()
    data = _render(scenes=(4,), views=2, mode_probs=(1.0, 0.0, 0.0, 0.0))
    scene, target = data["scene"], data["target"]

    def fast_mask():  # ONNX Runtime's mask, checked against the torch model's current weights
        fast = model.predict(scene, target, runtime="onnxruntime")
        _assert_masks_agree(fast, model.predict(scene, target, runtime="torch"), _torch_margin(model, scene, target))
        return fast, next(iter(model._runtime_cache[1].values()))

    def optimiser_step():  # in place
        with torch.no_grad():
            for p in model.parameters():
                p.add_(0.05 * torch.randn_like(p))

    def swapped_classes():  # the head's two class rows swapped: the mask turns inside out
        return {k: v.flip(0) if k.startswith("head.") else v for k, v in model.state_dict().items()}

    first, session = fast_mask()
    assert fast_mask()[1] is session  # same weights, same shape: the graph is reused
    masks = [first]
    for change in (
        optimiser_step,
        lambda: model.load_state_dict(swapped_classes()),
        lambda: setattr(model, "head", nn.Conv2d(8, 2, 3, 1, 1).requires_grad_(False)),  # new tensors
        # a new parameter in a layer (background everywhere): only a registration tells the weights' key
        lambda: setattr(model.head, "bias", nn.Parameter(torch.tensor([9.0, -9.0]), requires_grad=False)),
    ):
        change()
        mask, new_session = fast_mask()
        assert new_session is not session
        masks.append(mask)
        session = new_session
    assert all(0 < m.float().mean() < 1 for m in masks[:3])  # real masks: target and background
    assert all(not torch.equal(a, b) for a, b in zip(masks, masks[1:]))  # each change moved the mask
    copied = copy.deepcopy(model)  # sessions are not copied; the copy builds its own
    assert copied._runtime_cache is None and torch.equal(copied.predict(scene, target), masks[-1])


def test_onnxruntime_runs_the_verifier_as_torch_does_on_rendered_frames():
    model = load_pretrained()  # the two-stage model: network, then the verifier on each candidate region
    data = _render("unseen", scenes=(900001, 900002), views=4, image_size=128)
    scene, target = data["scene"], data["target"]
    candidates = [len(regions(m, 4)[1]) for m in _shipped_network().predict(scene, target).numpy()]
    assert candidates[0] == 0 and max(candidates) >= 2  # frames with no candidate region and with several
    model.predict(scene[:1], target[:1], runtime="onnxruntime")
    assert all(key[0] != "verifier" for key in model._runtime_cache[1])  # no region: the session is not called

    def agree():  # ONNX Runtime's masks and presence against torch's, one frame at a time and batched
        for largest in (False, True):
            for frames in [slice(i, i + 1) for i in range(len(scene))] + [slice(None)]:
                mask, presence = model.predict_with_presence(scene[frames], target[frames], largest, "onnxruntime")
                plain_mask, plain_presence = model.predict_with_presence(
                    scene[frames], target[frames], largest, "torch"
                )
                assert torch.equal(mask, plain_mask)
                torch.testing.assert_close(presence, plain_presence, rtol=0, atol=1e-4)
        return model.predict_with_presence(scene, target, runtime="onnxruntime")

    mask, presence = agree()
    assert any(key[0] == "verifier" for key in model._runtime_cache[1])
    assert not mask[0].any() and presence[0] == 0  # frame 0 has no candidate region: nothing in view
    scored = presence > 0  # the frames with candidate regions: some accepted, some rejected
    assert mask.any((1, 2)).sum() >= 2 and (scored & ~mask.any((1, 2))).any()
    with torch.no_grad():
        model.verifier.head[-1].bias.sub_(2.0)  # a stricter verifier: its graph is rebuilt
    assert (agree()[1][scored] < presence[scored]).all()


DISCRIMINATING = dict(full_res_channels=4, target_pooling="masked", shape_kernel=3, presence_head=True)


def _target_with_box(rows, cols, color=(200, 40, 30)):
    """A target image as the task makes it: grey 128 but for the target's pixels (here a rectangle)."""
    target = np.full((1, 64, 64, 3), 128, np.uint8)
    target[0, rows[0] : rows[1], cols[0] : cols[1]] = color
    return target


def test_discriminating_model_runs_the_same_on_onnxruntime_and_its_presence_gates_the_mask():
    torch.manual_seed(0)
    model = OneShotFCN(FCNConfig(channels=(8, 8, 16), **DISCRIMINATING)).eval()
    rng = np.random.default_rng(3)
    scene = rng.integers(0, 256, (3, 64, 64, 3), dtype=np.uint8)
    target = np.repeat(_target_with_box((10, 30), (20, 50)), 3, 0)
    margin = _torch_margin(model, scene, target)
    with torch.no_grad():  # about half the pixels on the target side of the scores, whatever the init gave
        model.head.bias[1] -= margin.median()
    margin = _torch_margin(model, scene, target)
    for bias, expected in ((20.0, margin > 0), (-20.0, torch.zeros_like(margin, dtype=torch.bool))):
        with torch.no_grad():
            model.presence[-1].bias.fill_(bias)
        for runtime in ("torch", "onnxruntime"):
            mask, presence = model.predict_with_presence(scene, target, runtime=runtime)
            assert presence.shape == (3,) and ((presence > 0.99) if bias > 0 else (presence < 0.01)).all()
            _assert_masks_agree(mask, expected, margin)
            assert torch.equal(model.predict(scene, target, runtime=runtime), mask)
    assert (margin > 0).float().mean() > 0.2  # the open gate let a real mask through
    with pytest.raises(ValueError, match="target_pooling='mean' is not one of: max, masked"):
        FCNConfig(target_pooling="mean")


def test_masked_pooling_and_the_shape_kernel_read_the_targets_pixels_only():
    from mani_active_vision.agents.fcn import _box_grid

    target = images_to_input(_target_with_box((10, 30), (20, 50)))
    grid = _box_grid(target, 6)[0]  # x then y, normalised to [-1, 1] over the 64-pixel sides
    assert grid[..., 0].min() > 20 / 32 - 1 and grid[..., 0].max() < 50 / 32 - 1
    assert grid[..., 1].min() > 10 / 32 - 1 and grid[..., 1].max() < 30 / 32 - 1
    assert torch.allclose(_box_grid(images_to_input(_target_with_box((0, 0), (0, 0))), 2)[0].abs(), torch.tensor(0.5))
    torch.manual_seed(0)
    model = OneShotFCN(FCNConfig(channels=(8, 8, 16), **DISCRIMINATING)).eval()
    target = images_to_input(_target_with_box((0, 32), (0, 32)))  # the top-left quarter, whole cells at 1/2
    with torch.inference_mode():
        vectors, encoded = model.target_features(target), model.encode(target)[0]
    inside = encoded[:, :, :16, :16]
    assert torch.allclose(vectors[0][:, :8, 0, 0], inside.mean((2, 3)), atol=1e-6)  # mean and max of its cells
    assert torch.equal(vectors[0][:, 8:, 0, 0], inside.amax((2, 3)))
    assert not torch.allclose(vectors[0][:, :8, 0, 0], encoded.mean((2, 3)))  # not of the grey around it
    assert len(vectors) == 5 and vectors[3].shape == (1, 8, 3, 3) and vectors[4].shape == (1, 16, 3, 3)


def test_lookalike_views_aim_at_the_lookalikes():
    config = SegmentationDataConfig(view_mode_probs=(0, 0, 0, 1), height_range=(0.2, 0.4))
    object_xy = np.array([[0.6, 0.0], [0.0, 0.6], [-0.6, 0.0]])  # target ahead, distractors left and behind
    rng = np.random.default_rng(0)
    azimuths = []
    for _ in range(40):
        pos, mode, _ = sample_camera_position(rng, object_xy, config, lookalikes=(2,))
        azimuths.append(np.arctan2(pos[1], pos[0]))
        assert mode == "lookalike"
    assert np.mean(np.abs(np.cos(azimuths) + 1) < 0.2) > 0.8  # behind the robot, towards slot 2
    with pytest.raises(ValueError, match="must be 4 probabilities"):
        SegmentationDataConfig(view_mode_probs=(0.65, 0.2, 0.15))


def test_data_sets_of_larger_frames_are_downsampled_to_the_first_sets_size(tmp_path):
    import json

    for name, size in (("small", 8), ("large", 16)):
        rng = np.random.default_rng(size)
        mask = np.zeros((2, size, size), bool)
        mask[:, : size // 2] = True
        arrays = dict(
            scene=rng.integers(0, 256, (2, size, size, 3), dtype=np.uint8),
            target=np.zeros((2, 4, 4, 3), np.uint8),
            mask=mask,
        )
        (tmp_path / name).mkdir()
        np.savez(tmp_path / name / "shard_00000.npz", **arrays)
        (tmp_path / name / "manifest.json").write_text(json.dumps(dict(shards=[dict(file="shard_00000.npz")])))
        if name == "large":
            large = arrays
    data = load_segmentation_sets([str(tmp_path / "small"), str(tmp_path / "large")])
    assert data["scene"].shape == (4, 8, 8, 3) and data["mask"].shape == (4, 8, 8)
    block = large["scene"][0, :2, :2].reshape(-1, 3).astype(float).mean(0)
    assert np.array_equal(data["scene"][2, 0, 0], np.round(block).astype(np.uint8))
    assert data["mask"][2, :4].all() and not data["mask"][2, 4:].any()
    with pytest.raises(ValueError, match="do not fit"):
        load_segmentation_sets([str(tmp_path / "large"), str(tmp_path / "small")])


def test_runtime_choice_and_fallback_to_torch():
    model = OneShotFCN(FCNConfig(channels=(8, 8, 16)))
    rng = np.random.default_rng(2)
    target = rng.integers(0, 256, (1, 64, 64, 3), dtype=np.uint8)
    with pytest.raises(ValueError, match="runtime 'jit' is not one of"):
        model.predict(np.zeros((1, 64, 64, 3), np.uint8), target, runtime="jit")
    model.predict(np.zeros((1, 64, 64, 3), np.uint8), target)
    assert model._runtime_cache is None  # training mode: "auto" runs torch
    model.eval()
    odd = rng.integers(0, 256, (1, 96, 96, 3), dtype=np.uint8)  # 96 -> 64 "area" resize: not exportable
    with pytest.warns(UserWarning, match="running the torch model instead"):
        mask = model.predict(odd, target)
    assert torch.equal(mask, model.predict(odd, target, runtime="torch"))
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # the failure is remembered: no second export, no second warning
        model.predict(odd, target)
    with pytest.raises(torch.onnx.errors.OnnxExporterError):
        OneShotFCN(model.config).eval().predict(odd, target, runtime="onnxruntime")


@pytest.mark.parametrize(
    "scene, words",
    [
        (np.zeros((1, 60, 64, 3), np.uint8), "multiples of 8"),
        (np.zeros((1, 3, 64, 64), np.uint8), "channels-first"),
        (np.zeros((1, 64, 64, 3), np.float32), "uint8"),
        (np.zeros((64, 64, 3), np.uint8), "(N, H, W, 3)"),
        (np.zeros((2, 64, 64, 3), np.uint8), "one target per scene"),
        ([[0]], "numpy array or torch tensor"),
    ],
)
def test_bad_inputs_are_clear_errors(scene, words):
    model = OneShotFCN(FCNConfig(channels=(8, 8, 8)))
    with pytest.raises((ValueError, TypeError), match=words.replace("(", r"\(").replace(")", r"\)")):
        model.predict(scene, np.zeros((1, 64, 64, 3), np.uint8))


def test_checkpoints_round_trip_and_bad_files_are_clear_errors(tmp_path):
    model = OneShotFCN(FCNConfig(channels=(8, 8, 16)))
    path = str(tmp_path / "fcn.pt")
    save_checkpoint(path, model, epoch=3)
    loaded, checkpoint = load_checkpoint(path)
    assert checkpoint["epoch"] == 3 and loaded.config == model.config
    x = torch.rand(1, 3, 64, 64)
    assert torch.equal(loaded(x, x), model.eval()(x, x))
    with pytest.raises(FileNotFoundError, match="does not exist"):
        load_checkpoint(str(tmp_path / "missing.pt"))
    (tmp_path / "corrupt.pt").write_bytes(b"not a checkpoint")
    with pytest.raises(ValueError, match="not a readable"):
        load_checkpoint(str(tmp_path / "corrupt.pt"))
    torch.save({"weights": torch.zeros(1)}, tmp_path / "other.pt")
    with pytest.raises(ValueError, match="not an FCN checkpoint"):
        load_checkpoint(str(tmp_path / "other.pt"))
    checkpoint["config"]["channels"] = (8, 8, 8)
    torch.save(checkpoint, tmp_path / "mismatch.pt")
    with pytest.raises(ValueError, match="does not match"):
        load_checkpoint(str(tmp_path / "mismatch.pt"))


def test_boxes_and_metrics_of_hand_made_masks():
    mask = torch.zeros(3, 8, 8, dtype=torch.bool)
    mask[0, 2:4, 1:6] = True  # rows 2-3, columns 1-5
    mask[1, 7, 7] = True
    box = mav.mask_to_box(mask)
    torch.testing.assert_close(box[0], torch.tensor([1 / 8, 2 / 8, 5 / 8, 2 / 8]))
    torch.testing.assert_close(box[1], torch.tensor([7 / 8, 7 / 8, 1 / 8, 1 / 8]))
    assert torch.equal(box[2], torch.zeros(4))
    pred = mask.clone()
    pred[0, 2:4, 1:3] = False  # 4 of 10 pixels missed
    pred[2, 0, 0] = True  # a false positive where there is no target
    metrics = summarize_counts(mask_counts(pred, mask))
    assert metrics["target_iou"] == pytest.approx((0.6 + 1.0) / 2)
    assert metrics["false_positive_rate"] == 1.0 and metrics["samples_without_target"] == 1
    assert metrics["box_error"] == pytest.approx(float((2 / 8 + 2 / 8) / 4 / 2))


def test_boxes_and_target_stats_on_the_cpu_are_the_batched_torch_ones_bit_for_bit():
    boxes = mav.boxes
    rng = np.random.default_rng(0)
    for i in range(60):
        n, (h, w) = 1 + i % 3, [(128, 128), (64, 64), (40, 72)][i % 3]
        mask = np.zeros((n, h, w), dtype=bool)  # boxes, some cut by the border, some images empty
        for k in range(n):
            y0, x0 = rng.integers(-8, h), rng.integers(-8, w)
            mask[k, max(y0, 0) : max(y0 + rng.integers(0, h), 0), max(x0, 0) : max(x0 + rng.integers(0, w), 0)] = True
        if i % 4 == 0:
            mask |= rng.random(mask.shape) < 0.01  # scattered pixels
        mask = torch.from_numpy(mask)
        numpy_path, torch_path = boxes.target_stats(mask), boxes._target_stats_torch(mask)
        for key, value in torch_path.items():
            assert numpy_path[key].dtype == value.dtype and torch.equal(numpy_path[key], value), key
        assert torch.equal(boxes.mask_to_box(mask), boxes._box_torch(mask))
        assert torch.equal(boxes.mask_stats(mask), boxes._mask_stats_torch(mask))
        for a, b in zip(boxes.centroid(mask), boxes._centroid_torch(mask)):
            assert a.dtype == b.dtype and torch.equal(a, b)
    assert torch.isinf(boxes.target_stats(torch.zeros(1, 8, 8, dtype=torch.bool))["center_offset"]).all()


def test_largest_component_keeps_the_biggest_region_or_nothing():
    mask = torch.zeros(3, 8, 8, dtype=torch.bool)
    mask[0, 1:4, 1:4] = True  # 9 pixels
    mask[0, 6, 6:8] = True  # a 2-pixel speck
    mask[1, 0, 0] = mask[1, 1, 1] = True  # diagonal neighbours: one 8-connected region of 2
    kept = mav.boxes.largest_component(mask, min_pixels=2)
    assert torch.equal(kept[0], mask[0] & ~(torch.arange(8)[:, None] == 6))
    assert torch.equal(kept[1], mask[1])
    assert not kept[2].any()
    assert not mav.boxes.largest_component(mask, min_pixels=10).any()
    with pytest.raises(ValueError, match="bool tensor"):
        mav.boxes.largest_component(mask.float())


def test_box_state_from_fcn_and_its_last_mask():
    env = BoxState(
        mav.DiscreteDirections(cached_task(start_pose="search", placement="fixed", obs_mode="rgb")),
        source="fcn",
        segmenter=load_pretrained(),
    )
    obs, info = env.reset(seed=0)
    for action in (0, 0, 0, 2):
        obs, _, _, _, info = env.step(action)
    assert obs.shape == (1, 4) and env.last_mask.shape == (1, 64, 64) and env.last_mask.dtype == torch.bool
    assert torch.equal(obs, mav.mask_to_box(env.last_mask))
    ground_truth = BoxState(cached_task(start_pose="search", placement="fixed"))
    obs, info = ground_truth.reset(seed=0)
    assert torch.equal(obs, mav.mask_to_box(ground_truth.last_mask)) and torch.allclose(obs, info["target_bbox"])
    with pytest.raises(ValueError, match="needs an obs_mode with segmentation"):
        BoxState(cached_task(obs_mode="rgb"), source="ground_truth")
    with pytest.raises(ValueError, match="is not one of: ground_truth, fcn"):
        BoxState(cached_task(), source="yolo")
    with pytest.raises(ValueError, match="needs segmenter="):
        BoxState(cached_task(), source="fcn")


def test_box_state_tracks_within_an_episode_and_forgets_at_reset():
    class Recording:  # the shipped FCN, noting what BoxState passes it
        def __init__(self):
            self.model, self.calls = load_pretrained(), []

        def predict_with_presence(self, scene, target, largest_component, **tracking):
            self.calls.append(tracking)
            return self.model.predict_with_presence(scene, target, largest_component, **tracking)

    segmenter = Recording()
    task = mav.DiscreteDirections(cached_task(start_pose="search", placement="fixed", obs_mode="rgb"))
    env = BoxState(task, source="fcn", segmenter=segmenter, thresholds=(0.97, 0.5))
    env.reset(seed=0)
    for action in (0, 0, 0):
        env.step(action)
    env.reset(seed=1)
    previous = [call["previous"] for call in segmenter.calls]
    assert previous[0] is None and previous[4] is None  # each reset's observation tracks nothing
    assert all(p is not None and p.shape == (1, 64, 64) for p in previous[1:4])
    assert all(call["thresholds"] == (0.97, 0.5) for call in segmenter.calls)
    untracked = BoxState(task, source="fcn", segmenter=segmenter)
    segmenter.calls.clear()
    untracked.reset(seed=0)
    assert segmenter.calls == [{}]  # (0, 0): every frame alone, as before
    with pytest.raises(ValueError, match="must be \\(acquire, track\\)"):
        BoxState(task, source="fcn", segmenter=segmenter, thresholds=(0.9, 1.5))
    with pytest.raises(ValueError, match="fcn_track_threshold=1.5 must be in"):
        mav.EnvConfig(fcn_track_threshold=1.5)


def test_box_hold_keeps_the_last_box_seen_for_its_steps_and_forgets_it_at_reset():
    class Scripted:  # a segmenter that sees a box, then nothing
        def __init__(self, seen):
            self.seen, self.calls = seen, 0

        def predict_with_presence(self, scene, target, largest_component):
            mask = torch.zeros(1, *scene.shape[1:3], dtype=torch.bool)
            if self.seen[self.calls % len(self.seen)]:
                mask[0, 8:24, 16:32] = True
            self.calls += 1
            return mask, mask.flatten(1).any(1).float()

    task = mav.DiscreteDirections(cached_task(start_pose="search", placement="fixed", obs_mode="rgb"))
    segmenter = Scripted([True, False, False, False, True, False])
    env = BoxState(task, source="fcn", segmenter=segmenter, hold_steps=2)
    outputs = [env.reset(seed=0)] + [env.step(0) for _ in range(5)]
    boxes = [torch.as_tensor(out[0]).reshape(-1).numpy() for out in outputs]
    seen = boxes[0]
    assert seen[2] > 0 and np.allclose(boxes[1], seen) and np.allclose(boxes[2], seen)  # held 2 steps
    assert not boxes[3].any() and env.last_mask is not None and not env.last_mask.any()  # then not seen
    assert np.allclose(boxes[4], seen) and np.allclose(boxes[5], seen)  # seen again, held again
    assert [out[-1]["box_held"] for out in outputs] == [False, True, True, False, False, True]  # info says which
    segmenter.seen = [False]
    assert not torch.as_tensor(env.reset(seed=0)[0]).any()  # a new episode holds nothing of the last
    with pytest.raises(ValueError, match="box_hold_steps=-1 must be an integer of at least 0"):
        mav.EnvConfig(box_hold_steps=-1)


def test_candidates_in_a_batch_raise_the_bar_only_in_their_own_episodes():
    class Verifier:  # per episode (its index in the scene's first pixel) one region and its probability
        def __init__(self, regions):
            self.regions, self.calls = regions, []

        def predict_with_presence(self, scene, target, largest_component, thresholds=(0.0, 0.0), previous=None, **_):
            rows = scene[:, 0, 0, 0].tolist()
            self.calls.append((rows, thresholds, None if previous is None else len(previous)))
            mask = torch.zeros(len(scene), *scene.shape[1:3], dtype=torch.bool)
            presence = torch.zeros(len(scene))
            for i, row in enumerate(rows):
                if self.regions[row] is not None:
                    region, presence[i] = self.regions[row]
                    mask[i][region] = presence[i] >= thresholds[0]
            return mask, presence

    inside = (slice(24, 32), slice(24, 40))
    verifier = Verifier([(inside, 0.95), (inside, 0.98), None])  # a candidate, a sighting, nothing
    task = mav.DiscreteDirections(cached_task(start_pose="search", placement="fixed", obs_mode="rgb"))
    env = BoxState(task, source="fcn", segmenter=verifier, thresholds=(0.97, 0.9), candidate_threshold=0.9)
    rgb = torch.zeros(3, 64, 64, 3, dtype=torch.uint8)
    rgb[:, 0, 0, 0] = torch.arange(3)
    target = torch.zeros(3, 32, 32, 3, dtype=torch.uint8)
    tracking = dict(previous=torch.zeros(3, 64, 64, dtype=torch.bool), thresholds=(0.97, 0.9))

    mask, presence = env._segment_after_candidates(rgb, target, tracking)
    boxes = env._candidates(rgb, target, mask, presence)
    assert mask.flatten(1).any(1).tolist() == [False, True, False]
    assert boxes[0].tolist() == [24 / 64, 24 / 64, 16 / 64, 8 / 64] and not boxes[1:].any()
    assert verifier.calls[-1] == ([0], (0.9, 0.9), None)  # the candidate located in its own episode only
    assert env._after_candidate.tolist() == [True, False, False]

    verifier.calls.clear()
    verifier.regions = [(inside, 0.98)] * 3  # the same score everywhere: only episode 0's bar is raised
    mask, _ = env._segment_after_candidates(rgb, target, tracking)
    assert verifier.calls == [([0, 1, 2], (0.97, 0.9), 3), ([0], (CANDIDATE_ACQUIRE, 0.9), 1)]
    assert mask.flatten(1).any(1).tolist() == [False, True, True]


def test_the_held_box_is_tracked_where_the_border_bar_is_kept_near_it():
    class Scripted:  # a segmenter that sees a box, then nothing, noting what it is asked to track
        def __init__(self):
            self.calls = []

        def predict_with_presence(self, scene, target, largest_component, **tracking):
            self.calls.append(tracking)
            mask = torch.zeros(1, *scene.shape[1:3], dtype=torch.bool)
            if len(self.calls) == 1:
                mask[0, 8:24, 16:32] = True
            return mask, mask.flatten(1).any(1).float()

    task = mav.DiscreteDirections(cached_task(start_pose="search", placement="fixed", obs_mode="rgb"))
    segmenter = Scripted()
    env = BoxState(
        task, source="fcn", segmenter=segmenter, thresholds=(0.97, 0.9), hold_steps=2, border_bar_near_box=True
    )
    env.reset(seed=0)
    env.step(0)  # the box is held
    env.step(0)
    seen, held = segmenter.calls[1]["previous"], segmenter.calls[2]["previous"]
    assert seen[0, 8:24, 16:32].all() and seen.sum() == 16 * 16  # the region kept
    assert held[0, 8:24, 16:32].all() and held.sum() == 16 * 16  # nothing kept: the held box (it stays put here)
    assert all(call["border_bar_near_previous"] for call in segmenter.calls[1:])
    segmenter.calls.clear()
    env.reset(seed=0)
    assert segmenter.calls[0]["previous"] is None  # a new episode tracks nothing of the last
    with pytest.raises(ValueError, match="border_bar_near_box restricts the verifier's low bar"):
        BoxState(task, source="fcn", segmenter=segmenter, border_bar_near_box=True)
    with pytest.raises(ValueError, match="fcn_border_bar_near_box restricts the verifier's low bar"):
        mav.EnvConfig(box_source="fcn", fcn_border_bar_near_box=True)
    assert mav.EnvConfig(fcn_border_bar_near_box=True).box_source == "ground_truth"  # the FCN's field, ignored there


def test_a_region_the_verifier_turned_away_by_little_is_a_candidate_and_raises_the_next_acquire_bar():
    class Verifier:  # one scripted region per frame with its probability, accepted at the acquire bar given
        def __init__(self):
            self.region, self.probability, self.bars = None, 0.0, []

        def predict_with_presence(self, scene, target, largest_component, thresholds=(0.0, 0.0), **tracking):
            self.bars.append(thresholds)
            mask = torch.zeros(1, *scene.shape[1:3], dtype=torch.bool)
            if self.region is not None and self.probability >= thresholds[0]:
                mask[0][self.region] = True
            return mask, torch.tensor([self.probability if self.region is not None else 0.0])

    task = mav.DiscreteDirections(cached_task(start_pose="search", placement="fixed", obs_mode="rgb"))
    verifier = Verifier()
    env = BoxState(task, source="fcn", segmenter=verifier, thresholds=(0.97, 0.9), candidate_threshold=0.9)
    inside, border, tiny = (slice(24, 32), slice(24, 40)), (slice(24, 32), slice(0, 8)), (slice(30, 32), slice(30, 32))

    def step(region, probability):
        verifier.region, verifier.probability = region, probability
        verifier.bars.clear()
        obs, _, _, _, info = env.step(0)
        return obs.reshape(-1)[:4], info["candidate_box"].reshape(-1), verifier.bars

    obs, info = env.reset(seed=0)
    assert not info["candidate_box"].any() and not obs.any()
    box, candidate, bars = step(inside, 0.95)  # turned away at 0.97, over 0.9: a candidate, its box reported
    assert not box.any() and torch.allclose(candidate, torch.tensor([24 / 64, 24 / 64, 16 / 64, 8 / 64]))
    assert bars == [(0.97, 0.9), (0.9, 0.9)]
    box, candidate, bars = step(inside, 0.98)  # after a candidate a new region needs CANDIDATE_ACQUIRE (0.99)
    assert bars[0] == (CANDIDATE_ACQUIRE, 0.9) and not box.any() and candidate.any()
    box, candidate, bars = step(border, 0.95)  # at the border: not reported, but the bar stays raised
    assert not candidate.any()
    box, candidate, bars = step(tiny, 0.95)  # 4 pixels: not reported
    assert bars[0] == (CANDIDATE_ACQUIRE, 0.9) and not candidate.any()
    box, candidate, bars = step(None, 0.0)  # nothing: no candidate
    assert not candidate.any() and len(bars) == 1
    box, candidate, bars = step(inside, 0.98)  # the usual bar again: the region becomes the box
    assert bars == [(0.97, 0.9)] and box.any() and not candidate.any()
    verifier.region, verifier.probability = inside, 0.95
    env.step(0)
    verifier.bars.clear()
    env.reset(seed=0)
    assert verifier.bars[0] == (0.97, 0.9)  # a new episode keeps nothing of the last one's candidates
    assert "candidate_box" not in BoxState(task, source="fcn", segmenter=verifier).reset(seed=0)[1]
    with pytest.raises(
        ValueError, match="candidate_threshold=0.9 must be in \\[0, 1\\) \\(0: off\\), and needs source 'fcn'"
    ):
        BoxState(cached_task(), source="ground_truth", candidate_threshold=0.9)
    with pytest.raises(ValueError, match="fcn_candidate_threshold=1.0 must be in"):
        mav.EnvConfig(fcn_candidate_threshold=1.0)
    flags = torch.tensor([True, True, False])  # a batched env's state, some of its episodes reset
    cleared = _cleared(flags, [1])
    assert cleared.tolist() == [True, False, False] and flags.tolist() == [True, True, False]  # a copy
    assert _cleared(flags, None) is None and _cleared(None, [0]) is None


def test_a_held_box_centred_in_the_view_is_dropped_after_its_steps_until_a_box_is_seen_again():
    class Scripted:  # a segmenter that sees a box at the image centre or at its border, then nothing
        def __init__(self, seen):
            self.seen, self.calls = seen, 0

        def predict_with_presence(self, scene, target, largest_component):
            mask = torch.zeros(1, *scene.shape[1:3], dtype=torch.bool)
            where = self.seen[self.calls % len(self.seen)]
            if where == "centre":
                mask[0, 28:36, 28:36] = True
            elif where == "border":
                mask[0, 28:36, 0:8] = True
            self.calls += 1
            return mask, mask.flatten(1).any(1).float()

    task = mav.DiscreteDirections(cached_task(start_pose="search", placement="fixed", obs_mode="rgb"))
    seen = ["centre"] + [None] * 4 + ["border"] + [None] * 4
    env = BoxState(task, source="fcn", segmenter=Scripted(seen), hold_steps=10, hold_drop_centred=2)
    outputs = [env.reset(seed=0)] + [env.step(0) for _ in range(9)]
    held = [out[-1]["box_held"] for out in outputs]
    assert held == [False, True, True, False, False, False, True, True, True, True]  # centred: 2 steps; border: all
    assert not torch.as_tensor(outputs[3][0]).any() and not torch.as_tensor(outputs[4][0]).any()  # dropped
    batched = BoxState(task, source="fcn", segmenter=Scripted(seen), hold_steps=10, hold_drop_centred=1)
    batched._hold(torch.tensor([[0.45, 0.45, 0.1, 0.1], [0.0, 0.45, 0.1, 0.1]]))  # one centred, one at the border
    held_now = []
    for _ in range(3):
        batched._hold(torch.zeros(2, 4))
        held_now.append(batched._held_now.tolist())
    assert held_now == [[True, True], [False, True], [False, True]]  # each env's own count: the centred one dropped
    for bad in (-1, 1.5):
        with pytest.raises(ValueError, match=f"hold_drop_centred={bad} must be an integer of at least 0"):
            BoxState(task, source="fcn", segmenter=Scripted(seen), hold_steps=10, hold_drop_centred=bad)
    with pytest.raises(ValueError, match="box_hold_drop_centred=4 must be .* needs box_hold_steps > 0"):
        EnvConfig(box_hold_drop_centred=4)


def test_a_held_box_that_follows_the_camera_moves_as_the_ground_truths_box_does():
    """Anchored on the floor where the box was seen and projected with the next step's camera, the box lands where
    the ground truth's box is after that step (the real renderer, steps of every direction)."""
    env = BoxState(
        mav.DiscreteDirections(cached_task(start_pose="search", placement="fixed")),
        with_mask_stats=True,
        hold_steps=3,
        hold_follows_camera=True,
    )
    obs, _ = env.reset(seed=0)
    compared = 0
    for action in [0, 0, 0, 1, 1, 1, 1, 1, 2, 2, 3, 3, 4, 5, 5]:
        before, camera = obs[0].numpy().astype(np.float64), env._camera
        obs, *_ = env.step(action)
        now = obs[0].numpy()
        inside = lambda box: box[2] > 0 and box[0] > 0.02 and box[0] + box[2] < 0.98  # noqa: E731
        if inside(before) and inside(now):
            moved, in_front = moved_box(before[None], floor_anchor(before[None], *camera), *env._camera)
            assert in_front.all()
            centre = lambda box: box[:2] + box[2:4] / 2  # noqa: E731
            assert np.abs(centre(moved[0]) - centre(now)).max() < 0.02  # a step moves it ~0.1
            np.testing.assert_allclose(moved[0, 5:], now[5:], atol=0.02)  # the centroid's offset too
            compared += 1
    assert compared >= 5


def test_a_held_box_that_follows_the_camera_stays_at_the_border_the_target_left_by():
    class SeenOnce:  # a segmenter that sees a box below the image centre once, then nothing
        def __init__(self):
            self.calls = 0

        def predict_with_presence(self, scene, target, largest_component):
            mask = torch.zeros(1, *scene.shape[1:3], dtype=torch.bool)
            if self.calls == 0:
                mask[0, 32:48, 24:40] = True
            self.calls += 1
            return mask, mask.flatten(1).any(1).float()

    task = mav.DiscreteDirections(cached_task(start_pose="search", placement="fixed", obs_mode="rgb"))
    env = BoxState(task, "fcn", with_mask_stats=True, segmenter=SeenOnce(), hold_steps=8, hold_follows_camera=True)
    outputs = [env.reset(seed=0)] + [env.step(0) for _ in range(9)]  # the camera steps left: the scene moves right
    boxes = np.stack([torch.as_tensor(out[0]).reshape(-1).numpy() for out in outputs])
    assert [bool(out[-1]["box_held"]) for out in outputs] == [False] + [True] * 8 + [False]
    centre_x = boxes[:9, 0] + boxes[:9, 2] / 2
    assert (np.diff(centre_x[:5]) > 0.05).all()  # it moves as the scene does, until the border cuts it
    assert np.isclose(boxes[8, 0] + boxes[8, 2], 1.0) and np.isclose(boxes[8, 5], 0.5)  # at the right border
    assert boxes[8, 4] < boxes[0, 4]  # its share: the part still in view
    assert not boxes[9].any()  # the hold's steps are over
    # batched: an env that has seen nothing yet holds nothing, beside one whose box is held
    batched = BoxState(task, "fcn", segmenter=SeenOnce(), hold_steps=2, hold_follows_camera=True)
    extrinsic, intrinsic, width = env._camera
    batched._camera = (np.repeat(extrinsic, 2, 0), np.repeat(intrinsic, 2, 0), width)
    seen = torch.tensor([[0.375, 0.5, 0.25, 0.25], [0.0, 0.0, 0.0, 0.0]])
    batched._hold(seen)
    held = batched._hold(torch.zeros(2, 4))  # the same camera: the box stays where it was
    assert batched._held_now.tolist() == [True, False] and not held[1].any()
    torch.testing.assert_close(held[0], seen[0])
    with pytest.raises(ValueError, match="it needs hold_steps > 0"):
        BoxState(task, "fcn", segmenter=SeenOnce(), hold_follows_camera=True)
    with pytest.raises(ValueError, match="box_hold_follows_camera moves a held box with the camera"):
        mav.EnvConfig(box_hold_follows_camera=True)
    assert EnvConfig().as_dqn_deployed().box_hold_follows_camera  # the shipped DQNs' deployment


def test_rollout_frames_name_what_each_pixel_shows_and_attribute_false_positives(tmp_path):
    from mani_active_vision.evaluation.rollout_frames import (
        FLOOR,
        OCCLUDER,
        RELATIONS,
        ROBOT,
        RolloutFramesConfig,
        attribute_false_positives,
        collect_rollout_frames,
        slot_relations,
    )

    red, blue = (1.0, 0.0, 0.0), (0.0, 0.0, 1.0)
    relations = slot_relations(["duck", "duck", "duck", "mug", "cup"], [red, red, blue, red, blue])
    assert [RELATIONS[r] for r in relations] == [
        "target",
        "identical twin",
        "same shape",
        "same colour",
        "other object",
    ]

    config = RolloutFramesConfig(sources=("servo_sky",), episodes_per_source=1, frame_stride=25, image_size=32)
    manifest = collect_rollout_frames(str(tmp_path), config, progress=False)
    data = load_segmentation_data(str(tmp_path))
    assert manifest["num_samples"] == len(data["mask"]) == 5  # steps 0, 25, 50, 75, 100
    assert data["scene"].shape == (5, 32, 32, 3) and data["objects"].shape == (5, 32, 32)
    np.testing.assert_array_equal(data["mask"], data["objects"] == 1)  # slot 0, the target, is value 1
    assert data["relations"][0, 0] == RELATIONS.index("target") and list(data["step"]) == [0, 25, 50, 75, 100]

    objects = np.full((3, 4, 4), FLOOR, np.uint8)
    objects[:, :2, :2] = 3  # slot 2 is in view
    objects[:, 3, :] = ROBOT
    objects[:, 2, 2:] = OCCLUDER
    fake = {
        "mask": np.zeros((3, 4, 4), bool),
        "objects": objects,
        "relations": np.array([[0, 1, 3, 4, 4]] * 3, np.int8),
    }  # slot 2 has the target's colour
    pred = np.zeros((3, 4, 4), bool)
    pred[0, :2, :2] = True  # on the same-colour distractor
    pred[1, 3, :] = True  # on the robot
    pred[2, 2, 2:] = True  # on a panel
    assert attribute_false_positives(pred, fake) == {
        "identical twin": 0,
        "same shape": 0,
        "same colour": 1,
        "other object": 0,
        "floor": 0,
        "occluder": 1,
        "robot": 1,
    }
