//! Rays, shading frames and robust ray origins.

use glam::Vec3;

/// A ray `o + t d` for `t` in `[tmin, tmax)`.
#[derive(Clone, Copy, Debug)]
pub struct Ray {
    /// Origin.
    pub o: Vec3,
    /// Direction (unit length unless stated otherwise).
    pub d: Vec3,
    /// Smallest accepted distance.
    pub tmin: f32,
    /// Largest accepted distance.
    pub tmax: f32,
}

impl Ray {
    /// A ray with an unbounded far end.
    pub fn new(o: Vec3, d: Vec3) -> Self {
        Ray {
            o,
            d,
            tmin: 0.0,
            tmax: f32::INFINITY,
        }
    }

    /// The point at distance `t`.
    pub fn at(&self, t: f32) -> Vec3 {
        self.o + self.d * t
    }
}

/// An orthonormal frame whose `n` axis is the (shading) normal; local
/// coordinates put the normal on +z, as in pbrt and Mitsuba.
#[derive(Clone, Copy, Debug)]
pub struct Frame {
    /// First tangent.
    pub s: Vec3,
    /// Second tangent.
    pub t: Vec3,
    /// Normal.
    pub n: Vec3,
}

impl Frame {
    /// A frame around the unit vector `n` (Duff et al. 2017, "Building an
    /// orthonormal basis, revisited": branchless and continuous almost everywhere).
    pub fn from_normal(n: Vec3) -> Self {
        let sign = 1.0f32.copysign(n.z);
        let a = -1.0 / (sign + n.z);
        let b = n.x * n.y * a;
        let s = Vec3::new(1.0 + sign * n.x * n.x * a, sign * b, -sign * n.x);
        let t = Vec3::new(b, sign + n.y * n.y * a, -n.y);
        Frame { s, t, n }
    }

    /// World to local.
    #[inline]
    pub fn to_local(&self, v: Vec3) -> Vec3 {
        Vec3::new(v.dot(self.s), v.dot(self.t), v.dot(self.n))
    }

    /// Local to world.
    #[inline]
    pub fn to_world(&self, v: Vec3) -> Vec3 {
        self.s * v.x + self.t * v.y + self.n * v.z
    }
}

/// Moves a surface point off its surface along the geometric normal `ng`, to the
/// side that `dir` points into, so that a ray leaving it cannot hit the
/// surface it starts on. Integer-ULP offset of Wächter and Binder ("A fast and
/// robust method for avoiding self-intersection", Ray Tracing Gems, ch. 6):
/// the step scales with the magnitude of the coordinates, so it works for
/// scenes in millimetres and in metres alike.
#[inline]
pub fn offset_point(p: Vec3, ng: Vec3, dir: Vec3) -> Vec3 {
    const ORIGIN: f32 = 1.0 / 32.0;
    const FLOAT_SCALE: f32 = 1.0 / 65536.0;
    const INT_SCALE: f32 = 256.0;
    let n = if ng.dot(dir) < 0.0 { -ng } else { ng };
    let of_i = [
        (INT_SCALE * n.x) as i32,
        (INT_SCALE * n.y) as i32,
        (INT_SCALE * n.z) as i32,
    ];
    let step = |pc: f32, oi: i32| -> f32 {
        let bits = pc.to_bits() as i32;
        let moved = if pc < 0.0 { bits - oi } else { bits + oi };
        f32::from_bits(moved as u32)
    };
    let pi = Vec3::new(step(p.x, of_i[0]), step(p.y, of_i[1]), step(p.z, of_i[2]));
    Vec3::new(
        if p.x.abs() < ORIGIN {
            p.x + FLOAT_SCALE * n.x
        } else {
            pi.x
        },
        if p.y.abs() < ORIGIN {
            p.y + FLOAT_SCALE * n.y
        } else {
            pi.y
        },
        if p.z.abs() < ORIGIN {
            p.z + FLOAT_SCALE * n.z
        } else {
            pi.z
        },
    )
}

/// Reflects `v` about the +z axis of a local frame.
#[inline]
pub fn reflect_local(v: Vec3) -> Vec3 {
    Vec3::new(-v.x, -v.y, v.z)
}

/// Mitsuba's `lookat` camera-to-world transform: columns left, up, forward
/// and the origin, with left = normalize(up × dir).
pub fn look_at(origin: Vec3, target: Vec3, up: Vec3) -> glam::Mat4 {
    let dir = (target - origin).normalize_or(Vec3::Z);
    let left = up.cross(dir).normalize_or(Vec3::X);
    let new_up = dir.cross(left);
    glam::Mat4::from_cols(
        left.extend(0.0),
        new_up.extend(0.0),
        dir.extend(0.0),
        origin.extend(1.0),
    )
}
