//! Vehicles on a straight synthetic road: screenshot with ids and overlays, plus pose geometry.

mod render_support;

use std::f64::consts::PI;
use std::sync::Arc;

use glam::DVec2;
use render_support::{TOLERANCE, check_snapshot, near, renderer};
use smlworld::render::{
    BirdseyeView, Environment, Line, LineStyle, PatternKind, PatternSet, RadarCone, RoadStrip, VehicleSprite,
    class_color,
};

/// A 80 m long, two-lane road along the x axis (y = -3.5..3.5 m) with yellow edges and a dashed
/// white centre line.
fn road_env() -> Environment {
    let xs: Vec<f64> = (0..=8).map(|i| -40.0 + 10.0 * f64::from(i)).collect();
    let line = |y: f64| xs.iter().map(|&x| DVec2::new(x, y)).collect::<Vec<_>>();
    Environment {
        background: PatternKind::Forest,
        areas: vec![],
        roads: vec![RoadStrip { left: line(3.5), right: line(-3.5) }],
        fills: vec![],
        lines: vec![
            Line { style: LineStyle::EXTERIOR, points: line(3.5) },
            Line { style: LineStyle::EXTERIOR, points: line(-3.5) },
            Line { style: LineStyle::INTERIOR, points: line(0.0) },
        ],
    }
}

fn three_vehicles() -> Vec<VehicleSprite> {
    let mut truck = VehicleSprite::new(1, DVec2::new(-12.0, -1.75), 0.0, 8.0, 2.5, "Truck");
    truck.real = true;
    truck.overlays.radar = Some(RadarCone { range: 20.0, angle: PI / 3.0 });
    truck.overlays.route = Some(Arc::from(vec![
        DVec2::new(-12.0, -1.75),
        DVec2::new(5.0, -1.75),
        DVec2::new(15.0, 1.75),
        DVec2::new(30.0, 1.75),
    ]));
    let mut car = VehicleSprite::new(-2, DVec2::new(12.0, 1.75), PI, 4.5, 1.8, "Car");
    car.overlays.velodyne = Some(6.0);
    let mut bus = VehicleSprite::new(23, DVec2::new(0.0, -10.0), PI / 2.0, 12.0, 2.55, "Bus");
    bus.real = true;
    bus.overlays.wifi = Some(9.0);
    vec![truck, car, bus]
}

#[test]
fn three_vehicles_with_ids_and_radar_match_the_reference() {
    let mut r = renderer();
    let view = BirdseyeView::centered_on_origin(640, 360, 10.0).unwrap();
    let layer = r.environment_layer(&road_env(), &view, &PatternSet::builtin()).unwrap();
    let frame = r.render_frame(&layer, &three_vehicles()).unwrap();
    check_snapshot("three_vehicles", &frame, TOLERANCE);
}

/// Bytes of a shader colour (the shaders work with sRGB values in 0..1).
fn bytes(c: [f64; 3]) -> [u8; 3] {
    c.map(|v| (255.0 * v).round() as u8)
}

/// Pixel of a point given in a vehicle's own frame (x forward, y left) [m].
fn pixel_of(view: &BirdseyeView, v: &VehicleSprite, local: DVec2) -> (u32, u32) {
    let p = v.position + DVec2::from_angle(v.yaw).rotate(local);
    let px = view.world_to_pixel(p);
    (px.x.floor() as u32, px.y.floor() as u32)
}

