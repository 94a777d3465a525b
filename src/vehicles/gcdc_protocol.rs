//! The decision rules of the GCDC 2016 merge protocol as pure functions (no ECS): the safe gaps,
//! the zipper pairing, STOM (safe to merge), and whether a merger merges, waits or aborts. The
//! plugin ([`super::gcdc`]) feeds them what each vehicle heard over V2V.
//!
//! Sources: the 2015 lab code (`scripts/sml_world_old/vehiclesupervisorymodule.py` of
//! marinarantanen/sml_world, `scen1`: an A vehicle pairs forward with a B vehicle, opens a gap
//! and sets STOM; the B vehicle learns its backward partner, pairs forward with that partner's
//! leader, waits for the partner's STOM and changes lane; both reset their pairing when done) and
//! its lane-change safe gaps (`vehiclesupervisorymodule_old.py`: front `max(10, 0.27 v^1.5)` m,
//! rear `max(10, 0.23 v^1.5)` m). Where we depart:
//! - the 2015 STOM rule (partner more than 5 m ahead, own leader more than 20 m ahead) did not
//!   grow with speed; we ask for the speed-dependent safe gaps above on both sides of the merger;
//! - the 2015 A vehicle paired with whichever B vehicle its perception grid showed front-left,
//!   so two A vehicles could chase one B vehicle; here every vehicle computes the same zipper
//!   from the broadcasts ([`zipper_order`]) and takes its pairs from it ([`pairs_in`]), so the
//!   pairs agree without a negotiation round, and a partner that is no longer heard drops out of
//!   the zipper: the next vehicle becomes the pair (re-pairing).

use crate::world::VehicleId;

/// The gap rule of the merge (`controller.merge.gap_rule`): the bumper-to-bumper gaps a merger
/// needs in front of it and behind it at a speed.
///
/// In a scenario: `gap_rule = "sml2015"` (the default) or `gap_rule = { time_gap = 0.8,
/// standstill = 5.0 }`; anything else is refused naming the key and both forms.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub enum GapRule {
    /// The 2015 lab code's lane-change safe gaps (`vehiclesupervisorymodule_old.py` of
    /// marinarantanen/sml_world): front `max(safe_gap, 0.27 v^1.5)` \[m\], rear `max(safe_gap,
    /// 0.23 v^1.5)` \[m\] (v in m/s, `safe_gap` the minimum, 10 m in 2015): about 28 m and 24 m at
    /// 80 km/h.
    #[default]
    Sml2015,
    /// A constant time gap on both sides, `standstill + time_gap * v` \[m\]: the spacing policy of
    /// ACC and CACC (ISO 15622 asks ACC for time gaps of at least 0.8 s; the GCDC 2016 teams
    /// drove CACC at 0.5 to 1 s; IDM's `s0 + v T`, Treiber et al. 2000, is the same form).
    TimeGap {
        /// Time gap \[s\]; raising it opens longer gaps (safer, slower merge).
        time_gap: f64,
        /// Gap at standstill \[m\]: the smallest gap the rule asks for.
        standstill: f64,
    },
}

impl GapRule {
    /// Front gap \[m\] at speed `v` [m/s]: from the merger to the vehicle it merges behind.
    /// `min` \[m\] is `merge.safe_gap`, the minimum of the 2015 rule.
    pub fn front(&self, v: f64, min: f64) -> f64 {
        match *self {
            GapRule::Sml2015 => safe_gap_front(v, min),
            GapRule::TimeGap { time_gap, standstill } => standstill + time_gap * v.max(0.0),
        }
    }

    /// Rear gap \[m\] at speed `v` [m/s]: from the vehicle behind to the merger.
    pub fn rear(&self, v: f64, min: f64) -> f64 {
        match *self {
            GapRule::Sml2015 => safe_gap_rear(v, min),
            GapRule::TimeGap { time_gap, standstill } => standstill + time_gap * v.max(0.0),
        }
    }

    /// The gap \[m\] under which a merge in progress is aborted: `min` (`merge.safe_gap`) for
    /// the 2015 rule, the standstill gap for a time-gap rule.
    pub fn minimum(&self, min: f64) -> f64 {
        match *self {
            GapRule::Sml2015 => min,
            GapRule::TimeGap { standstill, .. } => standstill,
        }
    }

    /// Check the values (keys relative to `gap_rule`): `time_gap` [0, 60] s, `standstill`
    /// (0, 1e3] m.
    pub fn check(&self) -> Result<(), crate::sim::params::ParamError> {
        use crate::sim::params::{Range, check_all};
        match *self {
            GapRule::Sml2015 => Ok(()),
            GapRule::TimeGap { time_gap, standstill } => check_all([
                ("time_gap", time_gap, Range::non_negative(60.0)),
                ("standstill", standstill, Range::positive(1e3)),
            ])
            .map_err(|e| e.within("gap_rule")),
        }
    }
}

