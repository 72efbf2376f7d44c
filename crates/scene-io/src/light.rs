//! Singular emitters: lights without a surface (glTF `KHR_lights_punctual` point, spot and
//! directional lights, and the sun), in radiometric units.
//!
//! A light is sampled from a receiving point: [`Light::sample`] gives the direction towards
//! the light, its distance and the irradiance it would give a surface facing that direction,
//! so a point with unit normal `n` receives `E = irradiance * max(0, n · direction)` (W/m²)
//! when nothing blocks the segment (an expected value over `u` for a sun of finite size). An
//! environment light fits the same interface later (a direction sampled by its pdf, infinite
//! distance).

use glam::{DVec3, Vec3};

/// The luminous efficacy of the photometric units of glTF lights by default: 683 lm/W, the
/// factor Blender's glTF exporter uses (`PBR_WATTS_TO_LUMENS`), so a point light of `I` cd
/// radiates `I / 683` W/sr and a directional light of `E_v` lux gives `E_v / 683` W/m².
pub const DEFAULT_LIGHT_EFFICACY: f64 = 683.0;

/// The sun's angular diameter by default: 0.53 degrees (as radians).
pub const DEFAULT_SUN_DIAMETER: f64 = 0.53 * std::f64::consts::PI / 180.0;

/// A light without a surface, in the scene's frame and radiometric units (RGB per channel).
#[derive(Debug, Clone, PartialEq)]
pub enum Light {
    /// An isotropic point light.
    Point(PointLight),
    /// A spot light: a point light limited to a cone, with the glTF smooth falloff.
    Spot(SpotLight),
    /// A distant light (the sun, a glTF directional light): parallel rays within a cone.
    Sun(Sun),
}

/// An isotropic point light at `position` with radiant intensity `intensity` (W/sr per
/// channel): a surface at distance `d` facing it receives `intensity * window(d) / d²` W/m²,
/// with the glTF `range` window `window(d) = clamp(1 - (d / range)^4, 0, 1)` (1 without a
/// range).
#[derive(Debug, Clone, PartialEq)]
pub struct PointLight {
    /// Position (scene units, the scene's frame).
    pub position: Vec3,
    /// Radiant intensity, W/sr per channel (`>= 0`).
    pub intensity: DVec3,
    /// The distance beyond which the light is zero (scene units, `> 0`); `None`: unlimited.
    pub range: Option<f64>,
}

/// A spot light: a [`PointLight`] shining along `direction` whose intensity at angle `theta`
/// from its axis is `intensity * f(cos theta)`, with the glTF reference falloff
/// `f = saturate((cos theta - cos outer) / (cos inner - cos outer))²`: 1 within the inner cone,
/// 0 beyond the outer one.
#[derive(Debug, Clone, PartialEq)]
pub struct SpotLight {
    /// The point light at the apex (position, intensity on the axis in W/sr, range).
    pub point: PointLight,
    /// Unit direction the spot shines along.
    pub direction: Vec3,
    /// Half-angle of the inner cone (radians, `0 <= inner < outer`).
    pub inner: f64,
    /// Half-angle of the outer cone (radians, `outer <= pi / 2`).
    pub outer: f64,
}

/// A distant light: the sun, or a glTF directional light.
#[derive(Debug, Clone, PartialEq)]
pub struct Sun {
    /// Unit direction towards the light.
    pub direction: Vec3,
    /// Irradiance on a surface facing the light, W/m² per channel (`>= 0`).
    pub irradiance: DVec3,
    /// Angular diameter of the light's disk (radians, in `[0, pi / 2)`); 0 is a single
    /// direction.
    pub diameter: f64,
}

/// One sample of a light seen from a receiving point (see [`Light::sample`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LightSample {
    /// Unit direction from the receiving point towards the light.
    pub direction: DVec3,
    /// Distance to the light (scene units); infinite for a [`Sun`].
    pub distance: f64,
    /// Irradiance on a surface at the point facing `direction`, W/m² per channel: the point
    /// with unit normal `n` receives `irradiance * max(0, n · direction)` when unoccluded.
    pub irradiance: DVec3,
}

impl PointLight {
    /// The `range` window `clamp(1 - (d / range)^4, 0, 1)` at distance `d`.
    pub fn window(&self, d: f64) -> f64 {
        match self.range {
            Some(r) => (1.0 - (d / r).powi(4)).clamp(0.0, 1.0),
            None => 1.0,
        }
    }
}

