"""Writes the small hand-made CommonRoad test scenarios of this folder (2018b and 2020a).

Run from this folder: `python3 make_files.py`. The road: two lanes eastwards from x = 0 to 100 m
(lanelets 1 -> 2 on the right, y 0..3.5 m; 3 -> 4 on the left, y 3.5..7 m; each link listed as
successor and as predecessor, as commonroad-io expects), then lanelet 5 curving left after
lanelet 2. Obstacle 100 drives the left lane at 10 m/s with a small weave; obstacle 101 drives
the right lane at 5 m/s from x = 40 m for 8 s; the planning problem's ego starts at x = 5 m on the
right lane at 12 m/s, goal a 10 m x 4 m rectangle around (70, 1.75) m by step 200.
"""

import math

DT = 0.1


def pt(x, y, indent):
    return f"{indent}<point>\n{indent}  <x>{x:.4f}</x>\n{indent}  <y>{y:.4f}</y>\n{indent}</point>\n"


def bound(tag, pts, marking):
    s = f"    <{tag}>\n"
    for x, y in pts:
        s += pt(x, y, "      ")
    if marking:
        s += f"      <lineMarking>{marking}</lineMarking>\n"
    return s + f"    </{tag}>\n"


def straight(x0, x1, y, n=6):
    return [(x0 + (x1 - x0) * k / (n - 1), y) for k in range(n)]


def arc(r, y_centre, start_x, n=8):
    # quarter-circle-ish curve to the left, centre (start_x, y_centre + ...)
    return [(start_x + r * math.sin(a), y_centre - r * math.cos(a)) for a in [k * (math.pi / 4) / (n - 1) for k in range(n)]]


def lanelet(lid, left, right, lm, rm, pred=(), succ=(), adj_left=None, adj_right=None, ltype=True):
    s = f'  <lanelet id="{lid}">\n'
    s += bound("leftBound", left, lm)
    s += bound("rightBound", right, rm)
    for p in pred:
        s += f'    <predecessor ref="{p}"/>\n'
    for p in succ:
        s += f'    <successor ref="{p}"/>\n'
    if adj_left:
        s += f'    <adjacentLeft ref="{adj_left}" drivingDir="same"/>\n'
    if adj_right:
        s += f'    <adjacentRight ref="{adj_right}" drivingDir="same"/>\n'
    if ltype:
        s += "    <laneletType>highway</laneletType>\n"
    return s + "  </lanelet>\n"


def state(tag, x, y, yaw, t, v, indent="    ", initial=False):
    s = f"{indent}<{tag}>\n"
    s += f"{indent}  <position>\n" + pt(x, y, indent + "    ") + f"{indent}  </position>\n"
    s += f"{indent}  <orientation>\n{indent}    <exact>{yaw:.6f}</exact>\n{indent}  </orientation>\n"
    s += f"{indent}  <time>\n{indent}    <exact>{t}</exact>\n{indent}  </time>\n"
    s += f"{indent}  <velocity>\n{indent}    <exact>{v:.4f}</exact>\n{indent}  </velocity>\n"
    if initial:
        for k in ["acceleration", "yawRate", "slipAngle"]:
            s += f"{indent}  <{k}>\n{indent}    <exact>0.0</exact>\n{indent}  </{k}>\n"
    return s + f"{indent}</{tag}>\n"


def obstacle(oid, version, states, length=4.5, width=1.8):
    head = f'  <dynamicObstacle id="{oid}">\n' if version == "2020a" else f'  <obstacle id="{oid}">\n    <role>dynamic</role>\n'
    s = head + "    <type>car</type>\n"
    s += f"    <shape>\n      <rectangle>\n        <length>{length}</length>\n        <width>{width}</width>\n      </rectangle>\n    </shape>\n"
    s += state("initialState", *states[0], indent="    ", initial=True)
    s += "    <trajectory>\n"
    for st in states[1:]:
        s += state("state", *st, indent="      ")
    s += "    </trajectory>\n"
    return s + ("  </dynamicObstacle>\n" if version == "2020a" else "  </obstacle>\n")


def scenario(version):
    out = f"<?xml version='1.0' encoding='UTF-8'?>\n"
    out += f'<commonRoad timeStepSize="{DT}" commonRoadVersion="{version}" author="SML World tests" affiliation="KTH" source="hand-made" benchmarkID="SWE_SmlTest-1_1_T-1" date="2026-11-23"' + (' tags="highway"' if version == "2018b" else "") + ">\n"
    if version == "2020a":
        out += "  <location>\n    <geoNameId>-999</geoNameId>\n    <gpsLatitude>999</gpsLatitude>\n    <gpsLongitude>999</gpsLongitude>\n  </location>\n"
        out += "  <scenarioTags>\n    <Highway/>\n  </scenarioTags>\n"
    lt = version == "2020a"
    out += lanelet(1, straight(0, 50, 3.5), straight(0, 50, 0), "dashed", "solid", succ=[2], adj_left=3, ltype=lt)
    out += lanelet(2, straight(50, 100, 3.5), straight(50, 100, 0), "dashed", "solid", pred=[1], succ=[5], adj_left=4, ltype=lt)
    out += lanelet(3, straight(0, 50, 7), straight(0, 50, 3.5), "solid", "dashed", succ=[4], adj_right=1, ltype=lt)
    out += lanelet(4, straight(50, 100, 7), straight(50, 100, 3.5), "solid", "dashed", pred=[3], adj_right=2, ltype=lt)
    # Lanelet 5 curves left around (100, 40): right bound radius 40, left bound radius 36.5.
    right = arc(40.0, 40.0, 100.0)
    left = arc(36.5, 40.0, 100.0)
    out += lanelet(5, left, right, "solid", "solid", pred=[2], ltype=lt)
    # Obstacle 100: 10 m/s along the left lane from x = 10 m, weaving +-0.3 m, 40 steps.
    s100 = []
    for k in range(41):
        x = 10.0 + 1.0 * k + 0.0123 * k
        y = 5.25 + 0.3 * math.sin(k / 5.0)
        yaw = math.atan2(0.3 / 5.0 * math.cos(k / 5.0), 1.0123)
        s100.append((x, y, yaw, k, 10.123))
    out += obstacle(100, version, s100)
    # Obstacle 101: 5 m/s along the right lane from x = 40 m for 8 s (80 steps), to x = 80 m.
    s101 = [(40.0 + 0.5 * k, 1.75, 0.0, k, 5.0) for k in range(0, 81, 1)]
    out += obstacle(101, version, s101)
    out += '  <planningProblem id="200">\n'
    out += state("initialState", 5.0, 1.75, 0.0, 0, 12.0, indent="    ", initial=True)
    out += "    <goalState>\n"
    out += "      <position>\n        <rectangle>\n          <length>10.0</length>\n          <width>4.0</width>\n"
    out += "          <orientation>0.0</orientation>\n          <center>\n            <x>70.0</x>\n            <y>1.75</y>\n          </center>\n"
    out += "        </rectangle>\n      </position>\n"
    out += "      <time>\n        <intervalStart>0</intervalStart>\n        <intervalEnd>200</intervalEnd>\n      </time>\n"
    out += "    </goalState>\n  </planningProblem>\n"
    return out + "</commonRoad>\n"


for v in ["2018b", "2020a"]:
    with open(f"two_lanes_{v}.xml", "w") as f:
        f.write(scenario(v))
