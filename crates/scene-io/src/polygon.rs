//! Polygon geometry in f64 for validation: vector area, planarity, fan convexity and ear
//! clipping. Positions are f32; their differences are exact in f64.

use glam::{DVec2, DVec3};

/// A face's vertices may be fanned from `apex` only if every fan triangle has at least this
/// fraction of the polygon's area (on the front side): slivers from (nearly) collinear vertices
/// do not count as "convex enough".
const MIN_FAN_FRACTION: f64 = 1e-7;
/// A polygon is planar if no vertex is farther than this times its longest edge from the plane
/// through its centroid with its Newell normal.
const PLANARITY: f64 = 1e-2;
/// Above this many vertices only apex 0 is tried for the fan (trying all is quadratic).
const MAX_APEX_SEARCH: usize = 1024;
/// Corner tests (each linear in the vertices) an ear clipping may make per vertex before it
/// gives up and fans the rest (see [`ear_clip`]).
const EAR_TESTS_PER_VERTEX: usize = 16;

/// Twice the vector area of a polygon: the sum of the fan cross products
/// `(p_i - p_0) x (p_{i+1} - p_0)`. Its direction is the Newell normal (front side), its length
/// twice the area.
pub(crate) fn vector_area2(pts: &[DVec3]) -> DVec3 {
    let Some(&p0) = pts.first() else {
        return DVec3::ZERO;
    };
    pts.windows(2)
        .skip(1)
        .map(|w| (w[0] - p0).cross(w[1] - p0))
        .sum()
}

/// How a polygon is to be stored.
#[derive(Debug, PartialEq)]
pub(crate) enum Shape {
    /// Zero or near-zero area: drop it.
    Degenerate,
    /// Planar and convex enough: keep it whole, rotated so that vertex `apex` comes first (the
    /// fan from the first vertex is then valid).
    Fan {
        /// The vertex to start the list at.
        apex: usize,
    },
    /// Non-planar or non-convex: these triangles (indices into the polygon, counter-clockwise
    /// from the front) replace it. Slivers are already left out; may be empty.
    Split(Vec<[usize; 3]>),
}

/// Decides how to store the polygon `pts` (at least 3 points, no two consecutive equal), given
/// the area at or below which a face counts as degenerate.
pub(crate) fn classify(pts: &[DVec3], degenerate_area: f64) -> Shape {
    let n = pts.len();
    if n < 3 {
        return Shape::Degenerate;
    }
    let normal2 = vector_area2(pts);
    let area = normal2.length() / 2.0;
    if area.is_nan() || area <= degenerate_area {
        return Shape::Degenerate;
    }
    if n == 3 {
        return Shape::Fan { apex: 0 };
    }
    let unit = normal2 / (2.0 * area);
    // Fan triangles must reach this doubled area (cross product length) on the front side.
    let min_cross = 2.0 * degenerate_area.max(MIN_FAN_FRACTION * area);
    if is_planar(pts, unit) {
        if fan_min_cross(pts, 0, unit) > min_cross {
            return Shape::Fan { apex: 0 };
        }
        if n <= MAX_APEX_SEARCH {
            let best = (1..n)
                .map(|k| (k, fan_min_cross(pts, k, unit)))
                .max_by(|a, b| a.1.total_cmp(&b.1));
            if let Some((apex, c)) = best
                && c > min_cross
            {
                return Shape::Fan { apex };
            }
        }
    }
    let flat = project(pts, unit);
    Shape::Split(ear_clip(&flat, min_cross))
}

/// True if every vertex lies within `PLANARITY` times the longest edge of the plane through the
/// centroid with normal `unit`.
fn is_planar(pts: &[DVec3], unit: DVec3) -> bool {
    let n = pts.len() as f64;
    let centroid = pts.iter().copied().sum::<DVec3>() / n;
    let longest = pts
        .iter()
        .zip(pts.iter().cycle().skip(1))
        .map(|(a, b)| a.distance(*b))
        .fold(0.0, f64::max);
    let farthest = pts
        .iter()
        .map(|p| (*p - centroid).dot(unit).abs())
        .fold(0.0, f64::max);
    farthest <= PLANARITY * longest
}

/// The smallest front-side doubled area of the fan triangles `(p_k, p_{k+i}, p_{k+i+1})`.
fn fan_min_cross(pts: &[DVec3], k: usize, unit: DVec3) -> f64 {
    let n = pts.len();
    let apex = pts[k];
    (1..n - 1)
        .map(|i| {
            let a = pts[(k + i) % n] - apex;
            let b = pts[(k + i + 1) % n] - apex;
            a.cross(b).dot(unit)
        })
        .fold(f64::INFINITY, f64::min)
}

