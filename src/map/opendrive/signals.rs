//! Signals, controllers and junction priorities -> what [`crate::map::junctions`] reads:
//! traffic lights with one signal group per `<controller>`, and major/minor arms.
//!
//! - **Where a signal applies.** A road's `<signal>` (or `<signalReference>`, which repeats a
//!   signal of another road here) applies to the drivable lanes of the lane section at its `s`
//!   that it faces (`orientation` `+`: lanes driving along `s`, `-`: against it, `none`: both),
//!   narrowed to its `<validity fromLane toLane>` ranges where it has them (OpenDRIVE 1.8 §14.2,
//!   §14.4). From each such lane, the lanes that follow it on the same road lead to the next
//!   junction: the signal controls the junction's connecting lanelets entered from there (its
//!   **links**). A signal on a connecting road controls that lanelet itself.
//! - **Traffic lights.** The types CARLA's reader takes for lights (`SignalType::IsTrafficLight`
//!   in `LibCarla/source/carla/road/SignalType.cpp`: 1000001 the three-light signal, 1000008 to
//!   1000012, 1000014 to 1000020, ...), except the pedestrian light 1000002 (in
//!   `multi_intersections.xodr` its `validity` names lane 0 only: it faces the crosswalk, not a
//!   lane) and the pedestrian-and-bicycle and bicycle lights 1000007 and 1000013: nobody walks or
//!   cycles in this simulator, so they show nothing to a car. The signals of one top-level
//!   `<controller>` always show the same state (§14.6): they form one **signal group**, and the
//!   links they control get green together; a light in no controller is a group of its own.
//! - **Program.** A junction whose links some group controls gets a fixed-time program
//!   ([`crate::map::LaneletMap::signal_programs`], the `signal_program` and `signal_index` tags of its links,
//!   as SUMO's `<tlLogic>` gives them): each group in turn, in the order of the junction's
//!   `<controller sequence>` (file order where not given), shows green for
//!   [`DEFAULT_GREEN`] s, yellow for [`DEFAULT_YELLOW`] s, then all red for [`DEFAULT_ALL_RED`]
//!   s, the durations of the default program that Lanelet2 and generated maps get
//!   ([`crate::map::junctions::default_program`]). A link turning across the opposite traffic
//!   (left; right on left-hand roads) or back shows the yielding green `g`, as in that program;
//!   a link of the junction that no group controls (an arm without lights) shows `g` throughout.
//!   Links carry `traffic_light=yes` too, so the junction's control is `traffic_light`.
//! - **Right of way.** Static signs with German numbers (`country` `DE`, `OpenDRIVE` or none,
//!   as [`crate::map::junctions::sign_priority`] reads them for CommonRoad and Lanelet2: 205
//!   yield, 206 stop, 301 right of way at the next junction, 306 priority road) tag the links
//!   they lead to `priority=minor` or `major` (the JOSM/Lanelet2 tag the junction logic reads;
//!   a stop or yield sign wins over a priority sign). A junction's `<priority high low>` (§12:
//!   the connecting road with priority and the one that yields) tags the links of `high` major
//!   and those of `low` minor, over what signs say.
//! - Every other signal type, pedestrian lights included, gives one warning per type and country
//!   with its count and first line; a light or sign that leads to no junction link, and a
//!   reference to a signal that is not in the file, one warning each kind.

use std::collections::BTreeMap;
use std::path::Path as FsPath;

use super::road::{Document, Facing, Signal};
use crate::map::error::{Location, MapWarning};
use crate::map::junctions::{
    DEFAULT_ALL_RED, DEFAULT_GREEN, DEFAULT_YELLOW, MapSignalProgram, SignalPhase, sign_priority, wrap_angle,
};
use crate::map::lanelet::Lanelet;

/// Light types that control cars: CARLA's `IsTrafficLight` list less the pedestrian (1000002),
/// pedestrian-and-bicycle (1000007) and bicycle (1000013) lights.
pub const CAR_LIGHTS: [&str; 13] = [
    "1000001", "1000008", "1000009", "1000010", "1000011", "1000012", "1000014", "1000015", "1000016", "1000017",
    "1000018", "1000019", "1000020",
];

/// Light types for pedestrians and cyclists (read, shown to no car).
pub const OTHER_LIGHTS: [&str; 3] = ["1000002", "1000007", "1000013"];

