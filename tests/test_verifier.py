"""The FCN's second stage: crops around candidate regions, which regions it keeps, and its checkpoint."""

import dataclasses
import json

import numpy as np
import pytest
import torch

from mani_active_vision.agents.fcn import (
    FCNConfig,
    OneShotFCN,
    load_checkpoint,
    normalize_images,
    save_checkpoint,
    target_pixels,
)
from mani_active_vision.agents.verifier import (
    at_border,
    candidate_crops,
    keep_verified,
    mask_box,
    near_previous,
    region_boxes,
    regions,
    square_crops,
    target_crops,
)


def _image_with_square(size: int, corner: tuple[int, int], side: int) -> torch.Tensor:
    image = torch.zeros(1, 1, size, size)
    image[..., corner[0] : corner[0] + side, corner[1] : corner[1] + side] = 1.0
    return image


def test_square_crops_frame_the_box_whatever_its_size_and_place():
    for size, corner, side in ((128, (10, 70), 20), (128, (60, 5), 40), (64, (30, 30), 12)):
        image = _image_with_square(size, corner, side)
        box = torch.tensor([[corner[1], corner[0], corner[1] + side, corner[0] + side]], dtype=torch.float32)
        crop = square_crops(image, box, 32, margin=2.0)[0, 0]
        inside = crop > 0.5  # the square fills the middle half of the crop, at any scale
        assert inside[8:24, 8:24].float().mean() > 0.95 and inside.float().mean() == pytest.approx(0.25, abs=0.04)
    outside = square_crops(torch.ones(1, 1, 64, 64), torch.tensor([[0.0, 0.0, 20.0, 20.0]]), 32, margin=2.0)
    assert outside[0, 0, :4, :4].abs().max() < 1e-6 and outside[0, 0, -4:, -4:].min() > 0.99  # off the image: 0


def test_crops_of_one_image_in_one_pass_are_those_of_a_copy_per_box_bit_for_bit():
    """`square_crops(..., image=)` samples one image's boxes in one tall grid, without a copy of the image per box;
    several images go through the copy per box."""
    generator = torch.Generator().manual_seed(0)
    for num_images, num_boxes in ((1, 1), (1, 4), (3, 5)):
        images = torch.rand(num_images, 3, 128, 128, generator=generator) - 0.5
        corner = torch.rand(num_boxes, 2, generator=generator) * 110
        boxes = torch.cat([corner, corner + 1 + torch.rand(num_boxes, 2, generator=generator) * 60], 1).floor()
        image = torch.randint(num_images, (num_boxes,), generator=generator)
        one_pass = square_crops(images, boxes, 32, image=image)
        assert one_pass.shape == (num_boxes, 3, 32, 32) and one_pass.is_contiguous()
        assert torch.equal(one_pass, square_crops(images[image], boxes, 32))


def test_regions_and_their_boxes_largest_first():
    mask = np.zeros((32, 32), bool)
    mask[2:4, 2:4] = True  # 4 px
    mask[10:20, 5:8] = True  # 30 px
    mask[25:30, 25:30] = True  # 25 px
    labels, ids, sizes = regions(mask, max_regions=2)
    assert [int((labels == k).sum()) for k in ids] == sizes == [30, 25]
    assert region_boxes(labels, ids).tolist() == [[5, 10, 8, 20], [25, 25, 30, 30]]
    assert regions(np.zeros((8, 8), bool), 4)[1] == []
    empty_and_square = torch.zeros(2, 16, 16, dtype=torch.bool)
    empty_and_square[1, 4:6, 3:9] = True
    assert mask_box(empty_and_square).tolist() == [[0, 0, 16, 16], [3, 4, 9, 6]]


