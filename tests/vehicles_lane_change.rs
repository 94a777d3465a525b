//! The lane-change manoeuvre's profile (bounded lateral acceleration, completes within its
//! length) and MOBIL's decision (never into a gap the sensors show occupied).

use smlworld::vehicles::AdaptiveCruise;
use smlworld::vehicles::lane_change::{LaneChangeProfile, Mobil, MobilDecision, Seen, Surroundings, mobil_decision};
use smlworld::vehicles::longitudinal::LeaderGap;
use smlworld::world::VehicleId;

#[test]
fn lane_change_completes_within_its_distance_under_the_lateral_bound() {
    let (width, a_max) = (3.5, 1.0);
    for speed in [5.0, 15.0, 25.0, 35.0] {
        let p = LaneChangeProfile::for_speed(width, speed, a_max, 20.0);
        assert!(p.length >= 20.0);
        // Numerically, independently of the closed form: d'' by second differences, times v².
        let n = 20_000;
        let h = p.length / n as f64;
        let mut peak: f64 = 0.0;
        for k in 1..n {
            let s = k as f64 * h;
            let d2 = (p.offset_at(s + h) - 2.0 * p.offset_at(s) + p.offset_at(s - h)) / (h * h);
            peak = peak.max((d2 * speed * speed).abs());
            // Monotone: never overshoots into the lane beyond.
            assert!(p.offset_at(s) >= p.offset_at(s - h) - 1e-12 && p.offset_at(s) <= width + 1e-12);
            // The slope is the derivative of the offset (the yaw follows the manoeuvre).
            let numeric = (p.offset_at(s + h) - p.offset_at(s - h)) / (2.0 * h);
            assert!((numeric - p.slope_at(s)).abs() < 1e-6, "slope at {s}");
        }
        assert!(peak <= a_max * 1.001, "v = {speed}: lateral acceleration {peak} over {a_max}");
        assert!((peak - p.peak_lateral_accel(speed)).abs() < 1e-3 * a_max.max(peak));
        // Completes within its length: the full offset at L, none at 0, flat at both ends.
        assert_eq!(p.offset_at(0.0), 0.0);
        assert!((p.offset_at(p.length) - width).abs() < 1e-12);
        assert_eq!(p.offset_at(p.length + 10.0), p.offset_at(p.length));
        assert!(p.slope_at(0.0).abs() < 1e-12 && p.slope_at(p.length).abs() < 1e-12);
        // Faster = longer (when not held at the minimum): L grows with v at a fixed bound.
        if speed > 10.0 {
            assert!((peak - a_max).abs() < 0.01, "v = {speed}: the shortest change uses the bound ({peak})");
        }
    }
    let slow = LaneChangeProfile::for_speed(-3.5, 30.0, 1.0, 0.0);
    let fast = LaneChangeProfile::for_speed(-3.5, 30.0, 2.0, 0.0);
    assert!(slow.length > fast.length && slow.offset_at(slow.length) < 0.0, "right changes are negative offsets");
}

/// The ACC law as MOBIL's longitudinal model, cruising at 30 m/s.
fn acc_law(v: f64, leader: Option<(f64, f64)>) -> f64 {
    let acc = AdaptiveCruise::default();
    let gap =
        leader.map(|(gap, speed)| LeaderGap { id: VehicleId(0), distance: gap + 4.0, gap, speed, acceleration: 0.0 });
    acc.acceleration(v, 30.0, gap.as_ref(), 0.0)
}

fn seen(s: f64, speed: f64) -> Seen {
    Seen { s, speed }
}

/// We (25 m/s) are closing on a slow truck (15 m/s, 25 m ahead); the target lane is free far
/// ahead, so MOBIL wants to change.
fn stuck_behind_a_truck() -> Surroundings {
    Surroundings {
        me: seen(100.0, 25.0),
        length: 4.0,
        leader: Some(seen(129.0, 15.0)),
        follower: Some(seen(60.0, 25.0)),
        target_leader: Some(seen(300.0, 30.0)),
        target_follower: None,
    }
}

#[test]
fn mobil_changes_when_it_gains_and_not_into_an_occupied_gap() {
    let p = Mobil::default();
    let free = stuck_behind_a_truck();
    let MobilDecision::Change(gain) = mobil_decision(&p, &free, acc_law) else {
        panic!("stuck behind a truck with a free lane beside: {:?}", mobil_decision(&p, &free, acc_law))
    };
    assert!(gain > p.threshold);
    // A car right beside us in the target lane: a change would put two cars in one place. The
    // incentive is as large as before (its gap is behind us), so only the sensor check refuses.
    let beside = Surroundings { target_follower: Some(seen(98.0, 25.0)), ..free };
    assert_eq!(mobil_decision(&p, &beside, acc_law), MobilDecision::Occupied);
    let beside_ahead = Surroundings { target_leader: Some(seen(102.0, 25.0)), ..free };
    assert_eq!(mobil_decision(&p, &beside_ahead, acc_law), MobilDecision::Occupied);
    // Even a huge incentive does not override it.
    let eager = Mobil { politeness: 0.0, threshold: -100.0, safe_deceleration: 1e9 };
    assert_eq!(mobil_decision(&eager, &beside, acc_law), MobilDecision::Occupied);
    // A fast car 10 m behind in the target lane would have to brake hard: unsafe.
    let fast_behind = Surroundings { target_follower: Some(seen(86.0, 35.0)), ..free };
    match mobil_decision(&p, &fast_behind, acc_law) {
        MobilDecision::Unsafe(a) => assert!(a < -p.safe_deceleration),
        other => panic!("expected Unsafe, got {other:?}"),
    }
    // Nothing ahead of us to escape and nobody behind to make room for: no gain.
    let open_road = Surroundings { leader: None, follower: None, ..free };
    assert!(matches!(mobil_decision(&p, &open_road, acc_law), MobilDecision::NoGain(_)));
}
