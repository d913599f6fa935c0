//! An environment given beside the scene file (`kalos render|bake --env
//! FILE.exr|.hdr [--env-scale S]` or `--env-constant R,G,B`), for scenes
//! that carry no sky: glTF, OBJ and PLY files have no way to say one.
//!
//! It becomes the emitter a Mitsuba scene would declare: `--env` is
//! `<emitter type="envmap">` (a latitude–longitude map with Mitsuba's
//! orientation, `to_world` the identity: +y up), `--env-constant` is
//! `<emitter type="constant">`, so every method lights the scene with it as
//! it does a Mitsuba sky.
//!
//! A scene that already has an environment is refused: kalos lights a scene
//! with one environment (the first), and silently dropping either would
//! render something the user did not ask for. The one exception is the
//! default white environment a loader adds to a file without any emitter
//! ([`Scene::light_if_dark`]): that stood in for the missing light, and the
//! option replaces it.

use std::path::{Path, PathBuf};
use std::sync::Arc;

use glam::Mat4;

use super::{EmitterDesc, Rgb, Scene, SceneError, TexImage};

/// An environment to add to a loaded scene.
#[derive(Clone, Debug, PartialEq)]
pub enum Environment {
    /// Radiance arriving uniformly from every direction (Mitsuba
    /// `constant`).
    Constant(Rgb),
    /// A latitude–longitude radiance map (Mitsuba `envmap`), read from
    /// `path` (`.exr`, `.hdr` or `.pfm`, linear) and multiplied by `scale`.
    Map {
        /// The image file.
        path: PathBuf,
        /// Multiplier of its radiance.
        scale: f32,
    },
}

impl Environment {
    /// Parses `R,G,B` (three finite, non-negative radiances, W/(m²·sr)), or
    /// one value for all three channels.
    pub fn parse_constant(s: &str) -> Result<Rgb, String> {
        let v: Vec<f32> = s
            .split(',')
            .map(|x| x.trim().parse::<f32>())
            .collect::<Result<_, _>>()
            .map_err(|_| format!("expected R,G,B such as 1,1,1, got '{s}'"))?;
        let c = match v[..] {
            [x] => Rgb::splat(x),
            [r, g, b] => Rgb::new(r, g, b),
            _ => return Err(format!("expected R,G,B such as 1,1,1, got '{s}'")),
        };
        if !c.is_finite() || c.min_element() < 0.0 {
            return Err(format!(
                "the radiance must be finite and not negative, got '{s}'"
            ));
        }
        Ok(c)
    }
}

impl Scene {
    /// Adds `env` as the scene's environment emitter. Refuses a scene that
    /// already has an environment (see the [module docs](self)), except the
    /// default one a loader gave a file without emitters, which `env`
    /// replaces. A map is read here (from the command line's path, not
    /// through the scene's file access); errors name the file.
    pub fn add_environment(&mut self, env: &Environment) -> Result<(), SceneError> {
        let has_env = |e: &EmitterDesc| {
            matches!(e, EmitterDesc::Constant { .. } | EmitterDesc::EnvMap { .. })
        };
        if self.default_environment() {
            self.emitters.clear();
            self.notes.retain(|n| !n.ends_with(super::DEFAULT_ENV_NOTE));
        } else if self.emitters.iter().any(has_env) {
            return Err(SceneError::new(
                &self.source,
                0,
                "the scene already has an environment emitter; --env and --env-constant are \
                 for scenes without one (edit the scene's own sky instead)",
            ));
        }
        let desc = match env {
            Environment::Constant(radiance) => EmitterDesc::Constant {
                radiance: *radiance,
            },
            Environment::Map { path, scale } => {
                if !(scale.is_finite() && *scale >= 0.0) {
                    return Err(SceneError::new(
                        path,
                        0,
                        format!("--env-scale must be finite and not negative, got {scale}"),
                    ));
                }
                EmitterDesc::EnvMap {
                    image: Arc::new(read_map(path)?),
                    scale: *scale,
                    to_world: Mat4::IDENTITY,
                }
            }
        };
        self.emitters.push(desc);
        Ok(())
    }

