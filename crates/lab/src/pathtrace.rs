//! A ground truth for pictures (issue 15, item 4): an independent diffuse path tracer.
//!
//! It shares nothing with the radiosity solver but the scene's data (the mesh's patches, their
//! reflectance `rho` and emission `E`, W/m²) and the ray caster: no form factor, no radiosity
//! estimate, no mesh resolution. Every surface is Lambertian: its front emits radiance `E / π`
//! (W/(m² sr)) and reflects with the BRDF `rho / π`; a back face absorbs, unless the face is
//! two-sided and the caster is the mesh's ([`Mesh::caster`]: a ray from behind meets the back
//! side's own patch, which emits and reflects likewise).
//!
//! Pixel `(x, y)` of a `width × height` image is the mean over its box (uniform points of the
//! pixel's square) of the radiance `L` arriving at the eye, estimated by paths: at each vertex
//! the emitted radiance seen (from the camera: all of it; after a bounce: weighted by the
//! balance heuristic against light sampling), plus one light sample (an emitter triangle drawn
//! in proportion to its power `|E| A`, a uniform point `y` on it, a shadow ray), then a
//! cosine-distributed bounce with throughput `rho` and, from the fourth vertex on, Russian
//! roulette with survival probability `max_c rho_c` (throughput divided by it: unbiased). With
//! `p_L = (|E_y| / sum_k |E_k| A_k) r² / cos θ_y` and `p_C = cos θ_x / π` the densities of a
//! direction per steradian, the light sample scores `T rho (E_y / π) cos θ_x / (π (p_L + p_C))`
//! and an emitter hit after a bounce `T (E / π) p_C / (p_C + p_L)`.
//!
//! Lights without a surface (point, spot, sun: [`Light`]) cannot be hit, so each path vertex
//! samples every one of them once ([`Light::sample`], a sun's direction uniform in its cone) with
//! a shadow ray and scores `T rho / π E_l max(0, n · w_l)`: the singular part of the light, no
//! weighting needed.
//!
//! The standard error of a pixel is the sample standard deviation of its paths over
//! `sqrt(samples)`: what the image error subtracts to judge a render against this picture
//! ([`compare::image_error_against_noisy`](crate::compare::image_error_against_noisy)).
//!
//! Randomness: pixel `p` draws from `Stream::new(seed, 0, p, PATH_TAG)`, so the picture depends
//! on the seed only, not on the thread count.

use glam::{DVec3, Vec2, Vec3};
use mcrad_meshing::Mesh;
use mcrad_random::Stream;
use mcrad_raycast::{Ray, RayCaster, SurfacePoint};
use mcrad_render::{Camera, Image};
use mcrad_scene_io::Light;
use rayon::prelude::*;
use std::f64::consts::FRAC_1_PI;

/// The sub-stream tag of the path tracer's streams.
const PATH_TAG: u64 = 0x7061_7468;

/// Vertices a path always keeps before Russian roulette may end it.
const ROULETTE_AFTER: u32 = 3;

/// Settings of [`path_trace`].
#[derive(Debug, Clone, PartialEq)]
pub struct PathTraceOptions {
    /// Image width, pixels (`> 0`).
    pub width: u32,
    /// Image height, pixels (`> 0`).
    pub height: u32,
    /// Paths per pixel (`>= 2`, so that each pixel has a standard error).
    pub samples_per_pixel: u32,
    /// The seed of every random stream.
    pub seed: u64,
    /// The sky: a path that leaves the scene gains its throughput times the sky's radiance
    /// along its last direction (W/(m² sr); the sky is found by the bounces only, so that term
    /// has weight 1). `None`: escaping paths gain nothing.
    pub sky: Option<mcrad_scene_io::Sky>,
}

/// What [`path_trace`] returns.
#[derive(Debug, Clone, PartialEq)]
pub struct PathTraced {
    /// Mean radiance per pixel, W/(m² sr), linear RGB.
    pub radiance: Image,
    /// Standard error of each pixel's mean, W/(m² sr) per channel.
    pub standard_error: Image,
    /// Rays cast (camera, bounce and shadow rays).
    pub rays: u64,
}

