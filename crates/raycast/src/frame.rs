//! The canonical frame: input validation, the world <-> canonical map, and the surface offsets.
//!
//! Shared by [`Bvh`](crate::Bvh) (which works in canonical `f32`) and
//! [`BruteForce`](crate::BruteForce) (which works in world `f64` but must offset ray origins
//! by the same amounts to be a fair oracle).

use glam::{DVec3, Vec3, Vec3A};

use crate::{BuildError, CANONICAL_EPSILON, NO_ID, Ray, SurfacePoint};

/// Origins farther than this (canonical units, or four windows) outside the scene's box are
/// moved to it before casting (see [`Frame::approach`]).
const APPROACH_MARGIN: f64 = 8.0;

/// Origins (rounded to `f32`) within this of the scene's box need no approach (see
/// [`Frame::approach`]): half of [`APPROACH_MARGIN`], so that the unrounded origin (within
/// `2^-13` of the rounded one: canonical coordinates there are below 2048) is inside the
/// approach box too.
const INNER_MARGIN: f64 = 0.5 * APPROACH_MARGIN;

/// A direction or normal whose squared length is within this of 1 is used as it is. `f32`
/// normalisation itself only gets the squared length to within about 3 such ulps
/// (`f32::EPSILON`) of 1, so renormalising would not make it any more unit; it would only cost a
/// square root and a division at the start of every query.
const UNIT_TOLERANCE: f32 = 4.0 * f32::EPSILON;

/// The largest origin lift (canonical units) a scene may need, `2^20`: box areas padded by it
/// stay far below `f32::MAX` (see [`Frame::check_lift`]).
const MAX_LIFT: f64 = (1u64 << 20) as f64;

/// Lower end of the canonical extent: the largest bounding-box side lies in `[512, 1024)`.
const CANONICAL_EXTENT_MIN: f64 = 512.0;

/// Origin lift per canonical unit of world-coordinate magnitude: `2^-21`, i.e. 4 ulps of an `f32`
/// coordinate (an `f32` ulp is at most `2^-23` of the value). A point given in world `f32` is only
/// known to about half an ulp of its largest coordinate; far from the world origin that
/// uncertainty, not `CANONICAL_EPSILON`, decides whether the origin sits above its surface.
const LIFT_PER_MAGNITUDE: f64 = 1.0 / (1u64 << 21) as f64;

/// Checks the input of a build and returns the bounds (min, max) of all vertices.
pub(crate) fn validate(triangles: &[[Vec3; 3]], ids: &[u32]) -> Result<(Vec3, Vec3), BuildError> {
    validate_with(triangles.len(), |i| triangles[i], ids)
}

/// [`validate`] of the `count` triangles that `triangle(i)` gives.
pub(crate) fn validate_with(
    count: usize,
    triangle: impl Fn(usize) -> [Vec3; 3],
    ids: &[u32],
) -> Result<(Vec3, Vec3), BuildError> {
    if count != ids.len() {
        return Err(BuildError::LengthMismatch {
            triangles: count,
            ids: ids.len(),
        });
    }
    if count == 0 {
        return Err(BuildError::Empty);
    }
    let mut min = Vec3::INFINITY;
    let mut max = Vec3::NEG_INFINITY;
    for (triangle, (tri, &id)) in (0..count).map(&triangle).zip(ids).enumerate() {
        for (vertex, &value) in tri.iter().enumerate() {
            if !value.is_finite() {
                return Err(BuildError::NonFiniteVertex {
                    triangle,
                    vertex,
                    value,
                });
            }
            min = min.min(value);
            max = max.max(value);
        }
        if id == NO_ID {
            return Err(BuildError::ReservedId { triangle });
        }
    }
    Ok((min, max))
}

/// A ray prepared for the canonical frame: lifted origin, unit direction, and the window
/// around the origin in which only front-facing crossings count (see [`crate::exact::ray_rule`]).
/// An origin far outside the scene is first moved along the ray to near the scene's box;
/// `skip` is the distance it moved (canonical units, added to hit distances).
#[derive(Clone, Copy, Debug)]
pub(crate) struct CanonicalRay {
    pub origin: Vec3A,
    pub dir: Vec3A,
    pub window: f32,
    pub skip: f64,
}

