//! `kalos.bake`: view-independent lighting by density estimation, as numpy
//! arrays and as the .glb (or .ply) that `kalos bake` writes.

use std::path::PathBuf;
use std::sync::atomic::AtomicBool;

use glam::Vec3;
use numpy::{PyArray1, PyArray2, PyArray3, PyArrayMethods, PyUntypedArrayMethods};
use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;
use pyo3::types::PyDict;

use kalos::bake::job::{BakeError, BakeEvent, BakeJob, Baked};
use kalos::bake::lightmap::bake::{self as lmbake, LightmapBake, LightmapSettings};
use kalos::bake::lightmap::estimate::Options;
use kalos::bake::lightmap::gather::{GatherOptions, DEFAULT_LIGHTS, DEFAULT_RAYS};
use kalos::bake::lightmap::Lightmap as Atlas;
use kalos::bake::{self as kbake, BakedMesh as Mesh};
use kalos::job::SceneInput;
use kalos::methods::density;
use kalos::methods::MethodConfig;
use kalos::scene::CameraDesc;

use crate::render::{count, method_config, Progress, Watch};
use crate::scene::Scene;
use crate::{ImageError, RenderError};

/// `v` as a float32 array of shape (len, 3).
fn vec3s<'py>(py: Python<'py>, v: &[Vec3]) -> PyResult<Bound<'py, PyArray2<f32>>> {
    let flat: Vec<f32> = v.iter().flat_map(|p| p.to_array()).collect();
    PyArray1::from_vec(py, flat).reshape([v.len(), 3])
}

/// Triangles with per-vertex attributes, as numpy arrays (read-only
/// attributes; the arrays are the object's own).
#[pyclass(frozen, get_all, module = "kalos")]
pub struct BakedMesh {
    /// Vertex positions, float32 (n, 3), world space.
    positions: Py<PyArray2<f32>>,
    /// Vertex normals, float32 (n, 3): the side the lighting is for.
    normals: Py<PyArray2<f32>>,
    /// Display colours in [0, 1], float32 (n, 3): the radiance over the
    /// white point, as the .glb's COLOR_0 holds them.
    colours: Py<PyArray2<f32>>,
    /// Outgoing radiance, W/(m²·sr), float32 (n, 3).
    radiance: Py<PyArray2<f32>>,
    /// Irradiance, W/m², float32 (n, 3).
    irradiance: Py<PyArray2<f32>>,
    /// Triangles, uint32 (m, 3), indices into the vertices.
    indices: Py<PyArray2<u32>>,
}

impl BakedMesh {
    fn new(py: Python<'_>, m: &Mesh, w0: f32) -> PyResult<Self> {
        let flat: Vec<u32> = m.indices.iter().flatten().copied().collect();
        Ok(BakedMesh {
            positions: vec3s(py, &m.positions)?.unbind(),
            normals: vec3s(py, &m.normals)?.unbind(),
            colours: vec3s(py, &kbake::gltf::display_colors(m, w0))?.unbind(),
            radiance: vec3s(py, &m.radiance)?.unbind(),
            irradiance: vec3s(py, &m.irradiance)?.unbind(),
            indices: PyArray1::from_vec(py, flat)
                .reshape([m.indices.len(), 3])?
                .unbind(),
        })
    }
}

#[pymethods]
impl BakedMesh {
    fn __repr__(&self, py: Python<'_>) -> String {
        format!(
            "<kalos.BakedMesh {} vertices, {} triangles>",
            self.positions.bind(py).shape()[0],
            self.indices.bind(py).shape()[0]
        )
    }
}

/// A bake: the display mesh of the diffuse surfaces with their lighting
/// (`lit`, whose arrays `positions`, `normals`, `colours`, `radiance`,
/// `irradiance` and `indices` are also the bake's own attributes), the
/// unlit geometry of the other surfaces (`unlit`), the white point `w0`
/// and the bake's figures (`stats`). `save` writes it.
#[pyclass(frozen, module = "kalos")]
pub struct Bake {
    /// The lit display mesh.
    #[pyo3(get)]
    lit: Py<BakedMesh>,
    /// The surfaces with no diffuse part (glass, metal), unlit.
    #[pyo3(get)]
    unlit: Py<BakedMesh>,
    /// The white point of the display colours, radiance (luminance).
    #[pyo3(get)]
    w0: f32,
    /// The figures of `kalos bake --stats`, as a dict.
    #[pyo3(get)]
    stats: Py<PyDict>,
    meshes: (Mesh, Mesh),
    /// The scene's camera, which the .glb carries as `kalos bake` writes it.
    camera: CameraDesc,
}

#[pymethods]
impl Bake {
    /// The lit mesh's vertex positions.
    #[getter]
    fn positions(&self, py: Python<'_>) -> Py<PyArray2<f32>> {
        self.lit.get().positions.clone_ref(py)
    }

