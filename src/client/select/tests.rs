use std::collections::{HashMap, HashSet};

use proptest::prelude::*;

use super::*;
use crate::client::tree::{Synthetic, entry};
use crate::geom::Mesh;
use crate::store::IndexChunk;
use crate::tiling::Pyramid;

fn small_tree() -> TileTree {
    TileTree::synthetic(&Synthetic {
        width: 8 * 64 + 1,
        height: 6 * 64 + 1,
        tile_size: 64,
        cell_size: 10.0,
        relief: 300.0,
        levels: 3,
        leaf_error: 2.0,
        seed: 7,
    })
    .unwrap()
}

fn cam(eye: [f64; 3], target: [f64; 3]) -> Camera {
    let (eye, target) = (DVec3::from_array(eye), DVec3::from_array(target));
    Camera { eye, target, up: DVec3::Z, width: 1280, height: 800, fov_deg: 60.0 }
}

fn params(distance: DistanceRule, fade: f64) -> SelectParams {
    SelectParams { threshold_px: 2.0, fade_seconds: fade, distance }
}

/// Deepest loaded nodes (tree leaves) whose subtree box is in view.
fn visible_leaves(tree: &TileTree, view: &View) -> Vec<NodeId> {
    (0..tree.len() as NodeId)
        .filter(|&n| tree.node(n).loaded_children().count() == 0 && view.intersects(&tree.node(n).cull))
        .collect()
}

/// For each visible leaf, how many non-retiring draws cover it (ancestor-or-self).
fn coverage(tree: &TileTree, view: &View, sel: &Selection) -> Vec<(NodeId, usize)> {
    let drawn: HashSet<NodeId> = sel.draws.iter().filter(|d| !d.retiring).map(|d| d.node).collect();
    visible_leaves(tree, view)
        .into_iter()
        .map(|leaf| {
            let mut n = leaf;
            let mut c = 0;
            while n != NO_NODE {
                c += usize::from(drawn.contains(&n));
                n = tree.node(n).parent;
            }
            (leaf, c)
        })
        .collect()
}

fn drawn_set(sel: &Selection) -> Vec<(NodeId, u8)> {
    let mut v: Vec<_> = sel.draws.iter().filter(|d| !d.retiring).map(|d| (d.node, d.level)).collect();
    v.sort_unstable();
    v
}

#[test]
fn camera_errors_name_the_field() {
    let c = cam([0.0, 0.0, 10.0], [10.0, 0.0, 0.0]);
    assert!(c.view().is_ok());
    let e = |c: Camera| c.view().unwrap_err().to_string();
    assert!(e(Camera { width: 0, ..c }).contains("viewport 0×800"));
    assert!(e(Camera { fov_deg: 180.0, ..c }).contains("fov 180"));
    assert!(e(Camera { target: c.eye, ..c }).contains("same point"));
    assert!(e(Camera { up: DVec3::ZERO, ..c }).contains("up"));
    assert!(e(Camera { eye: DVec3::new(f64::NAN, 0.0, 0.0), ..c }).contains("not finite"));
    let straight_down = Camera { target: DVec3::ZERO, ..c };
    assert!(e(straight_down).contains("parallel"));
    assert!(Selector::new(SelectParams { threshold_px: 0.0, ..SelectParams::default() }).is_err());
    assert!(Selector::new(SelectParams { fade_seconds: -1.0, ..SelectParams::default() }).is_err());
}