/// What `gap_rule` may be, for error messages.
const GAP_RULE_FORMS: &str = "expected \"sml2015\" or a table { time_gap = 0.8, standstill = 5.0 } \
     (time gap [s], standstill gap [m])";

/// The table form of [`GapRule::TimeGap`], parsed strictly.
#[derive(serde::Deserialize)]
#[serde(deny_unknown_fields)]
struct TimeGapTable {
    time_gap: f64,
    standstill: f64,
}

impl<'de> serde::Deserialize<'de> for GapRule {
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        struct Visitor;
        impl<'de> serde::de::Visitor<'de> for Visitor {
            type Value = GapRule;
            fn expecting(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
                f.write_str(GAP_RULE_FORMS)
            }
            fn visit_str<E: serde::de::Error>(self, v: &str) -> Result<GapRule, E> {
                match v {
                    "sml2015" => Ok(GapRule::Sml2015),
                    other => Err(E::custom(format!("unknown gap rule `{other}`: {GAP_RULE_FORMS}"))),
                }
            }
            fn visit_map<A: serde::de::MapAccess<'de>>(self, map: A) -> Result<GapRule, A::Error> {
                let t = <TimeGapTable as serde::Deserialize>::deserialize(
                    serde::de::value::MapAccessDeserializer::new(map),
                )
                .map_err(|e| serde::de::Error::custom(format!("{e}; {GAP_RULE_FORMS}")))?;
                Ok(GapRule::TimeGap { time_gap: t.time_gap, standstill: t.standstill })
            }
        }
        d.deserialize_any(Visitor)
    }
}

impl serde::Serialize for GapRule {
    fn serialize<S: serde::Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        use serde::ser::SerializeStruct;
        match *self {
            GapRule::Sml2015 => s.serialize_str("sml2015"),
            GapRule::TimeGap { time_gap, standstill } => {
                let mut t = s.serialize_struct("GapRule", 2)?;
                t.serialize_field("time_gap", &time_gap)?;
                t.serialize_field("standstill", &standstill)?;
                t.end()
            }
        }
    }
}

/// Share of a planned gap opening spent speeding the opening up and slowing it down again
/// (each end) [-]: the gap grows along a trapezoid of rates, so the gap makers' decelerations
/// build up and fade instead of jumping.
pub const PLAN_RAMP: f64 = 0.15;

/// The plan of one gap (the virtual gap between a vehicle and its forward pair): from `gap0`
/// where the pair formed to the full gap of the rule where the merges begin, opened over the
/// road between (the whole merge zone), not at once.
///
/// Every vehicle of the zipper opens only its own gap, and every gap opens over the road up to
/// the same point: a vehicle `k` places behind the head drops back at the sum of the `k` rates
/// ahead of it, spread over the whole stretch, instead of the last gap maker braking for every
/// gap at once; and the merger's own lower speed opens its front gap by itself (the plan then
/// only holds it back from closing up).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct GapPlan {
    /// Distance to the merge zone where the plan began \[m\] (the vehicle's own, along the road).
    pub d0: f64,
    /// The gap then \[m\] (bumper to bumper; negative while the pair is still side by side).
    pub gap0: f64,
    /// Distance to the merge zone where the gap must be open \[m\] (negative: inside the zone).
    pub d_ready: f64,
}

/// Where the gaps must be open, as a distance to the merge zone \[m\], for a zone whose lane ends
/// at `d_end` \[m\] (negative: inside the zone; `None`: the end is not known): `room` \[m\] before
/// the end (the merges themselves and the last resort need that road), but not before `d_now` +
/// `min_length` (a pair that forms late still opens its gap over some road).
pub fn ready_point(d_now: f64, d_end: Option<f64>, room: f64, min_length: f64) -> f64 {
    let latest = d_now - min_length;
    match d_end {
        Some(end) => (end + room).min(latest),
        None => latest,
    }
}

/// Trapezoid shape of a plan at progress `p` in [0, 1]: (share of the opening done, its rate
/// per unit of progress). The rate rises linearly over the first [`PLAN_RAMP`] of the way,
/// holds, and falls over the last; the peak rate is `1 / (1 - PLAN_RAMP)` times the mean.
pub fn plan_shape(p: f64) -> (f64, f64) {
    let r = PLAN_RAMP;
    let peak = 1.0 / (1.0 - r);
    let p = p.clamp(0.0, 1.0);
    if p < r {
        (0.5 * peak * p * p / r, peak * p / r)
    } else if p <= 1.0 - r {
        (peak * (0.5 * r + (p - r)), peak)
    } else {
        let q = 1.0 - p;
        (1.0 - 0.5 * peak * q * q / r, peak * q / r)
    }
}

