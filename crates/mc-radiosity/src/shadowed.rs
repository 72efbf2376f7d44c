//! Groups of patches split where the direct light's visibility changes across them: what a
//! cluster of small faces that shares one irradiance ([`mcrad_meshing::Mesh::clustered`]) must
//! not straddle.
//!
//! A group is tested as an element of the refinement is (the visibility mark of
//! [`refine`](crate::refine)): `rays` points of the group, at most 4 a member (a member drawn
//! by area, stratified along the members' centroids' longest extent so that a shadow over more
//! than `1 / rays` of the group is seen; a uniform point on it, its own normal), from each a
//! shadow ray to a point of the emitters drawn by power, one to each light without a surface
//! (point, spot, sun) and one cosine-distributed ray towards the sky where there is one. The
//! group's direct light that varies, `rho D min(f, 1 - f)` (`D` the unoccluded direct
//! irradiance estimate, `f` its visible share, `rho` the members' area-weighted mean
//! reflectance), is compared with `tolerance` of its luminance (from `radiosity`, the
//! area-weighted mean of its members'). A group over it is cut in two at the median of its
//! members' centroids along their longest extent, and each half is tested again, down to
//! single patches or to groups smaller than [`ShadowSplit::min_span`]. A group that sees part
//! of the sky from everywhere is split too (the test does not tell a change across the group
//! from an even partial view): measured on the sun- and sky-lit atrium, testing the sky's
//! change between the group's halves instead kept a third fewer elements but raised the image
//! error (docs/meshing.md).

use glam::DVec3;
use mcrad_meshing::{Clusters, Mesh, UNGROUPED};
use mcrad_random::Stream;
use mcrad_raycast::{RayCaster, SurfacePoint};
use mcrad_scene_io::{Light, Sky};
use rayon::prelude::*;

use crate::adaptive::{Lights, luminance, point_on};

/// The stream tag of the shadow rays of [`split_shadowed`].
const SPLIT_TAG: u64 = 0xada5_0000;

/// Settings of [`split_shadowed`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ShadowSplit {
    /// Points per test of a group (`>= 1`; at most 4 a member), each with its shadow rays.
    pub rays: u32,
    /// The share of a group's luminance that its varying direct light must exceed to split it
    /// (`>= 0`; the refinement's 2%).
    pub tolerance: f64,
    /// The seed of the shadow rays' streams, keyed by group and place in the splits.
    pub seed: u64,
    /// A group whose members span less than this ([`Clusters::span`], scene units, `>= 0`) is
    /// not tested or split: twice the refinement's smallest edge, so that a group is cut no
    /// finer than a large face would be, whatever its faces' tessellation.
    pub min_span: f64,
}

/// Splits the groups of `mesh`'s patches (`group[i]`: patch `i`'s group, or [`UNGROUPED`])
/// across which the direct light of its emitters, of `lights` (in the scene's frame) and of the
/// `sky` changes
/// visibility (see the module documentation), casting through `caster` (over `mesh`);
/// `radiosity` per patch (W/m²) gives each group's luminance. Renumbers the groups (in order of
/// their first appearance, each half after the other) and returns the splits made. The same on
/// any thread count.
pub fn split_shadowed<C: RayCaster>(
    mesh: &Mesh,
    caster: &C,
    lights: &[Light],
    sky: Option<&Sky>,
    radiosity: &[DVec3],
    group: &mut [u32],
    split: ShadowSplit,
) -> usize {
    let groups = Clusters::from_groups(group, |_| true);
    let probe = Probe {
        mesh,
        caster,
        emitters: Lights::new(mesh),
        lights: lights
            .iter()
            .map(|l| l.translated(-mesh.origin()))
            .collect(),
        sky: sky.filter(|s| !s.is_dark()),
        far: mesh.escape_distance(),
        radiosity,
        split,
    };
    let leaves: Vec<(Vec<Vec<u32>>, usize)> = (0..groups.len())
        .into_par_iter()
        .map(|k| {
            let mut m = groups.get(k).to_vec();
            // the streams keyed by the group's own number
            let g = u64::from(group[m[0] as usize]);
            let mut out = Vec::new();
            let splits = probe.settle(&mut m, g, 1, &mut out);
            (out, splits)
        })
        .collect();
    group.fill(UNGROUPED);
    let (mut next, mut splits) = (0u32, 0);
    for (parts, s) in leaves {
        splits += s;
        for part in parts.iter().filter(|p| p.len() >= 2) {
            for &i in part {
                group[i as usize] = next;
            }
            next += 1;
        }
    }
    splits
}

/// What the tests of [`split_shadowed`] share.
struct Probe<'a, C> {
    mesh: &'a Mesh,
    caster: &'a C,
    emitters: Option<Lights>,
    /// The lights without a surface, in the mesh's frame.
    lights: Vec<Light>,
    sky: Option<&'a Sky>,
    far: f64,
    radiosity: &'a [DVec3],
    split: ShadowSplit,
}

