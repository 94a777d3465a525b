"""Gymnasium environments: the env checker, reproducibility from the seed, collisions terminate."""

import filecmp

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

import smlworld.envs  # noqa: F401  (registers the environments)


def test_packaged_map_is_the_repo_map(root):
    from importlib import resources

    packaged = resources.files("smlworld") / "data" / "highway_ring.osm"
    assert filecmp.cmp(str(packaged), root / "maps/highway_ring.osm", shallow=False)


def test_platoon_follow_passes_check_env():
    env = gym.make("smlworld/PlatoonFollow-v0")
    check_env(env.unwrapped, skip_render_check=True)


def _rollout(seed, policy, steps=200):
    env = gym.make("smlworld/PlatoonFollow-v0")
    obs, _ = env.reset(seed=seed)
    out = [obs]
    rewards = []
    for _ in range(steps):
        obs, r, term, trunc, info = env.step(policy(obs))
        out.append(obs)
        rewards.append(r)
        if term or trunc:
            break
    return np.array(out), np.array(rewards), term


def _follow(o):
    v, gap, dv, _ = o
    return np.array([0.5 * (gap - (5 + v)) + 1.0 * dv], dtype=np.float32)


def test_platoon_follow_bit_reproducible_from_seed():
    a, ra, _ = _rollout(7, _follow)
    b, rb, _ = _rollout(7, _follow)
    c, _, _ = _rollout(8, _follow)
    assert np.array_equal(a, b) and np.array_equal(ra, rb)
    assert not np.array_equal(a, c)


def test_platoon_follow_tracks_and_collides():
    obs, rewards, term = _rollout(3, _follow, steps=600)
    assert not term
    assert obs[:, 1].min() > 2.0  # a sensible follower keeps a gap
    # the leader's acceleration arrives over wifi
    assert np.count_nonzero(obs[:, 3]) > len(obs) // 2
    obs, rewards, term = _rollout(3, lambda o: np.array([3.0], dtype=np.float32), steps=600)
    assert term and rewards[-1] == -1.0
    assert obs[-1, 1] <= 0.0  # bumper to bumper


def test_platoon_follow_rewards_are_bounded():
    # Issue 22 item 12: every step's reward lies in [-1, 1]; a random policy no longer collects
    # -177,000 in 1,000 steps, and following beats it.
    rng = np.random.default_rng(0)
    _, random_rewards, _ = _rollout(5, lambda o: rng.uniform(-6.0, 3.0, size=1).astype(np.float32), steps=1000)
    _, follow_rewards, _ = _rollout(5, _follow, steps=1000)
    for r in (random_rewards, follow_rewards):
        assert r.min() >= -1.0 and r.max() <= 1.0, (r.min(), r.max())
    assert follow_rewards.mean() > random_rewards.mean()


def test_platoon_parallel_api():
    from pettingzoo.test import parallel_api_test

    from smlworld.envs import platoon_parallel_env

    parallel_api_test(platoon_parallel_env(n=5), num_cycles=200)


def test_platoon_parallel_observes_predecessor_over_wifi():
    from smlworld.envs import platoon_parallel_env

    env = platoon_parallel_env(n=3)
    obs, _ = env.reset(seed=4)
    assert set(obs) == {"member_0", "member_1", "member_2"}
    heard = 0
    for _ in range(50):
        actions = {a: np.array([0.5 * (o[1] - (5 + o[0])) + o[2]], dtype=np.float32) for a, o in obs.items()}
        obs, rew, term, trunc, info = env.step(actions)
        heard += sum(o[3] != 0.0 for o in obs.values())
        assert not any(term.values())
    assert heard > 50
    assert all(2.0 < info[a]["gap"] < 40.0 for a in info)


def test_a_plain_import_registers_the_envs_and_rgb_array_renders_frames():
    """Issue 20 item 3 (for the existing env): ``gymnasium.make`` after a plain ``import
    smlworld`` (no ``import smlworld.envs``), and ``render_mode="rgb_array"`` gives HxWx3 frames."""
    import subprocess
    import sys

    code = (
        "import gymnasium, smlworld\n"
        "env = gymnasium.make('smlworld/PlatoonFollow-v0', render_mode='rgb_array')\n"
        "env.reset(seed=1)\n"
        "env.step(env.action_space.sample())\n"
        "f = env.render()\n"
        "assert f.shape == (360, 640, 3) and f.dtype.name == 'uint8', (f.shape, f.dtype)\n"
        "assert f.std() > 1.0, 'a picture, not a blank frame'\n"
        "print('ok')\n"
    )
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert done.returncode == 0 and done.stdout.strip() == "ok", done.stderr[-2000:]
