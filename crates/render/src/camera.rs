//! The pinhole camera: pixel coordinates to rays and back.

use glam::{DVec3, Vec2, Vec3};
use mcrad_raycast::Ray;

/// Why a camera could not be built.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum CameraError {
    /// A position, the up vector or the field of view is NaN or infinite.
    #[error(
        "camera input is not finite: eye {eye}, look-at {look}, up {up}, field of view {fov_y_degrees} degrees"
    )]
    NonFinite {
        /// Eye position (scene units).
        eye: Vec3,
        /// Look-at point (scene units).
        look: Vec3,
        /// Up vector.
        up: Vec3,
        /// Vertical field of view (degrees).
        fov_y_degrees: f32,
    },
    /// The eye and the look-at point coincide, so there is no view direction.
    #[error("camera eye and look-at point coincide at {0}")]
    EyeAtTarget(Vec3),
    /// The up vector is zero or parallel to the view direction.
    #[error("camera up vector {up} is zero or parallel to the view direction {dir}")]
    UpParallel {
        /// The up vector given.
        up: Vec3,
        /// The unit view direction.
        dir: Vec3,
    },
    /// The vertical field of view is not strictly between 0 and 180 degrees.
    #[error("camera vertical field of view must lie strictly between 0 and 180 degrees, got {0}")]
    BadFov(f32),
    /// The scene to frame has no extent (no triangles, or all in one point).
    #[error("cannot frame a scene without extent (bounds {min} to {max})")]
    EmptyScene {
        /// Smallest corner of the scene's bounding box (scene units).
        min: Vec3,
        /// Largest corner of the scene's bounding box (scene units).
        max: Vec3,
    },
}

/// A pinhole camera. The image plane is spanned by [`Camera::right`] and [`Camera::up`]; its
/// aspect ratio is the image's (`width / height`, square pixels), fixed only when a ray is cast.
///
/// Pixel coordinates: `x` to the right, `y` down, `(0, 0)` the top-left *corner* of the image,
/// `(width, height)` the bottom-right one; pixel `(i, j)` has its centre at `(i + 0.5, j + 0.5)`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Camera {
    eye: Vec3,
    forward: Vec3,
    right: Vec3,
    up: Vec3,
    fov_y_degrees: f32,
    /// `tan(fov_y / 2)`: half the image height at unit distance.
    tan_half: f32,
}

impl Camera {
    /// A camera at `eye` looking at `look` (both scene units), with `up` the direction that
    /// appears upward (it need not be perpendicular to the view direction, only not parallel)
    /// and `fov_y_degrees` the vertical field of view in degrees, in `(0, 180)`.
    pub fn look_at(
        eye: Vec3,
        look: Vec3,
        up: Vec3,
        fov_y_degrees: f32,
    ) -> Result<Camera, CameraError> {
        if !(eye.is_finite() && look.is_finite() && up.is_finite() && fov_y_degrees.is_finite()) {
            return Err(CameraError::NonFinite {
                eye,
                look,
                up,
                fov_y_degrees,
            });
        }
        if !(fov_y_degrees > 0.0 && fov_y_degrees < 180.0) {
            return Err(CameraError::BadFov(fov_y_degrees));
        }
        let forward = (look - eye).normalize_or_zero();
        if forward == Vec3::ZERO {
            return Err(CameraError::EyeAtTarget(eye));
        }
        let right = forward.cross(up.normalize_or_zero());
        if right.length() < 1e-6 {
            return Err(CameraError::UpParallel { up, dir: forward });
        }
        let right = right.normalize();
        Ok(Camera {
            eye,
            forward,
            right,
            up: right.cross(forward),
            fov_y_degrees,
            tan_half: (fov_y_degrees.to_radians() * 0.5).tan(),
        })
    }

    /// The camera a scene file stores (`mcrad_scene_io::Camera`: eye, unit view direction, up,
    /// vertical field of view), checked like [`Camera::look_at`] with the look-at point one unit
    /// along the view direction.
    pub fn from_scene(camera: &mcrad_scene_io::Camera) -> Result<Camera, CameraError> {
        Camera::look_at(
            camera.eye,
            camera.eye + camera.forward,
            camera.up,
            camera.fov_y_degrees,
        )
    }

    /// The same camera with its eye moved by `-offset` (scene units): the camera of a scene
    /// whose positions are stored relative to `offset`, such as a mesh's local frame
    /// (`mcrad_meshing::Mesh::origin`). The subtraction is done in `f64` and rounded once, so
    /// a camera far from the world origin keeps its precision in the local frame.
    pub fn translated(&self, offset: DVec3) -> Camera {
        Camera {
            eye: (self.eye.as_dvec3() - offset).as_vec3(),
            ..*self
        }
    }

    /// The eye (centre of projection), scene units.
    pub fn eye(&self) -> Vec3 {
        self.eye
    }

    /// Unit view direction (towards the image centre).
    pub fn forward(&self) -> Vec3 {
        self.forward
    }

    /// Unit vector pointing to the right of the image (`forward × up`).
    pub fn right(&self) -> Vec3 {
        self.right
    }

    /// Unit vector pointing to the top of the image, perpendicular to [`Camera::forward`].
    pub fn up(&self) -> Vec3 {
        self.up
    }

    /// Vertical field of view, degrees.
    pub fn fov_y_degrees(&self) -> f32 {
        self.fov_y_degrees
    }

    /// The ray from the eye through `pixel` (pixel coordinates, see [`Camera`]) of a
    /// `width × height` image; its direction is a unit vector. A zero `width` or `height` gives
    /// a non-finite direction, which ray casters treat as hitting nothing.
    pub fn ray(&self, pixel: Vec2, width: u32, height: u32) -> Ray {
        let (w, h) = (width as f32, height as f32);
        let aspect = w / h;
        let sx = (2.0 * pixel.x / w - 1.0) * self.tan_half * aspect;
        let sy = (1.0 - 2.0 * pixel.y / h) * self.tan_half;
        let dir = (self.forward + sx * self.right + sy * self.up).normalize();
        Ray::new(self.eye, dir)
    }

