//! spade's predicates as terrastream builds them (`vendor/robust`: the floating-point determinant
//! is returned where integer coordinates make it exact): their signs against exact integer
//! arithmetic, on grid points (often collinear and cocircular) and on points where the fast
//! path must not apply (large or fractional coordinates).
#![allow(clippy::unwrap_used)]

use proptest::prelude::*;
use robust::{Coord, incircle, orient2d};

fn c(p: (i64, i64)) -> Coord<f64> {
    Coord { x: p.0 as f64, y: p.1 as f64 }
}

/// The sign of orient2d's determinant, exactly.
fn orient_exact(a: (i64, i64), b: (i64, i64), p: (i64, i64)) -> i32 {
    let d = i128::from(a.0 - p.0) * i128::from(b.1 - p.1) - i128::from(a.1 - p.1) * i128::from(b.0 - p.0);
    d.signum() as i32
}

/// The sign of incircle's determinant, exactly.
fn incircle_exact(a: (i64, i64), b: (i64, i64), cc: (i64, i64), d: (i64, i64)) -> i32 {
    let r = |p: (i64, i64)| {
        let (x, y) = (i128::from(p.0 - d.0), i128::from(p.1 - d.1));
        (x, y, x * x + y * y)
    };
    let ((ax, ay, al), (bx, by, bl), (cx, cy, cl)) = (r(a), r(b), r(cc));
    let det = al * (bx * cy - cx * by) + bl * (cx * ay - ax * cy) + cl * (ax * by - bx * ay);
    det.signum() as i32
}

fn sign(v: f64) -> i32 {
    if v > 0.0 {
        1
    } else if v < 0.0 {
        -1
    } else {
        0
    }
}

fn point(span: i64) -> impl Strategy<Value = (i64, i64)> {
    (-span..=span, -span..=span)
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(4000))]

    /// Small grids: many collinear and cocircular quadruples, all on the fast path.
    #[test]
    fn signs_are_exact_on_small_grids(a in point(3), b in point(3), cc in point(3), d in point(3), off in point(100_000)) {
        let t = |p: (i64, i64)| (p.0 + off.0, p.1 + off.1);
        let (a, b, cc, d) = (t(a), t(b), t(cc), t(d));
        prop_assert_eq!(sign(orient2d(c(a), c(b), c(d))), orient_exact(a, b, d));
        prop_assert_eq!(sign(incircle(c(a), c(b), c(cc), c(d))), incircle_exact(a, b, cc, d));
    }

    /// Nearly cocircular and nearly collinear points spread past the fast paths' bounds (2^12 for
    /// incircle, 2^26 for orient2d): the adaptive stages decide, and still exactly.
    #[test]
    fn signs_are_exact_past_the_fast_bounds(
        o in point(1 << 20), w in 1i64..(1 << 28), h in 1i64..(1 << 28), dx in -1i64..=1, dy in -1i64..=1,
    ) {
        // A rectangle's corners (cocircular), the last one nudged by a unit or not at all.
        let (a, b, cc) = (o, (o.0 + w, o.1), (o.0 + w, o.1 + h));
        let d = (o.0 + dx, o.1 + h + dy);
        prop_assert_eq!(sign(incircle(c(a), c(b), c(cc), c(d))), incircle_exact(a, b, cc, d));
        // Nearly collinear: the far corner nudged off the diagonal through a and cc.
        let e = (o.0 + 2 * w + dx, o.1 + 2 * h + dy);
        prop_assert_eq!(sign(orient2d(c(a), c(cc), c(e))), orient_exact(a, cc, e));
    }
}

#[test]
fn a_grid_square_is_cocircular_and_its_sides_collinear() {
    let sq = [(0, 0), (1, 0), (1, 1), (0, 1)];
    assert_eq!(sign(incircle(c(sq[0]), c(sq[1]), c(sq[2]), c(sq[3]))), 0);
    assert_eq!(sign(orient2d(c((0, 0)), c((2, 0)), c((5, 0)))), 0);
    // Fractional coordinates are never taken for exact: a nearly cocircular quadruple off the
    // grid still gets its exact (adaptive) sign.
    let f = |x: f64, y: f64| Coord { x, y };
    let eps = f64::EPSILON;
    let v = incircle(f(0.5, 0.5), f(1.5, 0.5), f(1.5, 1.5), f(0.5, 1.5 + eps));
    assert_ne!(sign(v), 0, "a point off the circle is not on it: {v}");
}