def test_keep_verified_keeps_the_regions_over_the_threshold_and_reports_the_best():
    masks = np.zeros((3, 16, 16), bool)
    masks[0, 1:3, 1:3] = masks[0, 8:12, 8:12] = True  # two regions
    masks[1, 5:7, 5:7] = True  # one
    scene = torch.zeros(3, 3, 16, 16)
    found = candidate_crops(scene, masks, max_regions=4, crop=8)
    assert found["image"].tolist() == [0, 0, 1] and found["scene_crops"].shape == (3, 3, 8, 8)
    kept, presence = keep_verified(found, torch.tensor([0.9, 0.3, 0.2]), threshold=0.5, num_images=3)
    assert kept[0].sum() == 16 and kept[0, 9, 9] and not kept[0, 1, 1]  # the larger region, scored 0.9
    assert not kept[1].any() and not kept[2].any()
    assert presence.tolist() == pytest.approx([0.9, 0.2, 0.0])
    both, _ = keep_verified(found, torch.tensor([0.6, 0.7, 0.2]), threshold=0.5, num_images=3)
    best, _ = keep_verified(found, torch.tensor([0.6, 0.7, 0.2]), threshold=0.5, num_images=3, best_only=True)
    assert both[0].sum() == 20 and best[0].sum() == 4 and best[0, 1, 1]  # the smaller region, scored higher


def test_tracking_lowers_the_bar_only_for_a_region_near_the_previous_box():
    masks = np.zeros((2, 32, 32), bool)
    masks[0, 4:8, 4:8] = masks[0, 20:30, 20:30] = True  # a small region near the tracked box, a larger far one
    masks[1, 4:8, 4:8] = True
    found = candidate_crops(torch.zeros(2, 3, 32, 32), masks, max_regions=4, crop=8)
    previous = torch.zeros(2, 32, 32, dtype=torch.bool)
    previous[0, 6:12, 6:12] = True  # image 0 kept a box overlapping its small region; image 1 kept nothing
    near = near_previous(found["boxes"], found["image"], previous)
    assert near.tolist() == [False, True, False]  # regions: image 0 large, image 0 small, image 1
    probability = torch.tensor([0.8, 0.6, 0.6])
    threshold = torch.where(near, 0.5, 0.9)
    kept, presence = keep_verified(found, probability, threshold, num_images=2, best_only=True)
    assert kept[0].sum() == 16 and kept[0, 5, 5]  # the tracked region, though the far one scores higher
    assert not kept[1].any() and presence.tolist() == pytest.approx([0.8, 0.6])
    far = torch.zeros(1, 32, 32, dtype=torch.bool)
    far[0, 0:2, 28:32] = True  # 4 wide: grown by 2 px on every side it stays clear of both regions
    assert not near_previous(found["boxes"][:2], found["image"][:2], far).any()


def test_predict_keeps_what_the_verifier_accepts_and_the_checkpoint_carries_it(tmp_path):
    torch.manual_seed(0)
    model = OneShotFCN(FCNConfig(channels=(8, 8, 16), verifier_crop=16, verifier_threshold=0.5)).eval()
    rng = np.random.default_rng(0)
    scene = rng.integers(0, 256, (2, 64, 64, 3), dtype=np.uint8)
    target = np.full((2, 64, 64, 3), 128, np.uint8)
    target[:, 20:40, 24:44] = 200
    with torch.no_grad():
        model.up1.bias[1] += 50.0  # the segmentation marks every pixel: one region, the whole image
    for bias, accepted in ((20.0, True), (-20.0, False)):
        with torch.no_grad():
            model.verifier.head[-1].bias.fill_(bias)
        mask, presence = model.predict_with_presence(scene, target)
        assert bool(mask.all()) is accepted and not (mask.any() and not accepted)
        assert ((presence > 0.99) if accepted else (presence < 0.01)).all()
    path = str(tmp_path / "fcn.pt")
    save_checkpoint(path, model)
    loaded, _ = load_checkpoint(path)
    assert loaded.config.verifier_crop == 16 and torch.equal(
        loaded.verifier.head[-1].bias, model.verifier.head[-1].bias
    )
    assert torch.equal(loaded.predict(scene, target), model.predict(scene, target))
    with pytest.raises(ValueError, match="verifier_crop=12 must be 0 or a positive multiple of 8"):
        FCNConfig(verifier_crop=12)