    /// The lit mesh's vertex normals.
    #[getter]
    fn normals(&self, py: Python<'_>) -> Py<PyArray2<f32>> {
        self.lit.get().normals.clone_ref(py)
    }

    /// The lit mesh's display colours.
    #[getter]
    fn colours(&self, py: Python<'_>) -> Py<PyArray2<f32>> {
        self.lit.get().colours.clone_ref(py)
    }

    /// The lit mesh's outgoing radiance.
    #[getter]
    fn radiance(&self, py: Python<'_>) -> Py<PyArray2<f32>> {
        self.lit.get().radiance.clone_ref(py)
    }

    /// The lit mesh's irradiance.
    #[getter]
    fn irradiance(&self, py: Python<'_>) -> Py<PyArray2<f32>> {
        self.lit.get().irradiance.clone_ref(py)
    }

    /// The lit mesh's triangles.
    #[getter]
    fn indices(&self, py: Python<'_>) -> Py<PyArray2<u32>> {
        self.lit.get().indices.clone_ref(py)
    }

    /// Writes the bake atomically: .glb, the glTF binary `kalos bake`
    /// writes (display colours in COLOR_0, linear radiance in _RADIANCE,
    /// the unlit surfaces as a second primitive), or .ply, the lit mesh
    /// with its irradiance (`kalos bake --ply`). Raises ImageError naming
    /// the file.
    fn save(&self, py: Python<'_>, path: PathBuf) -> PyResult<()> {
        let ext = path
            .extension()
            .and_then(|e| e.to_str())
            .map(str::to_ascii_lowercase)
            .unwrap_or_default();
        let (lit, unlit) = &self.meshes;
        let r = py.detach(|| match ext.as_str() {
            "glb" => Some(kbake::gltf::write_glb(
                &path,
                lit,
                unlit,
                self.w0,
                Some(&self.camera),
            )),
            "ply" => Some(kbake::ply::write_ply(&path, lit)),
            _ => None,
        });
        match r {
            Some(r) => r.map_err(|e| ImageError::new_err(e.to_string())),
            None => Err(PyValueError::new_err(format!(
                "{}: a bake is saved as .glb or .ply",
                path.display()
            ))),
        }
    }

    fn __repr__(&self) -> String {
        format!(
            "<kalos.Bake {} lit triangles, {} unlit, w0 {:.4e}>",
            self.meshes.0.indices.len(),
            self.meshes.1.indices.len(),
            self.w0
        )
    }
}

/// `v` (row-major from the top row) as a float32 array (height, width, 3).
fn atlas_array<'py>(
    py: Python<'py>,
    v: &[Vec3],
    width: u32,
    height: u32,
) -> PyResult<Bound<'py, PyArray3<f32>>> {
    let flat: Vec<f32> = v.iter().flat_map(|p| p.to_array()).collect();
    PyArray1::from_vec(py, flat).reshape([height as usize, width as usize, 3])
}

/// A lightmap bake (`kalos.bake(scene, lightmap=True)`): the atlas of
/// irradiance E (W/m², linear RGB; a Lambertian surface of albedo R shows
/// R·E/π) and its standard errors, float32 (height, width, 3), row 0 at
/// the top; `covered`, bool (height, width), the texels a triangle covers
/// (the others are padding); the figures in `stats`. `save(path)` writes
/// the atlas as .exr; `save_error(path)` the error map.
#[pyclass(frozen, module = "kalos")]
pub struct LightmapResult {
    /// The irradiance, float32 (height, width, 3).
    #[pyo3(get)]
    atlas: Py<PyArray3<f32>>,
    /// The standard error of each texel and channel, float32 (height,
    /// width, 3).
    #[pyo3(get)]
    error: Py<PyArray3<f32>>,
    /// Whether a triangle covers each texel, bool (height, width).
    #[pyo3(get)]
    covered: Py<PyArray2<bool>>,
    /// Figures of the bake, as a dict.
    #[pyo3(get)]
    stats: Py<PyDict>,
    baked: LightmapBake,
    world: std::sync::Arc<kalos::world::World>,
}

#[pymethods]
impl LightmapResult {
    /// Writes the lightmapped asset as .glb (the scene's file whole when it
    /// is glTF, with TEXCOORD_1 and the atlas, and the float atlas beside it
    /// as PATH.lightmap.exr), or the atlas alone as .exr (atomically);
    /// raises ImageError naming the file.
    fn save(&self, py: Python<'_>, path: PathBuf) -> PyResult<()> {
        if path.extension().and_then(|e| e.to_str()) == Some("glb") {
            let scene = &self.world.scene;
            let source = std::path::Path::new(&scene.source);
            let source = source.is_file().then_some(source);
            return py
                .detach(|| {
                    kalos::bake::lightmap::glb::write_lightmapped(
                        &path,
                        scene,
                        source,
                        &self.baked.uv,
                        &self.baked.lightmap,
                    )
                })
                .map(|_| ())
                .map_err(|e| ImageError::new_err(e.to_string()));
        }
        self.write(py, path, lmbake::irradiance_image(&self.baked.lightmap))
    }

