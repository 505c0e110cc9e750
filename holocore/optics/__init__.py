"""Wave optics (docs/design.md §5, §7): band-limited ASM (`propagation`), several recording planes chained by it
(`plane_chain`), an eye's view of a hologram (`viewing`, `fieldsource`) and the direct Rayleigh-Sommerfeld
reference (`rs_reference`)."""