impl GapPlan {
    /// The gap to keep now \[m\] and how fast it grows [m/s], at distance `d` \[m\] to the zone,
    /// speed `v` [m/s], towards the `full` gap \[m\]. Past `d_ready` (or a plan with no road) it
    /// is the full gap, growing no more; a gap already wider than `full` is held at `full`.
    pub fn keep(&self, d: f64, v: f64, full: f64) -> (f64, f64) {
        let length = self.d0 - self.d_ready;
        let start = self.gap0.min(full);
        if length <= 0.0 || d <= self.d_ready {
            return (full, 0.0);
        }
        let (done, rate) = plan_shape((self.d0 - d) / length);
        (start + (full - start) * done, (full - start) * rate * v.max(0.0) / length)
    }
}

/// Front safe gap \[m\] at speed `v` [m/s] (bumper to bumper, merger to the vehicle it merges
/// behind): `max(min, 0.27 v^1.5)` (the 2015 rule with `min` = 10 m).
pub fn safe_gap_front(v: f64, min: f64) -> f64 {
    min.max(0.27 * v.max(0.0).powf(1.5))
}

/// Rear safe gap \[m\] at speed `v` [m/s] (bumper to bumper, the vehicle behind to the merger):
/// `max(min, 0.23 v^1.5)` (the 2015 rule with `min` = 10 m).
pub fn safe_gap_rear(v: f64, min: f64) -> f64 {
    min.max(0.23 * v.max(0.0).powf(1.5))
}

/// A participant as one vehicle knows it (itself, or from its newest broadcast).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Participant {
    /// Its id.
    pub id: VehicleId,
    /// Whether it merges (it came from the ending lane).
    pub merger: bool,
    /// Distance to the merge zone along the road \[m\] (smaller = further ahead).
    pub distance: f64,
}

/// The order of the participants after the merge: mergers and the others each in their own
/// order along the road, taken in turn (a zipper), starting with the group whose first vehicle
/// is further ahead; what is left of the larger group follows at the end. Ties in distance go to
/// the lower id, so every vehicle that knows the same participants computes the same order.
pub fn zipper_order(participants: &[Participant]) -> Vec<VehicleId> {
    let sorted = |merger: bool| {
        let mut g: Vec<&Participant> = participants.iter().filter(|p| p.merger == merger).collect();
        g.sort_by(|a, b| a.distance.total_cmp(&b.distance).then(a.id.cmp(&b.id)));
        g
    };
    let (m, o) = (sorted(true), sorted(false));
    let mergers_lead = match (m.first(), o.first()) {
        (Some(a), Some(b)) => (a.distance, a.id) < (b.distance, b.id),
        (Some(_), None) => true,
        _ => false,
    };
    let (first, second) = if mergers_lead { (&m, &o) } else { (&o, &m) };
    let mut order = Vec::with_capacity(participants.len());
    for k in 0..first.len().max(second.len()) {
        order.extend(first.get(k).map(|p| p.id));
        order.extend(second.get(k).map(|p| p.id));
    }
    order
}

/// A vehicle's pair partners: the vehicles of the other group directly ahead of and behind it in
/// the order after the merge (the iCLCM `forward_pair` and `backward_pair`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct Pairs {
    /// The vehicle that will be ahead of it, if it is of the other group.
    pub forward: Option<VehicleId>,
    /// The vehicle that will be behind it, if it is of the other group.
    pub backward: Option<VehicleId>,
}

/// `me`'s pairs in `order` (from [`zipper_order`]); `merger(id)` tells the groups apart. A
/// neighbour of its own group is no pair (the tail of the larger group follows its own).
pub fn pairs_in(order: &[VehicleId], me: VehicleId, merger: impl Fn(VehicleId) -> bool) -> Pairs {
    let Some(k) = order.iter().position(|&id| id == me) else { return Pairs::default() };
    let mine = merger(me);
    let other = |id: &VehicleId| merger(*id) != mine;
    Pairs {
        forward: k.checked_sub(1).and_then(|j| order.get(j)).filter(|id| other(id)).copied(),
        backward: order.get(k + 1).filter(|id| other(id)).copied(),
    }
}

