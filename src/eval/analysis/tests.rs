use super::*;

fn plan() -> CameraPlan {
    CameraPlan {
        width: 400,
        height: 300,
        fov_deg: 60.0,
        distances: vec![1.0, 2.0],
        azimuths: 4,
        elevations: vec![30.0, 60.0],
    }
}

fn cube() -> Bounds {
    Bounds::new([10.0, 20.0, 0.0], [30.0, 40.0, 20.0])
}

#[test]
fn confusion_counts_and_metrics() {
    let r = [true, true, true, false, false, true];
    let l = [true, false, true, true, false, true];
    let c = Confusion::of_masks(&r, &l);
    assert_eq!(c, Confusion { tp: 3, fp: 1, fn_: 1 });
    assert!((c.recall() - 0.75).abs() < 1e-12);
    assert!((c.precision() - 0.75).abs() < 1e-12);
    assert!((c.f_measure() - 0.75).abs() < 1e-12);
    let c = Confusion { tp: 8, fp: 2, fn_: 0 };
    let (p, r) = (0.8, 1.0);
    assert!((c.f_measure() - 2.0 * p * r / (p + r)).abs() < 1e-12);
}

#[test]
fn confusion_edge_cases() {
    let none = Confusion::default();
    assert_eq!((none.recall(), none.precision(), none.f_measure()), (1.0, 1.0, 1.0));
    let only_fp = Confusion { tp: 0, fp: 5, fn_: 0 };
    assert_eq!(only_fp.precision(), 0.0);
    assert_eq!(only_fp.f_measure(), 0.0);
    let only_fn = Confusion { tp: 0, fp: 0, fn_: 5 };
    assert_eq!(only_fn.recall(), 0.0);
    assert_eq!(only_fn.f_measure(), 0.0);
    let mut a = Confusion { tp: 1, fp: 2, fn_: 3 };
    a.add(&Confusion { tp: 10, fp: 20, fn_: 30 });
    assert_eq!(a, Confusion { tp: 11, fp: 22, fn_: 33 });
}

#[test]
fn depth_round_trips_and_differences() {
    let (n, f) = (0.5, 1000.0);
    for d in [0.5, 1.0, 10.0, 123.0, 999.0] {
        let z = f * (d - n) / ((f - n) * d);
        let back = linear_depth(z as f32, n, f).unwrap();
        assert!((back - d).abs() / d < 1e-4, "{d} → {back}");
    }
    assert_eq!(linear_depth(1.0, n, f), None);
    let a = [1.0, 2.0, f64::NAN, 4.0];
    let b = [1.5, f64::NAN, 3.0, 3.0];
    let dd = DepthDiff::of(&a, &b);
    assert_eq!(dd.count, 2);
    assert!((dd.mean().unwrap() - 0.75).abs() < 1e-12);
    assert_eq!(DepthDiff::default().mean(), None);
}

#[test]
fn cameras_spread_on_spheres_and_see_the_whole_box_at_fit_distance() {
    let b = cube();
    let p = plan();
    let cams = cameras(&b, Subject::Terrain, &p).unwrap();
    assert_eq!(cams.len(), 2 * 4 * 2);
    let (c, r) = bounding_sphere(&b);
    let fit = fit_distance(r, p.width, p.height, p.fov_deg);
    for e in &cams {
        let d = (e.camera.eye - c).length();
        assert!((d - e.distance_factor * fit).abs() < 1e-9 * fit);
        assert!((d - e.distance).abs() < 1e-9);
        assert_eq!(e.camera.target, c);
        // Elevation above the horizontal plane matches.
        let el = ((e.camera.eye[2] - c[2]) / d).asin().to_degrees();
        assert!((el - e.elevation_deg).abs() < 1e-9);
        assert!(e.far > d + r && e.near > 0.0 && e.near < d - r);
        let view = e.camera.view().unwrap();
        // At the fit distance every corner of the box is inside the frustum.
        if e.distance_factor == 1.0 {
            for i in 0..8 {
                let corner = [
                    if i & 1 == 0 { b.min[0] } else { b.max[0] },
                    if i & 2 == 0 { b.min[1] } else { b.max[1] },
                    if i & 4 == 0 { b.min[2] } else { b.max[2] },
                ];
                let q = DVec3::from_array(corner) - view.eye;
                let z = q.dot(view.forward);
                assert!(z > 0.0);
                assert!(q.dot(view.right).abs() <= z * view.tan_h + 1e-9);
                assert!(q.dot(view.up).abs() <= z * view.tan_v + 1e-9);
            }
        }
    }
    // Azimuths are distinct and evenly spread.
    let az: Vec<f64> = cams.iter().take(4).map(|e| e.azimuth_deg).collect();
    assert_eq!(az, vec![0.0, 90.0, 180.0, 270.0]);
}

