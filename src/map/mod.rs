//! Road network: JOSM/OSM lanelet maps, projection to metres, routing and map generation.
//!
//! Layered without cycles, as in Lanelet2: [`osm`] reads the raw XML into an [`osm::OsmDocument`]
//! (no semantics); the loader turns that into a [`LaneletMap`] ([`lanelet`]: metres, bounds,
//! centre lines, successors, tags) and builds its routing graph from plain lanelet data;
//! [`routing`] searches that map and never touches XML; [`polyline`] and [`path`] hold the
//! geometry every layer shares; [`commonroad`] reads CommonRoad scenario XML (lanelets, obstacles,
//! planning problems) into the same [`LaneletMap`], [`opendrive`] reads OpenDRIVE (`.xodr`) roads and [`sumo`] SUMO networks (`.net.xml`) and demand; [`generate`] writes parametric maps back as JOSM-compatible XML.
//! Nothing here knows about the ECS or rendering.

pub mod commonroad;
pub mod error;
pub mod generate;
mod geometry_checks;
mod graph;
pub mod junctions;
pub mod lane_routing;
pub mod lanelet;
mod loader;
pub mod neighbours;
pub mod opendrive;
pub mod osm;
pub mod path;
pub mod polyline;
pub mod projection;
mod reach;
pub mod routing;
pub mod sumo;

pub use error::{MapError, MapWarning};
pub use junctions::{Junction, JunctionControl, Junctions};
pub use lane_routing::{LaneChange, LaneChangeOptions, LaneChangeRoute, LaneRoute};
pub use lanelet::{Lanelet, LaneletId, LaneletMap, MapNode, MapWay, RegulatoryElement};
pub use neighbours::Neighbours;
pub use path::{Path, PathProjection};
pub use projection::Projector;
pub use routing::{Place, RouteOptions, RouteSearch, Routed};
