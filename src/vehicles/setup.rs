//! Scenario-facing settings of the smart-vehicle controllers and how they are attached to a
//! spawned vehicle (the `controller = { type = ... }` tables of a scenario file).
//!
//! ```toml
//! controller = { type = "cruise_control", speed = 20.0, cruise = { kp = 500.0 } }
//! controller = { type = "acc", speed = 25.0, acc = { time_gap = 1.5 }, emergency = { ttc = 1.5 } }
//! controller = { type = "acc", speed = 8.0, crossing = { center = [0.0, 0.0], radius = 10.0 } }
//! controller = { type = "acc", speed = 10.0, intersection = { platoon_window = 3.0 } }
//! controller = { type = "platoon", role = "leader", speed = 20.0, cruise = { dip = { at = 30.0, speed = 10.0, deceleration = 6.0 } } }
//! controller = { type = "platoon", role = "follower", speed = 22.0, platoon = { time_gap = 0.5 } }
//! controller = { type = "idm", speed = 30.0, time_gap = 1.5, min_gap = 2.0, accel = 1.0, decel = 2.0, delta = 4.0 }
//! controller = { type = "gcdc", role = "auto", speed = 22.2, platoon = { time_gap = 0.6 }, merge = { safe_gap = 10.0 } }
//! ```
//! Every vehicle with one of these also gets the path follower (steering, and its `speed` as
//! the cruise speed) and emergency braking (`emergency.ttc = 0` turns it off).

use bevy_ecs::prelude::{Entity, World};

use super::gcdc::{GcdcVehicle, MergeParams, Role};
use super::gcdc_intersection::{IntersectionNegotiator, IntersectionParams};
use super::{
    AccController, AdaptiveCruise, Crossing, CrossingNegotiator, CruiseControl, CruiseController, EmergencyBrake,
    EmergencyBraking, Fallback, Idm, IdmController, PathFollower, PathFollowing, PlatoonMember, Platooning,
};
use crate::sim::params::{MAX_SPEED, MAX_TIME, ParamError, Range};
use crate::world::SimTime;

fn default_speed() -> f64 {
    PathFollowing::default().speed
}

/// `type = "cruise_control"`: PID on speed.
#[derive(Debug, Clone, Copy, PartialEq, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CruiseSetup {
    /// Cruise speed [m/s].
    #[serde(default = "default_speed")]
    pub speed: f64,
    /// PID gains and optional scripted dip.
    #[serde(default)]
    pub cruise: CruiseControl,
    /// Emergency braking.
    #[serde(default)]
    pub emergency: EmergencyBraking,
}

/// `type = "acc"`: adaptive cruise control on radar, optionally negotiating an intersection.
#[derive(Debug, Clone, Copy, PartialEq, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct AccSetup {
    /// Cruise speed when nobody is ahead [m/s].
    #[serde(default = "default_speed")]
    pub speed: f64,
    /// Gap law.
    #[serde(default)]
    pub acc: AdaptiveCruise,
    /// Emergency braking.
    #[serde(default)]
    pub emergency: EmergencyBraking,
    /// Intersection negotiation, if the route crosses a junction.
    #[serde(default)]
    pub crossing: Option<Crossing>,
    /// The GCDC 2016 cooperative intersection: negotiate the junction a roadside unit
    /// announces (see [`super::gcdc_intersection`]).
    #[serde(default)]
    pub intersection: Option<IntersectionParams>,
}

/// Role of a platoon vehicle.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum PlatoonRole {
    /// Leads (its id names the platoon); its speed comes from cruise control.
    Leader,
    /// Joins the platoon ahead of it.
    Follower,
}