impl std::str::FromStr for Sun {
    type Err = String;

    /// `X,Y,Z,E[,DIAM]`: the direction towards the sun (any non-zero length), the irradiance
    /// `E >= 0` (W/m², all channels) on a surface facing it, and the angular diameter in
    /// degrees in `[0, 90)` (0.53 by default; 0 is a single direction). The error says which
    /// part is wrong.
    fn from_str(s: &str) -> Result<Sun, String> {
        let usage = || format!("'{s}' is not X,Y,Z,E[,DIAM] (direction, W/m², degrees)");
        let parts: Vec<f64> = s
            .split(',')
            .map(|x| x.trim().parse::<f64>())
            .collect::<Result<_, _>>()
            .map_err(|_| usage())?;
        if !(parts.len() == 4 || parts.len() == 5) || parts.iter().any(|x| !x.is_finite()) {
            return Err(usage());
        }
        let direction = DVec3::new(parts[0], parts[1], parts[2]);
        if direction.length() == 0.0 {
            return Err(format!("'{s}': the direction towards the sun is zero"));
        }
        if parts[3] < 0.0 {
            return Err(format!(
                "'{s}': the irradiance {} W/m² is negative",
                parts[3]
            ));
        }
        let degrees = parts.get(4).copied().unwrap_or(0.53);
        if !(0.0..90.0).contains(&degrees) {
            return Err(format!(
                "'{s}': the angular diameter {degrees} degrees is not in [0, 90)"
            ));
        }
        Ok(Sun {
            direction: direction.normalize().as_vec3(),
            irradiance: DVec3::splat(parts[3]),
            diameter: degrees.to_radians(),
        })
    }
}

impl SpotLight {
    /// The angular falloff `f(cos theta)` (see [`SpotLight`]), in `[0, 1]`.
    pub fn falloff(&self, cos_theta: f64) -> f64 {
        let (ci, co) = (self.inner.cos(), self.outer.cos());
        let scale = 1.0 / (ci - co).max(1e-3);
        let f = ((cos_theta - co) * scale).clamp(0.0, 1.0);
        f * f
    }
}

impl Light {
    /// The light sampled from `point` (the scene's frame) with the uniform numbers `u` in
    /// `[0, 1)²` (used by a sun of finite size only: a direction uniform in its cone, scaled
    /// so that a surface facing the sun's centre receives exactly its irradiance on average).
    /// `None` when the light gives nothing there (beyond the range or the spot's cone, or at
    /// the light's own position).
    pub fn sample(&self, point: Vec3, u: [f64; 2]) -> Option<LightSample> {
        match self {
            Light::Point(p) => point_sample(p, point, 1.0),
            Light::Spot(s) => {
                let to = (s.point.position - point).as_dvec3();
                let cos = -to.normalize_or_zero().dot(s.direction.as_dvec3());
                let f = s.falloff(cos);
                if f <= 0.0 {
                    return None;
                }
                point_sample(&s.point, point, f)
            }
            Light::Sun(s) => {
                let axis = s.direction.as_dvec3().normalize();
                let half = 0.5 * s.diameter;
                if half <= 0.0 {
                    return Some(LightSample {
                        direction: axis,
                        distance: f64::INFINITY,
                        irradiance: s.irradiance,
                    });
                }
                // Uniform in the cone's solid angle: cos theta uniform in [cos half, 1].
                let cos_max = half.cos();
                let cos = 1.0 - u[0] * (1.0 - cos_max);
                let sin = (1.0 - cos * cos).max(0.0).sqrt();
                let phi = std::f64::consts::TAU * u[1];
                let (t, b) = axis.any_orthonormal_pair();
                let direction = (axis * cos + (t * phi.cos() + b * phi.sin()) * sin).normalize();
                // The mean of cos over the cone is (1 + cos half) / 2: divided out, a surface
                // facing the axis receives the irradiance exactly.
                let scale = 2.0 / (1.0 + cos_max);
                Some(LightSample {
                    direction,
                    distance: f64::INFINITY,
                    irradiance: s.irradiance * scale,
                })
            }
        }
    }

