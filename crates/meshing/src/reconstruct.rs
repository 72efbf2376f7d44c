//! Linear reconstruction of per-patch values for display.
//!
//! A patch value is the patch's mean (`B_i`, W/m²). The area-weighted mean of the patches around
//! a point ([`Mesh::corner_radiosity`]) is exact for a linear field only where the patches close
//! around the point: at a face's edge it is the value half an element inwards, and the slope of
//! the light towards a wall's corner flattens into the last element's mean. A renderer that
//! interpolates the corners then shows every concave corner and every element-sized stretch of
//! a face's border too bright or too dark by `h |grad B| / 2`.
//!
//! [`Mesh::seamless_corner_radiosity`] instead averages each patch's *linear extrapolation* to
//! the point, `v_q + g_q . (x - c_q)`, with `g_q` the patch's limited least-squares gradient
//! ([`limited_gradients`]): a field linear over a face comes out exact at every corner, the
//! border included, and a step (a shadow's edge) makes no new extremes inside the surface.

use crate::build::{Mesh, Patch};
use crate::smooth::{Points, point_key, same_surface};
use glam::{DVec3, Vec3};
use rayon::prelude::*;

/// Least-squares gradients closer to singular than this (the smaller eigenvalue of the
/// normal matrix relative to its trace, roughly) are not trusted: the neighbours lie on a line.
const SINGULAR: f64 = 1e-6;

/// A plane that leaves at most this share of the neighbours' squared differences unexplained
/// is a smooth field, extended past the surface's border unlimited.
const SMOOTH_RESIDUAL: f64 = 0.1;

/// A turn short of this share of `2 pi` leaves a point open: a face's border.
const CLOSED_TURN: f64 = 1.0 - 1e-3;

/// Per patch and RGB channel, the gradient of `values` in the patch's plane (value per scene
/// unit), as its two components along the patch's tangent frame ([`Slope`]).
///
/// With `c_p` the patch's centroid and `q` over its neighbours (patches with a corner at one of
/// `p`'s corner points and on `p`'s surface, the same test as [`Mesh::corner_radiosity`]'s),
/// `g` minimises `sum_q w_q (v_q - v_p - g . (c_q - c_p))²` in the patch's plane with
/// `w_q = 1 / |c_q - c_p|²`: exact for a field linear over the neighbours' centroids. It is then
/// scaled by the largest `phi` in `[0, 1]` (per channel) such that at every corner of `p`
/// around which `p`'s surface closes, `v_p + phi g . (x - c_p)` stays within the range of `v`
/// over `p` and its neighbours (Barth and Jespersen's limiter: no overshoot at a shadow's
/// edge). Corners on the surface's border are left out of the limit where the plane explains
/// all but [`SMOOTH_RESIDUAL`] of `sum_q w_q (v_q - v_p)²` (a smooth field: its slope goes on
/// to the face's edge instead of flattening into the last element; noise and steps are limited
/// there too). A patch whose neighbours do not span two directions gets `g = 0`.
///
/// `points` index the mesh's `(point, patch)` incidences, sorted without repeats
/// (`Mesh::incidences`), `min_cosine` is the crease test's.
pub(crate) fn limited_gradients(
    mesh: &Mesh,
    values: &[DVec3],
    points: &Points,
    min_cosine: f64,
) -> Vec<Slope> {
    let patches = mesh.patches();
    // Per incidence: whether the patch's surface closes around the point (its patches' angles
    // there make a full turn); by blocks of whole points in parallel, in place.
    let mut closed = vec![false; points.patches.len()];
    points
        .split(&mut closed)
        .into_par_iter()
        .for_each(|((first, end), out)| {
            let (mut k, mut angles) = (0, Vec::new());
            for number in first..end {
                let (group, point) = (points.at(number), points.point(number));
                angles.clear();
                angles.extend(group.iter().map(|&q| angle_at(mesh, q as usize, point)));
                for &p in group {
                    let own = &patches[p as usize];
                    let turn: f64 = group
                        .iter()
                        .zip(&angles)
                        .filter(|&(&q, _)| {
                            q == p || same_surface(own, &patches[q as usize], min_cosine)
                        })
                        .map(|(_, angle)| angle)
                        .sum();
                    out[k] = turn > std::f64::consts::TAU * CLOSED_TURN;
                    k += 1;
                }
            }
        });
    // Each patch's fit from its neighbours (gathered at its corners' points, in order), in
    // parallel, in place.
    let mut gradients = vec![[[0.0f32; 2]; 3]; patches.len()];
    gradients.par_iter_mut().enumerate().for_each_init(
        || (Vec::<u32>::new(), Vec::new()),
        |(run, around), (p, g)| {
            let own = &patches[p];
            run.clear();
            for &v in mesh.corners(own) {
                let (from, to) = points.range_of_vertex(v).unwrap_or((0, 0));
                run.extend(points.patches[from..to].iter().copied().filter(|&q| {
                    q as usize != p && same_surface(own, &patches[q as usize], min_cosine)
                }));
            }
            run.sort_unstable();
            run.dedup();
            if !run.is_empty()
                && let Some(fitted) = fit(mesh, values, points, &closed, p, (run, around))
            {
                *g = fitted;
            }
        },
    );
    gradients
}

