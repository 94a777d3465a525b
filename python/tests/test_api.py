"""The core API: stepping, states, readings, commands, Python controllers, V2V bytes, maps."""

import math

import numpy as np
import pytest

import smlworld

PLATOON = "scenarios/platoon_brake.toml"


@pytest.fixture
def sim(root):
    return smlworld.Sim.from_scenario(root / PLATOON, seed=3, duration=10.0)


def test_step_advances_time_and_states_are_sorted_columns(sim):
    assert sim.time == 0.0
    s0 = sim.states()
    assert list(s0) == ["id", "x", "y", "yaw", "vx", "vy", "lanelet", "lane_offset"]
    assert s0["id"].tolist() == [-5, -4, -3, -2, -1]
    sim.step(0.5)
    assert sim.time == pytest.approx(0.5)
    s1 = sim.states()
    # the trucks drive at 15 m/s: in 0.5 s each moves about 7.5 m
    moved = np.hypot(s1["x"] - s0["x"], s1["y"] - s0["y"])
    assert np.all((moved > 7.0) & (moved < 8.0)), moved
    speeds = np.hypot(s1["vx"], s1["vy"])
    assert speeds[-1] == pytest.approx(15.0)  # the leader cruises
    assert np.all((speeds > 12.0) & (speeds <= 15.0 + 1e-9))  # followers open their gaps


def test_stepping_in_chunks_equals_one_step(root):
    a = smlworld.Sim.from_scenario(root / PLATOON, seed=3)
    b = smlworld.Sim.from_scenario(root / PLATOON, seed=3)
    a.step(3.0)
    for _ in range(30):
        b.step(0.1)
    for k in ("x", "y", "vx", "vy"):
        assert np.array_equal(a.states()[k], b.states()[k])


def test_run_returns_the_summary(sim):
    summary = sim.run(10.0)
    assert summary["sim_seconds"] == pytest.approx(10.0)
    assert summary["vehicles"] == 5
    assert summary["seed"] == 3
    assert summary["metrics"]["collision_count"] == 0


def test_readings_nearest_first(sim):
    sim.step(1.0)
    r = sim.readings(-2)  # the truck behind the leader sees it with its radar
    assert r.shape[1] == 5 and r.shape[0] >= 1
    assert r[0, 0] == -1
    st = sim.states()
    me = np.array([st["x"][st["id"] == -2][0], st["y"][st["id"] == -2][0]])
    d = np.hypot(r[:, 1] - me[0], r[:, 2] - me[1])
    assert np.all(np.diff(d) >= 0)
    assert 15.0 < d[0] < 30.0  # 21.5 m between centres at the start


def test_each_reading_names_the_sensor_that_saw_it(sim):
    sim.step(1.0)
    r, names = sim.readings(-2), sim.reading_sensors(-2)
    assert len(names) == r.shape[0] >= 1
    # the leader ahead is in the truck's radar cone
    assert names[0] == "radar"
    assert set(names) <= {"radar", "velodyne", "omniscient"}
    with pytest.raises(ValueError):
        sim.reading_sensors(42)


def test_set_commands_brakes_a_vehicle(root):
    sim = smlworld.Sim.from_scenario(root / PLATOON, seed=3)
    ids = np.array([-1])
    # a Python controller that brakes the leader hard at every control tick overrides nothing
    # of the followers and stops the leader
    sim.add_controller(ids, lambda obs: {"throttle": np.full(len(obs["id"]), -60000.0)}, rate=20.0)
    v0 = float(np.hypot(*[sim.states()[k][sim.states()["id"] == -1][0] for k in ("vx", "vy")]))
    sim.step(1.0)
    st = sim.states()
    v1 = float(np.hypot(st["vx"][st["id"] == -1][0], st["vy"][st["id"] == -1][0]))
    assert v1 < v0 - 3.0, (v0, v1)


