//! kalos as a library: load a scene, pick a method, render, write a PFM.
//!
//! ```text
//! cargo run --release --example render -- scenes/cbox/cbox.xml out.pfm
//! ```

#![allow(clippy::disallowed_methods)] // std::fs is denied only in the scene loaders (clippy.toml)
use kalos::methods::{plb, MethodConfig};
use kalos::render::Render;
use kalos::world::World;

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().collect();
    let (scene, out) = match args.as_slice() {
        [_, scene, out] => (scene, out),
        _ => return Err("usage: render SCENE OUT.pfm".into()),
    };
    let world = World::new(kalos::scene::load(scene.as_ref())?);
    let result = Render::new(&world)
        .method(MethodConfig::Plb(plb::Settings::default()))
        .seed(7)
        .spp(4.0)
        .run(|p| eprint!("\rpass {} ({:.0} %)", p.passes, 100.0 * p.fraction))?;
    kalos::image_io::write_image(out.as_ref(), &result.image, &Default::default())?;
    println!("\n{}: {} rays in {:.2} s", out, result.rays, result.seconds);
    Ok(())
}
