//! `kalos.render`: a method with its settings (keyword arguments read by
//! the command line's own parsers), a budget, a progress callback and
//! Ctrl-C, through the library's render job (`kalos::job::RenderJob`).

use std::sync::atomic::{AtomicBool, Ordering};

use numpy::PyArray3;
use pyo3::exceptions::{PyTypeError, PyValueError};
use pyo3::prelude::*;
use pyo3::types::{PyBool, PyDict, PyFloat, PyInt, PyString};

use kalos::job::{JobError, Reference, RenderEvent, RenderJob, SceneInput};
use kalos::methods::{self as kmethods, cli as mcli, Budget, Common, MethodConfig};

use crate::images::{image_from_array, image_to_array};
use crate::scene::Scene;
use crate::RenderError;

/// Progress of a render or a bake, passed to the `progress` callback after
/// every pass, or every few passes for `path`, which takes up to a quarter
/// of a second of them at a time (and between units of a setup's work).
#[pyclass(frozen, get_all, module = "kalos")]
#[derive(Clone)]
pub struct Progress {
    /// Passes done.
    pub passes: u64,
    /// Rays traced so far.
    pub rays: u64,
    /// Seconds since the render started.
    pub elapsed: f64,
    /// Fraction of the budget used, in [0, 1].
    pub fraction: f64,
    /// What a setup is doing (density's bake names its phases); None
    /// during the passes.
    pub phase: Option<String>,
}

#[pymethods]
impl Progress {
    fn __repr__(&self) -> String {
        format!(
            "<kalos.Progress {} passes, {} rays, {:.2} s, {:.0} %{}>",
            self.passes,
            self.rays,
            self.elapsed,
            100.0 * self.fraction,
            self.phase
                .as_deref()
                .map(|p| format!(", {p}"))
                .unwrap_or_default()
        )
    }
}

/// What `kalos.render(..., full=True)` returns: the image and the render's
/// figures.
#[pyclass(frozen, module = "kalos")]
pub struct RenderResult {
    /// The image, float32, shape (height, width, 3), linear radiance.
    #[pyo3(get)]
    image: Py<PyArray3<f32>>,
    /// The method's name.
    #[pyo3(get)]
    method: String,
    /// Rays traced (setup included).
    #[pyo3(get)]
    rays: u64,
    /// Passes run.
    #[pyo3(get)]
    passes: u64,
    /// Samples per pixel, or the method's equivalent.
    #[pyo3(get)]
    spp: f64,
    /// Render time in seconds (setup included, logging excluded).
    #[pyo3(get)]
    seconds: f64,
    /// The convergence log: one dict per row (time_s, rays, spp, rel_mse),
    /// every `log_every` seconds and at the end; rel_mse is None without a
    /// reference.
    #[pyo3(get)]
    log: Vec<Py<PyDict>>,
    /// The method's own statistics, one line, when it keeps any.
    #[pyo3(get)]
    report: Option<String>,
}

#[pymethods]
impl RenderResult {
    fn __repr__(&self) -> String {
        format!(
            "<kalos.RenderResult {}: {} passes, {:.1} spp, {} rays, {:.2} s>",
            self.method, self.passes, self.spp, self.rays, self.seconds
        )
    }
}

/// Watches a long call from its progress path: runs the user's callback
/// and Python's signal handlers (Ctrl-C raises KeyboardInterrupt there),
/// and on the first exception sets the cancel flag and keeps the exception
/// to raise once the call has returned.
pub(crate) struct Watch<'a> {
    callback: Option<&'a Py<PyAny>>,
    cancel: &'a AtomicBool,
    failure: Option<PyErr>,
}

impl<'a> Watch<'a> {
    pub(crate) fn new(callback: Option<&'a Py<PyAny>>, cancel: &'a AtomicBool) -> Self {
        Watch {
            callback,
            cancel,
            failure: None,
        }
    }

    /// Called from the progress path, with the interpreter released.
    pub(crate) fn report(&mut self, progress: Progress) {
        if self.failure.is_some() {
            return;
        }
        let r = Python::attach(|py| {
            py.check_signals()?;
            if let Some(cb) = self.callback {
                cb.call1(py, (progress,))?;
            }
            Ok::<_, PyErr>(())
        });
        if let Err(e) = r {
            self.failure = Some(e);
            self.cancel.store(true, Ordering::Relaxed);
        }
    }

    /// The exception to raise, if the callback or a signal handler raised.
    pub(crate) fn failure(self) -> Option<PyErr> {
        self.failure
    }
}

