//! The world a method reads: the scene and what is built from it once (the
//! BVH, the light distribution, the camera).

use crate::accel::Accel;
use crate::camera::Camera;
use crate::emitter::Lights;
use crate::scene::Scene;

/// Everything a method reads: the scene and what is built from it once.
pub struct World {
    /// The scene.
    pub scene: Scene,
    /// The BVH.
    pub accel: Accel,
    /// The lights, ready for sampling.
    pub lights: Lights,
    /// The camera.
    pub camera: Camera,
}

impl World {
    /// Builds the BVH, the light distribution and the camera.
    pub fn new(scene: Scene) -> Self {
        let accel = Accel::build(&scene);
        let lights = Lights::new(&scene);
        let camera = Camera::new(&scene.camera);
        World {
            scene,
            accel,
            lights,
            camera,
        }
    }
}
