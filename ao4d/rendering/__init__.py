"""From a 4D scene to a 3D image volume: the 4D camera, lights, the render pipeline, screen-space
AO and compositing.

==================================  ==============================================================
:mod:`~ao4d.rendering.camera`       :class:`Camera4D`: Hollasch's viewing model, voxel rays,
                                    projection; the 3D image size check
:mod:`~ao4d.rendering.lighting`     lights and the local shading terms (Lambert, Blinn-Phong,
                                    depth cue), pure numpy
:mod:`~ao4d.rendering.pipeline`     :func:`render` as a short pipeline: primary rays, AO at hits,
                                    shadows, layers composited -> :class:`RenderResult`
:mod:`~ao4d.rendering.screen_ao`    screen-space AO in 4D from the image's own depth volume
:mod:`~ao4d.rendering.compositing`  front-to-back "over" (Porter & Duff), the one copy
==================================  ==============================================================

Data flow one way: camera, lighting, compositing <- screen_ao <- pipeline. The names below load
on first use: importing this package imports neither numpy nor pyopencl.
"""

from __future__ import annotations

from .._lazy import lazy_face

__all__ = [
    "Camera4D",
    "Light",
    "RenderResult",
    "render",
]

__getattr__, __dir__ = lazy_face(
    __name__,
    {
        "Camera4D": "camera:Camera4D",
        "Light": "lighting:Light",
        "RenderResult": "pipeline:RenderResult",
        "render": "pipeline:render",
    },
)
