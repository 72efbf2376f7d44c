//! glTF `KHR_lights_punctual` lights → radiometric [`Light`]s, placed by their node's world
//! transform.

use crate::error::SceneError;
use crate::light::{DEFAULT_SUN_DIAMETER, Light, PointLight, SpotLight, Sun};
use glam::{DVec3, Mat4, Vec3};
use gltf::khr_lights_punctual::Kind;

/// The extras key of a directional light that sets its angular diameter, in degrees (the
/// sun's 0.53 without it).
pub const SUN_DIAMETER_EXTRA: &str = "angular_diameter";

/// The light of `node`, if it has one, under the world transform `world`, with photometric
/// intensities divided by the luminous `efficacy` (lm/W): candela → W/sr for point and spot
/// lights, lux → W/m² for directional lights; `color` multiplies per channel. The light sits
/// at the node's origin and points along its local `-z`; node scale changes neither intensity
/// nor range (as the extension says). A directional light's extras may give its angular
/// diameter in degrees ([`SUN_DIAMETER_EXTRA`]).
pub(crate) fn node_light(
    node: &gltf::Node,
    world: Mat4,
    efficacy: f64,
) -> Result<Option<Light>, SceneError> {
    let Some(light) = node.light() else {
        return Ok(None);
    };
    let bad = |what: String| {
        SceneError::parse(format!(
            "node {} light {}: {what}",
            node.index(),
            light.index()
        ))
    };
    if !(efficacy > 0.0 && efficacy.is_finite()) {
        return Err(SceneError::parse(format!(
            "the luminous efficacy {efficacy} lm/W is not positive and finite"
        )));
    }
    let colour = DVec3::from(light.color().map(f64::from));
    let intensity = f64::from(light.intensity());
    if !(intensity.is_finite() && intensity >= 0.0) {
        return Err(bad(format!(
            "intensity {intensity} is negative or not finite"
        )));
    }
    let radiometric = colour * (intensity / efficacy);
    let position = world.transform_point3(Vec3::ZERO);
    let forward = world.transform_vector3(Vec3::NEG_Z).normalize_or_zero();
    if forward == Vec3::ZERO {
        return Err(bad("its node's transform is degenerate".into()));
    }
    let range = light.range().map(f64::from);
    let point = PointLight {
        position,
        intensity: radiometric,
        range,
    };
    Ok(Some(match light.kind() {
        Kind::Point => Light::Point(point),
        Kind::Spot {
            inner_cone_angle,
            outer_cone_angle,
        } => Light::Spot(SpotLight {
            point,
            direction: forward,
            inner: f64::from(inner_cone_angle),
            outer: f64::from(outer_cone_angle),
        }),
        Kind::Directional => {
            let diameter = match sun_diameter_extra(light.extras()) {
                Some(degrees) => degrees.to_radians(),
                None => DEFAULT_SUN_DIAMETER,
            };
            Light::Sun(Sun {
                direction: -forward,
                irradiance: radiometric,
                diameter,
            })
        }
    }))
}

/// The angular diameter (degrees) in a light's extras, if given as a number.
fn sun_diameter_extra(extras: &gltf::json::Extras) -> Option<f64> {
    let raw = extras.as_ref()?;
    let value: gltf::json::Value = gltf::json::deserialize::from_str(raw.get()).ok()?;
    value.get(SUN_DIAMETER_EXTRA)?.as_f64()
}
