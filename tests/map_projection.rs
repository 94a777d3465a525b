//! Projection pinned to reference coordinates at millimetre tolerance.
//!
//! References: PROJ (pyproj 3, `+proj=utm +zone=Z +ellps=WGS84`), computed independently of the
//! `utm` crate; local coordinates are differences of those UTM eastings/northings.

use glam::DVec2;
use smlworld::map::Projector;

const MM: f64 = 1e-3;

fn assert_close(got: DVec2, want: DVec2, what: &str) {
    assert!((got - want).abs().max_element() < MM, "{what}: got {got}, want {want} (diff {})", got - want);
}

#[test]
fn sml_lab_origin_and_right_lane_node() {
    // HighwaySML.xml: origin node -552 and the right_lane_node -142, zone 33V.
    let p = Projector::new(59.15374861144, 17.6606166112);
    assert_eq!(p.zone_name(), "33V");
    assert_close(p.forward(59.15374861144, 17.6606166112), DVec2::ZERO, "origin");
    let want = DVec2::new(652188.5007 - 652150.6454, 6560262.4083 - 6560206.0143);
    assert_close(p.forward(59.15424095717, 17.66131705525), want, "node -142");
}

#[test]
fn karlsruhe_lanelet2_origin() {
    // Lanelet2's examples project mapping_example.osm around lat 49.0, lon 8.4 (zone 32U).
    let p = Projector::new(49.0, 8.4);
    assert_eq!(p.zone_name(), "32U");
    let want = DVec2::new(458313.0293 - 456114.5959, 5428168.1177 - 5427629.2039);
    assert_close(p.forward(49.005, 8.43), want, "49.005N 8.43E");
}

#[test]
fn nodes_stay_in_the_origin_zone() {
    // 12.1E is in zone 33, but a map whose origin is in zone 32 projects it in zone 32 so the map
    // stays continuous.
    let p = Projector::new(49.0, 8.4);
    let want = DVec2::new(726726.5165 - 456114.5959, 5432086.9366 - 5427629.2039);
    assert_close(p.forward(49.0, 12.1), want, "49N 12.1E in zone 32");
}

#[test]
fn reverse_inverts_forward_to_a_tenth_of_a_millimetre() {
    for (lat0, lon0) in [(59.15374861144, 17.6606166112), (49.0, 8.4), (-33.92487, 18.42406), (0.5, -0.5)] {
        let p = Projector::new(lat0, lon0);
        for (dx, dy) in [(0.0, 0.0), (123.4, -56.7), (-2500.0, 1800.0), (15000.0, 9000.0)] {
            let (lat, lon) = p.reverse(DVec2::new(dx, dy));
            let back = p.forward(lat, lon);
            assert!(
                (back - DVec2::new(dx, dy)).length() < 1e-4,
                "({dx}, {dy}) around ({lat0}, {lon0}) came back as {back}"
            );
        }
    }
}
