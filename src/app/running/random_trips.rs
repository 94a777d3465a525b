//! Random trips (`[[traffic]] route = "random"`): an origin and a destination lanelet drawn with
//! probability proportional to their length (so every metre of road is equally likely, as
//! SUMO's `randomTrips.py` weighs edges by length), joined by the shortest route over the map's
//! routing graph ([`LaneletMap::route_lanelets`]); pairs that no route joins, or whose route is
//! shorter than [`MIN_TRIP_M`], are redrawn up to [`TRIES`] times. Every draw is counter-based
//! ([`crate::sim::random::uniform`] of (seed, stream, vehicle, draw)), so the trip of vehicle
//! `k` depends on nothing else: a bench can give an arriving vehicle a fresh one by drawing the
//! next `k`.

use std::sync::Arc;

use crate::map::{Lanelet, LaneletId, LaneletMap, Path, RouteOptions};
use crate::sim::random::uniform;

/// Shortest route a random trip may have \[m\]: shorter ones (a lanelet to its own successor)
/// are redrawn, as they measure nothing but the insertion.
pub const MIN_TRIP_M: f64 = 50.0;
/// Draws whose destination is any lanelet; later draws pick among the lanelets the origin
/// reaches (a search over the whole map, so only where direct draws keep failing).
const DIRECT_TRIES: u64 = 4;
/// Draws of an origin and destination pair before a vehicle is given up.
pub const TRIES: u64 = 20;
/// Draw index of the first try's origin; try `t` draws `FIRST_DRAW + 2t` (origin) and
/// `FIRST_DRAW + 2t + 1` (destination). The traffic tables use draws 0 to 3 for speed, class,
/// lane and arrival time.
const FIRST_DRAW: u64 = 8;

/// One random trip.
#[derive(Debug, Clone)]
pub struct RandomTrip {
    /// Where it starts (at the lanelet's start).
    pub origin: LaneletId,
    /// Where it ends (at the lanelet's end).
    pub destination: LaneletId,
    /// The route, from the start of `origin` to the end of `destination`.
    pub path: Arc<Path>,
    /// Pairs drawn before this one was found (0: the first pair).
    pub redraws: u64,
}

/// The lanelets a trip may start and end on (the routable ones, in map order) with their
/// cumulative lengths: built once per map, then each draw is a binary search.
#[derive(Debug, Clone)]
pub struct RandomTrips {
    lanelets: Vec<LaneletId>,
    /// `cumulative[i]` = summed centre-line length of `lanelets[..=i]` [m].
    cumulative: Vec<f64>,
    opts: RouteOptions,
    /// By map index: whether a trip may end there (routable, not a junction's link).
    destination: Vec<bool>,
    /// By map index: routable successors (map indices).
    successors: Vec<Vec<u32>>,
    /// By map index: whether a successor is a junction's link (the lanelet ends at a stop line).
    before_junction: Vec<bool>,
    /// By map index: whether a trip may pass through (see [`RandomTrips::on_fast_roads`]).
    passable: Vec<bool>,
}

/// A trip does not start closer than this to a junction \[m\] (a car at 12 m/s stops in 24 m at
/// 3 m/s²): a vehicle inserted at speed just
/// before a stop line could not stop for a red light.
pub const CLEAR_OF_JUNCTIONS_M: f64 = 25.0;

impl RandomTrips {
    /// The table of `map`; routes are resampled at `points_per_meter` [points per metre].
    pub fn new(map: &LaneletMap, points_per_meter: f64) -> RandomTrips {
        RandomTrips::filtered(map, points_per_meter, |_| true, |_| true)
    }

    /// The table of `map` for trips on fast roads: they start and end on lanelets whose speed
    /// limit ([`Lanelet::speed_limit`]) is at least `min_speed_limit` [m/s] and drive through
    /// none with a lower one (a lanelet without a limit passes: OpenDRIVE's connecting roads in
    /// junctions carry none, so a motorway's junctions with its ramps stay open). A drawn pair
    /// whose shortest route leaves them is redrawn.
    pub fn on_fast_roads(map: &LaneletMap, points_per_meter: f64, min_speed_limit: f64) -> RandomTrips {
        RandomTrips::filtered(
            map,
            points_per_meter,
            |l| l.speed_limit().is_some_and(|v| v >= min_speed_limit),
            |l| l.speed_limit().is_none_or(|v| v >= min_speed_limit),
        )
    }

