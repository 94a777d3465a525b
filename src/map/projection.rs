//! Projection between WGS84 lat/lon and local metres: UTM in the origin's zone, minus the origin.
//!
//! Every node is projected into the UTM zone of the origin, never into its own zone, so a map that
//! straddles a zone border stays continuous. x points east, y north.

use glam::DVec2;

/// Projects lat/lon \[deg\] to local x/y \[m\] around an origin, and back.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Projector {
    /// Latitude of the local origin \[deg\].
    pub origin_lat: f64,
    /// Longitude of the local origin \[deg\].
    pub origin_lon: f64,
    /// UTM zone number used for every node (the origin's zone).
    pub zone: u8,
    /// UTM latitude band letter of the origin.
    pub band: char,
    origin_easting: f64,
    origin_northing: f64,
}

impl Projector {
    /// A projector whose local (0, 0) is at `origin_lat`, `origin_lon` \[deg\].
    pub fn new(origin_lat: f64, origin_lon: f64) -> Projector {
        // The utm crate gives zone 61 at exactly 180 degrees east; zones run 1..=60.
        let zone = utm::lat_lon_to_zone_number(origin_lat, origin_lon).clamp(1, 60);
        let band = utm::lat_to_zone_letter(origin_lat).unwrap_or(if origin_lat >= 0.0 { 'X' } else { 'C' });
        // utm returns (northing, easting, convergence): mind the order.
        let (northing, easting, _) = utm::to_utm_wgs84(origin_lat, origin_lon, zone);
        Projector { origin_lat, origin_lon, zone, band, origin_easting: easting, origin_northing: northing }
    }

    /// The UTM zone as usually written, e.g. `33V`.
    pub fn zone_name(&self) -> String {
        format!("{}{}", self.zone, self.band)
    }

    /// lat/lon \[deg\] -> local x (east), y (north) \[m\].
    ///
    /// The false northing is the origin's hemisphere's for every point (as Lanelet2's
    /// `UtmProjector` does), so a map that crosses the equator stays continuous.
    pub fn forward(&self, lat: f64, lon: f64) -> DVec2 {
        let (mut northing, easting) = utm_wgs84(lat, lon, self.zone);
        if (lat > 0.0) != (self.origin_lat > 0.0) {
            northing += if lat > 0.0 { FALSE_NORTHING_SOUTH } else { -FALSE_NORTHING_SOUTH };
        }
        DVec2::new(easting - self.origin_easting, northing - self.origin_northing)
    }

    /// Local x/y \[m\] -> (lat, lon) \[deg\], exact to well below a millimetre.
    ///
    /// The closed-form inverse of the `utm` crate is only good to a few metres, so it is used as
    /// the first guess of a Newton iteration on [`Projector::forward`].
    pub fn reverse(&self, p: DVec2) -> (f64, f64) {
        let easting = p.x + self.origin_easting;
        let northing = p.y + self.origin_northing;
        // The band only tells the crate's inverse which false northing the northing carries:
        // the origin's hemisphere's, as in `forward` (a band letter before N is southern).
        let band = if self.origin_lat > 0.0 { 'N' } else { 'M' };
        let (mut lat, mut lon) =
            utm::wsg84_utm_to_lat_lon(easting, northing, self.zone, band).unwrap_or((self.origin_lat, self.origin_lon));
        // Newton steps with a finite-difference Jacobian; converges in 2-3 iterations.
        let h = 1e-7;
        for _ in 0..8 {
            let f = self.forward(lat, lon) - p;
            if f.length() < 1e-6 {
                break;
            }
            let dlat = (self.forward(lat + h, lon) - self.forward(lat, lon)) / h;
            let dlon = (self.forward(lat, lon + h) - self.forward(lat, lon)) / h;
            let det = dlat.x * dlon.y - dlat.y * dlon.x;
            if det.abs() < 1e-12 {
                break;
            }
            lat -= (f.x * dlon.y - f.y * dlon.x) / det;
            lon -= (dlat.x * f.y - dlat.y * f.x) / det;
        }
        (lat, lon)
    }
}

/// The false northing UTM adds south of the equator [m].
const FALSE_NORTHING_SOUTH: f64 = 10_000_000.0;

/// WGS84 semi-major axis [m] and flattening [-], as the `utm` crate has them.
const WGS84_A: f64 = 6378137.0;
const WGS84_F: f64 = 1.0 / 298.257222101;

