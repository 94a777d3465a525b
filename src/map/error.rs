//! Errors (unrecoverable input) and warnings (recoverable problems) of map loading and routing.

use std::path::PathBuf;

/// Where in an input file something was found: the file and the 1-based line.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Location {
    /// File the map was read from (or `<memory>` for text given directly).
    pub file: PathBuf,
    /// 1-based line number, 0 when unknown.
    pub line: usize,
}

impl std::fmt::Display for Location {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        if self.line > 0 {
            write!(f, "{}:{}", self.file.display(), self.line)
        } else {
            write!(f, "{}", self.file.display())
        }
    }
}

/// Unrecoverable problems: the map cannot be used as given.
#[derive(Debug, thiserror::Error)]
pub enum MapError {
    /// The file could not be read.
    #[error("{path}: cannot read the map file: {source}")]
    Io {
        /// File that could not be read.
        path: PathBuf,
        /// Underlying I/O error.
        source: std::io::Error,
    },
    /// The file holds no OSM data at all.
    #[error("{0}: the file is empty; expected JOSM/OSM XML starting with <osm>")]
    Empty(PathBuf),
    /// The XML itself is broken.
    #[error("{at}: malformed XML: {message}; fix the file (JOSM can re-save it)")]
    Xml {
        /// Where the parser stopped.
        at: Location,
        /// What the XML parser said.
        message: String,
    },
    /// An attribute is missing or has a value that cannot be used.
    #[error("{at}: {element} {id}: attribute `{attribute}` {problem}")]
    BadAttribute {
        /// Where.
        at: Location,
        /// `node`, `way`, `relation` or `tag` (for `<nd>` and `<member>`: their way or relation).
        element: &'static str,
        /// Id of the element (or `?` when the id itself is bad).
        id: String,
        /// The attribute name.
        attribute: &'static str,
        /// What is wrong and what is allowed.
        problem: String,
    },
    /// The file's structure is wrong in a way XML allows: an object nested inside another, an
    /// object outside `<osm>`, a file that ends before `</osm>`, an attribute given twice.
    #[error("{at}: {message}")]
    Structure {
        /// Where.
        at: Location,
        /// What is wrong, which object, and what to do.
        message: String,
    },
    /// A node cannot be projected (outside UTM's latitudes, or the map crosses the antimeridian).
    #[error("{at}: node {node}: {message}")]
    Coordinates {
        /// Where the node is defined.
        at: Location,
        /// The node.
        node: i64,
        /// What is wrong and what is allowed.
        message: String,
    },
    /// Two objects of the same kind share an id.
    #[error("{at}: duplicate {element} id {id} (first defined on line {first_line}); ids must be unique")]
    DuplicateId {
        /// Where the second one is.
        at: Location,
        /// `node`, `way` or `relation`.
        element: &'static str,
        /// The id.
        id: i64,
        /// Line of the first definition.
        first_line: usize,
    },
    /// A CommonRoad element is missing something or has a value that cannot be used.
    #[error("{at}: CommonRoad: {message}")]
    CommonRoad {
        /// Where the element is.
        at: Location,
        /// What is wrong and what is allowed.
        message: String,
    },
    /// An OpenDRIVE element is missing something, has a value that cannot be used, or links to
    /// something the file does not define.
    #[error("{at}: OpenDRIVE: {message}")]
    OpenDrive {
        /// Where the element is.
        at: Location,
        /// What is wrong, which road/lane/junction, and what is allowed.
        message: String,
    },
    /// A SUMO network or demand element is missing something, has a value that cannot be used,
    /// or names a lane, edge, route or type the files do not define.
    #[error("{at}: SUMO: {message}")]
    Sumo {
        /// Where the element is.
        at: Location,
        /// What is wrong, which element id, and what is allowed.
        message: String,
    },
    /// A way lists a node that the file does not define.
    #[error("{at}: way {way} references node {node}, which is not in the file; add the node or remove it from the way")]
    MissingNode {
        /// Where the way is.
        at: Location,
        /// The way.
        way: i64,
        /// The missing node.
        node: i64,
    },
    /// A lanelet names a bound way that the file does not define.
    #[error("{at}: lanelet {lanelet} references way {way} (role `{role}`), which is not in the file")]
    MissingWay {
        /// Where the relation is.
        at: Location,
        /// The lanelet relation id.
        lanelet: i64,
        /// The missing way.
        way: i64,
        /// The member role.
        role: String,
    },
    /// The nodes span more than one UTM zone around the origin in a way that cannot be projected.
    #[error("{0}")]
    Projection(String),
    /// A node id given by the user is not in the map.
    #[error("unknown node id {0}: no node with that id in the map (see `smlworld map info`)")]
    UnknownNode(i64),
    /// A node tag value given by the user is not in the map.
    #[error("unknown tag `{0}`: no node has a tag with that value (see `smlworld map info` for the tags)")]
    UnknownTag(String),
    /// The node is not on any routable lanelet bound.
    #[error("node {0} does not lie on any routable lanelet")]
    NodeNotOnLanelet(i64),
    /// A lanelet given by the caller is not a drivable lanelet of the map.
    #[error("lanelet {0} is no drivable lanelet of the map (see `smlworld map info`)")]
    UnknownLanelet(i64),
    /// An option given by the user is out of range.
    #[error("{0}")]
    InvalidOption(String),
    /// No route exists between the two ends.
    #[error("no route from {from} to {to}: the lanelets are not connected in the driving direction")]
    NoRoute {
        /// Start as the user named it.
        from: String,
        /// End as the user named it.
        to: String,
    },
}

/// Recoverable problems found while loading; the map is still usable.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct MapWarning {
    /// `file:line` of the element concerned.
    pub at: String,
    /// What was skipped or assumed, and why.
    pub message: String,
}

impl std::fmt::Display for MapWarning {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{}: {}", self.at, self.message)
    }
}