#[test]
fn frustum_and_screen_error() {
    let v = Camera { width: 320, height: 200, ..cam([0.0, 0.0, 0.0], [10.0, 0.0, 0.0]) }.view().unwrap();
    // k = w / (2·tan(30°)).
    assert!((v.k - 320.0 / (2.0 * 30f64.to_radians().tan())).abs() < 1e-9);
    assert!((v.screen_error(2.0, 100.0) - 2.0 * v.k / 100.0).abs() < 1e-12);
    let b = |x0: f64, y0: f64| Bounds::new([x0, y0, -1.0], [x0 + 1.0, y0 + 1.0, 1.0]);
    assert!(v.intersects(&b(50.0, 0.0)));
    assert!(!v.intersects(&b(-50.0, 0.0)), "behind the eye");
    assert!(!v.intersects(&b(50.0, 60.0)), "left of a 60° view (tan 30° · 50 ≈ 29)");
    assert!(v.intersects(&b(50.0, 25.0)));
    // Vertical fov is narrower (200/320 of the horizontal tangent): 18 m up at 50 m is out.
    assert!(!v.intersects(&Bounds::new([50.0, 0.0, 19.0], [51.0, 1.0, 20.0])));
    assert!(v.intersects(&Bounds::new([50.0, 0.0, 17.0], [51.0, 1.0, 18.0])));
}

#[test]
fn all_resident_meets_threshold_and_covers_once() {
    let tree = small_tree();
    let mut s = Selector::new(params(DistanceRule::Centre, 0.0)).unwrap();
    let c = cam([2500.0, -1500.0, 1500.0], [2500.0, 2000.0, 100.0]);
    let sel = s.select(&tree, &c, &AllResident, 0.0).unwrap().clone();
    let view = c.view().unwrap();
    assert!(sel.stats.under_threshold, "max {} px", sel.stats.max_error_px);
    assert!(sel.draws.iter().all(|d| d.error_px <= 2.0));
    let depths: HashSet<u8> = sel.draws.iter().map(|d| d.key.z).collect();
    assert!(depths.len() > 1, "several depths in one view: {depths:?}");
    assert!(coverage(&tree, &view, &sel).iter().all(|&(_, c)| c == 1));
    assert!(sel.wants.is_empty() && sel.missing_chunks.is_empty());
    assert_eq!(sel.stats.holes, 0);
    // Each drawn level is the coarsest under the threshold.
    for d in &sel.draws {
        let errs = tree.level_errors(d.node);
        let node = tree.node(d.node);
        let dist = (node.center - c.eye).length();
        for &e in &errs[usize::from(d.level) + 1..] {
            assert!(view.screen_error(e, dist) > 2.0);
        }
    }
    // A second identical frame visits only the cut and its parents.
    let again = s.select(&tree, &c, &AllResident, 0.1).unwrap();
    assert_eq!(drawn_set(again), drawn_set(&sel));
    assert!(again.stats.visited <= 2 * again.stats.active, "{:?}", again.stats);
}

#[test]
fn leaves_too_coarse_are_drawn_and_reported_over_threshold() {
    let tree = small_tree();
    let mut s = Selector::new(params(DistanceRule::Centre, 0.0)).unwrap();
    // 3 m above a leaf: even level 0 (0.5 m error) is ~20 px.
    let c = cam([100.0, 100.0, 260.0], [200.0, 200.0, 150.0]);
    let sel = s.select(&tree, &c, &AllResident, 0.0).unwrap();
    assert!(!sel.stats.under_threshold);
    assert!(sel.draws.iter().any(|d| d.level == 0 && tree.node(d.node).is_leaf() && d.error_px > 2.0));
}

