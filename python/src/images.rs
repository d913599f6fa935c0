//! Images as numpy arrays: `kalos.read_image`, `kalos.write_image`,
//! `kalos.compare` and `kalos.error_image`, on `kalos::image_io` and
//! `kalos::metrics`.

use std::path::PathBuf;

use glam::Vec3;
use numpy::{PyArray1, PyArray3, PyArrayMethods, PyUntypedArrayMethods};
use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;
use pyo3::types::PyDict;

use kalos::film::Image;
use kalos::image_io::{self, PngOptions, Tonemap};
use kalos::metrics;

use crate::ImageError;

/// `img` as a float32 array of shape (height, width, 3).
pub(crate) fn image_to_array<'py>(
    py: Python<'py>,
    img: &Image,
) -> PyResult<Bound<'py, PyArray3<f32>>> {
    let flat: Vec<f32> = img.data.iter().flat_map(|v| v.to_array()).collect();
    PyArray1::from_vec(py, flat).reshape([img.height as usize, img.width as usize, 3])
}

/// An image from any array-like of shape (height, width, 3) (converted to
/// float32); `what` names the argument in errors.
pub(crate) fn image_from_array(what: &str, obj: &Bound<'_, PyAny>) -> PyResult<Image> {
    let np = obj.py().import("numpy")?;
    let arr = np.call_method1("ascontiguousarray", (obj, "float32"))?;
    let arr = arr.cast::<numpy::PyArrayDyn<f32>>()?;
    let shape = arr.shape().to_vec();
    if shape.len() != 3 || shape[2] != 3 || shape[0] == 0 || shape[1] == 0 {
        // the shape as Python prints it
        let dims: Vec<String> = shape.iter().map(|d| d.to_string()).collect();
        let comma = if dims.len() == 1 { "," } else { "" };
        return Err(PyValueError::new_err(format!(
            "{what}: expected an RGB image, an array of shape (height, width, 3), got shape ({}{comma})",
            dims.join(", ")
        )));
    }
    let (h, w) = (shape[0], shape[1]);
    if w > u32::MAX as usize || h > u32::MAX as usize {
        return Err(PyValueError::new_err(format!(
            "{what}: {w}x{h} is too large"
        )));
    }
    let ro = arr.readonly();
    let data = ro
        .as_slice()
        .map_err(|e| PyValueError::new_err(format!("{what}: {e}")))?
        .chunks_exact(3)
        .map(|c| Vec3::new(c[0], c[1], c[2]))
        .collect();
    Ok(Image {
        width: w as u32,
        height: h as u32,
        data,
    })
}

/// Reads an image as float32 (height, width, 3), linear: EXR, PFM and HDR
/// as stored; PNG and JPEG are taken as sRGB and made linear. Raises
/// ImageError naming the file.
#[pyfunction]
pub fn read_image<'py>(py: Python<'py>, path: PathBuf) -> PyResult<Bound<'py, PyArray3<f32>>> {
    let img = py
        .detach(|| image_io::read_image(&path))
        .map_err(|e| ImageError::new_err(e.to_string()))?;
    image_to_array(py, &img)
}

/// Writes `image` (an array of shape (height, width, 3), linear radiance)
/// to `path`, in the format its extension names: .exr and .pfm (32-bit
/// float), .png (8-bit sRGB after `exposure` stops and `tonemap`, "clamp",
/// "reinhard" or "aces"). The file is written atomically (a temporary file,
/// then a rename). Raises ImageError naming the file.
#[pyfunction]
#[pyo3(signature = (path, image, *, exposure=0.0, tonemap="clamp"))]
pub fn write_image(
    py: Python<'_>,
    path: PathBuf,
    image: &Bound<'_, PyAny>,
    exposure: f32,
    tonemap: &str,
) -> PyResult<()> {
    let tonemap = match tonemap {
        "clamp" => Tonemap::Clamp,
        "reinhard" => Tonemap::Reinhard,
        "aces" => Tonemap::Aces,
        _ => {
            return Err(PyValueError::new_err(format!(
                "tonemap: expected clamp, reinhard or aces, got '{tonemap}'"
            )))
        }
    };
    if !exposure.is_finite() {
        return Err(PyValueError::new_err(format!(
            "exposure: expected a finite number of stops, got {exposure}"
        )));
    }
    let img = image_from_array("image", image)?;
    let opts = PngOptions { exposure, tonemap };
    py.detach(|| image_io::write_image(&path, &img, &opts))
        .map_err(|e| ImageError::new_err(e.to_string()))
}

/// The image and the reference as kalos images of one size, with no NaN
/// or infinite pixel (every figure would be NaN).
fn pair(image: &Bound<'_, PyAny>, reference: &Bound<'_, PyAny>) -> PyResult<(Image, Image)> {
    let img = image_from_array("image", image)?;
    let r = image_from_array("reference", reference)?;
    if (img.width, img.height) != (r.width, r.height) {
        return Err(PyValueError::new_err(format!(
            "the image is {}x{} but the reference is {}x{}",
            img.width, img.height, r.width, r.height
        )));
    }
    for (what, i) in [("the image", &img), ("the reference", &r)] {
        let bad = metrics::non_finite_pixels(i);
        if bad > 0 {
            return Err(PyValueError::new_err(format!(
                "{what}: {bad} of its {} pixels are NaN or infinite, so every figure would be NaN",
                i.data.len()
            )));
        }
    }
    Ok((img, r))
}

/// The figures `kalos compare` prints for `image` against `reference`
/// (arrays of one shape (height, width, 3), linear radiance): a dict with
/// rel_mse (as defined in refs/README.md), rmse, rel_l1, means and
/// reference_means (the channel means, (r, g, b)). Raises ValueError for
/// arrays of different shapes or with NaN or infinite pixels.
#[pyfunction]
pub fn compare<'py>(
    py: Python<'py>,
    image: &Bound<'py, PyAny>,
    reference: &Bound<'py, PyAny>,
) -> PyResult<Bound<'py, PyDict>> {
    let (img, r) = pair(image, reference)?;
    let c = metrics::Comparison::new(&img, &r).map_err(|e| PyValueError::new_err(e.to_string()))?;
    let d = PyDict::new(py);
    d.set_item("rel_mse", c.rel_mse)?;
    d.set_item("rmse", c.rmse)?;
    d.set_item("rel_l1", c.rel_l1)?;
    d.set_item("means", (c.means.x, c.means.y, c.means.z))?;
    let m = c.reference_means;
    d.set_item("reference_means", (m.x, m.y, m.z))?;
    Ok(d)
}

/// The false-colour relative-error image of `kalos compare --error-image`,
/// float32 (height, width, 3).
#[pyfunction]
pub fn error_image<'py>(
    py: Python<'py>,
    image: &Bound<'py, PyAny>,
    reference: &Bound<'py, PyAny>,
) -> PyResult<Bound<'py, PyArray3<f32>>> {
    let (img, r) = pair(image, reference)?;
    let e =
        metrics::false_color_error(&img, &r).map_err(|e| PyValueError::new_err(e.to_string()))?;
    image_to_array(py, &e)
}