/// Safe to merge, as the gap maker announces it: the gap from it to its forward partner (the
/// merger, projected into its lane) is at least the rear gap of `rule`, and the room between the
/// merger and the gap maker's own leader (`None`: no leader) at least the front gap, both at
/// the gap maker's speed `v` [m/s] with the minimum `safe_gap` \[m\]. Gaps bumper to bumper \[m\].
pub fn stom(gap_to_partner: f64, partner_room_ahead: Option<f64>, v: f64, safe_gap: f64, rule: GapRule) -> bool {
    gap_to_partner >= rule.rear(v, safe_gap) && partner_room_ahead.is_none_or(|g| g >= rule.front(v, safe_gap))
}

/// How far a gap may fall under the rule before an announced STOM is withdrawn \[m\].
pub const STOM_HYSTERESIS: f64 = 2.0;

/// STOM with hysteresis: once announced (`announced`), it holds while the partner `merging`
/// changes lanes as long as the gap to it stays at the rule's minimum ([`GapRule::minimum`] of
/// `safe_gap` \[m\]: a gap breathing around the speed-dependent value must not abort a merge
/// halfway), and before that while both gaps stay within [`STOM_HYSTERESIS`] of the rule (a
/// gap opened along a plan reaches the rule slowly; the partner starts its change on STOM and
/// needs a wifi round to say so); otherwise [`stom`]. The merger itself still checks the full
/// rule before it starts ([`merge_action`]).
pub fn keep_stom(
    announced: bool,
    merging: bool,
    gap_to_partner: f64,
    partner_room_ahead: Option<f64>,
    v: f64,
    safe_gap: f64,
    rule: GapRule,
) -> bool {
    if announced && merging {
        return gap_to_partner >= rule.minimum(safe_gap);
    }
    if announced {
        return gap_to_partner >= rule.rear(v, safe_gap) - STOM_HYSTERESIS
            && partner_room_ahead.is_none_or(|g| g >= rule.front(v, safe_gap) - STOM_HYSTERESIS);
    }
    stom(gap_to_partner, partner_room_ahead, v, safe_gap, rule)
}

/// What a merger sees before and while it changes lanes.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MergeView {
    /// Its pairs are acknowledged both ways (the partners name it back in their broadcasts).
    pub acknowledged: bool,
    /// Its backward partner announces STOM (`true` when it has none: it merges at the tail).
    pub stom: bool,
    /// Gap to the forward partner \[m\] (bumper to bumper, along the road), if it has one.
    pub front_gap: Option<f64>,
    /// Gap from the backward partner \[m\], if it has one.
    pub rear_gap: Option<f64>,
    /// Its speed [m/s].
    pub speed: f64,
    /// Minimum safe gap \[m\] (`merge.safe_gap`).
    pub safe_gap: f64,
    /// The gap rule (`merge.gap_rule`).
    pub rule: GapRule,
    /// A lane change is in progress.
    pub merging: bool,
    /// It is inside the merge zone the roadside unit announced (past its start).
    pub in_zone: bool,
}

/// A merger's decision this tick.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum MergeAction {
    /// Keep the lane (and keep asking for STOM).
    Wait,
    /// Ask the lane-change plugin for the change (its own safety check has the last word).
    Merge,
    /// Go on with the change in progress.
    Continue,
    /// Abort the change in progress back to the ending lane (the lane-change plugin does so
    /// before the halfway point).
    Abort,
}

/// The merger's rule: merge only inside the merge zone, with acknowledged pairs, the backward
/// partner's STOM and its own check of both gaps against the gap rule at its speed; while merging, abort when the pairs or
/// STOM are gone or a gap has shrunk under the rule's minimum (the 2015 `Abort` check
/// "safety distance is not fulfilled", `Supervisory/GCDC_supervisory_layer.py`).
pub fn merge_action(view: &MergeView) -> MergeAction {
    let v = view.speed;
    if view.merging {
        let min = view.rule.minimum(view.safe_gap);
        let too_close = view.front_gap.is_some_and(|g| g < min) || view.rear_gap.is_some_and(|g| g < min);
        return if !view.acknowledged || !view.stom || too_close { MergeAction::Abort } else { MergeAction::Continue };
    }
    let front_ok = view.front_gap.is_none_or(|g| g >= view.rule.front(v, view.safe_gap));
    let rear_ok = view.rear_gap.is_none_or(|g| g >= view.rule.rear(v, view.safe_gap));
    if view.in_zone && view.acknowledged && view.stom && front_ok && rear_ok {
        MergeAction::Merge
    } else {
        MergeAction::Wait
    }
}

