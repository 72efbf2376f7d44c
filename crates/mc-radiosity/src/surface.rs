//! Uniform points and cosine-distributed rays on patches.

use crate::context::Sampler;
use crate::jobs::JOB_RAYS;
use crate::sampling::{
    Frame, cosine_hemisphere_concentric, cosine_hemisphere_rejection, uniform_triangle,
};
use glam::{Vec2, Vec3};
use mcrad_meshing::{Mesh, Patch};
use mcrad_random::{Sobol, Stream, StreamKey};
use mcrad_raycast::Ray;

/// Draws uniform points (density `1/A_i` per unit area) and rays leaving patches with the
/// cosine density `cos(theta)/pi` per steradian.
///
/// It reads the triangles, positions and normals from the mesh it borrows and keeps one `f32`
/// per triangle of its own (4 bytes per triangle): a triangle's first vertex and edges, and a
/// patch's tangent frame, are computed where a point or ray needs them, by the same `f32`
/// operations a stored copy was made with, so the points and rays are the same bit for bit.
#[derive(Debug, Clone)]
pub struct SurfaceSampler<'m> {
    mesh: &'m Mesh,
    /// Per triangle of [`Mesh::triangles`]: the cumulative area fraction within its patch up
    /// to and including it (1 for a patch's last triangle).
    cdf: Vec<f32>,
}

