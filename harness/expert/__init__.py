"""The privileged expert (``driver``) and the dataset it records: per-frame recording at
4 Hz (``collect``) and reading it back, with the closed-loop BEV (``dataset``)."""
