"""Process set-up chosen once: the compute device (`device`), the Mitsuba variant (`mitsuba_env`), reproducible
torch CPU numerics (`torch_runtime`) and the memory budget (`membudget`)."""
