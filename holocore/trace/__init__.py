"""Wave path tracing (DESIGN.md §3-4): the map T (`mapping`), rays from the recording plane and their
accumulation into frames (`hologram_rays`), the fused Dr.Jit wave-path kernel (`kernel`), the reference chain
tracer the analysis and tests trust (`reference_chain`), the fast preset's cache (`radiance_cache`) and the
band-limited random fields and frame phases (`randomfield`)."""