#[test]
fn down_switch_waits_for_all_children() {
    let tree = small_tree();
    let root = tree.root().unwrap();
    let mut res: HashMap<TileKey, u32> = HashMap::new();
    res.insert(tree.node(root).key, 0b111);
    let mut s = Selector::new(params(DistanceRule::Centre, 0.0)).unwrap();
    let c = cam([2500.0, -1500.0, 1500.0], [2500.0, 1900.0, 100.0]);
    let view = c.view().unwrap();
    let sel = s.select(&tree, &c, &res, 0.0).unwrap().clone();
    // Only the root is resident: it stands in for the whole cut, at its finest level.
    assert_eq!(drawn_set(&sel), vec![(root, 0)]);
    assert!(!sel.wants.is_empty());
    assert!(sel.wants.iter().all(|w| w.priority_px > 2.0 && w.priority_px.is_finite()));
    // Three of the root's four children arrive (every level): still the root.
    let kids: Vec<NodeId> = tree.node(root).loaded_children().collect();
    let wanted: HashSet<TileKey> = sel.wants.iter().map(|w| w.key).collect();
    let cut_kids: Vec<NodeId> =
        kids.iter().copied().filter(|k| wanted.contains(&tree.node(*k).key)).collect();
    if cut_kids.len() == kids.len() {
        for &k in &kids[..3] {
            res.insert(tree.node(k).key, 0b111);
        }
        let sel = s.select(&tree, &c, &res, 0.1).unwrap();
        assert_eq!(drawn_set(sel), vec![(root, 0)]);
        res.insert(tree.node(kids[3]).key, 0b111);
        let sel = s.select(&tree, &c, &res, 0.2).unwrap();
        assert!(sel.draws.iter().all(|d| kids.contains(&d.node)));
    }
    // Whatever arrived, every visible leaf is covered exactly once.
    let sel = s.select(&tree, &c, &res, 0.3).unwrap();
    assert!(coverage(&tree, &view, sel).iter().all(|&(_, c)| c == 1));
}

#[test]
fn up_switch_keeps_children_until_parent_arrives() {
    let tree = small_tree();
    let mut s = Selector::new(params(DistanceRule::Centre, 0.0)).unwrap();
    let near = cam([2500.0, -200.0, 500.0], [2500.0, 1900.0, 100.0]);
    let near_sel = s.select(&tree, &near, &AllResident, 0.0).unwrap().clone();
    // Only what was drawn near stays resident.
    let res: HashMap<TileKey, u32> = near_sel.draws.iter().fold(HashMap::new(), |mut m, d| {
        *m.entry(d.key).or_insert(0) |= 1 << d.level;
        m
    });
    let near_cov: Vec<NodeId> =
        coverage(&tree, &near.view().unwrap(), &near_sel).iter().filter(|c| c.1 == 1).map(|c| c.0).collect();
    assert!(!near_cov.is_empty());
    let far = cam([2500.0, -30000.0, 20000.0], [2500.0, 1900.0, 100.0]);
    let view = far.view().unwrap();
    let sel = s.select(&tree, &far, &res, 1.0).unwrap().clone();
    assert_eq!(s.active(), &[tree.root().unwrap()], "the cut merged up to the root");
    // Nothing resident above the old draws, so the old draws keep standing in where they were.
    assert_eq!(drawn_set(&sel), drawn_set(&near_sel));
    assert_eq!(sel.stats.holes, 0);
    assert_eq!(sel.wants.len(), 1);
    assert!(sel.wants.iter().all(|w| w.priority_px == 0.0), "finer stand-ins: lowest priority");
    let cov: HashMap<NodeId, usize> = coverage(&tree, &view, &sel).into_iter().collect();
    assert!(cov.values().all(|&c| c <= 1));
    assert!(near_cov.iter().all(|l| cov.get(l) == Some(&1)));
    // The root arrives: it replaces them all.
    let res = HashMap::from([(tree.node(0).key, 1u32)]);
    let sel = s.select(&tree, &far, &res, 1.1).unwrap();
    assert_eq!(drawn_set(sel), vec![(0, 0)]);
}