#[test]
fn a_vehicle_covers_exactly_its_posed_rectangle_with_the_windscreen_in_front() {
    let mut r = renderer();
    let view = BirdseyeView::centered_on_origin(400, 300, 10.0).unwrap();
    let layer = r.environment_layer(&road_env(), &view, &PatternSet::builtin()).unwrap();
    let empty = r.render_frame(&layer, &[]).unwrap();
    let yaw = 30f64.to_radians();
    let mut v = VehicleSprite::new(7, DVec2::new(3.0, -2.0), yaw, 10.0, 3.0, "Truck");
    v.real = true;
    let frame = r.render_frame(&layer, std::slice::from_ref(&v)).unwrap();
    let centre_px = view.world_to_pixel(v.position);
    // Half the screen width of the rotated body [px]: the label starts right of it.
    let extent_x = 0.5 * (v.length * yaw.cos().abs() + v.width * yaw.sin().abs()) * view.pixels_per_meter;
    let (mut inside, mut inside_changed) = (0, 0);
    for (x, y, p) in frame.enumerate_pixels() {
        let changed = p != empty.get_pixel(x, y);
        // The pixel centre in the vehicle's frame [m].
        let w = view.pixel_to_world(DVec2::new(f64::from(x) + 0.5, f64::from(y) + 0.5));
        let local = DVec2::from_angle(-yaw).rotate(w - v.position);
        let margin = 1.5 / view.pixels_per_meter;
        let in_body = local.x.abs() < 0.5 * v.length - margin && local.y.abs() < 0.5 * v.width - margin;
        // The soft shadow reaches |(0.15, -0.22)| m offset + 0.2 m blur (2 px) beyond the body.
        let shadow = 0.5;
        let near_body = local.x.abs() < 0.5 * v.length + shadow && local.y.abs() < 0.5 * v.width + shadow;
        if in_body {
            inside += 1;
            inside_changed += usize::from(changed);
        } else if changed && !near_body {
            // The only other change is the id label, entirely right of the body's screen footprint.
            assert!(
                f64::from(x) + 1.0 > centre_px.x + extent_x,
                "pixel ({x}, {y}) changed outside the vehicle's rectangle and left of its label"
            );
        }
    }
    // Every pixel of the body differs from the road unless the body colour happens to match it.
    assert!(inside > 2000, "body too small: {inside} px");
    assert!(inside_changed as f64 > 0.98 * inside as f64, "{inside_changed} of {inside} body pixels drawn");
    // The windscreen (dark) is 25 % of the length behind the front, not behind the centre.
    let (fx, fy) = pixel_of(&view, &v, DVec2::new(0.25 * v.length, 0.0));
    let (bx, by) = pixel_of(&view, &v, DVec2::new(-0.25 * v.length, 0.0));
    let front = frame.get_pixel(fx, fy);
    let back = frame.get_pixel(bx, by);
    // Windscreen colour in fs_vehicle: (0.19, 0.25, 0.31).
    assert!(near(front, bytes([0.19, 0.25, 0.31]), 2), "windscreen pixel {front:?} is not dark");
    let body = class_color("Truck");
    assert!(near(back, [body[0], body[1], body[2]], 3), "rear pixel {back:?} is not the truck colour {body:?}");
}

#[test]
fn real_and_virtual_vehicles_look_different() {
    let mut r = renderer();
    let view = BirdseyeView::centered_on_origin(200, 200, 10.0).unwrap();
    let layer = r.environment_layer(&road_env(), &view, &PatternSet::builtin()).unwrap();
    let mut real = VehicleSprite::new(5, DVec2::ZERO, 0.0, 8.0, 3.0, "Car");
    real.real = true;
    let virt = VehicleSprite { id: -5, real: false, ..real.clone() };
    let a = r.render_frame(&layer, std::slice::from_ref(&real)).unwrap();
    let b = r.render_frame(&layer, &[virt]).unwrap();
    // The outline on the left side: dark for real, light for virtual.
    let (x, y) = pixel_of(&view, &real, DVec2::new(-1.0, 1.4));
    // Outline colours in fs_vehicle: 0.1 (real) and 0.96 (virtual).
    assert!(near(a.get_pixel(x, y), bytes([0.1; 3]), 2), "real outline {:?}", a.get_pixel(x, y));
    assert!(near(b.get_pixel(x, y), bytes([0.96; 3]), 2), "virtual outline {:?}", b.get_pixel(x, y));
}

#[test]
fn bad_sprites_are_skipped_not_drawn_or_panicking() {
    let mut r = renderer();
    let view = BirdseyeView::centered_on_origin(100, 100, 10.0).unwrap();
    let layer = r.environment_layer(&road_env(), &view, &PatternSet::builtin()).unwrap();
    let empty = r.render_frame(&layer, &[]).unwrap();
    let bad = [
        VehicleSprite::new(1, DVec2::new(f64::NAN, 0.0), 0.0, 4.0, 2.0, "Car"),
        VehicleSprite::new(2, DVec2::ZERO, 0.0, -4.0, 2.0, "Car"),
    ];
    let mut img = image::RgbaImage::new(1, 1);
    let skipped = r.render_frame_into(&layer, &bad, &mut img).unwrap();
    assert_eq!(skipped, 2);
    assert_eq!(img, empty);
}

#[test]
fn a_vehicle_under_two_pixels_is_drawn_as_a_point_not_lost_between_pixels() {
    let mut r = renderer();
    // 0.05 px/m: a 4.5 m car is a fifth of a pixel. At the origin it sits on the corner of four
    // pixels, covering none of their centres: drawn at its size it would leave no trace. The
    // vehicle shader draws every vehicle at least 4 px wide (issue 25: "vehicles under 2 px
    // drawn as points"), so a whole ring of thousands stays visible.
    let view = BirdseyeView::centered_on_origin(200, 200, 0.05).unwrap();
    let layer = r.environment_layer(&road_env(), &view, &PatternSet::builtin()).unwrap();
    let empty = r.render_frame(&layer, &[]).unwrap();
    let car = VehicleSprite::new(-3, DVec2::ZERO, 0.3, 4.5, 1.8, "Car");
    let img = r.render_frame(&layer, &[car]).unwrap();
    for (x, y) in [(99, 99), (100, 99), (99, 100), (100, 100)] {
        assert_ne!(img.get_pixel(x, y), empty.get_pixel(x, y), "pixel ({x}, {y}) of the point is not drawn");
    }
}
