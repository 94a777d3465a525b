"""Issue 57: `smlworld run --mcap` and `replay --mcap` write MCAP files that the tools robotics labs
use read back (PyPI `mcap`, `mcap-protobuf-support`); `--foxglove` serves the same channels over
the Foxglove WebSocket protocol (a `websockets` client subscribes while a run goes)."""

import asyncio
import csv
import json
import socket
import struct
import subprocess
from collections import defaultdict
from pathlib import Path

import pytest

mcap_reader = pytest.importorskip("mcap.reader")
mcap_protobuf = pytest.importorskip("mcap_protobuf.decoder")


def decode_all(path: Path):
    """Every message of every channel, decoded: (topic, log_time [ns], message, schema name)."""
    factory = mcap_protobuf.DecoderFactory()
    out = []
    with open(path, "rb") as f:
        reader = mcap_reader.make_reader(f)
        summary = reader.get_summary()
        assert summary is not None and summary.chunk_indexes, "the file has an index of its chunks"
        assert {c.compression for c in summary.chunk_indexes} == {"zstd"}
        for schema, channel, message in reader.iter_messages(log_time_order=True):
            if channel.message_encoding == "json":
                decoded = json.loads(message.data)
            else:
                assert channel.message_encoding == "protobuf", channel.topic
                decoder = factory.decoder_for(channel.message_encoding, schema)
                assert decoder is not None, channel.topic
                decoded = decoder(message.data)
            out.append((channel.topic, message.log_time, decoded, schema.name if schema else ""))
    return out


def rows_by_time(csv_path: Path):
    """trajectories.csv as {t_us: {id: (x, y)}}."""
    rows = defaultdict(dict)
    with open(csv_path) as f:
        for r in csv.DictReader(f):
            t_us = round(float(r["t"]) * 1e6)
            rows[t_us][int(r["id"])] = (float(r["x"]), float(r["y"]))
    return rows


