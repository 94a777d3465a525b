//! SUMO demand (`.rou.xml`): vehicle types, vehicles, flows and trips, each turned into a
//! [`DemandGroup`]: the lanelets its vehicles drive (routed on the map read by [`super`]) and
//! when they depart.
//!
//! Read (SUMO's `docs/web/docs/Definition_of_Vehicles,_Vehicle_Types,_and_Routes.md`):
//! - `<vType>`: `length`, `minGap`, `accel`, `decel`, `maxSpeed`, `tau`, `vClass`, and the IDM
//!   parameter `delta` (with `carFollowModel="IDM"`; other models are driven by our IDM with the
//!   same parameters); SUMO's defaults (5 m, 2.5 m, 2.6 m/s², 4.5 m/s², 55.56 m/s, 1 s) where
//!   absent, `DEFAULT_VEHTYPE` when a vehicle names none;
//! - `<route id edges>`, and a `<route edges>` inside a `<vehicle>` or `<flow>`;
//! - `<vehicle id depart route>`, `<flow id begin end vehsPerHour|period|probability|number>`
//!   (`period="exp(X)"`: Poisson arrivals of rate X), `<trip from to [via]>` and the same as a
//!   flow with `from`/`to` (routed on load, shortest by length over lanes open to passenger cars);
//! - `departLane` (a lane index, or `best`/`free`/`random`/`allowed`: every lane of the first
//!   edge from which the route can be driven, `first`: lane 0), `departSpeed` (a number [m/s],
//!   or `max`/`desired`/`best`/`speedLimit`: the vehicle's desired speed; SUMO's default 0).
//!
//! The route of a group runs, edge by edge, on the lanes from which the next edge is reached
//! (SUMO's connections, through the junction's internal lanes); where no lane of an edge leads
//! on to the route's end, lane changes on the edges join it ([`EdgeIndex::route_with_changes`],
//! driven by the lane-change plugin). A route over edges that no connection joins even so is a
//! [`MapError::Sumo`] naming the file, line, element id and the two
//! edges; so is a flow without a rate, a route, type or edge the files do not define.

use std::collections::{BTreeMap, BTreeSet, BinaryHeap};
use std::path::{Path as FsPath, PathBuf};

use super::super::error::{Location, MapError, MapWarning};
use super::super::lane_routing::LaneRoute;
use super::super::lanelet::{LaneletId, LaneletMap};
use super::super::neighbours::Neighbours;
use super::super::opendrive::xml::{Element, parse_root};

/// A `<vType>` with SUMO's defaults for what it does not say.
#[derive(Debug, Clone, PartialEq)]
pub struct VehicleType {
    /// Type id.
    pub id: String,
    /// Body length \[m\].
    pub length: f64,
    /// Standstill gap to the leader \[m\] (IDM s₀).
    pub min_gap: f64,
    /// Maximum acceleration [m/s²].
    pub accel: f64,
    /// Comfortable deceleration [m/s²].
    pub decel: f64,
    /// Top speed [m/s].
    pub max_speed: f64,
    /// Desired time headway \[s\] (IDM T).
    pub tau: f64,
    /// IDM acceleration exponent δ.
    pub delta: f64,
    /// SUMO vehicle class (`passenger`, `truck`, `bus`, ...).
    pub class: String,
}

impl VehicleType {
    /// SUMO's `DEFAULT_VEHTYPE` (a passenger car, Krauss parameters).
    pub fn sumo_default(id: &str) -> VehicleType {
        VehicleType {
            id: id.to_string(),
            length: 5.0,
            min_gap: 2.5,
            accel: 2.6,
            decel: 4.5,
            max_speed: 55.56,
            tau: 1.0,
            delta: 4.0,
            class: "passenger".into(),
        }
    }
}