/// Whether `order` (ids front to back) is a zipper of the two groups: they alternate for as long
/// as both have vehicles left, and each group keeps its order `mergers` / `others` (front to back).
pub fn is_zipper(order: &[VehicleId], mergers: &[VehicleId], others: &[VehicleId]) -> bool {
    let in_group = |g: &[VehicleId]| order.iter().copied().filter(|id| g.contains(id)).collect::<Vec<_>>();
    if in_group(mergers) != mergers || in_group(others) != others || order.len() != mergers.len() + others.len() {
        return false;
    }
    let alternating = 2 * mergers.len().min(others.len());
    let is_merger = |id: &VehicleId| mergers.contains(id);
    let head = &order[..alternating.min(order.len())];
    head.windows(2).all(|w| is_merger(&w[0]) != is_merger(&w[1]))
        && order[head.len()..].iter().all(|id| is_merger(id) == (mergers.len() > others.len()))
}

#[cfg(test)]
mod tests {
    use super::*;

    const R: GapRule = GapRule::Sml2015;

    fn p(id: i32, merger: bool, distance: f64) -> Participant {
        Participant { id: VehicleId(id), merger, distance }
    }

    fn ids(v: &[i32]) -> Vec<VehicleId> {
        v.iter().map(|&i| VehicleId(i)).collect()
    }

    #[test]
    fn the_2015_safe_gaps_grow_with_speed_above_the_minimum() {
        // 50 km/h: about 14 m and 12 m (REFERENCE.md); slow: the 10 m minimum.
        let v = 50.0 / 3.6;
        assert!((safe_gap_front(v, 10.0) - 0.27 * v.powf(1.5)).abs() < 1e-12);
        assert!((13.5..14.5).contains(&safe_gap_front(v, 10.0)), "{}", safe_gap_front(v, 10.0));
        assert!((11.5..12.5).contains(&safe_gap_rear(v, 10.0)), "{}", safe_gap_rear(v, 10.0));
        assert_eq!(safe_gap_front(5.0, 10.0), 10.0);
        assert_eq!(safe_gap_rear(0.0, 10.0), 10.0);
        assert!(safe_gap_front(22.0, 10.0) > safe_gap_rear(22.0, 10.0));
    }

    #[test]
    fn pairing_zips_the_groups_and_pairs_each_merger_with_its_neighbours_to_be() {
        // Mergers -1 (ahead), -2, -3; others 1, 2, 3 with 1 level with -1 but behind it.
        let all = [p(1, false, 100.0), p(2, false, 120.0), p(3, false, 140.0), p(-1, true, 95.0), p(-2, true, 115.0)];
        let all = [all.as_slice(), &[p(-3, true, 135.0)]].concat();
        let order = zipper_order(&all);
        assert_eq!(order, ids(&[-1, 1, -2, 2, -3, 3]));
        let merger = |id: VehicleId| id.0 < 0;
        // The head merger has no one of the others ahead; its backward pair opens the gap.
        assert_eq!(pairs_in(&order, VehicleId(-1), merger), Pairs { forward: None, backward: Some(VehicleId(1)) });
        assert_eq!(
            pairs_in(&order, VehicleId(-2), merger),
            Pairs { forward: Some(VehicleId(1)), backward: Some(VehicleId(2)) }
        );
        // Acknowledged both ways: 1's forward pair is -1 and -1's backward pair is 1.
        assert_eq!(pairs_in(&order, VehicleId(1), merger).forward, Some(VehicleId(-1)));
        assert_eq!(pairs_in(&order, VehicleId(3), merger), Pairs { forward: Some(VehicleId(-3)), backward: None });
        // Others ahead: the zipper starts with them.
        let ahead = [p(1, false, 90.0), p(-1, true, 95.0)];
        assert_eq!(zipper_order(&ahead), ids(&[1, -1]));
        // Every vehicle computes the same order whatever order it heard the others in.
        let mut shuffled = all.clone();
        shuffled.reverse();
        assert_eq!(zipper_order(&shuffled), order);
        // A larger group ends with its own vehicles: no pairs among them.
        let more = [p(1, false, 100.0), p(2, false, 120.0), p(3, false, 140.0), p(-1, true, 95.0)];
        let order = zipper_order(&more);
        assert_eq!(order, ids(&[-1, 1, 2, 3]));
        assert_eq!(pairs_in(&order, VehicleId(2), merger), Pairs::default());
        assert_eq!(pairs_in(&order, VehicleId(9), merger), Pairs::default(), "unknown vehicle");
    }

