"""The Rerun recorder: files verify, hold the expected rows per entity and the blueprint, survive
exceptions and Ctrl-C, and an unwritable path fails before the rollout."""

import os
import signal
import subprocess
import sys
import time
import warnings
from collections import Counter

import gymnasium as gym
import numpy as np
import pytest
import rerun as rr
import rerun.chunk
from conftest import ROOT, cached_task

import mani_active_vision as mav
from mani_active_vision.box_state import BoxState
from mani_active_vision.envs import ENV_ID, EnvConfig, make_env
from mani_active_vision.recording import RerunRecorder, RerunVectorRecorder, blueprint
from mani_active_vision.recording.screenshots import screenshots


@pytest.fixture(autouse=True)
def strict_mode():
    """Any logging mistake (e.g. a channels-first image) raises instead of writing garbage with a warning."""
    rr.set_strict_mode(True)
    yield
    rr.set_strict_mode(False)


def fresh_env():
    # Not the cached conftest env: closing the recorder closes the env it wraps.
    return make_env(EnvConfig(start_pose="search", box_source="none"))


def verify(path):
    result = subprocess.run([sys.executable, "-m", "rerun", "rrd", "verify", str(path)], capture_output=True, text=True)
    assert result.returncode == 0, result.stderr
    return result


def temporal_rows(path) -> Counter:
    rows = Counter()
    for chunk in rr.chunk.RrdReader(str(path)).stream().to_chunks():
        if not chunk.is_static:
            rows[str(chunk.entity_path).lstrip("/")] += chunk.num_rows
    return rows


def column_by_step(path, entity, column):
    """{step: value} of one component column of an entity, read back from the file."""
    values = {}
    for chunk in rr.chunk.RrdReader(str(path)).stream().to_chunks():
        if str(chunk.entity_path).lstrip("/") == entity and not chunk.is_static:
            batch = chunk.to_record_batch()
            if column in batch.schema.names:
                for step, value in zip(batch.column("step").to_pylist(), batch.column(column).to_pylist()):
                    values[step] = value
    return values


def test_short_recording_verifies_with_expected_rows_and_blueprint(tmp_path):
    path = tmp_path / "short.rrd"
    box_state = BoxState(fresh_env())  # the recorder logs its mask (the ground truth's here, the FCN's with "fcn")
    env = RerunRecorder(box_state, str(path))
    actions = []
    try:
        for episode, steps in enumerate((5, 3)):
            env.reset(seed=episode)
            for t in range(steps):
                actions.append(t % len(mav.DIRECTIONS))
                env.step(actions[-1])
        gt_mask = box_state.last_mask[0].numpy()
        target_id = int(env.unwrapped.target_seg_id[0])
        segmentation = env.unwrapped._hand_camera_images()["segmentation"][0, ..., 0].numpy()
    finally:
        env.close()
    verify(path)
    observations, steps = 2 + 8, 8
    rows = temporal_rows(path)
    camera = "world/env0/camera"
    assert rows[f"{camera}/image/rgb"] == observations
    assert rows[f"{camera}/image/segmentation"] == observations
    assert rows[f"{camera}/image/target_box"] == observations  # ground truth, from info
    assert rows[f"{camera}/image/ground_truth_mask"] == observations  # the BoxState's mask
    assert rows[f"{camera}/image/ground_truth_mask_box"] == observations
    assert rows[camera] == observations  # Transform3D
    assert rows["world/env0/ee_path"] == observations
    for entity in ("env0/action", "env0/reward", "env0/success", "env0/target_fraction"):
        assert rows[entity] == steps, entity
    assert rows["env0/target_image"] == 2
    assert rows[f"{camera}/image"] == 2  # a Pinhole per episode
    assert rows["env0/outcome"] == 4  # two starts, one "reset" and one "interrupted" end
    # the global step timeline: one tick per observation; actions are logged under their names
    logged_actions = column_by_step(path, "env0/action", "TextLog:text")
    assert sorted(logged_actions) == [1, 2, 3, 4, 5, 7, 8, 9]
    assert [text[0].split(" ")[0] for _, text in sorted(logged_actions.items())] == [mav.DIRECTIONS[a] for a in actions]
    # the last mask logged is the BoxState's, which is the target's pixels of the segmentation
    masks = column_by_step(path, f"{camera}/image/ground_truth_mask", "SegmentationImage:buffer")
    assert np.array_equal(np.array(masks[9][0], np.uint8).reshape(64, 64), gt_mask.astype(np.uint8))
    assert np.array_equal(gt_mask, segmentation == target_id)
    assert rr.chunk.RrdReader(str(path)).blueprints(), "no blueprint stored in the file"


def test_no_mask_entity_without_a_box_state_and_raw_images(tmp_path):
    path = tmp_path / "raw.rrd"
    with RerunRecorder(fresh_env(), str(path), image_format="raw") as env:
        env.reset(seed=0)
        env.step(0)
    verify(path)
    rows = temporal_rows(path)
    assert rows["world/env0/camera/image/rgb"] == 2
    assert not any("mask" in entity for entity in rows)
    rgb = column_by_step(path, "world/env0/camera/image/rgb", "Image:buffer")
    assert len(rgb[1][0]) == 64 * 64 * 3  # raw pixels, not JPEG


