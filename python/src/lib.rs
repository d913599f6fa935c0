//! The native half of the Python package `kalos` (PyO3): scenes, renders,
//! metrics, images and bakes on numpy arrays, all through the library API
//! (`kalos::scene::load`, `kalos::render::Render`, `kalos::metrics`,
//! `kalos::image_io`, `kalos::methods::density::bake_within`). The module
//! `kalos` (python/kalos/__init__.py) re-exports it; python/kalos/_kalos.pyi
//! holds the types.
//!
//! Long work (loading, rendering, baking) runs with the interpreter
//! released, so other Python threads go on. Ctrl-C is seen through
//! `PyErr_CheckSignals` from the progress path, which sets the driver's
//! cancel flag; the call then raises `KeyboardInterrupt`.

#![allow(clippy::disallowed_methods)] // std::fs is denied only in the scene loaders (clippy.toml)
mod bake;
mod images;
mod render;
mod scene;

use pyo3::create_exception;
use pyo3::exceptions::PyException;
use pyo3::prelude::*;

create_exception!(
    kalos,
    KalosError,
    PyException,
    "The base of the errors kalos raises (besides ValueError for bad arguments)."
);
create_exception!(
    kalos,
    SceneError,
    KalosError,
    "A scene file that cannot be loaded: the message names the file, the line and what was expected."
);
create_exception!(
    kalos,
    ImageError,
    KalosError,
    "An image that cannot be read or written: the message names the file."
);
create_exception!(
    kalos,
    RenderError,
    KalosError,
    "A render or bake that failed after it started (its setup, the memory limit, scratch files)."
);

/// The native module, `kalos._kalos`.
#[pymodule]
fn _kalos(m: &Bound<'_, PyModule>) -> PyResult<()> {
    let py = m.py();
    m.add("__version__", env!("CARGO_PKG_VERSION"))?;
    m.add("KalosError", py.get_type::<KalosError>())?;
    m.add("SceneError", py.get_type::<SceneError>())?;
    m.add("ImageError", py.get_type::<ImageError>())?;
    m.add("RenderError", py.get_type::<RenderError>())?;
    m.add_class::<scene::Scene>()?;
    m.add_class::<render::Progress>()?;
    m.add_class::<render::RenderResult>()?;
    m.add_class::<bake::Bake>()?;
    m.add_class::<bake::BakedMesh>()?;
    m.add_function(wrap_pyfunction!(scene::load, m)?)?;
    m.add_function(wrap_pyfunction!(render::render, m)?)?;
    m.add_function(wrap_pyfunction!(render::methods, m)?)?;
    m.add_function(wrap_pyfunction!(render::settings, m)?)?;
    m.add_function(wrap_pyfunction!(render::set_threads, m)?)?;
    m.add_function(wrap_pyfunction!(images::read_image, m)?)?;
    m.add_function(wrap_pyfunction!(images::write_image, m)?)?;
    m.add_function(wrap_pyfunction!(images::compare, m)?)?;
    m.add_function(wrap_pyfunction!(images::error_image, m)?)?;
    m.add_function(wrap_pyfunction!(bake::bake, m)?)?;
    Ok(())
}
