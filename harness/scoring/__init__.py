"""Everything that turns an episode into numbers: route-ending criteria (``criteria``),
Leaderboard infractions (``infractions``, ``lanes``) and scores (``scores``), stability
metrics (``stability``), the record schema (``records``), the run folder's files
(``outputs``), the paper's tables (``report``) and figures (``figures``), Bench2Drive's
figures and metric_info files (``bench2drive``) and tables (``b2d_tables``). Pure functions
of logs and records; nothing here runs the simulator."""
