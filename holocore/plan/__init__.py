"""Planning a render before it runs (docs/design.md §8): the sparse pre-pass (`analysis`), the EffectPlan (`effects`),
several recording planes (`wrp_planes`), time and memory estimates (`estimate`, `estimate_probe`,
`memory_estimate`; the machine calibration in `data/`)."""
