//! Projection between WGS84 lat/lon and local metres: UTM in the origin's zone, minus the origin.
//!
//! Every node is projected into the UTM zone of the origin, never into its own zone, so a map that
//! straddles a zone border stays continuous. x points east, y north.

use glam::DVec2;

/// Projects lat/lon [deg] to local x/y [m] around an origin, and back.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Projector {
    /// Latitude of the local origin [deg].
    pub origin_lat: f64,
    /// Longitude of the local origin [deg].
    pub origin_lon: f64,
    /// UTM zone number used for every node (the origin's zone).
    pub zone: u8,
    /// UTM latitude band letter of the origin.
    pub band: char,
    origin_easting: f64,
    origin_northing: f64,
}

impl Projector {
    /// A projector whose local (0, 0) is at `origin_lat`, `origin_lon` [deg].
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

    /// lat/lon [deg] -> local x (east), y (north) [m].
    pub fn forward(&self, lat: f64, lon: f64) -> DVec2 {
        let (northing, easting, _) = utm::to_utm_wgs84(lat, lon, self.zone);
        DVec2::new(easting - self.origin_easting, northing - self.origin_northing)
    }

    /// Local x/y [m] -> (lat, lon) [deg], exact to well below a millimetre.
    ///
    /// The closed-form inverse of the `utm` crate is only good to a few metres, so it is used as
    /// the first guess of a Newton iteration on [`Projector::forward`].
    pub fn reverse(&self, p: DVec2) -> (f64, f64) {
        let easting = p.x + self.origin_easting;
        let northing = p.y + self.origin_northing;
        let (mut lat, mut lon) = utm::wsg84_utm_to_lat_lon(easting, northing, self.zone, self.band)
            .unwrap_or((self.origin_lat, self.origin_lon));
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