/// A visibility segment in the canonical frame, with the windows at its two ends
/// (see [`crate::exact::segment_rule`]).
#[derive(Clone, Copy, Debug)]
pub(crate) struct CanonicalSegment {
    pub origin: Vec3A,
    pub dir: Vec3A,
    pub len: f32,
    pub window_start: f32,
    pub window_end: f32,
}

/// A ray or segment prepared for world-space `f64` intersection (the brute-force oracle);
/// `len` is infinite for a ray.
#[derive(Clone, Copy, Debug)]
pub(crate) struct WorldRay {
    pub origin: DVec3,
    pub dir: DVec3,
    pub len: f64,
    pub window_start: f64,
    pub window_end: f64,
}

/// The map `canonical = (world - center) * scale`, `scale` a power of two and `center` an `f32`
/// point (the box's centre rounded to `f32`).
///
/// Because both are exact in `f32`, the `f32` formula `(p - center) * scale` (one correctly
/// rounded subtraction, an exact scaling) gives the same canonical point as the `f64` one with
/// one rounding, which lets the hot path of [`Frame::canonical_ray`] stay in `f32`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) struct Frame {
    center: DVec3,
    scale: f64,
    inv_scale: f64,
    /// Half the sides of a box centred on the canonical origin that holds the scene
    /// (canonical units).
    half_extent: DVec3,
    /// `half_extent + INNER_MARGIN` in `f32`: origins within it need no approach.
    inner: Vec3A,
    /// `center` in `f32` (exact).
    center32: Vec3A,
    /// `scale` in `f32` (exact), or 0 when it is not a normal `f32` (scenes smaller than about
    /// `2^-117` units): the `f32` path is then never taken.
    scale32: f32,
    /// Points with `max|p_i|` at most this have `lift(p) == CANONICAL_EPSILON` (`-1` when
    /// `scale32` is 0).
    eps_magnitude: f32,
}

impl Frame {
    /// The frame of a scene with these (finite) bounds.
    pub(crate) fn new(min: Vec3, max: Vec3) -> Frame {
        // the centre rounded to the nearest f32, which lies between `min` and `max` on each axis
        // (they are f32 too), so the box around it still holds the scene within one extent
        let center = ((min.as_dvec3() + max.as_dvec3()) * 0.5)
            .as_vec3()
            .as_dvec3();
        let (min, max) = (min.as_dvec3(), max.as_dvec3());
        let extent = (max - min).max_element();
        let mut exp: i32 = 0;
        if extent > 0.0 {
            // f64 holds every finite f32 extent and its power-of-two rescaling exactly, so the
            // loops below are exact; log2 only gives the starting guess.
            exp = 9 - extent.log2().floor() as i32;
            while extent * pow2(exp) >= 2.0 * CANONICAL_EXTENT_MIN {
                exp -= 1;
            }
            while extent * pow2(exp) < CANONICAL_EXTENT_MIN {
                exp += 1;
            }
        }
        let scale = pow2(exp);
        let half_extent = (max - center).max(center - min) * scale;
        let scale32 = if (f32::MIN_POSITIVE as f64..=f32::MAX as f64).contains(&scale) {
            scale as f32
        } else {
            0.0
        };
        // lift(p) == CANONICAL_EPSILON  <=>  max|p_i| * scale <= 2^-10 / 2^-21 = 2^11
        let eps_magnitude = pow2(11 - exp);
        let mut eps_magnitude32 = eps_magnitude as f32;
        if eps_magnitude32 as f64 > eps_magnitude {
            eps_magnitude32 = eps_magnitude32.next_down();
        }
        if scale32 == 0.0 {
            // no f32 path: no point qualifies
            eps_magnitude32 = -1.0;
        }
        Frame {
            center,
            scale,
            inv_scale: pow2(-exp),
            half_extent,
            inner: (half_extent + INNER_MARGIN).as_vec3().into(),
            center32: center.as_vec3().into(),
            scale32,
            eps_magnitude: eps_magnitude32,
        }
    }