def test_followers_of_a_python_leader_braking_at_6_ms2_brake_with_it(root):
    """Issue 22 item 5: platoon_brake with its leader driven by a Python controller
    (``add_controller``) that brakes at 6 m/s² to a stop from 10 s on (before the scenario's
    own stop at 30 s): the leader's V2V beacons carry the deceleration its commands give, so
    the CACC followers brake with it: no collision, every follower's minimum gap above 1 m."""
    sim = smlworld.Sim.from_scenario(root / PLATOON, seed=1)
    model = sim.models()
    leader = model["id"] == -1
    mass, drag = float(model["mass"][leader][0]), float(model["drag"][leader][0])
    stopped = []

    def brake(obs):
        v = np.hypot(obs["vx"], obs["vy"])
        if obs["time"][0] < 10.0:
            accel = np.clip(0.8 * (15.0 - v), -1.0, 1.0)  # [m/s²] cruise at 15 m/s
        else:
            accel = np.where(v > 0.3, -6.0, 0.0)  # [m/s²] brake hard, then stay stopped
            stopped.append(bool(v[0] < 0.5))
        throttle = np.where(v > 0.3, mass * accel + drag * v, np.minimum(mass * accel, 0.0))
        return {"throttle": throttle}

    sim.add_controller([-1], brake, rate=20.0)
    summary = sim.run(25.0)
    assert sim.time == pytest.approx(25.0)
    assert stopped and stopped[-1], "the leader stopped"
    metrics = summary["metrics"]
    assert metrics["collision_count"] == 0, metrics["collisions"]
    followers = metrics["followers"]
    assert sorted(f["id"] for f in followers) == [-5, -4, -3, -2]
    for f in followers:
        assert f["min_gap"] > 1.0, f


def test_python_controller_called_once_per_tick_for_the_batch(root):
    sim = smlworld.Sim.from_scenario(root / PLATOON, seed=3)
    calls = []

    def fn(obs):
        calls.append((obs["time"][0], obs["id"].tolist()))
        return {}

    sim.add_controller([-2, -3], fn, rate=20.0)
    sim.step(1.0)
    assert len(calls) == 20
    assert calls[0][1] == [-2, -3]
    assert [round(t, 6) for t, _ in calls] == [round(k / 20.0, 6) for k in range(20)]


def test_v2v_bytes_round_trip(sim):
    sim.send(-1, "wifi", b"hello")
    sim.step(0.05)  # the wifi round at t = 0 delivers it (10 Hz rounds, 20 Hz control)
    got = sim.inbox(-2, "wifi")
    assert (-1, b"hello") in got
    assert all(s != -2 for s, _ in got)
    assert (-1, b"hello") not in sim.inbox(-1, "wifi")  # never to itself
    far = sim.inbox(-5, "wifi")  # 86 m behind the leader: beyond the 50 m wifi range
    assert (-1, b"hello") not in far


def test_load_map_route_and_loop(root):
    m = smlworld.load_map(root / "maps/highway_ring.osm")
    assert len(m.lanelets) > 0
    assert m.successors.shape[1] == 2
    loop = m.loop("right_lane_node")
    assert loop.shape[1] == 2 and loop.shape[0] > 10
    # a closed loop: consecutive points are close, and the ring is hundreds of metres long
    seg = np.hypot(*np.diff(loop, axis=0).T)
    assert seg.max() < 5.0
    assert seg.sum() > 200.0
    # Issue 22 item 12: route ends are node ids or tag values, like the CLI's --from/--from-tag.
    by_tag = m.route("right_lane_node", "right_lane_node")
    assert by_tag.shape[1] == 2 and np.hypot(*np.diff(by_tag, axis=0).T).sum() > 200.0
    assert np.array_equal(by_tag, m.route(-590, "right_lane_node"))  # node -590 carries the tag
    with pytest.raises(ValueError, match="no route in lane|not connected"):
        m.route("right_lane_node", "left_lane_node")
    with pytest.raises(ValueError, match="node id .* or a node tag"):
        m.route(1.5, "right_lane_node")


