"""The display a hologram is for (docs/design.md §2-3): its optics (`optics`: OpticsConfig, the recording cone) and
named or user display profiles (`profiles`: the paper's display is the default)."""