/// A neighbour's term in a patch's fit: its centroid in the patch's plane `(x, y)` (scene
/// units), its weight `1 / (x² + y²)` and its value's difference from the patch's.
type Term = (f64, f64, f64, DVec3);

/// Patch `p`'s limited gradient (see [`limited_gradients`]) from its neighbours `run` (patch
/// indices, ascending), or `None` where the fit is singular; `around` is room for the
/// neighbours' terms (reused from patch to patch).
fn fit(
    mesh: &Mesh,
    values: &[DVec3],
    points: &Points,
    closed: &[bool],
    p: usize,
    (run, around): (&[u32], &mut Vec<Term>),
) -> Option<Slope> {
    let patches = mesh.patches();
    let own = &patches[p];
    let (t1, t2) = tangents(own);
    let centre = own.centroid.as_dvec3();
    let in_plane = |x: DVec3| {
        let d = x - centre;
        (d.dot(t1), d.dot(t2))
    };
    // Per neighbour: its centroid in the patch's plane, its weight and its value's difference.
    around.clear();
    around.extend(run.iter().map(|&q| {
        let (x, y) = in_plane(patches[q as usize].centroid.as_dvec3());
        let w = 1.0 / (x * x + y * y).max(f64::MIN_POSITIVE);
        (x, y, w, values[q as usize] - values[p])
    }));
    // The weighted normal equations [sxx sxy; sxy syy] g = [rx; ry], per channel.
    let (mut sxx, mut sxy, mut syy) = (0.0, 0.0, 0.0);
    let (mut rx, mut ry) = (DVec3::ZERO, DVec3::ZERO);
    let (mut lo, mut hi) = (values[p], values[p]);
    for (&(x, y, w, dv), &q) in around.iter().zip(run) {
        sxx += w * x * x;
        sxy += w * x * y;
        syy += w * y * y;
        rx += w * x * dv;
        ry += w * y * dv;
        lo = lo.min(values[q as usize]);
        hi = hi.max(values[q as usize]);
    }
    let det = sxx * syy - sxy * sxy;
    // NaN (a non-finite value) counts as singular too.
    let trusted = det > SINGULAR * (sxx + syy) * (sxx + syy);
    if !trusted {
        return None;
    }
    let (gx, gy) = ((rx * syy - ry * sxy) / det, (ry * sxx - rx * sxy) / det);
    // How much of the neighbours' differences the plane leaves unexplained, per channel.
    let (mut unexplained, mut total) = (DVec3::ZERO, DVec3::ZERO);
    for &(x, y, w, dv) in around.iter() {
        let miss = dv - (gx * x + gy * y);
        unexplained += w * miss * miss;
        total += w * dv * dv;
    }
    let smooth = unexplained.cmple(total * SMOOTH_RESIDUAL);
    let mut phi = DVec3::ONE;
    for &v in mesh.corners(own) {
        let point = mesh.positions()[v as usize];
        let i = points
            .incidence_of_vertex(v, p as u32)
            .expect("a patch's corner is one of its incidences");
        let (x, y) = in_plane(point.as_dvec3());
        let step = gx * x + gy * y;
        for k in 0..3 {
            if !closed[i] && smooth.test(k) {
                continue;
            }
            let room = if step[k] > 0.0 {
                hi[k] - values[p][k]
            } else {
                lo[k] - values[p][k]
            };
            if step[k] != 0.0 {
                phi[k] = phi[k].min((room / step[k]).clamp(0.0, 1.0));
            }
        }
    }
    Some(std::array::from_fn(|k| {
        [toward_zero(gx[k] * phi[k]), toward_zero(gy[k] * phi[k])]
    }))
}