/// When the vehicles of a group depart.
#[derive(Debug, Clone, PartialEq)]
pub enum Departures {
    /// At these times \[s\], sorted.
    Times(Vec<f64>),
    /// One vehicle each second with probability `p`, from `begin` to `end` \[s\].
    Probability {
        /// First second \[s\].
        begin: f64,
        /// No departure at or after \[s\].
        end: f64,
        /// Chance per second.
        p: f64,
    },
    /// Poisson arrivals of `rate` [1/s] from `begin` to `end` \[s\] (`period="exp(rate)"`).
    Poisson {
        /// Start \[s\].
        begin: f64,
        /// End \[s\].
        end: f64,
        /// Rate [1/s].
        rate: f64,
    },
}

/// How fast a vehicle enters.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum DepartSpeed {
    /// This speed [m/s] (at most its desired speed).
    Given(f64),
    /// Its desired speed (SUMO `max`, `desired`, `best`, `speedLimit`).
    Desired,
}

/// One vehicle, flow or trip of the demand, routed.
#[derive(Debug, Clone, PartialEq)]
pub struct DemandGroup {
    /// Element id.
    pub id: String,
    /// Element name (`vehicle`, `flow`, `trip`).
    pub kind: String,
    /// File and line, for messages.
    pub at: String,
    /// Index into [`Demand::types`].
    pub vtype: usize,
    /// Routes by start lane: the lanelets driven from each usable start lane (junction links
    /// included), in order.
    pub routes: Vec<Vec<LaneletId>>,
    /// When its vehicles depart.
    pub departures: Departures,
    /// Speed on entry.
    pub depart_speed: DepartSpeed,
    /// Speed limit of the first lane [m/s] (the desired speed is at most this).
    pub first_speed_limit: f64,
    /// Where the route needs lane changes (a turn reached from other lanes than the one that
    /// comes in): the route lane by lane, and `routes` end where the first change must be made.
    /// `None`: every start lane drives the whole route without a change.
    pub lane_route: Option<LaneRoute>,
}

/// Everything the demand files define.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Demand {
    /// Vehicle types (`DEFAULT_VEHTYPE` first).
    pub types: Vec<VehicleType>,
    /// Vehicles, flows and trips in file order.
    pub groups: Vec<DemandGroup>,
    /// What was not read.
    pub warnings: Vec<MapWarning>,
}

/// Lanes of the SUMO net by edge, and where each lane leads.
pub struct EdgeIndex {
    /// Lanelet indices of each normal edge's routable lanes, by lane index (`None`: closed).
    lanes: BTreeMap<String, Vec<Option<usize>>>,
    /// Edge id of every lanelet of a normal lane.
    edge_of: Vec<Option<String>>,
    /// Lane-change neighbours of every lanelet.
    neighbours: Vec<Neighbours>,
}

/// A route over edges, lane by lane: the start routes and, where it needs lane changes, the
/// route for the lane-change plugin.
pub type LaneRoutes = (Vec<Vec<LaneletId>>, Option<LaneRoute>);

impl EdgeIndex {
    /// The index of a map read from a SUMO net (lanelet tags `sumo:edge`, `sumo:index`).
    pub fn new(map: &LaneletMap) -> EdgeIndex {
        let mut lanes: BTreeMap<String, Vec<Option<usize>>> = BTreeMap::new();
        let mut edge_of = vec![None; map.lanelets.len()];
        for (i, l) in map.lanelets.iter().enumerate() {
            if l.tags.contains_key("sumo:function") {
                continue;
            }
            let (Some(edge), Some(k)) =
                (l.tags.get("sumo:edge"), l.tags.get("sumo:index").and_then(|k| k.parse::<usize>().ok()))
            else {
                continue;
            };
            let list = lanes.entry(edge.clone()).or_default();
            if list.len() <= k {
                list.resize(k + 1, None);
            }
            if l.routable {
                list[k] = Some(i);
                edge_of[i] = Some(edge.clone());
            }
        }
        EdgeIndex { lanes, edge_of, neighbours: map.neighbours() }
    }

    /// Whether the net has an edge of this id.
    pub fn has_edge(&self, edge: &str) -> bool {
        self.lanes.contains_key(edge)
    }