#[test]
fn model_cameras_use_the_y_axis_as_pole() {
    let mut p = plan();
    p.elevations = vec![-45.0, 45.0];
    let cams = cameras(&cube(), Subject::Model, &p).unwrap();
    let (c, _) = bounding_sphere(&cube());
    for e in &cams {
        let d = e.distance;
        let el = ((e.camera.eye[1] - c[1]) / d).asin().to_degrees();
        assert!((el - e.elevation_deg).abs() < 1e-9);
        assert_eq!(e.camera.up, DVec3::Y);
    }
}

#[test]
fn bad_plans_are_refused_with_the_field_named() {
    let b = cube();
    let mut p = plan();
    p.elevations = vec![90.0];
    assert!(cameras(&b, Subject::Terrain, &p).unwrap_err().to_string().contains("elevations"));
    let mut p = plan();
    p.distances = vec![0.0];
    assert!(cameras(&b, Subject::Terrain, &p).unwrap_err().to_string().contains("distances"));
    let mut p = plan();
    p.azimuths = 0;
    assert!(cameras(&b, Subject::Terrain, &p).unwrap_err().to_string().contains("azimuths"));
    assert!(cameras(&Bounds::empty(), Subject::Terrain, &plan()).unwrap_err().to_string().contains("bounds"));
}

fn result(f: f64, lod: Confusion) -> CameraResult {
    CameraResult {
        distance_factor: f,
        distance: f,
        azimuth_deg: 0.0,
        elevation_deg: 0.0,
        lod,
        depth: DepthDiff { sum: 2.0, count: 4 },
        drawn_per_level: vec![1, 2],
        points_drawn: 10,
        triangles_drawn: 20,
        per_level: vec![lod, Confusion { tp: 1, fp: 0, fn_: 1 }],
    }
}

#[test]
fn summaries_sum_pixels_and_group_by_distance() {
    let rs = vec![
        result(2.0, Confusion { tp: 90, fp: 10, fn_: 0 }),
        result(1.0, Confusion { tp: 50, fp: 0, fn_: 50 }),
        result(2.0, Confusion { tp: 100, fp: 0, fn_: 0 }),
    ];
    let s = summarize(&rs);
    assert_eq!(s.cameras, 3);
    assert_eq!(s.lod, Confusion { tp: 240, fp: 10, fn_: 50 });
    assert_eq!(s.drawn_per_level, vec![3, 6]);
    assert_eq!(s.per_level[1], Confusion { tp: 3, fp: 0, fn_: 3 });
    assert!((s.depth.mean().unwrap() - 0.5).abs() < 1e-12);
    let f: Vec<f64> = rs.iter().map(|r| r.lod.f_measure()).collect();
    assert!((s.mean_f - f.iter().sum::<f64>() / 3.0).abs() < 1e-12);
    assert!((s.per_level_mean_f[1] - 2.0 / 3.0).abs() < 1e-12);
    let rec: Vec<f64> = rs.iter().map(|r| r.lod.recall()).collect();
    assert!((s.mean_recall - rec.iter().sum::<f64>() / 3.0).abs() < 1e-12);
    let g = by_distance(&rs);
    assert_eq!(g.len(), 2);
    assert_eq!(g[0].0, 1.0);
    assert_eq!(g[1].1.cameras, 2);
    assert_eq!(g[1].1.lod, Confusion { tp: 190, fp: 10, fn_: 0 });
}