/// Projects onto the plane with normal `unit`, in a basis that keeps counter-clockwise (seen
/// from the front) counter-clockwise, centred on the first point for precision.
fn project(pts: &[DVec3], unit: DVec3) -> Vec<DVec2> {
    let e1 = unit.any_orthonormal_vector();
    let e2 = unit.cross(e1);
    let origin = pts[0];
    pts.iter()
        .map(|p| {
            let d = *p - origin;
            DVec2::new(d.dot(e1), d.dot(e2))
        })
        .collect()
}

fn cross2(a: DVec2, b: DVec2) -> f64 {
    a.perp_dot(b)
}

/// True if `p` is inside or on the counter-clockwise triangle `a, b, c`.
fn in_triangle(p: DVec2, a: DVec2, b: DVec2, c: DVec2) -> bool {
    cross2(b - a, p - a) >= 0.0 && cross2(c - b, p - b) >= 0.0 && cross2(a - c, p - c) >= 0.0
}

/// Ear clipping of a counter-clockwise polygon. An ear is a vertex whose triangle with its
/// neighbours has doubled area above `min_cross` and holds no reflex (not strictly convex)
/// vertex, on its boundary included. The search resumes next to the last ear, so a polygon with
/// few reflex vertices takes about quadratic time. When a whole round finds no ear, a (nearly)
/// collinear vertex is removed (its triangle has negligible area); when there is none either (a
/// self-intersecting outline), the rest is fanned from its first vertex, keeping only the
/// front-facing triangles. The same fallback ends a search that has tested
/// [`EAR_TESTS_PER_VERTEX`] corners per vertex without finishing (outlines that touch
/// themselves everywhere, such as `f 1 2 3 1 2 3 ...`), so the time stays quadratic in the
/// vertices, never cubic.
fn ear_clip(pts: &[DVec2], min_cross: f64) -> Vec<[usize; 3]> {
    let mut tests_left = EAR_TESTS_PER_VERTEX * pts.len();
    let mut ring: Vec<usize> = (0..pts.len()).collect();
    let mut tris = Vec::with_capacity(pts.len().saturating_sub(2));
    // The corner at ring position `j`: its vertex, its neighbours and its doubled area.
    let corner = |ring: &[usize], j: usize| {
        let m = ring.len();
        let (a, b, c) = (ring[(j + m - 1) % m], ring[j], ring[(j + 1) % m]);
        (a, b, c, cross2(pts[b] - pts[a], pts[c] - pts[a]))
    };
    let is_ear = |ring: &[usize], j: usize| {
        let (a, b, c, cross) = corner(ring, j);
        let (pa, pb, pc) = (pts[a], pts[b], pts[c]);
        cross > min_cross
            && !(0..ring.len()).any(|k| {
                let o = ring[k];
                let p = pts[o];
                o != a
                    && o != b
                    && o != c
                    && p != pa
                    && p != pb
                    && p != pc
                    && corner(ring, k).3 <= min_cross
                    && in_triangle(p, pa, pb, pc)
            })
    };
    let mut j = 0;
    let mut misses = 0;
    while ring.len() > 3 {
        let m = ring.len();
        j %= m;
        if tests_left == 0 {
            misses = m;
        } else {
            tests_left -= 1;
        }
        if misses < m && is_ear(&ring, j) {
            let (a, b, c, _) = corner(&ring, j);
            tris.push([a, b, c]);
            ring.remove(j);
            // Resume at the previous vertex, whose corner just changed.
            j = if j == 0 { m - 2 } else { j - 1 };
            misses = 0;
            continue;
        }
        j += 1;
        misses += 1;
        if misses < m {
            continue;
        }
        misses = 0;
        if let Some(k) = (0..m).find(|&k| corner(&ring, k).3.abs() <= min_cross) {
            ring.remove(k);
            continue;
        }
        for k in 1..m - 1 {
            let (a, b, c) = (ring[0], ring[k], ring[k + 1]);
            if cross2(pts[b] - pts[a], pts[c] - pts[a]) > min_cross {
                tris.push([a, b, c]);
            }
        }
        return tris;
    }
    if ring.len() == 3 && corner(&ring, 1).3 > min_cross {
        tris.push([ring[0], ring[1], ring[2]]);
    }
    tris
}

#[cfg(test)]
mod tests {
    use super::*;

    fn pts(v: &[[f64; 3]]) -> Vec<DVec3> {
        v.iter().map(|p| DVec3::from_array(*p)).collect()
    }

    fn area_of(p: &[DVec3], tris: &[[usize; 3]]) -> f64 {
        tris.iter()
            .map(|t| vector_area2(&[p[t[0]], p[t[1]], p[t[2]]]).z / 2.0)
            .sum()
    }

