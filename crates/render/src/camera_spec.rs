//! A camera written as text, `eye=X,Y,Z,look=X,Y,Z[,up=X,Y,Z][,fov=DEGREES]` (the command
//! line's `--camera`, the xtask path tracer's).

use crate::Camera;
use glam::Vec3;

/// Why a camera specification does not parse: the message says which key and why.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("{0}")]
pub struct CameraSpecError(String);

/// Parses `eye=X,Y,Z,look=X,Y,Z[,up=X,Y,Z][,fov=DEGREES]` into a [`Camera`] (scene units). `up`
/// defaults to +y and `fov` (vertical, degrees) to 40; keys in any order, case-insensitive.
pub fn parse_camera(s: &str) -> Result<Camera, CameraSpecError> {
    parse(s).map_err(CameraSpecError)
}

fn parse(s: &str) -> Result<Camera, String> {
    let mut fields: Vec<(String, Vec<f32>)> = Vec::new();
    for token in s.split(',').map(str::trim) {
        let value = match token.split_once('=') {
            Some((key, value)) => {
                fields.push((key.trim().to_ascii_lowercase(), Vec::new()));
                value
            }
            None => token,
        };
        let Some((key, values)) = fields.last_mut() else {
            return Err(format!("'{s}' must start with a key, as in eye=0,1,2"));
        };
        let x: f32 = value
            .trim()
            .parse()
            .map_err(|_| format!("'{value}' in {key}= is not a number"))?;
        if !x.is_finite() {
            return Err(format!("{key}= has a non-finite value"));
        }
        values.push(x);
    }
    let get = |key: &str| {
        fields
            .iter()
            .find(|(k, _)| k == key)
            .map(|(_, v)| v.as_slice())
    };
    for (key, _) in &fields {
        if !["eye", "look", "up", "fov"].contains(&key.as_str()) {
            return Err(format!("unknown key '{key}' (expected eye, look, up, fov)"));
        }
    }
    let vec3 = |key: &str| -> Result<Option<Vec3>, String> {
        match get(key) {
            None => Ok(None),
            Some(&[x, y, z]) => Ok(Some(Vec3::new(x, y, z))),
            Some(v) => Err(format!("{key}= needs 3 numbers, got {}", v.len())),
        }
    };
    let eye = vec3("eye")?.ok_or("eye=X,Y,Z is required")?;
    let look = vec3("look")?.ok_or("look=X,Y,Z is required")?;
    let up = vec3("up")?.unwrap_or(Vec3::Y);
    let fov_y_degrees = match get("fov") {
        None => 40.0,
        Some(&[f]) => f,
        Some(v) => return Err(format!("fov= needs 1 number, got {}", v.len())),
    };
    Camera::look_at(eye, look, up, fov_y_degrees).map_err(|e| e.to_string())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn full_and_default_forms_parse() {
        let c = parse_camera("eye=0.278,0.273,-0.8,look=0.278,0.273,0,up=0,1,0,fov=39.3").unwrap();
        assert_eq!(c.eye(), Vec3::new(0.278, 0.273, -0.8));
        assert_eq!(c.forward(), Vec3::Z);
        assert_eq!(c.fov_y_degrees(), 39.3);
        let d = parse_camera("look=0,0,0, eye=1,2,3").unwrap();
        let expected = Camera::look_at(Vec3::new(1.0, 2.0, 3.0), Vec3::ZERO, Vec3::Y, 40.0);
        assert_eq!(Ok(d), expected);
        for bad in [
            "",
            "eye=1,2",
            "eye=1,2,3",
            "look=1,2,3",
            "1,2,3",
            "eye=1,2,x,look=0,0,0",
            "eye=1,2,3,look=0,0,0,zoom=2",
            "eye=1,2,3,look=0,0,0,fov=1,2",
            "eye=inf,0,0,look=0,0,0",
            "eye=0,0,0,look=0,0,0",
            "eye=0,0,0,look=0,1,0",
            "eye=1,2,3,look=0,0,0,fov=180",
        ] {
            assert!(parse_camera(bad).is_err(), "{bad}");
        }
    }
}
