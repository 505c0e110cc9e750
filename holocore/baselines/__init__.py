"""The methods we compare with, in the RESULT format: RGB-D layers (`layers`) and the focal stack
(`focal_stack`)."""
