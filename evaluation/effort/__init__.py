"""Equal control effort: the effort statistics, the knob search and the matching of a run's controllers."""
