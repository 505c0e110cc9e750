"""Fullscreen SLM window (pygame / SDL2): the SLM is driven as a monitor.

Frames are preloaded as display-format surfaces (gray levels on all three RGB channels), shown one per
vsync with ``pygame.display.flip``. pygame is imported only here (lazily), so the agent runs without it
when another backend is used. Headless tests use ``SDL_VIDEODRIVER=dummy``.
"""

from __future__ import annotations

import os
from typing import Optional

import numpy as np

from display_agent.slm.base import SLM, SLMError

__all__ = ["WindowSLM"]


class WindowSLM(SLM):
    """``monitor``: SDL display index; ``size``: (W, H) of the window (default: the monitor's mode).

    A stack smaller than the window is centred on a level-0 background; a larger one is refused."""

    @classmethod
    def from_spec(cls, arg: str) -> "WindowSLM":
        """``MONITOR[:WxH]`` (both optional)."""
        monitor, _, size = arg.partition(":")
        try:
            mon = int(monitor) if monitor else 0
            wh = tuple(int(v) for v in size.lower().split("x")) if size else None
        except ValueError:
            raise ValueError(f"slm window spec must be window[:MONITOR[:WxH]], got {arg!r}") from None
        if wh is not None and len(wh) != 2:
            raise ValueError(f"slm window size must be WxH, got {size!r}")
        return cls(monitor=mon, size=wh)  # type: ignore[arg-type]

    def __init__(self, *, monitor: int = 0, size: Optional[tuple[int, int]] = None, vsync: bool = True,
                 fullscreen: bool = True) -> None:
        super().__init__()
        os.environ.setdefault("PYGAME_HIDE_SUPPORT_PROMPT", "1")
        try:
            import pygame
        except ImportError as exc:  # pragma: no cover - depends on the install
            raise SLMError("the window SLM needs pygame (pip install 'holopathtracer[agent]')") from exc
        self._pg = pygame
        pygame.display.init()
        n = pygame.display.get_num_displays()
        if not (0 <= monitor < n):
            raise ValueError(f"monitor must be in [0, {n - 1}], got {monitor}")
        if size is None:
            sizes = pygame.display.get_desktop_sizes()
            size = tuple(sizes[monitor]) if monitor < len(sizes) else (1920, 1080)
        w, h = int(size[0]), int(size[1])
        if w < 1 or h < 1:
            raise ValueError(f"size must be positive (W, H), got {size}")
        flags = pygame.FULLSCREEN if fullscreen else 0
        try:
            self._screen = pygame.display.set_mode((w, h), flags, display=monitor, vsync=1 if vsync else 0)
        except pygame.error:  # some drivers cannot vsync (dummy, software): fall back, still counts frames
            self._screen = pygame.display.set_mode((w, h), flags, display=monitor)
        pygame.display.set_caption("holo SLM")
        pygame.mouse.set_visible(False)
        self.size = tuple(self._screen.get_size())  # the mode SDL gave (fullscreen may differ from asked)
        self._surfaces: dict[tuple[int, int], object] = {}

    def _prepare(self, levels: np.ndarray, stack_id: str) -> None:
        pg = self._pg
        f, c, h, w = levels.shape
        if w > self.size[0] or h > self.size[1]:
            raise ValueError(f"stack frames are {w}x{h}, larger than the SLM window {self.size[0]}x{self.size[1]}")
        surfaces = {}
        for i in range(f):
            for j in range(c):
                rgb = np.repeat(levels[i, j][:, :, None], 3, axis=2)  # [H, W, 3]
                surf = pg.image.frombuffer(np.ascontiguousarray(rgb).tobytes(), (w, h), "RGB")
                surfaces[(i, j)] = surf.convert()  # display format: blits are plain copies
        self._surfaces = surfaces
        self._origin = ((self.size[0] - w) // 2, (self.size[1] - h) // 2)

    def _pump(self) -> None:
        for event in self._pg.event.get():
            if event.type == self._pg.QUIT:
                raise SLMError("SLM window closed")

    def _present(self, frame: int, color: int) -> None:
        self._pump()
        self._screen.fill((0, 0, 0))
        self._screen.blit(self._surfaces[(frame, color)], self._origin)
        self._pg.display.flip()

    def screen_levels(self) -> np.ndarray:
        """The gray levels now on the window, uint8 [H, W] (red channel; for checks)."""
        arr = self._pg.surfarray.array3d(self._screen)  # [W, H, 3]
        return np.ascontiguousarray(arr[:, :, 0].T)

    def _blank(self) -> None:
        self._surfaces = {}
        self._screen.fill((0, 0, 0))
        self._pg.display.flip()

    def close(self) -> None:
        try:
            self._pg.display.quit()
        except Exception:  # pragma: no cover
            pass