    /// True when the only emitter is the white environment a loader added
    /// to a file without emitters.
    fn default_environment(&self) -> bool {
        matches!(
            self.emitters[..],
            [EmitterDesc::Constant { radiance }] if radiance == Rgb::ONE
        ) && self
            .notes
            .iter()
            .any(|n| n.ends_with(super::DEFAULT_ENV_NOTE))
    }
}

/// Reads a linear radiance map: `.exr`, `.hdr` or `.pfm`, every texel
/// finite and not negative.
fn read_map(path: &Path) -> Result<TexImage, SceneError> {
    let linear = path.extension().and_then(|e| e.to_str()).is_some_and(|e| {
        ["exr", "hdr", "pfm"]
            .iter()
            .any(|x| e.eq_ignore_ascii_case(x))
    });
    if !linear {
        return Err(SceneError::new(
            path,
            0,
            "an environment map must be a linear .exr, .hdr or .pfm image",
        ));
    }
    let img = crate::image_io::read_image(path).map_err(|e| {
        // the error names the file already; SceneError names it again
        let text = e.to_string();
        let prefix = format!("{}: ", path.display());
        let reason = text.strip_prefix(&prefix).unwrap_or(&text).to_string();
        SceneError::new(path, 0, reason)
    })?;
    if let Some(i) = img
        .data
        .iter()
        .position(|p| !p.is_finite() || p.min_element() < 0.0)
    {
        return Err(SceneError::new(
            path,
            0,
            format!(
                "texel ({}, {}) is {:?}: radiance must be finite and not negative",
                i as u32 % img.width,
                i as u32 / img.width,
                img.data[i]
            ),
        ));
    }
    Ok(TexImage::new(img.width, img.height, img.data))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn constants_parse_and_bad_ones_are_refused() {
        assert_eq!(
            Environment::parse_constant("1, 0.5,2"),
            Ok(Rgb::new(1.0, 0.5, 2.0))
        );
        assert_eq!(Environment::parse_constant("0.25"), Ok(Rgb::splat(0.25)));
        for bad in ["", "1,2", "1,2,3,4", "a,b,c", "-1,0,0", "inf,1,1", "NaN"] {
            assert!(Environment::parse_constant(bad).is_err(), "{bad}");
        }
    }

    #[test]
    fn a_scene_with_a_sky_is_refused_and_the_default_one_replaced() {
        let mut sc = Scene::empty("sky");
        sc.emitters
            .push(EmitterDesc::Constant { radiance: Rgb::ONE });
        let env = Environment::Constant(Rgb::splat(2.0));
        let e = sc.add_environment(&env).expect_err("refused");
        assert!(e.to_string().contains("already has an environment"), "{e}");

        let mut bare = Scene::empty("bare");
        bare.light_if_dark(Path::new("bare.obj"));
        assert_eq!(bare.emitters.len(), 1);
        let replaced = bare.add_environment(&env);
        assert!(
            replaced.is_ok(),
            "the default sky is replaced: {replaced:?}"
        );
        assert!(matches!(
            bare.emitters[..],
            [EmitterDesc::Constant { radiance }] if radiance == Rgb::splat(2.0)
        ));
        assert!(bare.notes.is_empty(), "{:?}", bare.notes);
    }

    #[test]
    fn a_map_must_be_linear_and_readable() {
        let mut sc = Scene::empty("map");
        for (p, why) in [
            ("sky.png", "linear .exr"),
            ("no-such-sky-kalos.exr", "no-such-sky-kalos.exr"),
        ] {
            let env = Environment::Map {
                path: p.into(),
                scale: 1.0,
            };
            let e = sc.add_environment(&env).expect_err("refused");
            assert!(e.to_string().contains(why), "{e}");
        }
        assert!(sc.emitters.is_empty());
    }
}
