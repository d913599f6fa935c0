//! Where light tracing spends its work on a two-room scene: light paths are
//! traced as `light` traces them ([`kalos::transport::light_walk`]: Russian
//! roulette on the albedo, a camera connection at every non-delta vertex,
//! made in the walk's hook), and their vertices are split by room
//! (x < 0: the light's room, x > 0: the camera's room). Prints, per room,
//! the vertices, the camera connections that reached the film, and the
//! image energy (luminance) those connections carry. Used for the plb
//! diagnosis in docs/notebook/plb.md.
//!
//! ```text
//! cargo run --release --example two_rooms_paths -- scenes/two-rooms/scene.xml [PATHS]
//! ```

#![allow(clippy::disallowed_methods)] // std::fs is denied only in the scene loaders (clippy.toml)
use std::ops::ControlFlow;

use kalos::methods::World;
use kalos::sampling::Pcg32;
use kalos::scene::luminance;
use kalos::transport::{connect_to_camera, light_walk, Roulette, Spectrum};

/// Tallies of one room.
#[derive(Default)]
struct Room {
    vertices: u64,
    connected: u64,
    energy: f64,
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let mut args = std::env::args().skip(1);
    let path = args.next().ok_or("usage: SCENE [PATHS]")?;
    let paths: u64 = args.next().map_or(Ok(200_000), |a| a.parse())?;
    let world = World::new(kalos::scene::load(std::path::Path::new(&path))?);
    let mut rng = Pcg32::keyed(&[1, 2]);
    let mut rooms = [Room::default(), Room::default()]; // light's, camera's
    let mut rays = 0u64;
    for _ in 0..paths {
        let Some(es) = world
            .lights
            .sample_emission(rng.next_f32(), rng.next_2d(), rng.next_2d())
        else {
            continue;
        };
        let mut connection_rays = 0;
        rays += light_walk(
            &world,
            es.ray(),
            es.phi,
            Spectrum::Rgb,
            Roulette::Albedo,
            None,
            &mut rng,
            |e| {
                let v = e.vertex;
                let room = &mut rooms[usize::from(v.sp.p.x > 0.0)];
                room.vertices += 1;
                if v.bsdf.has_smooth() {
                    if let Some((_, c)) =
                        connect_to_camera(&world, v, e.beta, false, &mut connection_rays)
                    {
                        room.connected += 1;
                        room.energy += luminance(c) as f64;
                    }
                }
                ControlFlow::Continue(())
            },
        );
        rays += connection_rays;
    }
    let v: u64 = rooms.iter().map(|r| r.vertices).sum();
    let e: f64 = rooms.iter().map(|r| r.energy).sum();
    println!("{paths} light paths, {rays} rays");
    for (name, r) in ["light's room", "camera's room"].iter().zip(&rooms) {
        println!(
            "{name:>14}: {:>9} vertices ({:6.3} %), {:>8} connections on the film, {:5.1} % of the image energy",
            r.vertices,
            100.0 * r.vertices as f64 / v.max(1) as f64,
            r.connected,
            100.0 * r.energy / if e > 0.0 { e } else { 1.0 }
        );
    }
    Ok(())
}
