//! Irradiance PLY writer: binary little-endian, per vertex x y z and the
//! irradiance H (W/m²) as float `irradiance_r/g/b`, plus the faces.

use std::io::Write;
use std::path::Path;

use super::BakedMesh;
use crate::image_io::{write_atomic, ImageIoError};

/// The bytes of the PLY file.
pub fn encode_ply(m: &BakedMesh) -> Vec<u8> {
    let mut out = format!(
        "ply\nformat binary_little_endian 1.0\ncomment kalos bake: irradiance in W/m^2\nelement vertex {}\nproperty float x\nproperty float y\nproperty float z\nproperty float irradiance_r\nproperty float irradiance_g\nproperty float irradiance_b\nelement face {}\nproperty list uchar uint vertex_indices\nend_header\n",
        m.positions.len(),
        m.indices.len()
    )
    .into_bytes();
    for (p, h) in m.positions.iter().zip(&m.irradiance) {
        for c in p.to_array().into_iter().chain(h.to_array()) {
            out.extend_from_slice(&c.to_le_bytes());
        }
    }
    for t in &m.indices {
        out.push(3);
        for i in t {
            out.extend_from_slice(&i.to_le_bytes());
        }
    }
    out
}

/// Writes the PLY atomically.
pub fn write_ply(path: &Path, m: &BakedMesh) -> Result<(), ImageIoError> {
    let bytes = encode_ply(m);
    write_atomic(path, |w| {
        w.write_all(&bytes).map_err(|e| ImageIoError::Io {
            path: path.to_path_buf(),
            source: e,
        })
    })
}