#[test]
fn level_choice_follows_the_screen_space_error() {
    use crate::client::tree::LevelCost;
    let cost = |p: u32| LevelCost { primitives: p, bytes: u64::from(p) * 4 };
    let errs = [0.1, 1.0, 10.0];
    let costs = [cost(300), cost(200), cost(100)];
    let k = 500.0;
    // e·k/d ≤ 2 ⇔ d ≥ e·k/2: level 2 from 2500, level 1 from 250, else 0.
    assert_eq!(level_for(&errs, &costs, k, 3000.0, 2.0), 2);
    assert_eq!(level_for(&errs, &costs, k, 2499.0, 2.0), 1);
    assert_eq!(level_for(&errs, &costs, k, 250.0, 2.0), 1);
    assert_eq!(level_for(&errs, &costs, k, 10.0, 2.0), 0);
    // Under the threshold the cheapest wins, not the coarsest; an absent level never does.
    let dearer = [cost(300), cost(100), cost(200)];
    assert_eq!(level_for(&errs, &dearer, k, 3000.0, 2.0), 1);
    let absent = [0.1, f64::INFINITY, 10.0];
    let gap = [cost(300), LevelCost::ABSENT, cost(100)];
    assert_eq!(level_for(&absent, &gap, k, 2499.0, 2.0), 0);
    assert_eq!(level_for(&absent, &gap, k, 3000.0, 2.0), 2);
}

#[test]
fn grid_is_centred_and_its_camera_sees_every_instance() {
    let o = grid_offsets(3, 2.0, Subject::Model);
    assert_eq!(o.len(), 9);
    assert_eq!(o[4], [0.0, 0.0, 0.0]);
    assert!(o.iter().all(|p| p[1] == 0.0));
    let c = DVec3::new(0.0, 0.5, 0.0);
    let cam = grid_camera(c, 0.7, 3, 2.0, Subject::Model, 400, 300, 60.0);
    let view = cam.camera.view().unwrap();
    for p in &o {
        let p = DVec3::from_array(*p);
        assert!(view.intersects(&Bounds::new((p - 0.7).to_array(), (p + 0.7).to_array())));
    }
    assert!((median(&[3.0, 1.0, 2.0]) - 2.0).abs() < 1e-12);
    assert!((median(&[4.0, 1.0, 2.0, 3.0]) - 2.5).abs() < 1e-12);
    assert!(median(&[]).is_nan());
}

#[test]
fn report_ends_with_the_f_measure_line() {
    let rep = EvalReport {
        tileset: "t".into(),
        source_file: "bun_zipper.ply".into(),
        subject: Subject::Model,
        adapter: "a".into(),
        plan: plan(),
        threshold_px: 2.0,
        levels: vec![],
        reference_points: 1,
        reference_triangles: 1,
        results: vec![result(1.0, Confusion { tp: 98, fp: 2, fn_: 2 })],
        instances: vec![InstanceRow {
            n: 11,
            ms_full: 10.0,
            ms_lod: 2.5,
            per_level: vec![0, 121],
            triangles_full: 1,
            triangles_lod: 0,
            points_lod: 5,
        }],
        instances_note: None,
        grid_skipped: vec![81],
    };
    let t = rep.text();
    assert_eq!(t.lines().last().unwrap(), "F-measure: 0.9800");
    assert!(t.contains("ratio 4.00"));
    let md = rep.markdown("f.png", Some("t.png"), "EXTRA\n");
    assert!(md.contains("EXTRA\nF-measure"));
    assert!(md.contains("![F-measure by distance](f.png)"));
    assert!(md.contains("| 121 | 10.00 | 2.50 | 4.00 |"));
    assert!(md.contains("N = [81]"));
    assert!(md.trim_end().ends_with("F-measure: 0.9800"));
}

fn paper_report(source: &str, subject: Subject, sides: &[u32]) -> EvalReport {
    let row = |n| InstanceRow {
        n,
        ms_full: 10.0,
        ms_lod: 2.5,
        per_level: vec![],
        triangles_full: 1,
        triangles_lod: 0,
        points_lod: 5,
    };
    EvalReport {
        tileset: "t".into(),
        source_file: source.into(),
        subject,
        adapter: "a".into(),
        plan: plan(),
        threshold_px: 1.0,
        levels: vec![],
        reference_points: 1,
        reference_triangles: 1,
        results: vec![result(1.0, Confusion { tp: 98, fp: 2, fn_: 2 })],
        instances: sides.iter().map(|&n| row(n)).collect(),
        instances_note: None,
        grid_skipped: vec![],
    }
}

