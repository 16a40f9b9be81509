"""Route runs: jobs over local worker processes (``runner``) or Ray tasks (``ray_backend``),
and what software made a run (``provenance``)."""