#[test]
fn fades_cross_over_with_complementary_alpha() {
    let tree = small_tree();
    let mut s = Selector::new(params(DistanceRule::Centre, 0.5)).unwrap();
    let a = cam([2500.0, -3000.0, 3000.0], [2500.0, 1900.0, 100.0]);
    let first = s.select(&tree, &a, &AllResident, 0.0).unwrap().clone();
    assert!(first.draws.iter().all(|d| (d.alpha - 1.0).abs() < 1e-6 && !d.retiring), "first frame: no fade");
    let b = cam([2500.0, -500.0, 800.0], [2500.0, 1900.0, 100.0]);
    let mid = s.select(&tree, &b, &AllResident, 10.0).unwrap().clone();
    let retiring: Vec<&DrawItem> = mid.draws.iter().filter(|d| d.retiring).collect();
    let fresh: Vec<&DrawItem> = mid.draws.iter().filter(|d| !d.retiring && d.alpha < 1.0).collect();
    assert!(!retiring.is_empty() && !fresh.is_empty());
    assert!(retiring.iter().all(|d| (d.alpha - 1.0).abs() < 1e-6));
    assert!(fresh.iter().all(|d| d.alpha.abs() < 1e-6));
    let later = s.select(&tree, &b, &AllResident, 10.2).unwrap().clone();
    for d in later.draws.iter().filter(|d| d.retiring) {
        assert!((d.alpha - 0.6).abs() < 1e-4, "{}", d.alpha);
    }
    for d in later.draws.iter().filter(|d| !d.retiring && fresh.iter().any(|f| f.node == d.node)) {
        assert!((d.alpha - 0.4).abs() < 1e-4, "{}", d.alpha);
    }
    let done = s.select(&tree, &b, &AllResident, 10.6).unwrap();
    assert!(done.draws.iter().all(|d| !d.retiring && (d.alpha - 1.0).abs() < 1e-6));
}

#[test]
fn missing_chunk_is_requested_and_node_kept() {
    let p = Pyramid::new(8 * 64 + 1, 8 * 64 + 1, 64).unwrap();
    assert_eq!(p.depth, 3);
    let full = TileTree::synthetic(&Synthetic {
        width: 8 * 64 + 1,
        height: 8 * 64 + 1,
        tile_size: 64,
        cell_size: 10.0,
        relief: 300.0,
        levels: 2,
        leaf_error: 2.0,
        seed: 1,
    })
    .unwrap();
    let mut t = TileTree::new(p);
    let root = full.node(0);
    t.insert(&entry(root.key, root.bounds, full.level_errors(0))).unwrap();
    let mut s = Selector::new(params(DistanceRule::Centre, 0.0)).unwrap();
    let c = cam([2500.0, -500.0, 800.0], [2500.0, 2500.0, 100.0]);
    let res: HashMap<TileKey, u32> = HashMap::from([(root.key, 0b11)]);
    let sel = s.select(&t, &c, &res, 0.0).unwrap();
    assert_eq!(sel.missing_chunks, vec![TileKey::new(0, 0, 0)]);
    assert_eq!(drawn_set(sel), vec![(0, 0)]);
    assert_eq!(sel.wants.len(), 0, "level 0 of the root is resident");
    // The chunk arrives (root chunk holds depths 0..=3 here): selection refines at once.
    let chunk = IndexChunk {
        root: TileKey::new(0, 0, 0),
        nodes: (0..full.len() as NodeId)
            .map(|n| entry(full.node(n).key, full.node(n).bounds, full.level_errors(n)))
            .collect(),
    };
    t.insert_chunk(&chunk).unwrap();
    let sel = s.select(&t, &c, &AllResident, 0.1).unwrap();
    assert!(sel.missing_chunks.is_empty());
    assert!(sel.draws.len() > 1);
}

#[test]
fn coherent_cut_matches_fresh_cut_with_nearest_distance() {
    let tree = small_tree();
    let mut carried = Selector::new(params(DistanceRule::Nearest, 0.0)).unwrap();
    for i in 0..40 {
        let t = f64::from(i) / 39.0;
        let c = cam(
            [5000.0 * t, -2000.0 + 3000.0 * t, 3000.0 - 2700.0 * t],
            [2500.0, 1900.0 + 500.0 * (t * 6.0).sin(), 100.0],
        );
        let a = drawn_set(carried.select(&tree, &c, &AllResident, t).unwrap());
        let mut fresh = Selector::new(params(DistanceRule::Nearest, 0.0)).unwrap();
        let b = drawn_set(fresh.select(&tree, &c, &AllResident, t).unwrap());
        assert_eq!(a, b, "frame {i}");
    }
}

