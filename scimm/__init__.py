"""The teacher stage: the path-speed representation of the expert's trajectories
(``pathspeed``, ``planref``, ``ego``), the five motion modes and their scene conditioning
(``modes``, ``cues``, ``scene``), the Fixed-IMM and SC-IMM filters and the offline smoother
(``imm``, ``smoother``), the teacher labels they write for a dataset (``teacher``,
``stage``) and the paper's Table 2 and lag figures (``table2``, ``lag``, ``plot``)."""
