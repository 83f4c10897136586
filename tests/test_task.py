"""ActiveVisionFind-v0: registration, observations, reward, determinism, object sets, bad options."""

import shutil
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest
import torch
from conftest import cached_task
from mani_skill.utils.building.ground import build_ground
from mani_skill.utils.structs import Link

import mani_active_vision as mav
import mani_active_vision.tasks.active_vision_find as task
from mani_active_vision import wrist_shader
from mani_active_vision.boxes import silhouette, silhouette_iou
from mani_active_vision.envs import EnvConfig
from mani_active_vision.evaluation.views import aimed_qpos
from mani_active_vision.objects import object_set


def test_registered_and_observation_layout():
    env = cached_task(start_pose="search")
    obs, info = env.reset(seed=0)
    cam = obs["sensor_data"]["hand_camera"]
    assert cam["rgb"].shape == (1, 64, 64, 3) and cam["rgb"].dtype == torch.uint8
    assert cam["segmentation"].shape == (1, 64, 64, 1) and cam["segmentation"].dtype == torch.int16
    target = obs["extra"]["target_image"]
    assert target.shape == (1, 64, 64, 3) and target.dtype == torch.uint8
    for key in ("success", "target_fraction", "target_visible", "target_bbox", "refused", "refused_count"):
        assert key in info
    assert info["target_bbox"].shape == (1, 4)
    assert env.unwrapped.control_mode == "pd_ee_delta_pos"
    assert env.unwrapped.target is env.unwrapped.objects[0]


def test_target_image_shows_the_target_alone_centred():
    env = cached_task()
    for seed in range(3):
        obs, _ = env.reset(seed=seed)
        image = obs["extra"]["target_image"][0].numpy().astype(int)
        alone = (image != 128).any(-1)  # non-target pixels are exactly grey
        share = alone.mean()
        assert 0.05 < share < 0.9, share  # zoomed: a large part of the image, not cut off
        assert not (alone[0].any() or alone[-1].any() or alone[:, 0].any() or alone[:, -1].any())
        ys, xs = np.nonzero(alone)
        size = image.shape[0]
        assert abs(xs.mean() + 0.5 - size / 2) < 0.15 * size and abs(ys.mean() + 0.5 - size / 2) < 0.15 * size


def test_target_image_shows_the_side_the_robot_sees():
    # The camera aimed at the target from above its line of sight sees the outline the picture shows
    # (baselines/target_view_match.py: silhouette IoU 0.76-0.85 against 0.38-0.45 for same-colour look-alikes).
    env = cached_task(**EnvConfig(image_size=128).task_kwargs())
    base = env.unwrapped
    for seed in range(3):
        obs, _ = env.reset(seed=seed)
        picture = silhouette((obs["extra"]["target_image"][0].numpy() != 128).any(-1))
        base.agent.robot.set_qpos(aimed_qpos(base.objects[0].pose.p[0, :2].numpy(), 0.3))
        base.forget_view()
        view = base._hand_camera_images()["segmentation"][0, ..., 0] == base.target_seg_id[0]
        assert silhouette_iou(silhouette(view.numpy()), picture) > 0.6, seed


def test_reward_is_share_of_target_pixels():
    env = mav.DiscreteDirections(cached_task(start_pose="search", placement="fixed"))
    obs, _ = env.reset(seed=3)
    seen = 0
    for step in range(25):
        obs, reward, terminated, truncated, info = env.step(0 if step < 12 else 2)
        seg = obs["sensor_data"]["hand_camera"]["segmentation"][0, ..., 0]
        expected = (seg == env.unwrapped.target_seg_id[0]).float().mean()
        assert float(reward[0]) == pytest.approx(float(expected), abs=1e-7)
        assert float(info["target_fraction"][0]) == pytest.approx(float(expected), abs=1e-7)
        assert bool(info["target_visible"][0]) == bool(expected > 0)
        seen += int(expected > 0)
    assert seen > 0, "the fixed layout's target should come into view while orbiting left"


def test_reward_modes():
    env = mav.DiscreteDirections(cached_task(start_pose="search", placement="fixed", reward_mode="normalized_dense"))
    env.reset(seed=0)
    for _ in range(6):
        _, reward, _, _, info = env.step(0)
        assert 0.0 <= float(reward[0]) <= 1.0
        expected = min(float(info["target_fraction"][0]) / env.unwrapped.success_fraction, 1.0)
        assert float(reward[0]) == pytest.approx(expected, rel=1e-5)


