"""Evaluation (docs/design.md §7): views against Mitsuba ground truth (`scoring`, `groundtruth`), PSNR/SSIM
(`metrics`), pictures a person looks at (`preview`)."""