    /// The table of `map` for trips that start and end on lanelets `ends` accepts and drive
    /// only through lanelets `through` accepts (`ends` implies `through`).
    fn filtered(
        map: &LaneletMap,
        points_per_meter: f64,
        ends: impl Fn(&Lanelet) -> bool,
        through: impl Fn(&Lanelet) -> bool,
    ) -> RandomTrips {
        let n = map.lanelets.len();
        // Not a junction's own lanelets: a vehicle would appear in the middle of crossing traffic.
        let junctions = map.junctions();
        let link: Vec<bool> = map.lanelets.iter().map(|l| junctions.of_lanelet(l.id).is_some()).collect();
        let passable: Vec<bool> = map.lanelets.iter().map(&through).collect();
        let successors: Vec<Vec<u32>> = map
            .lanelets
            .iter()
            .map(|l| {
                l.successors
                    .iter()
                    .filter_map(|id| map.lanelet_index(*id))
                    .filter(|&j| map.lanelets[j].routable && passable[j])
                    .map(|j| j as u32)
                    .collect()
            })
            .collect();
        // Distance from each lanelet's start to the nearest junction ahead [m], up to the limit.
        let near_junction = |i: usize| {
            let mut stack = vec![(i, 0.0)];
            let mut steps = 0;
            while let Some((k, d)) = stack.pop() {
                steps += 1;
                if steps > 64 {
                    break;
                }
                let reach = d + map.lanelets[k].length;
                if reach >= CLEAR_OF_JUNCTIONS_M {
                    continue;
                }
                for &j in &successors[k] {
                    if link[j as usize] {
                        return true;
                    }
                    stack.push((j as usize, reach));
                }
            }
            false
        };
        let mut total = 0.0;
        let (mut lanelets, mut cumulative) = (Vec::new(), Vec::new());
        let destination: Vec<bool> = (0..n)
            .map(|i| {
                let l = &map.lanelets[i];
                l.routable && l.length > 0.0 && !link[i] && passable[i] && ends(l)
            })
            .collect();
        for i in (0..n).filter(|&i| destination[i] && (junctions.is_empty() || !near_junction(i))) {
            total += map.lanelets[i].length;
            lanelets.push(map.lanelets[i].id);
            cumulative.push(total);
        }
        let before_junction = successors.iter().map(|next| next.iter().any(|&j| link[j as usize])).collect();
        RandomTrips {
            lanelets,
            cumulative,
            opts: RouteOptions { points_per_meter },
            destination,
            successors,
            before_junction,
            passable,
        }
    }

    /// How much of lanelet `i` (map index) a trip may start on, from its start \[m\]: all of it,
    /// less the last [`CLEAR_OF_JUNCTIONS_M`] where it ends at a junction (a long lanelet up to
    /// a stop line is an origin, but a car placed at speed just before the line could not stop
    /// for a red light or a foe: two were, and collided, in a 10 x 10 town).
    pub fn start_room(&self, i: usize, length: f64) -> f64 {
        if self.before_junction.get(i).copied().unwrap_or(false) {
            (length - CLEAR_OF_JUNCTIONS_M).max(0.0)
        } else {
            length
        }
    }

    /// The lanelets reachable from `origin` (map index) whose end lies at least [`MIN_TRIP_M`]
    /// along the way, with the cumulative lengths of those lanelets (a breadth-first search over
    /// successors, O(lanelets)).
    fn reachable(&self, map: &LaneletMap, origin: usize) -> (Vec<usize>, Vec<f64>) {
        let mut seen = vec![false; map.lanelets.len()];
        let mut queue = std::collections::VecDeque::from([(origin, map.lanelets[origin].length)]);
        seen[origin] = true;
        let (mut out, mut cumulative, mut total) = (Vec::new(), Vec::new(), 0.0);
        while let Some((k, end)) = queue.pop_front() {
            if k != origin && self.destination[k] && end >= MIN_TRIP_M {
                total += map.lanelets[k].length;
                out.push(k);
                cumulative.push(total);
            }
            for &j in &self.successors[k] {
                if !seen[j as usize] {
                    seen[j as usize] = true;
                    queue.push_back((j as usize, end + map.lanelets[j as usize].length));
                }
            }
        }
        (out, cumulative)
    }

    /// Number of lanelets a trip may start or end on.
    pub fn len(&self) -> usize {
        self.lanelets.len()
    }

    /// Whether the map has no routable lanelet (no trip can be drawn).
    pub fn is_empty(&self) -> bool {
        self.lanelets.is_empty()
    }

    /// The lanelet a uniform number `u` in [0, 1) stands for, weighted by length.
    pub fn pick(&self, u: f64) -> Option<LaneletId> {
        weighted_index(&self.cumulative, u).map(|i| self.lanelets[i])
    }

    /// The trip of vehicle `k` of random stream `stream` under `seed`, routed on `map` (the map
    /// the table was built from); `None` when [`TRIES`] pairs all failed (no route, the same
    /// lanelet twice, or a route shorter than [`MIN_TRIP_M`]).
    pub fn trip(&self, map: &LaneletMap, seed: u64, stream: u64, k: u64) -> Option<RandomTrip> {
        for t in 0..TRIES {
            let origin = self.pick(uniform(seed, stream, k, FIRST_DRAW + 2 * t))?;
            if let Some(trip) = self.try_from(map, origin, (seed, stream, k), t) {
                return Some(trip);
            }
        }
        None
    }
}