/// Heading changes under this \[rad\] (30°) go straight on, over 150° turn back (as the
/// junction logic classifies turns).
const STRAIGHT: f64 = std::f64::consts::FRAC_PI_6;

/// A lane of the file, as the builder indexes lanelets: (road index, section index, lane id).
pub(crate) type LaneOf<'a> = &'a dyn Fn(usize, usize, i32) -> Option<usize>;

/// What a signal means here.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Meaning {
    /// A light for cars.
    Light,
    /// `priority=major` or `minor` on the links it leads to.
    Sign(&'static str),
    /// Nothing (warned once per type).
    Unused(&'static str),
}

fn meaning(sig: &Signal) -> Meaning {
    let kind = sig.kind.as_str();
    if CAR_LIGHTS.contains(&kind) {
        return Meaning::Light;
    }
    if OTHER_LIGHTS.contains(&kind) {
        return Meaning::Unused(": a light for pedestrians or cyclists, who are not simulated");
    }
    let german = matches!(sig.country.as_str(), "" | "DE" | "OpenDRIVE");
    if german && let Some(p) = sign_priority(&[kind]) {
        return Meaning::Sign(p);
    }
    Meaning::Unused(match (german, kind) {
        (true, "1000003") => ": a pedestrian crossing, and pedestrians are not simulated",
        (true, "294") => ": a stop line; vehicles stop where the junction's lanes start",
        (true, "274") => ": a speed limit sign; the lanes' <speed> records give the limits",
        _ => "",
    })
}

/// A count and the first line, for one warning per kind.
#[derive(Default)]
struct Tally {
    count: usize,
    line: usize,
}

impl Tally {
    fn add(&mut self, line: usize) {
        if self.count == 0 {
            self.line = line;
        }
        self.count += 1;
    }
}

/// The links (lanelet indices) a signal on lanelet `start` leads to: `start` itself when it is
/// a junction's connecting lanelet, else the connecting lanelets that follow the lanelets of the
/// same road after it.
fn links_ahead(lanelets: &[Lanelet], start: usize) -> Vec<usize> {
    let tag = |i: usize, k: &str| lanelets[i].tags.get(k).map(String::as_str).unwrap_or("");
    let in_junction = |i: usize| !matches!(tag(i, "opendrive:junction"), "" | "-1");
    if in_junction(start) {
        return vec![start];
    }
    let road = tag(start, "opendrive:road");
    let (mut out, mut seen, mut todo) = (Vec::new(), vec![start], vec![start]);
    while let Some(x) = todo.pop() {
        for next in &lanelets[x].successors {
            let j = next.0 as usize - 1;
            if j >= lanelets.len() || seen.contains(&j) {
                continue;
            }
            seen.push(j);
            if in_junction(j) {
                if lanelets[j].routable {
                    out.push(j);
                }
            } else if tag(j, "opendrive:road") == road {
                todo.push(j);
            }
        }
    }
    out.sort_unstable();
    out
}

/// Whether a link turns across the opposite traffic (left, on a left-hand road right) or back:
/// it shows the yielding green `g`.
fn far_turn(l: &Lanelet) -> bool {
    let c = &l.centre;
    if c.len() < 2 {
        return false;
    }
    let dir = |a: glam::DVec2, b: glam::DVec2| (b - a).y.atan2((b - a).x);
    let change = wrap_angle(dir(c[c.len() - 2], c[c.len() - 1]) - dir(c[0], c[1]));
    let left_hand = l.tags.get("driving_side").is_some_and(|v| v == "left");
    change.abs() > 5.0 * STRAIGHT || if left_hand { change < -STRAIGHT } else { change > STRAIGHT }
}

/// Reads the document's signals onto the built lanelets (tags) and returns the junctions'
/// programs. `along[i]`: lanelet `i` runs along its road's `s`.
pub(crate) fn apply(
    doc: &Document,
    lane_of: LaneOf<'_>,
    along: &[bool],
    lanelets: &mut [Lanelet],
    source: &FsPath,
    warnings: &mut Vec<MapWarning>,
) -> BTreeMap<String, MapSignalProgram> {
    let at = |line: usize| Location { file: source.to_path_buf(), line }.to_string();
    // Signals by id (ids repeat in some files: every signal of that id).
    let mut by_id: BTreeMap<&str, Vec<&Signal>> = BTreeMap::new();
    for road in &doc.roads {
        for sig in road.signals.iter().filter(|s| !s.reference) {
            by_id.entry(sig.id.as_str()).or_default().push(sig);
        }
    }
    // The controller of each signal id (the first that names it).
    let mut group_of: BTreeMap<&str, &str> = BTreeMap::new();
    for c in &doc.controllers {
        for sid in &c.signals {
            group_of.entry(sid.as_str()).or_insert(c.id.as_str());
        }
    }
    let mut unused: BTreeMap<(String, String), (Tally, &'static str)> = BTreeMap::new();
    let (mut nowhere, mut missing) = (Tally::default(), Tally::default());
    // Link -> groups of lights leading to it (group key, first line); link -> sign votes.
    let mut light_groups: BTreeMap<usize, Vec<String>> = BTreeMap::new();
    let mut signs: BTreeMap<usize, Vec<&'static str>> = BTreeMap::new();
    for (ri, road) in doc.roads.iter().enumerate() {
        for sig in &road.signals {
            // A reference takes its meaning from the signal it names.
            let kind_of = if sig.reference {
                match by_id.get(sig.id.as_str()).and_then(|v| v.first()) {
                    Some(target) => *target,
                    None => {
                        missing.add(sig.line);
                        continue;
                    }
                }
            } else {
                sig
            };
            let m = meaning(kind_of);
            if let Meaning::Unused(why) = m {
                unused
                    .entry((kind_of.kind.clone(), kind_of.country.clone()))
                    .or_insert_with(|| (Tally::default(), why))
                    .0
                    .add(sig.line);
                continue;
            }
            // The lanes it faces in the section at its s.
            let section = road.sections.iter().rposition(|x| x.s <= sig.s + 1e-9).unwrap_or(0);
            let sec = &road.sections[section];
            let valid = |id: i32| {
                sig.validity.is_empty() || sig.validity.iter().any(|&(a, b)| (a.min(b)..=a.max(b)).contains(&id))
            };
            let mut links = Vec::new();
            for lane in sec.left.iter().chain(&sec.right).filter(|l| valid(l.id)) {
                let Some(i) = lane_of(ri, section, lane.id) else { continue };
                let faces = match sig.facing {
                    Facing::Along => along[i],
                    Facing::Against => !along[i],
                    Facing::Both => true,
                };
                if faces && lanelets[i].routable {
                    links.extend(links_ahead(lanelets, i));
                }
            }
            links.sort_unstable();
            links.dedup();
            if links.is_empty() {
                nowhere.add(sig.line);
                continue;
            }
            match m {
                Meaning::Light => {
                    let group = group_of
                        .get(kind_of.id.as_str())
                        .map_or_else(|| format!("signal {}", kind_of.id), |c| format!("controller {c}"));
                    for l in links {
                        let groups = light_groups.entry(l).or_default();
                        if !groups.contains(&group) {
                            groups.push(group.clone());
                        }
                    }
                }
                Meaning::Sign(p) => {
                    for l in links {
                        signs.entry(l).or_default().push(p);
                    }
                }
                Meaning::Unused(_) => {}
            }
        }
    }
    for ((kind, country), (tally, why)) in &unused {
        let country = if country.is_empty() { "none".to_string() } else { country.clone() };
        warnings.push(MapWarning {
            at: at(tally.line),
            message: format!(
                "OpenDRIVE signal type {kind:?} (country {country}) is not used{why} ({} in the file, the first here); ignored",
                tally.count
            ),
        });
    }
    if nowhere.count > 0 {
        warnings.push(MapWarning {
            at: at(nowhere.line),
            message: format!(
                "{} OpenDRIVE traffic lights or priority signs face no drivable lane that leads into a junction (the first here); ignored",
                nowhere.count
            ),
        });
    }
    if missing.count > 0 {
        warnings.push(MapWarning {
            at: at(missing.line),
            message: format!(
                "{} <signalReference>s name a signal id that no <signal> has (the first here); ignored",
                missing.count
            ),
        });
    }

    // Programs, one per OpenDRIVE junction that lights control.
    let junction_of = |l: &Lanelet| l.tags.get("opendrive:junction").cloned().unwrap_or_default();
    let mut programs = BTreeMap::new();
    for j in &doc.junctions {
        let members: Vec<usize> =
            (0..lanelets.len()).filter(|&i| lanelets[i].routable && junction_of(&lanelets[i]) == j.id).collect();
        // Groups: the junction's controllers by `sequence` (then file order), then the rest.
        let mut order: Vec<(String, Option<i64>, usize)> =
            j.controllers.iter().enumerate().map(|(k, (c, seq))| (format!("controller {c}"), *seq, k)).collect();
        order.sort_by_key(|(_, seq, k)| (seq.unwrap_or(i64::MAX), *k));
        let mut groups: Vec<String> = Vec::new();
        let present = |g: &String| members.iter().any(|i| light_groups.get(i).is_some_and(|v| v.contains(g)));
        for (g, _, _) in &order {
            if present(g) && !groups.contains(g) {
                groups.push(g.clone());
            }
        }
        for i in &members {
            for g in light_groups.get(i).into_iter().flatten() {
                if !groups.contains(g) {
                    groups.push(g.clone());
                }
            }
        }
        if groups.is_empty() {
            if j.controlled {
                warnings.push(MapWarning {
                    at: at(j.line),
                    message: format!(
                        "junction {}: names controllers, but no light of theirs faces a lane entering it; its lanes get the default fixed-time program",
                        j.id
                    ),
                });
                for &i in &members {
                    lanelets[i].tags.insert("traffic_light".into(), "yes".into());
                }
            }
            continue;
        }
        let n = groups.len();
        let program = format!("opendrive:{}", j.id);
        for &i in &members {
            // A link two groups light goes with the first of them in the cycle.
            let k = light_groups.get(&i).and_then(|v| groups.iter().position(|g| v.contains(g)));
            let index = match k {
                Some(k) => 2 * k + usize::from(far_turn(&lanelets[i])),
                None => 2 * n,
            };
            let tags = &mut lanelets[i].tags;
            tags.insert("traffic_light".into(), "yes".into());
            tags.insert("signal_program".into(), program.clone());
            tags.insert("signal_index".into(), index.to_string());
        }
        let state = |k: usize, green: bool, lit: bool| -> String {
            (0..=2 * n)
                .map(|c| match c {
                    c if c == 2 * n => 'g',
                    c if lit && c / 2 == k => match (green, c % 2) {
                        (true, 0) => 'G',
                        (true, _) => 'g',
                        _ => 'y',
                    },
                    _ => 'r',
                })
                .collect()
        };
        let mut phases = Vec::with_capacity(3 * n);
        for k in 0..n {
            phases.push(SignalPhase { state: state(k, true, true), duration: DEFAULT_GREEN });
            phases.push(SignalPhase { state: state(k, false, true), duration: DEFAULT_YELLOW });
            phases.push(SignalPhase { state: state(k, false, false), duration: DEFAULT_ALL_RED });
        }
        programs.insert(program, MapSignalProgram { phases, offset: 0.0 });
    }

    // Right of way: junction priorities over signs; of signs, stop and yield over priority.
    let mut stated: BTreeMap<usize, &'static str> = BTreeMap::new();
    for j in &doc.junctions {
        for (high, low, _) in &j.priorities {
            for (i, l) in lanelets.iter().enumerate() {
                if junction_of(l) != j.id || !l.routable {
                    continue;
                }
                let road = l.tags.get("opendrive:road").map(String::as_str).unwrap_or("");
                if road == high {
                    stated.insert(i, "major");
                } else if road == low {
                    stated.entry(i).or_insert("minor");
                }
            }
        }
    }
    for (i, votes) in &signs {
        let p = if votes.contains(&"minor") { "minor" } else { "major" };
        lanelets[*i].tags.insert("priority".into(), p.into());
    }
    for (i, p) in stated {
        lanelets[i].tags.insert("priority".into(), p.into());
    }
    programs
}

#[cfg(test)]
mod tests {
    use std::path::Path;

    use crate::map::junctions::{JunctionControl, map_program};
    use crate::map::lanelet::LaneletMap;

    /// A road of one right lane (id -1, 3.5 m, driving along `s`) from (x, y) heading `hdg`.
    fn road(id: u32, junction: i32, (x, y): (f64, f64), hdg: f64, length: f64, links: &str, signals: &str) -> String {
        format!(
            r#"<road id="{id}" length="{length}" junction="{junction}"><link>{links}</link>
<planView><geometry s="0" x="{x}" y="{y}" hdg="{hdg}" length="{length}"><line/></geometry></planView>
<lanes><laneSection s="0"><center><lane id="0" type="none"/></center><right><lane id="-1" type="driving">
<link><predecessor id="-1"/><successor id="-1"/></link><width sOffset="0" a="3.5" b="0" c="0" d="0"/></lane></right></laneSection></lanes>
<signals>{signals}</signals></road>
"#
        )
    }

    /// Two roads crossing at the origin in junction 100: road 1 (west, heading east) through
    /// connecting road 10 to road 2, road 3 (south, heading north) through connecting road 11 to
    /// road 4. `on_1` and `on_3`: signals of roads 1 and 3; `junction`: more children of the
    /// junction; `controllers`: top-level elements.
    fn crossing(on_1: &str, on_3: &str, junction: &str, controllers: &str) -> LaneletMap {
        let half = std::f64::consts::FRAC_PI_2;
        let into = r#"<successor elementType="junction" elementId="100"/>"#;
        let from = r#"<predecessor elementType="junction" elementId="100"/>"#;
        let through = |a: u32, b: u32| {
            format!(
                r#"<predecessor elementType="road" elementId="{a}" contactPoint="end"/><successor elementType="road" elementId="{b}" contactPoint="start"/>"#
            )
        };
        let text = format!(
            r#"<?xml version="1.0"?><OpenDRIVE><header revMajor="1" revMinor="6"/>
{}{}{}{}{}{}<junction id="100">
<connection id="0" incomingRoad="1" connectingRoad="10" contactPoint="start"><laneLink from="-1" to="-1"/></connection>
<connection id="1" incomingRoad="3" connectingRoad="11" contactPoint="start"><laneLink from="-1" to="-1"/></connection>
{junction}</junction>{controllers}</OpenDRIVE>"#,
            road(1, -1, (-100.0, 0.0), 0.0, 90.0, into, on_1),
            road(2, -1, (10.0, 0.0), 0.0, 90.0, from, ""),
            road(3, -1, (0.0, -100.0), half, 90.0, into, on_3),
            road(4, -1, (0.0, 10.0), half, 90.0, from, ""),
            road(10, 100, (-10.0, 0.0), 0.0, 20.0, &through(1, 2), ""),
            road(11, 100, (0.0, -10.0), half, 20.0, &through(3, 4), ""),
        );
        super::super::parse_str(&text, Path::new("crossing.xodr")).expect("the crossing loads")
    }

    /// The links of the map's one junction on roads 10 and 11, and whether 10 yields to 11.
    fn ten_yields(map: &LaneletMap) -> (JunctionControl, Option<bool>) {
        let junctions = map.junctions();
        assert_eq!(junctions.len(), 1);
        let j = &junctions.list[0];
        let on = |road: &str| {
            map.lanelets.iter().find(|l| l.tags.get("opendrive:road").is_some_and(|r| r == road)).map(|l| l.id)
        };
        let (ten, eleven) = (on("10").expect("road 10"), on("11").expect("road 11"));
        let c = j.conflicts.iter().find(|c| (c.a == ten && c.b == eleven) || (c.a == eleven && c.b == ten));
        (j.control, c.expect("10 and 11 cross").yields_from(ten))
    }

    const SIGN: &str =
        r#"<signal id="S" s="80" t="-4" orientation="+" dynamic="no" country="OpenDRIVE" type="TYPE" subtype="-1"/>"#;

    #[test]
    fn junction_priority_and_signs_rank_the_arms() {
        // Nothing said: equal arms, right before left; 11 comes from 10's right, so 10 yields.
        assert_eq!(ten_yields(&crossing("", "", "", "")), (JunctionControl::RightBeforeLeft, Some(true)));
        // <priority high="10" low="11">: 11 yields.
        let p = crossing("", "", r#"<priority high="10" low="11"/>"#, "");
        assert_eq!(ten_yields(&p), (JunctionControl::Priority, Some(false)));
        let tags = |road: &str| {
            p.lanelets.iter().find(|l| l.tags.get("opendrive:road").is_some_and(|r| r == road)).map(|l| l.tags.clone())
        };
        assert_eq!(tags("10").unwrap().get("priority").map(String::as_str), Some("major"));
        assert_eq!(tags("11").unwrap().get("priority").map(String::as_str), Some("minor"));
        // A stop sign (206) facing road 3's lane: its arm yields.
        let stop = crossing("", &SIGN.replace("TYPE", "206"), "", "");
        assert_eq!(ten_yields(&stop), (JunctionControl::Priority, Some(false)));
        // A priority road sign (306) on road 1: its arm has the right of way.
        assert_eq!(ten_yields(&crossing(&SIGN.replace("TYPE", "306"), "", "", "")).1, Some(false));
        // A yield sign (205) facing away from the lane (orientation -) says nothing to it.
        let away = SIGN.replace("TYPE", "205").replace("orientation=\"+\"", "orientation=\"-\"");
        let away = crossing(&away, "", "", "");
        assert_eq!(ten_yields(&away), (JunctionControl::RightBeforeLeft, Some(true)));
        assert!(away.warnings.iter().any(|w| w.message.contains("face no drivable lane")), "{:?}", away.warnings);
        // The junction's priority wins over a sign.
        let both = crossing("", "", r#"<priority high="11" low="10"/>"#, "");
        assert_eq!(ten_yields(&both).1, Some(true));
    }

    #[test]
    fn lights_of_one_controller_are_one_group_and_unknown_types_warn_once() {
        let light = |id: &str| {
            format!(
                r#"<signal id="{id}" s="85" t="-4" orientation="+" dynamic="yes" country="OpenDRIVE" type="1000001" subtype="-1"/>"#
            )
        };
        let odd =
            r#"<signal id="X" s="5" t="-4" orientation="+" dynamic="no" country="OpenDRIVE" type="999" subtype="-1"/>"#;
        let walk = r#"<signal id="P" s="5" t="-4" orientation="+" dynamic="yes" country="OpenDRIVE" type="1000002" subtype="-1"/>"#;
        let map = crossing(
            &(light("L1") + odd + odd),
            &(light("L3") + walk),
            r#"<controller id="c2" sequence="2"/><controller id="c1" sequence="1"/>"#,
            r#"<controller id="c1"><control signalId="L1"/></controller><controller id="c2"><control signalId="L3"/></controller>"#,
        );
        let junctions = map.junctions();
        let j = &junctions.list[0];
        assert_eq!(j.control, JunctionControl::TrafficLight);
        let (program, _) = map_program(&map, j).expect("the file's program");
        // Controller c1 (road 1 -> link on road 10) first by its sequence, then c2 (road 11).
        let road_of = |k: usize| map.lanelet(j.links[k].lanelet).unwrap().tags["opendrive:road"].clone();
        let green: Vec<Vec<String>> = program
            .iter()
            .filter(|p| p.state.contains('G'))
            .map(|p| (0..j.links.len()).filter(|&k| p.state.as_bytes()[k] == b'G').map(road_of).collect())
            .collect();
        assert_eq!(green, vec![vec!["10".to_string()], vec!["11".to_string()]]);
        let durations: Vec<f64> = program.iter().map(|p| p.duration).collect();
        assert_eq!(durations, [27.0, 3.0, 2.0, 27.0, 3.0, 2.0]);
        // Without controllers each light is a group of its own: still two.
        let alone = crossing(&light("L1"), &light("L3"), "", "");
        let junctions = alone.junctions();
        let (program, _) = map_program(&alone, &junctions.list[0]).expect("the file's program");
        assert_eq!(program.iter().filter(|p| p.state.contains('G')).count(), 2);
        // One controller for both: one group, both green at once.
        let one = crossing(
            &light("L1"),
            &light("L3"),
            "",
            r#"<controller id="c"><control signalId="L1"/><control signalId="L3"/></controller>"#,
        );
        let junctions = one.junctions();
        let (program, _) = map_program(&one, &junctions.list[0]).expect("the file's program");
        assert_eq!(program.iter().map(|p| p.state.as_str()).collect::<Vec<_>>(), ["GG", "yy", "rr"]);
        // Type 999 warns once (two in the file), the pedestrian light once, with their lines.
        let about = |what: &str| map.warnings.iter().filter(|w| w.message.contains(what)).collect::<Vec<_>>();
        let odd = about("signal type \"999\"");
        assert_eq!(odd.len(), 1, "{:?}", map.warnings);
        assert!(odd[0].message.contains("2 in the file") && odd[0].at.starts_with("crossing.xodr:"), "{}", odd[0]);
        assert_eq!(about("signal type \"1000002\"").len(), 1, "{:?}", map.warnings);
        assert!(about("<road/signals>").is_empty() && about("<signals/signal>").is_empty(), "{:?}", map.warnings);
    }
}