/// One keyword argument's value as the command line would spell it: a
/// bool as on/off (a switch takes on to be given), a number or a string as
/// written, a path through `os.fspath`.
fn setting_text(name: &str, v: &Bound<'_, PyAny>) -> PyResult<String> {
    if v.is_instance_of::<PyBool>() {
        let on: bool = v.extract()?;
        return Ok(if on { "on" } else { "off" }.to_string());
    }
    if v.is_instance_of::<PyString>() {
        return v.extract();
    }
    if v.is_instance_of::<PyInt>() || v.is_instance_of::<PyFloat>() {
        return Ok(v.str()?.to_string());
    }
    if v.hasattr("__fspath__")? {
        let os = v.py().import("os")?;
        return Ok(os.call_method1("fspath", (v,))?.str()?.to_string());
    }
    Err(PyTypeError::new_err(format!(
        "setting {name}: expected a bool, number, string or path, got {}",
        v.get_type().name()?
    )))
}

/// The method's settings from keyword arguments: `rr_depth=3` is
/// `--rr-depth 3`; a trailing underscore is dropped (`lambda_=2`, since
/// `lambda` is a Python keyword; `**{"lambda": 2}` works too); None leaves
/// the default.
pub(crate) fn method_config(
    method: &str,
    settings: Option<&Bound<'_, PyDict>>,
) -> PyResult<MethodConfig> {
    let mut pairs = Vec::new();
    if let Some(d) = settings {
        for (k, v) in d.iter() {
            let key: String = k.extract()?;
            if v.is_none() {
                continue;
            }
            let name = key.trim_end_matches('_').replace('_', "-");
            pairs.push((name.clone(), setting_text(&name, &v)?));
        }
    }
    mcli::config_from_pairs(method, &pairs).map_err(|e| PyValueError::new_err(e.0))
}

/// A count given as an int or as text such as "30M" (the command line's
/// parser).
pub(crate) fn count(name: &str, v: Option<&Bound<'_, PyAny>>) -> PyResult<Option<u64>> {
    let Some(v) = v else { return Ok(None) };
    if v.is_none() {
        return Ok(None);
    }
    let text = if v.is_instance_of::<PyString>() {
        v.extract::<String>()?
    } else if v.is_instance_of::<PyInt>() && !v.is_instance_of::<PyBool>() {
        v.str()?.to_string()
    } else {
        return Err(PyTypeError::new_err(format!(
            "{name}: expected an int or a count such as \"30M\", got {}",
            v.get_type().name()?
        )));
    };
    mcli::parse_count(&text)
        .map(Some)
        .map_err(|e| PyValueError::new_err(format!("{name}: {e}")))
}