    /// Where lanelet `i` (of a normal lane) leads: (internal lanelets passed, the next normal
    /// lane's lanelet), in successor order.
    fn next(&self, map: &LaneletMap, i: usize) -> Vec<(Option<usize>, usize)> {
        let mut out = Vec::new();
        for s in &map.lanelets[i].successors {
            let Some(j) = map.lanelet_index(*s).filter(|&j| map.lanelets[j].routable) else { continue };
            if self.edge_of[j].is_some() {
                out.push((None, j));
                continue;
            }
            for s2 in &map.lanelets[j].successors {
                if let Some(k) = map.lanelet_index(*s2).filter(|&k| self.edge_of[k].is_some()) {
                    out.push((Some(j), k));
                }
            }
        }
        out
    }

    /// The lanelets driven along `edges` from each usable start lane (only `lane` where given),
    /// without lane changes where every edge's next is reached from a lane that drives on; else
    /// with the lane changes SUMO's vehicles make ([`EdgeIndex::route_with_changes`]). `Err`
    /// names the first pair of consecutive edges no connection joins even with lane changes
    /// (or the edge missing). `key` names the route among the simulation's goals.
    pub fn route(
        &self,
        map: &LaneletMap,
        edges: &[&str],
        lane: Option<usize>,
        key: &str,
    ) -> Result<LaneRoutes, String> {
        match self.route_strict(map, edges, lane) {
            Ok(routes) => Ok((routes, None)),
            Err(strict) => match self.route_with_changes(map, edges, lane, key) {
                Ok((routes, lane_route)) => Ok((routes, Some(lane_route))),
                // A missing edge or a departLane that cannot drive the route says so as before.
                Err(_) => Err(strict),
            },
        }
    }

    /// Lanes of edge `e` open to passenger cars.
    fn lanes_of(&self, e: &str) -> Result<Vec<usize>, String> {
        let l = self.lanes.get(e).ok_or_else(|| format!("edge {e} is not in the network"))?;
        Ok(l.iter().flatten().copied().collect())
    }

    /// The lanes of `here` from which lane changes (each into an allowed neighbour) lead into
    /// `good` (`good` included).
    fn changeable(&self, map: &LaneletMap, here: &[usize], good: &[usize]) -> Vec<usize> {
        let mut out: BTreeSet<usize> = good.iter().copied().collect();
        loop {
            let before = out.len();
            for &i in here {
                let n = self.neighbours[i];
                let into = |id: Option<LaneletId>, ok: bool| {
                    ok && id.and_then(|id| map.lanelet_index(id)).is_some_and(|j| out.contains(&j))
                };
                if into(n.left, n.change_left) || into(n.right, n.change_right) {
                    out.insert(i);
                }
            }
            if out.len() == before {
                return here.iter().copied().filter(|i| out.contains(i)).collect();
            }
        }
    }