def _rollout(env, seed, actions):
    obs, info = env.reset(seed=seed)
    frames, rewards = [obs["sensor_data"]["hand_camera"]["rgb"].clone()], []
    for a in actions:
        obs, reward, *_ = env.step(a)
        frames.append(obs["sensor_data"]["hand_camera"]["rgb"].clone())
        rewards.append(float(reward[0]))
    return torch.stack(frames), rewards, obs["extra"]["target_image"].clone(), list(env.unwrapped.object_names[0])


def test_same_seed_same_episode_and_different_seeds_differ():
    env = mav.DiscreteDirections(cached_task(start_pose="search"))
    actions = [0, 0, 2, 4, 1, 3]
    a = _rollout(env, 7, actions)
    b = _rollout(env, 7, actions)
    c = _rollout(env, 8, actions)
    assert torch.equal(a[0], b[0]) and a[1] == b[1] and torch.equal(a[2], b[2]) and a[3] == b[3]
    assert a[3] != c[3] or not torch.equal(a[0], c[0])


def test_object_sets_are_disjoint():
    train, unseen = object_set("train"), object_set("unseen")
    assert len(train) == 800 and len(unseen) == 204
    assert not {m.mesh_path for m in train} & {m.mesh_path for m in unseen}
    env = cached_task(object_set="unseen", num_objects=3)
    env.reset(seed=0)
    names = {m.name for m in unseen}
    assert set(env.unwrapped.object_names[0]) <= names


@pytest.mark.parametrize(
    "kwargs, words",
    [
        (dict(object_set="foo"), ["object_set='foo'", "train", "unseen", "primitives"]),
        (dict(placement="somewhere"), ["placement='somewhere'", "random", "fixed"]),
        (dict(start_pose="ground"), ["start_pose='ground'", "sky", "search"]),
        (dict(obs_mode="pointcloud"), ["obs_mode='pointcloud'", "rgb+segmentation", "state"]),
        (dict(control_mode="pd_joint_pos"), ["control_mode='pd_joint_pos'", "pd_ee_delta_pos"]),
        (dict(reward_mode="shaped"), ["reward_mode='shaped'", "dense", "sparse"]),
        (dict(num_objects=0), ["num_objects=0"]),
        (dict(step_size=0.5), ["step_size=0.5"]),
    ],
)
def test_bad_options_are_clear_errors(kwargs, words):
    with pytest.raises(ValueError) as err:
        gym.make("ActiveVisionFind-v0", render_backend="cpu", **kwargs)
    for word in words:
        assert word in str(err.value)


def test_obs_modes_rgb_and_state():
    env = cached_task(obs_mode="rgb", start_pose="search")
    obs, info = env.reset(seed=0)
    assert set(obs["sensor_data"]["hand_camera"]) == {"rgb"}
    _, reward, *_ = env.step(np.zeros(3, dtype=np.float32))
    assert float(reward[0]) == pytest.approx(float(env.unwrapped.evaluate()["target_fraction"][0]))
    env = cached_task(obs_mode="state", start_pose="search")
    obs, _ = env.reset(seed=0)
    assert obs.ndim == 2 and obs.dtype == torch.float32 and torch.isfinite(obs).all()


def test_success_does_not_end_the_episode_unless_asked():
    env = cached_task(start_pose="search")
    env.reset(seed=0)
    base = env.unwrapped
    default_fraction = base.success_fraction
    base.success_fraction = 0.0  # make every visible, centred frame a success
    try:
        _, _, terminated, _, info = env.step(np.zeros(3, dtype=np.float32))
        assert not bool(terminated[0])
        base.terminate_on_success = True
        _, _, terminated, _, info = env.step(np.zeros(3, dtype=np.float32))
        assert bool(terminated[0]) == bool(info["success"][0])
    finally:
        base.success_fraction, base.terminate_on_success = default_fraction, False


def test_no_distractor_is_an_identical_twin_of_the_target():
    from mani_active_vision.evaluation.rollout_frames import RELATIONS, slot_relations

    env = cached_task(object_set="primitives", num_objects=8)  # palette colours: where a twin could arise
    base, same_shape = env.unwrapped, 0
    for seed in range(25):
        env.reset(seed=seed)
        relations = slot_relations(base.object_names[0], base.object_colors[0])
        assert RELATIONS.index("identical twin") not in relations, (seed, base.object_names[0], base.object_colors[0])
        same_shape += int((relations == RELATIONS.index("same shape")).sum())
    assert same_shape > 10  # the look-alikes are still there, in other colours


