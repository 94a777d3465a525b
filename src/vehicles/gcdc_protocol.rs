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
/// merger, projected into its lane) is at least the rear safe gap, and the room between the
/// merger and the gap maker's own leader (`None`: no leader) at least the front safe gap, both at
/// the gap maker's speed `v` [m/s] with the minimum `safe_gap` \[m\]. Gaps bumper to bumper \[m\].
pub fn stom(gap_to_partner: f64, partner_room_ahead: Option<f64>, v: f64, safe_gap: f64) -> bool {
    gap_to_partner >= safe_gap_rear(v, safe_gap) && partner_room_ahead.is_none_or(|g| g >= safe_gap_front(v, safe_gap))
}

/// STOM with hysteresis: once announced (`announced`), it holds while the partner `merging`
/// changes lanes as long as the gap to it stays at the minimum `safe_gap` \[m\] (a gap breathing
/// around the speed-dependent value must not abort a merge halfway); otherwise [`stom`].
pub fn keep_stom(
    announced: bool,
    merging: bool,
    gap_to_partner: f64,
    partner_room_ahead: Option<f64>,
    v: f64,
    safe_gap: f64,
) -> bool {
    if announced && merging {
        return gap_to_partner >= safe_gap;
    }
    stom(gap_to_partner, partner_room_ahead, v, safe_gap)
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
/// partner's STOM and its own check of both gaps against the safe gaps at its speed; while merging, abort when the pairs or
/// STOM are gone or a gap has shrunk under the minimum `safe_gap` (the 2015 `Abort` check
/// "safety distance is not fulfilled", `Supervisory/GCDC_supervisory_layer.py`).
pub fn merge_action(view: &MergeView) -> MergeAction {
    let v = view.speed;
    if view.merging {
        let too_close =
            view.front_gap.is_some_and(|g| g < view.safe_gap) || view.rear_gap.is_some_and(|g| g < view.safe_gap);
        return if !view.acknowledged || !view.stom || too_close { MergeAction::Abort } else { MergeAction::Continue };
    }
    let front_ok = view.front_gap.is_none_or(|g| g >= safe_gap_front(v, view.safe_gap));
    let rear_ok = view.rear_gap.is_none_or(|g| g >= safe_gap_rear(v, view.safe_gap));
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
        assert!(stom(rear, Some(front), v, 10.0));
        assert!(stom(rear + 5.0, None, v, 10.0), "no leader: only the rear gap counts");
        assert!(!stom(rear - 0.1, Some(front + 50.0), v, 10.0), "too close behind the partner");
        assert!(!stom(rear + 50.0, Some(front - 0.1), v, 10.0), "no room ahead of the partner");
        // The 10 m minimum holds at low speed.
        assert!(!stom(9.9, None, 3.0, 10.0));
        assert!(stom(10.0, Some(10.0), 3.0, 10.0));
        // A larger configured minimum raises both.
        assert!(!stom(rear, Some(front), v, 40.0));
    }

    #[test]
    fn stom_once_announced_holds_while_the_partner_merges_above_the_minimum() {
        let (front, rear) = (safe_gap_front(22.0, 10.0), safe_gap_rear(22.0, 10.0));
        assert!(!keep_stom(false, true, rear - 1.0, Some(front), 22.0, 10.0), "never announced: the full rule");
        assert!(keep_stom(true, true, rear - 1.0, Some(front - 5.0), 22.0, 10.0), "merging: hold");
        assert!(!keep_stom(true, true, 9.0, Some(front), 22.0, 10.0), "under the minimum: withdrawn");
        assert!(!keep_stom(true, false, rear - 1.0, Some(front), 22.0, 10.0), "not merging yet: the full rule");
    }

    fn view(front: Option<f64>, rear: Option<f64>, stom: bool, merging: bool) -> MergeView {
        MergeView {
            acknowledged: true,
            stom,
            front_gap: front,
            rear_gap: rear,
            speed: 22.0,
            safe_gap: 10.0,
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
}
