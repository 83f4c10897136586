"""A two-node Ray cluster simulated on this machine (`ray.cluster_utils.Cluster`, one CPU per node): sweep
runs and vector-env actors land on both nodes, joined by address; a lost node is reported by env index."""

import os
import time

import gymnasium as gym
import numpy as np
import pytest
import ray
from ray.cluster_utils import Cluster

from mani_active_vision.ray_vec_env import RayVectorEnv
from mani_active_vision.sweep import Run, run_sweep
from mani_active_vision.vec_errors import WorkerCrashedError


@pytest.fixture(scope="module")
def cluster():
    assert not ray.is_initialized()
    cluster = Cluster(initialize_head=True, head_node_args={"num_cpus": 1, "include_dashboard": False})
    worker = cluster.add_node(num_cpus=1)
    cluster.wait_for_nodes()
    yield cluster, worker
    ray.shutdown()
    cluster.shutdown()


def test_a_sweep_joins_the_cluster_by_address_and_its_runs_land_on_both_nodes(cluster, tmp_path):
    cluster, worker = cluster

    def write(run_dir):
        time.sleep(1.0)  # long enough that the two runs overlap: one CPU per node
        os.makedirs(run_dir)
        with open(os.path.join(run_dir, "eval.json"), "w") as f:
            f.write("{}")

    ran = run_sweep([Run("a", write), Run("b", write)], str(tmp_path), address=cluster.address)
    assert set(ran.values()) == {cluster.head_node.node_id, worker.node_id}
    assert (tmp_path / "a" / "eval.json").exists() and (tmp_path / "b" / "eval.json").exists()


def test_envs_spread_over_the_nodes_and_a_lost_node_is_reported_by_env_index(cluster):
    cluster, worker = cluster
    env = RayVectorEnv([lambda: gym.make("CartPole-v1")] * 2, address=cluster.address)
    assert set(env.node_ids) == {cluster.head_node.node_id, worker.node_id}
    lost = env.node_ids.index(worker.node_id)
    env.reset(seed=0)
    cluster.remove_node(worker)
    start = time.time()
    with pytest.raises(WorkerCrashedError, match=rf"worker {lost} \(Ray actor.*died during step: its node has died"):
        for _ in range(1000):
            env.step(np.array([0, 1]))
            time.sleep(0.01)
    assert time.time() - start < 10.0
    env.close()
