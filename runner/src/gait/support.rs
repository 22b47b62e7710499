//! The support triangle of a crawl (the three feet on the ground while one swings): how far a
//! point lies inside it ([`margin`]) and the smallest horizontal shift that puts the centre of
//! mass a given margin inside ([`shift_into`]).

use nalgebra::Vector2;

/// Signed distance of `p` inside the triangle `tri` (positive inside: the distance to the
/// nearest edge; negative outside), whatever the vertices' order.
pub fn margin(p: &Vector2<f64>, tri: &[Vector2<f64>; 3]) -> f64 {
    let area2 = (tri[1] - tri[0]).perp(&(tri[2] - tri[0]));
    let sign = if area2 >= 0.0 { 1.0 } else { -1.0 };
    (0..3)
        .map(|k| {
            let (a, b) = (tri[k], tri[(k + 1) % 3]);
            let e = b - a;
            sign * e.perp(&(p - a)) / e.norm().max(1e-12)
        })
        .fold(f64::INFINITY, f64::min)
}

/// The triangle's incentre and inradius (the point deepest inside and its margin).
pub fn incentre(tri: &[Vector2<f64>; 3]) -> (Vector2<f64>, f64) {
    let side = |k: usize| (tri[(k + 1) % 3] - tri[(k + 2) % 3]).norm();
    let (a, b, c) = (side(0), side(1), side(2));
    let perimeter = (a + b + c).max(1e-12);
    let centre = (a * tri[0] + b * tri[1] + c * tri[2]) / perimeter;
    (centre, margin(&centre, tri))
}

/// The smallest shift `d` along the line from `p` to the incentre with `margin(p + d) >=
/// required`, or `None` when even the incentre is not that deep (its inradius). Each edge's
/// distance is affine along the line, so the shift is the largest of the edges' needs.
pub fn shift_into(p: &Vector2<f64>, tri: &[Vector2<f64>; 3], required: f64) -> Option<Vector2<f64>> {
    let (centre, inradius) = incentre(tri);
    if inradius < required {
        return None;
    }
    let area2 = (tri[1] - tri[0]).perp(&(tri[2] - tri[0]));
    let sign = if area2 >= 0.0 { 1.0 } else { -1.0 };
    let mut alpha: f64 = 0.0;
    for k in 0..3 {
        let (a, b) = (tri[k], tri[(k + 1) % 3]);
        let e = b - a;
        let dist = |x: &Vector2<f64>| sign * e.perp(&(x - a)) / e.norm().max(1e-12);
        let (dp, dc) = (dist(p), dist(&centre));
        if dp < required && dc > dp {
            alpha = alpha.max((required - dp) / (dc - dp));
        }
    }
    Some((centre - p) * alpha.min(1.0))
}