    #[test]
    fn a_partner_that_leaves_is_replaced_by_the_next_vehicle() {
        let all = vec![p(1, false, 100.0), p(2, false, 120.0), p(-1, true, 95.0), p(-2, true, 115.0)];
        let merger = |id: VehicleId| id.0 < 0;
        let before = pairs_in(&zipper_order(&all), VehicleId(-2), merger);
        assert_eq!(before, Pairs { forward: Some(VehicleId(1)), backward: Some(VehicleId(2)) });
        // Vehicle 2 is no longer heard: -2 merges at the tail, no backward pair.
        let without_2: Vec<_> = all.iter().copied().filter(|q| q.id != VehicleId(2)).collect();
        let after = pairs_in(&zipper_order(&without_2), VehicleId(-2), merger);
        assert_eq!(after, Pairs { forward: Some(VehicleId(1)), backward: None });
        // Vehicle 1 leaves instead: 2 moves up and becomes -1's backward pair, -2's forward pair.
        let without_1: Vec<_> = all.iter().copied().filter(|q| q.id != VehicleId(1)).collect();
        let order = zipper_order(&without_1);
        assert_eq!(pairs_in(&order, VehicleId(-1), merger).backward, Some(VehicleId(2)));
        assert_eq!(pairs_in(&order, VehicleId(-2), merger), Pairs { forward: Some(VehicleId(2)), backward: None });
    }

    #[test]
    fn stom_only_when_both_gaps_are_safe_at_the_speed() {
        let v = 22.0;
        let (front, rear) = (safe_gap_front(v, 10.0), safe_gap_rear(v, 10.0));
        assert!(stom(rear, Some(front), v, 10.0, R));
        assert!(stom(rear + 5.0, None, v, 10.0, R), "no leader: only the rear gap counts");
        assert!(!stom(rear - 0.1, Some(front + 50.0), v, 10.0, R), "too close behind the partner");
        assert!(!stom(rear + 50.0, Some(front - 0.1), v, 10.0, R), "no room ahead of the partner");
        // The 10 m minimum holds at low speed.
        assert!(!stom(9.9, None, 3.0, 10.0, R));
        assert!(stom(10.0, Some(10.0), 3.0, 10.0, R));
        // A larger configured minimum raises both.
        assert!(!stom(rear, Some(front), v, 40.0, R));
    }

    #[test]
    fn stom_once_announced_holds_while_the_partner_merges_above_the_minimum() {
        let (front, rear) = (safe_gap_front(22.0, 10.0), safe_gap_rear(22.0, 10.0));
        assert!(!keep_stom(false, true, rear - 1.0, Some(front), 22.0, 10.0, R), "never announced: the full rule");
        assert!(keep_stom(true, true, rear - 1.0, Some(front - 5.0), 22.0, 10.0, R), "merging: hold");
        assert!(!keep_stom(true, true, 9.0, Some(front), 22.0, 10.0, R), "under the minimum: withdrawn");
        assert!(keep_stom(true, false, rear - 1.0, Some(front - 1.0), 22.0, 10.0, R), "announced: hysteresis");
        let below = rear - STOM_HYSTERESIS - 0.1;
        assert!(!keep_stom(true, false, below, Some(front), 22.0, 10.0, R), "not merging yet: the rule less 2 m");
        assert!(!keep_stom(true, false, rear, Some(front - 2.1), 22.0, 10.0, R), "no room ahead: withdrawn");
    }

    fn view(front: Option<f64>, rear: Option<f64>, stom: bool, merging: bool) -> MergeView {
        MergeView {
            acknowledged: true,
            stom,
            front_gap: front,
            rear_gap: rear,
            speed: 22.0,
            safe_gap: 10.0,
            rule: R,
            merging,
            in_zone: true,
        }
    }

    #[test]
    fn a_merger_waits_for_stom_and_its_own_check_then_merges() {
        let (front, rear) = (safe_gap_front(22.0, 10.0), safe_gap_rear(22.0, 10.0));
        assert_eq!(merge_action(&view(Some(front), Some(rear), true, false)), MergeAction::Merge);
        assert_eq!(merge_action(&view(Some(front), Some(rear), false, false)), MergeAction::Wait, "no STOM");
        assert_eq!(merge_action(&view(Some(front - 1.0), Some(rear), true, false)), MergeAction::Wait);
        assert_eq!(merge_action(&view(Some(front), Some(rear - 1.0), true, false)), MergeAction::Wait);
        assert_eq!(merge_action(&view(None, Some(rear), true, false)), MergeAction::Merge, "head merger");
        let unacknowledged = MergeView { acknowledged: false, ..view(Some(front), Some(rear), true, false) };
        assert_eq!(merge_action(&unacknowledged), MergeAction::Wait);
        let before_the_zone = MergeView { in_zone: false, ..view(Some(front), Some(rear), true, false) };
        assert_eq!(merge_action(&before_the_zone), MergeAction::Wait);
    }

