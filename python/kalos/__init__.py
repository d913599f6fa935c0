"""kalos: a global-illumination renderer and light baker, on numpy arrays.

    import kalos
    scene = kalos.load("scenes/cbox/cbox.xml")       # or kalos.load() for the built-in box
    img = kalos.render(scene, method="plb", spp=16, seed=7, lambda_=2)
    ref = kalos.read_image("refs/cbox.pfm")
    print(kalos.compare(img, ref)["rel_mse"])

Every function is documented (``help(kalos.render)``); the methods and their
settings are listed by ``kalos.methods()`` and ``kalos.settings(name)``.
"""

from ._kalos import (
    Bake,
    BakedMesh,
    ImageError,
    KalosError,
    Progress,
    RenderError,
    RenderResult,
    Scene,
    SceneError,
    __version__,
    bake,
    compare,
    error_image,
    load,
    methods,
    read_image,
    render,
    set_threads,
    settings,
    write_image,
)

__all__ = [
    "Bake",
    "BakedMesh",
    "ImageError",
    "KalosError",
    "Progress",
    "RenderError",
    "RenderResult",
    "Scene",
    "SceneError",
    "__version__",
    "bake",
    "compare",
    "error_image",
    "load",
    "methods",
    "read_image",
    "render",
    "set_threads",
    "settings",
    "write_image",
]
