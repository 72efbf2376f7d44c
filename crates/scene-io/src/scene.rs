//! The validated scene: positions, polygon faces and materials.

use crate::error::{SceneError, Warning};
use glam::Vec3;

/// A diffuse material.
#[derive(Debug, Clone, PartialEq)]
pub struct Material {
    /// Name from the input file (MTL `newmtl`, glTF material name or `material<N>`).
    pub name: String,
    /// Diffuse reflectance `rho` per RGB channel; invariant: each channel in `[0, 1)`.
    pub reflectance: Vec3,
    /// Emitted radiosity `E` per RGB channel in W/m² (exitance, `E = pi * L`); invariant: finite, `>= 0`.
    pub emission: Vec3,
}

/// One planar polygon face of the input, vertices counter-clockwise seen from its front side.
#[derive(Debug, Clone, PartialEq)]
pub struct Face {
    /// Indices into [`Scene::positions`], at least 3, counter-clockwise from the front.
    pub vertices: Vec<u32>,
    /// Index into [`Scene::materials`].
    pub material: u32,
    /// The face's number in the input: OBJ faces in file order over all objects, glTF triangles
    /// over primitives in document order. Kept when degenerate faces before it are dropped.
    pub source: u32,
}

/// A validated scene. Invariants (checked by [`Scene::new`]): at least one face; every position
/// finite; every face has >= 3 in-range vertex indices and a non-zero area; every material index
/// in range; every reflectance in `[0,1)`; every emission finite and `>= 0`; some face emits.
#[derive(Debug, Clone, PartialEq)]
pub struct Scene {
    positions: Vec<Vec3>,
    faces: Vec<Face>,
    materials: Vec<Material>,
}

impl Scene {
    /// Validates and builds a scene. Zero-area faces are dropped and reported in the returned
    /// warnings (counted); every other violation of the invariants is an error.
    pub fn new(
        positions: Vec<Vec3>,
        faces: Vec<Face>,
        materials: Vec<Material>,
    ) -> Result<(Scene, Vec<Warning>), SceneError> {
        todo!("helper implements")
    }
    /// Vertex positions in scene units.
    pub fn positions(&self) -> &[Vec3] {
        &self.positions
    }
    /// The faces, in input order (degenerate ones removed).
    pub fn faces(&self) -> &[Face] {
        &self.faces
    }
    /// The materials.
    pub fn materials(&self) -> &[Material] {
        &self.materials
    }
}