    /// Writes the error map as .exr (atomically).
    fn save_error(&self, py: Python<'_>, path: PathBuf) -> PyResult<()> {
        self.write(py, path, lmbake::error_image(&self.baked.lightmap))
    }

    fn __repr__(&self) -> String {
        let m = &self.baked.lightmap;
        format!(
            "<kalos.LightmapResult {}×{} texels, {} particles>",
            m.width, m.height, self.baked.stats.particles
        )
    }
}

impl LightmapResult {
    fn write(&self, py: Python<'_>, path: PathBuf, img: kalos::film::Image) -> PyResult<()> {
        if path.extension().and_then(|e| e.to_str()) != Some("exr") {
            return Err(PyValueError::new_err(format!(
                "{}: a lightmap is saved as .glb (the asset with its lightmap) or .exr",
                path.display()
            )));
        }
        py.detach(|| {
            kalos::image_io::write_image(&path, &img, &kalos::image_io::PngOptions::default())
        })
        .map_err(|e| ImageError::new_err(e.to_string()))
    }

    fn new(
        py: Python<'_>,
        baked: LightmapBake,
        world: std::sync::Arc<kalos::world::World>,
    ) -> PyResult<Self> {
        let m: &Atlas = &baked.lightmap;
        let (w, h) = (m.width, m.height);
        let covered =
            PyArray1::from_vec(py, m.covered.clone()).reshape([h as usize, w as usize])?;
        let st = &baked.stats;
        let stats = PyDict::new(py);
        stats.set_item("particles", st.particles)?;
        stats.set_item("hits", st.hits)?;
        stats.set_item("rays", st.rays)?;
        stats.set_item("texels", st.texels)?;
        stats.set_item("t_trace", st.t_trace)?;
        stats.set_item("t_index", st.t_index)?;
        stats.set_item("t_estimate", st.t_estimate)?;
        Ok(LightmapResult {
            atlas: atlas_array(py, &m.irradiance, w, h)?.unbind(),
            error: atlas_array(py, &m.std_error, w, h)?.unbind(),
            covered: covered.unbind(),
            stats: stats.unbind(),
            baked,
            world,
        })
    }
}

/// Bakes the view-independent lighting of `scene` by density estimation
/// (as `kalos bake`): particle tracing, kernel density estimation,
/// decimated display mesh. The density method's settings are keyword
/// arguments as for `kalos.render(method="density")` (`particles=1_000_000`
/// or "1M", `c1`, `c2`, `epsilon`, `no_decimate=True`, ...). `progress(p)`
/// is called between units of work with the phase in `p.phase`; Ctrl-C
/// stops the bake, removes its scratch files and raises
/// KeyboardInterrupt. Returns a `kalos.Bake`.
///
/// `lightmap=True` bakes a lightmap instead (as `kalos bake --lightmap`):
/// `texel_density` (texels per metre) or `lightmap_size` (texels a side,
/// default 512), `neighbours` (a fixed k for the estimator; without it k
/// grows with the hits) and `sectors` (its
/// visibility rays), `gather` and `gather_lights` (the final gather's
/// rays and light samples per texel, default 64 each, the lights
/// defaulting to the rays; 0 and 0: no gather, the density estimate
/// alone, the paper's method), `time` (seconds) and `rays` limits;
/// `output`, if
/// given, is where the atlas is saved (.exr). Returns a
/// `kalos.LightmapResult` whose `atlas` and `error` are numpy arrays.
#[pyfunction]
#[pyo3(signature = (scene, *, seed=0, max_depth=None, progress=None, max_memory=None,
    lightmap=false, texel_density=None, lightmap_size=None, neighbours=None, sectors=None,
    gather=None, gather_lights=None, time=None, rays=None, output=None, **settings))]