    /// Canonical units per scene unit (a power of two).
    pub(crate) fn scale(&self) -> f64 {
        self.scale
    }

    /// Scene units per canonical unit.
    pub(crate) fn inv_scale(&self) -> f64 {
        self.inv_scale
    }

    /// World point -> canonical `f32` point (one rounding).
    pub(crate) fn canonical(&self, p: Vec3) -> Vec3 {
        ((p.as_dvec3() - self.center) * self.scale).as_vec3()
    }

    /// Canonical point -> world point.
    pub(crate) fn world(&self, p: DVec3) -> Vec3 {
        (self.center + p * self.inv_scale).as_vec3()
    }

    /// How far (canonical units) a ray origin at world point `p` is lifted off its surface, and
    /// the half-width of the window around it: `max(CANONICAL_EPSILON, 2^-21 * max|p_i| * s)`.
    fn lift(&self, p: Vec3) -> f64 {
        let magnitude = p.abs().max_element() as f64 * self.scale;
        (magnitude * LIFT_PER_MAGNITUDE).max(CANONICAL_EPSILON as f64)
    }

    /// The largest [`Frame::lift`] of a point within these bounds.
    pub(crate) fn max_lift(&self, min: Vec3, max: Vec3) -> f64 {
        self.lift(min.abs().max(max.abs()))
    }

    /// Refuses a scene whose largest [`Frame::lift`] exceeds [`MAX_LIFT`] (a scene farther
    /// from the origin than about `2^31` to `2^32` times its size): its boxes, padded by the
    /// lift, would overflow `f32` surface areas and distances. (Long before that, from about
    /// `2^21` times its size, origins are lifted by more than the scene's size: the solver
    /// refuses such scenes by the spacing of `f32` at their smallest patch.)
    pub(crate) fn check_lift(&self, min: Vec3, max: Vec3) -> Result<(), BuildError> {
        if self.max_lift(min, max) <= MAX_LIFT {
            return Ok(());
        }
        let magnitude = min.abs().max(max.abs()).max_element();
        Err(BuildError::FarFromOrigin {
            magnitude,
            extent: (max.as_dvec3() - min.as_dvec3()).max_element() as f32,
            spacing: magnitude.next_up() - magnitude,
        })
    }

    /// The lifted origin (canonical, `f64`) of a point leaving along `normal` (unit or zero),
    /// `lift` being [`Frame::lift`] of `p`: the canonical point (rounded to `f32` like a
    /// vertex) plus the lift. Rounded to `f32`, that is the `f32` sum the fast path of
    /// [`Frame::canonical_ray`] computes: the `f64` sum is exact unless a normal component is
    /// below `2^-9`, and even then the two differ only at a double-rounding tie.
    #[inline(always)]
    fn lifted(&self, p: Vec3, normal: Vec3, lift: f64) -> DVec3 {
        let c = self.canonical(p).as_dvec3();
        if normal == Vec3::ZERO {
            c
        } else {
            c + normal.as_dvec3() * lift
        }
    }

    /// Whether an origin (canonical `f32`) is close enough to the scene's box that
    /// [`Frame::approach`] would not move it (and is finite).
    #[inline(always)]
    fn needs_no_approach(&self, origin: Vec3A) -> bool {
        origin.abs().cmple(self.inner).all()
    }

