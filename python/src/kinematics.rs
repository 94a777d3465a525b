//! The kinematics observation of learning environments (highway-env's `Kinematics`): one
//! vehicle and its nearest neighbours as rows of numbers, computed in Rust so that an env step
//! costs one call and no per-vehicle Python work.

use smlworld::app::Session;
use smlworld::app::SessionError;
use smlworld::world::VehicleId;

/// Vehicle `id` and its nearest vehicles, as [`observe`] returns them.
#[derive(Debug, Clone, PartialEq)]
pub struct Kinematics {
    /// Row 0: `[1, x, y, vx, vy]` of the vehicle [-, m, m, m/s, m/s]; then one row per nearest
    /// other vehicle (nearest first, equal distances in id order), `[1, dx, dy, dvx, dvy]`
    /// relative to it (world axes, no rotation); rows of zeros when there are fewer vehicles.
    pub rows: Vec<[f64; 5]>,
    /// Its speed [m/s].
    pub speed: f64,
    /// Whether another vehicle's centre lies strictly inside the axis-aligned box of `footprint`
    /// = (length along x, width along y) [m] around it: `|dx| < length and |dy| < width`.
    pub collided: bool,
}

/// The [`Kinematics`] of vehicle `id` with its `nearest` nearest vehicles (by centre distance)
/// and the collision check of `footprint`; an unknown id is an argument error naming the ids.
pub fn observe(
    session: &Session,
    id: i32,
    nearest: usize,
    (length, width): (f64, f64),
) -> Result<Kinematics, SessionError> {
    let states = session.sim().states(); // in id order
    let Some(me) = states.iter().find(|(v, _)| *v == VehicleId(id)).map(|(_, s)| *s) else {
        let ids: Vec<i32> = states.iter().map(|(v, _)| v.0).collect();
        return Err(SessionError::Argument(format!("unknown vehicle id {id}; the scenario has ids {ids:?}")));
    };
    let (p, v) = (me.position, me.velocity);
    let mut others: Vec<(f64, [f64; 5])> = Vec::with_capacity(states.len());
    let mut collided = false;
    for (other, s) in &states {
        if *other == VehicleId(id) {
            continue;
        }
        let d = s.position - p;
        collided |= d.x.abs() < length && d.y.abs() < width;
        let dv = s.velocity - v;
        others.push((d.x.hypot(d.y), [1.0, d.x, d.y, dv.x, dv.y]));
    }
    // A stable sort: equal distances keep id order.
    others.sort_by(|a, b| a.0.total_cmp(&b.0));
    let mut rows = Vec::with_capacity(nearest + 1);
    rows.push([1.0, p.x, p.y, v.x, v.y]);
    rows.extend(others.iter().take(nearest).map(|(_, row)| *row));
    rows.resize(nearest + 1, [0.0; 5]);
    Ok(Kinematics { rows, speed: v.x.hypot(v.y), collided })
}

/// The commands of one learning step of vehicle `id`: ask for a lane change to `change`
/// (`"left"`, `"right"` or none; refused quietly as [`Session::change_lane`] refuses) and set its
/// throttle [N] as [`Session::set_commands`] does.
pub fn command(session: &mut Session, id: i32, throttle: f64, change: Option<&str>) -> Result<(), SessionError> {
    if let Some(side) = change {
        session.change_lane(id, side)?;
    }
    session.set_commands(&[id], Some(&[throttle]), None, None)
}

/// One learning step in one call (`Sim.drive`): [`command`], advance `dt` [s], then
/// [`observe`].
pub fn drive(
    session: &mut Session,
    id: i32,
    throttle: f64,
    change: Option<&str>,
    dt: f64,
    nearest: usize,
    footprint: (f64, f64),
) -> Result<Kinematics, SessionError> {
    command(session, id, throttle, change)?;
    session.step(dt)?;
    observe(session, id, nearest, footprint)
}