#[derive(Debug, Clone)]
struct Step {
    eye: [f64; 3],
    target: [f64; 3],
    arrive: Vec<bool>,
    evict: Vec<bool>,
}

fn steps() -> impl Strategy<Value = Vec<Step>> {
    prop::collection::vec(
        (
            (-2000.0..7000.0f64, -2000.0..6000.0f64, 30.0..4000.0f64),
            (0.0..5120.0f64, 0.0..3840.0f64, 0.0..300.0f64),
            prop::collection::vec(any::<bool>(), 64),
            prop::collection::vec(prop::bool::weighted(0.3), 64),
        )
            .prop_map(|(e, t, arrive, evict)| Step {
                eye: [e.0, e.1, e.2],
                target: [t.0, t.1, t.2],
                arrive,
                evict,
            }),
        1..12,
    )
}

/// One scripted run: wanted tiles arrive at random, undrawn tiles are evicted at random (drawn
/// ones are pinned, as `TileCache` does). Checks every frame.
fn run(steps: &[Step], root_resident: bool, distance: DistanceRule) -> Result<(), TestCaseError> {
    let tree = small_tree();
    let root_key = tree.node(tree.root().unwrap()).key;
    let mut res: HashMap<TileKey, u32> = HashMap::new();
    if root_resident {
        res.insert(root_key, 0b100);
    }
    let mut s = Selector::new(params(distance, 0.3)).unwrap();
    let mut prev_covered: HashSet<NodeId> = HashSet::new();
    for (i, st) in steps.iter().enumerate() {
        let c = cam(st.eye, st.target);
        let Ok(view) = c.view() else { continue };
        let sel = s.select(&tree, &c, &res, i as f64 * 0.1).unwrap().clone();
        let drawn: Vec<NodeId> = sel.draws.iter().filter(|d| !d.retiring).map(|d| d.node).collect();
        for d in &sel.draws {
            prop_assert!(
                res.get(&d.key).copied().unwrap_or(0) & (1 << d.level) != 0,
                "drawn but not resident"
            );
        }
        for &a in &drawn {
            for &b in &drawn {
                prop_assert!(a == b || !tree.is_ancestor_or_self(a, b), "overlapping draws {a} {b}");
            }
        }
        let cov = coverage(&tree, &view, &sel);
        for &(leaf, n) in &cov {
            prop_assert!(n <= 1);
            if root_resident {
                prop_assert_eq!(n, 1, "hole at leaf {} in frame {}", leaf, i);
            } else if prev_covered.contains(&leaf) {
                prop_assert_eq!(n, 1, "leaf {} was covered last frame and lost it in frame {}", leaf, i);
            }
        }
        prev_covered = cov.iter().filter(|(_, n)| *n == 1).map(|(l, _)| *l).collect();
        // Evict undrawn tiles (never the pinned root when it is the safety net).
        let pinned: HashSet<(TileKey, u8)> = sel.draws.iter().map(|d| (d.key, d.level)).collect();
        let keys: Vec<TileKey> = {
            let mut k: Vec<_> = res.keys().copied().collect();
            k.sort();
            k
        };
        for (j, key) in keys.into_iter().enumerate() {
            if st.evict[j % st.evict.len()] && key != root_key {
                let m = res.entry(key).or_insert(0);
                for l in 0..3u8 {
                    if !pinned.contains(&(key, l)) {
                        *m &= !(1 << l);
                    }
                }
            }
        }
        for (j, w) in sel.wants.iter().enumerate() {
            if st.arrive[j % st.arrive.len()] {
                *res.entry(w.key).or_insert(0) |= 1 << w.level;
            }
        }
    }
    Ok(())
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 64, ..ProptestConfig::default() })]

    #[test]
    fn never_a_hole_with_root_resident(steps in steps()) {
        run(&steps, true, DistanceRule::Centre)?;
    }

    #[test]
    fn covered_area_stays_covered(steps in steps()) {
        run(&steps, false, DistanceRule::Centre)?;
        run(&steps, false, DistanceRule::Nearest)?;
    }

    #[test]
    fn threshold_met_when_everything_resident(
        e in (-2000.0..7000.0f64, -2000.0..6000.0f64, 80.0..4000.0f64),
        t in (0.0..5120.0f64, 0.0..3840.0f64, 0.0..300.0f64),
    ) {
        let tree = small_tree();
        let c = cam([e.0, e.1, e.2], [t.0, t.1, t.2]);
        let Ok(view) = c.view() else { return Ok(()) };
        let mut s = Selector::new(params(DistanceRule::Centre, 0.0)).unwrap();
        let sel = s.select(&tree, &c, &AllResident, 0.0).unwrap().clone();
        for d in &sel.draws {
            prop_assert!(d.error_px <= 2.0 || (tree.node(d.node).is_leaf() && d.level == 0),
                "node {} level {} at {} px", d.key, d.level, d.error_px);
        }
        prop_assert!(coverage(&tree, &view, &sel).iter().all(|&(_, n)| n == 1));
    }
}