def check_recording(messages, rows):
    """The channels match trajectories.csv (issue 57's Done-when)."""
    topics = defaultdict(list)
    for topic, t_ns, msg, schema in messages:
        topics[topic].append((t_ns, msg, schema))
    assert [s for _, _, s in topics["/vehicles"]][:1] == ["foxglove.SceneUpdate"]
    # One /vehicles message per log tick, at the tick's sim time (the CSV has rows only at the
    # ticks that had vehicles: a traffic run starts empty).
    vehicle_times = [t for t, _, _ in topics["/vehicles"]]
    assert len(vehicle_times) == len(set(vehicle_times))
    assert [t for t, m, _ in topics["/vehicles"] if m.entities] == sorted(t_us * 1000 for t_us in rows)
    ticks = [t // 1000 for t in vehicle_times]
    # /tf: vehicle/<id> at each log time is that vehicle's x, y in the CSV (1 mm).
    tf_times = []
    for t_ns, msg, _ in topics["/tf"]:
        t_us = t_ns // 1000
        tf_times.append(t_ns)
        seen = {}
        for tr in msg.transforms:
            if tr.child_frame_id.startswith("vehicle/"):
                assert tr.parent_frame_id == "world"
                seen[int(tr.child_frame_id.split("/")[1])] = (tr.translation.x, tr.translation.y)
        assert set(seen) == set(rows.get(t_us, {})), t_us
        for vid, (x, y) in rows.get(t_us, {}).items():
            assert abs(seen[vid][0] - x) <= 1e-3 and abs(seen[vid][1] - y) <= 1e-3, (t_us, vid)
    assert tf_times == vehicle_times
    # Entities of departed vehicles are deleted at the first tick without them.
    for (t_ns, msg, _), before, now in zip(topics["/vehicles"][1:], ticks, ticks[1:]):
        gone = set(rows.get(before, {})) - set(rows.get(now, {}))
        deleted = {int(d.id.split("/")[1]) for d in msg.deletions}
        assert deleted == gone, t_ns
        assert {e.id for e in msg.entities} == {f"vehicle/{i}" for i in rows.get(now, {})}
    # /map once at t = 0 with lines; /metrics once at the end holding summary.json.
    assert len(topics["/map"]) == 1 and topics["/map"][0][0] == 0
    assert any(p.points for e in topics["/map"][0][1].entities for p in e.lines)
    assert len(topics["/metrics"]) == 1 and "sim_seconds" in topics["/metrics"][0][1]
    # Per-vehicle state: JSON with the plottable fields.
    states = [k for k in topics if k.startswith("/vehicle/") and k.endswith("/state")]
    assert len(states) == len({i for r in rows.values() for i in r})
    first = topics[states[0]][0][1]
    assert {"x", "y", "yaw", "speed", "accel", "lanelet", "lane_offset", "mode"} <= set(first)
    return topics


def run(cli, root, tmp_path, scenario, duration, *extra):
    out = tmp_path / "out"
    mcap = tmp_path / "run.mcap"
    subprocess.run(
        [str(cli), "run", str(root / "scenarios" / scenario), "--out", str(out), "--duration", str(duration),
         "--mcap", str(mcap), *extra],
        check=True, capture_output=True, text=True, timeout=300,
    )
    return out, mcap


def test_run_writes_an_mcap_file_that_matches_the_csv(cli, root, tmp_path):
    # Background traffic leaves at its route's end: departures and deletions happen.
    out, mcap = run(cli, root, tmp_path, "lane_drop.toml", 60)
    assert not list(tmp_path.glob(".*.partial")), "the temporary file was renamed into place"
    rows = rows_by_time(out / "trajectories.csv")
    all_ids = [set(r) for r in rows.values()]
    assert any(a - b for a, b in zip(all_ids, all_ids[1:])), "some vehicle leaves in this run"
    topics = check_recording(decode_all(mcap), rows)
    # Events: the lane changes and vehicles leaving as foxglove.Log lines.
    names = {m.name for _, m, _ in topics["/events"]}
    assert {"vehicle"} <= names and names & {"lane_change", "merge"}, names
    # A map with a geographic origin: LocationFix per vehicle.
    gps = [k for k in topics if k.startswith("/gps/")]
    assert gps and all(-90 <= m.latitude <= 90 for _, m, _ in topics[gps[0]])


def test_images_and_v2v(cli, root, tmp_path):
    out, mcap = run(cli, root, tmp_path, "platoon_brake.toml", 3, "--mcap-images", "2")
    topics = check_recording(decode_all(mcap), rows_by_time(out / "trajectories.csv"))
    images = topics["/camera/birdseye"]
    assert len(images) >= 6 and images[0][1].format == "png" and images[0][1].data[:4] == b"\x89PNG"
    v2v = topics["/v2v"]
    assert v2v and {"wifi", "network"} <= set(v2v[-1][1]) and v2v[-1][1]["wifi"]["sent"] > 0


def test_replay_writes_the_same_ticks(cli, root, tmp_path):
    out, _ = run(cli, root, tmp_path, "lane_drop.toml", 20)
    replayed = tmp_path / "replay.mcap"
    subprocess.run([str(cli), "replay", str(out), "--mcap", str(replayed)], check=True, capture_output=True,
                   text=True, timeout=300)
    check_recording(decode_all(replayed), rows_by_time(out / "trajectories.csv"))


def test_a_bad_mcap_path_is_an_error_that_names_it(cli, root, tmp_path):
    bad = tmp_path / "missing" / "run.mcap"
    r = subprocess.run(
        [str(cli), "run", str(root / "scenarios" / "highway.toml"), "--out", str(tmp_path / "o"), "--duration", "1",
         "--mcap", str(bad)],
        capture_output=True, text=True, timeout=120,
    )
    assert r.returncode != 0 and str(bad) in r.stderr and "panicked" not in r.stderr


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def test_live_foxglove_server_streams_vehicles(cli, root, tmp_path):
    websockets = pytest.importorskip("websockets")
    from foxglove_schemas_protobuf.SceneUpdate_pb2 import SceneUpdate

    port = free_port()
    proc = subprocess.Popen(
        [str(cli), "run", str(root / "scenarios" / "highway.toml"), "--out", str(tmp_path / "o"), "--duration", "30",
         "--realtime", "--foxglove", f"127.0.0.1:{port}"],
        stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True,
    )

    async def client():
        for _ in range(100):
            try:
                # The SDK's server speaks `foxglove.sdk.v1` (the `foxglove.websocket.v1` protocol
                # renamed); a client offers both, as Foxglove and Lichtblick do.
                ws = await websockets.connect(f"ws://127.0.0.1:{port}", max_size=None,
                                              subprotocols=["foxglove.sdk.v1", "foxglove.websocket.v1"])
                break
            except OSError:
                await asyncio.sleep(0.1)
        else:
            raise AssertionError("the server did not start")
        async with ws:
            assert ws.subprotocol in ("foxglove.sdk.v1", "foxglove.websocket.v1")
            channels = {}
            while "/vehicles" not in channels:
                msg = json.loads(await asyncio.wait_for(ws.recv(), 10))
                if msg.get("op") == "advertise":
                    channels.update({c["topic"]: c for c in msg["channels"]})
            assert {"/tf", "/map", "/events"} <= set(channels)
            await ws.send(json.dumps({"op": "subscribe",
                                      "subscriptions": [{"id": 7, "channelId": channels["/vehicles"]["id"]}]}))
            scenes = []
            while len(scenes) < 3:
                data = await asyncio.wait_for(ws.recv(), 10)
                if isinstance(data, bytes) and data[0] == 1:
                    sub_id, t_ns = struct.unpack_from("<IQ", data, 1)
                    assert sub_id == 7
                    scene = SceneUpdate()
                    scene.ParseFromString(data[13:])
                    scenes.append((t_ns, scene))
            assert all(len(s.entities) == 12 for _, s in scenes)
            assert [t for t, _ in scenes] == sorted(t for t, _ in scenes)

    try:
        asyncio.run(asyncio.wait_for(client(), 60))
    finally:
        proc.terminate()
        proc.wait(timeout=30)


def test_ros2_profile_reads_with_rosbags(cli, root, tmp_path):
    pytest.importorskip("rosbags")
    from rosbags.rosbag2 import Reader
    from rosbags.typesys import Stores, get_typestore, get_types_from_msg

    out, mcap = run(cli, root, tmp_path, "lane_drop.toml", 20, "--mcap-profile", "ros2")
    rows = rows_by_time(out / "trajectories.csv")
    store = get_typestore(Stores.ROS2_HUMBLE)
    counts = defaultdict(int)
    with Reader(mcap) as reader:
        kinds = {c.topic: c.msgtype for c in reader.connections}
        assert kinds["/tf"] == "tf2_msgs/msg/TFMessage"
        assert kinds["/clock"] == "rosgraph_msgs/msg/Clock"
        assert kinds["/vehicles"] == kinds["/map"] == "visualization_msgs/msg/MarkerArray"
        odoms = [t for t in kinds if t.endswith("/odom")]
        assert odoms and all(kinds[t] == "nav_msgs/msg/Odometry" for t in odoms)
        for c in reader.connections:
            # The embedded definitions parse (what `ros2 bag play` and rosbags read them by).
            assert get_types_from_msg(c.msgdef.data, c.msgtype), c.topic
        for conn, t_ns, raw in reader.messages():
            msg = store.deserialize_cdr(raw, conn.msgtype)
            counts[conn.topic.split("/")[-1] if conn.topic.endswith("/odom") else conn.topic] += 1
            if conn.topic.endswith("/odom"):
                vid = int(conn.topic.split("/")[2])
                x, y = rows[t_ns // 1000][vid]
                assert msg.child_frame_id == f"vehicle/{vid}"
                assert abs(msg.pose.pose.position.x - x) <= 1e-3 and abs(msg.pose.pose.position.y - y) <= 1e-3
            elif conn.topic == "/clock":
                assert msg.clock.sec * 10**9 + msg.clock.nanosec == t_ns
            elif conn.topic == "/tf":
                assert {tr.child_frame_id for tr in msg.transforms} == {f"vehicle/{i}" for i in rows.get(t_ns // 1000, {})}
    assert counts["odom"] == sum(len(r) for r in rows.values())
    assert counts["/map"] == 1 and counts["/vehicles"] == counts["/clock"] == counts["/tf"]


def test_vehicles_making_way_for_an_emergency_vehicle_are_events(cli, root, tmp_path):
    out, mcap = run(cli, root, tmp_path, "emergency_vehicle.toml", 30)
    topics = check_recording(decode_all(mcap), rows_by_time(out / "trajectories.csv"))
    lines = [m.message for _, m, _ in topics["/events"] if m.name == "emergency"]
    assert any("makes way for an emergency vehicle" in line for line in lines), lines


def test_the_scenario_output_key_records_into_the_output_folder(cli, root, tmp_path):
    out = tmp_path / "out"
    subprocess.run(
        [str(cli), "run", str(root / "scenarios" / "highway.toml"), "--out", str(out), "--duration", "2",
         "--set", 'output.mcap="run.mcap"'],
        check=True, capture_output=True, text=True, timeout=120,
    )
    check_recording(decode_all(out / "run.mcap"), rows_by_time(out / "trajectories.csv"))