    /// `None` for rays that cannot hit anything: zero or non-finite direction or origin, or an
    /// origin outside the scene's box on a line that misses it.
    ///
    /// The common case (unit direction, unit or zero normal, origin in the scene's box: every
    /// surface ray) is inlined; the rest is [`Frame::canonical_ray_general`], which gives the
    /// same result for the common case too.
    #[inline(always)]
    pub(crate) fn canonical_ray(&self, ray: &Ray) -> Option<CanonicalRay> {
        if is_unit(ray.dir.length_squared())
            && let Some(normal) = self.epsilon_lift_normal(ray.origin, ray.origin_normal)
        {
            // `Frame::lifted` in f32: the canonical point is exact in f32 (see `Frame`) and so
            // is the lift `normal * 2^-10`, so the one rounding of their sum is the only one
            let origin = self.canonical32(ray.origin) + normal * CANONICAL_EPSILON;
            if self.needs_no_approach(origin) {
                return Some(CanonicalRay {
                    origin,
                    dir: positive_zeros(ray.dir).into(),
                    window: CANONICAL_EPSILON,
                    skip: 0.0,
                });
            }
        }
        self.canonical_ray_general(ray)
    }

    /// The canonical point of `p` by the `f32` formula: the same as [`Frame::canonical`] when
    /// `scale32` is not 0 and the result is finite.
    #[inline(always)]
    fn canonical32(&self, p: Vec3) -> Vec3A {
        (Vec3A::from(p) - self.center32) * self.scale32
    }

    /// For a point whose lift is `CANONICAL_EPSILON` (and `scale32 != 0`) and a normal that
    /// [`is_unit`] or has squared length 0: the normal [`unit_or_zero`] makes of it.
    #[inline(always)]
    fn epsilon_lift_normal(&self, p: Vec3, normal: Vec3) -> Option<Vec3A> {
        let n2 = normal.length_squared();
        // (a NaN coordinate may slip through `max_element`; it makes the result non-finite)
        if p.abs().max_element() > self.eps_magnitude {
            None
        } else if is_unit(n2) {
            Some(normal.into())
        } else if n2 == 0.0 {
            // what `normalize_or_zero` makes of it
            Some(Vec3A::ZERO)
        } else {
            None
        }
    }

    /// [`Frame::canonical_ray`] for any ray.
    #[cold]
    #[inline(never)]
    fn canonical_ray_general(&self, ray: &Ray) -> Option<CanonicalRay> {
        let dir = positive_zeros(unit_or_zero(ray.dir));
        if dir == Vec3::ZERO || !ray.origin.is_finite() {
            return None;
        }
        let normal = unit_or_zero(ray.origin_normal);
        let window = self.lift(ray.origin);
        let origin = self.lifted(ray.origin, normal, window);
        let skip = self.approach(origin, dir.as_dvec3(), window)?;
        let (origin, window) = if skip > 0.0 {
            ((origin + dir.as_dvec3() * skip).as_vec3(), 0.0)
        } else {
            (origin.as_vec3(), window as f32)
        };
        if !origin.is_finite() {
            return None;
        }
        Some(CanonicalRay {
            origin: origin.into(),
            dir: dir.into(),
            window,
            skip,
        })
    }

    /// How far to move an origin along `dir` before casting: `0` near the scene's box,
    /// otherwise to a few windows before the box (which no surface is then within a window of),
    /// `None` if the line misses the box. obvhs treats a zero direction component as
    /// `±f32::EPSILON`, so a ray drifts off its line by `1.2e-7 * t`: a camera far away must not
    /// start its traversal there.
    #[inline(never)]
    fn approach(&self, origin: DVec3, dir: DVec3, window: f64) -> Option<f64> {
        let margin = APPROACH_MARGIN.max(4.0 * window);
        let half = self.half_extent + margin;
        if origin.abs().cmple(half).all() {
            return Some(0.0);
        }
        let inv = dir.recip();
        let (a, b) = ((-half - origin) * inv, (half - origin) * inv);
        // a zero component gives inf or NaN; NaN (origin on a slab face) is ignored by max/min
        let enter = a.min(b).max_element();
        let exit = a.max(b).min_element();
        (enter <= exit && exit >= 0.0 && enter.is_finite()).then_some(enter.max(0.0))
    }

