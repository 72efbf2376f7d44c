//! Values at every patch corner of a mesh, kept once per `(point, patch)` incidence.

use std::ops::Index;

use glam::DVec3;

#[cfg(doc)]
use crate::Mesh;

/// Per-channel values at every corner of a mesh's patches (the unit of the per-patch values
/// they were made from: W/m² for radiosity), in global corner order: corner `k` of patch `p`
/// is entry [`Mesh::corner_offset`]`(p) + k`, read as `values[corner]` or
/// [`CornerValues::get`].
///
/// The values are stored once per `(point, patch)` incidence with a 4-byte index per corner
/// (28 bytes a corner), as [`Mesh::corner_radiosity`] makes them: putting them in corner order
/// would take a second copy of the values while both are held (at 10^7 patches, 0.7 GB).
#[derive(Debug, Clone)]
pub struct CornerValues {
    /// The distinct values.
    values: Vec<DVec3>,
    /// Each corner's entry in `values`.
    of_corner: Vec<u32>,
}

impl CornerValues {
    /// One value per corner, in corner order.
    ///
    /// # Panics
    /// If there are `2^32` values or more.
    pub fn per_corner(values: Vec<DVec3>) -> CornerValues {
        let n = u32::try_from(values.len()).expect("fewer than 2^32 corners");
        CornerValues {
            values,
            of_corner: (0..n).collect(),
        }
    }

    /// `values` read through `of_corner` (each entry an index into `values`).
    pub(crate) fn shared(values: Vec<DVec3>, of_corner: Vec<u32>) -> CornerValues {
        debug_assert!(of_corner.iter().all(|&i| (i as usize) < values.len()));
        CornerValues { values, of_corner }
    }

    /// The number of corners.
    pub fn len(&self) -> usize {
        self.of_corner.len()
    }

    /// Whether there are no corners.
    pub fn is_empty(&self) -> bool {
        self.of_corner.is_empty()
    }

    /// The value at `corner`, if there is one.
    pub fn get(&self, corner: usize) -> Option<DVec3> {
        self.of_corner.get(corner).map(|&i| self.values[i as usize])
    }

    /// The values in corner order.
    pub fn iter(&self) -> impl ExactSizeIterator<Item = DVec3> + '_ {
        self.of_corner.iter().map(|&i| self.values[i as usize])
    }

    /// The first corner whose value is not finite, with its value (read in storage order
    /// first: every value is finite in a sound solution).
    pub fn first_not_finite(&self) -> Option<(usize, DVec3)> {
        if self.values.iter().all(|v| v.is_finite()) {
            return None;
        }
        self.iter().enumerate().find(|(_, v)| !v.is_finite())
    }
}

/// Equal when every corner's value is (however they are shared).
impl PartialEq for CornerValues {
    fn eq(&self, other: &CornerValues) -> bool {
        self.len() == other.len() && self.iter().eq(other.iter())
    }
}

impl Index<usize> for CornerValues {
    type Output = DVec3;

    /// The value at `corner`.
    ///
    /// # Panics
    /// If `corner >= self.len()`.
    fn index(&self, corner: usize) -> &DVec3 {
        &self.values[self.of_corner[corner] as usize]
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn corners_read_their_shared_values_in_corner_order() {
        let shared = CornerValues::shared(vec![DVec3::ONE, DVec3::splat(2.0)], vec![1, 0, 1]);
        let want = [DVec3::splat(2.0), DVec3::ONE, DVec3::splat(2.0)];
        assert_eq!(shared.len(), 3);
        assert_eq!(shared.iter().collect::<Vec<_>>(), want);
        assert_eq!((0..3).map(|c| shared[c]).collect::<Vec<_>>(), want);
        assert_eq!(shared.get(3), None);
        let own = CornerValues::per_corner(want.to_vec());
        assert_eq!(own.iter().collect::<Vec<_>>(), want);
        assert_eq!(own.get(1), Some(DVec3::ONE));
        assert_eq!(shared.first_not_finite(), None);
        let nan = CornerValues::shared(vec![DVec3::ONE, DVec3::NAN], vec![0, 1, 1]);
        let (corner, value) = nan.first_not_finite().unwrap();
        assert!(corner == 1 && value.is_nan());
    }
}