impl<C: RayCaster> Probe<'_, C> {
    /// Tests `members` of group `g` (at `path` in its splits: 1 for the whole, `2 p` and
    /// `2 p + 1` for the halves of `p`), pushes the parts it keeps onto `out`, and returns the
    /// splits made.
    fn settle(&self, members: &mut [u32], g: u64, path: u64, out: &mut Vec<Vec<u32>>) -> usize {
        if members.len() < 2 {
            out.push(members.to_vec());
            return 0;
        }
        // along the centroids' longest extent: the test's points are stratified in this
        // order, and a split cuts it at the median
        Clusters::sort_along_extent(self.mesh, members);
        if path >= 1 << 62
            || Clusters::span(self.mesh, members) < self.split.min_span
            || !self.shadowed(members, g, path)
        {
            out.push(members.to_vec());
            return 0;
        }
        let (left, right) = members.split_at_mut(members.len() / 2);
        1 + self.settle(left, g, 2 * path, out) + self.settle(right, g, 2 * path + 1, out)
    }

    /// Whether the direct light's visibility changes across `members` beyond the tolerance.
    fn shadowed(&self, members: &[u32], g: u64, path: u64) -> bool {
        let patches = self.mesh.patches();
        let mut rng = Stream::new(self.split.seed, SPLIT_TAG, g, path);
        // members drawn by area; the group's reflectance and luminance, area-weighted
        let mut cumulative = Vec::with_capacity(members.len());
        let (mut area, mut rho, mut lum) = (0.0, 0.0, 0.0);
        for &i in members {
            let p = &patches[i as usize];
            area += p.area;
            rho += luminance(p.reflectance.as_dvec3()) * p.area;
            lum += luminance(self.radiosity[i as usize]) * p.area;
            cumulative.push(area);
        }
        if area <= 0.0 || rho <= 0.0 {
            return false;
        }
        let (rho, lum) = (rho / area, lum / area);
        let (mut all, mut visible, mut seen, mut blocked) = (0.0, 0.0, 0u32, 0u32);
        let mut shade = |g: f64, occluded: bool| {
            all += g;
            if occluded {
                blocked += 1;
            } else {
                visible += g;
                seen += 1;
            }
        };
        // at most 4 points a member: stratified, they cover every member of a small group
        let rays = self
            .split
            .rays
            .min(u32::try_from(4 * members.len()).unwrap_or(u32::MAX))
            .max(1);
        for point in 0..rays {
            // stratified along the members' order
            let u = (f64::from(point) + rng.uniform_f64()) / f64::from(rays) * area;
            let k = cumulative
                .partition_point(|&c| c <= u)
                .min(members.len() - 1);
            let i = members[k] as usize;
            let p = &patches[i];
            let x = point_on(self.mesh, i, &mut rng);
            let from = SurfacePoint::new(x, p.normal, i as u32);
            if let Some(emitters) = &self.emitters {
                let (light, probability) = emitters.draw(self.mesh, rng.uniform_f64());
                let y = point_on(self.mesh, light, &mut rng);
                let l = &patches[light];
                let d = (y - x).as_dvec3();
                let r2 = d.length_squared();
                if light != i && r2 > 0.0 {
                    let w = d / r2.sqrt();
                    let (cx, cy) = (p.normal.as_dvec3().dot(w), -l.normal.as_dvec3().dot(w));
                    if cx > 0.0 && cy > 0.0 {
                        // irradiance of this sample: E_l cos cos / (pi r²) / (p_l / A_l)
                        let g = luminance(l.emission.as_dvec3()) * cx * cy
                            / (std::f64::consts::PI * r2)
                            * l.area
                            / probability;
                        let to = SurfacePoint::new(y, l.normal, light as u32);
                        shade(g, self.caster.occluded(&from, &to));
                    }
                }
            }
            for light in &self.lights {
                let u = [rng.uniform_f64(), rng.uniform_f64()];
                if let Some((e, target)) = light.arrival(x, p.normal, u, self.far) {
                    let occluded = self.caster.occluded(&from, &SurfacePoint::free(target));
                    shade(luminance(e), occluded);
                }
            }
            if let Some(sky) = self.sky {
                // a cosine direction: its irradiance estimate pi L(w) where it leaves the scene
                let n = p.normal.as_dvec3();
                let (t, b) = n.any_orthonormal_pair();
                let r = rng.uniform_f64().sqrt();
                let phi = std::f64::consts::TAU * rng.uniform_f64();
                let z = (1.0 - r * r).max(0.0).sqrt();
                let w = (t * (r * phi.cos()) + b * (r * phi.sin()) + n * z).normalize();
                let target = (x.as_dvec3() + w * self.far).as_vec3();
                let occluded = self.caster.occluded(&from, &SurfacePoint::free(target));
                shade(std::f64::consts::PI * luminance(sky.radiance(w)), occluded);
            }
        }
        if seen == 0 || blocked == 0 || all <= 0.0 {
            return false;
        }
        let f = visible / all;
        let direct = rho * all / f64::from(rays);
        direct * f.min(1.0 - f) > self.split.tolerance * lum.max(1e-300)
    }
}