    #[test]
    fn square_is_kept_whole() {
        let p = pts(&[[0., 0., 0.], [1., 0., 0.], [1., 1., 0.], [0., 1., 0.]]);
        assert_eq!(classify(&p, 1e-12), Shape::Fan { apex: 0 });
        assert_eq!(vector_area2(&p), DVec3::new(0., 0., 2.));
    }

    #[test]
    fn collinear_vertex_rotates_the_fan_instead_of_splitting() {
        // A T-junction vertex on the bottom edge: fanning from vertex 0 gives a zero-area triangle.
        let p = pts(&[
            [0., 0., 0.],
            [1., 0., 0.],
            [2., 0., 0.],
            [2., 1., 0.],
            [0., 1., 0.],
        ]);
        let Shape::Fan { apex } = classify(&p, 1e-12) else {
            panic!("expected a fan")
        };
        assert_ne!(apex, 0);
        assert!(fan_min_cross(&p, apex, DVec3::Z) > 0.0);
    }

    #[test]
    fn concave_faces_are_fanned_when_star_shaped_else_ear_clipped() {
        // An L is star-shaped: fanned from a suitable corner it stays whole (rotated).
        let p = pts(&[
            [2., 0., 0.],
            [2., 1., 0.],
            [1., 1., 0.],
            [1., 2., 0.],
            [0., 2., 0.],
            [0., 0., 0.],
        ]);
        assert!(fan_min_cross(&p, 0, DVec3::Z) < 0.0);
        let Shape::Fan { apex } = classify(&p, 1e-12) else {
            panic!("expected a fan")
        };
        assert!(fan_min_cross(&p, apex, DVec3::Z) > 0.0);
        // A star-like outline (two reflex vertices facing each other) is not.
        let p = pts(&[
            [0., 0., 0.],
            [3., 0., 0.],
            [3., 3., 0.],
            [2., 1., 0.],
            [1., 1., 0.],
            [0., 3., 0.],
        ]);
        let Shape::Split(tris) = classify(&p, 1e-12) else {
            panic!("expected a split")
        };
        assert_eq!(tris.len(), 4);
        assert!((area_of(&p, &tris) - 5.0).abs() < 1e-12);
    }

    #[test]
    fn non_planar_quad_is_split_in_two() {
        let p = pts(&[[0., 0., 0.], [1., 0., 0.], [1., 1., 0.5], [0., 1., 0.]]);
        let Shape::Split(tris) = classify(&p, 1e-12) else {
            panic!("expected a split")
        };
        assert_eq!(tris.len(), 2);
    }

    #[test]
    fn zero_and_tiny_area_are_degenerate() {
        let line = pts(&[[0., 0., 0.], [1., 0., 0.], [2., 0., 0.]]);
        assert_eq!(classify(&line, 0.0), Shape::Degenerate);
        let tiny = pts(&[[0., 0., 0.], [1e-7, 0., 0.], [0., 1e-7, 0.]]);
        assert_eq!(classify(&tiny, 1e-12), Shape::Degenerate);
        assert_eq!(classify(&tiny, 0.0), Shape::Fan { apex: 0 });
    }

    #[test]
    fn large_comb_is_split_quickly_with_its_area() {
        // A comb of 500 teeth: 2000 vertices, 500 reflex.
        let teeth = 500;
        let mut p = vec![DVec3::new(teeth as f64, -1.0, 0.0)];
        for t in (0..teeth).rev() {
            let x = t as f64;
            p.extend([
                DVec3::new(x + 1.0, 0.0, 0.0),
                DVec3::new(x + 1.0, 1.0, 0.0),
                DVec3::new(x + 0.5, 1.0, 0.0),
                DVec3::new(x + 0.5, 0.0, 0.0),
            ]);
        }
        p.push(DVec3::new(0.0, -1.0, 0.0));
        let Shape::Split(tris) = classify(&p, 1e-12) else {
            panic!("expected a split")
        };
        let expected = vector_area2(&p).z / 2.0;
        let got = area_of(&p, &tris);
        assert!((got - expected).abs() < 1e-6, "{got} vs {expected}");
        assert_eq!(tris.len(), p.len() - 2);
        assert!(
            tris.iter()
                .all(|t| vector_area2(&[p[t[0]], p[t[1]], p[t[2]]]).z > 0.0)
        );
    }

    #[test]
    fn self_intersecting_outline_does_not_panic() {
        let bowtie = pts(&[
            [0., 0., 0.],
            [1., 1., 0.],
            [1., 0., 0.],
            [0., 1., 0.],
            [0.5, 2., 0.],
        ]);
        let _ = classify(&bowtie, 1e-12);
    }
}