/// Why [`path_trace`] cannot run.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum PathTraceError {
    /// The image has no pixels.
    #[error("the image must have at least one pixel, got {width} x {height}")]
    EmptyImage {
        /// Width asked.
        width: u32,
        /// Height asked.
        height: u32,
    },
    /// Fewer than two paths per pixel leave no standard error.
    #[error("at least 2 paths per pixel are needed for a standard error, got {0}")]
    TooFewSamples(u32),
}

/// The scene as the path tracer sees it.
struct Scene<'a> {
    mesh: &'a Mesh,
    /// Lights without a surface, in the mesh's frame.
    lights: &'a [Light],
    /// A distance that leaves the scene from any point in it (scene units).
    far: f64,
    /// Emitter triangles: (triangle, cumulative power share up to and including it).
    emitters: Vec<(usize, f64)>,
    triangles: Vec<[Vec3; 3]>,
    /// `sum_k |E_k| A_k` over the emitters, W/m² · units² (channel sums).
    power: f64,
    /// What an escaping path sees.
    sky: Option<&'a mcrad_scene_io::Sky>,
}

impl<'a> Scene<'a> {
    fn new(mesh: &'a Mesh, lights: &'a [Light]) -> Scene<'a> {
        let triangles = mesh.triangle_positions();
        let patches = mesh.patches();
        let mut emitters = Vec::new();
        let mut power = 0.0;
        for (t, (tri, &p)) in triangles.iter().zip(mesh.triangle_patch()).enumerate() {
            let e = channel_sum(patches[p as usize].emission.as_dvec3());
            let area = triangle_area(tri);
            if e > 0.0 && area > 0.0 {
                power += e * area;
                emitters.push((t, power));
            }
        }
        for e in &mut emitters {
            e.1 /= power;
        }
        Scene {
            mesh,
            lights,
            far: mesh.escape_distance(),
            emitters,
            triangles,
            power,
            sky: None,
        }
    }

    /// Light sampling's density per unit area at a point of patch `p`: `|E_p| / sum |E| A`.
    fn area_density(&self, p: usize) -> f64 {
        if self.power > 0.0 {
            channel_sum(self.mesh.patches()[p].emission.as_dvec3()) / self.power
        } else {
            0.0
        }
    }

    /// A point of an emitter triangle drawn in proportion to power, and its patch; `None`
    /// without emitters.
    fn sample_light(&self, rng: &mut Stream) -> Option<(Vec3, usize)> {
        let u = rng.uniform_f64();
        let k = self
            .emitters
            .partition_point(|&(_, c)| c < u)
            .min(self.emitters.len().checked_sub(1)?);
        let t = self.emitters[k].0;
        let [a, b, c] = self.triangles[t];
        let (s, r) = (rng.uniform().sqrt(), rng.uniform());
        let point = a * (1.0 - s) + b * (s * (1.0 - r)) + c * (s * r);
        Some((point, self.mesh.triangle_patch()[t] as usize))
    }
}

fn channel_sum(v: DVec3) -> f64 {
    v.x + v.y + v.z
}

fn triangle_area(t: &[Vec3; 3]) -> f64 {
    0.5 * (t[1] - t[0])
        .as_dvec3()
        .cross((t[2] - t[0]).as_dvec3())
        .length()
}

/// A cosine-distributed unit direction about `n` (Malley: a uniform disc point lifted).
fn cosine_direction(n: Vec3, rng: &mut Stream) -> Vec3 {
    let (u, v) = (rng.uniform_f64(), rng.uniform_f64());
    let r = u.sqrt();
    let phi = 2.0 * std::f64::consts::PI * v;
    let local = DVec3::new(r * phi.cos(), r * phi.sin(), (1.0 - u).max(0.0).sqrt());
    let n = n.as_dvec3();
    let a = if n.x.abs() > 0.9 { DVec3::Y } else { DVec3::X };
    let t = n.cross(a).normalize();
    let b = n.cross(t);
    (t * local.x + b * local.y + n * local.z)
        .normalize()
        .as_vec3()
}

