//! Lane-change building blocks as pure functions (no ECS yet): the manoeuvre's lateral profile
//! with bounded lateral acceleration, and MOBIL's decision (Kesting, Treiber, Helbing 2007).
//!
//! Not yet wired into a plugin: a vehicle does not change lanes in a scenario today. What is here
//! is what that plugin will call each tick: [`LaneChangeProfile`] for the blended path offset and
//! yaw, [`mobil_decision`] for whether to go, with the accelerations from the vehicle's own
//! longitudinal law passed in as a function.

/// A lane change's lateral offset from the old lane's centre line as a function of the distance
/// driven since it began: the minimum-jerk quintic `d(s) = D (10u³ - 15u⁴ + 6u⁵)`, `u = s / L`,
/// whose curvature-free start and end need no steering jump.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LaneChangeProfile {
    /// Signed lateral distance to the target lane's centre \[m\] (positive = left).
    pub offset: f64,
    /// Distance along the road over which the change happens \[m\].
    pub length: f64,
}

/// Largest `|d''(s)| L² / |D|` of the quintic: `10 / √3`, at `u = 1/2 ± 1/(2√3)`.
const QUINTIC_PEAK: f64 = 5.773_502_691_896_258;

impl LaneChangeProfile {
    /// The shortest profile whose lateral acceleration at `speed` [m/s] stays at or under
    /// `max_lateral_accel` [m/s²], but no shorter than `min_length` \[m\]: `L = v √(5.77 |D| / a)`.
    pub fn for_speed(offset: f64, speed: f64, max_lateral_accel: f64, min_length: f64) -> LaneChangeProfile {
        let a = max_lateral_accel.max(1e-6);
        let length = (speed.abs() * (QUINTIC_PEAK * offset.abs() / a).sqrt()).max(min_length).max(1e-3);
        LaneChangeProfile { offset, length }
    }

    /// The highest speed [m/s] at which this profile keeps its lateral acceleration at or under
    /// `max_lateral_accel` [m/s²] (the inverse of [`LaneChangeProfile::for_speed`]'s length).
    pub fn speed_for(&self, max_lateral_accel: f64) -> f64 {
        self.length / (QUINTIC_PEAK * self.offset.abs() / max_lateral_accel.max(1e-6)).sqrt().max(1e-9)
    }

    /// Lateral offset \[m\] after driving `s` \[m\] since the start (clamped to the ends).
    pub fn offset_at(&self, s: f64) -> f64 {
        let u = (s / self.length).clamp(0.0, 1.0);
        self.offset * u * u * u * (10.0 - 15.0 * u + 6.0 * u * u)
    }

    /// Slope `d'(s)` of the offset [m/m]: the heading relative to the lane is `atan(slope)`, so
    /// the vehicle's yaw follows the manoeuvre.
    pub fn slope_at(&self, s: f64) -> f64 {
        let u = (s / self.length).clamp(0.0, 1.0);
        self.offset * 30.0 * u * u * (1.0 - u) * (1.0 - u) / self.length
    }

    /// Largest lateral acceleration [m/s²] at constant `speed` [m/s]: `v² · 5.77 |D| / L²`.
    pub fn peak_lateral_accel(&self, speed: f64) -> f64 {
        speed * speed * QUINTIC_PEAK * self.offset.abs() / (self.length * self.length)
    }
}

/// MOBIL's parameters (Kesting, Treiber, Helbing 2007, symmetric rule for discretionary changes).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Mobil {
    /// Politeness factor p [-]: weight of the other vehicles' acceleration changes; 0 is selfish,
    /// raising it changes lanes only when the followers lose little.
    pub politeness: f64,
    /// Switching threshold Δa_th [m/s²]: the net gain a change must bring; raising it changes
    /// lanes less often (and stops ping-pong).
    pub threshold: f64,
    /// Safe deceleration b_safe [m/s²] (positive): the new follower must not have to brake
    /// harder than this; raising it accepts tighter gaps.
    pub safe_deceleration: f64,
}

