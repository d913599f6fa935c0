//! `kalos.load` and `kalos.Scene`: a loaded scene with its BVH, lights and
//! camera built once, for any number of renders.

use std::path::PathBuf;
use std::sync::Arc;

use pyo3::exceptions::{PyUserWarning, PyValueError};
use pyo3::prelude::*;
use pyo3::types::PyDict;

use kalos::job;
use kalos::scene::Summary;
use kalos::world::{BuildEvent, World};

use crate::SceneError;

/// A scene ready to render: the scene file's triangles, materials,
/// emitters and camera, with its BVH, light distribution and camera built
/// once. Made by `kalos.load`; read-only.
#[pyclass(frozen, module = "kalos")]
pub struct Scene {
    pub(crate) world: Arc<World>,
}

#[pymethods]
impl Scene {
    /// Where the scene came from (its file, or "builtin:cornell-box").
    #[getter]
    fn source(&self) -> String {
        self.world.scene.source.clone()
    }

    /// Number of triangles (after exact duplicates are removed).
    #[getter]
    fn triangles(&self) -> usize {
        self.world.scene.triangles.len()
    }

    /// Number of vertices.
    #[getter]
    fn vertices(&self) -> usize {
        self.world.scene.positions.len()
    }

    /// Number of input shapes.
    #[getter]
    fn shapes(&self) -> usize {
        self.world.scene.shapes.len()
    }

    /// Number of materials.
    #[getter]
    fn materials(&self) -> usize {
        self.world.scene.materials.len()
    }

    /// Number of emitters (area lights and environments).
    #[getter]
    fn emitters(&self) -> usize {
        self.world.scene.emitters.len()
    }

    /// The bounding box, ((x, y, z) lowest, (x, y, z) highest).
    #[getter]
    fn bounds(&self) -> ((f32, f32, f32), (f32, f32, f32)) {
        let (lo, hi) = self.world.scene.bounds();
        ((lo.x, lo.y, lo.z), (hi.x, hi.y, hi.z))
    }

    /// The film size (width, height) in pixels; a render's image has
    /// shape (height, width, 3).
    #[getter]
    fn resolution(&self) -> (u32, u32) {
        (self.world.camera.width, self.world.camera.height)
    }

    /// The camera: width, height, fov_x (degrees), position and to_world
    /// (4×4, row-major, camera to world).
    #[getter]
    fn camera<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        let c = &self.world.scene.camera;
        let d = PyDict::new(py);
        d.set_item("width", c.width)?;
        d.set_item("height", c.height)?;
        d.set_item("fov_x", c.fov_x_deg)?;
        let p = self.world.camera.position();
        d.set_item("position", (p.x, p.y, p.z))?;
        let rows: Vec<[f32; 4]> = c.to_world.transpose().to_cols_array_2d().to_vec();
        d.set_item("to_world", rows)?;
        Ok(d)
    }

    /// The scene's own sample count (Mitsuba's `<sampler>`), the default
    /// budget of a render that gives none; None when it has none.
    #[getter]
    fn sample_count(&self) -> Option<u32> {
        self.world.scene.sample_count
    }

    /// What the loader skipped or approximated, one string each.
    #[getter]
    fn warnings(&self) -> Vec<String> {
        self.world.scene.warnings.clone()
    }

    /// What the loader added or chose that changes the image.
    #[getter]
    fn notes(&self) -> Vec<String> {
        self.world.scene.notes.clone()
    }

    /// What `kalos info` prints.
    fn __str__(&self) -> String {
        Summary(&self.world.scene).to_string()
    }

    fn __repr__(&self) -> String {
        let s = &self.world.scene;
        format!(
            "<kalos.Scene {}: {} triangles, {} emitters, {}x{}>",
            s.source,
            s.triangles.len(),
            s.emitters.len(),
            s.camera.width,
            s.camera.height
        )
    }
}

/// Loads a scene: Mitsuba 3 XML, glTF, OBJ or PLY (and pbrt-v4 where the
/// library reads it), or the built-in Cornell box when `path` is None or
/// "builtin". `defines` fills a Mitsuba scene's `$name`s (as `kalos
/// render -D name=value`); `res=(width, height)` overrides the film size.
/// The scene may read only the files under its own folder: `allow_read`
/// (a list of folders) widens that, as `--allow-read`; `max_memory` (bytes)
/// caps what its data may take, as `--max-memory` (default: the machine's
/// memory).
/// The loader's warnings are issued as Python warnings and kept in
/// `Scene.warnings`. Raises SceneError, naming the file and the line.
#[pyfunction]
#[pyo3(signature = (path=None, *, defines=None, res=None, allow_read=None, max_memory=None))]
pub fn load(
    py: Python<'_>,
    path: Option<PathBuf>,
    defines: Option<&Bound<'_, PyDict>>,
    res: Option<(u32, u32)>,
    allow_read: Option<Vec<PathBuf>>,
    max_memory: Option<u64>,
) -> PyResult<Scene> {
    // {name: value}, a value in any type that prints as the scene expects
    let defines = match defines {
        Some(d) => d
            .iter()
            .map(|(k, v)| Ok((k.extract::<String>()?, v.str()?.to_string())))
            .collect::<PyResult<Vec<_>>>()?,
        None => Vec::new(),
    };
    if let Some((w, h)) = res {
        if w == 0 || h == 0 || w > 16384 || h > 16384 {
            return Err(PyValueError::new_err(format!(
                "res: resolution out of range (1..16384): {w}x{h}"
            )));
        }
    }
    let loaded = py.detach(|| {
        let opts = kalos::scene::LoadOptions {
            defines,
            read: kalos::scene::ReadPolicy {
                allow_read: allow_read.unwrap_or_default(),
                memory_limit: job::memory_limit(max_memory, "max_memory"),
            },
        };
        let loaded = job::load_scene(path.as_deref(), &opts)?;
        let mut s = loaded.scene;
        if let Some((w, h)) = res {
            s.set_resolution(w, h);
        }
        // the loader's warnings the user should see, then the build's
        let mut warnings = loaded.warnings;
        let world = World::build(s, &mut |e| {
            if let BuildEvent::Warning(w) = e {
                warnings.push(w);
            }
        });
        Ok::<_, kalos::scene::SceneError>((world, warnings))
    });
    let (world, warnings) = loaded.map_err(|e| SceneError::new_err(e.to_string()))?;
    for w in &warnings {
        PyErr::warn(
            py,
            &py.get_type::<PyUserWarning>(),
            &std::ffi::CString::new(w.replace('\0', " "))?,
            1,
        )?;
    }
    Ok(Scene {
        world: Arc::new(world),
    })
}
