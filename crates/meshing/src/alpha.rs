//! The ray caster of a mesh with alpha-tested patches: rays pass their cut-out parts.

use std::sync::Arc;

use glam::Vec3;
use mcrad_raycast::{AnyHit, BuildError, Bvh};
use mcrad_scene_io::SceneTextures;

use crate::Mesh;

/// The any-hit test of a mesh's alpha-tested patches (glTF `MASK` and `BLEND`, see
/// [`mcrad_scene_io::FaceAlpha`]): a ray crossing patch `id` at a point passes where the face's
/// alpha says. `BLEND`'s coin is a hash of the crossing (point, direction, patch), so a ray gets
/// the same answer on any thread and independent rays independent answers.
#[derive(Debug)]
pub struct AlphaTest {
    textures: Arc<SceneTextures>,
    /// Per patch: the face whose alpha it has, or `u32::MAX` for an opaque patch.
    faces: Vec<u32>,
    /// The mesh's local frame origin (crossings come in local coordinates).
    origin: Vec3,
}

impl AlphaTest {
    /// The test of `mesh`'s patches, or `None` when none is alpha-tested.
    pub fn new(mesh: &Mesh) -> Option<AlphaTest> {
        let textures = mesh.textures().filter(|t| t.has_alpha())?;
        let faces = mesh
            .patches()
            .iter()
            .map(|p| {
                let tested = textures
                    .faces
                    .get(p.face as usize)
                    .and_then(Option::as_ref)
                    .is_some_and(|m| m.alpha.is_some());
                if tested { p.face } else { u32::MAX }
            })
            .collect();
        Some(AlphaTest {
            textures: Arc::clone(textures),
            faces,
            origin: mesh.origin(),
        })
    }
}

impl AlphaTest {
    /// Per input face (indexed by [`crate::Patch::face`]), whether `mesh` alpha-tests it;
    /// `None` when it tests none.
    pub(crate) fn tested_faces(mesh: &Mesh) -> Option<Vec<bool>> {
        let textures = mesh.textures().filter(|t| t.has_alpha())?;
        let mut tested = vec![false; mesh.face_count()];
        for (f, t) in tested.iter_mut().zip(&textures.faces) {
            *f = t.as_ref().is_some_and(|m| m.alpha.is_some());
        }
        Some(tested)
    }
}

impl AnyHit for AlphaTest {
    fn passes(&self, id: u32, point: Vec3, dir: Vec3) -> bool {
        let Some(&face) = self.faces.get(id as usize).filter(|&&f| f != u32::MAX) else {
            return false;
        };
        let u = coin(id, point, dir);
        let world = (point.as_dvec3() + self.origin.as_dvec3()).as_vec3();
        self.textures.passes(face, world, u)
    }
}

/// A uniform number in `[0, 1)` from the bits of a crossing (SplitMix64 finaliser over them).
fn coin(id: u32, point: Vec3, dir: Vec3) -> f32 {
    let mut h = u64::from(id) ^ 0x9e37_79b9_7f4a_7c15;
    for x in point.to_array().into_iter().chain(dir.to_array()) {
        h = mix(h ^ u64::from(x.to_bits()));
    }
    (h >> 40) as f32 / (1u64 << 24) as f32
}

/// SplitMix64's finaliser.
fn mix(mut z: u64) -> u64 {
    z = z.wrapping_add(0x9e37_79b9_7f4a_7c15);
    z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
    z ^ (z >> 31)
}

impl Mesh {
    /// The ray caster of this mesh: a [`Bvh`] over its triangles tagged with their patch
    /// indices, with the [`AlphaTest`] of its alpha-tested patches if it has any (rays pass
    /// their cut-out parts, for closest hits and occlusion alike). The back side of a
    /// two-sided face ([`crate::Patch::back`]) adds no triangles: its front's are built once
    /// and report the back's index where a ray meets them from behind
    /// ([`Bvh::with_back_sides`]).
    pub fn caster(&self) -> Result<Bvh, BuildError> {
        if !self.is_two_sided() {
            let bvh =
                Bvh::build_indexed(self.positions(), self.triangles(), self.triangle_patch())?;
            return Ok(match AlphaTest::new(self) {
                Some(test) => bvh.with_any_hit(Arc::new(test)),
                None => bvh,
            });
        }
        let patches = self.patches();
        let (mut triangles, mut ids) = (Vec::new(), Vec::new());
        for (t, &p) in self.triangles().iter().zip(self.triangle_patch()) {
            if !patches[p as usize].back {
                triangles.push(t.map(|i| self.positions()[i as usize]));
                ids.push(p);
            }
        }
        let pairs: Vec<(u32, u32)> = (1..patches.len())
            .filter(|&i| patches[i].back)
            .map(|i| (i as u32 - 1, i as u32))
            .collect();
        let bvh = Bvh::build(&triangles, &ids)?.with_back_sides(&pairs)?;
        Ok(match AlphaTest::new(self) {
            Some(test) => bvh.with_any_hit(Arc::new(test)),
            None => bvh,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn coins_are_uniform_and_differ_between_crossings() {
        let n = 20_000;
        let mut mean = 0.0f64;
        let mut below_quarter = 0;
        for i in 0..n {
            let p = Vec3::new(i as f32 * 1e-3, 0.5, 0.25);
            let u = coin(7, p, Vec3::Y);
            assert!((0.0..1.0).contains(&u));
            mean += f64::from(u) / n as f64;
            below_quarter += usize::from(u < 0.25);
        }
        // mean of uniforms: standard error 1 / sqrt(12 n) = 0.002; 5 of them
        assert!((mean - 0.5).abs() < 0.01, "{mean}");
        // binomial(n, 1/4): standard error sqrt(n 3/16) = 61; 5 of them
        assert!((below_quarter as f64 - n as f64 / 4.0).abs() < 306.0);
        assert_eq!(coin(7, Vec3::X, Vec3::Y), coin(7, Vec3::X, Vec3::Y));
        assert_ne!(coin(7, Vec3::X, Vec3::Y), coin(8, Vec3::X, Vec3::Y));
    }
}