/// `type = "platoon"`: a platoon leader or follower (cooperative ACC over wifi).
#[derive(Debug, Clone, Copy, PartialEq, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PlatoonSetup {
    /// Leader or follower.
    pub role: PlatoonRole,
    /// Cruise speed [m/s] (followers: when nobody is ahead; set it above the leader's).
    #[serde(default = "default_speed")]
    pub speed: f64,
    /// Gap law and feed-forward.
    #[serde(default)]
    pub platoon: Platooning,
    /// Followers: ACC on radar while the beacons of the member ahead are stale.
    #[serde(default)]
    pub fallback: Fallback,
    /// The leader's cruise control (with an optional scripted dip).
    #[serde(default)]
    pub cruise: CruiseControl,
    /// Sim time at which it leaves the platoon \[s\], if any.
    #[serde(default)]
    pub leave_at: Option<f64>,
    /// Emergency braking.
    #[serde(default)]
    pub emergency: EmergencyBraking,
    /// Intersection negotiation, if the route crosses a junction.
    #[serde(default)]
    pub crossing: Option<Crossing>,
    /// The GCDC 2016 cooperative intersection: negotiate the junction a roadside unit
    /// announces (see [`super::gcdc_intersection`]).
    #[serde(default)]
    pub intersection: Option<IntersectionParams>,
}

fn gcdc_platoon() -> Platooning {
    Platooning { time_gap: 0.6, ..Platooning::default() }
}

/// `type = "gcdc"`: the GCDC 2016 merge protocol over V2V with CACC (see [`super::gcdc`]).
#[derive(Debug, Clone, Copy, PartialEq, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct GcdcSetup {
    /// `auto` (the vehicle whose lane ends merges), `gap_maker` or `merger`.
    #[serde(default)]
    pub role: Role,
    /// Cruise speed [m/s] until the merge zone is heard (then `merge.speed` if set).
    #[serde(default = "default_speed")]
    pub speed: f64,
    /// CACC gap law (default time gap 0.6 s).
    #[serde(default = "gcdc_platoon")]
    pub platoon: Platooning,
    /// Safe gaps and the speed in the merge zone.
    #[serde(default)]
    pub merge: MergeParams,
    /// Emergency braking.
    #[serde(default)]
    pub emergency: EmergencyBraking,
}

/// One of the smart controllers of a scenario vehicle.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum SmartController {
    /// Cruise control.
    Cruise(CruiseSetup),
    /// Adaptive cruise control.
    Acc(AccSetup),
    /// Platooning.
    Platoon(PlatoonSetup),
    /// Treiber's IDM (`controller = { type = "idm", speed, time_gap, min_gap, accel, decel, delta }`).
    Idm(Idm),
    /// GCDC 2016 merging (`controller = { type = "gcdc", role, speed, platoon, merge }`).
    Gcdc(GcdcSetup),
}

impl SmartController {
    /// Check the values: `Err((key, problem))` names the key (relative to `controller`) and what
    /// is allowed. Each parameter table checks its own ranges ([`CruiseControl::check`] and the
    /// like), so TOML, CLI and Python share one definition.
    pub fn check(&self) -> Result<(), (String, String)> {
        self.check_params().map_err(Into::into)
    }

