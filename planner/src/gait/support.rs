//! The support triangle of a crawl (the three feet on the ground while one swings): where the
//! ground pushes a standing robot that also carries a load in its hand ([`centre_of_pressure`]),
//! how far a point lies inside the triangle ([`margin`]), what share of the weight each foot
//! carries ([`shares`]), how far along a line it must move to be a given margin inside with
//! every foot carrying a given share ([`along`]), and the shortest shift that gets it there
//! ([`least_shift`]).

use nalgebra::{Isometry3, Vector2, Vector3};
use protocol::conventions::GRAVITY;

/// The wrench the object applies to a robot's hand (world-aligned, on the robot), where it
/// applies: with its weight, what the robot's feet must carry.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct HandLoad {
    /// Point of application (the hand frame's origin), world, m.
    pub point: Vector3<f64>,
    /// Force and moment about `point`, N and N m.
    pub force: Vector3<f64>,
    pub moment: Vector3<f64>,
}

impl HandLoad {
    /// The same load carried along by a rigid motion of the object (the grasp moves with it).
    pub fn moved(&self, by: &Isometry3<f64>) -> HandLoad {
        HandLoad {
            point: (by * nalgebra::Point3::from(self.point)).coords,
            force: by.rotation * self.force,
            moment: by.rotation * self.moment,
        }
    }

    pub fn is_finite(&self) -> bool {
        self.point.iter().chain(self.force.iter()).chain(self.moment.iter()).all(|x| x.is_finite())
    }
}

/// Where the ground's resultant acts on a robot standing still on flat ground at height
/// `ground_z`: its weight `mass` g at `com` and the hand's load balanced by the feet (statics:
/// the ground's force `F = m g e_z - f`, its moment about the origin `-(p x f + n + c x (-m g
/// e_z))`, and the point of the ground plane about which that moment has no horizontal part).
/// Also how far that point moves per metre the centre of mass moves horizontally (`m g / F_z`:
/// a hand pressed down moves it less than the CoM). `None` when the feet carry no weight
/// (`F_z <= 0`: the hand lifts the robot).
pub fn centre_of_pressure(
    mass: f64,
    com: &Vector3<f64>,
    load: Option<&HandLoad>,
    ground_z: f64,
) -> Option<(Vector2<f64>, f64)> {
    let weight = Vector3::new(0.0, 0.0, -mass * GRAVITY);
    let (mut force, mut moment) = (-weight, -com.cross(&weight));
    if let Some(h) = load {
        force -= h.force;
        moment -= h.point.cross(&h.force) + h.moment;
    }
    if force.z.is_nan() || force.z <= 0.0 {
        return None;
    }
    let x = (ground_z * force.x - moment.y) / force.z;
    let y = (moment.x + ground_z * force.y) / force.z;
    Some((Vector2::new(x, y), mass * GRAVITY / force.z))
}

/// Each edge `k` of `tri` (from vertex `k` to `k + 1`) as the signed distance of a point
/// inside it, an affine map `d(p) = n . (p - a)` with `n` the edge's inward unit normal: `(a,
/// n)` for each edge, whatever the vertices' order.
fn edges(tri: &[Vector2<f64>; 3]) -> [(Vector2<f64>, Vector2<f64>); 3] {
    let area2 = (tri[1] - tri[0]).perp(&(tri[2] - tri[0]));
    let sign = if area2 >= 0.0 { 1.0 } else { -1.0 };
    std::array::from_fn(|k| {
        let (a, b) = (tri[k], tri[(k + 1) % 3]);
        let e = b - a;
        // e.perp(q) = e.x q.y - e.y q.x = n . q with n = (-e.y, e.x).
        (a, sign * Vector2::new(-e.y, e.x) / e.norm().max(1e-12))
    })
}

/// Signed distance of `p` inside the triangle `tri` (positive inside: the distance to the
/// nearest edge; negative outside), whatever the vertices' order.
pub fn margin(p: &Vector2<f64>, tri: &[Vector2<f64>; 3]) -> f64 {
    edges(tri).iter().map(|(a, n)| n.dot(&(p - a))).fold(f64::INFINITY, f64::min)
}

/// The triangle's incentre and inradius (the point deepest inside and its margin).
pub fn incentre(tri: &[Vector2<f64>; 3]) -> (Vector2<f64>, f64) {
    let side = |k: usize| (tri[(k + 1) % 3] - tri[(k + 2) % 3]).norm();
    let (a, b, c) = (side(0), side(1), side(2));
    let perimeter = (a + b + c).max(1e-12);
    let centre = (a * tri[0] + b * tri[1] + c * tri[2]) / perimeter;
    (centre, margin(&centre, tri))
}