impl RandomTrips {
    /// A trip of vehicle `k` that starts on `origin` (where a vehicle arrived): destinations are
    /// drawn as in [`RandomTrips::trip`].
    pub fn trip_from(&self, map: &LaneletMap, origin: LaneletId, seed: u64, stream: u64, k: u64) -> Option<RandomTrip> {
        (0..TRIES).find_map(|t| self.try_from(map, origin, (seed, stream, k), t))
    }

    /// Draw `t` of a destination for a trip from `origin` ((seed, stream, vehicle) keys the
    /// draw): any lanelet for the first [`DIRECT_TRIES`], then one the origin reaches; the trip
    /// when a route of at least [`MIN_TRIP_M`] joins them.
    fn try_from(&self, map: &LaneletMap, origin: LaneletId, key: (u64, u64, u64), t: u64) -> Option<RandomTrip> {
        let (seed, stream, k) = key;
        let o = map.lanelet_index(origin)?;
        let u = uniform(seed, stream, k, FIRST_DRAW + 2 * t + 1);
        let destination = if t < DIRECT_TRIES {
            // Any lanelet: on a connected map (a grid) almost every pair has a route.
            self.pick(u).filter(|d| *d != origin)?
        } else {
            // Among the lanelets this origin reaches: a map in several pieces (Lanelet2's
            // example) would otherwise waste most draws on pairs no route joins.
            let (reach, cumulative) = self.reachable(map, o);
            map.lanelets[reach[weighted_index(&cumulative, u)?]].id
        };
        let path = map.route_lanelets(origin, destination, &self.opts).ok().filter(|p| {
            p.length >= MIN_TRIP_M
                && p.lanelets.iter().all(|id| map.lanelet_index(*id).is_some_and(|i| self.passable[i]))
        })?;
        Some(RandomTrip { origin, destination, path: Arc::new(path), redraws: t })
    }
}

/// The random route of vehicle `k` of stream `stream` under `seed` on `map`, resampled at 5
/// points per metre; `None` when no route was found in [`TRIES`] draws. Builds the lanelet table
/// on every call (O(lanelets)): for many draws keep a [`RandomTrips`] and call
/// [`RandomTrips::trip`].
pub fn random_route(map: &LaneletMap, seed: u64, stream: u64, k: u64) -> Option<Arc<Path>> {
    RandomTrips::new(map, RouteOptions::default().points_per_meter).trip(map, seed, stream, k).map(|t| t.path)
}

/// Index `i` with `cumulative[i - 1] <= u * total < cumulative[i]` (`total` the last entry) for
/// rising `cumulative` sums of non-negative weights: item `i` is drawn with probability
/// `weight_i / total`. `None` when there is nothing to draw (empty or all zero); `u` is clamped
/// to [0, 1).
pub fn weighted_index(cumulative: &[f64], u: f64) -> Option<usize> {
    let total = *cumulative.last()?;
    if total <= 0.0 || !u.is_finite() {
        return None;
    }
    let x = u.clamp(0.0, 1.0) * total;
    let i = cumulative.partition_point(|&c| c <= x);
    Some(i.min(cumulative.len() - 1))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_weighted_draw_picks_each_item_by_its_share() {
        // Weights 1, 0, 3: item 1 never, item 2 three times as often as item 0.
        let cumulative = [1.0, 1.0, 4.0];
        assert_eq!(weighted_index(&cumulative, 0.0), Some(0));
        assert_eq!(weighted_index(&cumulative, 0.2499), Some(0));
        assert_eq!(weighted_index(&cumulative, 0.25), Some(2));
        assert_eq!(weighted_index(&cumulative, 0.9999), Some(2));
        assert_eq!(weighted_index(&cumulative, 1.0), Some(2), "u = 1 stays on the last item");
        let mut counts = [0u32; 3];
        let n = 40_000;
        for k in 0..n {
            counts[weighted_index(&cumulative, uniform(1, 2, k, 0)).expect("weights above 0")] += 1;
        }
        assert_eq!(counts[1], 0, "a zero weight is never drawn");
        let share = f64::from(counts[2]) / f64::from(n as u32);
        assert!((share - 0.75).abs() < 0.01, "share of the weight-3 item: {share}");
    }

    #[test]
    fn nothing_is_drawn_from_no_weight() {
        assert_eq!(weighted_index(&[], 0.5), None);
        assert_eq!(weighted_index(&[0.0, 0.0], 0.5), None);
        assert_eq!(weighted_index(&[2.0], f64::NAN), None);
    }
}
