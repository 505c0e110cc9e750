"""The compute device, chosen once per process: ``--device cpu|cuda|auto`` on the CLI or ``HOLO_DEVICE``.

The choice is kept in ``HOLO_DEVICE`` (so child processes, the service's workers included, inherit it) and read
by :func:`holocore.runtime.mitsuba_env.mitsuba`, which sets the matching Mitsuba variant (``cuda_ad_rgb`` on CUDA,
``llvm_ad_rgb`` on the CPU) the first time Mitsuba is used; torch work then runs on the same device
(:func:`holocore.runtime.mitsuba_env.compute_device`). ``auto`` (the default) takes CUDA when torch sees a GPU.
"""

from __future__ import annotations

import os
import re
import sys
from typing import Optional

__all__ = ["ENV", "cuda_available", "requested_device", "select_device", "torch_device"]

ENV = "HOLO_DEVICE"
_PATTERN = re.compile(r"^(auto|cpu|cuda(:\d+)?)$")


def requested_device(name: Optional[str] = None) -> str:
    """``name``, else HOLO_DEVICE, else "auto"; checked to be auto, cpu, cuda or cuda:N."""
    raw = (name if name is not None else os.environ.get(ENV, "auto")).strip().lower() or "auto"
    if not _PATTERN.match(raw):
        src = "--device" if name is not None else ENV
        raise ValueError(f"{src} must be auto, cpu, cuda or cuda:N, got {raw!r}")
    return raw


def cuda_available() -> bool:
    """Whether torch sees a CUDA device (HOLO_NO_CUDA set: never)."""
    if os.environ.get("HOLO_NO_CUDA"):
        return False
    try:
        import torch

        return bool(torch.cuda.is_available())
    except Exception:  # noqa: BLE001 - torch absent or broken: no CUDA
        return False


def select_device(name: Optional[str] = None) -> str:
    """Resolve the device ("cpu" or "cuda[:N]") and record it in HOLO_DEVICE for this process and its children.

    Raises ValueError when CUDA is asked for but torch sees none, or when Mitsuba already runs a variant of the
    other kind in this process (the variant is chosen once)."""
    dev = requested_device(name)
    if dev == "auto":
        dev = "cuda" if cuda_available() else "cpu"
    elif dev.startswith("cuda") and not cuda_available():
        raise ValueError(f"device {dev} asked for, but torch sees no CUDA device")
    # Mitsuba's variant is set only through holocore.runtime.mitsuba_env (which reads this module's choice): not
    # imported yet, no variant is set
    mitsuba_env = sys.modules.get("holocore.runtime.mitsuba_env")
    current = mitsuba_env.variant_if_set() if mitsuba_env is not None else None
    if current is not None and current.startswith("cuda") != dev.startswith("cuda"):
        raise ValueError(f"device {dev} asked for, but this process already runs Mitsuba's {current}")
    os.environ[ENV] = dev
    return dev


def torch_device(name: Optional[str] = None):
    """The torch device of :func:`select_device`."""
    import torch

    return torch.device(select_device(name))
