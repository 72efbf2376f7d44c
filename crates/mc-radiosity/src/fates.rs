//! Where rays leaving patches end: in the void, or absorbed where they land.

use crate::surface::SurfaceSampler;
use mcrad_meshing::Mesh;
use mcrad_random::StreamKey;
use mcrad_raycast::RayCaster;
use rayon::prelude::*;

/// What the cosine-distributed rays of [`ray_fates`] met first, counted per patch: the
/// fractions estimate, for the light a patch sends out, the share that leaves the scene and the
/// share that is absorbed where it lands without being reflected.
#[derive(Debug, Clone, PartialEq)]
pub struct RayFates {
    /// Per patch: rays cast.
    pub rays: Vec<u32>,
    /// Per patch: rays that hit nothing (left the scene).
    pub escaped: Vec<u32>,
    /// Per patch and RGB channel: rays whose first hit is a back face (absorbed) or the front
    /// of a patch of reflectance 0 in the channel.
    pub sunk: Vec<[u32; 3]>,
}

/// Casts `rays[i]` cosine-distributed rays from uniform points of each patch `i` (one value per
/// patch) and counts where they end. Streams keyed by `seed` and the patch: deterministic on
/// any thread count.
pub fn ray_fates<C: RayCaster>(mesh: &Mesh, caster: &C, rays: Vec<u32>, seed: u64) -> RayFates {
    let sampler = SurfaceSampler::new(mesh);
    let key = StreamKey::new(seed);
    let black: Vec<[bool; 3]> = mesh
        .patches()
        .iter()
        .map(|p| p.reflectance.to_array().map(|r| r == 0.0))
        .collect();
    let seen: Vec<(u32, [u32; 3])> = (0..rays.len())
        .into_par_iter()
        .map(|i| {
            let mut rng = key.item(i as u64).stream();
            let (mut escaped, mut sunk) = (0u32, [0u32; 3]);
            for _ in 0..rays[i] {
                match caster.closest_hit(&sampler.ray(i, &mut rng)) {
                    None => escaped += 1,
                    Some(h) if !h.front => sunk.iter_mut().for_each(|s| *s += 1),
                    Some(h) => {
                        for (s, &dark) in sunk.iter_mut().zip(&black[h.id as usize]) {
                            *s += u32::from(dark);
                        }
                    }
                }
            }
            (escaped, sunk)
        })
        .collect();
    let (escaped, sunk) = seen.into_iter().unzip();
    RayFates {
        rays,
        escaped,
        sunk,
    }
}
