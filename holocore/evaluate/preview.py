"""Pictures a person can look at: simulated views of an SLM field at chosen focus depths (docs/design.md §7),
composited to RGB and written as PNG contact sheets."""

from __future__ import annotations

from pathlib import Path
from typing import Optional, Sequence

import numpy as np

from holocore.display.optics import channel_of
from holocore.formats.meta import MetaLike, parse_view_meta
from holocore.optics.fieldsource import SlmFieldSource

__all__ = ["view_rgb", "views_rgb", "focal_sweep_png", "to_png8", "depth_words"]


def depth_words(z_m: float, meta: MetaLike) -> str:
    """Where a hologram depth ``z_m`` (m from the SLM) lies in the scene: z = z_inf + f^2 / d (docs/design.md §3)."""
    meta = parse_view_meta(meta)
    dz = z_m - meta.z_inf_m
    if abs(dz) < 1e-12:
        return "optical infinity"
    if dz < 0:
        return "beyond infinity"
    return f"scene distance {meta.focal_length_m ** 2 / dz:.3g} m"


def views_rgb(slm_field, meta: MetaLike, *, focus_z_m, pupil_diameter_m: float = 4e-3,
              view_offset_m: tuple[float, float] = (0.0, 0.0), device=None,
              memory_budget_bytes: Optional[int] = None) -> list[np.ndarray]:
    """Frame-averaged intensity [H, W, 3] seen with the eye focused at each hologram depth of ``focus_z_m``.

    ``slm_field``: a complex [F, C, H, W] array or a chunked source
    (:func:`holocore.optics.fieldsource.open_slm_field`), read in chunks of frames that fit
    ``memory_budget_bytes``; ``device``: where the FFTs run."""
    meta = parse_view_meta(meta)
    import torch

    from holocore.optics.viewing import view_intensities

    if isinstance(slm_field, SlmFieldSource):
        src = slm_field
    else:
        src = SlmFieldSource.from_array(torch.from_numpy(np.ascontiguousarray(slm_field)))
    wl = list(meta.wavelengths_m)
    inten = view_intensities(src, wavelengths_m=wl, pitch_m=float(meta.pitch_m),
                             focal_length_m=meta.focal_length_m, pupil_diameter_m=pupil_diameter_m,
                             distances_m=[float(z) for z in focus_z_m], view_offset_m=view_offset_m, device=device,
                             memory_budget_bytes=memory_budget_bytes,
                             fourier_filter=meta.fourier_filter, pixel_orders=None).cpu().numpy()
    out = []
    for one in inten:
        H, W = one.shape[-2:]
        rgb = np.zeros((H, W, 3), dtype=np.float64)
        for c, lam in enumerate(wl):
            rgb[..., channel_of(lam)] += one[c]
        if len(wl) == 1:
            rgb[...] = one[0][..., None]
        out.append(rgb)
    return out


def view_rgb(slm_field, meta: MetaLike, *, focus_z_m: float, pupil_diameter_m: float = 4e-3,
             view_offset_m: tuple[float, float] = (0.0, 0.0), device=None,
             memory_budget_bytes: Optional[int] = None) -> np.ndarray:
    """Frame-averaged intensity [H, W, 3] seen with the eye focused at hologram depth ``focus_z_m``."""
    return views_rgb(slm_field, meta, focus_z_m=[focus_z_m], pupil_diameter_m=pupil_diameter_m,
                     view_offset_m=view_offset_m, device=device, memory_budget_bytes=memory_budget_bytes)[0]


def to_png8(rgb: np.ndarray, *, white: Optional[float] = None, gamma: float = 2.2) -> np.ndarray:
    """Linear intensity -> 8-bit sRGB-ish image (white = 99.5th percentile unless given)."""
    w = white if white is not None else float(np.percentile(rgb, 99.5)) or 1.0
    x = np.clip(rgb / max(w, 1e-30), 0.0, 1.0) ** (1.0 / gamma)
    return (x * 255.0 + 0.5).astype(np.uint8)


def focus_depths(meta: MetaLike, n_planes: int) -> list[float]:
    """n hologram depths spread over the scene's image volume (near to far), from the render's analysis (else
    ``z_inf_m``: a mapping with just those does)."""
    ana = meta.get("analysis") or {}
    near, far = ana.get("z_near_holo_m"), ana.get("z_far_holo_m")
    if near is None or far is None:
        near = far = float(meta["z_inf_m"])
    return list(np.linspace(far, near, n_planes)) if n_planes > 1 else [0.5 * (near + far)]


def focal_sweep_png(slm_field: np.ndarray, meta: MetaLike, path: str | Path, *, n_planes: int = 3,
                    depths_m: Optional[Sequence[float]] = None, pupil_diameter_m: float = 4e-3) -> Path:
    """A row of simulated views focused from far to near, one shared white level; returns the path."""
    from PIL import Image, ImageDraw

    zs = list(depths_m) if depths_m is not None else focus_depths(meta, n_planes)
    views = [view_rgb(slm_field, meta, focus_z_m=z, pupil_diameter_m=pupil_diameter_m) for z in zs]
    white = float(np.percentile(np.stack(views), 99.5)) or 1.0
    tiles = [to_png8(v, white=white) for v in views]
    H, W = tiles[0].shape[:2]
    sheet = Image.new("RGB", (W * len(tiles), H + 14), (0, 0, 0))
    draw = ImageDraw.Draw(sheet)
    for i, (tile, z) in enumerate(zip(tiles, zs)):
        sheet.paste(Image.fromarray(tile), (i * W, 14))
        draw.text((i * W + 2, 1), f"focus {z * 1e3:.2f} mm", fill=(255, 255, 255))
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    sheet.save(path)
    return path
