"""Vector envs stepped in Rust (issue 25 item 4): ``smlworld.envs.make_vec`` gives a gymnasium
``VectorEnv`` with batched spaces and next-step autoreset whose every array equals, bit for bit,
what gymnasium's own ``SyncVectorEnv`` of the single envs gives for the same seeds and actions."""

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.vector import AutoresetMode, VectorEnv

import smlworld.envs  # noqa: F401  (registers the environments)
from smlworld.envs import make_vec


def _reference(env_id, n, **kwargs):
    return gym.make_vec(env_id, num_envs=n, vectorization_mode="sync", **kwargs)


def _follow(obs):
    """A sensible follower for a (n, 4) batch of PlatoonFollow observations."""
    v, gap, dv = obs[:, 0], obs[:, 1], obs[:, 2]
    return (0.5 * (gap - (5 + v)) + dv).astype(np.float32).reshape(-1, 1)


def _compare(ours, theirs, policy, steps, seed):
    """Step both vector envs with the same actions; every array must be identical."""
    a, _ = ours.reset(seed=seed)
    b, _ = theirs.reset(seed=seed)
    assert a.dtype == b.dtype and np.array_equal(a, b)
    ends = 0
    for t in range(steps):
        actions = policy(a, t)
        a, ra, ta, ua, ia = ours.step(actions)
        b, rb, tb, ub, ib = theirs.step(actions)
        assert np.array_equal(a, b), (t, np.argwhere(a != b)[:3])
        assert ra.dtype == np.float64 and np.array_equal(ra, rb), (t, ra, rb)
        assert np.array_equal(ta, tb) and np.array_equal(ua, ub), t
        for key, mask in ((k, v) for k, v in ib.items() if k.startswith("_")):
            name = key[1:]
            assert np.array_equal(ia[key], mask), (t, key)
            assert np.array_equal(ia[name][mask], ib[name][mask]), (t, name)
        ends += int(np.sum(ta | ua))
    return ends


def test_make_vec_is_a_vector_env_with_batched_spaces():
    envs = make_vec("smlworld/PlatoonFollow-v0", num_envs=8)
    single = gym.make("smlworld/PlatoonFollow-v0")
    assert isinstance(envs, VectorEnv) and envs.num_envs == 8
    assert envs.metadata["autoreset_mode"] == AutoresetMode.NEXT_STEP
    assert envs.single_observation_space == single.observation_space
    assert envs.single_action_space == single.action_space
    assert envs.observation_space.shape == (8, 4) and envs.action_space.shape == (8, 1)
    obs, info = envs.reset(seed=1)
    assert obs.shape == (8, 4) and obs.dtype == np.float32 and obs in envs.observation_space
    obs, rew, term, trunc, info = envs.step(envs.action_space.sample())
    assert rew.shape == term.shape == trunc.shape == (8,) and term.dtype == np.bool_
    assert set(info) == {"gap", "_gap", "time", "_time"} and info["time"].shape == (8,)

    merge = make_vec("smlworld/HighwayMerge-v0", num_envs=3, seed=0)
    assert merge.single_action_space == gym.spaces.Discrete(5)
    assert merge.action_space == gym.spaces.MultiDiscrete([5, 5, 5])
    assert merge.observation_space.shape == (3, 6, 5)
    cont = make_vec("smlworld/HighwayMerge-v0", num_envs=3, action="continuous")
    assert cont.action_space.shape == (3, 2)


def test_gymnasium_make_vec_builds_the_rust_vector_env_by_default():
    envs = gym.make_vec("smlworld/PlatoonFollow-v0", num_envs=4)
    assert isinstance(envs.unwrapped, smlworld.envs.SmlworldVectorEnv)
    assert envs.unwrapped.spec.id == "smlworld/PlatoonFollow-v0"


def test_unknown_env_id_names_the_known_ones():
    with pytest.raises(ValueError, match="smlworld/PlatoonFollow-v0.*smlworld/HighwayMerge-v0"):
        make_vec("smlworld/Nope-v0", num_envs=2)
    with pytest.raises(ValueError, match="num_envs"):
        make_vec("smlworld/PlatoonFollow-v0", num_envs=0)


def test_platoon_follow_equals_sync_vector_env_of_single_envs_through_autoresets():
    """Short episodes (max_steps=40) so that several end and reset inside the run, some by
    collision (full throttle in half the envs for a while); same seeds, same actions."""
    n = 6
    ours = make_vec("smlworld/PlatoonFollow-v0", num_envs=n, max_steps=40)
    theirs = _reference("smlworld/PlatoonFollow-v0", n, max_steps=40)
    rng = np.random.default_rng(0)

    def policy(obs, t):
        a = _follow(obs)
        a[::2] = 3.0 if t % 50 < 25 else a[::2]  # ram the leader now and then: collisions
        a[1] += rng.uniform(-1.0, 1.0)
        return a

    ends = _compare(ours, theirs, policy, steps=130, seed=11)
    assert ends >= n * 2, ends  # truncations and collisions both happened and were reset


