"""Traffic-signal control with sumo-rl's interface (issue 55): ``smlworld/TrafficSignal-v0`` passes
gymnasium's checker, the parallel env PettingZoo's, resets reproduce, one step's observation and
reward match numbers computed here from the vehicles' positions and speeds, and
``enforce_max_green`` bounds every green."""

import importlib.util
import os
import subprocess
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env
from pettingzoo.test import parallel_api_test

import smlworld
from smlworld.envs.traffic_signal import _scenario_text, sumo_rl_nets, traffic_signal_parallel_env


@pytest.fixture(scope="module")
def nets() -> Path:
    """sumo-rl's ``nets`` folder (``$SUMO_RL_NETS``, else the installed sumo_rl package's), as
    tests/sumo.rs finds it; sumo-rl is in python/requirements-test.txt."""
    return sumo_rl_nets()


@pytest.fixture(scope="module")
def two_way(nets):
    d = nets / "2way-single-intersection"
    return str(d / "single-intersection.net.xml"), str(d / "single-intersection-vhvh.rou.xml")


@pytest.fixture(scope="module")
def random_traffic(cli, tmp_path_factory):
    """A generated four-arm junction with traffic lights and random traffic (seeded)."""
    d = tmp_path_factory.mktemp("signals")
    subprocess.run(
        [str(cli), "map", "generate", "intersection4", "--traffic-lights", "--out", str(d / "x.osm")],
        check=True,
        capture_output=True,
    )
    (d / "lights.toml").write_text(
        'seed = 7\nduration = 3600.0\nmap = "x.osm"\n\n'
        "[[traffic]]\n"
        'route = "random"\nrate = 1200.0\nspeed = [10.0, 12.0]\nclasses = { car = 1.0 }\nlane_change = false\n'
    )
    return d / "lights.toml"


def test_check_env_on_sumo_rl_s_two_way_intersection(two_way):
    env = gym.make("smlworld/TrafficSignal-v0", net_file=two_way[0], route_file=two_way[1], num_seconds=300)
    check_env(env.unwrapped, skip_render_check=True)
    ts = env.unwrapped.traffic_signals["t"]
    # sumo-rl's phases for this net's program (4 green, 4 yellow): 4 greens, 12 yellow transitions.
    assert ts.num_green_phases == 4 and len(ts.yellow_dict) == 12 and len(ts.all_phases) == 16
    assert env.observation_space.shape == (4 + 1 + 2 * 8,), "8 incoming lanes"
    obs, info = env.reset(seed=1)
    total = 0
    for _ in range(20):
        obs, reward, terminated, truncated, info = env.step(env.action_space.sample())
        total += info["system_total_stopped"]
        assert env.observation_space.contains(obs)
        assert not terminated and not truncated
    for key in ("system_total_stopped", "system_total_waiting_time", "system_mean_waiting_time", "system_mean_speed"):
        assert key in info
    assert info["step"] == 100
    assert total > 0, "some vehicles halt at the red lights in 100 s"


def test_the_episode_ends_after_num_seconds(two_way):
    env = gym.make("smlworld/TrafficSignal-v0", net_file=two_way[0], route_file=two_way[1], num_seconds=20)
    env.reset(seed=0)
    flags = [env.step(0)[3] for _ in range(4)]
    assert flags == [False, False, False, True]


def test_parallel_api_on_resco_grid4x4(nets):
    d = nets / "RESCO" / "grid4x4"
    env = traffic_signal_parallel_env(
        net_file=str(d / "grid4x4.net.xml"), route_file=str(d / "grid4x4_1.rou.xml"), num_seconds=200
    )
    assert len(env.possible_agents) == 16
    parallel_api_test(env, num_cycles=60)
    obs, infos = env.reset(seed=2)
    assert set(obs) == set(env.possible_agents)
    assert all("system_total_stopped" in infos[a] for a in env.possible_agents)
    agent = env.possible_agents[0]
    assert f"{agent}_stopped" in infos[agent]