def test_exception_mid_rollout_leaves_a_valid_file(tmp_path):
    path = tmp_path / "crash.rrd"
    with pytest.raises(RuntimeError, match="policy crashed"), RerunRecorder(fresh_env(), str(path)) as env:
        env.reset(seed=0)
        for t in range(10):
            if t == 3:
                raise RuntimeError("policy crashed")
            env.step(0)
    verify(path)
    rows = temporal_rows(path)
    assert rows["world/env0/camera/image/rgb"] == 4 and rows["env0/action"] == 3
    outcomes = column_by_step(path, "env0/outcome", "TextLog:text")
    assert "interrupted" in outcomes[3][0]


def test_ctrl_c_leaves_a_valid_file(tmp_path):
    path = tmp_path / "interrupted.rrd"
    process = subprocess.Popen(
        [
            sys.executable,
            os.path.join(ROOT, "baselines", "record.py"),
            "--episodes",
            "50",
            "--env.image-size",
            "64",
            "--out",
            str(path),
        ],
        cwd=ROOT,
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
    )
    try:
        deadline = time.monotonic() + 180
        while not (path.exists() and path.stat().st_size > 100_000):  # a few dozen steps are written
            assert process.poll() is None, process.stdout.read()
            assert time.monotonic() < deadline, "the recording did not grow"
            time.sleep(0.5)
        process.send_signal(signal.SIGINT)
        output, _ = process.communicate(timeout=60)
    finally:
        if process.poll() is None:
            process.kill()
    assert process.returncode != 0 and "KeyboardInterrupt" in output
    verify(path)
    rows = temporal_rows(path)
    assert rows["env0/action"] > 10
    # the episode loop stops between steps: every step is logged whole
    assert rows["world/env0/camera/image/rgb"] == rows["env0/action"] + rows["env0/target_image"]
    outcomes = column_by_step(path, "env0/outcome", "TextLog:text")
    last = outcomes[max(outcomes)][0]
    # the episode in progress is closed as interrupted; a Ctrl-C between two episodes leaves none in progress
    assert "interrupted" in last or ("ended" in last and "starts" not in last), last


def test_unwritable_path_fails_before_the_rollout(tmp_path):
    env = mav.DiscreteDirections(cached_task(start_pose="search"))  # never closed here: the cached env
    blocker = tmp_path / "a_file"
    blocker.write_text("")
    with pytest.raises(OSError, match="cannot write the recording"):
        RerunRecorder(env, str(blocker / "x.rrd"))  # its folder would have to be a file
    with pytest.raises(ValueError, match="must end in .rrd"):
        RerunRecorder(env, str(tmp_path / "x.txt"))
    with pytest.raises(ValueError, match="image_format='png' is not one of: jpeg, raw"):
        RerunRecorder(env, str(tmp_path / "x.rrd"), image_format="png")


def test_vector_env_with_autoreset_is_recorded_per_env(tmp_path):
    """A gymnasium vector env (in-process here; AsyncVectorEnv takes the same path) of two 4-step
    episodes: the step after an episode's end brings the next episode's first observation."""
    from mani_skill.utils.wrappers.gymnasium import CPUGymWrapper

    def make():
        return CPUGymWrapper(
            mav.DiscreteDirections(
                gym.make(ENV_ID, **EnvConfig(start_pose="search", max_episode_steps=4).task_kwargs())
            )
        )

    path = tmp_path / "vector.rrd"
    with RerunVectorRecorder(gym.vector.SyncVectorEnv([make, make]), str(path)) as env:
        env.reset(seed=0)
        for t in range(7):
            env.step(np.array([t % 6, (t + 1) % 6]))
    verify(path)
    rows = temporal_rows(path)
    for i in range(2):
        assert rows[f"world/env{i}/camera/image/rgb"] == 8
        assert rows[f"env{i}/target_image"] == 2  # the autoreset started a second episode
        assert sorted(column_by_step(path, f"env{i}/action", "TextLog:text")) == [1, 2, 3, 4, 6, 7]  # step 5 is a reset
        episodes = column_by_step(path, f"world/env{i}/camera/image/rgb", "episode")
        assert [episodes[step] for step in range(8)] == [0, 0, 0, 0, 0, 1, 1, 1]
        assert rows[f"env{i}/outcome"] == 4  # two starts, one end, one interrupted


def test_blueprint_has_one_tab_per_env():
    assert len(blueprint(3).root_container.contents) == 3


def test_screenshots_at_chosen_steps(tmp_path):
    path = tmp_path / "shot.rrd"
    with RerunRecorder(fresh_env(), str(path)) as env:
        env.reset(seed=0)
        for _ in range(4):
            env.step(mav.DIRECTIONS.index("forward"))
    from PIL import Image

    with warnings.catch_warnings():
        warnings.simplefilter("error")  # a view that cannot show something (e.g. no pinhole) fails the test
        (png,) = screenshots(str(path), [3], str(tmp_path / "png"))
    image = np.asarray(Image.open(png).convert("RGB"))
    assert image.shape[0] > 300 and image.shape[1] > 300
    assert image.std() > 10  # views were drawn, not a blank window
    with pytest.raises(ValueError, match="outside the recording's steps 0..4"):
        screenshots(str(path), [99], str(tmp_path / "png"))


def test_occluders_are_logged_as_boxes_in_the_3d_view(tmp_path):
    path = tmp_path / "occluded.rrd"
    with RerunRecorder(make_env(EnvConfig(start_pose="search", box_source="none", occluders=2)), str(path)) as env:
        env.reset(seed=0)
        env.step(0)
    verify(path)
    rows = temporal_rows(path)
    assert rows["world/env0/occluders"] == 1 and "world/env1/occluders" not in rows
    centers = column_by_step(path, "world/env0/occluders", "Boxes3D:centers")
    assert len(next(iter(centers.values()))) == 2
    assert "world/env0/objects" in rows
