"""torch set up once per process for reproducible CPU numerics; imported by every module that computes with
torch (importing it is the whole API).

torch's CPU ``sqrt`` runs on MKL's vector math (VML) over two or more threads. When the first such call runs on
two threads at once, MKL's lazy start-up races, and about one process in three then computes the worker
thread's half of every later call in a low-accuracy mode: float64 errors of 2e-11 (2e5 ulp) instead of 1 ulp,
float32 errors of 3e-4. The same seed then gave arrays that differ between processes (a service job's stack
against the CLI's), and the ASM transfer function lost accuracy. One small call on this thread first lets MKL
start up alone (tests/optics/test_propagation.py checks 1 ulp in fresh processes).
"""

from __future__ import annotations

import torch

torch.sqrt(torch.ones(4, dtype=torch.float32))  # below torch's parallel grain: runs on this thread only