def _rollout(env, seed, steps=15):
    obs, _ = env.reset(seed=seed)
    out = [obs]
    rewards = []
    for k in range(steps):
        obs, r, _, _, _ = env.step(k // 3 % env.action_space.n)
        out.append(obs)
        rewards.append(r)
    return np.array(out), np.array(rewards)


def test_reset_with_a_seed_reproduces_the_episode(random_traffic):
    env = gym.make("smlworld/TrafficSignal-v0", scenario=str(random_traffic), num_seconds=600)
    a = _rollout(env, seed=5)
    b = _rollout(env, seed=5)
    other = gym.make("smlworld/TrafficSignal-v0", scenario=str(random_traffic), num_seconds=600)
    c = _rollout(other, seed=5)
    d = _rollout(other, seed=6)
    assert np.array_equal(a[0], b[0]) and np.array_equal(a[1], b[1])
    assert np.array_equal(a[0], c[0]) and np.array_equal(a[1], c[1])
    assert not np.array_equal(a[0], d[0]), "another seed draws other random traffic"
    assert a[0][:, 5:].max() > 0, "vehicles reach the incoming lanes"


def _length(points):
    return float(np.hypot(*np.diff(points, axis=0).T).sum())


def test_observation_and_reward_match_a_hand_computed_step(two_way, tmp_path):
    """One env and a twin simulation of the same scenario, rates and seed, stepped here one
    dynamics tick (the env's ``sim_step``, SUMO's 1 s by default) at a time with the states
    sumo-rl's rules show for the same actions; from the
    twin's positions and speeds this test counts each incoming lane's vehicles and halting
    vehicles and integrates every vehicle's waiting (speed < 0.1 m/s), then compares with the
    env's observation and diff-waiting-time reward at every step."""
    net, rou = two_way
    env = smlworld.envs.traffic_signal.TrafficSignalEnv(
        net_file=net, route_file=rou, num_seconds=400, single_agent=True
    )
    obs, _ = env.reset(seed=11)
    ts = env.traffic_signals["t"]
    junction = ts.junction
    greens = [p.state for p in ts.green_phases]

    scenario = tmp_path / "twin.toml"
    scenario.write_text(_scenario_text(net, rou, 0, 400))
    twin = smlworld.Sim.from_scenario(scenario, seed=11, **env._overrides)
    lanes = ts.lanes
    geometry = twin.map()
    lane_length = {lane: _length(geometry.centre(lane)) for lane in lanes}
    vehicle_length = 5.0  # SUMO's default vType length: the route file names no vType
    dt = env.sim_step_length
    assert dt == 1.0, "SUMO files run at SUMO's default step"
    waited = {}

    def tick_twin(seconds):
        for _ in range(int(round(seconds / dt))):
            twin.step(dt)
            st = twin.states()
            speed = np.hypot(st["vx"], st["vy"])
            for vid, v in zip(st["id"], speed):
                waited[vid] = waited.get(vid, 0.0) + (dt if v < 0.1 else 0.0)

    def expected_lanes():
        st = twin.states()
        speed = np.hypot(st["vx"], st["vy"])
        density, queue, wait = [], [], 0.0
        for lane in lanes:
            on = st["lanelet"] == lane
            capacity = lane_length[lane] / (2.5 + vehicle_length)
            density.append(min(1.0, on.sum() / capacity))
            queue.append(min(1.0, (on & (speed < 0.1)).sum() / capacity))
            wait += sum(waited.get(v, 0.0) for v in st["id"][on])
        return np.array(density), np.array(queue), wait

    # Hold green 0 for 15 s, ask for green 2 (yellow 2 s, then green), then green 1 at 35 s.
    actions = [0, 0, 0, 2, 2, 2, 2, 1, 1, 1]
    twin.set_phase(junction, greens[0])
    green, since, last_wait = 0, 0, 0.0
    for k, action in enumerate(actions):
        obs, reward, _, _, _ = env.step(action)
        # sumo-rl's rules, written out: a change needs yellow_time + min_green = 7 s in the phase.
        if action != green and since >= 7:
            yellow = "".join("y" if a in "Gg" and b in "rs" else a for a, b in zip(greens[green], greens[action]))
            twin.set_phase(junction, yellow)
            tick_twin(2.0)
            twin.set_phase(junction, greens[action])
            tick_twin(3.0)
            green, since = action, 5
        else:
            twin.set_phase(junction, greens[green])
            tick_twin(5.0)
            since += 5
        density, queue, wait = expected_lanes()
        one_hot = np.eye(4)[green]
        min_green = 1.0 if since >= 7 else 0.0
        expected = np.concatenate([one_hot, [min_green], density, queue]).astype(np.float32)
        np.testing.assert_allclose(obs, expected, atol=1e-6, err_msg=f"step {k} (t = {5 * (k + 1)} s)")
        assert reward == pytest.approx(last_wait - wait / 100.0, abs=1e-6), f"step {k}"
        last_wait = wait / 100.0
    assert obs[5:13].sum() > 0 and last_wait > 0, "the check saw queued, waiting vehicles"


def test_enforce_max_green_bounds_every_green(two_way):
    """Always asking for green 0: without enforcement it stays green all episode; with
    ``enforce_max_green`` every green (from the end of its yellow to the start of the next
    yellow) lasts at most ``max_green``."""

    def greens(enforce):
        env = gym.make(
            "smlworld/TrafficSignal-v0",
            net_file=two_way[0],
            route_file=two_way[1],
            num_seconds=200,
            max_green=20,
            enforce_max_green=enforce,
        )
        env.reset(seed=0)
        ts = env.unwrapped.traffic_signals["t"]
        starts, changes = [0], []
        phase = ts.green_phase
        for _ in range(40):
            env.step(0)
            if ts.green_phase != phase:
                changes.append(env.unwrapped.sim_step - 5)  # the yellow began at the step's start
                starts.append(changes[-1] + ts.yellow_time)
                phase = ts.green_phase
        ends = changes + [env.unwrapped.sim_step]
        return [end - start for start, end in zip(starts, ends)]

    held = greens(False)
    assert held == [200]
    bounded = greens(True)
    assert len(bounded) > 5 and max(bounded) <= 20, bounded


def test_sumo_rl_arguments_it_does_not_support_are_refused(two_way):
    net, rou = two_way
    with pytest.raises(ValueError, match=r"use_gui=True is a sumo-rl argument this env does not support"):
        smlworld.envs.TrafficSignalEnv(net_file=net, route_file=rou, use_gui=True)
    with pytest.raises(ValueError, match=r"additional_sumo_cmd="):
        smlworld.envs.TrafficSignalEnv(net_file=net, route_file=rou, additional_sumo_cmd="--step-length 0.1")
    with pytest.raises(TypeError, match=r"unexpected keyword argument 'colour'"):
        smlworld.envs.TrafficSignalEnv(net_file=net, route_file=rou, colour=1)
    with pytest.raises(ValueError, match=r"delta_time \(2\) must be greater than yellow_time \(2\)"):
        smlworld.envs.TrafficSignalEnv(net_file=net, route_file=rou, delta_time=2)
    with pytest.raises(NotImplementedError, match=r"Reward function nope not implemented"):
        smlworld.envs.TrafficSignalEnv(net_file=net, route_file=rou, reward_fn="nope")
    # sumo-rl's defaults for them are accepted.
    env = smlworld.envs.TrafficSignalEnv(net_file=net, route_file=rou, use_gui=False, out_csv_name=None)
    assert env.ts_ids == ["t"]


def test_callable_rewards_see_sumo_rl_s_traffic_signal(two_way):
    seen = []

    def my_reward(ts):
        seen.append((ts.get_total_queued(), ts.get_pressure(), ts.get_average_speed(), ts.time_since_last_phase_change))
        return -float(sum(ts.get_lanes_queue()))

    env = gym.make("smlworld/TrafficSignal-v0", net_file=two_way[0], route_file=two_way[1], reward_fn=my_reward)
    env.reset(seed=0)
    for _ in range(8):
        _, reward, _, _, _ = env.step(1)
    ts = env.unwrapped.traffic_signals["t"]
    assert reward == -sum(ts.get_lanes_queue())
    assert len(seen) == 8 and seen[-1][0] == ts.get_total_queued() > 0


def test_bench_signals_measures_ours(root):
    """python/bench/bench_signals.py (README's sumo-rl comparison) runs and reports its format."""
    import re
    import sys

    done = subprocess.run(
        [
            sys.executable,
            str(root / "python/bench/bench_signals.py"),
            "--only",
            "ours",
            "--steps",
            "5",
            "--repeat",
            "2",
            "--net",
            "2way",
        ],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert done.returncode == 0, done.stderr[-2000:]
    m = re.search(
        r"2way smlworld: ([\d,]+) / ([\d,]+) / ([\d,]+) \(min / median / max\) env-steps/s "
        r"\(5 steps, 1 agent, 2 runs\)",
        done.stdout,
    )
    assert m, done.stdout
    lo, mid, hi = (float(g.replace(",", "")) for g in m.groups())
    assert 0 < lo <= mid <= hi


def test_make_vec_steps_copies_together_as_the_single_env_does(two_way):
    """make_vec's copies advance in one Rust call per signal event; each copy gives what a single
    env gives for its seed (s + i) and actions, autoreset (NEXT_STEP) included."""
    net, rou = two_way
    n, steps = 3, 9
    kwargs = dict(net_file=net, route_file=rou, num_seconds=30, sumo_seed=0)
    vec = smlworld.envs.make_vec("smlworld/TrafficSignal-v0", num_envs=n, seed=4, **kwargs)
    assert vec.observation_space.shape == (n, 21)
    rng = np.random.default_rng(0)
    actions = rng.integers(0, 4, size=(steps, n))
    singles = [gym.make("smlworld/TrafficSignal-v0", **kwargs) for _ in range(n)]
    first = [s.reset(seed=4 + i)[0] for i, s in enumerate(singles)]
    assert np.array_equal(np.stack(first), vec.reset(seed=4)[0])
    done = np.zeros(n, dtype=bool)
    truncations = 0
    for k in range(steps):
        obs, rewards, terminated, truncated, infos = vec.step(actions[k])
        for i, s in enumerate(singles):
            if done[i]:
                o, _ = s.reset()
                r, tr = 0.0, False
            else:
                o, r, _, tr, _ = s.step(int(actions[k, i]))
            np.testing.assert_array_equal(obs[i], o, err_msg=f"step {k}, env {i}")
            assert rewards[i] == r and truncated[i] == tr, (k, i)
            done[i] = tr
        truncations += int(truncated.sum())
        assert "system_total_stopped" in infos and len(infos["system_total_stopped"]) == n
    assert truncations == n, "every copy ended its 30 s episode once (at the 6th step) and was reset"
    default = gym.make_vec("smlworld/TrafficSignal-v0", num_envs=2, **kwargs)
    assert type(default).__name__ == "TrafficSignalVectorEnv"


def test_rgb_array_frames_show_the_junction(two_way):
    env = gym.make("smlworld/TrafficSignal-v0", net_file=two_way[0], route_file=two_way[1], render_mode="rgb_array")
    env.reset(seed=0)
    env.step(1)
    frame = env.render()
    assert frame.shape == (360, 640, 3) and frame.dtype == np.uint8
    assert len(np.unique(frame.reshape(-1, 3), axis=0)) > 3, "roads, vehicles and signals, not a blank image"
    with pytest.raises(ValueError, match=r"render_mode must be None or 'rgb_array'"):
        smlworld.envs.TrafficSignalEnv(net_file=two_way[0], route_file=two_way[1], render_mode="human")


@pytest.mark.parametrize(
    "net, routes",
    [
        (
            "2way-single-intersection/single-intersection.net.xml",
            "2way-single-intersection/single-intersection-vhvh.rou.xml",
        ),
        ("RESCO/grid4x4/grid4x4.net.xml", "RESCO/grid4x4/grid4x4_1.rou.xml"),
    ],
)
def test_lights_phases_and_lanes_are_sumo_rl_s(nets, net, routes):
    """sumo-rl's own SumoEnvironment (TraCI, SUMO from eclipse-sumo) on the same files gives the
    same light ids in the same order, the same green phases and yellow transitions (their
    characters; ours are in our link order), and the same incoming lanes in the same order
    (matched by their centre lines), so a policy's observation layout carries over."""
    import sumo

    os.environ.setdefault("SUMO_HOME", sumo.SUMO_HOME)
    import sumolib
    from sumo_rl import SumoEnvironment

    net_file, route_file = str(nets / net), str(nets / routes)
    theirs = SumoEnvironment(net_file=net_file, route_file=route_file, sumo_warnings=False)
    ours = smlworld.envs.TrafficSignalEnv(net_file=net_file, route_file=route_file)
    assert ours.ts_ids == theirs.ts_ids
    sumo_net = sumolib.net.readNet(net_file)
    geometry = ours._sim.map()
    ends = {int(k): (c[0], c[-1]) for k in geometry.lanelets for c in [geometry.centre(int(k))]}

    def lanelet_of(lane_id):
        shape = np.array(sumo_net.getLane(lane_id).getShape())
        d = {k: np.hypot(*(a - shape[0])) + np.hypot(*(b - shape[-1])) for k, (a, b) in ends.items()}
        best = min(d, key=d.get)
        assert d[best] < 1.0, (lane_id, d[best])
        return best

    for ts_id in ours.ts_ids:
        a, b = theirs.traffic_signals[ts_id], ours.traffic_signals[ts_id]
        assert b.num_green_phases == a.num_green_phases, ts_id
        assert [sorted(p.state) for p in b.green_phases] == [sorted(p.state) for p in a.green_phases], ts_id
        assert b.yellow_dict == a.yellow_dict
        for key, k in a.yellow_dict.items():
            assert sorted(b.all_phases[b.yellow_dict[key]].state) == sorted(a.all_phases[k].state), (ts_id, key)
        assert b.lanes == [lanelet_of(lane) for lane in a.lanes], ts_id
        assert set(b.out_lanes) == {lanelet_of(lane) for lane in a.out_lanes}, ts_id
        for lane in a.lanes:
            assert b.lanes_length[lanelet_of(lane)] == pytest.approx(a.lanes_length[lane], abs=0.5)


def test_ts_id_picks_the_single_agent_s_light_and_reward_dicts_pick_lights(nets):
    d = nets / "RESCO" / "grid4x4"
    files = dict(net_file=str(d / "grid4x4.net.xml"), route_file=str(d / "grid4x4_1.rou.xml"), num_seconds=60)
    env = gym.make("smlworld/TrafficSignal-v0", ts_id="B1", **files)
    assert env.unwrapped.ts_ids[0] == "B1"
    obs, info = env.reset(seed=0)
    b1 = env.unwrapped.traffic_signals["B1"]
    assert obs.shape == (b1.num_green_phases + 1 + 2 * len(b1.lanes),)
    with pytest.raises(ValueError, match=r"ts_id 'Z9' is not a traffic light"):
        smlworld.envs.TrafficSignalEnv(ts_id="Z9", **files)
    two = smlworld.envs.TrafficSignalEnv(reward_fn={"A0": "queue", "D3": "pressure"}, **files)
    assert two.ts_ids == ["A0", "D3"]
    two.reset(seed=0)
    for _ in range(6):
        _, rewards, _, _ = two.step({"A0": 1, "D3": 0})
    assert rewards["A0"] == -two.traffic_signals["A0"].get_total_queued()
    assert rewards["D3"] == two.traffic_signals["D3"].get_pressure()


def test_sim_step_values_that_do_not_divide_a_second_are_refused(two_way):
    net, rou = two_way
    for bad in (0.3, 0.0, -1.0, 2.0, float("nan"), "1", True):
        with pytest.raises(ValueError, match=r"sim_step must"):
            smlworld.envs.TrafficSignalEnv(net_file=net, route_file=rou, sim_step=bad)
    env = smlworld.envs.TrafficSignalEnv(net_file=net, route_file=rou, sim_step=0.25)
    assert env.sim_step_length == 0.25
    assert env._overrides["rates.dynamics"] == 4.0 and env._overrides["rates.control"] == 4.0
    # Explicit overrides win over sim_step's rates.
    env = smlworld.envs.TrafficSignalEnv(
        net_file=net, route_file=rou, sim_step=1.0, overrides={"rates.dynamics": 10.0}
    )
    assert env._overrides["rates.dynamics"] == 10.0 and env._overrides["rates.control"] == 1.0


def test_one_second_steps_on_two_way_run_without_collisions_or_red_entries(two_way, monkeypatch):
    """At SUMO's 1 s step (sumo-rl's default) vehicles stop at the line on red, enter behind a
    queue that reaches the lane's start and track their turns: 600 s of the file's program on
    2way + vhvh, as the 50 Hz run (before the step-aware stop, entry and look-ahead: 76
    collisions, 52 vehicles over the line on red and a gridlock at 0.25-0.5 s)."""
    monkeypatch.setattr(smlworld.Sim, "stop_metrics", lambda self: None)
    net, rou = two_way
    env = smlworld.envs.TrafficSignalEnv(net_file=net, route_file=rou, num_seconds=600, sim_step=1.0, fixed_ts=True)
    env.reset(seed=0)
    done = False
    while not done:
        _, _, dones, _ = env.step(None)
        done = dones["__all__"]
    m = env._sim.summary()["metrics"]
    assert m["collision_count"] == 0, m["collisions"][:5]
    assert m["red_light_crossings"] == 0
    # SUMO inserts about 400 of the 422 due in 600 s; the 50 Hz run 320 and arrives 237.
    assert m["trips"]["inserted"] > 300 and m["trips"]["arrived"] > 220, m["trips"]
    st = env._sim.states()
    assert len(st["id"]) < 100


def test_sumo_rl_nets_honours_the_variable_and_names_both_ways_when_missing(monkeypatch, tmp_path):
    monkeypatch.setenv("SUMO_RL_NETS", str(tmp_path))
    assert sumo_rl_nets() == tmp_path
    monkeypatch.delenv("SUMO_RL_NETS")
    monkeypatch.setattr(importlib.util, "find_spec", lambda name: None)
    with pytest.raises(FileNotFoundError, match="pip install sumo-rl.*SUMO_RL_NETS"):
        sumo_rl_nets()
