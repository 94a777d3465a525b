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


def test_platoon_parallel_env_leaves_no_folder_behind():
    """Each env writes its scenario into a temporary folder: ``close()`` removes it, and so does
    collecting an env nobody closed (a sweep of many envs used to leave one folder each)."""
    import gc
    import os

    from smlworld.envs import platoon_parallel_env

    env = platoon_parallel_env(n=2)
    env.reset(seed=1)
    folder = env._dir
    assert os.path.isdir(folder)
    env.close()
    assert not os.path.exists(folder)
    with pytest.raises(RuntimeError, match="closed"):
        env.reset(seed=1)

    env = platoon_parallel_env(n=2)
    folder = env._dir
    assert os.path.isdir(folder)
    del env
    gc.collect()
    assert not os.path.exists(folder)


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
        "for name in ('smlworld/PlatoonFollow-v0', 'smlworld/HighwayMerge-v0'):\n"
        "    env = gymnasium.make(name, render_mode='rgb_array')\n"
        "    env.reset(seed=1)\n"
        "    env.step(env.action_space.sample())\n"
        "    f = env.render()\n"
        "    assert f.shape == (360, 640, 3) and f.dtype.name == 'uint8', (name, f.shape, f.dtype)\n"
        "    assert f.std() > 1.0, (name, 'a picture, not a blank frame')\n"
        "print('ok')\n"
    )
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert done.returncode == 0 and done.stdout.strip() == "ok", done.stderr[-2000:]


# -- smlworld/HighwayMerge-v0 (issue 20 item 3) -------------------------------------------------


def merge_policy(obs, info):
    """A scripted continuous policy: match the speed of the right lane's gap, centre on it, ask
    for the change when both gaps are comfortable; once merged, follow the vehicle ahead."""
    others = obs[1:]
    pres = others[:, 0] > 0
    dx, dy, dv = others[:, 1] * 100, others[:, 2] * 7, others[:, 3] * 30
    if info.get("merged"):
        same = pres & (np.abs(dy) < 1.5) & (dx > 0)
        if same.any():
            k = int(np.argmin(np.where(same, dx, 1e9)))
            return np.array([0.3 * (dx[k] - 25) + dv[k], 0.0], dtype=np.float32)
        return np.array([0.5, 0.0], dtype=np.float32)
    right = pres & (dy < -1.5)
    ahead, behind = right & (dx > 0), right & (dx <= 0)
    ga = dx[ahead].min() if ahead.any() else 60.0
    gb = -dx[behind].max() if behind.any() else 60.0
    dva = dv[ahead][np.argmin(dx[ahead])] if ahead.any() else 0.0
    dvb = dv[behind][np.argmax(dx[behind])] if behind.any() else 0.0
    accel = 0.1 * (ga - gb) + 0.4 * (dva + dvb)
    change = -1.0 if (ga > 15 and gb > 20 and abs(dva) < 3 and abs(dvb) < 3) else 0.0
    return np.array([accel, change], dtype=np.float32)


def run_episode(env, policy, seed):
    obs, info = env.reset(seed=seed)
    rewards, observations = [], [obs]
    while True:
        obs, r, term, trunc, info = env.step(policy(obs, info))
        rewards.append(r)
        observations.append(obs)
        if term or trunc:
            return rewards, observations, info


def test_highway_merge_passes_the_env_checker_in_both_action_modes():
    from gymnasium.utils.env_checker import check_env

    for action in ("discrete", "continuous"):
        env = gym.make("smlworld/HighwayMerge-v0", action=action)
        check_env(env.unwrapped, skip_render_check=True)
    assert gym.make("smlworld/HighwayMerge-v0").action_space.n == 5  # highway-env's DiscreteMetaAction
    with pytest.raises(ValueError):
        gym.make("smlworld/HighwayMerge-v0", action="steering")