    /// Where `point` (scene units) appears in a `width × height` image, in pixel coordinates;
    /// `None` when it lies behind the eye (or on its plane) or outside the image rectangle
    /// (edges included). Occlusion is not checked. The inverse of [`Camera::ray`]:
    /// `project(ray(p).origin + t * ray(p).dir) ≈ p` for `t > 0`.
    pub fn project(&self, point: Vec3, width: u32, height: u32) -> Option<Vec2> {
        let (w, h) = (width as f32, height as f32);
        let d = point - self.eye;
        let z = d.dot(self.forward);
        if z.is_nan() || z <= 0.0 {
            return None;
        }
        let aspect = w / h;
        let sx = d.dot(self.right) / (z * self.tan_half * aspect);
        let sy = d.dot(self.up) / (z * self.tan_half);
        let p = Vec2::new((sx + 1.0) * 0.5 * w, (1.0 - sy) * 0.5 * h);
        let inside = (0.0..=w).contains(&p.x) && (0.0..=h).contains(&p.y);
        inside.then_some(p)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn cam() -> Camera {
        Camera::look_at(
            Vec3::new(1.0, 2.0, -5.0),
            Vec3::new(1.0, 2.0, 0.0),
            Vec3::Y,
            40.0,
        )
        .unwrap()
    }

    #[test]
    fn look_at_point_projects_to_the_image_centre() {
        let p = cam().project(Vec3::new(1.0, 2.0, 3.0), 640, 480).unwrap();
        assert!((p - Vec2::new(320.0, 240.0)).length() < 1e-3, "{p}");
    }

    #[test]
    fn point_up_right_lands_at_the_computed_pixel() {
        // Looking along +z with +y up, image right is -x. A point 1 unit right and 0.5 up at
        // depth 5: x = (1 + (1/5)/(tan20°·aspect)) · w/2, y = (1 - (0.5/5)/tan20°) · h/2.
        let (w, h) = (640, 480);
        let p = cam().project(Vec3::new(0.0, 2.5, 0.0), w, h).unwrap();
        let t = 20f32.to_radians().tan();
        let expected = Vec2::new(
            (1.0 + 0.2 / (t * 640.0 / 480.0)) * 320.0,
            (1.0 - 0.1 / t) * 240.0,
        );
        assert!(p.x > 320.0 && p.y < 240.0, "{p}");
        assert!((p - expected).length() < 1e-3, "{p} vs {expected}");
    }

    #[test]
    fn project_inverts_ray() {
        let c = cam();
        for &(w, h) in &[(640u32, 480u32), (100, 300)] {
            for &px in &[
                Vec2::new(0.5, 0.5),
                Vec2::new(320.25, 11.75),
                Vec2::new(99.5, 299.5),
            ] {
                if px.x > w as f32 || px.y > h as f32 {
                    continue;
                }
                let r = c.ray(px, w, h);
                for t in [0.5f32, 3.0, 40.0] {
                    let q = c.project(r.origin + t * r.dir, w, h).unwrap();
                    assert!((q - px).length() < 2e-3, "{q} vs {px}");
                }
            }
        }
    }

    #[test]
    fn centre_ray_looks_forward_and_corner_rays_span_the_fov() {
        let c = cam();
        let r = c.ray(Vec2::new(50.0, 50.0), 100, 100);
        assert!((r.dir - Vec3::Z).length() < 1e-6);
        let top = c.ray(Vec2::new(50.0, 0.0), 100, 100);
        assert!((top.dir.angle_between(Vec3::Z).to_degrees() - 20.0).abs() < 1e-3);
        assert!(top.dir.y > 0.0);
        let left = c.ray(Vec2::new(0.0, 50.0), 100, 100);
        assert!(
            left.dir.x > 0.0,
            "image left is +x when looking +z with +y up"
        );
    }

    #[test]
    fn points_behind_or_outside_do_not_project() {
        let c = cam();
        assert_eq!(c.project(Vec3::new(1.0, 2.0, -6.0), 64, 64), None);
        assert_eq!(c.project(Vec3::new(1.0, 2.0, -5.0), 64, 64), None);
        assert_eq!(c.project(Vec3::new(100.0, 2.0, 0.0), 64, 64), None);
    }

    #[test]
    fn degenerate_input_is_a_typed_error() {
        let e = Vec3::ZERO;
        assert_eq!(
            Camera::look_at(e, e, Vec3::Y, 40.0),
            Err(CameraError::EyeAtTarget(e))
        );
        assert!(matches!(
            Camera::look_at(e, Vec3::Y, Vec3::Y, 40.0),
            Err(CameraError::UpParallel { .. })
        ));
        assert!(matches!(
            Camera::look_at(e, Vec3::X, Vec3::ZERO, 40.0),
            Err(CameraError::UpParallel { .. })
        ));
        for fov in [0.0, -1.0, 180.0, 200.0] {
            assert_eq!(
                Camera::look_at(e, Vec3::X, Vec3::Y, fov),
                Err(CameraError::BadFov(fov))
            );
        }
        assert!(matches!(
            Camera::look_at(Vec3::new(f32::NAN, 0.0, 0.0), Vec3::X, Vec3::Y, 40.0),
            Err(CameraError::NonFinite { .. })
        ));
        assert!(matches!(
            Camera::look_at(e, Vec3::X, Vec3::Y, f32::INFINITY),
            Err(CameraError::NonFinite { .. })
        ));
    }
}
