"""The closed loop (docs/design.md §3-§5, §9-§10): one subpackage per concern, imported in this order.

    common/    atomic file writes, the bad-input error, the run-folder lock, the user's
               stops (Ctrl-C, SIGTERM) told from an agent's exceptions; shared by every stage
    sim/       the simulated world: libsumo, hazards, background traffic, contacts, the
               route's global plan (the only code that calls libsumo)
    sensors/   the BEV raster
    scoring/   route-ending criteria, Leaderboard infractions and scores, stability
               metrics, the record schema, run-folder files, reports and figures
    loop/      the agent API, the episode loop, the reference agent, rendering
    expert/    the privileged expert and the dataset it records
    runs/      route runs over processes or Ray, provenance, the bench

Each subpackage imports only the ones above it in this list.
"""
