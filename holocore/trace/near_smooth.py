"""Near-smooth surfaces: rough conductors and dielectrics whose roughness still keeps an image (docs/physics.md,
"Near-smooth surfaces").

The paper splits vertices into delta (the coherent chain goes on) and non-delta (the image point P is there). A
GGX surface of small roughness alpha (polished metal, frosted-free acrylic) is neither: it reflects or refracts
a blurred image at the apparent depth of what it shows. Here such a surface continues the chain through a
micro-normal sampled from its lobe: the ray leaves in the sampled direction, the differentials are reflected or
refracted about the micro-normal (:func:`micro_normal`), and the chain's throughput takes the sample's weight.
Each ray of a sub-hologram samples its own micro-normal, so the image point behind the surface is spread over the
lobe: the random phase of a rough interface, whose angular spectrum is the lobe (a coherence area of about
lambda / 2 alpha on the surface), sampled ray by ray. P is then whatever the surface shows (a diffuse wall, a
light), whose radiance converges as a diffuse P's does, not the glossy lobe's two-sample estimate.

Only BSDFs whose every lobe is glossy qualify (``roughconductor``, ``roughdielectric``): a BSDF that mixes a
glossy coat with a diffuse base (``roughplastic``) keeps its image point on the surface, as before. Above
``holocore.scene.features.NEAR_SMOOTH_MAX_ALPHA`` the lobe is wide enough that the highlight sits on the surface
for an eye (its position changes little across a pupil against its width) and the surface stays P.
"""

from __future__ import annotations

import numpy as np

from holocore.runtime.mitsuba_env import mitsuba
from holocore.scene.features import near_smooth_shapes

__all__ = ["near_smooth_table", "is_near_smooth", "micro_normal"]


def near_smooth_table(scene):
    """A Dr.Jit Bool array indexed by a BSDF's registry id: True for the near-smooth BSDFs of ``scene``; None when
    it has none (the kernel then compiles without the test)."""
    mi = mitsuba()
    import drjit as dr

    ids = [int(dr.reinterpret_array(mi.UInt32, mi.BSDFPtr(sh.bsdf()))[0]) for _i, sh, _a in near_smooth_shapes(scene)]
    if not ids:
        return None
    table = np.zeros(max(ids) + 1, dtype=bool)
    table[ids] = True
    return mi.Bool(table)


def is_near_smooth(table, bsdf, active):
    """Per lane: whether ``bsdf`` (mi.BSDFPtr) is in ``table`` (:func:`near_smooth_table`)."""
    mi = mitsuba()
    import drjit as dr

    idx = dr.reinterpret_array(mi.UInt32, bsdf)
    inside = active & (idx < dr.width(table))
    return dr.gather(mi.Bool, table, dr.select(inside, idx, 0), inside)


def micro_normal(D, D_new, eta, is_refl):
    """The micro-normal (unit, float64) that turns the incoming direction D into D_new: the half vector
    D_new - D for a reflection, D - eta D_new for a refraction (eta: the sample's relative index n2 / n1;
    Walter et al. 2007, Eq. 16)."""
    import drjit as dr

    m = dr.select(is_refl, D_new - D, D - eta * D_new)
    return dr.normalize(m)