def test_predict_tracks_a_region_whose_score_dips_under_the_threshold():
    torch.manual_seed(0)
    model = OneShotFCN(FCNConfig(channels=(8, 8, 16), verifier_crop=16, verifier_threshold=0.9)).eval()
    scene = np.random.default_rng(0).integers(0, 256, (1, 64, 64, 3), dtype=np.uint8)
    target = np.full((1, 64, 64, 3), 128, np.uint8)
    target[:, 20:40, 24:44] = 200
    with torch.no_grad():
        model.up1.bias[1] += 50.0  # one region, the whole image
        model.verifier.head[-1].weight.zero_()
        model.verifier.head[-1].bias.zero_()  # it scores 0.5
    assert not model.predict(scene, target, largest_component=True).any()
    kept = torch.ones(1, 64, 64, dtype=torch.bool)
    tracked, presence = model.predict_with_presence(
        scene, target, largest_component=True, previous=kept, thresholds=(0.0, 0.4)
    )
    assert tracked.all() and presence.item() == pytest.approx(0.5)
    # with track_below, a region covering that share of the image or more needs the acquire bar (0.9) again
    up_close = model.predict_with_presence(scene, target, True, previous=kept, thresholds=(0.0, 0.4), track_below=0.5)
    assert not up_close[0].any() and up_close[1].item() == pytest.approx(0.5)
    with pytest.raises(ValueError, match=r"track_below=1.0 must be in \[0, 1\)"):
        model.predict_with_presence(scene, target, True, previous=kept, thresholds=(0.0, 0.4), track_below=1.0)
    nothing_kept = torch.zeros_like(kept)
    assert not model.predict_with_presence(scene, target, True, previous=nothing_kept, thresholds=(0, 0.4))[0].any()
    assert (
        model.predict(scene, target, True).sum() == 0
        and model.predict_with_presence(scene, target, True, thresholds=(0.45, 0))[0].all()
    )  # a lower bar to acquire, no previous mask
    with pytest.raises(ValueError, match=r"thresholds=\(0.5, 1.2\) must be \(acquire, track\)"):
        model.predict_with_presence(scene, target, previous=kept, thresholds=(0.5, 1.2))


def test_a_large_region_cut_by_the_border_needs_only_the_cut_bar():
    torch.manual_seed(0)
    config = FCNConfig(channels=(8, 8, 16), verifier_crop=16, verifier_threshold=0.9, verifier_cut_share=0.05)
    scene = torch.from_numpy(np.random.default_rng(0).integers(0, 256, (1, 64, 64, 3), dtype=np.uint8))
    target = np.full((1, 64, 64, 3), 128, np.uint8)
    target[:, 20:40, 24:44] = 200
    target = normalize_images(torch.from_numpy(target))

    def kept(model, rows, cols):
        mask = torch.zeros(1, 64, 64, dtype=torch.bool)
        mask[0, rows, cols] = True
        with torch.inference_mode():
            return bool(model.verify(scene, target, mask, model._weights_key(), best_only=True)[0].any())

    for cut_threshold, accepted in ((0.4, True), (0.6, False)):  # the verifier scores every region 0.5
        model = OneShotFCN(dataclasses.replace(config, verifier_cut_threshold=cut_threshold)).eval()
        with torch.no_grad():
            model.verifier.head[-1].weight.zero_()
            model.verifier.head[-1].bias.zero_()
        assert kept(model, slice(0, 20), slice(30, 50)) is accepted  # 400 px (0.10 of the image), at the top
        assert not kept(model, slice(20, 40), slice(20, 40))  # as large, whole: the bar
        assert not kept(model, slice(0, 8), slice(0, 8))  # cut, but 0.016 of the image: the bar
    assert at_border(torch.tensor([[0.0, 5, 10, 10], [3, 3, 64, 10], [3, 3, 63, 63]]), (64, 64)).tolist() == [
        True,
        True,
        False,
    ]
    with pytest.raises(ValueError, match="verifier_cut_share=1.5 must be in"):
        FCNConfig(verifier_cut_share=1.5)


