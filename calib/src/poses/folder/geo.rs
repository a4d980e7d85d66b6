//! Where the metadata puts a shot: GPS to local east-north-up metres, gimbal angles to a
//! camera rotation.
//!
//! - **Local ENU**: metres east and north of the first positioned shot on the WGS84 ellipsoid's
//!   tangent plane (meridian and prime-vertical radii of curvature at its latitude; over a
//!   survey's few hundred metres the flat-earth error is below a centimetre), up from the
//!   barometric **relative** altitude when the file has one (DJI's `RelativeAltitude`, ~0.1 m
//!   between shots of one flight), else the GPS altitude (metres off), else none.
//! - **Rotation**: DJI's gimbal angles are yaw clockwise from north, pitch up positive, roll
//!   about the optical axis; the camera frame is x right, y down, z forward (COLMAP's, OpenCV's),
//!   and the rotation returned is world (east, north, up) ← camera.

use nalgebra::{Matrix3, Vector3};
use s3tir_capture::image_meta::{Attitude, GeoPosition};

/// WGS84 semi-major axis (m) and first eccentricity squared.
const WGS84_A: f64 = 6_378_137.0;
const WGS84_E2: f64 = 6.694_379_990_14e-3;

/// East/north metres of positions relative to `origin` (a tangent plane at the origin).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LocalTangent {
    origin: GeoPosition,
    metres_per_deg_lat: f64,
    metres_per_deg_lon: f64,
}

impl LocalTangent {
    /// The tangent plane at `origin`.
    pub fn at(origin: GeoPosition) -> Self {
        let lat = origin.latitude_deg.to_radians();
        let s2 = lat.sin().powi(2);
        let w = (1.0 - WGS84_E2 * s2).sqrt();
        // Meridian radius M and prime-vertical radius N.
        let m = WGS84_A * (1.0 - WGS84_E2) / (w * w * w);
        let n = WGS84_A / w;
        Self {
            origin,
            metres_per_deg_lat: m.to_radians(),
            metres_per_deg_lon: (n * lat.cos()).to_radians(),
        }
    }

    /// The origin.
    pub fn origin(&self) -> GeoPosition {
        self.origin
    }

    /// East and north metres of `p` from the origin.
    pub fn east_north(&self, p: &GeoPosition) -> [f64; 2] {
        let mut dlon = p.longitude_deg - self.origin.longitude_deg;
        if dlon > 180.0 {
            dlon -= 360.0;
        } else if dlon < -180.0 {
            dlon += 360.0;
        }
        [
            dlon * self.metres_per_deg_lon,
            (p.latitude_deg - self.origin.latitude_deg) * self.metres_per_deg_lat,
        ]
    }
}

/// World (east, north, up) ← camera (x right, y down, z forward) for gimbal angles (module
/// docs). Pitch −90° looks straight down (a nadir shot), the top of the image towards `yaw`.
pub fn world_from_camera(a: &Attitude) -> Matrix3<f64> {
    let (y, p, r) = (
        a.yaw_deg.to_radians(),
        a.pitch_deg.to_radians(),
        a.roll_deg.to_radians(),
    );
    let fwd = Vector3::new(y.sin() * p.cos(), y.cos() * p.cos(), p.sin());
    // Right of the heading, level; for a nadir shot the heading still defines it.
    let right = Vector3::new(y.cos(), -y.sin(), 0.0);
    let down = fwd.cross(&right);
    let level = Matrix3::from_columns(&[right, down, fwd]);
    let (cr, sr) = (r.cos(), r.sin());
    // Roll turns the image about the optical axis (clockwise seen from behind the camera).
    level * Matrix3::new(cr, -sr, 0.0, sr, cr, 0.0, 0.0, 0.0, 1.0)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_level_camera_facing_east_has_its_axes_where_they_should_be() {
        let r = world_from_camera(&Attitude {
            yaw_deg: 90.0,
            pitch_deg: 0.0,
            roll_deg: 0.0,
        });
        let close = |a: Vector3<f64>, b: Vector3<f64>| (a - b).norm() < 1e-12;
        assert!(
            close(r.column(2).into(), Vector3::new(1.0, 0.0, 0.0)),
            "forward is east: {r}"
        );
        assert!(
            close(r.column(0).into(), Vector3::new(0.0, -1.0, 0.0)),
            "right is south: {r}"
        );
        assert!(
            close(r.column(1).into(), Vector3::new(0.0, 0.0, -1.0)),
            "down is down: {r}"
        );
        assert!((r.determinant() - 1.0).abs() < 1e-12, "a rotation: {r}");
    }

    #[test]
    fn nadir_shots_look_down_with_the_image_top_towards_the_heading() {
        let r = world_from_camera(&Attitude {
            yaw_deg: 0.0,
            pitch_deg: -90.0,
            roll_deg: 0.0,
        });
        let fwd: Vector3<f64> = r.column(2).into();
        let down: Vector3<f64> = r.column(1).into();
        assert!(
            (fwd - Vector3::new(0.0, 0.0, -1.0)).norm() < 1e-12,
            "looks down: {fwd}"
        );
        // The image's up (−down) points north.
        assert!(
            (-down - Vector3::new(0.0, 1.0, 0.0)).norm() < 1e-12,
            "top is north: {down}"
        );
    }

    #[test]
    fn local_metres_match_the_published_lengths_of_a_degree() {
        // A degree at 45° N: 111.132 km of latitude, 78.847 km of longitude (the WGS84 table of
        // "Latitude", Wikipedia); the tangent plane's scale at the origin must equal them.
        let o = GeoPosition {
            latitude_deg: 45.0,
            longitude_deg: 7.0,
            altitude_m: None,
        };
        let t = LocalTangent::at(o);
        let en = t.east_north(&GeoPosition {
            latitude_deg: 45.001,
            longitude_deg: 7.001,
            altitude_m: None,
        });
        assert!((en[1] - 111.132).abs() < 0.002, "north of 0.001°: {en:?}");
        assert!((en[0] - 78.847).abs() < 0.002, "east of 0.001°: {en:?}");
        // Across the antimeridian the short way round.
        let t = LocalTangent::at(GeoPosition {
            longitude_deg: 179.9995,
            ..o
        });
        let en = t.east_north(&GeoPosition {
            longitude_deg: -179.9995,
            ..o
        });
        assert!((en[0] - 78.847).abs() < 0.002, "across 180°: {en:?}");
    }
}
