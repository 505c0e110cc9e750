"""holocore: the physics and numerics of wave path tracing (scene analysis, tracing, propagation,
random fields, encoding, viewing, metrics). Import submodules directly: `from holocore import propagation`."""

__version__ = "0.1.0"
