//! Parametric maps (ring highway, intersections, grid city) written as JOSM-compatible OSM XML.