    /// `None` when there is nothing to block: non-finite end points, end points closer than
    /// their two windows, or a segment that stays outside the scene's box.
    ///
    /// Inlined for the common case (unit or zero normals, lifts of `CANONICAL_EPSILON`: the
    /// canonical points come from the `f32` formula, which is exact); the rest is
    /// [`Frame::canonical_segment_general`], which gives the same result for the common case.
    #[inline(always)]
    pub(crate) fn canonical_segment(
        &self,
        a: &SurfacePoint,
        b: &SurfacePoint,
    ) -> Option<CanonicalSegment> {
        if let (Some(na), Some(nb)) = (
            self.epsilon_lift_normal(a.point, a.normal),
            self.epsilon_lift_normal(b.point, b.normal),
        ) {
            let (ca, cb) = (self.canonical32(a.point), self.canonical32(b.point));
            // (non-finite: a non-finite point, or an overflow of the f32 formula for a point far
            // outside a huge scene, which the f64 one handles)
            if ca.is_finite() && cb.is_finite() {
                // `Frame::lifted`
                let eps = CANONICAL_EPSILON as f64;
                let pa = ca.as_dvec3() + na.as_dvec3() * eps;
                let pb = cb.as_dvec3() + nb.as_dvec3() * eps;
                return self.segment_between(pa, pb, eps, eps);
            }
        }
        self.canonical_segment_general(a, b)
    }

    /// [`Frame::canonical_segment`] for any end points.
    #[cold]
    #[inline(never)]
    fn canonical_segment_general(
        &self,
        a: &SurfacePoint,
        b: &SurfacePoint,
    ) -> Option<CanonicalSegment> {
        if !(a.point.is_finite() && b.point.is_finite()) {
            return None;
        }
        let (window_start, window_end) = (self.lift(a.point), self.lift(b.point));
        let pa = self.lifted(a.point, unit_or_zero(a.normal), window_start);
        let pb = self.lifted(b.point, unit_or_zero(b.normal), window_end);
        self.segment_between(pa, pb, window_start, window_end)
    }

    /// The segment between two lifted end points (canonical `f64`) with these windows.
    #[inline(always)]
    fn segment_between(
        &self,
        pa: DVec3,
        pb: DVec3,
        window_start: f64,
        window_end: f64,
    ) -> Option<CanonicalSegment> {
        let delta = pb - pa;
        let len = delta.length();
        if !(len > window_start + window_end && len.is_finite()) {
            return None;
        }
        let dir = positive_zeros((delta / len).as_vec3());
        let near = Vec3A::from(pa.as_vec3());
        if self.needs_no_approach(near) {
            // what follows with `skip = 0`
            return Some(CanonicalSegment {
                origin: near,
                dir: dir.into(),
                len: len as f32,
                window_start: window_start as f32,
                window_end: window_end as f32,
            });
        }
        let skip = self.approach(pa, dir.as_dvec3(), window_start)?;
        let (origin, window_start) = if skip > 0.0 {
            (pa + dir.as_dvec3() * skip, 0.0)
        } else {
            (pa, window_start)
        };
        let len = len - skip;
        let origin = origin.as_vec3();
        if !(len > window_start + window_end && origin.is_finite()) {
            return None;
        }
        Some(CanonicalSegment {
            origin: origin.into(),
            dir: dir.into(),
            len: len as f32,
            window_start: window_start as f32,
            window_end: window_end as f32,
        })
    }

    /// The same ray as [`Frame::canonical_ray`], in world `f64` (`t` in scene units).
    pub(crate) fn world_ray(&self, ray: &Ray) -> Option<WorldRay> {
        let dir = ray.dir.as_dvec3().normalize_or_zero();
        if dir == DVec3::ZERO || !ray.origin.is_finite() {
            return None;
        }
        let origin = self.world_lifted(ray.origin, unit_or_zero(ray.origin_normal));
        let window = self.lift(ray.origin) * self.inv_scale;
        Some(WorldRay {
            origin,
            dir,
            len: f64::INFINITY,
            window_start: window,
            window_end: 0.0,
        })
    }

