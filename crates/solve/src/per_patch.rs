//! Values per patch that patches may share: the method's estimate per element of transport
//! ([`crate::Clustering::Transport`]), kept once per element instead of once per member.

use glam::DVec3;
use std::sync::Arc;

/// A value per patch of a mesh (mesh order), each kept once per element its patches share.
///
/// Invariant: every index of the sharing map is below the number of values.
#[derive(Debug, Clone, PartialEq)]
pub struct PerPatch {
    values: Vec<DVec3>,
    /// Patch `i`'s value is `values[of_patch[i]]`; without it, `values[i]`.
    of_patch: Option<Arc<Vec<u32>>>,
}

impl PerPatch {
    /// One value per patch: patch `i`'s is `values[i]`.
    pub fn new(values: Vec<DVec3>) -> Self {
        Self {
            values,
            of_patch: None,
        }
    }

    /// Values shared between patches: patch `i`'s is `values[of_patch[i]]`. `None` when an
    /// index is out of range.
    pub fn shared(values: Vec<DVec3>, of_patch: Arc<Vec<u32>>) -> Option<Self> {
        of_patch
            .iter()
            .all(|&e| (e as usize) < values.len())
            .then_some(Self {
                values,
                of_patch: Some(of_patch),
            })
    }

    /// The number of patches.
    pub fn len(&self) -> usize {
        self.of_patch
            .as_ref()
            .map_or(self.values.len(), |m| m.len())
    }

    /// Whether there is no patch.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Patch `i`'s value (`i < len()`).
    pub fn get(&self, i: usize) -> DVec3 {
        match &self.of_patch {
            Some(m) => self.values[m[i] as usize],
            None => self.values[i],
        }
    }

    /// Each patch's value, in mesh order.
    pub fn iter(&self) -> impl ExactSizeIterator<Item = DVec3> + '_ {
        (0..self.len()).map(|i| self.get(i))
    }

    /// One value per patch, in mesh order (made only where the values are shared).
    pub fn into_vec(self) -> Vec<DVec3> {
        match self.of_patch {
            Some(_) => self.iter().collect(),
            None => self.values,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn shared_values_read_as_one_per_patch() {
        let values = vec![DVec3::X, DVec3::Y];
        let shared = PerPatch::shared(values.clone(), Arc::new(vec![1, 0, 1])).unwrap();
        assert_eq!(shared.len(), 3);
        assert_eq!(shared.get(2), DVec3::Y);
        assert_eq!(
            shared.clone().into_vec(),
            vec![DVec3::Y, DVec3::X, DVec3::Y]
        );
        assert_eq!(shared.iter().len(), 3);
        let own = PerPatch::new(values.clone());
        assert_eq!((own.len(), own.get(1)), (2, DVec3::Y));
        assert_eq!(own.into_vec(), values);
        assert!(PerPatch::shared(values, Arc::new(vec![2])).is_none());
    }
}
