//! Road network: JOSM/OSM lanelet maps, projection to metres, routing and map generation.
//!
//! Layered without cycles, as in Lanelet2: [`osm`] reads the raw XML into an [`osm::OsmDocument`]
//! (no semantics); [`lanelet`] turns that into a [`LaneletMap`] (metres, bounds, centre lines,
//! successors, tags); [`routing`] searches that map and never touches XML; [`generate`] writes
//! parametric maps back as JOSM-compatible XML. Nothing here knows about the ECS or rendering.

pub mod error;
pub mod generate;
pub mod lanelet;
pub mod osm;
pub mod projection;
pub mod routing;

pub use error::{MapError, MapWarning};
pub use lanelet::{Lanelet, LaneletId, LaneletMap, MapNode, MapWay};
pub use projection::Projector;
pub use routing::{Path, PathProjection, Place, RouteOptions};
