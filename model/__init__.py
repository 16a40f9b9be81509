"""The student stage: the BEV student network (``network``), its loss (``loss``), its data
and BEV cache (``data``, ``cache``), training and checkpoints (``train``, ``checkpoint``,
``curves``), the student as a closed-loop agent (``agent``, ``runtime``) and the whole
experiment, collect to tables (``reproduce``, ``arm_tables``)."""
