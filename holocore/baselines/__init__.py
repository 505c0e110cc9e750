"""The methods we compare with, in the RESULT format, behind one interface (`registry`: `get_baseline`,
`baseline_names`): RGB-D layers (`layers`), the focal stack (`focal_stack`), the light field (`light_field`)."""