/// `x` in `f32`, rounded towards zero: a slope stored so never steps further than the limiter
/// let it.
fn toward_zero(x: f64) -> f32 {
    let y = x as f32;
    if f64::from(y).abs() > x.abs() {
        if y > 0.0 { y.next_down() } else { y.next_up() }
    } else {
        y
    }
}

/// The interior angle (radians) of patch `q` at its corner `point` (0 if it has none there).
fn angle_at(mesh: &Mesh, q: usize, point: Vec3) -> f64 {
    let c = mesh.corners(&mesh.patches()[q]);
    let at = |k: usize| mesh.positions()[c[k % c.len()] as usize].as_dvec3();
    let key = point_key(point);
    (0..c.len())
        .find(|&k| point_key(mesh.positions()[c[k] as usize]) == key)
        .map_or(0.0, |k| {
            let v = at(k);
            (at(k + 1) - v).angle_between(at(k + c.len() - 1) - v)
        })
}

/// A patch's gradient per RGB channel in its plane: the components along the two tangents of
/// [`tangents`] (value per scene unit), in `f32` for display (24 bytes a patch; rounded towards
/// zero, so the limiter's bound holds).
pub(crate) type Slope = [[f32; 2]; 3];

/// The tangent frame of `patch`'s plane that its [`Slope`] is given in (from its unit normal).
pub(crate) fn tangents(patch: &Patch) -> (DVec3, DVec3) {
    patch.normal.as_dvec3().any_orthonormal_pair()
}

/// `value + g . d` per channel: a patch's linear extrapolation by `d` from its centroid, `g`
/// its `slope` in the frame `(t1, t2)` of [`tangents`].
pub(crate) fn extrapolate(
    value: DVec3,
    slope: &Slope,
    (t1, t2): (DVec3, DVec3),
    d: DVec3,
) -> DVec3 {
    let (x, y) = (t1.dot(d), t2.dot(d));
    value
        + DVec3::from_array(std::array::from_fn(|k| {
            f64::from(slope[k][0]) * x + f64::from(slope[k][1]) * y
        }))
}

#[cfg(test)]
mod tests {
    use crate::adaptive_tests::scene;
    use crate::{
        AdaptiveBounds, AdaptiveMesh, CornerValues, DEFAULT_CREASE_ANGLE_DEGREES, Mesh, Subdivision,
    };
    use glam::{DVec3, Vec3};
    use mcrad_scene_io::Scene;

    /// A 4 x 4 square (one quad face) and a right triangle over half of it.
    fn square_and_triangle() -> [Scene; 2] {
        let p = vec![
            Vec3::new(0.0, 0.0, 0.0),
            Vec3::new(4.0, 0.0, 0.0),
            Vec3::new(4.0, 4.0, 0.0),
            Vec3::new(0.0, 4.0, 0.0),
        ];
        [
            scene(p.clone(), vec![vec![0, 1, 2, 3]]),
            scene(p, vec![vec![0, 1, 2]]),
        ]
    }