    /// The route along `edges` where lanes may be changed on an edge (SUMO's strategic lane
    /// changes): `good[k]`, the lanes of edge `k` from which a connection leads into a lane of
    /// edge `k + 1` from which lane changes lead into `good[k + 1]` (every lane of the last edge
    /// is good). A good lane drives on along the route until it enters a lane that is not good
    /// (there the vehicle must change); the start routes are those of the good lanes of the first
    /// edge (`lane` where given, good or not, if changes lead from it to a good one).
    pub fn route_with_changes(
        &self,
        map: &LaneletMap,
        edges: &[&str],
        lane: Option<usize>,
        key: &str,
    ) -> Result<(Vec<Vec<LaneletId>>, LaneRoute), String> {
        if edges.is_empty() {
            return Err("the route has no edges".into());
        }
        let n = edges.len();
        let mut all: Vec<Vec<usize>> = Vec::with_capacity(n);
        for e in edges {
            all.push(self.lanes_of(e)?);
        }
        if all[n - 1].is_empty() {
            return Err(format!("edge {} has no lane open to passenger cars", edges[n - 1]));
        }
        let mut good: Vec<Vec<usize>> = vec![Vec::new(); n];
        let mut reachable: Vec<Vec<usize>> = vec![Vec::new(); n];
        good[n - 1] = all[n - 1].clone();
        reachable[n - 1] = all[n - 1].clone();
        for k in (0..n - 1).rev() {
            let next: BTreeSet<usize> = reachable[k + 1].iter().copied().collect();
            good[k] =
                all[k].iter().copied().filter(|&i| self.next(map, i).iter().any(|(_, j)| next.contains(j))).collect();
            if good[k].is_empty() {
                return Err(format!(
                    "no connection leads from edge {} to edge {} (for a passenger car, on to the route's end, even with lane changes)",
                    edges[k],
                    edges[k + 1]
                ));
            }
            reachable[k] = self.changeable(map, &all[k], &good[k]);
        }
        // The lanelets driven from lane `i` of edge `k`.
        let walk = |k: usize, i: usize, reach: &mut BTreeSet<LaneletId>| -> Vec<LaneletId> {
            let mut out = vec![map.lanelets[i].id];
            if !good[k].contains(&i) {
                return out;
            }
            reach.insert(map.lanelets[i].id);
            let mut at = i;
            for k2 in k + 1..n {
                // A good lane first, then the lane of the same index, then the first connection.
                let options = self.next(map, at);
                let pick = options
                    .iter()
                    .filter(|(_, j)| reachable[k2].contains(j))
                    .min_by_key(|(_, j)| (!good[k2].contains(j), lane_index(map, *j) != lane_index(map, at), *j))
                    .copied();
                let Some((via, j)) = pick else { break };
                if let Some(v) = via {
                    out.push(map.lanelets[v].id);
                    reach.insert(map.lanelets[v].id);
                }
                out.push(map.lanelets[j].id);
                if !good[k2].contains(&j) {
                    break;
                }
                reach.insert(map.lanelets[j].id);
                at = j;
            }
            out
        };
        let mut reach = BTreeSet::new();
        let mut lanes = BTreeMap::new();
        for (k, lanes_k) in all.iter().enumerate() {
            for &i in lanes_k {
                let ids = walk(k, i, &mut reach);
                lanes.insert(map.lanelets[i].id, ids);
            }
        }
        let starts = self.depart_lanes(edges[0], lane, &reachable[0], &good[0])?;
        let routes = starts.iter().map(|&i| lanes[&map.lanelets[i].id].clone()).collect();
        Ok((routes, LaneRoute { key: key.to_string(), reach: reach.into_iter().collect(), lanes }))
    }

    /// The lanes of `edge` a vehicle of the route departs on: lane `lane` (departLane) when it is
    /// one of `allowed` (those that can drive the route), else each of `default`.
    fn depart_lanes(
        &self,
        edge: &str,
        lane: Option<usize>,
        allowed: &[usize],
        default: &[usize],
    ) -> Result<Vec<usize>, String> {
        let Some(n) = lane else { return Ok(default.to_vec()) };
        let i = self.lanes.get(edge).and_then(|l| l.get(n).copied().flatten());
        match i.filter(|i| allowed.contains(i)) {
            Some(i) => Ok(vec![i]),
            None => Err(format!("departLane {n} of edge {edge} cannot drive this route")),
        }
    }

    /// [`EdgeIndex::route`] without lane changes.
    fn route_strict(
        &self,
        map: &LaneletMap,
        edges: &[&str],
        lane: Option<usize>,
    ) -> Result<Vec<Vec<LaneletId>>, String> {
        if edges.is_empty() {
            return Err("the route has no edges".into());
        }
        // ok[k]: lanes of edge k from which the rest of the route can be driven.
        let mut ok: Vec<Vec<usize>> = vec![Vec::new(); edges.len()];
        ok[edges.len() - 1] = self.lanes_of(edges[edges.len() - 1])?;
        if ok[edges.len() - 1].is_empty() {
            return Err(format!("edge {} has no lane open to passenger cars", edges[edges.len() - 1]));
        }
        for k in (0..edges.len() - 1).rev() {
            let here = self.lanes_of(edges[k])?;
            let next: BTreeSet<usize> = ok[k + 1].iter().copied().collect();
            ok[k] = here.into_iter().filter(|&i| self.next(map, i).iter().any(|(_, j)| next.contains(j))).collect();
            if ok[k].is_empty() {
                return Err(format!(
                    "no connection leads from edge {} to edge {} (for a passenger car, on to the route's end)",
                    edges[k],
                    edges[k + 1]
                ));
            }
        }
        let starts = self.depart_lanes(edges[0], lane, &ok[0], &ok[0])?;
        let mut routes = Vec::with_capacity(starts.len());
        for s in starts {
            let mut out = vec![map.lanelets[s].id];
            let mut at = s;
            for next_ok in ok.iter().skip(1) {
                // Prefer the lane of the same index, then the first connection.
                let options = self.next(map, at);
                let pick = options
                    .iter()
                    .filter(|(_, j)| next_ok.contains(j))
                    .min_by_key(|(_, j)| (lane_index(map, *j) != lane_index(map, at), *j))
                    .copied();
                let Some((via, j)) = pick else { break };
                if let Some(v) = via {
                    out.push(map.lanelets[v].id);
                }
                out.push(map.lanelets[j].id);
                at = j;
            }
            routes.push(out);
        }
        Ok(routes)
    }

