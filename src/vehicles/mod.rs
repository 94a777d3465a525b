//! Controllers (path following, cruise control, ACC, platooning) as plugins, one per file.
//!
//! Each controller follows the contract documented in [`crate::app`]: systems in the
//! [`crate::sim::Control`] schedule that read state, readings, mail and route, and write
//! [`crate::world::ControlCommand`] and out-going messages. The speed controllers share one
//! pipeline ([`longitudinal`]): they agree on an acceleration, limiters (intersection yielding,
//! emergency braking) may lower it, and it is turned into the model's command once.
//!
//! | plugin | component (per vehicle) | parameters |
//! |---|---|---|
//! | [`PathFollowingPlugin`] | [`PathFollower`] | [`PathFollowing`] |
//! | [`CruisePlugin`] | [`CruiseController`] | [`CruiseControl`] |
//! | [`AccPlugin`] | [`AccController`] | [`AdaptiveCruise`] |
//! | [`PlatoonPlugin`] | [`PlatoonMember`] | [`Platooning`] |
//! | [`EmergencyBrakingPlugin`] | [`EmergencyBrake`] | [`EmergencyBraking`] |
//! | [`CrossingPlugin`] | [`CrossingNegotiator`] | [`Crossing`] |
//! | [`IdmPlugin`] | [`IdmController`] | [`Idm`] |
//! | [`LaneChangePlugin`] | [`LaneChanger`] | [`LaneChangeParams`] |
//! | [`EmergencyVehiclePlugin`] | [`EmergencyVehicle`], [`YieldToEmergency`] | [`EmergencySettings`] |
//! | [`GcdcPlugin`] | [`GcdcVehicle`] | [`MergeParams`], [`Rsu`] |
//! | [`GcdcIntersectionPlugin`] | [`IntersectionNegotiator`] | [`IntersectionParams`] |
//!
//! [`smart_vehicles`] adds them all.

pub mod acc;
pub mod crossing;
pub mod cruise;
pub mod emergency_braking;
pub mod emergency_vehicle;
pub mod follow_laws;
pub mod gcdc;
pub mod gcdc_intersection;
pub mod gcdc_protocol;
pub mod idm;
pub mod lane_change;
pub mod lane_changing;
pub mod lane_state;
pub mod lanes;
pub mod longitudinal;
pub mod path_following;
pub mod platoon;
pub mod right_of_way;
pub mod setup;

pub use acc::{AccController, AccPlugin, AdaptiveCruise, control_acc};
pub use crossing::{
    Crossing, CrossingClaim, CrossingNegotiator, CrossingPlugin, goes_first, stop_before, yield_at_crossings, zone_span,
};
pub use cruise::{CruiseControl, CruiseController, CruisePlugin, SpeedDip, control_cruise};
pub use emergency_braking::{
    EmergencyBrake, EmergencyBraking, EmergencyBrakingPlugin, brake_for_emergencies, time_to_collision,
};
pub use emergency_vehicle::{
    EmergencyBeacon, EmergencyLog, EmergencySettings, EmergencySummary, EmergencyVehicle, EmergencyVehiclePlugin,
    YieldPlan, YieldToEmergency, yield_plan,
};
pub use gcdc::{GcdcMessage, GcdcPlugin, GcdcVehicle, MergeLog, MergeParams, MergeSummary, Motion, Role, Rsu, RsuKind};
pub use gcdc_intersection::{
    GcdcIntersectionPlugin, Intention, IntersectionMessage, IntersectionNegotiator, IntersectionParams,
    negotiate_intersection,
};
pub use gcdc_protocol::GapRule;
pub use idm::{Idm, IdmController, IdmPlugin, control_idm};
pub use lane_changing::{
    ChangeKind, FollowLaw, LaneChangeEvent, LaneChangeLog, LaneChangeParams, LaneChangePlugin, LaneChanger,
    LaneCrossings, NewLaneChangers, RouteGoal, Side,
};
pub use lanes::{LaneMap, LanePosition, LanePositionsAt, LanesPlugin, refresh_lane_positions};
pub use longitudinal::{
    LEADER_RANGE, LeaderFromLanes, LeaderGap, Longitudinal, LongitudinalSystems, SteeringSystems, actuate_longitudinal,
    find_leaders, leader_along_route, leader_on_path,
};
pub use path_following::{LateralShift, PathFollower, PathFollowing, PathFollowingPlugin, follow_paths};
pub use platoon::{
    FALLBACK_WIFI_INTERVALS, Fallback, PlatoonBeacon, PlatoonMember, PlatoonPlugin, Platooning, control_platoon,
    send_platoon_beacons,
};
pub use right_of_way::{
    JunctionDriver, JunctionNetwork, JunctionParams, JunctionStats, JunctionsPlugin, TrafficLights,
    give_way_at_junctions,
};
pub use setup::{AccSetup, CruiseSetup, GcdcSetup, PlatoonRole, PlatoonSetup, SmartController};

use crate::sim::SimBuilder;

/// Every smart-vehicle controller of this module (not the path follower): cruise control, ACC,
/// platooning, intersection negotiation (the disc of `crossing` and the GCDC intersection) and
/// emergency braking. Each acts only on vehicles with
/// its component.
pub fn smart_vehicles(sim: &mut SimBuilder) {
    sim.add_plugin(CruisePlugin)
        .add_plugin(AccPlugin)
        .add_plugin(IdmPlugin)
        .add_plugin(PlatoonPlugin)
        .add_plugin(CrossingPlugin)
        .add_plugin(GcdcIntersectionPlugin)
        .add_plugin(EmergencyBrakingPlugin);
}
