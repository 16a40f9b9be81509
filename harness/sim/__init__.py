"""The simulated world: a libsumo simulation (``world``), the route hazards as actors
(``hazard_actor``: their interface; ``hazards``: one class per hazard type), background
traffic (``traffic``), ego contacts (``contacts``) and the route's global plan (``plan``).
The only code of the project that calls libsumo."""