def test_the_wrist_shader_pack_is_written_once_and_reused_not_taken_from_a_folder_that_differs(monkeypatch, tmp_path):
    """Every process finds the one-pass pack in the folder named by its contents (workers exit without clean-up,
    so a folder per process would pile up); a folder of that name that holds something else is not used."""
    monkeypatch.setattr(wrist_shader.tempfile, "tempdir", str(tmp_path))
    folder = wrist_shader.derived_pack.__wrapped__()
    assert folder.parent == tmp_path and wrist_shader.derived_pack.__wrapped__() == folder
    assert [p.name for p in tmp_path.iterdir()] == [folder.name]  # nothing else left behind
    gbuffer = (folder / "gbuffer.frag").read_text()
    assert "specularIBL(fresnel" not in gbuffer and "outColorRaw" not in gbuffer and "out vec4 outColor;" in gbuffer
    (folder / "gbuffer.frag").write_text(gbuffer.replace("outColor", "outColorRaw"))  # tampered with
    private = wrist_shader.derived_pack.__wrapped__()
    assert private != folder and private.parent == tmp_path and (private / "gbuffer.frag").read_text() == gbuffer
    monkeypatch.setattr(wrist_shader.tempfile, "tempdir", str(tmp_path / "missing"))  # nowhere to write: `minimal`
    with pytest.warns(UserWarning, match="uses SAPIEN's 'minimal' shader pack"):
        assert wrist_shader.derived_pack.__wrapped__() is None
    monkeypatch.setattr(wrist_shader.tempfile, "tempdir", str(tmp_path / "cleaned"))
    (tmp_path / "cleaned").mkdir()
    wrist_shader.derived_pack.cache_clear()
    try:
        first = Path(wrist_shader.wrist_shader_config().shader_pack)
        shutil.rmtree(first)  # the temporary directory cleaned while the process runs: written again
        assert Path(wrist_shader.wrist_shader_config().shader_pack) == first and (first / "gbuffer.frag").exists()
    finally:
        wrist_shader.derived_pack.cache_clear()


def test_culling_the_floor_in_pieces_and_the_wrist_shader_leave_every_pixel_as_it_was(monkeypatch):
    """Same seed, same actions: the task renders the same rgb, segmentation, target image and reward as with
    ManiSkill's one-mesh floor, no culling and SAPIEN's `minimal` shader pack on the wrist camera (as it
    rendered before), also where the robot's base is in view, and `render()` after culled frames shows
    everything again."""
    moves = ["down"] * 6 + ["backward"] * 6 + list(np.random.default_rng(0).choice(mav.DIRECTIONS, 20))

    def rollout(cull: bool, shader_pack: str | None = None):
        kwargs = mav.EnvConfig(start_pose="search").task_kwargs()
        if shader_pack is not None:  # ManiSkill's way to choose a camera's shader
            kwargs["sensor_configs"]["hand_camera"]["shader_pack"] = shader_pack
        env = mav.DiscreteDirections(gym.make("ActiveVisionFind-v0", render_mode="rgb_array", **kwargs))
        env.unwrapped.cull = cull
        frames = dict(target=[], rgb=[], segmentation=[], reward=[], human=[])
        for seed in (0, 1):  # the second reset builds a new scene
            obs, _ = env.reset(seed=seed)
            frames["target"].append(obs["extra"]["target_image"])
            for move in moves:
                obs, reward, *_ = env.step(mav.DIRECTIONS.index(move))
                frames["rgb"].append(obs["sensor_data"]["hand_camera"]["rgb"])
                frames["segmentation"].append(obs["sensor_data"]["hand_camera"]["segmentation"])
                frames["reward"].append(reward)
            frames["human"].append(env.render())
        links = [i for i, part in env.unwrapped.segmentation_id_map.items() if isinstance(part, Link)]
        pack = env.unwrapped._sensors["hand_camera"].config.shader_pack
        env.close()
        return {k: torch.cat(v) for k, v in frames.items()}, links, pack

    now, links, pack = rollout(cull=True)
    assert pack == str(wrist_shader.derived_pack()), "the wrist camera does not use the one-pass pack"
    with monkeypatch.context() as patch:
        patch.setattr(task, "build_floor", build_ground)
        before, _, pack = rollout(cull=False, shader_pack="minimal")
    assert pack == "minimal"
    for key in now:
        assert torch.equal(now[key], before[key]), key
    assert torch.isin(now["segmentation"], torch.tensor(links)).any(), "the robot never came into view"