#[allow(clippy::too_many_arguments)]
pub fn bake(
    py: Python<'_>,
    scene: &Bound<'_, Scene>,
    seed: u64,
    max_depth: Option<u32>,
    progress: Option<Py<PyAny>>,
    max_memory: Option<&Bound<'_, PyAny>>,
    lightmap: bool,
    texel_density: Option<f32>,
    lightmap_size: Option<u32>,
    neighbours: Option<usize>,
    sectors: Option<usize>,
    gather: Option<u32>,
    gather_lights: Option<u32>,
    time: Option<f64>,
    rays: Option<&Bound<'_, PyAny>>,
    output: Option<PathBuf>,
    settings: Option<&Bound<'_, PyDict>>,
) -> PyResult<Py<PyAny>> {
    let lm_only = texel_density.is_some()
        || lightmap_size.is_some()
        || neighbours.is_some()
        || sectors.is_some()
        || gather.is_some()
        || gather_lights.is_some()
        || output.is_some();
    if lm_only && !lightmap {
        return Err(PyValueError::new_err(
            "texel_density, lightmap_size, neighbours, sectors, gather, gather_lights and output need lightmap=True",
        ));
    }
    let MethodConfig::Density(s) = method_config("density", settings)? else {
        unreachable!("the density row builds density settings")
    };
    let world = scene.get().world.clone();
    let mut job = BakeJob::new(
        SceneInput::World(world.clone()),
        density::Settings {
            seed,
            max_depth,
            ..s
        },
    );
    job.max_memory = count("max_memory", max_memory)?;
    job.max_memory_flag = "max_memory";
    job.time = time;
    job.rays = count("rays", rays)?;
    if lightmap {
        let d = Options::default();
        job.lightmap = Some(LightmapSettings {
            texel_density,
            size: lightmap_size,
            fast_packing: false,
            atlas: output,
            error: None,
            estimator: Options {
                neighbours: neighbours.or(d.neighbours),
                sectors: sectors.unwrap_or(d.sectors),
                ..d
            },
            gather: GatherOptions {
                rays: gather.unwrap_or(DEFAULT_RAYS),
                lights: gather_lights.or(gather).unwrap_or(DEFAULT_LIGHTS),
                seed: 0,
            },
        });
    }
    let checked = job.check().map_err(bake_error)?;

    let cancel = AtomicBool::new(false);
    let mut watch = Watch::new(progress.as_ref(), &cancel);
    let outcome = py.detach(|| {
        checked.run(None, Some(&cancel), &mut |e| match e {
            BakeEvent::Tick(t) => watch.report(Progress {
                passes: 0,
                rays: t.rays,
                elapsed: t.elapsed,
                fraction: t.bake_fraction(),
                phase: Some(t.phase.name().to_string()),
            }),
            BakeEvent::Texels { done, total } => watch.report(Progress {
                passes: 0,
                rays: 0,
                elapsed: 0.0,
                fraction: done as f64 / total.max(1) as f64,
                phase: Some("estimating texels".to_string()),
            }),
            _ => {}
        })
    });
    if let Some(e) = watch.failure() {
        return Err(e);
    }
    let outcome = outcome.map_err(bake_error)?;
    if let Some(lm) = outcome.lightmap {
        return Ok(Py::new(py, LightmapResult::new(py, lm, world.clone())?)?.into_any());
    }
    // a bake in this process (no dataflow) always gives its meshes
    let Baked {
        bake: b,
        lit,
        unlit,
    } = outcome
        .baked
        .ok_or_else(|| RenderError::new_err("the bake gave no meshes"))?;
    let meshes = (lit, unlit);
    let st = &b.stats;
    let stats = PyDict::new(py);
    stats.set_item("particles", st.particles)?;
    stats.set_item("hits", st.hits)?;
    stats.set_item("rays", st.rays)?;
    stats.set_item("surfaces", st.surfaces)?;
    stats.set_item("t_trace", st.t_trace)?;
    stats.set_item("t_estimate", st.t_estimate)?;
    stats.set_item("t_decimate", st.t_decimate)?;
    stats.set_item("tris_before", st.tris_before)?;
    stats.set_item("tris_after", st.tris_after)?;
    stats.set_item("max_brightness_error", st.max_brightness_error)?;
    stats.set_item("mean_brightness_error", st.mean_brightness_error)?;
    let bake = Bake {
        lit: Py::new(py, BakedMesh::new(py, &meshes.0, b.w0)?)?,
        unlit: Py::new(py, BakedMesh::new(py, &meshes.1, b.w0)?)?,
        w0: b.w0,
        stats: stats.unbind(),
        meshes,
        camera: world.scene.camera.clone(),
    };
    Ok(Py::new(py, bake)?.into_any())
}

/// A bake job's error as Python raises it: ValueError for bad settings,
/// RenderError when the bake cannot run (with the package's own words for
/// a scene whose emitters emit nothing).
fn bake_error(e: BakeError) -> PyErr {
    match e {
        BakeError::Settings(e) => PyValueError::new_err(e.0),
        BakeError::MaxDepth | BakeError::Budget(_) => PyValueError::new_err(e.to_string()),
        BakeError::Lightmap(lmbake::LightmapError::Settings(m)) => PyValueError::new_err(m),
        BakeError::NoLight { scene } => RenderError::new_err(format!(
            "{scene}: the scene has no emitters that emit light: nothing to bake"
        )),
        e => RenderError::new_err(e.to_string()),
    }
}