    /// The same segment as [`Frame::canonical_segment`], in world `f64`.
    pub(crate) fn world_segment(&self, a: &SurfacePoint, b: &SurfacePoint) -> Option<WorldRay> {
        if !(a.point.is_finite() && b.point.is_finite()) {
            return None;
        }
        let pa = self.world_lifted(a.point, unit_or_zero(a.normal));
        let pb = self.world_lifted(b.point, unit_or_zero(b.normal));
        let delta = pb - pa;
        let len = delta.length();
        let window_start = self.lift(a.point) * self.inv_scale;
        let window_end = self.lift(b.point) * self.inv_scale;
        if !(len > window_start + window_end && len.is_finite()) {
            return None;
        }
        Some(WorldRay {
            origin: pa,
            dir: delta / len,
            len,
            window_start,
            window_end,
        })
    }

    /// `CANONICAL_EPSILON` in scene units.
    pub(crate) fn world_epsilon(&self) -> f64 {
        CANONICAL_EPSILON as f64 * self.inv_scale
    }

    fn world_lifted(&self, p: Vec3, normal: Vec3) -> DVec3 {
        if normal == Vec3::ZERO {
            p.as_dvec3()
        } else {
            p.as_dvec3() + normal.as_dvec3() * (self.lift(p) * self.inv_scale)
        }
    }
}

/// A squared length close enough to 1 (see [`UNIT_TOLERANCE`]).
#[inline(always)]
fn is_unit(length_squared: f32) -> bool {
    (length_squared - 1.0).abs() <= UNIT_TOLERANCE
}

/// `v` normalised, or zero (zero, tiny, huge or non-finite `v`, as `normalize_or_zero`); a `v`
/// that [`is_unit`] already is returned as it is.
#[inline(always)]
fn unit_or_zero(v: Vec3) -> Vec3 {
    if is_unit(v.length_squared()) {
        v
    } else {
        v.normalize_or_zero()
    }
}

/// `-0.0` components replaced by `+0.0`. obvhs 0.4 picks a ray's octant with `d < 0.0` (false
/// for `-0.0`) but inverts `-0.0` to `-1/f32::EPSILON`, so its box test swaps entry and exit and
/// a ray such as `-Vec3::Y` (which is `(-0, -1, -0)`) misses everything.
fn positive_zeros(d: Vec3) -> Vec3 {
    Vec3::select(d.cmpeq(Vec3::ZERO), Vec3::ZERO, d)
}