impl<'m> SurfaceSampler<'m> {
    /// The sampler of `mesh`'s patches.
    pub fn new(mesh: &'m Mesh) -> SurfaceSampler<'m> {
        let mut cdf = Vec::with_capacity(mesh.triangles().len());
        let pos = mesh.positions();
        for patch in mesh.patches() {
            let tris = mesh.patch_triangles(patch);
            if let [_] = tris {
                cdf.push(1.0);
                continue;
            }
            let areas: Vec<f64> = tris
                .iter()
                .map(|t| {
                    let [a, b, c] = t.map(|i| pos[i as usize].as_dvec3());
                    (b - a).cross(c - a).length()
                })
                .collect();
            let total: f64 = areas.iter().sum();
            let mut acc = 0.0;
            for area in &areas {
                acc += area;
                cdf.push((acc / total) as f32);
            }
            // Rounding must not leave a gap at the top.
            *cdf.last_mut().expect("a patch has a triangle") = 1.0;
        }
        SurfaceSampler { mesh, cdf }
    }

    /// The first triangle of `patch` and its triangle count.
    #[inline]
    fn triangles(&self, patch: usize) -> (usize, usize) {
        let p = &self.mesh.patches()[patch];
        (
            self.mesh.first_triangle(p),
            self.mesh.patch_triangles(p).len(),
        )
    }

    /// The point of triangle `t` at barycentric `b` (weights of its second and third vertex).
    #[inline]
    fn on_triangle(&self, t: usize, b: Vec2) -> Vec3 {
        let pos = self.mesh.positions();
        let [a, v1, v2] = self.mesh.triangles()[t].map(|i| pos[i as usize]);
        a + (v1 - a) * b.x + (v2 - a) * b.y
    }

    /// The tangent frame about `patch`'s normal.
    #[inline]
    fn frame(&self, patch: usize) -> Frame {
        Frame::from_normal(self.mesh.patches()[patch].normal)
    }

    /// A uniform point of `patch` from three uniforms in `[0, 1)`: the first picks a triangle by
    /// area, the other two a point in it.
    #[inline]
    pub fn point(&self, patch: usize, u: [f32; 3]) -> Vec3 {
        self.point_on(patch, u).0
    }

    /// [`point`](Self::point) and the triangle (its index in the mesh) it lies on.
    #[inline]
    pub fn point_on(&self, patch: usize, u: [f32; 3]) -> (Vec3, usize) {
        let t = self.triangle_at(patch, u[0]);
        (
            self.on_triangle(t, uniform_triangle(Vec2::new(u[1], u[2]))),
            t,
        )
    }

    /// A uniform point of `patch` from two uniforms in `[0, 1)`: the first picks a triangle by
    /// area and, rescaled to the triangle's share of `[0, 1)`, gives the point's distance along
    /// the triangle with the second (so stratified pairs give stratified points).
    #[inline]
    pub fn point2(&self, patch: usize, u: [f32; 2]) -> Vec3 {
        self.point2_on(patch, u).0
    }

    /// [`point2`](Self::point2) and the triangle (its index in the mesh) it lies on.
    #[inline]
    pub fn point2_on(&self, patch: usize, u: [f32; 2]) -> (Vec3, usize) {
        let first = self.triangles(patch).0;
        let t = self.triangle_at(patch, u[0]);
        let low = if t == first { 0.0 } else { self.cdf[t - 1] };
        let width = self.cdf[t] - low;
        let v = if width > 0.0 {
            ((u[0] - low) / width).clamp(0.0, 1.0 - f32::EPSILON / 2.0)
        } else {
            0.0
        };
        (self.on_triangle(t, uniform_triangle(Vec2::new(v, u[1]))), t)
    }

    /// The tangent frame at the points of triangle `t` of `patch` (for a cluster, its
    /// triangle's own normal: [`Mesh::triangle_normal`]), given `frame`, the patch's.
    #[inline]
    pub fn frame_on(&self, patch: usize, t: usize, frame: &Frame) -> Frame {
        let p = &self.mesh.patches()[patch];
        if p.is_cluster() {
            Frame::from_normal(self.mesh.triangle_normal(p, t))
        } else {
            *frame
        }
    }

    /// The triangle of `patch` (its index in the mesh) that [`point2`](Self::point2) puts a
    /// point with first uniform `u0` on.
    #[inline]
    pub fn triangle_at(&self, patch: usize, u0: f32) -> usize {
        let (first, count) = self.triangles(patch);
        // the first triangle whose cumulative share exceeds u0 (the last if none does); a
        // binary search, as a cluster has many triangles
        first + self.cdf[first..first + count - 1].partition_point(|&c| u0 >= c)
    }

    /// The ray of `patch` from a point `u` of the unit 4-cube: a cosine-distributed direction
    /// from `u[0..2]` (Shirley and Chiu's concentric map lifted to the hemisphere) leaving the uniform point
    /// [`point2`](Self::point2)`(patch, u[2..4])`. Uniform `u` gives a uniform point and a cosine
    /// direction; stratified `u` (a quasi-Monte Carlo sequence) gives stratified rays.
    #[inline]
    pub fn ray_at(&self, patch: usize, u: [f32; 4]) -> Ray {
        let (p, t) = self.point2_on(patch, [u[2], u[3]]);
        let frame = self.frame(patch);
        let frame = self.frame_on(patch, t, &frame);
        let d = frame.to_world(cosine_hemisphere_concentric(Vec2::new(u[0], u[1])));
        self.leaving(patch, p, &frame, d)
    }

    /// A ray leaving a uniform point of `patch` in a cosine-distributed direction about its
    /// normal, drawing three uniforms for the point and about 2.5 for the direction from `rng`.
    #[inline]
    pub fn ray(&self, patch: usize, rng: &mut Stream) -> Ray {
        let (p, t) = self.point_on(patch, [rng.uniform(), rng.uniform(), rng.uniform()]);
        let frame = self.frame(patch);
        let frame = self.frame_on(patch, t, &frame);
        // Unit to rounding: a unit local direction in an orthonormal frame.
        let d = frame.to_world(cosine_hemisphere_rejection(|| rng.uniform()));
        self.leaving(patch, p, &frame, d)
    }

    /// The ray from point `p` of `patch` (tangent frame `frame` there) in direction `d`. A
    /// planar patch cannot hit itself, and its own hits are filtered out; a cluster's member
    /// may see another member (a fold between them), so a cluster's ray excludes nothing: it
    /// is lifted off its own triangle's plane, which it leaves.
    #[inline]
    fn leaving(&self, patch: usize, p: Vec3, frame: &Frame, d: Vec3) -> Ray {
        Ray::from_surface(p, frame.normal, d, self.own_id(patch))
    }

    /// The id rays from `patch` exclude ([`own_id`]).
    #[inline]
    pub fn own_id(&self, patch: usize) -> u32 {
        own_id(&self.mesh.patches()[patch], patch)
    }

    /// The unit normal at the points of triangle `t` of `patch`, given `normal`, the patch's
    /// (a cluster's triangle's own: [`Mesh::triangle_normal`]).
    #[inline]
    pub fn normal_on(&self, patch: usize, t: usize, normal: Vec3) -> Vec3 {
        let p = &self.mesh.patches()[patch];
        if p.is_cluster() {
            self.mesh.triangle_normal(p, t)
        } else {
            normal
        }
    }
}

/// The id that rays and shadow rays from a point of `patch` (number `i`) exclude: its own,
/// whose planar triangles it cannot see; none for a cluster, one member of which may see
/// another across a fold (the ray is lifted off its own triangle's plane, which it leaves).
#[inline]
pub(crate) fn own_id(patch: &Patch, i: usize) -> u32 {
    if patch.is_cluster() {
        mcrad_raycast::NO_ID
    } else {
        i as u32
    }
}

/// Where the rays of one job of a patch come from (see [`Sampler`](crate::Sampler)):
/// independent uniforms, or consecutive points of the patch's quasi-Monte Carlo sequence.
#[derive(Debug, Clone)]
pub(crate) enum Rays {
    /// [`SurfaceSampler::ray`] from a stream.
    Random(Stream),
    /// [`SurfaceSampler::ray_at`] at points `next, next + 1, ...` of a sequence.
    Qmc {
        /// The patch's sequence.
        sequence: Sobol,
        /// The index of the next point.
        next: u64,
    },
}

impl Rays {
    /// The rays of chunk `chunk` (of [`JOB_RAYS`](crate::jobs::JOB_RAYS) rays) of an item whose
    /// streams are keyed by `item`, for the estimator tagged `tag`: the stream
    /// `item.substream(tag + chunk)`, or the points from `chunk * JOB_RAYS` on of the sequence
    /// `item.substream(tag)`, as `sampling` says.
    pub fn for_chunk(sampling: Sampler, item: StreamKey, tag: u64, chunk: u32) -> Rays {
        match sampling {
            Sampler::Random => Rays::Random(item.substream(tag + chunk as u64).stream()),
            Sampler::Qmc => Rays::Qmc {
                sequence: item.substream(tag).sobol(),
                next: chunk as u64 * JOB_RAYS as u64,
            },
        }
    }

