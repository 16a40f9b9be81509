"""The ego's vehicle and its controllers: the kinematic ego model the harness integrates
(``vehicle``), PIDs (``pid``), PDM-Lite's longitudinal controller the expert drives with
(``longitudinal``), and SimLingo's controller, with its compiled look-ahead
(``simlingo``, ``lookahead``), that turns a student's predicted path and speed waypoints
into steer, throttle and brake."""