    /// The irradiance `E max(0, n · w)` (W/m² per channel) the light gives a point `x` with unit
    /// normal `n` when nothing blocks it, drawn with `u` as [`Light::sample`] draws, and where
    /// that point's shadow ray ends: at the light, or for a sun `far` scene units away towards
    /// it. `None` where the light gives nothing there (behind the surface, beyond its range or
    /// cone).
    pub fn arrival(&self, x: Vec3, n: Vec3, u: [f64; 2], far: f64) -> Option<(DVec3, Vec3)> {
        let s = self.sample(x, u)?;
        let cos = n.as_dvec3().dot(s.direction);
        if cos <= 0.0 {
            return None;
        }
        let reach = if s.distance.is_finite() {
            s.distance
        } else {
            far
        };
        Some((
            s.irradiance * cos,
            (x.as_dvec3() + s.direction * reach).as_vec3(),
        ))
    }

    /// The radiant power the light emits (W per channel): `4 pi I` for a point light (its
    /// range window ignored), `2 pi I ((1 - cos inner) + (cos inner - cos outer) / 3)` for a
    /// spot light; `None` for a sun (its power depends on the area it falls on).
    pub fn power(&self) -> Option<DVec3> {
        use std::f64::consts::{PI, TAU};
        match self {
            Light::Point(p) => Some(p.intensity * 4.0 * PI),
            Light::Spot(s) => {
                let (ci, co) = (s.inner.cos(), s.outer.cos());
                Some(s.point.intensity * TAU * ((1.0 - ci) + (ci - co) / 3.0))
            }
            Light::Sun(_) => None,
        }
    }

    /// The light moved by `offset` (a sun, at infinity, is unchanged).
    pub fn translated(&self, offset: Vec3) -> Light {
        let mut light = self.clone();
        match &mut light {
            Light::Point(p) => p.position += offset,
            Light::Spot(s) => s.point.position += offset,
            Light::Sun(_) => {}
        }
        light
    }

    /// A short name of the kind: `point`, `spot` or `sun`.
    pub fn kind(&self) -> &'static str {
        match self {
            Light::Point(_) => "point",
            Light::Spot(_) => "spot",
            Light::Sun(_) => "sun",
        }
    }

    /// `Err(reason)` when a value is out of its documented range (non-finite position or
    /// direction, negative or non-finite intensity, range not positive, cones out of order).
    pub fn check(&self) -> Result<(), String> {
        let colour = |c: DVec3, what: &str| {
            if c.is_finite() && c.min_element() >= 0.0 {
                Ok(())
            } else {
                Err(format!("{what} {c} is negative or not finite"))
            }
        };
        let point = |p: &PointLight| {
            if !p.position.is_finite() {
                return Err(format!("position {} is not finite", p.position));
            }
            if let Some(r) = p.range
                && !(r > 0.0 && r.is_finite())
            {
                return Err(format!("range {r} is not positive"));
            }
            colour(p.intensity, "intensity")
        };
        let direction = |d: Vec3| {
            if d.is_finite() && d.length() > 0.0 {
                Ok(())
            } else {
                Err(format!("direction {d} is zero or not finite"))
            }
        };
        match self {
            Light::Point(p) => point(p),
            Light::Spot(s) => {
                point(&s.point)?;
                direction(s.direction)?;
                let right = std::f64::consts::FRAC_PI_2;
                if !(s.inner >= 0.0 && s.inner < s.outer && s.outer <= right) {
                    return Err(format!(
                        "cone angles inner {} and outer {} are not 0 <= inner < outer <= pi/2",
                        s.inner, s.outer
                    ));
                }
                Ok(())
            }
            Light::Sun(s) => {
                direction(s.direction)?;
                if !(s.diameter >= 0.0 && s.diameter < std::f64::consts::FRAC_PI_2) {
                    return Err(format!(
                        "angular diameter {} rad is not in [0, pi/2)",
                        s.diameter
                    ));
                }
                colour(s.irradiance, "irradiance")
            }
        }
    }
}