    /// The shortest edge sequence (by lane length) from edge `from` to edge `to`.
    pub fn shortest(&self, map: &LaneletMap, from: &str, to: &str) -> Option<Vec<String>> {
        let length = |e: &str| {
            self.lanes.get(e).and_then(|l| l.iter().flatten().next()).map_or(0.0, |&i| map.lanelets[i].length)
        };
        let mut best: BTreeMap<String, (f64, Option<String>)> = BTreeMap::new();
        // Max-heap on negated cost (ties by edge id, so the result does not depend on order).
        let mut heap: BinaryHeap<(std::cmp::Reverse<u64>, String)> = BinaryHeap::new();
        let key = |c: f64| std::cmp::Reverse((c * 1000.0).round() as u64);
        best.insert(from.to_string(), (0.0, None));
        heap.push((key(0.0), from.to_string()));
        while let Some((_, e)) = heap.pop() {
            let cost = best[&e].0;
            if e == to {
                let mut path = vec![e.clone()];
                let mut at = e;
                while let Some(p) = best[&at].1.clone() {
                    path.push(p.clone());
                    at = p;
                }
                path.reverse();
                return Some(path);
            }
            let here = cost + length(&e);
            let mut seen = BTreeSet::new();
            for &i in self.lanes.get(&e).into_iter().flatten().flatten() {
                for (_, j) in self.next(map, i) {
                    let Some(next) = self.edge_of[j].clone() else { continue };
                    if !seen.insert(next.clone()) {
                        continue;
                    }
                    if best.get(&next).is_none_or(|(c, _)| here < *c) {
                        best.insert(next.clone(), (here, Some(e.clone())));
                        heap.push((key(here), next));
                    }
                }
            }
        }
        None
    }
}

/// The SUMO lane index of lanelet `i` (its `sumo:index` tag; empty for none): routes prefer to
/// go on in the lane of the same index.
fn lane_index(map: &LaneletMap, i: usize) -> &str {
    map.lanelets[i].tags.get("sumo:index").map_or("", String::as_str)
}

/// Reads an optional number attribute of an element, or says which and why not.
type NumberAttr<'a> = dyn Fn(&Element, &str) -> Result<Option<f64>, MapError> + 'a;

/// Reads demand files against one network.
struct Reader<'m> {
    map: &'m LaneletMap,
    index: EdgeIndex,
    until: f64,
    demand: Demand,
    types: BTreeMap<String, usize>,
    routes: BTreeMap<String, Vec<String>>,
}