/// Renders `mesh`, lit by its emitting patches and by `lights` (in the mesh's local frame:
/// [`Light::translated`] by `-mesh.origin()`), as seen by `camera` (in the same frame: translate
/// a world camera by [`Mesh::origin`] with [`Camera::translated`]) by diffuse path tracing (see
/// the [module documentation](self)), each pixel the mean of `samples_per_pixel` paths through
/// uniform points of its square.
///
/// Errors: an empty image, or fewer than 2 paths per pixel.
pub fn path_trace<C: RayCaster + Sync>(
    mesh: &Mesh,
    lights: &[Light],
    caster: &C,
    camera: &Camera,
    options: &PathTraceOptions,
) -> Result<PathTraced, PathTraceError> {
    let (w, h) = (options.width, options.height);
    if w == 0 || h == 0 {
        return Err(PathTraceError::EmptyImage {
            width: w,
            height: h,
        });
    }
    if options.samples_per_pixel < 2 {
        return Err(PathTraceError::TooFewSamples(options.samples_per_pixel));
    }
    let scene = Scene {
        sky: options.sky.as_ref(),
        ..Scene::new(mesh, lights)
    };
    let n = options.samples_per_pixel as f64;
    let pixels: Vec<(Vec3, Vec3, u64)> = (0..u64::from(w) * u64::from(h))
        .into_par_iter()
        .map(|p| {
            let mut rng = Stream::new(options.seed, 0, p, PATH_TAG);
            let (x, y) = ((p % u64::from(w)) as f32, (p / u64::from(w)) as f32);
            let (mut sum, mut sum2, mut rays) = (DVec3::ZERO, DVec3::ZERO, 0);
            for _ in 0..options.samples_per_pixel {
                let pixel = Vec2::new(x + rng.uniform(), y + rng.uniform());
                let l = radiance(&scene, caster, camera.ray(pixel, w, h), &mut rng, &mut rays);
                sum += l;
                sum2 += l * l;
            }
            let mean = sum / n;
            let variance = ((sum2 - sum * mean) / (n - 1.0)).max(DVec3::ZERO);
            (mean.as_vec3(), (variance / n).sqrt().as_vec3(), rays)
        })
        .collect();
    let image = |f: fn(&(Vec3, Vec3, u64)) -> Vec3| Image {
        width: w,
        height: h,
        pixels: pixels.iter().map(f).collect(),
    };
    Ok(PathTraced {
        radiance: image(|p| p.0),
        standard_error: image(|p| p.1),
        rays: pixels.iter().map(|p| p.2).sum(),
    })
}