/// The point light's sample at `point`, its intensity times `factor` (a spot's falloff).
fn point_sample(p: &PointLight, point: Vec3, factor: f64) -> Option<LightSample> {
    let to = (p.position - point).as_dvec3();
    let d2 = to.length_squared();
    if d2 <= 0.0 {
        return None;
    }
    let d = d2.sqrt();
    let window = p.window(d);
    if window <= 0.0 {
        return None;
    }
    Some(LightSample {
        direction: to / d,
        distance: d,
        irradiance: p.intensity * (factor * window / d2),
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::f64::consts::PI;

    fn spot() -> SpotLight {
        SpotLight {
            point: PointLight {
                position: Vec3::new(0.0, 0.0, 2.0),
                intensity: DVec3::splat(8.0),
                range: None,
            },
            direction: Vec3::NEG_Z,
            inner: 0.2,
            outer: 0.4,
        }
    }

    #[test]
    fn a_point_light_follows_the_inverse_square_law_and_its_range_window() {
        let mut p = PointLight {
            position: Vec3::new(0.0, 0.0, 3.0),
            intensity: DVec3::new(9.0, 18.0, 0.0),
            range: None,
        };
        let s = Light::Point(p.clone())
            .sample(Vec3::ZERO, [0.5; 2])
            .unwrap();
        assert_eq!(s.direction, DVec3::Z);
        assert!(
            (s.irradiance - DVec3::new(1.0, 2.0, 0.0))
                .abs()
                .max_element()
                < 1e-12
        );
        p.range = Some(6.0);
        let s = Light::Point(p.clone())
            .sample(Vec3::ZERO, [0.5; 2])
            .unwrap();
        assert!((s.irradiance.x - (1.0 - 0.5f64.powi(4))).abs() < 1e-12);
        p.range = Some(3.0);
        assert!(Light::Point(p).sample(Vec3::ZERO, [0.5; 2]).is_none());
    }

    #[test]
    fn a_spot_gives_its_intensity_on_the_axis_and_nothing_beyond_the_outer_cone() {
        let light = Light::Spot(spot());
        // On the axis at h = 2: I / h².
        let s = light.sample(Vec3::ZERO, [0.5; 2]).unwrap();
        assert!((s.irradiance.x - 2.0).abs() < 1e-12);
        // Beyond the outer cone (tan 0.4 * 2 = 0.85): nothing.
        assert!(light.sample(Vec3::new(0.9, 0.0, 0.0), [0.5; 2]).is_none());
        // Half-way between the cones in cos: a quarter.
        let sp = spot();
        let mid = 0.5 * (sp.inner.cos() + sp.outer.cos());
        assert!((sp.falloff(mid) - 0.25).abs() < 1e-12);
    }

    #[test]
    fn a_spot_power_is_its_falloff_integrated_over_the_sphere() {
        let sp = spot();
        let n = 200_000;
        let (co, sum) = (sp.outer.cos(), {
            let co = sp.outer.cos();
            (0..n)
                .map(|k| {
                    let mu = co + (1.0 - co) * (k as f64 + 0.5) / n as f64;
                    sp.falloff(mu)
                })
                .sum::<f64>()
        });
        let numeric = 2.0 * PI * (1.0 - co) * sum / n as f64 * 8.0;
        let power = Light::Spot(sp).power().unwrap();
        assert!(
            (power.x - numeric).abs() < 1e-6 * numeric,
            "{power} {numeric}"
        );
    }

    #[test]
    fn a_sun_of_finite_size_gives_its_irradiance_to_a_surface_facing_it() {
        let sun = Light::Sun(Sun {
            direction: Vec3::new(0.0, 1.0, 1.0),
            irradiance: DVec3::splat(100.0),
            diameter: 0.3,
        });
        let axis = DVec3::new(0.0, 1.0, 1.0).normalize();
        let n = 400;
        let mut mean = 0.0;
        for i in 0..n {
            for j in 0..n {
                let u = [(i as f64 + 0.5) / n as f64, (j as f64 + 0.5) / n as f64];
                let s = sun.sample(Vec3::ZERO, u).unwrap();
                assert!(s.direction.dot(axis) >= (0.15f64).cos() - 1e-12);
                mean += s.irradiance.x * s.direction.dot(axis);
            }
        }
        mean /= (n * n) as f64;
        assert!((mean - 100.0).abs() < 1e-6, "{mean}");
    }

    #[test]
    fn bad_values_are_refused() {
        let mut sp = spot();
        sp.inner = 0.5;
        assert!(Light::Spot(sp).check().is_err());
        let sun = Light::Sun(Sun {
            direction: Vec3::ZERO,
            irradiance: DVec3::ONE,
            diameter: 0.0,
        });
        assert!(sun.check().is_err());
        assert!(Light::Spot(spot()).check().is_ok());
    }
}
