"""Python controllers run inside the Control phase of the tick they are due (issue 25 item 4):
their commands act from that tick's dynamics step, whatever chunks the caller steps by, as a
Rust controller's do; their errors are Python exceptions raised from ``Sim.step``."""

import numpy as np
import pytest

import smlworld

PLATOON = "scenarios/platoon_brake.toml"
BRAKE = -30000.0  # [N] on the leader (a 12,000 kg truck): about -2.5 m/s²
DUE = 2.0  # [s] the control tick (20 Hz) at which the controller starts braking


def _sim(root):
    return smlworld.Sim.from_scenario(root / PLATOON, seed=3)


def _brake_from(t0):
    def brake(obs):
        return {"throttle": np.full(len(obs["id"]), BRAKE)} if obs["time"][0] >= t0 else {}

    return brake


def _states(sim):
    st = sim.states()
    return np.stack([st[k] for k in ("x", "y", "yaw", "vx", "vy")])


def _run(sim, chunks):
    """Step by ``chunks`` [s], recording every vehicle's states after each."""
    out = []
    for dt in chunks:
        sim.step(dt)
        out.append((round(sim.time, 6), _states(sim)))
    return out


def test_a_python_command_acts_from_the_dynamics_step_of_the_tick_it_is_due(root):
    """The controller's braking, due at the control tick t = 2.0 s, gives the trajectory of a
    command set exactly at t = 2.0 s (bit for bit): it drives the dynamics step that starts at
    2.0 s, not one later; the states at 2.0 s are those of a run without it, those at 2.02 s
    (the next dynamics tick, 50 Hz) already differ."""
    ids = [-1]
    python = _sim(root)
    python.add_controller(ids, _brake_from(DUE), rate=20.0)
    by_python = dict(_run(python, [0.02] * 200))

    direct = _sim(root)
    direct.step(DUE)
    direct.set_commands(ids, throttle=[BRAKE])
    direct.step(4.0 - DUE)
    assert np.array_equal(by_python[4.0], _states(direct))

    free = dict(_run(_sim(root), [0.02] * 110))
    assert np.array_equal(by_python[DUE], free[DUE])
    assert not np.array_equal(by_python[DUE + 0.02], free[DUE + 0.02])

    def leader_speed(states):  # states are sorted by id (-5 ... -1): the leader is the last column
        return np.hypot(states[3, -1], states[4, -1])

    assert leader_speed(by_python[DUE + 0.02]) < leader_speed(free[DUE + 0.02])


def test_results_do_not_depend_on_how_the_caller_chunks_time(root):
    """Stepping by 13 ms, 37 ms, 1 s or in one go gives the same trajectory bit for bit: the
    controller's ticks come from the schedule, not from the caller's steps."""
    ends = []
    for chunks in ([0.013] * 300 + [0.1], [0.037] * 100 + [0.3], [1.0] * 4, [4.0]):
        sim = _sim(root)
        calls = []

        def wave(obs, calls=calls):
            calls.append(round(float(obs["time"][0]), 6))
            v = np.hypot(obs["vx"], obs["vy"])
            return {"throttle": 12000.0 * 0.8 * (15.0 + 3.0 * np.sin(obs["time"]) - v) + 3000.0}

        sim.add_controller([-1], wave, rate=20.0)
        _run(sim, chunks)
        assert sim.time == pytest.approx(4.0)
        assert calls == [round(k / 20.0, 6) for k in range(80)], calls[:5]
        ends.append(_states(sim))
    assert all(np.array_equal(ends[0], e) for e in ends[1:])


def test_the_observation_is_the_state_at_the_tick(root):
    seen = {}

    def record(obs):
        seen[round(float(obs["time"][0]), 6)] = np.stack([obs[k] for k in ("x", "y", "yaw", "vx", "vy")])
        return {}

    sim = _sim(root)
    sim.add_controller([-3, -1], record, rate=10.0)
    sim.step(1.0)
    assert sorted(seen) == [round(k / 10.0, 6) for k in range(10)]
    ref = _sim(root)
    for k in range(10):
        st = ref.states()
        rows = [int(np.flatnonzero(st["id"] == i)[0]) for i in (-3, -1)]
        expect = np.stack([st[c][rows] for c in ("x", "y", "yaw", "vx", "vy")])
        assert np.array_equal(seen[round(k / 10.0, 6)], expect), k
        ref.step(0.1)


def test_drive_runs_python_controllers(root):
    sim = smlworld.Sim.from_scenario(root / "python/smlworld/data/platoon_follow.toml", seed=1)
    calls = []
    sim.add_controller([-1], lambda obs: calls.append(obs["time"][0]) or {}, rate=20.0)
    sim.drive(-2, 0.0, None, 0.5)
    assert len(calls) == 10


def test_a_controller_added_later_starts_at_its_next_due_tick(root):
    sim = _sim(root)
    sim.step(1.01)
    calls = []
    sim.add_controller([-1], lambda obs: calls.append(round(float(obs["time"][0]), 6)) or {}, rate=10.0)
    sim.step(0.5)
    assert calls == [1.1, 1.2, 1.3, 1.4, 1.5]


def test_an_exception_in_a_callback_is_raised_from_step_at_its_tick(root):
    sim = _sim(root)

    def boom(obs):
        if obs["time"][0] >= 0.5:
            raise ZeroDivisionError("no gap")
        return {}

    sim.add_controller([-1], boom, rate=20.0)
    with pytest.raises(ZeroDivisionError, match="no gap"):
        sim.step(2.0)
    assert sim.time == pytest.approx(0.5)  # stopped at the tick that raised


@pytest.mark.parametrize(
    "result, error, message",
    [
        ({"throttle": np.array([np.nan])}, ValueError, r"throttle\[0\] = NaN for vehicle -1 at t = 0 s"),
        ({"throttle": np.array([1.0, 2.0])}, ValueError, "2 throttle values for 1 vehicles"),
        ({"gas": np.array([1.0])}, ValueError, "unknown keys"),
        ([1.0], TypeError, "must return a dict"),
    ],
)
def test_bad_results_are_python_errors(root, result, error, message):
    sim = _sim(root)
    sim.add_controller([-1], lambda obs: result, rate=20.0)
    with pytest.raises(error, match=message):
        sim.step(0.1)
    assert sim.time == 0.0


def test_a_callback_cannot_call_its_own_sim_and_rates_are_checked(root):
    sim = _sim(root)
    sim.add_controller([-1], lambda obs: sim.states() and {}, rate=20.0)
    with pytest.raises(RuntimeError, match="this Sim is stepping"):
        sim.step(0.1)
    with pytest.raises(ValueError, match="above the scenario's control rate 20"):
        _sim(root).add_controller([-1], lambda obs: {}, rate=50.0)
    with pytest.raises(ValueError, match="positive"):
        _sim(root).add_controller([-1], lambda obs: {}, rate=0.0)