/// (northing, easting) [m] of lat/lon [deg] in UTM `zone`: `utm::to_utm_wgs84` (0.1.6, MIT) with
/// the same expressions in the same order, so the same bits, less the meridian convergence it
/// also computes and [`Projector::forward`] dropped (five more sines, a tangent and a power per
/// node: half the time of loading a big map's nodes). A test pins it to the crate bit for bit.
fn utm_wgs84(latitude: f64, longitude: f64, zone: u8) -> (f64, f64) {
    use std::f64::consts::PI;
    let latitude = latitude * PI / 180.0;
    let longitude = longitude * PI / 180.0;
    let long_origin = zone as f64 * 6.0 - 183.0;
    let e2 = 2.0 * WGS84_F - WGS84_F * WGS84_F;
    let ep2 = e2 / (1.0 - e2);

    let n = WGS84_A / (1.0 - e2 * latitude.sin() * latitude.sin()).sqrt();
    let t = latitude.tan() * latitude.tan();
    let c = ep2 * latitude.cos() * latitude.cos();
    let a = latitude.cos() * (longitude - (long_origin * PI / 180.0));

    let term1 = 1.0 - e2 / 4.0 - (3.0 * e2 * e2) / 64.0 - (5.0 * e2 * e2 * e2) / 256.0;
    let term2 = (3.0 * e2) / 8.0 + (3.0 * e2 * e2) / 32.0 + (45.0 * e2 * e2 * e2) / 1024.0;
    let term3 = (15.0 * e2 * e2) / 256.0 + (45.0 * e2 * e2 * e2) / 1024.0;
    let term4 = (35.0 * e2 * e2 * e2) / 3072.0;

    let m = WGS84_A
        * (term1 * latitude - term2 * (2.0 * latitude).sin() + term3 * (4.0 * latitude).sin()
            - term4 * (6.0 * latitude).sin());

    let x1 = ((1.0 - t + c) * a * a * a) / 6.0;
    let x2 = ((5.0 - 18.0 * t + t * t + 72.0 * c - 58.0 * ep2) * a * a * a * a * a) / 120.0;
    let x = 0.9996 * n * (a + x1 + x2);

    let y1 = (5.0 - t + 9.0 * c + 4.0 * c * c) * (a * a * a * a) / 24.0;
    let y2 = (61.0 - 58.0 * t + t * t + 600.0 * c - 330.0 * ep2) * (a * a * a * a * a * a) / 720.0;
    let y3 = (a * a) / 2.0 + y1 + y2;
    let y = 0.9996 * (m + n * latitude.tan() * y3);

    // Southern hemisphere coordinates add a false northing.
    let northing_mod = if latitude > 0.0 { 0.0 } else { FALSE_NORTHING_SOUTH };
    (y + northing_mod, x + 500000.0)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Bit for bit the crate's northing and easting, over the globe's UTM latitudes, every zone
    /// and points off their zone's meridian.
    #[test]
    fn utm_matches_the_crate_bit_for_bit() {
        let mut checked = 0;
        for i in 0..=328 {
            let lat = -80.0 + i as f64 * 0.5 + 0.123_456_789;
            for j in 0..=240 {
                let lon = -180.0 + j as f64 * 1.5 + 0.000_987_654_321;
                let zone = utm::lat_lon_to_zone_number(lat, lon).clamp(1, 60);
                for zone in [zone, (zone % 60) + 1] {
                    let (northing, easting, _) = utm::to_utm_wgs84(lat, lon, zone);
                    let ours = utm_wgs84(lat, lon, zone);
                    assert_eq!(
                        (ours.0.to_bits(), ours.1.to_bits()),
                        (northing.to_bits(), easting.to_bits()),
                        "{lat} {lon} zone {zone}"
                    );
                    checked += 1;
                }
            }
        }
        assert!(checked > 100_000);
        assert_eq!(utm_wgs84(0.0, 3.0, 31), (10000000.0, 500000.0), "the equator on the meridian, southern rule");
    }

    /// An origin on the equator (OpenDRIVE files without a geoReference) with nodes on both
    /// sides: forward is continuous and reverse gives the point back (it diverged south of the
    /// equator when each point took its own hemisphere's false northing).
    #[test]
    fn a_map_across_the_equator_projects_both_ways() {
        for origin in [(0.0, 0.0), (0.001, 10.0), (-0.001, -70.0)] {
            let p = Projector::new(origin.0, origin.1);
            for q in [DVec2::new(120.0, -250.0), DVec2::new(-30.0, 400.0), DVec2::new(5.0, -0.5), DVec2::ZERO] {
                let (lat, lon) = p.reverse(q);
                let back = p.forward(lat, lon);
                assert!(back.distance(q) < 1e-6, "{origin:?}: {q} -> ({lat}, {lon}) -> {back}");
                assert!((lat - origin.0).abs() < 0.01, "{origin:?}: {q} -> latitude {lat}");
            }
            let (a, b) = (p.forward(-1e-9, origin.1), p.forward(1e-9, origin.1));
            assert!(a.distance(b) < 1e-3, "{origin:?}: {a} and {b} across the equator");
        }
    }
}
