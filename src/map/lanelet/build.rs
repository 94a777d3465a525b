//! Building a LaneletMap from an OsmDocument.
use super::*;
pub(super) fn build(_doc: &OsmDocument) -> Result<LaneletMap, MapError> { todo!() }
