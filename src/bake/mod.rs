//! Display-mesh export: writers for the baked lighting a view-independent
//! method produces (the density method's [`BakedMesh`], made by
//! [`crate::methods::density::Bake::baked_meshes`]), as glTF binary with
//! vertex colours and as an irradiance PLY. Nothing here computes
//! lighting: [`job`] runs the whole bake (load, build, the density
//! method's bake, these writers) for the front ends.

pub mod gltf;
pub mod job;
pub mod lightmap;
pub mod ply;

pub use crate::methods::density::BakedMesh;