/// `2^exp`, exact for the exponents used here (|exp| < 1000).
fn pow2(exp: i32) -> f64 {
    2f64.powi(exp)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn extent_in_canonical(min: Vec3, max: Vec3) -> f64 {
        let f = Frame::new(min, max);
        (max.as_dvec3() - min.as_dvec3()).max_element() * f.scale()
    }

    #[test]
    fn canonical_extent_is_in_512_1024_at_every_scale() {
        for e in [-140i32, -60, -20, -3, 0, 1, 9, 10, 11, 40, 120] {
            for m in [1.0f32, 1.3, 1.999_999, 1.5] {
                let size = m * 2f32.powi(e);
                for offset in [0.0f32, -3.0 * size, 1e4 * size] {
                    let min = Vec3::new(offset, offset, offset);
                    let max = min + Vec3::new(size, 0.5 * size, 0.0);
                    if !(min.is_finite() && max.is_finite()) {
                        continue;
                    }
                    let canon = extent_in_canonical(min, max);
                    let size = (max.x as f64) - (min.x as f64);
                    if size > 0.0 {
                        assert!((512.0..1024.0).contains(&canon), "size {size}: {canon}");
                    }
                }
            }
        }
    }

    #[test]
    fn huge_and_degenerate_bounds_give_finite_frames() {
        let f = Frame::new(Vec3::splat(-f32::MAX), Vec3::splat(f32::MAX));
        let corner = f.canonical(Vec3::splat(f32::MAX));
        assert!(
            corner.is_finite() && corner.x > 256.0 && corner.x <= 512.0,
            "{corner}"
        );
        let f = Frame::new(Vec3::ONE, Vec3::ONE);
        assert_eq!(f.scale(), 1.0);
        assert_eq!(f.canonical(Vec3::ONE), Vec3::ZERO);
    }

    #[test]
    fn scale_is_a_power_of_two_and_round_trips() {
        let f = Frame::new(Vec3::new(-3.0, 1.0, 2.0), Vec3::new(7.0, 4.0, 2.5));
        let s = f.scale();
        assert_eq!(s.log2().fract(), 0.0);
        assert_eq!(s * f.inv_scale(), 1.0);
        let p = Vec3::new(0.3, 2.2, 2.1);
        let back = f.world(f.canonical(p).as_dvec3());
        assert!((back - p).abs().max_element() < 1e-6);
    }

    #[test]
    fn lift_grows_only_far_from_the_origin() {
        let f = Frame::new(Vec3::ZERO, Vec3::ONE);
        assert_eq!(f.lift(Vec3::ONE), CANONICAL_EPSILON as f64);
        let far = Frame::new(Vec3::splat(1e4), Vec3::splat(1e4 + 1.0));
        let lift = far.lift(Vec3::splat(1e4));
        // half an f32 ulp of 1e4 is 2^-11 scene units; the lift must be several times that
        let half_ulp = 2f64.powi(-11) * far.scale();
        assert!(
            lift > 4.0 * half_ulp && lift < 16.0 * half_ulp,
            "{lift} vs {half_ulp}"
        );
    }

    #[test]
    fn degenerate_queries_give_none() {
        let f = Frame::new(Vec3::ZERO, Vec3::ONE);
        assert!(f.canonical_ray(&Ray::new(Vec3::ZERO, Vec3::ZERO)).is_none());
        assert!(f.canonical_ray(&Ray::new(Vec3::NAN, Vec3::X)).is_none());
        assert!(
            f.canonical_ray(&Ray::new(Vec3::ZERO, Vec3::INFINITY))
                .is_none()
        );
        assert!(
            f.canonical_ray(&Ray::new(Vec3::splat(1e38), Vec3::X))
                .is_none()
        );
        let p = SurfacePoint::new(Vec3::ZERO, Vec3::Y, 1);
        assert!(f.canonical_segment(&p, &p).is_none());
        assert!(f.world_segment(&p, &p).is_none());
        let q = SurfacePoint::new(Vec3::NAN, Vec3::Y, 1);
        assert!(f.canonical_segment(&p, &q).is_none());
    }

    /// The tests' seeded stream ([`crate::testing::uniforms`]) with the shapes they draw.
    struct Stream<F: FnMut() -> f32>(F);

    impl<F: FnMut() -> f32> Stream<F> {
        fn unit(&mut self) -> f32 {
            (self.0)()
        }
        fn point(&mut self, min: Vec3, max: Vec3) -> Vec3 {
            // mostly inside the box, some outside, some on its faces
            let t = Vec3::new(self.unit(), self.unit(), self.unit()) * 1.4 - 0.2;
            let t = if self.unit() < 0.1 {
                t.round().clamp(Vec3::ZERO, Vec3::ONE)
            } else {
                t
            };
            min + (max - min) * t
        }
        fn direction(&mut self) -> Vec3 {
            let d = Vec3::new(self.unit(), self.unit(), self.unit()) * 2.0 - 1.0;
            let d = if self.unit() < 0.1 {
                d * Vec3::new(1.0, 0.0, 0.0) // axis-parallel, with zeros
            } else {
                d
            };
            d.normalize_or(Vec3::Y)
        }
    }

    fn frames() -> Vec<(Vec3, Vec3)> {
        vec![
            (Vec3::ZERO, Vec3::ONE),
            (Vec3::splat(0.1), Vec3::new(0.3, 0.7, 0.2)),
            (Vec3::new(-3.0, 1.0, 2.0), Vec3::new(7.0, 4.0, 2.5)),
            (Vec3::splat(1e4), Vec3::splat(1e4 + 1.0)),
            (Vec3::splat(-1e-20), Vec3::new(3e-20, 1e-20, 0.0)),
            (Vec3::splat(-2e30), Vec3::splat(5e30)),
            (Vec3::new(1e-3, 2.0, -5.0), Vec3::new(1e3, 2.5, 5.0)),
            (Vec3::ZERO, Vec3::splat(3e38)),
        ]
    }

    fn same_ray(a: Option<CanonicalRay>, b: Option<CanonicalRay>) -> bool {
        match (a, b) {
            (None, None) => true,
            (Some(a), Some(b)) => {
                let bits = |v: Vec3A| v.to_array().map(f32::to_bits);
                bits(a.origin) == bits(b.origin)
                    && bits(a.dir) == bits(b.dir)
                    && a.window.to_bits() == b.window.to_bits()
                    && a.skip.to_bits() == b.skip.to_bits()
            }
            _ => false,
        }
    }

    fn same_segment(a: Option<CanonicalSegment>, b: Option<CanonicalSegment>) -> bool {
        match (a, b) {
            (None, None) => true,
            (Some(a), Some(b)) => {
                let bits = |v: Vec3A| v.to_array().map(f32::to_bits);
                bits(a.origin) == bits(b.origin)
                    && bits(a.dir) == bits(b.dir)
                    && a.len.to_bits() == b.len.to_bits()
                    && a.window_start.to_bits() == b.window_start.to_bits()
                    && a.window_end.to_bits() == b.window_end.to_bits()
            }
            _ => false,
        }
    }

    #[test]
    fn f32_canonical_points_match_the_f64_map() {
        let mut rng = Stream(crate::testing::uniforms(11));
        for (min, max) in frames() {
            let f = Frame::new(min, max);
            assert_eq!(f.center32.as_dvec3(), f.center);
            for _ in 0..20_000 {
                let p = rng.point(min, max);
                let fast = f.canonical32(p);
                if f.scale32 != 0.0 && fast.is_finite() {
                    assert_eq!(Vec3::from(fast), f.canonical(p), "{p} in {min}..{max}");
                }
            }
        }
    }

    #[test]
    fn fast_paths_match_the_general_paths() {
        let mut rng = Stream(crate::testing::uniforms(12));
        let mut fast_rays = 0;
        for (min, max) in frames() {
            let f = Frame::new(min, max);
            let surface = |rng: &mut Stream<_>| {
                let normal = if rng.unit() < 0.1 {
                    Vec3::ZERO
                } else {
                    rng.direction()
                };
                SurfacePoint::new(rng.point(min, max), normal, 1)
            };
            for _ in 0..20_000 {
                let p = surface(&mut rng);
                let ray = Ray::from_surface(p.point, p.normal, rng.direction(), 1);
                let fast = f.canonical_ray(&ray);
                assert!(
                    same_ray(fast, f.canonical_ray_general(&ray)),
                    "{ray:?} in {min}..{max}"
                );
                fast_rays += usize::from(fast.is_some_and(|c| c.skip == 0.0));
                let q = surface(&mut rng);
                assert!(
                    same_segment(
                        f.canonical_segment(&p, &q),
                        f.canonical_segment_general(&p, &q)
                    ),
                    "{p:?} -> {q:?} in {min}..{max}"
                );
            }
        }
        assert!(fast_rays > 50_000, "{fast_rays}");
        // a point far outside a huge scene overflows the f32 formula, not the f64 one
        let f = Frame::new(Vec3::ZERO, Vec3::splat(3e38));
        let (a, b) = (
            SurfacePoint::free(Vec3::splat(-3e38)),
            SurfacePoint::new(Vec3::splat(1e38), Vec3::X, 1),
        );
        assert!(!f.canonical32(a.point).is_finite());
        let segment = f.canonical_segment(&a, &b);
        assert!(segment.is_some());
        assert!(same_segment(segment, f.canonical_segment_general(&a, &b)));
    }
}
