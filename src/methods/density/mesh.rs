//! The display mesh: per receiving surface and side, triangles with the
//! irradiance at their vertices (planar surfaces in chart coordinates,
//! curved shapes on their own triangles), with point location for the
//! view pass.

use std::collections::HashMap;

use glam::{Vec2, Vec3};
use rayon::prelude::*;

use super::kernel::TriGrid;
use super::surfaces::{SurfaceId, Surfaces};

/// The mesh of one side of a planar surface.
#[derive(Clone, Debug, Default)]
pub struct PlanarMesh {
    /// The surface side.
    pub surface: SurfaceId,
    /// Vertices, chart coordinates.
    pub verts: Vec<Vec2>,
    /// Triangles (counter-clockwise in the chart).
    pub tris: Vec<[u32; 3]>,
    /// Irradiance at each vertex, W/m².
    pub h: Vec<Vec3>,
    /// Kernel bandwidth, chart units (0 without hits).
    pub bandwidth: f32,
    /// Hits that made the estimate.
    pub hits: u64,
    grid: TriGrid,
}

impl PlanarMesh {
    /// A mesh; builds its point-location grid.
    pub fn new(
        surface: SurfaceId,
        verts: Vec<Vec2>,
        tris: Vec<[u32; 3]>,
        h: Vec<Vec3>,
        bandwidth: f32,
        hits: u64,
    ) -> Self {
        let mut m = Self::unindexed(surface, verts, tris, h, bandwidth, hits);
        m.grid = TriGrid::new(&m.verts, &m.tris);
        m
    }

    /// A mesh without its point-location grid (the over-mesh of phase 2,
    /// which only the decimation reads): the grid is built by
    /// [`DisplayMesh::new`] if the mesh reaches the display mesh as it is.
    pub fn unindexed(
        surface: SurfaceId,
        verts: Vec<Vec2>,
        tris: Vec<[u32; 3]>,
        h: Vec<Vec3>,
        bandwidth: f32,
        hits: u64,
    ) -> Self {
        PlanarMesh {
            surface,
            verts,
            tris,
            h,
            bandwidth,
            hits,
            grid: TriGrid::default(),
        }
    }

    /// Irradiance at chart point `c`, linearly interpolated.
    pub fn irradiance(&self, c: Vec2) -> Vec3 {
        match self.grid.locate(&self.verts, &self.tris, c) {
            Some((t, b)) => {
                let t = self.tris[t as usize];
                self.h[t[0] as usize] * b.x
                    + self.h[t[1] as usize] * b.y
                    + self.h[t[2] as usize] * b.z
            }
            None => Vec3::ZERO,
        }
    }
}

/// The mesh of one side of a curved shape: its own triangles.
#[derive(Clone, Debug, Default)]
pub struct CurvedMesh {
    /// Shape index.
    pub shape: u32,
    /// True for the back side.
    pub back: bool,
    /// Scene triangles.
    pub tris: Vec<u32>,
    /// Irradiance at the three corners of each triangle.
    pub h: Vec<[Vec3; 3]>,
}

/// The whole display mesh.
#[derive(Clone, Debug, Default)]
pub struct DisplayMesh {
    /// Planar surfaces.
    pub planar: Vec<PlanarMesh>,
    /// Curved shapes.
    pub curved: Vec<CurvedMesh>,
    planar_index: HashMap<SurfaceId, u32>,
    curved_index: HashMap<(u32, bool), (u32, u32)>,
}

impl DisplayMesh {
    /// Builds the lookup tables (and the point-location grid of any planar
    /// mesh made [`PlanarMesh::unindexed`]).
    pub fn new(mut planar: Vec<PlanarMesh>, curved: Vec<CurvedMesh>) -> Self {
        planar.par_iter_mut().for_each(|m| {
            if m.grid.is_empty() && !m.tris.is_empty() {
                m.grid = TriGrid::new(&m.verts, &m.tris);
            }
        });
        let planar_index = planar
            .iter()
            .enumerate()
            .map(|(i, m)| (m.surface, i as u32))
            .collect();
        let mut curved_index = HashMap::new();
        for (i, m) in curved.iter().enumerate() {
            for (j, &t) in m.tris.iter().enumerate() {
                curved_index.insert((t, m.back), (i as u32, j as u32));
            }
        }
        DisplayMesh {
            planar,
            curved,
            planar_index,
            curved_index,
        }
    }

    /// Irradiance at a surface point: triangle `tri` at barycentrics
    /// (`b1`, `b2`), world point `p`, on the back side when `back`.
    pub fn irradiance(
        &self,
        surfaces: &Surfaces,
        tri: u32,
        b1: f32,
        b2: f32,
        p: Vec3,
        back: bool,
    ) -> Vec3 {
        let sid = surfaces.tri_surface[tri as usize];
        let key = SurfaceId { index: sid, back };
        if let Some(&i) = self.planar_index.get(&key) {
            let s = &surfaces.list[sid as usize];
            return self.planar[i as usize].irradiance(s.to_chart(p));
        }
        if let Some(&(i, j)) = self.curved_index.get(&(tri, back)) {
            let h = self.curved[i as usize].h[j as usize];
            return h[0] * (1.0 - b1 - b2) + h[1] * b1 + h[2] * b2;
        }
        Vec3::ZERO
    }

    /// Triangles in the mesh.
    pub fn triangle_count(&self) -> u64 {
        self.planar.iter().map(|m| m.tris.len() as u64).sum::<u64>()
            + self.curved.iter().map(|m| m.tris.len() as u64).sum::<u64>()
    }
}