    /// Every corner's value with its position.
    fn at_corners<'a>(
        mesh: &'a Mesh,
        values: &'a CornerValues,
    ) -> impl Iterator<Item = (Vec3, DVec3)> + 'a {
        (0..mesh.patches().len()).flat_map(move |p| {
            let o = mesh.corner_offset(p);
            mesh.corners(&mesh.patches()[p])
                .iter()
                .enumerate()
                .map(move |(k, &v)| (mesh.positions()[v as usize], values[o + k]))
        })
    }

    fn linear(p: DVec3) -> DVec3 {
        DVec3::new(
            20.0 + 2.0 * p.x - 3.0 * p.y,
            5.0 + 0.5 * p.x + p.y,
            4.0 - 0.25 * p.y,
        )
    }

    fn of_centroids(mesh: &Mesh, f: impl Fn(DVec3) -> DVec3) -> Vec<DVec3> {
        mesh.patches()
            .iter()
            .map(|p| f(p.centroid.as_dvec3()))
            .collect()
    }

    #[test]
    fn a_linear_field_is_exact_at_every_corner_border_included() {
        let [square, triangle] = square_and_triangle();
        let mut adaptive = AdaptiveMesh::new(
            &square,
            Subdivision::MaxEdge(1.0),
            AdaptiveBounds {
                min_edge: 0.01,
                max_patches: 1000,
            },
        )
        .unwrap();
        // Refine a corner element and one of its children: T-vertices next to coarser ones.
        adaptive.refine(&[0, 5]);
        adaptive.refine(&[1]);
        let meshes = [
            Mesh::build(&square, Subdivision::MaxEdge(1.0)).unwrap(),
            Mesh::build(&triangle, Subdivision::MaxEdge(0.75)).unwrap(),
            adaptive.mesh().clone(),
        ];
        for (m, mesh) in meshes.iter().enumerate() {
            let values = of_centroids(mesh, linear);
            let display = mesh.seamless_corner_radiosity(&values, DEFAULT_CREASE_ANGLE_DEGREES);
            let mean = mesh.corner_radiosity(&values, DEFAULT_CREASE_ANGLE_DEGREES);
            let mut worst_mean: f64 = 0.0;
            for ((x, got), (_, plain)) in at_corners(mesh, &display).zip(at_corners(mesh, &mean)) {
                let want = linear(x.as_dvec3());
                // exact but for the slopes' `f32` (about 1e-9 of the values here)
                assert!(
                    (got - want).abs().max_element() < 1e-7 * want.abs().max_element(),
                    "mesh {m}, corner at {x}: {got} against {want}"
                );
                worst_mean = worst_mean.max((plain - want).abs().max_element());
            }
            // The area-weighted mean misses the border by half an element's slope: the check
            // above can fail.
            assert!(
                worst_mean > 0.5,
                "mesh {m}: the mean is off by {worst_mean}"
            );
        }
    }

    #[test]
    fn a_step_makes_no_value_beyond_the_patches_range() {
        // A shadow's edge at x = 2 across the grid: 1 on the left, 0.01 on the right.
        let [square, triangle] = square_and_triangle();
        for (s, max_edge) in [(square, 1.0), (triangle, 0.75)] {
            let mesh = Mesh::build(&s, Subdivision::MaxEdge(max_edge)).unwrap();
            let values = of_centroids(&mesh, |c| DVec3::splat(if c.x < 2.0 { 1.0 } else { 0.01 }));
            let display = mesh.seamless_corner_radiosity(&values, DEFAULT_CREASE_ANGLE_DEGREES);
            for (x, v) in at_corners(&mesh, &display) {
                assert!(
                    v.min_element() >= 0.01 - 1e-12 && v.max_element() <= 1.0 + 1e-12,
                    "corner at {x}: {v}"
                );
            }
        }
    }

    #[test]
    fn a_constant_stays_exact_and_a_border_slope_never_goes_below_zero() {
        let [square, _] = square_and_triangle();
        let mesh = Mesh::build(&square, Subdivision::MaxEdge(1.0)).unwrap();
        let c = DVec3::new(0.7, 3.1, 12.9);
        let display = mesh.seamless_corner_radiosity(
            &vec![c; mesh.patches().len()],
            DEFAULT_CREASE_ANGLE_DEGREES,
        );
        assert!(display.iter().all(|v| v == c));
        // Falling steeply to the border x = 4: the slope would reach -1 there.
        let values = of_centroids(&mesh, |p| DVec3::splat((3.0 - p.x).max(0.0) + 0.05));
        let display = mesh.seamless_corner_radiosity(&values, DEFAULT_CREASE_ANGLE_DEGREES);
        assert!(display.iter().all(|v| v.min_element() >= 0.0));
        assert!(display.iter().any(|v| v.min_element() == 0.0));
    }
}