#[test]
fn report_prints_the_papers_figures_for_its_model() {
    let rep = paper_report("bun_zipper.ply", Subject::Model, &[11, 41, 3]);
    assert_eq!(rep.paper_model(), Some(paper::PaperModel::StanfordBunny));
    let t = rep.text();
    let line = |start: &str| t.lines().find(|l| l.starts_with(start)).unwrap().to_owned();
    assert!(
        line("instances  1681").ends_with(
            "ratio 4.00; paper (Stanford Bunny): GTX 750 ≥1.62 (120/74 FPS), GTX 1080 Ti capped (120/120 FPS)"
        ),
        "{t}"
    );
    assert!(
        line("instances   121").ends_with("GTX 750 capped (120/120 FPS), GTX 1080 Ti capped (120/120 FPS)")
    );
    assert!(
        line("instances     9")
            .ends_with("paper: no row for 9 instances (Tables 4–7: [121, 441, 961, 1681, 5041, 6561])")
    );
    assert!(
        line("LOD selection")
            .ends_with("paper (Table 12, Stanford Bunny): recall 0.950, precision 0.981, F 0.965")
    );
    assert_eq!(t.lines().last().unwrap(), "F-measure: 0.9800");
    let md = rep.markdown("f.png", None, "");
    assert!(md.contains("| the paper, Table 12, Stanford Bunny | 0.950 | 0.981 | 0.965 |"), "{md}");
    assert!(md.contains("| the paper, Table 12, average of its 5 models | 0.952 | 0.944 | 0.947 |"));
    assert!(
        md.contains("| 1681 | 10.00 | 2.50 | 4.00 | ≥1.62 (120/74 FPS) | capped (120/120 FPS) |"),
        "{md}"
    );
    assert!(md.contains("| 9 | 10.00 | 2.50 | 4.00 | no row | no row |"));
    assert!(md.contains("the Stanford Bunny's"));
    assert!(!md.contains("not reproduced") && !t.contains("not available"));
}

#[test]
fn report_prints_the_papers_range_for_other_models_and_terrain_f() {
    let rep = paper_report("spot.obj", Subject::Model, &[11]);
    assert_eq!(rep.paper_model(), None);
    let t = rep.text();
    assert!(
        t.contains(
            "ratio 4.00; paper (range over its 5 models): GTX 750 1.27–2.40 (Bunny capped), \
             GTX 1080 Ti ≥1.20–≥1.54 (Buddha, Dragon, Bunny capped)"
        ),
        "{t}"
    );
    assert!(t.contains(
        "paper (Table 12, average; not one of its models): recall 0.952, precision 0.944, F 0.947"
    ));
    let md = rep.markdown("f.png", None, "");
    assert!(md.contains("| 121 | 10.00 | 2.50 | 4.00 | 1.27–2.40 (Bunny capped) |"), "{md}");
    assert!(!md.contains("Table 12, Stanford Bunny"));

    // A terrain named like a model is still terrain: the large-terrain F, no model.
    let rep = paper_report("bunny.png", Subject::Terrain, &[]);
    assert_eq!(rep.paper_model(), None);
    let t = rep.text();
    assert!(t.contains("paper: F 0.972 (large terrain), Table 12 average: recall 0.952"), "{t}");
    assert!(!t.contains("paper's ratio"));
    let md = rep.markdown("f.png", None, "");
    assert!(md.contains("| the paper, large terrain (1,681 tiles, 5 levels) | | | 0.972 |"), "{md}");
}

#[test]
fn charts_draw_lines_in_their_colours() {
    let rep_rows = vec![
        InstanceRow {
            n: 11,
            ms_full: 10.0,
            ms_lod: 2.0,
            per_level: vec![],
            triangles_full: 0,
            triangles_lod: 0,
            points_lod: 0,
        },
        InstanceRow {
            n: 21,
            ms_full: 40.0,
            ms_lod: 5.0,
            per_level: vec![],
            triangles_full: 0,
            triangles_lod: 0,
            points_lod: 0,
        },
    ];
    let img = frametime_chart(&rep_rows).unwrap().draw();
    assert_eq!(img.dimensions(), (640, 400));
    let count = |c: [u8; 4]| img.pixels().filter(|p| p.0 == c).count();
    assert!(count(PALETTE[0]) > 50 && count(PALETTE[3]) > 50);
    assert!(count([0, 0, 0, 255]) > 500, "axes");
    assert!(frametime_chart(&[]).is_none());
    // A point outside a log axis (0) is skipped, not drawn at infinity.
    let ch = Chart {
        width: 100,
        height: 80,
        x_range: (1.0, 10.0),
        y_range: (1.0, 10.0),
        log_x: true,
        log_y: true,
        y_grid: vec![],
        y_mark: None,
        series: vec![Series { color: PALETTE[1], thick: false, points: vec![(0.0, 1.0), (2.0, 2.0)] }],
    };
    let img = ch.draw();
    assert!(img.pixels().filter(|p| p.0 == PALETTE[1]).count() > 10);
}