/// Each edge's height: the distance of the opposite vertex from it (edge `k` runs from vertex
/// `k` to `k + 1`, so the opposite vertex is `k + 2`).
fn heights(tri: &[Vector2<f64>; 3]) -> [f64; 3] {
    let e = edges(tri);
    std::array::from_fn(|k| e[k].1.dot(&(tri[(k + 2) % 3] - e[k].0)))
}

/// The share of a vertical load at `p` that each vertex of `tri` carries (three feet carry it
/// statically determinately): `p`'s barycentric coordinates, vertex `k`'s being the distance of
/// `p` from the opposite edge over the vertex's own distance from it. Negative outside.
pub fn shares(p: &Vector2<f64>, tri: &[Vector2<f64>; 3]) -> [f64; 3] {
    let (e, h) = (edges(tri), heights(tri));
    std::array::from_fn(|v| {
        let k = (v + 1) % 3;
        e[k].1.dot(&(p - e[k].0)) / h[k].max(1e-12)
    })
}

/// The conditions of [`along`] and [`least_shift`], edge by edge: a point `q` meets them when
/// `n . (q - a) >= r` for each edge's point `a` and inward normal `n`, with `r` the larger of
/// `required` and `min_share` of the edge's height (a share is an edge's distance over it).
fn conditions(
    tri: &[Vector2<f64>; 3],
    required: f64,
    min_share: f64,
) -> [(Vector2<f64>, Vector2<f64>, f64); 3] {
    let (e, h) = (edges(tri), heights(tri));
    std::array::from_fn(|k| (e[k].0, e[k].1, required.max(min_share * h[k])))
}

/// The least `alpha >= 0` with `p + alpha dir` at least `required` inside `tri` and leaving
/// every vertex at least `min_share` of the load ([`shares`]; `0`: no share asked), and the
/// largest for which that still holds (`None` when no `alpha` does): each edge's distance is
/// affine in `alpha`, and a share is an edge's distance over its height.
pub fn along(
    p: &Vector2<f64>,
    dir: &Vector2<f64>,
    tri: &[Vector2<f64>; 3],
    required: f64,
    min_share: f64,
) -> Option<(f64, f64)> {
    let (mut lo, mut hi): (f64, f64) = (0.0, f64::INFINITY);
    for (a, n, required) in conditions(tri, required, min_share) {
        let (d0, rate) = (n.dot(&(p - a)), n.dot(dir));
        if rate.abs() < 1e-15 {
            if d0 < required {
                return None;
            }
        } else if rate > 0.0 {
            lo = lo.max((required - d0) / rate);
        } else {
            hi = hi.min((required - d0) / rate);
        }
    }
    (lo <= hi).then_some((lo, hi))
}

/// The shortest horizontal shift `d` of a robot's torso that puts each of `points` (`p`, and
/// how far it moves per metre of shift) `required` inside `tri` with every vertex carrying at
/// least `min_share` ([`along`]'s conditions): the least-norm point of the intersection of
/// half-planes `n_k . (p + gain d - a_k) >= r_k`. In the plane that point is `0`, the
/// projection onto one boundary line, or the corner of two; the shortest feasible candidate
/// is it. `None` when no shift satisfies them all.
pub fn least_shift(
    points: &[(Vector2<f64>, f64)],
    tri: &[Vector2<f64>; 3],
    required: f64,
    min_share: f64,
) -> Option<Vector2<f64>> {
    // Each condition as `w . d >= b`.
    let mut rows: Vec<(Vector2<f64>, f64)> = Vec::with_capacity(3 * points.len());
    let edges = conditions(tri, required, min_share);
    for &(p, gain) in points {
        for (a, n, r) in edges {
            rows.push((gain * n, r - n.dot(&(p - a))));
        }
    }
    let feasible = |d: &Vector2<f64>| rows.iter().all(|(w, b)| w.dot(d) >= b - 1e-12);
    let mut candidates = vec![Vector2::zeros()];
    for (w, b) in &rows {
        let w2 = w.norm_squared();
        if w2 > 1e-24 {
            candidates.push(w * (b / w2));
        }
    }
    for (i, (wi, bi)) in rows.iter().enumerate() {
        for (wj, bj) in &rows[i + 1..] {
            let det = wi.perp(wj);
            if det.abs() > 1e-12 * wi.norm() * wj.norm() {
                // Solve [wi^T; wj^T] d = [bi; bj] by Cramer's rule.
                candidates.push(Vector2::new(bi * wj.y - bj * wi.y, wi.x * bj - wj.x * bi) / det);
            }
        }
    }
    candidates
        .into_iter()
        .filter(feasible)
        .min_by(|a, b| a.norm_squared().total_cmp(&b.norm_squared()))
}
