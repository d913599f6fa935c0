//! The bitmap textures of `big-room-textured`, drawn procedurally as 8-bit
//! sRGB images (read back as sRGB by both kalos and Mitsuba's `bitmap`).
//! Each tiles seamlessly: its patterns have whole periods across the image.

use std::f32::consts::TAU;

use image::{Rgb as Px, RgbImage};

use crate::sampling::Pcg32;

/// Spines side by side in [`spines`]: a book takes cell k, u in
/// [k / SPINES, (k + 1) / SPINES].
pub(super) const SPINES: u32 = 16;

/// Scales an sRGB colour by `f`, clamped to 8 bits.
fn shade(c: [f32; 3], f: f32) -> Px<u8> {
    Px(c.map(|v| (v * f).round().clamp(0.0, 255.0) as u8))
}

/// Wood planks running along u: eight planks across v, each with its own
/// tone, a wavy grain and one end joint, dark seams between them.
pub(super) fn wood() -> RgbImage {
    const N: u32 = 512;
    const PLANKS: u32 = 8;
    let ph = N / PLANKS;
    let mut rng = Pcg32::keyed(&[0x600D]);
    let planks: Vec<(f32, u32, f32)> = (0..PLANKS)
        .map(|_| {
            (
                0.8 + 0.35 * rng.next_f32(),
                rng.next_u32() % N,
                TAU * rng.next_f32(),
            )
        })
        .collect();
    RgbImage::from_fn(N, N, |x, y| {
        let (tone, joint, phase) = planks[(y / ph) as usize];
        let in_plank = (y % ph) as f32;
        let dx = (x as i64 - joint as i64).rem_euclid(N as i64);
        if y % ph < 2 || dx < 2 {
            return shade([70.0, 45.0, 28.0], 1.0);
        }
        let s = TAU * x as f32 / N as f32;
        let wave = 5.0 * (3.0 * s + phase).sin() + 2.0 * (7.0 * s + 2.0 * phase).sin();
        let grain = 0.5 + 0.5 * ((in_plank + wave) * 0.55).sin();
        shade([165.0, 112.0, 68.0], tone * (0.8 + 0.25 * grain))
    })
}

/// Cream wallpaper with sage stripes and a diamond between each pair.
pub(super) fn wallpaper() -> RgbImage {
    const N: u32 = 256;
    const PERIOD: i64 = 64;
    RgbImage::from_fn(N, N, |x, y| {
        let (sx, sy) = (x as i64 % PERIOD, y as i64 % PERIOD);
        if sx < 8 {
            return shade([150.0, 172.0, 140.0], 1.0);
        }
        let (cx, cy) = (36, 32);
        if (sx - cx).abs() + (sy - cy).abs() < 11 {
            return shade([196.0, 160.0, 118.0], 1.0);
        }
        shade([228.0, 218.0, 192.0], 1.0)
    })
}

/// [`SPINES`] book spines side by side (u across, v along the height):
/// each its own cloth colour, dark edges, gilt bands at both ends and on
/// some a pale title label.
pub(super) fn spines() -> RgbImage {
    const W: u32 = 32;
    const H: u32 = 256;
    const CLOTH: [[f32; 3]; SPINES as usize] = [
        [140.0, 30.0, 32.0],
        [30.0, 45.0, 105.0],
        [35.0, 90.0, 45.0],
        [190.0, 140.0, 50.0],
        [100.0, 25.0, 45.0],
        [30.0, 110.0, 115.0],
        [110.0, 70.0, 40.0],
        [35.0, 35.0, 38.0],
        [90.0, 105.0, 135.0],
        [120.0, 40.0, 30.0],
        [105.0, 110.0, 45.0],
        [85.0, 45.0, 110.0],
        [195.0, 165.0, 120.0],
        [25.0, 75.0, 75.0],
        [170.0, 75.0, 35.0],
        [215.0, 205.0, 180.0],
    ];
    RgbImage::from_fn(W * SPINES, H, |x, y| {
        let k = x / W;
        let (cx, cy) = (x % W, y);
        let cloth = CLOTH[k as usize];
        if cx == 0 || cx == W - 1 {
            return shade(cloth, 0.45);
        }
        let band = |y0: u32| (y0..y0 + 5).contains(&cy);
        if band(18) || band(28) || band(H - 23) || band(H - 33) {
            return shade([205.0, 170.0, 80.0], 1.0);
        }
        if k.is_multiple_of(3) && (6..W - 6).contains(&cx) && (90..170).contains(&cy) {
            return shade([232.0, 222.0, 196.0], 1.0);
        }
        shade(cloth, 1.0)
    })
}
