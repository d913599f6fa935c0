"""Types of kalos's native module (re-exported by ``kalos``)."""

import os
from typing import Any, Callable, Literal, Optional, Tuple, Union, overload

import numpy as np
import numpy.typing as npt

__version__: str

_Path = Union[str, "os.PathLike[str]"]
_Count = Union[int, str]
_Image = npt.ArrayLike
_F32Image = npt.NDArray[np.float32]
_Setting = Union[bool, int, float, str, "os.PathLike[str]", None]

class KalosError(Exception):
    """The base of the errors kalos raises (besides ValueError for bad arguments)."""

class SceneError(KalosError):
    """A scene file that cannot be loaded: the message names the file, the line and what was expected."""

class ImageError(KalosError):
    """An image that cannot be read or written: the message names the file."""

class RenderError(KalosError):
    """A render or bake that failed after it started (its setup, the memory limit, scratch files)."""

class Scene:
    """A scene ready to render, made by ``kalos.load``; read-only."""

    @property
    def source(self) -> str: ...
    @property
    def triangles(self) -> int: ...
    @property
    def vertices(self) -> int: ...
    @property
    def shapes(self) -> int: ...
    @property
    def materials(self) -> int: ...
    @property
    def emitters(self) -> int: ...
    @property
    def bounds(self) -> Tuple[Tuple[float, float, float], Tuple[float, float, float]]: ...
    @property
    def resolution(self) -> Tuple[int, int]:
        """(width, height); a render's image has shape (height, width, 3)."""
    @property
    def camera(self) -> dict[str, Any]:
        """width, height, fov_x (degrees), position, to_world (4x4 row-major)."""
    @property
    def sample_count(self) -> Optional[int]: ...
    @property
    def warnings(self) -> list[str]: ...
    @property
    def notes(self) -> list[str]: ...

class Progress:
    """Progress of a render or bake, passed to a ``progress`` callback."""

    @property
    def passes(self) -> int: ...
    @property
    def rays(self) -> int: ...
    @property
    def elapsed(self) -> float: ...
    @property
    def fraction(self) -> float: ...
    @property
    def phase(self) -> Optional[str]: ...

class RenderResult:
    """What ``kalos.render(..., full=True)`` returns."""

    @property
    def image(self) -> _F32Image: ...
    @property
    def method(self) -> str: ...
    @property
    def rays(self) -> int: ...
    @property
    def passes(self) -> int: ...
    @property
    def spp(self) -> float: ...
    @property
    def seconds(self) -> float: ...
    @property
    def log(self) -> list[dict[str, Any]]:
        """Rows with time_s, rays, spp and rel_mse (None without a reference)."""
    @property
    def report(self) -> Optional[str]: ...

class BakedMesh:
    """Triangles with per-vertex attributes as numpy arrays."""

    @property
    def positions(self) -> npt.NDArray[np.float32]: ...
    @property
    def normals(self) -> npt.NDArray[np.float32]: ...
    @property
    def colours(self) -> npt.NDArray[np.float32]: ...
    @property
    def radiance(self) -> npt.NDArray[np.float32]: ...
    @property
    def irradiance(self) -> npt.NDArray[np.float32]: ...
    @property
    def indices(self) -> npt.NDArray[np.uint32]: ...

class Bake:
    """A bake: the lit display mesh, the unlit surfaces, the white point, the figures."""

    @property
    def lit(self) -> BakedMesh: ...
    @property
    def unlit(self) -> BakedMesh: ...
    @property
    def w0(self) -> float: ...
    @property
    def stats(self) -> dict[str, Any]: ...
    @property
    def positions(self) -> npt.NDArray[np.float32]: ...
    @property
    def normals(self) -> npt.NDArray[np.float32]: ...
    @property
    def colours(self) -> npt.NDArray[np.float32]: ...
    @property
    def radiance(self) -> npt.NDArray[np.float32]: ...
    @property
    def irradiance(self) -> npt.NDArray[np.float32]: ...
    @property
    def indices(self) -> npt.NDArray[np.uint32]: ...
    def save(self, path: _Path) -> None:
        """Write a .glb (as ``kalos bake``) or a .ply (the lit mesh's irradiance)."""

def load(
    path: Optional[_Path] = None,
    *,
    defines: Optional[dict[str, str]] = None,
    res: Optional[Tuple[int, int]] = None,
    allow_read: Optional[list[_Path]] = None,
    max_memory: Optional[int] = None,
) -> Scene:
    """Load a scene file (or the built-in Cornell box when path is None).

    The scene may read only the files under its own folder; ``allow_read``
    (folders) widens that, as ``--allow-read``. ``max_memory`` (bytes) caps
    what the scene's data may take (default: the machine's memory)."""

@overload
def render(
    scene: Scene,
    method: str = "path",
    *,
    spp: Optional[float] = None,
    time: Optional[float] = None,
    rays: Optional[_Count] = None,
    seed: int = 0,
    max_depth: Optional[int] = None,
    progress: Optional[Callable[[Progress], Any]] = None,
    reference: Optional[_Image] = None,
    log_every: float = 0.0,
    max_memory: Optional[_Count] = None,
    full: Literal[False] = False,
    **settings: _Setting,
) -> _F32Image: ...
@overload
def render(
    scene: Scene,
    method: str = "path",
    *,
    spp: Optional[float] = None,
    time: Optional[float] = None,
    rays: Optional[_Count] = None,
    seed: int = 0,
    max_depth: Optional[int] = None,
    progress: Optional[Callable[[Progress], Any]] = None,
    reference: Optional[_Image] = None,
    log_every: float = 0.0,
    max_memory: Optional[_Count] = None,
    full: Literal[True],
    **settings: _Setting,
) -> RenderResult: ...
def methods() -> list[str]:
    """The method names ``render`` takes."""

def settings(method: str) -> dict[str, str]:
    """A method's settings: {keyword: help}."""

def set_threads(threads: int) -> None:
    """Set the worker thread count once, before the first render or bake."""

def read_image(path: _Path) -> _F32Image:
    """Read EXR, PFM, HDR (linear) or PNG, JPEG (sRGB, made linear)."""

def write_image(
    path: _Path,
    image: _Image,
    *,
    exposure: float = 0.0,
    tonemap: Literal["clamp", "reinhard", "aces"] = "clamp",
) -> None:
    """Write EXR, PFM or PNG atomically."""

def compare(image: _Image, reference: _Image) -> dict[str, Any]:
    """rel_mse, rmse, rel_l1, means, reference_means (as ``kalos compare``)."""

def error_image(image: _Image, reference: _Image) -> _F32Image:
    """The false-colour relative-error image of ``kalos compare --error-image``."""

def bake(
    scene: Scene,
    *,
    seed: int = 0,
    max_depth: Optional[int] = None,
    progress: Optional[Callable[[Progress], Any]] = None,
    max_memory: Optional[_Count] = None,
    **settings: _Setting,
) -> Bake:
    """Bake view-independent lighting by density estimation (as ``kalos bake``)."""
