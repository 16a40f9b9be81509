"""The simulated world: a libsumo session (``world``), the route hazards as actors
(``hazards``), background traffic (``traffic``), ego contacts (``contacts``) and the route's
global plan (``plan``). The only code of the project that calls libsumo."""