def test_frame_is_an_rgba_picture_of_the_map(sim, tmp_path):
    sim.step(1.0)
    img = sim.frame(width=320, height=240)
    assert img.shape == (240, 320, 4) and img.dtype == np.uint8
    assert (img[..., 3] == 255).all()
    # roads, grass and vehicles: many distinct colours, not a blank image
    colours = np.unique(img.reshape(-1, 4), axis=0)
    assert len(colours) > 20
    with pytest.raises(ValueError, match="frame size"):
        sim.frame(width=0, height=10)


def test_change_lane_is_carried_out_by_the_plugin_and_refused_where_the_map_forbids(root):
    # The overtaking car (id -2) is in the right lane of a two-lane ring, the truck 60 m ahead.
    sim = smlworld.Sim.from_scenario(root / "scenarios/overtaking.toml", duration=20.0)
    sim.step(0.1)
    lane_before = int(sim.states()["lanelet"][sim.states()["id"].tolist().index(-2)])
    assert sim.change_lane(-2, "right") is False  # no lane to the right of the right lane
    assert sim.change_lane(-2, "left") is True
    summary = sim.run(12.0)
    changes = [c for c in summary["metrics"]["lane_changes"] if c["id"] == -2]
    assert changes and changes[0]["kind"] == "requested" and changes[0]["direction"] == "left", changes
    assert changes[0]["from"] == lane_before
    with pytest.raises(ValueError, match="left.*right|side"):
        sim.change_lane(-2, "up")


def test_star_overrides_set_every_element_like_the_cli(root):
    sim = smlworld.Sim.from_scenario(root / PLATOON, **{"vehicles.*.speed": 7.0})
    sim.step(0.2)
    speeds = np.hypot(sim.states()["vx"], sim.states()["vy"])
    assert np.all(speeds < 7.5), speeds  # every truck starts at 7 m/s instead of 15
    # A misspelt key gets the file's error, naming the key and what is allowed.
    with pytest.raises(ValueError, match="unknown field `sped`, expected one of .*`speed`"):
        smlworld.Sim.from_scenario(root / PLATOON, **{"vehicles.*.sped": 7.0})


def test_quickstart_example_shows_a_sane_platoon(root):
    """The README quickstart's script and figure (issue 22 item 5): the followers of its
    Python-driven leader track its speed wave (before the fix they braked at 30 s for the
    leader's scripted stop while the leader sped up), string stable, without collision."""
    import runpy

    g = runpy.run_path(str(root / "examples/python_quickstart.py"), run_name="quickstart")
    times, speeds, ids, metrics = np.array(g["times"]), g["speeds"], list(g["ids"]), g["metrics"]
    assert (root / "out/python_quickstart.png").exists()
    assert metrics["collision_count"] == 0, metrics["collisions"]
    assert metrics["platoons"][0]["string_stable"], metrics["platoons"]
    lead = speeds[:, ids.index(-1)]
    late = times > 5.0  # after the start-up
    for vid in (-2, -3, -4, -5):
        off = np.abs(speeds[late, ids.index(vid)] - lead[late]).max()
        assert off < 1.5, f"truck {vid} strays {off:.1f} m/s from the leader's speed"


# -- what learning environments step with (issue 20 item 3's speed) ------------------------------

MERGE = "python/smlworld/data/highway_merge.toml"


def _merge_sim(root, seed, **overrides):
    return smlworld.Sim.from_scenario(root / MERGE, seed=seed, **overrides)


def _same_states(a, b):
    sa, sb = a.states(), b.states()
    return sa.keys() == sb.keys() and all(np.array_equal(sa[k], sb[k], equal_nan=True) for k in sa)


def test_restart_is_a_fresh_load_with_the_new_seed_and_keeps_the_overrides(root):
    sim = _merge_sim(root, 3, **{"traffic.0.count": 5})
    sim.step(2.0)
    sim.restart(8)
    assert sim.time == 0.0 and sim._core.seed == 8
    fresh = _merge_sim(root, 8, **{"traffic.0.count": 5})
    for _ in range(20):
        assert _same_states(sim, fresh)
        sim.step(0.5)
        fresh.step(0.5)
    assert len(sim.states()["id"]) == len(fresh.states()["id"])
    sim.restart()  # the seed of the run now: 8 again
    other = _merge_sim(root, 9, **{"traffic.0.count": 5})
    sim.step(5.0)
    other.step(5.0)
    fresh = _merge_sim(root, 8, **{"traffic.0.count": 5})
    fresh.step(5.0)
    assert _same_states(sim, fresh) and not _same_states(sim, other)
    with pytest.raises(ValueError, match="seed"):
        sim.restart(-1)