def test_highway_merge_equals_sync_vector_env_in_both_action_modes():
    n = 4
    rng = np.random.default_rng(3)
    ours = make_vec("smlworld/HighwayMerge-v0", num_envs=n)
    theirs = _reference("smlworld/HighwayMerge-v0", n)
    ends = _compare(ours, theirs, lambda obs, t: rng.integers(0, 5, size=n), steps=120, seed=5)
    assert ends >= n, ends
    ours = make_vec("smlworld/HighwayMerge-v0", num_envs=n, action="continuous")
    theirs = _reference("smlworld/HighwayMerge-v0", n, action="continuous")
    ends = _compare(
        ours,
        theirs,
        lambda obs, t: rng.uniform([-6.0, -1.0], [3.0, 1.0], size=(n, 2)).astype(np.float32),
        steps=120,
        seed=6,
    )
    assert ends >= n, ends


def test_next_step_autoreset_gives_the_first_observation_with_zero_reward():
    envs = make_vec("smlworld/PlatoonFollow-v0", num_envs=2, max_steps=3, seed=4)
    act = np.zeros((2, 1), dtype=np.float32)
    for _ in range(2):
        _, _, term, trunc, _ = envs.step(act)
        assert not trunc.any()
    _, _, term, trunc, info = envs.step(act)
    assert trunc.all() and not term.any()
    obs, rew, term, trunc, info = envs.step(np.full((2, 1), np.nan, dtype=np.float32))  # ignored
    assert not (term | trunc).any() and np.array_equal(rew, [0.0, 0.0])
    assert info == {} and np.all(envs.times() == 0.0) and obs in envs.observation_space
    envs.step(act)
    assert np.all(envs.times() > 0.0)


def test_seeds_reproduce_and_differ_and_lists_seed_each_env():
    a = make_vec("smlworld/HighwayMerge-v0", num_envs=3)
    b = make_vec("smlworld/HighwayMerge-v0", num_envs=3)
    oa, _ = a.reset(seed=7)
    ob, _ = b.reset(seed=[7, 8, 9])
    assert np.array_equal(oa, ob)
    actions = np.array([3, 1, 0])
    for _ in range(20):
        ra = a.step(actions)
        rb = b.step(actions)
        assert all(np.array_equal(x, y) for x, y in zip(ra[:4], rb[:4]))
    oc, _ = b.reset(seed=8)
    assert np.array_equal(oc[0], oa[1])  # env 0 seeded 8 is env 1 seeded 7 + 1
    sync = _reference("smlworld/HighwayMerge-v0", 3)
    ref, _ = sync.reset(seed=[None, 8, None])
    ours, _ = a.reset(seed=[None, 8, None])
    assert np.array_equal(ours[1], ref[1])


def test_reset_mask_resets_only_the_selected_envs():
    n = 3
    ours = make_vec("smlworld/PlatoonFollow-v0", num_envs=n, seed=2)
    theirs = _reference("smlworld/PlatoonFollow-v0", n)
    theirs.reset(seed=2)
    act = np.full((n, 1), 0.5, dtype=np.float32)
    for _ in range(5):
        ours.step(act)
        theirs.step(act)
    mask = np.array([False, True, False])
    a, _ = ours.reset(options={"reset_mask": mask})
    b, _ = theirs.reset(options={"reset_mask": mask})
    assert np.array_equal(a, b)
    assert np.array_equal(ours.step(act)[0], theirs.step(act)[0])


def test_results_do_not_depend_on_the_thread_count():
    def run(threads):
        envs = make_vec("smlworld/HighwayMerge-v0", num_envs=5, threads=threads, seed=1)
        rng = np.random.default_rng(0)
        out = []
        for _ in range(30):
            out.append(envs.step(rng.integers(0, 5, size=5))[:4])
        return out

    one, two = run(1), run(2)
    assert all(np.array_equal(x, y) for a, b in zip(one, two) for x, y in zip(a, b))


def test_bad_actions_raise_before_anything_moves():
    envs = make_vec("smlworld/PlatoonFollow-v0", num_envs=3, seed=0)
    before = envs.times()
    bad = np.zeros((3, 1), dtype=np.float32)
    bad[2] = np.nan
    with pytest.raises(ValueError, match="environment 2: action must be finite"):
        envs.step(bad)
    assert np.array_equal(envs.times(), before)
    with pytest.raises(ValueError, match="shape"):
        envs.step(np.zeros((2, 1)))
    merge = make_vec("smlworld/HighwayMerge-v0", num_envs=2, seed=0)
    with pytest.raises(ValueError, match="environment 1: action must be one of"):
        merge.step(np.array([1, 7]))
    with pytest.raises(RuntimeError, match="reset"):
        make_vec("smlworld/PlatoonFollow-v0", num_envs=2).step(np.zeros((2, 1)))
