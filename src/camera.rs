//! The pinhole camera: primary rays, and the projection of a surface point
//! onto the film with its pixel weight g(x), which light tracing and light
//! path building use to splat light-path vertices (eq. (2) of the
//! light-path-building paper; Veach's importance W_e).
//!
//! Conventions follow Mitsuba's `perspective` sensor: camera space looks along
//! +z with +y up; film x grows to the right, which is camera −x; film y grows
//! downward, which is camera −y.

use glam::{Mat4, Vec2, Vec3};

use crate::geometry::Ray;
use crate::scene::CameraDesc;

/// A pinhole camera ready for rendering.
#[derive(Clone, Debug)]
pub struct Camera {
    // The fields `ray` and `project` read are the crate's, for the lanes
    // that make eight camera rays or project eight light-path vertices at
    // once (`transport::lanes`)
    pub(crate) to_world: Mat4,
    pub(crate) to_camera: Mat4,
    pub(crate) origin: Vec3,
    pub(crate) forward: Vec3,
    /// tan of the half field of view along x and y.
    pub(crate) tan_half: Vec2,
    /// Film width in pixels.
    pub width: u32,
    /// Film height in pixels.
    pub height: u32,
    pub(crate) near: f32,
    /// W·H / A, with A the image-plane area at unit distance: the pixel count
    /// per unit of image-plane area.
    pixels_per_area: f32,
}

impl Camera {
    /// The camera of a scene description.
    pub fn new(desc: &CameraDesc) -> Self {
        let (w, h) = (desc.width.max(1), desc.height.max(1));
        let tx = (desc.fov_x_deg.to_radians() * 0.5).tan();
        let ty = tx * h as f32 / w as f32;
        let to_world = desc.to_world;
        let origin = to_world.transform_point3(Vec3::ZERO);
        let forward = to_world.transform_vector3(Vec3::Z).normalize_or(Vec3::Z);
        Camera {
            to_world,
            to_camera: to_world.inverse(),
            origin,
            forward,
            tan_half: Vec2::new(tx, ty),
            width: w,
            height: h,
            near: desc.near_clip.max(0.0),
            pixels_per_area: (w as f32 * h as f32) / (4.0 * tx * ty),
        }
    }

    /// The pinhole position.
    #[inline]
    pub fn position(&self) -> Vec3 {
        self.origin
    }

    /// Pixels per unit of image-plane area at unit distance (f²/S_p of the
    /// light-path-building paper, eqs. (2) and (9)).
    #[inline]
    pub fn pixels_per_area(&self) -> f32 {
        self.pixels_per_area
    }

    /// The primary ray through film position (`px`, `py`) in pixels.
    #[inline]
    pub fn ray(&self, px: f32, py: f32) -> Ray {
        let sx = px / self.width as f32;
        let sy = py / self.height as f32;
        let d_cam = Vec3::new(
            (1.0 - 2.0 * sx) * self.tan_half.x,
            (1.0 - 2.0 * sy) * self.tan_half.y,
            1.0,
        );
        let d = self.to_world.transform_vector3(d_cam).normalize();
        let cos = d.dot(self.forward).max(1e-6);
        Ray {
            o: self.origin,
            d,
            tmin: self.near / cos,
            tmax: f32::INFINITY,
        }
    }

    /// Where `x` lands on the film, in pixels, and its pixel weight
    /// g(x) = W·H / (A cos³θ_c r²): a light-path vertex at x that sends
    /// radiance L toward the camera adds L · cos θ_x · g(x) to its pixel
    /// (θ_x measured at x, θ_c at the camera, r the distance). None when x is
    /// behind the camera, nearer than the near clip, or off the film.
    #[inline]
    pub fn project(&self, x: Vec3) -> Option<(Vec2, f32)> {
        let p = self.to_camera.transform_point3(x);
        if p.z <= self.near || p.z <= 0.0 {
            return None;
        }
        let sx = 0.5 * (1.0 - p.x / (p.z * self.tan_half.x));
        let sy = 0.5 * (1.0 - p.y / (p.z * self.tan_half.y));
        if !(0.0..1.0).contains(&sx) || !(0.0..1.0).contains(&sy) {
            return None;
        }
        let d = x - self.origin;
        let r2 = d.length_squared();
        let cos_c = d.dot(self.forward) / r2.sqrt();
        if cos_c <= 0.0 {
            return None;
        }
        let g = self.pixels_per_area / (cos_c * cos_c * cos_c * r2);
        Some((
            Vec2::new(sx * self.width as f32, sy * self.height as f32),
            g,
        ))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn cam() -> Camera {
        let desc = CameraDesc {
            to_world: crate::geometry::look_at(Vec3::ZERO, Vec3::Z, Vec3::Y),
            fov_x_deg: 60.0,
            width: 64,
            height: 32,
            near_clip: 0.01,
        };
        Camera::new(&desc)
    }

    #[test]
    fn project_inverts_ray() {
        let c = cam();
        for &(px, py) in &[(0.5, 0.5), (10.25, 20.75), (63.5, 31.5), (32.0, 16.0)] {
            let r = c.ray(px, py);
            let (pix, _) = c.project(r.at(3.7)).unwrap();
            assert!(
                (pix.x - px).abs() < 1e-3 && (pix.y - py).abs() < 1e-3,
                "{pix} vs {px},{py}"
            );
        }
    }

    /// The weight g integrates to the pixel count over a plane that fills the
    /// view: Σ over film of ∫ g cosθ_x dA = W·H when every pixel sees the
    /// plane (each pixel's solid-angle measure is normalised).
    #[test]
    fn g_integrates_to_one_per_pixel() {
        let c = cam();
        // a plane at z = 2 facing the camera; integrate g cos over a grid
        let z = 2.0;
        let (hx, hy) = (c.tan_half.x * z, c.tan_half.y * z);
        let n = 400;
        let mut sum = 0.0f64;
        let da = (2.0 * hx / n as f32) * (2.0 * hy / n as f32);
        for i in 0..n {
            for j in 0..n {
                let x = -hx + (i as f32 + 0.5) * 2.0 * hx / n as f32;
                let y = -hy + (j as f32 + 0.5) * 2.0 * hy / n as f32;
                let p = Vec3::new(x, y, z);
                if let Some((_, g)) = c.project(p) {
                    let cos_x = z / p.length();
                    sum += (g * cos_x * da) as f64;
                }
            }
        }
        let pixels = (c.width * c.height) as f64;
        assert!((sum / pixels - 1.0).abs() < 1e-3, "{}", sum / pixels);
    }
}