def test_highway_merge_is_reproducible_from_its_seed_and_seeds_differ():
    env = gym.make("smlworld/HighwayMerge-v0", action="continuous")
    a = run_episode(env, merge_policy, 4)
    b = run_episode(env, merge_policy, 4)
    c = run_episode(env, merge_policy, 5)
    assert a[0] == b[0]
    assert all(np.array_equal(x, y) for x, y in zip(a[1], b[1]))
    assert len(a[1]) != len(c[1]) or any(not np.array_equal(x, y) for x, y in zip(a[1], c[1]))


def test_highway_merge_rewards_a_safe_merge_and_ends_when_the_lane_ends():
    """The scripted policy merges without a collision in most seeds and earns far more than
    keeping the lane (IDLE), which meets the lane's end: -1 and terminated."""
    env = gym.make("smlworld/HighwayMerge-v0", action="continuous")
    merged, returns = 0, []
    for seed in range(12):
        rewards, _, info = run_episode(env, merge_policy, seed)
        assert all(-1.0 <= r <= 1.0 for r in rewards)
        assert not info["collided"], (seed, info)
        merged += info["merged"]
        if info["merged"]:
            returns.append(sum(rewards))
    assert merged >= 6, merged
    idle = gym.make("smlworld/HighwayMerge-v0")
    rewards, _, info = run_episode(idle, lambda obs, info: 1, 0)
    assert not info["merged"] and rewards[-1] == -1.0 and info["x"] >= 299.0
    assert min(returns) > sum(rewards) + 5.0
    with pytest.raises(ValueError):
        idle.reset(seed=0)
        idle.step(7)



@pytest.mark.parametrize("name", ["smlworld/HighwayMerge-v0", "smlworld/PlatoonFollow-v0"])
def test_reset_loads_the_scenario_once_and_records_no_metrics(monkeypatch, name):
    """Speed (issue 20 item 3): a reset starts the loaded scenario over with the new seed instead
    of reading the file and the map again, and the env's session records no summary metrics
    (a third of a tick; the envs check collisions themselves)."""
    import smlworld

    loads = []
    real = smlworld.Sim.from_scenario.__func__

    def counting(cls, *args, **kwargs):
        loads.append(args)
        return real(cls, *args, **kwargs)

    monkeypatch.setattr(smlworld.Sim, "from_scenario", classmethod(counting))
    env = gym.make(name)
    first, _ = env.reset(seed=3)
    for _ in range(5):
        env.step(env.action_space.sample())
    again, _ = env.reset(seed=3)
    env.reset(seed=4)
    assert len(loads) == 1 and np.array_equal(first, again)
    if name == "smlworld/PlatoonFollow-v0":
        # full throttle into the leader: the env sees the collision, the summary records none
        while not env.step(np.array([3.0], dtype=np.float32))[2]:
            pass
        assert env.unwrapped._sim.summary()["metrics"]["collision_count"] == 0
    else:
        env.unwrapped._sim.step(8.0)  # the traffic's follower gaps are not recorded
        assert not env.unwrapped._sim.summary()["metrics"]["followers"]


def test_platoon_follow_frame_at_a_collision_shows_the_red_ring():
    """Issue 61 §2: the env stops the metrics that record collision events, so its frame at a
    collision showed the two cars overlapping and no ring; the frame now rings any vehicles whose
    footprints overlap (the ring's exact colour, RING_COLOR of src/render/overlay.rs)."""
    env = gym.make("smlworld/PlatoonFollow-v0", render_mode="rgb_array")
    env.reset(seed=3)
    ring = np.array([235, 20, 20], dtype=np.uint8)

    def ring_pixels(frame):
        return int(np.all(frame == ring, axis=-1).sum())

    assert ring_pixels(env.render()) == 0, "no collision yet, no ring"
    terminated = False
    for _ in range(2000):
        _, _, terminated, _, info = env.step(np.array([3.0], dtype=np.float32))
        if terminated:
            break
    assert terminated, "full throttle into the leader ends the episode"
    assert ring_pixels(env.render()) >= 30, "the collision is ringed in red"
