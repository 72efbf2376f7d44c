//! Automatic framing for scenes that bring no camera.

use glam::{Vec2, Vec3};
use mcrad_meshing::Mesh;
use mcrad_raycast::RayCaster;

use crate::camera::{Camera, CameraError};

/// Vertical field of view of an outside view chosen by [`Camera::frame_scene`], degrees.
pub const FRAME_FOV_Y_DEGREES: f32 = 40.0;

/// Vertical field of view of the inside view [`Camera::frame_scene`] falls back to, degrees.
pub const INSIDE_FOV_Y_DEGREES: f32 = 60.0;

/// Side of the square grid of probe rays each candidate view casts.
const PROBE_GRID: u32 = 16;

/// Extra room around the bounding box in an outside view (a 5% border).
const MARGIN: f32 = 1.05;

/// The six axis view directions, in tie-breaking order: along +z first (eye on the -z side),
/// then -z, +x, -x, +y, -y.
const DIRECTIONS: [Vec3; 6] = [
    Vec3::Z,
    Vec3::NEG_Z,
    Vec3::X,
    Vec3::NEG_X,
    Vec3::Y,
    Vec3::NEG_Y,
];

impl Camera {
    /// A camera for a scene that has none, looking at `mesh` (whose triangles `caster` holds,
    /// tagged with patch indices; only [`mcrad_raycast::Hit::front`] is used).
    ///
    /// For each axis direction `d` (+z, -z, +x, -x, +y, -y) the camera looks along `d` at the
    /// centre of the bounding box of the mesh's triangles, with a 40° vertical field of view,
    /// from just far enough outside the box that the box's face towards the eye, plus a 5%
    /// border, fits a square image (so it also fits any landscape image). Its up vector is +y,
    /// or -z when `d` is ±y. It casts a 16×16 grid of rays (pixel centres of a 16×16 image) and
    /// counts those whose first hit is a front face. The view with the most such hits wins;
    /// ties go to the earlier direction in the order above, so the choice is deterministic.
    ///
    /// When no outside view sees a single front face (a closed room whose walls face inwards),
    /// the camera goes inside: it looks along the positive axis of the box's largest extent
    /// (ties: z, then x, then y), from the box centre moved back by 40% of that extent (so it
    /// stands a tenth of the extent in front of the rear wall), with a 60° vertical field of
    /// view and the same up rule.
    ///
    /// Errors: [`CameraError::EmptyScene`] when the mesh has no triangles or no extent.
    pub fn frame_scene(mesh: &Mesh, caster: &impl RayCaster) -> Result<Camera, CameraError> {
        let (min, max) = triangle_bounds(mesh);
        let extent = max - min;
        if !(extent.is_finite() && extent.max_element() > 0.0) {
            return Err(CameraError::EmptyScene { min, max });
        }
        let centre = 0.5 * (min + max);
        let half = 0.5 * extent;
        let tan_half = (0.5 * FRAME_FOV_Y_DEGREES).to_radians().tan();
        let mut best: Option<(u32, Camera)> = None;
        for d in DIRECTIONS {
            let depth = half.dot(d.abs());
            let across = (half - depth * d.abs()).max_element();
            let distance = depth + MARGIN * across / tan_half;
            let camera = Camera::look_at(
                centre - distance * d,
                centre,
                up_for(d),
                FRAME_FOV_Y_DEGREES,
            )?;
            let hits = front_hits(&camera, caster);
            if hits > best.map_or(0, |b| b.0) {
                best = Some((hits, camera));
            }
        }
        match best {
            Some((_, camera)) => Ok(camera),
            None => {
                let d = if extent.z >= extent.x && extent.z >= extent.y {
                    Vec3::Z
                } else if extent.x >= extent.y {
                    Vec3::X
                } else {
                    Vec3::Y
                };
                let eye = centre - 0.4 * extent.dot(d) * d;
                Camera::look_at(eye, eye + d, up_for(d), INSIDE_FOV_Y_DEGREES)
            }
        }
    }
}

/// The up vector of an axis view along `d`: +y, or -z when looking along ±y.
fn up_for(d: Vec3) -> Vec3 {
    if d.y != 0.0 { Vec3::NEG_Z } else { Vec3::Y }
}

/// Number of probe rays of `camera` whose first hit is a front face.
fn front_hits(camera: &Camera, caster: &impl RayCaster) -> u32 {
    let mut count = 0;
    for j in 0..PROBE_GRID {
        for i in 0..PROBE_GRID {
            let pixel = Vec2::new(i as f32 + 0.5, j as f32 + 0.5);
            let ray = camera.ray(pixel, PROBE_GRID, PROBE_GRID);
            if caster.closest_hit(&ray).is_some_and(|h| h.front) {
                count += 1;
            }
        }
    }
    count
}

/// Bounds `(min, max)` of the vertices the mesh's triangles use (scene units); inverted
/// (`min > max`) for a mesh without triangles.
fn triangle_bounds(mesh: &Mesh) -> (Vec3, Vec3) {
    let positions = mesh.positions();
    mesh.triangles()
        .iter()
        .flatten()
        .map(|&v| positions[v as usize])
        .fold((Vec3::INFINITY, Vec3::NEG_INFINITY), |(lo, hi), p| {
            (lo.min(p), hi.max(p))
        })
}