def test_the_border_bar_can_be_kept_to_regions_near_the_tracked_box():
    torch.manual_seed(0)
    config = FCNConfig(channels=(8, 8, 16), verifier_crop=16, verifier_threshold=0.9, verifier_cut_share=0.05)
    model = OneShotFCN(dataclasses.replace(config, verifier_cut_threshold=0.4)).eval()
    with torch.no_grad():  # the verifier scores every region 0.5: under the bars (0.9), over the border's (0.4)
        model.verifier.head[-1].weight.zero_()
        model.verifier.head[-1].bias.zero_()
    scene = torch.from_numpy(np.random.default_rng(0).integers(0, 256, (1, 64, 64, 3), dtype=np.uint8))
    target = np.full((1, 64, 64, 3), 128, np.uint8)
    target[:, 20:40, 24:44] = 200
    target = normalize_images(torch.from_numpy(target))
    mask = torch.zeros(1, 64, 64, dtype=torch.bool)
    mask[0, 20:40, 44:64] = True  # cut by the right border, 0.10 of the image
    tracked_left, tracked_right = torch.zeros_like(mask), torch.zeros_like(mask)
    tracked_left[0, 20:36, 0:8] = True  # e.g. the held box where the target left by the left border
    tracked_right[0, 20:36, 56:64] = True

    def kept(previous, near_only):
        with torch.inference_mode():
            return bool(
                model.verify(
                    scene,
                    target,
                    mask,
                    model._weights_key(),
                    best_only=True,
                    previous=previous,
                    thresholds=(0.9, 0.9),
                    border_bar_near_previous=near_only,
                )[0].any()
            )

    assert kept(tracked_left, near_only=False)  # anywhere at the border's bar
    assert not kept(tracked_left, near_only=True)  # far from the tracked box: the acquire bar
    assert kept(tracked_right, near_only=True)  # near it: the border's bar still
    assert kept(torch.zeros_like(mask), near_only=True)  # nothing tracked: the border's bar everywhere


def test_mirror_averages_the_logits_of_the_pair_and_of_both_crops_mirrored():
    torch.manual_seed(0)
    config = FCNConfig(channels=(8, 8, 16), verifier_crop=16, verifier_threshold=0.5)
    scene = torch.from_numpy(np.random.default_rng(0).integers(0, 256, (1, 64, 64, 3), dtype=np.uint8))
    target = np.full((1, 64, 64, 3), 128, np.uint8)
    target[:, 20:40, 24:34] = 200  # not symmetric: its mirror image is another crop
    target = torch.from_numpy(target)
    mask = torch.zeros(1, 64, 64, dtype=torch.bool)
    mask[0, 10:30, 5:20] = True  # one candidate region
    plain = OneShotFCN(config).eval()
    with torch.no_grad():
        plain.verifier.head[-1].weight.mul_(100.0)  # spread the untrained verifier's scores
    mirrored = OneShotFCN(dataclasses.replace(config, verifier_mirror=True)).eval()
    mirrored.load_state_dict(plain.state_dict())
    crops = candidate_crops(normalize_images(scene), mask.numpy(), 4, 16)["scene_crops"]
    target_crop = target_crops(normalize_images(target), target_pixels(normalize_images(target)), 16)
    with torch.inference_mode():
        logits = [plain.verifier(t, c)[0] for t, c in ((target_crop, crops), (target_crop.flip(-1), crops.flip(-1)))]
        assert abs(float(logits[0] - logits[1])) > 1e-3  # the two views score differently
        for model, expected in ((plain, logits[0]), (mirrored, (logits[0] + logits[1]) / 2)):
            _, presence = model.verify(scene, normalize_images(target), mask, model._weights_key(), runtime="torch")
            assert float(presence[0]) == pytest.approx(float(expected.sigmoid()), abs=1e-6)
            _, on_onnx = model.verify(
                scene, normalize_images(target), mask, model._weights_key(), runtime="onnxruntime"
            )
            assert float(on_onnx[0]) == pytest.approx(float(expected.sigmoid()), abs=1e-5)