    #[test]
    fn a_merge_is_aborted_when_stom_or_the_pairing_goes_or_a_gap_collapses() {
        assert_eq!(merge_action(&view(Some(15.0), Some(12.0), true, true)), MergeAction::Continue);
        assert_eq!(merge_action(&view(Some(15.0), Some(12.0), false, true)), MergeAction::Abort, "STOM withdrawn");
        assert_eq!(merge_action(&view(Some(9.0), Some(12.0), true, true)), MergeAction::Abort, "front gap < 10 m");
        assert_eq!(merge_action(&view(Some(15.0), Some(9.0), true, true)), MergeAction::Abort, "rear gap < 10 m");
        let lost = MergeView { acknowledged: false, ..view(Some(15.0), Some(12.0), true, true) };
        assert_eq!(merge_action(&lost), MergeAction::Abort, "partner lost");
    }

    #[test]
    fn zipper_order_check_wants_alternation_and_each_groups_own_order() {
        let (m, o) = (ids(&[-1, -2]), ids(&[1, 2, 3]));
        assert!(is_zipper(&ids(&[-1, 1, -2, 2, 3]), &m, &o));
        assert!(is_zipper(&ids(&[1, -1, 2, -2, 3]), &m, &o));
        assert!(!is_zipper(&ids(&[-1, -2, 1, 2, 3]), &m, &o), "two mergers in a row");
        assert!(!is_zipper(&ids(&[-2, 1, -1, 2, 3]), &m, &o), "mergers swapped");
        assert!(!is_zipper(&ids(&[1, -1, 2, 3, -2]), &m, &o), "a merger behind two others");
        assert!(!is_zipper(&ids(&[-1, 1, -2, 2]), &m, &o), "a vehicle missing");
    }

    #[test]
    fn the_time_gap_rule_is_standstill_plus_time_gap_times_speed_on_both_sides() {
        let rule = GapRule::TimeGap { time_gap: 0.8, standstill: 5.0 };
        assert!((rule.front(22.0, 10.0) - 22.6).abs() < 1e-12);
        assert_eq!(rule.front(22.0, 10.0), rule.rear(22.0, 10.0));
        assert_eq!(rule.front(0.0, 10.0), 5.0, "the 2015 minimum does not apply to a time-gap rule");
        assert_eq!((rule.minimum(10.0), R.minimum(10.0)), (5.0, 10.0));
        assert_eq!(R.front(22.0, 10.0), safe_gap_front(22.0, 10.0));
        assert_eq!(R.rear(22.0, 10.0), safe_gap_rear(22.0, 10.0));
        // At 80 km/h the 0.8 s rule asks for less than the 2015 rule on both sides.
        assert!(rule.front(22.2, 10.0) < R.front(22.2, 10.0) && rule.rear(22.2, 10.0) < R.rear(22.2, 10.0));
    }

    #[derive(Debug, serde::Deserialize)]
    #[serde(deny_unknown_fields)]
    struct Holder {
        gap_rule: GapRule,
    }

    fn parse(text: &str) -> Result<GapRule, String> {
        toml::from_str::<Holder>(text).map(|h| h.gap_rule).map_err(|e| e.to_string())
    }