impl<'a> Reader<'a> {
    /// A reader for the network `map` that drops departures after `until` [s], knowing only
    /// SUMO's default vehicle type.
    fn new(map: &'a LaneletMap, until: f64) -> Reader<'a> {
        Reader {
            map,
            index: EdgeIndex::new(map),
            until,
            demand: Demand { types: vec![VehicleType::sumo_default("DEFAULT_VEHTYPE")], ..Demand::default() },
            types: BTreeMap::from([("DEFAULT_VEHTYPE".to_string(), 0)]),
            routes: BTreeMap::new(),
        }
    }
}

impl Demand {
    /// Read `files` (in order: a type or route defined in one is seen by the later ones) for
    /// the SUMO network `map`, with the clock starting at SUMO time `begin` \[s\] (a `.sumocfg`'s
    /// `begin`: departures before it are dropped, the others move `begin` earlier); departures
    /// more than `until` \[s\] after `begin` are dropped.
    pub fn load(files: &[PathBuf], map: &LaneletMap, begin: f64, until: f64) -> Result<Demand, MapError> {
        let mut r = Reader::new(map, begin + until);
        for f in files {
            let text = std::fs::read_to_string(f).map_err(|source| MapError::Io { path: f.clone(), source })?;
            r.file(&text, f)?;
        }
        if begin != 0.0 {
            for g in &mut r.demand.groups {
                match &mut g.departures {
                    Departures::Times(t) => {
                        t.retain(|&x| x >= begin);
                        t.iter_mut().for_each(|x| *x -= begin);
                    }
                    Departures::Probability { begin: b, end, .. } | Departures::Poisson { begin: b, end, .. } => {
                        *b = (*b - begin).max(0.0);
                        *end -= begin;
                    }
                }
            }
        }
        Ok(r.demand)
    }

    /// Read demand text; `source` names the file in messages.
    pub fn parse_str(text: &str, source: &FsPath, map: &LaneletMap, until: f64) -> Result<Demand, MapError> {
        let mut r = Reader::new(map, until);
        r.file(text, source)?;
        Ok(r.demand)
    }
}

impl Reader<'_> {
    fn file(&mut self, text: &str, source: &FsPath) -> Result<(), MapError> {
        let at = |el: &Element| Location { file: source.to_path_buf(), line: el.line };
        let err = |el: &Element, message: String| MapError::Sumo { at: at(el), message };
        let root = parse_root(text, source)?.ok_or_else(|| MapError::Sumo {
            at: Location { file: source.to_path_buf(), line: 0 },
            message: "no root element; expected <routes>".into(),
        })?;
        let num = |el: &Element, name: &str| -> Result<Option<f64>, MapError> {
            match el.attr(name) {
                None => Ok(None),
                Some(v) => v.trim().parse::<f64>().ok().filter(|x| x.is_finite()).map(Some).ok_or_else(|| {
                    err(el, format!("<{}> {}: `{name}` = `{v}` is not a number", el.name, el.attr("id").unwrap_or("")))
                }),
            }
        };
        let id_of = |el: &Element| -> Result<String, MapError> {
            el.attr("id").map(str::to_string).ok_or_else(|| err(el, format!("<{}> has no `id`", el.name)))
        };
        let mut unknown: BTreeMap<&str, usize> = BTreeMap::new();
        for el in &root.children {
            match el.name.as_str() {
                "vType" => {
                    let id = id_of(el)?;
                    let d = VehicleType::sumo_default(&id);
                    let mut t = VehicleType {
                        length: num(el, "length")?.unwrap_or(d.length),
                        min_gap: num(el, "minGap")?.unwrap_or(d.min_gap),
                        accel: num(el, "accel")?.unwrap_or(d.accel),
                        decel: num(el, "decel")?.unwrap_or(d.decel),
                        max_speed: num(el, "maxSpeed")?.unwrap_or(d.max_speed),
                        tau: num(el, "tau")?.unwrap_or(d.tau),
                        delta: num(el, "delta")?.unwrap_or(d.delta),
                        class: el.attr("vClass").unwrap_or("passenger").to_string(),
                        id: id.clone(),
                    };
                    // `<carFollowing-IDM .../>` children carry the model's parameters too.
                    for cf in el.children.iter().filter(|c| c.name.starts_with("carFollowing")) {
                        t.accel = num(cf, "accel")?.unwrap_or(t.accel);
                        t.decel = num(cf, "decel")?.unwrap_or(t.decel);
                        t.tau = num(cf, "tau")?.unwrap_or(t.tau);
                        t.delta = num(cf, "delta")?.unwrap_or(t.delta);
                    }
                    for (name, v) in
                        [("length", t.length), ("accel", t.accel), ("decel", t.decel), ("maxSpeed", t.max_speed)]
                    {
                        if v <= 0.0 {
                            return Err(err(el, format!("vType {id}: `{name}` must be above 0")));
                        }
                    }
                    match self.types.get(&id) {
                        Some(0) => self.demand.types[0] = t,
                        Some(_) => return Err(err(el, format!("vType {id} is defined twice"))),
                        None => {
                            self.types.insert(id, self.demand.types.len());
                            self.demand.types.push(t);
                        }
                    }
                }
                "route" => {
                    let id = id_of(el)?;
                    let edges = el.attr("edges").ok_or_else(|| err(el, format!("route {id} has no `edges`")))?;
                    self.routes.insert(id, edges.split_whitespace().map(str::to_string).collect());
                }
                "vehicle" | "flow" | "trip" => self.group(el, &at, &num, &id_of)?,
                "interval" => {
                    unknown.entry("interval").or_insert(el.line);
                }
                other => {
                    unknown.entry(other).or_insert(el.line);
                }
            }
        }
        for (name, line) in unknown {
            self.demand.warnings.push(MapWarning {
                at: Location { file: source.to_path_buf(), line }.to_string(),
                message: format!("<{name}> is not read; ignored"),
            });
        }
        Ok(())
    }

