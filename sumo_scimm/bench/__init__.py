"""``sumo-scimm bench``, all of it: the closed loop's figures (``closed_loop``), the IMM's
(``imm``), the student's (``student``), the whole-evaluation and machine figures
(``figures``) and the subcommand that prints them (``command``). It measures every stage,
so it sits in the last one. Nothing is imported here: ``python -m sumo_scimm.bench.imm``
sets its thread counts before NumPy loads."""