    #[test]
    fn the_gap_rule_parses_both_forms_and_names_the_problem_otherwise() {
        assert_eq!(parse("gap_rule = \"sml2015\""), Ok(GapRule::Sml2015));
        let t = parse("gap_rule = { time_gap = 0.8, standstill = 5.0 }");
        assert_eq!(t, Ok(GapRule::TimeGap { time_gap: 0.8, standstill: 5.0 }));
        let unknown = parse("gap_rule = \"sml2016\"").unwrap_err();
        assert!(
            unknown.contains("sml2016") && unknown.contains("sml2015") && unknown.contains("time_gap"),
            "{unknown}"
        );
        let typo = parse("gap_rule = { time_gapp = 0.8, standstill = 5.0 }").unwrap_err();
        assert!(typo.contains("time_gapp") && typo.contains("standstill"), "{typo}");
        let missing = parse("gap_rule = { time_gap = 0.8 }").unwrap_err();
        assert!(missing.contains("standstill"), "{missing}");
        let number = parse("gap_rule = 0.8").unwrap_err();
        assert!(number.contains("sml2015"), "{number}");
        let bad = GapRule::TimeGap { time_gap: -0.8, standstill: 5.0 }.check().unwrap_err();
        assert_eq!(bad.key, "gap_rule.time_gap");
        assert!(GapRule::TimeGap { time_gap: 0.8, standstill: 0.0 }.check().is_err());
        // Serialised back as written.
        let json = serde_json::to_string(&t.unwrap()).unwrap();
        assert_eq!(json, r#"{"time_gap":0.8,"standstill":5.0}"#);
        assert_eq!(serde_json::to_string(&GapRule::Sml2015).unwrap(), "\"sml2015\"");
    }

    #[test]
    fn the_plan_shape_is_a_trapezoid_of_rates_from_nothing_to_all() {
        assert_eq!(plan_shape(0.0), (0.0, 0.0));
        let (done, rate) = plan_shape(1.0);
        assert!((done - 1.0).abs() < 1e-12 && rate.abs() < 1e-12);
        assert!((plan_shape(0.5).0 - 0.5).abs() < 1e-12, "symmetric");
        let peak = 1.0 / (1.0 - PLAN_RAMP);
        // The share done is the integral of the rate: check by summing small steps.
        let n = 10_000;
        let mut sum = 0.0;
        for k in 0..n {
            let p = (k as f64 + 0.5) / n as f64;
            let (_, r) = plan_shape(p);
            assert!(r <= peak + 1e-12 && r >= 0.0);
            sum += r / n as f64;
            let next = plan_shape((k + 1) as f64 / n as f64).0;
            assert!((next - sum).abs() < 1e-6, "at {p}: {next} vs {sum}");
        }
        assert_eq!(plan_shape(2.0), plan_shape(1.0), "clamped");
    }

    #[test]
    fn a_planned_gap_opens_over_the_whole_road_to_the_ready_point() {
        // A pair side by side (gap -2 m) 300 m before the zone; the gaps must be open 400 m into
        // it: 700 m of road for 25 m of gap.
        let plan = GapPlan { d0: 300.0, gap0: -2.0, d_ready: -400.0 };
        let full = 25.0;
        assert_eq!(plan.keep(300.0, 20.0, full), (-2.0, 0.0), "starts where it is, at rest");
        let (mid, rate) = plan.keep(-50.0, 20.0, full);
        assert!((mid - 11.5).abs() < 1e-9, "half way, half the opening: {mid}");
        // The rate at the middle is the peak: 27 m over 700 m at 20 m/s, times the peak share.
        let peak = 27.0 / 700.0 * 20.0 / (1.0 - PLAN_RAMP);
        assert!((rate - peak).abs() < 1e-9, "{rate} vs {peak}");
        assert!(rate < 1.0, "a gentle relative speed, not a stop: {rate} m/s");
        assert_eq!(plan.keep(-400.0, 20.0, full), (full, 0.0));
        assert_eq!(plan.keep(-900.0, 20.0, full), (full, 0.0));
        // Monotone in the road driven.
        let mut last = f64::NEG_INFINITY;
        for k in 0..=70 {
            let (g, _) = plan.keep(300.0 - 10.0 * k as f64, 20.0, full);
            assert!(g >= last - 1e-12);
            last = g;
        }
        // A gap already open is held at the full gap.
        let wide = GapPlan { d0: 300.0, gap0: 40.0, d_ready: -400.0 };
        assert_eq!(wide.keep(100.0, 20.0, full), (full, 0.0));
        // No road left: the full gap.
        let late = GapPlan { d0: -500.0, gap0: 0.0, d_ready: -400.0 };
        assert_eq!(late.keep(-500.0, 20.0, full), (full, 0.0));
    }

    #[test]
    fn gaps_must_be_open_before_the_lane_ends_with_room_for_the_merges() {
        // Zone 700 m long: ready 200 m before its end.
        assert_eq!(ready_point(300.0, Some(-700.0), 200.0, 100.0), -500.0);
        // A pair formed late still gets its minimum of road.
        assert_eq!(ready_point(-450.0, Some(-700.0), 200.0, 100.0), -550.0);
        // The end unknown: the minimum.
        assert_eq!(ready_point(300.0, None, 200.0, 100.0), 200.0);
    }

    #[test]
    fn shared_plans_keep_the_last_gap_maker_above_three_quarters_of_its_speed() {
        // The GCDC scenario with the 0.8 s rule: five gap makers 19.5 m apart at 22.2 m/s, five
        // mergers of 4.5 m; each gap maker behind the head has two gaps of the zipper ahead of
        // it per merger to open. Summing the peak rates of every gap ahead of the last one
        // (each opened over ~800 m at about 19 m/s) must leave it at 75 % of its speed.
        let rule = GapRule::TimeGap { time_gap: 0.8, standstill: 5.0 };
        let (v, length, road) = (22.2, 4.5, 800.0);
        let per_merger = 2.0 * length + rule.front(v, 10.0) + rule.rear(v, 10.0) + 2.0 * 3.0 - 19.5;
        let rate = 4.0 * per_merger / road * 19.0 / (1.0 - PLAN_RAMP);
        assert!(v - rate >= 0.75 * v, "the last gap maker drops {rate} m/s");
    }
}
