//! Stream formats: which class names and which reference point a visualisation stream carries.
//!
//! - [`StreamFormat::Smlworld`] (the default): our class names (`Car`, `Truck`, `Bus`, ...) and
//!   `(x, y)` the **body centre**, as our viewer draws it.
//! - [`StreamFormat::Y2015`] (`--stream-format 2015`): what the 2015 viewers draw. They know only
//!   Python class names (`scripts/sml_world_old/VisualisationModule.py`, `draw_vehicles`:
//!   `SmartVehicle`, `DummyVehicle`, and the lab bodies `QualisysGoal`, `QualisysBigBox`,
//!   `QualisysSmallBox`; the later `visualization.py` also `BaseVehicle` and `WifiVehicle`) and
//!   stop on any other name. The name is mapped from our [`VehicleClass`] ([`class_name_2015`],
//!   the table in docs/lab.md):
//!
//!   | our class | 2015 name | why |
//!   |---|---|---|
//!   | `truck` | `SmartVehicle` | 2015 drove the lab's trucks, real or simulated, as `SmartVehicle` |
//!   | `emergency` | `SmartVehicle` | the 2015 emergency vehicle was a `SmartVehicle` (its supervisory module) |
//!   | `car`, `bus`, `motorcycle`, `bicycle` | `DummyVehicle` | 2015's traffic, drawn as cars coloured by id |
//!
//!   except that ids <= -100 are always `SmartVehicle`: the 2015 viewer skips `DummyVehicle`s
//!   there. `BaseVehicle` and `WifiVehicle` are never sent (the 2015 `VisualisationModule.py`
//!   stops on them). We have no motion-capture bodies other than vehicles (no goals, no boxes),
//!   so `QualisysGoal`, `QualisysBigBox` and `QualisysSmallBox` are never sent; our viewer draws
//!   them when a 2015 sender sends them ([`viewer_footprint`]). `(x, y)` is the **rear-axle
//!   point**: the 2015 viewer centres its "Offset" sprites on it (`load_smart_car_image`: a
//!   4.779 m car whose rear axle is 0.910 m ahead of its rear bumper, the sprite twice the
//!   axle-to-front length), so the body reaches [`REAR_AXLE_FROM_REAR`] of its length behind the
//!   point and the rest ahead. We place that point on our body at the same fraction of its
//!   length from the rear, so the 2015 viewer draws our vehicle where it is; our viewer, told
//!   the stream is 2015 (`view --stream-format 2015`), moves the point forward again
//!   ([`StreamFormat::centre_from_point`]).

use glam::DVec2;

use super::VizVehicle;
use crate::world::VehicleClass;

/// Rear axle of the 2015 car as a fraction of its length from the rear bumper: 0.910 m of
/// 4.779 m (`VisualisationModule.py`, `load_smart_car_image`).
pub const REAR_AXLE_FROM_REAR: f64 = 0.910 / 4.779;

/// What a visualisation stream carries (see the module docs).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum StreamFormat {
    /// Our class names; `(x, y)` the body centre.
    #[default]
    Smlworld,
    /// The 2015 viewers' class names; `(x, y)` the rear-axle point.
    Y2015,
}

impl std::str::FromStr for StreamFormat {
    type Err = String;

    fn from_str(s: &str) -> Result<StreamFormat, String> {
        match s {
            "smlworld" => Ok(StreamFormat::Smlworld),
            "2015" => Ok(StreamFormat::Y2015),
            _ => Err(format!("unknown stream format `{s}`; use `smlworld` (the default) or `2015`")),
        }
    }
}

impl StreamFormat {
    /// The class name sent for vehicle `id` of class `class`: our name (`Truck`, ...) or, in
    /// the 2015 format, [`class_name_2015`].
    pub fn class_name(self, id: i32, class: VehicleClass) -> &'static str {
        match self {
            StreamFormat::Smlworld => class.name(),
            StreamFormat::Y2015 => class_name_2015(id, class),
        }
    }

    /// The point sent for a body of `length` \[m\] centred at `centre` \[m\] heading `yaw` \[rad\].
    pub fn point_from_centre(self, centre: DVec2, yaw: f64, length: f64) -> DVec2 {
        match self {
            StreamFormat::Smlworld => centre,
            StreamFormat::Y2015 => centre - DVec2::from_angle(yaw) * (length * (0.5 - REAR_AXLE_FROM_REAR)),
        }
    }

    /// The body centre of a vehicle of `length` \[m\] whose stream point is `point` \[m\], heading
    /// `yaw` \[rad\] (the inverse of [`StreamFormat::point_from_centre`]).
    pub fn centre_from_point(self, point: DVec2, yaw: f64, length: f64) -> DVec2 {
        match self {
            StreamFormat::Smlworld => point,
            StreamFormat::Y2015 => point + DVec2::from_angle(yaw) * (length * (0.5 - REAR_AXLE_FROM_REAR)),
        }
    }
}

/// The 2015 viewers' class name for vehicle `id` of our class `class` (the table in the module
/// docs): trucks and emergency vehicles `SmartVehicle`, other classes `DummyVehicle`, and
/// `SmartVehicle` for every id <= -100 (the 2015 viewer draws no `DummyVehicle` there).
pub fn class_name_2015(id: i32, class: VehicleClass) -> &'static str {
    match class {
        _ if id <= -100 => "SmartVehicle",
        VehicleClass::Truck | VehicleClass::Emergency => "SmartVehicle",
        VehicleClass::Car | VehicleClass::Bus | VehicleClass::Motorcycle | VehicleClass::Bicycle => "DummyVehicle",
    }
}

/// Footprint `(length, width)` \[m\] the viewer draws for a class name of the stream (which carries
/// no sizes): our classes at the 2015 tool's scenario sizes, the 2015 vehicle classes at the 2015
/// car's size (4.779 x 2.096 m, `load_smart_car_image`) and the lab bodies at theirs (lab metres
/// x 32: `load_big_box_image`, `load_small_box_image`, `load_goal_image`).
pub fn viewer_footprint(class: &str) -> (f64, f64) {
    match class.to_ascii_lowercase().as_str() {
        "truck" => (12.0, 2.5),
        "bus" => (12.0, 2.55),
        "motorcycle" => (2.2, 0.8),
        "bicycle" | "bike" => (1.8, 0.6),
        "smartvehicle" | "dummyvehicle" | "basevehicle" | "wifivehicle" => (4.779, 2.096),
        "qualisysbigbox" => (0.6 * 32.0, 0.4 * 32.0),
        "qualisyssmallbox" => (0.4 * 32.0, 0.3 * 32.0),
        "qualisysgoal" => (0.2 * 32.0, 0.2 * 32.0),
        _ => (4.12, 1.7),
    }
}

/// Where the viewer draws a received vehicle of a stream in `format`: body centre \[m\], heading
/// \[rad\], length and width \[m\] ([`viewer_footprint`]).
pub fn viewer_body(format: StreamFormat, v: &VizVehicle) -> (DVec2, f64, f64, f64) {
    let (length, width) = viewer_footprint(&v.class_name);
    let yaw = v.yaw_deg.to_radians();
    (format.centre_from_point(DVec2::new(v.x, v.y), yaw, length), yaw, length, width)
}