#[test]
fn skirts_face_outward_and_skip_the_outer_border() {
    // Unit square, two triangles, counter-clockwise from above.
    let mesh = Mesh {
        positions: vec![[0.0, 0.0, 5.0], [1.0, 0.0, 5.0], [1.0, 1.0, 6.0], [0.0, 1.0, 6.0]],
        triangles: vec![[0, 1, 2], [0, 2, 3]],
    };
    let s = add_skirts(&mesh, 2.0, None);
    assert_eq!(s.first_skirt_vertex, 4);
    assert_eq!(s.mesh.positions.len(), 8);
    assert_eq!(s.mesh.triangles.len(), 2 + 8);
    let centre = DVec3::new(0.5, 0.5, 5.0);
    for t in &s.mesh.triangles[s.first_skirt_triangle..] {
        let [a, b, c] = t.map(|i| s.mesh.positions[i as usize]);
        let n = DVec3::from_array(crate::geom::triangle_normal(a, b, c));
        let mid = (DVec3::from_array(a) + DVec3::from_array(b) + DVec3::from_array(c)) * (1.0 / 3.0);
        assert!(n.dot(mid - centre) > 0.0, "skirt triangle {t:?} faces inward");
        assert!(n[2].abs() < 1e-12, "walls are vertical");
    }
    for p in &s.mesh.positions[4..] {
        assert!((p[2] - 3.0).abs() < 1e-12 || (p[2] - 4.0).abs() < 1e-12);
    }
    // Clockwise input gets outward walls too.
    let cw = Mesh { positions: mesh.positions.clone(), triangles: vec![[0, 2, 1], [0, 3, 2]] };
    let s2 = add_skirts(&cw, 2.0, None);
    for t in &s2.mesh.triangles[s2.first_skirt_triangle..] {
        let [a, b, c] = t.map(|i| s2.mesh.positions[i as usize]);
        let n = DVec3::from_array(crate::geom::triangle_normal(a, b, c));
        let mid = (DVec3::from_array(a) + DVec3::from_array(b) + DVec3::from_array(c)) * (1.0 / 3.0);
        assert!(n.dot(mid - centre) > 0.0);
    }
    // On the dataset's left and bottom border: only the two inner edges get walls.
    let outer = Bounds::new([0.0, 0.0, 0.0], [10.0, 10.0, 10.0]);
    let s3 = add_skirts(&mesh, 2.0, Some(&outer));
    assert_eq!(s3.mesh.triangles.len() - s3.first_skirt_triangle, 4);
    assert!((skirt_depth(0.5, 2.0) - 2.5).abs() < 1e-12);
}
