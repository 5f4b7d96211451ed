"""Indirect light of the spot at the camera: virtual point lights, gathered with shadow rays (instant radiosity).

Beside the direct term (lighting.py), not inside it, as Mitsuba keeps `direct` and `path` apart: this
package returns the irradiance E_indirect (W/m^2, RGB) that bounced light brings to each pixel's surface,
and the glossy term its lobe sends to the eye; the shader reflects both (material.py). Per frame, one file a step:

1. light_paths.py: virtual lights where the spot's rays land, bounce after bounce (the directions: sampling.py).
2. grid.py, shadow_rays.py: every `gather_stride` pixels a gather point sums what the lights of its interleaved
   subset bring it past one shadow ray each; near_field.py brings back what the lights' clamp leaves out.
3. filter.py: each gather point takes the plane fitted through the block of points around it (every subset once),
   weighted by how alike the surfaces are, at its own place; and then once more.
4. upsample.py: every block of pixels mixes its four nearest gather points under the same weights; orphan blocks
   (a surface narrower than the stride) gather on a finer grid of their own (gather.py, `IndirectGather`).

The pattern of directions is drawn once from the job's seed: a still camera gives the same frame every
time (no flicker), and the same job gives the same bytes.
"""

from pipeline.render.indirect.gather import IndirectGather
from pipeline.render.indirect.light_paths import LightPaths, VirtualLights

__all__ = ["IndirectGather", "LightPaths", "VirtualLights"]