/// One path's estimate of the radiance arriving along `ray` (W/(m² sr) per channel).
fn radiance<C: RayCaster>(
    scene: &Scene,
    caster: &C,
    mut ray: Ray,
    rng: &mut Stream,
    rays: &mut u64,
) -> DVec3 {
    let patches = scene.mesh.patches();
    let mut throughput = DVec3::ONE;
    let mut radiance = DVec3::ZERO;
    // The cosine density (per steradian) of the bounce that made `ray`; `None` for the camera.
    let mut bounce_pdf: Option<f64> = None;
    for vertex in 0.. {
        *rays += 1;
        let Some(hit) = caster.closest_hit(&ray) else {
            if let Some(sky) = scene.sky {
                radiance += throughput * sky.radiance(ray.dir.as_dvec3().normalize());
            }
            break;
        };
        if !hit.front {
            break;
        }
        let i = hit.id as usize;
        let patch = &patches[i];
        let (x, nx) = (hit.point, patch.normal);
        let e = patch.emission.as_dvec3();
        if channel_sum(e) > 0.0 {
            let weight = match bounce_pdf {
                None => 1.0,
                Some(p_c) => {
                    let d = (x - ray.origin).as_dvec3();
                    let cos_y = -ray.dir.as_dvec3().dot(nx.as_dvec3());
                    let p_l = scene.area_density(i) * d.length_squared() / cos_y.max(1e-12);
                    p_c / (p_c + p_l)
                }
            };
            radiance += throughput * e * FRAC_1_PI * weight;
        }
        let rho = patch.reflectance.as_dvec3();
        if rho.max_element() <= 0.0 {
            break;
        }
        // Light sampling.
        if let Some((y, j)) = scene.sample_light(rng).filter(|&(_, j)| j != i) {
            let d = (y - x).as_dvec3();
            let r2 = d.length_squared();
            let ny = patches[j].normal.as_dvec3();
            let (cos_x, cos_y) = if r2 > 0.0 {
                let r = r2.sqrt();
                (nx.as_dvec3().dot(d) / r, -ny.dot(d) / r)
            } else {
                (0.0, 0.0)
            };
            if cos_x > 0.0 && cos_y > 0.0 {
                *rays += 1;
                let blocked = caster.occluded(
                    &SurfacePoint::new(x, nx, i as u32),
                    &SurfacePoint::new(y, patches[j].normal, j as u32),
                );
                if !blocked {
                    let p_l = scene.area_density(j) * r2 / cos_y;
                    let p_c = cos_x * FRAC_1_PI;
                    let e_y = patches[j].emission.as_dvec3();
                    radiance +=
                        throughput * rho * e_y * (FRAC_1_PI * FRAC_1_PI * cos_x / (p_l + p_c));
                }
            }
        }
        // Lights without a surface: one shadow ray each.
        for light in scene.lights {
            let u = [rng.uniform_f64(), rng.uniform_f64()];
            let Some((e, to)) = light.arrival(x, nx, u, scene.far) else {
                continue;
            };
            *rays += 1;
            if !caster.occluded(&SurfacePoint::new(x, nx, i as u32), &SurfacePoint::free(to)) {
                radiance += throughput * rho * e * FRAC_1_PI;
            }
        }
        // The bounce: BRDF rho/π times cos over the cosine density cos/π is rho.
        let mut survive = 1.0;
        if vertex >= ROULETTE_AFTER {
            survive = rho.max_element().min(1.0);
            if rng.uniform_f64() >= survive {
                break;
            }
        }
        throughput *= rho / survive;
        let dir = cosine_direction(nx, rng);
        bounce_pdf = Some(dir.as_dvec3().dot(nx.as_dvec3()).max(0.0) * FRAC_1_PI);
        ray = Ray::from_surface(x, nx, dir, i as u32);
    }
    radiance
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::Vec3;
    use mcrad_meshing::Subdivision;
    use mcrad_raycast::Bvh;
    use mcrad_scene_io::{Face, Material, Scene as Input};

    /// A closed box of side 2 centred at the origin, inward faces, every face emitting `e` with
    /// reflectance `rho`; `light_only` makes only the ceiling emit (and reflect nothing).
    fn furnace(rho: f32, e: f32) -> Mesh {
        let positions: Vec<Vec3> = (0..8)
            .map(|k| {
                Vec3::new(
                    if k & 1 == 0 { -1.0 } else { 1.0 },
                    if k & 2 == 0 { -1.0 } else { 1.0 },
                    if k & 4 == 0 { -1.0 } else { 1.0 },
                )
            })
            .collect();
        // Counter-clockwise seen from inside the box.
        let quads = [
            [0, 1, 3, 2],
            [4, 6, 7, 5],
            [0, 4, 5, 1],
            [2, 3, 7, 6],
            [0, 2, 6, 4],
            [1, 5, 7, 3],
        ];
        let faces = quads
            .iter()
            .enumerate()
            .map(|(k, q)| Face {
                vertices: q.to_vec(),
                material: 0,
                source: k as u32,
            })
            .collect();
        let material = Material {
            name: "m".into(),
            reflectance: Vec3::splat(rho),
            emission: Vec3::splat(e),
        };
        let scene = Input::new(positions, faces, vec![material]).unwrap().0;
        Mesh::build(&scene, Subdivision::None).unwrap()
    }

    fn render(mesh: &Mesh, spp: u32, seed: u64) -> PathTraced {
        let bvh = Bvh::build(&mesh.triangle_positions(), mesh.triangle_patch()).unwrap();
        let camera = Camera::look_at(
            Vec3::new(0.1, 0.2, 0.5),
            Vec3::new(0.3, -0.2, -1.0),
            Vec3::Y,
            70.0,
        )
        .unwrap();
        let options = PathTraceOptions {
            width: 16,
            height: 12,
            samples_per_pixel: spp,
            seed,
            sky: None,
        };
        path_trace(mesh, &[], &bvh, &camera, &options).unwrap()
    }

    #[test]
    fn the_furnace_shows_its_exact_radiance_within_its_standard_errors() {
        // Every face emits E = 1 and reflects rho = 0.5 (and 0.9): L = E / (π (1 - rho))
        // everywhere. Per pixel and channel z = (L - exact) / SE: the mean of z² over 576
        // values within [0.7, 1.4] (about 6 standard deviations of it when calibrated), and the
        // image mean within 4.5 standard errors (false failures below 1e-4).
        for rho in [0.5f32, 0.9] {
            let mesh = furnace(rho, 1.0);
            let exact = FRAC_1_PI / (1.0 - rho as f64);
            let picture = render(&mesh, 64, 1);
            let (mut z2, mut sum, mut var) = (0.0, 0.0, 0.0);
            let values = picture.radiance.pixels.len() * 3;
            for (l, se) in picture
                .radiance
                .pixels
                .iter()
                .zip(&picture.standard_error.pixels)
            {
                for c in 0..3 {
                    let (l, se) = (l[c] as f64, se[c] as f64);
                    assert!(se > 0.0, "a pixel without spread");
                    z2 += ((l - exact) / se).powi(2);
                    sum += l;
                    var += se * se;
                }
            }
            let mean_z2 = z2 / values as f64;
            assert!(
                (0.7..=1.4).contains(&mean_z2),
                "rho {rho}: mean z² {mean_z2:.3}"
            );
            let mean = sum / values as f64;
            let se = var.sqrt() / values as f64;
            assert!(
                (mean - exact).abs() <= 4.5 * se,
                "rho {rho}: mean {mean:.5} against {exact:.5} ({:.1} SE)",
                (mean - exact).abs() / se
            );
        }
    }

    /// An open square `[-2, 2]²` at `z = 0` facing up, reflectance `rho`, seen from 1 above
    /// looking straight down (60°: the picture is all square), lit by `lights`.
    fn lit_ground(rho: f32, lights: &[Light], spp: u32) -> (PathTraced, Camera) {
        let positions = vec![
            Vec3::new(-2.0, -2.0, 0.0),
            Vec3::new(2.0, -2.0, 0.0),
            Vec3::new(2.0, 2.0, 0.0),
            Vec3::new(-2.0, 2.0, 0.0),
        ];
        let faces = vec![Face {
            vertices: vec![0, 1, 2, 3],
            material: 0,
            source: 0,
        }];
        let material = Material {
            name: "ground".into(),
            reflectance: Vec3::splat(rho),
            emission: Vec3::ZERO,
        };
        let scene = Input::new_lit(positions, faces, vec![material], lights.to_vec())
            .unwrap()
            .0;
        let mesh = Mesh::build(&scene, Subdivision::None).unwrap();
        let bvh = Bvh::build(&mesh.triangle_positions(), mesh.triangle_patch()).unwrap();
        let camera = Camera::look_at(Vec3::new(0.0, 0.0, 1.0), -Vec3::Z, Vec3::Y, 60.0)
            .unwrap()
            .translated(-mesh.origin().as_dvec3());
        let lights: Vec<Light> = lights
            .iter()
            .map(|l| l.translated(-mesh.origin()))
            .collect();
        let options = PathTraceOptions {
            width: 24,
            height: 24,
            samples_per_pixel: spp,
            seed: 7,
            sky: None,
        };
        (
            path_trace(&mesh, &lights, &bvh, &camera, &options).unwrap(),
            camera,
        )
    }

    #[test]
    fn the_sun_on_an_open_plane_shows_rho_e_sin_elevation_over_pi() {
        // The sun's disk (0.53°) jitters n · w by about 5e-3 of it: per pixel and channel
        // z = (L - exact) / SE, the mean z² over 1728 values within [0.7, 1.4].
        use mcrad_scene_io::Sun;
        let elevation = 40f64.to_radians();
        let sun = Light::Sun(Sun {
            direction: Vec3::new(elevation.cos() as f32, 0.0, elevation.sin() as f32),
            irradiance: DVec3::new(500.0, 600.0, 700.0),
            diameter: 0.53f64.to_radians(),
        });
        let rho = 0.4;
        let (picture, _) = lit_ground(rho, &[sun], 16);
        let exact =
            DVec3::new(500.0, 600.0, 700.0) * (f64::from(rho) * elevation.sin() * FRAC_1_PI);
        let mut z2 = 0.0;
        for (l, se) in picture
            .radiance
            .pixels
            .iter()
            .zip(&picture.standard_error.pixels)
        {
            for c in 0..3 {
                let (l, se) = (l[c] as f64, se[c] as f64);
                assert!(se > 0.0 && se < 1e-2 * exact[c], "pixel spread {se}");
                z2 += ((l - exact[c]) / se).powi(2);
            }
        }
        let mean_z2 = z2 / (3 * picture.radiance.pixels.len()) as f64;
        assert!((0.7..=1.4).contains(&mean_z2), "mean z² {mean_z2:.3}");
    }

    #[test]
    fn a_point_light_shows_its_inverse_square_law_and_a_spot_its_cone() {
        // A point light 2 above (0.3, 0.2): a ground point g shows rho I h / (pi r³); a pixel,
        // the mean of that over its box (8 x 8 points): within 4 of its standard errors (its
        // paths' spread is the box's spread of g) plus 1e-4 of it for the 64-point rule.
        use mcrad_scene_io::{PointLight, SpotLight};
        let (rho, intensity, h) = (0.5f32, 40.0, 2.0);
        let position = Vec3::new(0.3, 0.2, h as f32);
        let point = PointLight {
            position,
            intensity: DVec3::splat(intensity),
            range: None,
        };
        let (picture, camera) = lit_ground(rho, &[Light::Point(point.clone())], 16);
        let ground = |x: f32, y: f32| {
            let ray = camera.ray(Vec2::new(x, y), 24, 24);
            let t = -(ray.origin.z as f64) / ray.dir.z as f64;
            (ray.origin.as_dvec3() + ray.dir.as_dvec3() * t).truncate()
        };
        let shown = |g: glam::DVec2| {
            let d = position.as_dvec3().truncate() - g;
            let r2 = d.length_squared() + h * h;
            f64::from(rho) * intensity * h / (std::f64::consts::PI * r2 * r2.sqrt())
        };
        for y in 0..24 {
            for x in 0..24 {
                let mut exact = 0.0;
                for k in 0..64 {
                    let (u, v) = ((k % 8) as f32 + 0.5, (k / 8) as f32 + 0.5);
                    exact += shown(ground(x as f32 + u / 8.0, y as f32 + v / 8.0)) / 64.0;
                }
                let p = (y * 24 + x) as usize;
                let l = f64::from(picture.radiance.pixels[p].x);
                let se = f64::from(picture.standard_error.pixels[p].x);
                assert!(
                    (l - exact).abs() < 4.0 * se + 1e-4 * exact,
                    "pixel {x},{y}: {l} vs {exact} (se {se})"
                );
            }
        }
        let at = |x: u32, y: u32| ground(x as f32 + 0.5, y as f32 + 0.5);
        // The same light as a spot pointing down and a little along +x, outer cone 10°: the
        // ground beyond the cone's footprint is black (a pixel's box spans under 1.5°).
        let axis = Vec3::new(0.1, 0.0, -1.0).normalize();
        let spot = SpotLight {
            point,
            direction: axis,
            inner: 5f64.to_radians(),
            outer: 10f64.to_radians(),
        };
        let (picture, _) = lit_ground(rho, &[Light::Spot(spot)], 4);
        let (mut dark, mut lit) = (0, 0);
        for y in 0..24 {
            for x in 0..24 {
                let g = at(x, y).extend(0.0);
                let to = (g - position.as_dvec3()).normalize();
                let angle = to.dot(axis.as_dvec3()).clamp(-1.0, 1.0).acos();
                let l = picture.radiance.pixels[(y * 24 + x) as usize].x;
                if angle > 12f64.to_radians() {
                    assert_eq!(l, 0.0, "pixel {x},{y} beyond the cone");
                    dark += 1;
                } else if angle < 4f64.to_radians() {
                    assert!(l > 0.0, "pixel {x},{y} inside the cone");
                    lit += 1;
                }
            }
        }
        assert!(
            dark > 100 && lit > 10,
            "{dark} dark, {lit} lit pixels tested"
        );
    }

    #[test]
    fn same_seed_same_picture_and_two_seeds_differ_within_their_errors() {
        let mesh = furnace(0.5, 1.0);
        let a = render(&mesh, 8, 3);
        assert_eq!(a, render(&mesh, 8, 3));
        let b = render(&mesh, 8, 4);
        assert_ne!(a.radiance, b.radiance);
    }

    #[test]
    fn bad_options_are_errors() {
        let mesh = furnace(0.5, 1.0);
        let bvh = Bvh::build(&mesh.triangle_positions(), mesh.triangle_patch()).unwrap();
        let camera = Camera::look_at(Vec3::ZERO, Vec3::Z, Vec3::Y, 60.0).unwrap();
        let options = |width, height, samples_per_pixel| PathTraceOptions {
            width,
            height,
            samples_per_pixel,
            seed: 0,
            sky: None,
        };
        assert_eq!(
            path_trace(&mesh, &[], &bvh, &camera, &options(0, 4, 4)),
            Err(PathTraceError::EmptyImage {
                width: 0,
                height: 4
            })
        );
        assert_eq!(
            path_trace(&mesh, &[], &bvh, &camera, &options(4, 4, 1)),
            Err(PathTraceError::TooFewSamples(1))
        );
    }

    /// The 2 m square `|x|, |z| <= 1` on `y = 0` facing up, one face of material 0: its
    /// corners, the face, and a grey material of reflectance `rho` that emits nothing.
    fn square_plane(rho: f32) -> (Vec<Vec3>, Vec<Face>, Material) {
        let positions = vec![
            Vec3::new(-1.0, 0.0, -1.0),
            Vec3::new(-1.0, 0.0, 1.0),
            Vec3::new(1.0, 0.0, 1.0),
            Vec3::new(1.0, 0.0, -1.0),
        ];
        let faces = vec![Face {
            vertices: vec![0, 1, 2, 3],
            material: 0,
            source: 0,
        }];
        let material = Material {
            name: "plane".into(),
            reflectance: Vec3::splat(rho),
            emission: Vec3::ZERO,
        };
        (positions, faces, material)
    }

    /// A two-sided plane (reflectance 0.5, `y = 0`, front up) lit from below by a delta sun at
    /// 30 degrees elevation, 1000 W/m², with the mesh's caster (back sides report their own
    /// patch): seen from below, every pixel on the plane shows its back side,
    /// `rho E sin(30°) / π` exactly (one bounce, then the path escapes); seen from above, the
    /// front is dark. One-sided (the same plane without its back side), it is dark from below.
    #[test]
    fn a_two_sided_plane_shows_its_lit_back() {
        let (positions, faces, material) = square_plane(0.5);
        let el = 30f32.to_radians();
        let sun = Light::Sun(mcrad_scene_io::Sun {
            direction: Vec3::new(el.cos(), -el.sin(), 0.0),
            irradiance: DVec3::splat(1000.0),
            diameter: 0.0,
        });
        let exact = 0.5 * 1000.0 * f64::from(el.sin()) * FRAC_1_PI;
        let options = PathTraceOptions {
            width: 8,
            height: 8,
            samples_per_pixel: 4,
            seed: 1,
            sky: None,
        };
        let below = Camera::look_at(Vec3::new(0.0, -1.0, 0.0), Vec3::ZERO, Vec3::Z, 30.0).unwrap();
        let above = Camera::look_at(Vec3::new(0.0, 1.0, 0.0), Vec3::ZERO, Vec3::Z, 30.0).unwrap();
        for two_sided in [true, false] {
            let scene = Input::new_lit(
                positions.clone(),
                faces.clone(),
                vec![material.clone()],
                vec![sun.clone()],
            )
            .unwrap()
            .0
            .with_two_sided(vec![two_sided]);
            let mesh = Mesh::build(&scene, Subdivision::None).unwrap();
            let bvh = mesh.caster().unwrap();
            let lights = [sun.translated(-mesh.origin())];
            let from_below = path_trace(&mesh, &lights, &bvh, &below, &options).unwrap();
            let from_above = path_trace(&mesh, &lights, &bvh, &above, &options).unwrap();
            for (b, a) in from_below
                .radiance
                .pixels
                .iter()
                .zip(&from_above.radiance.pixels)
            {
                let expect = if two_sided { exact } else { 0.0 };
                assert!(
                    (f64::from(b.x) - expect).abs() < 1e-4 * exact,
                    "{b} vs {expect}"
                );
                assert_eq!(*a, Vec3::ZERO);
            }
        }
    }

    /// An open upward plane (reflectance 0.4, no emitter) under a uniform sky `L`: a path
    /// that hits the plane bounces once (throughput `rho`) and escapes, so each pixel on the
    /// plane is `rho L` without noise, and a pixel that misses it is `L`.
    #[test]
    fn escaping_paths_see_the_sky() {
        let l = DVec3::new(1.0, 2.0, 3.0);
        let sky = mcrad_scene_io::Sky::Uniform(l);
        let (positions, faces, material) = square_plane(0.4);
        let scene = Input::new_lit_sky(positions, faces, vec![material], vec![], Some(sky.clone()))
            .unwrap()
            .0;
        let mesh = Mesh::build(&scene, Subdivision::None).unwrap();
        let bvh = Bvh::build(&mesh.triangle_positions(), mesh.triangle_patch()).unwrap();
        // looking straight down from above: the plane fills the centre
        let camera = Camera::look_at(Vec3::new(0.0, 1.0, 0.0), Vec3::ZERO, Vec3::Z, 30.0).unwrap();
        let options = PathTraceOptions {
            width: 4,
            height: 4,
            samples_per_pixel: 4,
            seed: 1,
            sky: Some(sky),
        };
        let picture = path_trace(&mesh, &[], &bvh, &camera, &options).unwrap();
        for p in &picture.radiance.pixels {
            assert!((p.as_dvec3() - l * 0.4).abs().max_element() < 1e-6, "{p}");
        }
        // looking up: the sky itself
        let up = Camera::look_at(
            Vec3::new(0.0, 1.0, 0.0),
            Vec3::new(0.0, 2.0, 0.0),
            Vec3::Z,
            30.0,
        )
        .unwrap();
        let picture = path_trace(&mesh, &[], &bvh, &up, &options).unwrap();
        for p in &picture.radiance.pixels {
            assert!((p.as_dvec3() - l).abs().max_element() < 1e-6, "{p}");
        }
    }
}
