"""Wave path tracing (docs/design.md §3-4): the map T (`mapping`), rays from the recording plane accumulated into
frames (`hologram_rays`), one tile of them in one Dr.Jit kernel (`tile`), the fused wave-path kernel (`kernel`)
and its float64 ray-differential transfer (`differentials`), the reference chain tracer the analysis and tests
trust (`reference_chain`), the fast preset's cache (`radiance_cache`) and the band-limited random fields and
frame phases (`randomfield`)."""
