"""The simulated world: a libsumo simulation (``world``), the route hazards as actors
(``hazard_actor``: their interface; ``hazards``: one class per hazard type), background
traffic (``traffic``), ego contacts (``contacts``), the route's global plan (``plan``) and
which of its stop signs the ego has satisfied (``stop_signs``). The only code of the project
that calls libsumo."""