    fn group(
        &mut self,
        el: &Element,
        at: &dyn Fn(&Element) -> Location,
        num: &NumberAttr<'_>,
        id_of: &dyn Fn(&Element) -> Result<String, MapError>,
    ) -> Result<(), MapError> {
        let err = |message: String| MapError::Sumo { at: at(el), message };
        let id = id_of(el)?;
        let what = format!("{} {id}", el.name);
        let vtype = match el.attr("type") {
            None => 0,
            Some(t) => *self
                .types
                .get(t)
                .ok_or_else(|| err(format!("{what}: vType {t} is not defined (define it before its first use)")))?,
        };
        let from_to = el.attr("from").zip(el.attr("to"));
        let edges: Vec<String> = if let Some(r) = el.child("route") {
            let edges = r.attr("edges").ok_or_else(|| err(format!("{what}: its <route> has no `edges`")))?;
            edges.split_whitespace().map(str::to_string).collect()
        } else if let Some(r) = el.attr("route") {
            self.routes.get(r).cloned().ok_or_else(|| err(format!("{what}: route {r} is not defined")))?
        } else if let Some((from, to)) = from_to {
            let mut stops = vec![from];
            stops.extend(el.attr("via").unwrap_or("").split_whitespace());
            stops.push(to);
            let mut edges: Vec<String> = Vec::new();
            for w in stops.windows(2) {
                for e in [w[0], w[1]] {
                    if !self.index.has_edge(e) {
                        return Err(err(format!("{what}: edge {e} is not in the network")));
                    }
                }
                let leg = self
                    .index
                    .shortest(self.map, w[0], w[1])
                    .ok_or_else(|| err(format!("{what}: no route from edge {} to edge {}", w[0], w[1])))?;
                let skip = usize::from(!edges.is_empty());
                edges.extend(leg.into_iter().skip(skip));
            }
            edges
        } else {
            return Err(err(format!("{what}: no `route`, <route edges> or `from`/`to`")));
        };
        let lane = match el.attr("departLane") {
            None | Some("best" | "free" | "random" | "allowed" | "random_free" | "first_allowed") => None,
            Some("first") => Some(0),
            Some(v) => Some(v.trim().parse::<usize>().map_err(|_| {
                err(format!("{what}: departLane `{v}` is not a lane index or best/free/random/allowed/first"))
            })?),
        };
        let edge_refs: Vec<&str> = edges.iter().map(String::as_str).collect();
        let key = format!("{} {what}", at(el));
        let (routes, lane_route) =
            self.index.route(self.map, &edge_refs, lane, &key).map_err(|m| err(format!("{what}: {m}")))?;
        let depart_speed = match el.attr("departSpeed") {
            None => DepartSpeed::Given(0.0),
            Some("max" | "desired" | "best" | "speedLimit" | "last" | "avg") => DepartSpeed::Desired,
            Some("random") => DepartSpeed::Desired,
            Some(v) => DepartSpeed::Given(
                v.trim()
                    .parse::<f64>()
                    .ok()
                    .filter(|x| *x >= 0.0)
                    .ok_or_else(|| err(format!("{what}: departSpeed `{v}` is not a speed or max/desired/best")))?,
            ),
        };
        let until = self.until;
        let departures = match el.name.as_str() {
            "flow" => {
                let begin = num(el, "begin")?.unwrap_or(0.0);
                // SUMO's default end of a flow is a day after 0.
                let end_given = num(el, "end")?;
                let end = end_given.unwrap_or(86_400.0);
                let number = num(el, "number")?.map(|n| n.max(0.0) as usize);
                let period = match el.attr("period") {
                    Some(p) if p.trim().starts_with("exp(") => {
                        let inner = p.trim().trim_start_matches("exp(").trim_end_matches(')');
                        let rate =
                            inner.parse::<f64>().ok().filter(|r| *r > 0.0).ok_or_else(|| {
                                err(format!("{what}: period `{p}` is not exp(RATE) with a rate above 0"))
                            })?;
                        let d = Departures::Poisson { begin, end: end.min(until), rate };
                        self.push(el, at, id, vtype, (routes, lane_route), d, depart_speed);
                        return Ok(());
                    }
                    Some(_) => num(el, "period")?,
                    None => num(el, "vehsPerHour")?.filter(|v| *v > 0.0).map(|v| 3600.0 / v),
                };
                if let Some(p) = num(el, "probability")? {
                    if !(0.0..=1.0).contains(&p) {
                        return Err(err(format!("{what}: probability must lie in 0..=1")));
                    }
                    let d = Departures::Probability { begin, end: end.min(until), p };
                    self.push(el, at, id, vtype, (routes, lane_route), d, depart_speed);
                    return Ok(());
                }
                let (period, count) = match (period, number) {
                    (Some(p), n) if p > 0.0 => (p, n.unwrap_or(usize::MAX)),
                    (None, Some(n)) if n > 0 && end_given.is_some() => ((end - begin) / n as f64, n),
                    (None, Some(n)) if n > 0 => (1.0, n),
                    _ => {
                        return Err(err(format!(
                            "{what}: a flow needs a rate: `vehsPerHour`, `period`, `probability` or `number` (with `end`)"
                        )));
                    }
                };
                let mut times = Vec::new();
                let mut k = 0usize;
                loop {
                    let t = begin + k as f64 * period;
                    if k >= count || t >= end || t > until {
                        break;
                    }
                    times.push(t);
                    k += 1;
                }
                Departures::Times(times)
            }
            _ => {
                let v = el.attr("depart").ok_or_else(|| err(format!("{what}: no `depart` time")))?;
                let t = v.trim().parse::<f64>().ok().filter(|t| t.is_finite() && *t >= 0.0).ok_or_else(|| {
                    err(format!("{what}: depart `{v}` is not a time in seconds (triggered and containerTriggered are not supported)"))
                })?;
                Departures::Times(if t <= until { vec![t] } else { Vec::new() })
            }
        };
        self.push(el, at, id, vtype, (routes, lane_route), departures, depart_speed);
        Ok(())
    }

    #[allow(clippy::too_many_arguments)]
    fn push(
        &mut self,
        el: &Element,
        at: &dyn Fn(&Element) -> Location,
        id: String,
        vtype: usize,
        (routes, lane_route): LaneRoutes,
        departures: Departures,
        depart_speed: DepartSpeed,
    ) {
        let first_speed_limit = routes
            .first()
            .and_then(|r| r.first())
            .and_then(|l| self.map.lanelet(*l))
            .and_then(|l| l.tags.get("speed_limit"))
            .and_then(|v| v.parse::<f64>().ok())
            .map_or(13.89, |kmh| kmh / 3.6);
        self.demand.groups.push(DemandGroup {
            id,
            kind: el.name.clone(),
            at: at(el).to_string(),
            vtype,
            routes,
            departures,
            depart_speed,
            first_speed_limit,
            lane_route,
        });
    }
}
