//! A* routing gives routes as short as Dijkstra's, to the millimetre, on a generated grid city.

mod common;

use smlworld::map::generate::{GridParams, grid_city};
use smlworld::map::{LaneletMap, Place, RouteOptions, RouteSearch};

#[test]
fn astar_routes_are_as_short_as_dijkstra_routes_over_200_random_pairs() {
    let params = GridParams { rows: 12, cols: 12, ..GridParams::default() };
    let xml = grid_city(&params).expect("valid grid parameters");
    let map = LaneletMap::parse_str(&xml, std::path::Path::new("generated grid 12x12")).expect("the grid loads");
    let tags: Vec<&String> = map.tag_index.keys().collect();
    assert!(tags.len() > 400, "only {} tagged places", tags.len());
    let opts = RouteOptions { points_per_meter: 1.0 };
    let mut rng = common::Rng(0x5eed_0013);
    let mut routed = 0;
    for _ in 0..200 {
        let from = Place::Tag(tags[rng.below(tags.len() as u64) as usize].clone());
        let to = Place::Tag(tags[rng.below(tags.len() as u64) as usize].clone());
        let dijkstra = map.route_places_with(&from, &to, &opts, RouteSearch::Dijkstra);
        let astar = map.route_places_with(&from, &to, &opts, RouteSearch::AStar);
        match (dijkstra, astar) {
            (Ok(d), Ok(a)) => {
                routed += 1;
                // Equal in the searches' millimetres; the resampled polylines of two tied routes
                // differ by the rounding (0.5 mm per lanelet) and the chords of their corners.
                // Any detour on this grid is metres longer.
                assert!(
                    (d.length - a.length).abs() < 0.02,
                    "{from} -> {to}: Dijkstra {} m, A* {} m",
                    d.length,
                    a.length
                );
                assert!(d.points[0].distance(a.points[0]) < 1e-3, "{from} -> {to}: starts differ");
                let (de, ae) = (d.points[d.points.len() - 1], a.points[a.points.len() - 1]);
                assert!(de.distance(ae) < 1e-3, "{from} -> {to}: ends differ: {de} {ae}");
            }
            (Err(d), Err(a)) => assert_eq!(d.to_string(), a.to_string()),
            (d, a) => panic!("{from} -> {to}: Dijkstra {:?}, A* {:?}", d.map(|p| p.length), a.map(|p| p.length)),
        }
    }
    assert!(routed > 150, "only {routed} of 200 pairs had a route");
    // The lanelets are not compared: a regular grid has many equally short routes between far
    // junctions and the two searches break such ties differently.
}
