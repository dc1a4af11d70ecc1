//! Camera flights: any text through `Flight::from_json` (which validates). A flight that
//! validates must give finite poses with a unit-length-able up vector at every time of its
//! duration and around it, keep validating after `to_world`, and survive `to_json`.
#![no_main]
use libfuzzer_sys::fuzz_target;
use terrastream::client::stream::flight_path::{Flight, Pose};
use terrastream::geom::Bounds;

fn check_pose(p: &Pose, t: f64) {
    for v in [p.eye, p.target, p.up] {
        assert!(v.is_finite(), "pose at t = {t} is not finite: {p:?}");
    }
    assert!(p.up.to_array().iter().any(|&c| c != 0.0), "pose at t = {t} has a zero up vector: {p:?}");
}

fn check_flight(f: &Flight) {
    let (start, end) = (f.start(), f.end());
    assert!(start.is_finite() && end.is_finite() && start <= end, "times {start}..{end}");
    let mut times: Vec<f64> = f.keys.iter().map(|k| k.t).collect();
    for i in 0..=64 {
        // start + (end − start)·s overflows when the times span more than f64::MAX; this form
        // stays finite for any finite start and end.
        let s = f64::from(i) / 64.0;
        times.push(start * (1.0 - s) + end * s);
    }
    for w in f.keys.windows(2) {
        times.push(w[0].t / 2.0 + w[1].t / 2.0);
    }
    times.extend([start - 1.0, end + 1.0, f64::NEG_INFINITY, f64::INFINITY, f64::NAN]);
    for t in times {
        check_pose(&f.pose_at(t), t);
    }
}

fuzz_target!(|data: &[u8]| {
    let Ok(text) = std::str::from_utf8(data) else { return };
    let Ok(f) = Flight::from_json(text) else { return };
    check_flight(&f);
    let json = f.to_json().unwrap_or_else(|e| panic!("valid flight does not serialise: {e}"));
    let back =
        Flight::from_json(&json).unwrap_or_else(|e| panic!("serialised flight does not parse: {e}\n{json}"));
    assert_eq!(f, back, "flight changed through JSON");
    // A normalised flight on a 10 km tileset must stay valid in world units.
    let bounds = Bounds::new([0.0, 0.0, 100.0], [10_000.0, 8_000.0, 2_500.0]);
    if let Ok(w) = f.to_world(&bounds) {
        check_flight(&w);
    }
});