impl Default for Mobil {
    /// The paper's values: p = 0.2 (its range 0.2..0.5 for "realistic" drivers), Δa_th = 0.1 m/s²,
    /// b_safe = 4 m/s².
    fn default() -> Self {
        Mobil { politeness: 0.2, threshold: 0.1, safe_deceleration: 4.0 }
    }
}

/// A vehicle as MOBIL sees it: its position along the road [m, centre] and speed [m/s].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Seen {
    /// Position along the road \[m\] (centre).
    pub s: f64,
    /// Speed [m/s].
    pub speed: f64,
}

/// What the sensors show around a vehicle considering a change. Only what was detected goes in:
/// an unseen vehicle cannot be reasoned about (and a gap the sensors show occupied is refused).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Surroundings {
    /// Ourselves.
    pub me: Seen,
    /// Our length \[m\] (all vehicles assumed this long).
    pub length: f64,
    /// Nearest vehicle ahead in our lane.
    pub leader: Option<Seen>,
    /// Nearest vehicle behind in our lane.
    pub follower: Option<Seen>,
    /// Nearest vehicle ahead in the target lane (s >= me.s).
    pub target_leader: Option<Seen>,
    /// Nearest vehicle behind in the target lane (s < me.s).
    pub target_follower: Option<Seen>,
}

/// Why MOBIL said no, or yes.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum MobilDecision {
    /// Change: the net incentive [m/s²] exceeded the threshold.
    Change(f64),
    /// A vehicle overlaps the slot we would move into (bumper-to-bumper gap <= 0).
    Occupied,
    /// The new follower would brake harder than the safe deceleration [its acceleration, m/s²].
    Unsafe(f64),
    /// Not worth it: the net incentive [m/s²] is at or under the threshold.
    NoGain(f64),
}

/// MOBIL's decision. `law(v, leader)` is the vehicle's own longitudinal law: acceleration
/// [m/s²] at speed `v` [m/s] behind `leader = Some((gap [m], leader speed [m/s]))` or on a free
/// road. The gap check comes first, so an occupied slot is refused whatever the incentive.
pub fn mobil_decision(p: &Mobil, around: &Surroundings, law: impl Fn(f64, Option<(f64, f64)>) -> f64) -> MobilDecision {
    let gap = |back: Seen, front: Seen| front.s - back.s - around.length;
    let me = around.me;
    let behind = |f: Option<Seen>, leader: Option<Seen>| {
        f.map(|f| {
            (law(f.speed, Some((gap(f, me), me.speed))), leader.map(|l| law(f.speed, Some((gap(f, l), l.speed)))))
        })
    };
    let ahead_gap = around.target_leader.map(|l| gap(me, l));
    let behind_gap = around.target_follower.map(|f| gap(f, me));
    if ahead_gap.is_some_and(|g| g <= 0.0) || behind_gap.is_some_and(|g| g <= 0.0) {
        return MobilDecision::Occupied;
    }
    let follow = |leader: Option<Seen>| law(me.speed, leader.map(|l| (gap(me, l), l.speed)));
    let (a_c, a_c_new) = (follow(around.leader), follow(around.target_leader));
    // New follower: now behind the target leader (or free), after the change behind us.
    let (a_n, a_n_new) = match around.target_follower {
        Some(f) => (
            law(f.speed, around.target_leader.map(|l| (gap(f, l), l.speed))),
            law(f.speed, Some((gap(f, me), me.speed))),
        ),
        None => (0.0, 0.0),
    };
    if a_n_new < -p.safe_deceleration {
        return MobilDecision::Unsafe(a_n_new);
    }
    // Old follower: now behind us, after the change behind our leader (or free).
    let (a_o, a_o_new) = match behind(around.follower, around.leader) {
        Some((now, after)) => (now, after.unwrap_or_else(|| law(around.follower.map_or(0.0, |f| f.speed), None))),
        None => (0.0, 0.0),
    };
    let incentive = a_c_new - a_c + p.politeness * ((a_n_new - a_n) + (a_o_new - a_o));
    if incentive > p.threshold { MobilDecision::Change(incentive) } else { MobilDecision::NoGain(incentive) }
}