    /// The next point of the unit 4-cube: four uniforms, or the sequence's next point.
    #[inline]
    pub fn next_point(&mut self) -> [f32; 4] {
        match self {
            Rays::Random(rng) => [rng.uniform(), rng.uniform(), rng.uniform(), rng.uniform()],
            Rays::Qmc { sequence, next } => {
                let u = sequence.point(*next);
                *next += 1;
                u
            }
        }
    }

    /// The next ray of `patch`.
    #[inline]
    pub fn ray(&mut self, sampler: &SurfaceSampler<'_>, patch: usize) -> Ray {
        match self {
            Rays::Random(rng) => sampler.ray(patch, rng),
            Rays::Qmc { .. } => sampler.ray_at(patch, self.next_point()),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sampling::chi2;
    use mcrad_meshing::Subdivision;
    use mcrad_scene_io::{Face, Material, Scene};

    #[test]
    fn quad_points_are_uniform() {
        let mut rng = Stream::new(11, 0, 0, 0);
        quad_points_are_uniform_by(|s| s.point(0, [rng.uniform(), rng.uniform(), rng.uniform()]));
    }

    /// [`SurfaceSampler::point2`] (two uniforms, the triangle's share rescaled) is uniform too;
    /// so are the points [`SurfaceSampler::ray_at`] takes from a quasi-Monte Carlo sequence
    /// (its dimensions 2-3: one key, a million points in 16 blocks).
    #[test]
    fn quad_points_from_two_uniforms_are_uniform() {
        let mut rng = Stream::new(12, 0, 0, 0);
        quad_points_are_uniform_by(|s| s.point2(0, [rng.uniform(), rng.uniform()]));
        let sequence = mcrad_random::StreamKey::new(3).sobol();
        let mut k = 0;
        quad_points_are_uniform_by(|s| {
            let u = sequence.point(k);
            k += 1;
            s.point2(0, [u[2], u[3]])
        });
    }

    /// A million points of the quad by `sample` fall in its fan triangles' sub-triangles by
    /// area (chi-square, alpha 1e-4: a false failure for a correct sampler once in 10 000
    /// seeds).
    fn quad_points_are_uniform_by(mut sample: impl FnMut(&SurfaceSampler) -> Vec3) {
        // A trapezoid (not a parallelogram) split 1:2 by area between its two fan triangles.
        let positions = vec![
            Vec3::new(0.0, 0.0, 0.0),
            Vec3::new(3.0, 0.0, 0.0),
            Vec3::new(2.0, 1.0, 0.0),
            Vec3::new(1.0, 1.0, 0.0),
        ];
        let faces = vec![Face {
            vertices: vec![0, 1, 2, 3],
            material: 0,
            source: 0,
        }];
        let lamp = Material {
            name: "lamp".into(),
            reflectance: Vec3::ZERO,
            emission: Vec3::ONE,
        };
        let scene = Scene::new(positions.clone(), faces, vec![lamp]).unwrap().0;
        let mesh = Mesh::build(&scene, Subdivision::None).unwrap();
        let s = SurfaceSampler::new(&mesh);
        let tris = mesh.patch_triangles(&mesh.patches()[0]);
        let areas: Vec<f64> = tris
            .iter()
            .map(|t| {
                let [a, b, c] = t.map(|i| positions[i as usize].as_dvec3());
                (b - a).cross(c - a).length() / 2.0
            })
            .collect();
        let total: f64 = areas.iter().sum();
        let n = 10;
        let cells = 2 * n * n;
        let mut obs = vec![0.0; tris.len() * cells];
        let samples = 1_000_000;
        for _ in 0..samples {
            let p = sample(&s);
            // Locate the fan triangle and barycentrics of p from the geometry, not the sampler.
            let (k, b) = tris
                .iter()
                .enumerate()
                .map(|(k, t)| {
                    let [a, b, c] = t.map(|i| positions[i as usize]);
                    (k, barycentric(p, a, b, c))
                })
                .find(|(_, b)| b.x >= -1e-5 && b.y >= -1e-5 && b.x + b.y <= 1.0 + 1e-5)
                .expect("point inside the quad");
            obs[k * cells
                + crate::sampling::tests_support::sub_triangle(
                    b.clamp(Vec2::ZERO, Vec2::ONE),
                    n,
                )] += 1.0;
        }
        let exp: Vec<f64> = (0..obs.len())
            .map(|idx| {
                let (k, cell) = (idx / cells, idx % cells);
                let (c, down) = (cell / 2, cell % 2);
                let (i, j) = (c % n, c / n);
                let inside = if down == 0 { i + j < n } else { i + j + 1 < n };
                if inside {
                    samples as f64 * areas[k] / total / (n * n) as f64
                } else {
                    0.0
                }
            })
            .collect();
        chi2::test(&obs, &exp, 1e-4).unwrap();
    }

    fn barycentric(p: Vec3, a: Vec3, b: Vec3, c: Vec3) -> Vec2 {
        let (e1, e2, d) = ((b - a).as_dvec3(), (c - a).as_dvec3(), (p - a).as_dvec3());
        let (d11, d12, d22) = (e1.dot(e1), e1.dot(e2), e2.dot(e2));
        let (d1, d2) = (d.dot(e1), d.dot(e2));
        let det = d11 * d22 - d12 * d12;
        Vec2::new(
            ((d22 * d1 - d12 * d2) / det) as f32,
            ((d11 * d2 - d12 * d1) / det) as f32,
        )
    }
}