def test_stopping_the_metrics_keeps_every_trajectory_and_records_nothing_more(root):
    a, b = _merge_sim(root, 5), _merge_sim(root, 5)
    b.stop_metrics()
    for _ in range(30):
        a.step(0.5)
        b.step(0.5)
        assert _same_states(a, b)
    assert a.summary()["metrics"]["followers"] and not b.summary()["metrics"]["followers"]
    b.restart(5)  # a restarted session records none either
    b.step(10.0)
    assert not b.summary()["metrics"]["followers"]


def _kinematics_reference(states, ego, nearest, length, width):
    """The observation HighwayMerge-v0 built in numpy before it moved to Rust."""
    ids = states["id"]
    k = int(np.searchsorted(ids, ego))
    x, y, vx, vy = states["x"], states["y"], states["vx"], states["vy"]
    dx, dy = x - x[k], y - y[k]
    others = np.flatnonzero(ids != ego)
    collided = bool(np.any((np.abs(dx[others]) < length) & (np.abs(dy[others]) < width)))
    near = others[np.argsort(np.hypot(dx[others], dy[others]), kind="stable")[:nearest]]
    rows = np.zeros((nearest + 1, 5))
    rows[0] = [1.0, x[k], y[k], vx[k], vy[k]]
    rows[1 : 1 + len(near)] = np.stack(
        [np.ones(len(near)), dx[near], dy[near], vx[near] - vx[k], vy[near] - vy[k]], axis=1
    )
    return rows, float(np.hypot(vx[k], vy[k])), collided


def test_kinematics_equals_the_numpy_observation_it_replaces(root):
    sim = _merge_sim(root, 2)
    checked_collision = False
    for step in range(40):
        for nearest, footprint in ((5, (4.5, 1.8)), (20, (4.5, 1.8)), (3, (60.0, 4.0))):
            rows, speed, collided = sim.kinematics(-1, nearest, footprint)
            ref_rows, ref_speed, ref_collided = _kinematics_reference(sim.states(), -1, nearest, *footprint)
            assert rows.shape == (nearest + 1, 5)
            assert np.array_equal(rows, ref_rows), (step, nearest, rows, ref_rows)
            assert speed == ref_speed and collided == ref_collided
            checked_collision |= collided
        sim.step(0.5)
    assert checked_collision  # the 60 m box catches a neighbour at some point
    assert np.all(sim.kinematics(-1, 20)[0][-1] == 0.0)  # fewer vehicles than rows: zero rows
    with pytest.raises(ValueError, match="unknown vehicle id 42"):
        sim.kinematics(42)


def test_drive_is_change_lane_set_commands_step_and_kinematics_in_one_call(root):
    a, b = _merge_sim(root, 6), _merge_sim(root, 6)
    for k in range(30):
        change = (None, "right", "left")[k % 3]
        throttle = 800.0 * math.sin(k)
        got = a.drive(-1, throttle, change, 0.5, 5, (4.5, 1.8))
        if change is not None:
            b.change_lane(-1, change)
        b.set_commands([-1], throttle=[throttle])
        b.step(0.5)
        want = b.kinematics(-1, 5, (4.5, 1.8))
        assert np.array_equal(got[0], want[0]) and got[1:] == want[1:]
        assert _same_states(a, b)
    with pytest.raises(ValueError, match="side"):
        a.drive(-1, 0.0, "up", 0.5)
    with pytest.raises(ValueError, match="dt"):
        a.drive(-1, 0.0, None, -1.0)
    with pytest.raises(ValueError, match="finite"):
        a.drive(-1, float("nan"), None, 0.5)
