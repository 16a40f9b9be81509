"""Route runs: jobs over local worker processes (``runner``) or Ray tasks (``ray_backend``),
what software made a run (``provenance``) and the performance figures (``bench``)."""