def test_train_verifier_fine_tunes_a_shipped_verifier_from_its_weights(tmp_path, baseline_script):
    from mani_active_vision.agents.fcn import WEIGHTS_PATH
    from mani_active_vision.evaluation.rollout_frames import RolloutFramesConfig, collect_rollout_frames

    train_verifier = baseline_script("train_verifier")
    frames = tmp_path / "frames"
    config = RolloutFramesConfig(sources=("servo_over_sky",), episodes_per_source=2, frame_stride=10, occluders=1)
    collect_rollout_frames(str(frames), config, progress=False)
    args = train_verifier.Args(
        init=WEIGHTS_PATH, data_dirs=[str(frames)], run_dir=str(tmp_path / "run"), epochs=1, lr=1e-9, scales=(1,)
    )
    train_verifier.main(args)  # 2 episodes: scene seeds 405,000 (validation, every 10th) and 405,001 (training)
    assert json.loads((tmp_path / "run" / "history.json").read_text())[0]["train_loss"] > 0
    shipped, _ = load_checkpoint(WEIGHTS_PATH)
    tuned, checkpoint = load_checkpoint(str(tmp_path / "run" / "best.pt"))
    assert checkpoint["args"]["init"] == WEIGHTS_PATH
    for name, value in shipped.state_dict().items():  # the network as it was, the verifier moved by ~lr only
        atol = 1e-5 if name.startswith("verifier.") else 0.0
        torch.testing.assert_close(tuned.state_dict()[name], value, atol=atol, rtol=0.0, msg=name)
    with pytest.raises(ValueError, match="crop, regions"):
        train_verifier.main(dataclasses.replace(args, crop=16))


def test_eval_fcn_tables_the_verifier_at_other_bars(tmp_path, baseline_script):
    """At the checkpoint's own bar the table gives the main table's miss and false-positive rates; a lower bar
    accepts a superset of regions (misses fall or stay, false positives rise or stay)."""
    from mani_active_vision.evaluation.rollout_frames import RolloutFramesConfig, collect_rollout_frames

    eval_fcn = baseline_script("eval_fcn")
    frames = tmp_path / "frames"
    config = RolloutFramesConfig(episodes_per_source=1, frame_stride=10, seed=411_000)
    collect_rollout_frames(str(frames), config, progress=False)
    out = tmp_path / "eval.md"
    args = eval_fcn.Args(
        data_dirs=[str(frames)], out=str(out), examples_png=None, largest_component=True, verifier_bars=(0.3, 0.9, 0.99)
    )
    eval_fcn.main(args)
    lines = out.read_text().splitlines()
    main_row = next(line for line in lines if line.startswith(f"| {frames} |"))
    cells = [c.strip() for c in main_row.strip("|").split("|")]
    fp, miss = float(cells[7]), float(cells[9])  # the checkpoint's bar (0.9): COLUMNS' FP rate and miss rate
    rows = {
        float(c[1]): (float(c[3]), float(c[4]))
        for c in ([x.strip() for x in line.strip("|").split("|")] for line in lines)
        if len(c) == 5 and c[0] == str(frames)
    }
    assert set(rows) == {0.3, 0.9, 0.99} and rows[0.9] == (miss, fp)
    assert rows[0.3][0] <= rows[0.9][0] <= rows[0.99][0] and rows[0.3][1] >= rows[0.9][1] >= rows[0.99][1]
    assert rows[0.3] != rows[0.99]  # the bar moves something on these frames
    with pytest.raises(ValueError, match=r"\(0, 1\)"):
        eval_fcn.main(dataclasses.replace(args, verifier_bars=(1.5,)))