    fn check_params(&self) -> Result<(), ParamError> {
        let intersection = match self {
            SmartController::Acc(c) => c.intersection,
            SmartController::Platoon(c) => c.intersection,
            _ => None,
        };
        if let Some(i) = intersection {
            i.check().map_err(|e| e.within("intersection"))?;
        }
        let (speed, emergency, crossing) = match self {
            SmartController::Cruise(c) => {
                c.cruise.check().map_err(|e| e.within("cruise"))?;
                (c.speed, c.emergency, None)
            }
            SmartController::Acc(c) => {
                c.acc.check().map_err(|e| e.within("acc"))?;
                (c.speed, c.emergency, c.crossing)
            }
            SmartController::Platoon(c) => {
                c.platoon.check().map_err(|e| e.within("platoon"))?;
                c.fallback.check().map_err(|e| e.within("fallback"))?;
                if c.platoon.beacon_timeout.is_some() && c.fallback.beacon_timeout.is_some() {
                    return Err(ParamError {
                        key: "platoon.beacon_timeout".into(),
                        problem: "is the older spelling of `fallback.beacon_timeout` and both are set; keep one".into(),
                    });
                }
                if c.role == PlatoonRole::Leader {
                    c.cruise.check().map_err(|e| e.within("cruise"))?;
                }
                if let Some(t) = c.leave_at {
                    Range::non_negative(MAX_TIME).check("leave_at", t)?;
                }
                (c.speed, c.emergency, c.crossing)
            }
            SmartController::Idm(c) => {
                c.check()?;
                (c.speed, EmergencyBraking::default(), None)
            }
            SmartController::Gcdc(c) => {
                c.platoon.check().map_err(|e| e.within("platoon"))?;
                c.merge.check().map_err(|e| e.within("merge"))?;
                (c.speed, c.emergency, None)
            }
        };
        Range::non_negative(MAX_SPEED).check("speed", speed)?;
        emergency.check().map_err(|e| e.within("emergency"))?;
        match crossing {
            Some(c) => c.check().map_err(|e| e.within("crossing")),
            None => Ok(()),
        }
    }

    /// Whether the controller needs a sensor that sees the vehicle ahead (ACC, IDM, platoon
    /// followers): without one it would drive into whatever is ahead.
    pub fn needs_sensing_ahead(&self) -> bool {
        match self {
            SmartController::Cruise(_) => false,
            SmartController::Acc(_) | SmartController::Idm(_) | SmartController::Gcdc(_) => true,
            SmartController::Platoon(p) => p.role == PlatoonRole::Follower,
        }
    }

    /// The controller's name in a scenario file.
    pub fn type_name(&self) -> &'static str {
        match self {
            SmartController::Cruise(_) => "cruise_control",
            SmartController::Acc(_) => "acc",
            SmartController::Platoon(_) => "platoon",
            SmartController::Idm(_) => "idm",
            SmartController::Gcdc(_) => "gcdc",
        }
    }

    /// Add the controller's components (and the path follower's) to vehicle `entity`.
    pub fn attach(&self, world: &mut World, entity: Entity) {
        let mut e = world.entity_mut(entity);
        let (speed, emergency, crossing) = match *self {
            SmartController::Cruise(c) => {
                e.insert(CruiseController::new(c.cruise));
                (c.speed, c.emergency, None)
            }
            SmartController::Acc(c) => {
                e.insert(AccController { params: c.acc });
                (c.speed, c.emergency, c.crossing)
            }
            SmartController::Platoon(c) => {
                let mut member = match c.role {
                    PlatoonRole::Leader => {
                        e.insert(CruiseController::new(c.cruise));
                        PlatoonMember::leader(c.platoon)
                    }
                    PlatoonRole::Follower => PlatoonMember::follower(c.platoon),
                };
                member.leave_at = c.leave_at.map(SimTime::from_secs);
                member.fallback = c.fallback;
                e.insert(member);
                (c.speed, c.emergency, c.crossing)
            }
            SmartController::Idm(c) => {
                e.insert(IdmController { params: c });
                (c.speed, EmergencyBraking::default(), None)
            }
            SmartController::Gcdc(c) => {
                e.insert(GcdcVehicle::new(c.role, c.platoon, c.merge));
                (c.speed, c.emergency, None)
            }
        };
        e.insert(PathFollower::new(PathFollowing { speed, ..Default::default() }));
        e.insert(EmergencyBrake::new(emergency));
        if let Some(c) = crossing {
            e.insert(CrossingNegotiator::new(c));
        }
        let intersection = match *self {
            SmartController::Acc(c) => c.intersection,
            SmartController::Platoon(c) => c.intersection,
            _ => None,
        };
        if let Some(i) = intersection {
            e.insert(IntersectionNegotiator::new(i));
        }
    }
}
