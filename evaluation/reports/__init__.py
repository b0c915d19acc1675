"""The reports of a run: the summary table beside the paper's Table I, the paired statistics and the written
``summary.md`` and plots."""
