"""The ego's vehicle and its controllers: the two ego models the harness integrates, CARLA's
Lincoln MKZ (``carla_car``, compiled, with CPython's hypot in ``hypot``) and the kinematic
bicycle (``vehicle``), chosen by name in ``ego``; PIDs (``pid``), PDM-Lite's longitudinal
controller the expert drives with (``longitudinal``), and SimLingo's controller, with its
compiled look-ahead (``simlingo``, ``lookahead``), that turns a student's predicted path
and speed waypoints into steer, throttle and brake."""