/// Renders `scene` with `method` and returns the image as a float32 numpy
/// array of shape (height, width, 3), linear radiance.
///
/// The budget is `spp`, `time` (seconds) and/or `rays` (an int or "30M");
/// the first reached stops; with none, the scene's own sample count or 16
/// spp. `seed` gives the same image as `kalos render --seed` and whatever
/// the thread count. `max_depth` is Mitsuba's. The method's settings are
/// keyword arguments named as its command-line flags (`rr_depth=3` for
/// `--rr-depth 3`, `lambda_=2` or `**{"lambda": 2}`, `camera_pass=False`,
/// `no_decimate=True`), checked with the command line's messages;
/// `kalos.settings(method)` lists them.
///
/// `progress(p)` is called with a `kalos.Progress` after every pass (every
/// few passes for `path`); an
/// exception it raises stops the render and is raised. Ctrl-C stops the
/// render after the current pass and raises KeyboardInterrupt. The
/// interpreter is released while rendering.
///
/// With `reference` (an array of the image's shape) and `log_every`
/// (seconds), the convergence log records the relMSE; `full=True` returns
/// a `kalos.RenderResult` (image, rays, passes, spp, seconds, log) instead
/// of the array. Raises ValueError for bad arguments and settings,
/// RenderError when the render cannot run.
#[pyfunction]
#[pyo3(signature = (
    scene, method="path", *, spp=None, time=None, rays=None, seed=0, max_depth=None,
    progress=None, reference=None, log_every=0.0, max_memory=None, full=false, **settings
))]
#[allow(clippy::too_many_arguments)]
pub fn render<'py>(
    py: Python<'py>,
    scene: &Bound<'py, Scene>,
    method: &str,
    spp: Option<f64>,
    time: Option<f64>,
    rays: Option<&Bound<'py, PyAny>>,
    seed: u64,
    max_depth: Option<u32>,
    progress: Option<Py<PyAny>>,
    reference: Option<&Bound<'py, PyAny>>,
    log_every: f64,
    max_memory: Option<&Bound<'py, PyAny>>,
    full: bool,
    settings: Option<&Bound<'py, PyDict>>,
) -> PyResult<Py<PyAny>> {
    // Check what can be checked before any work, as `kalos render` does
    let cfg = method_config(method, settings)?;
    let rays = count("rays", rays)?;
    let max_memory = count("max_memory", max_memory)?;
    if !(log_every.is_finite() && log_every >= 0.0) {
        return Err(PyValueError::new_err(format!(
            "log_every must be a finite number ≥ 0, got {log_every}"
        )));
    }
    let reference = match reference {
        Some(r) if !r.is_none() => Some(Reference::Image(image_from_array("reference", r)?)),
        _ => None,
    };
    let mut job = RenderJob::new(SceneInput::World(scene.get().world.clone()), cfg);
    job.common = Common { seed, max_depth };
    job.budget = Budget {
        spp,
        time,
        rays,
        passes: None,
    };
    job.reference = reference;
    job.log_every = log_every;
    job.max_memory = max_memory;
    job.max_memory_flag = "max_memory";
    let checked = job.check().map_err(job_error)?;

    // Render with the interpreter released; the progress path runs the
    // callback and the signal handlers
    let cancel = AtomicBool::new(false);
    let mut watch = Watch::new(progress.as_ref(), &cancel);
    let outcome = py.detach(|| {
        checked.run(Some(&cancel), &mut |e| {
            if let RenderEvent::Progress(p) = e {
                watch.report(Progress {
                    passes: p.passes,
                    rays: p.rays,
                    elapsed: p.elapsed,
                    fraction: p.fraction,
                    phase: p.phase.map(str::to_string),
                })
            }
        })
    });
    if let Some(e) = watch.failure() {
        return Err(e);
    }
    let result = outcome.map_err(job_error)?.result;
    let image = image_to_array(py, &result.image)?;
    if !full {
        return Ok(image.into_any().unbind());
    }
    let log = result
        .log
        .iter()
        .map(|row| {
            let d = PyDict::new(py);
            d.set_item("time_s", row.time_s)?;
            d.set_item("rays", row.rays)?;
            d.set_item("spp", row.spp)?;
            d.set_item("rel_mse", row.rel_mse)?;
            Ok(d.unbind())
        })
        .collect::<PyResult<Vec<_>>>()?;
    let full = RenderResult {
        image: image.unbind(),
        method: result.method.to_string(),
        rays: result.rays,
        passes: result.passes,
        spp: result.spp,
        seconds: result.seconds,
        log,
        report: result.report,
    };
    Ok(Py::new(py, full)?.into_any())
}

/// A render job's error as Python raises it: ValueError for bad arguments
/// and settings, RenderError when the render cannot run (with the
/// package's own words for a scene whose emitters emit nothing).
fn job_error(e: JobError) -> PyErr {
    match e {
        JobError::Settings(e) => PyValueError::new_err(e.0),
        JobError::ReferenceSize { .. } => PyValueError::new_err(e.to_string()),
        JobError::NoLight { scene, .. } => RenderError::new_err(format!(
            "{scene}: the scene has no emitters that emit light, so the image would be black"
        )),
        JobError::Render(e) => RenderError::new_err(e.0),
        e => RenderError::new_err(e.to_string()),
    }
}

/// The names of the methods, as `method=` takes them.
#[pyfunction]
pub fn methods() -> Vec<&'static str> {
    kmethods::names()
}

/// The settings of `method`: {keyword name: help text}. The keyword is the
/// command-line flag with '_' for '-' (`rr_depth` for `--rr-depth`).
#[pyfunction]
pub fn settings<'py>(py: Python<'py>, method: &str) -> PyResult<Bound<'py, PyDict>> {
    let info = kmethods::by_name(method).map_err(|e| PyValueError::new_err(e.0))?;
    let cmd = (info.args)(clap::Command::new(info.name));
    let d = PyDict::new(py);
    for a in cmd.get_arguments() {
        if let Some(long) = a.get_long() {
            let help = a.get_help().map(|h| h.to_string()).unwrap_or_default();
            d.set_item(long.replace('-', "_"), help)?;
        }
    }
    Ok(d)
}

/// Sets the number of worker threads for every later render and bake (as
/// `kalos render --threads`). It can be set once, before the first render
/// or bake; by default kalos uses every core. The image does not depend on
/// it.
#[pyfunction]
pub fn set_threads(threads: usize) -> PyResult<()> {
    kalos::job::set_threads(threads).map_err(|_| {
        PyValueError::new_err(
            "the thread count can be set only once, before the first render or bake",
        )
    })
}
