"""Expected-depth renderer (R16): numba z-buffer rasteriser with label images.

``render_depth(cam, meshes)`` -> (H, W) float32 metres (0 = nothing);
``Renderer(cam).render(meshes)`` -> ``(depth, labels)`` views of reused buffers.
"""

from depthguard.render.renderer import Renderer, render_depth

__all__ = ["Renderer", "render_depth"]
